// The sessions the service fuzz targets work on: a tiny map (seven voxels a side, one level,
// two features, one training iteration on 64 rays) so that creating, training, saving and loading
// one takes about a millisecond, and a session manager over a scratch data directory.
#pragma once

#include <google/protobuf/stubs/logging.h>

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "fuzz_util.h"
#include "server/service/service.h"
#include "server/session/session_manager.h"
#include "support/small_session.h"

namespace rim::fuzz {

inline constexpr char kRobot[] = "fuzz";

// CreateSession overrides of the tiny map: a 2.4 m x 2.4 m x 1.6 m box of 0.4 m voxels.
inline std::vector<std::pair<std::string, std::string>> TinyMapOverrides() {
  return {{"grid.leaf_size_m", "0.4"},
          {"grid.levels", "1"},
          {"grid.feature_dim", "2"},
          {"grid.half_extent_x_m", "1.2"},
          {"grid.half_extent_y_m", "1.2"},
          {"grid.z_min_m", "-0.8"},
          {"grid.z_max_m", "0.8"},
          {"decoder.hidden_width", "8"},
          {"train.iterations", "1"},
          {"train.min_iterations", "1"},
          {"sampler.rays_per_iteration", "64"},
          {"sampler.free_space_rays", "64"},
          {"buffer.max_points", "64"},
          {"buffer.max_points_per_frame", "32"},
          {"submap.block_size", "2"},
          {"mesh.resolution_m", "0.2"}};
}

// 81 returns 25 cm apart on a floor 0.6 m below a sensor at (x, 0, 0): inside the tiny map's box.
inline PosedScan TinyScan(double x) { return testing_support::FloorScan(x, 9, 0.25f, 0.6f); }

// A session manager as rim_server builds one (session_manager.h), over its own scratch data
// directory, with the server's default limits except a host memory budget: a session file that
// asks for a map larger than it is refused before anything is allocated.
struct FuzzService {
  explicit FuzzService(const std::string& name, int checkpoint_every_frames = 0)
      : quiet((google::protobuf::SetLogHandler(nullptr), true)), dir(name), sessions([&] {
          server::SessionManagerOptions o;
          o.data_dir = dir.path();
          o.checkpoint_every_frames = checkpoint_every_frames;
          o.host_memory_budget_bytes = uint64_t{256} << 20;
          return o;
        }()) {
    limits.host_memory_budget_bytes = uint64_t{256} << 20;
  }

  std::string SessionDir() const { return dir.path() + "/sessions/" + kRobot; }

  // Protobuf logs every string field with invalid UTF-8 that it parses, and the fuzzer makes
  // thousands a second: the log handler is switched off first.
  bool quiet;
  ScratchDir dir;
  server::SessionManager sessions;
  server::ServiceLimits limits;
};

}  // namespace rim::fuzz
