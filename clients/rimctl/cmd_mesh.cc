// rimctl mesh (tiles to files) and rimctl watch (live tile updates and session stats).
#include <chrono>
#include <condition_variable>
#include <fstream>
#include <iostream>
#include <limits>
#include <mutex>
#include <optional>
#include <thread>

#include "absl/strings/str_format.h"
#include "rim/base/binary_io.h"
#include "rim/io/mesh_io.h"
#include "rimctl/commands.h"

namespace rim::rimctl {
namespace {

constexpr char kMeshUsage[] = R"(usage: rimctl mesh ROBOT_ID --out DIR [--since V] [--resolution M]

Fetches the session's mesh tiles (one per sub-map, Draco-compressed) newer than map version V
(default 0: all), writes each as DIR/tile_X_Y_Z.drc and all of them merged into DIR/mesh.ply,
with the copies of border vertices that neighbouring tiles share welded into one. Prints the tile
count, Draco bytes, and the merged mesh's vertices and faces.
--resolution M: the level of detail, M metres a mesh cell (one of the session's mesh levels,
`rimctl session get` lists them; default 0: the finest).
)";

constexpr char kWatchUsage[] =
    R"(usage: rimctl watch ROBOT_ID [--count N] [--duration S] [--since V] [--resolution M]

Prints each mesh tile as training changes it, and the session's stats every 2 s. Starts from the
session's current map version (--since 0 first replays every tile). Stops after N tiles, after S
seconds, or on Ctrl-C. --resolution M watches the tiles at level of detail M metres (one of the
session's mesh levels; default 0: the finest).
)";

std::string TileName(const DecodedTile& t) {
  return absl::StrFormat("tile_%d_%d_%d", t.key[0], t.key[1], t.key[2]);
}

// Prints the session's stats every 2 s from its own thread until stopped.
class StatsPrinter {
 public:
  StatsPrinter(const SessionHandle& session, std::mutex* out_mu, std::ostream& out)
      : session_(session), out_mu_(out_mu), out_(out), thread_([this] { Run(); }) {}
  ~StatsPrinter() { Stop(); }

  void Stop() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      done_ = true;
    }
    cv_.notify_all();
    if (thread_.joinable()) thread_.join();
  }

 private:
  void Run() {
    std::unique_lock<std::mutex> lock(mu_);
    while (!cv_.wait_for(lock, std::chrono::seconds(2), [this] { return done_; })) {
      lock.unlock();
      auto s = session_.Info();  // without the lock: Stop must not wait for a slow call
      lock.lock();
      if (!s.ok() || done_) continue;
      std::lock_guard<std::mutex> out_lock(*out_mu_);
      out_ << absl::StrFormat(
                  "stats: integrated frames %u, queue %u, iterations %u, map version %u, "
                  "loss %.4g\n",
                  s->integrated_frames(), s->queue_depth(), s->iterations_per_frame(),
                  s->map_version(), s->last_loss())
           << std::flush;
    }
  }

  const SessionHandle session_;
  std::mutex* const out_mu_;
  std::ostream& out_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool done_ = false;
  std::thread thread_;  // last: starts after the members it uses
};

}  // namespace

int RunMesh(const std::vector<std::string>& words, const Io& io) {
  auto args = Args::Parse(words, WithGlobalFlags({{"out", FlagKind::kValue},
                                                  {"since", FlagKind::kValue},
                                                  {"resolution", FlagKind::kValue}}));
  if (!args.ok()) return UsageError(io, "mesh", std::string(args.status().message()), kMeshUsage);
  if (args->help()) return PrintHelp(io, kMeshUsage);
  if (args->positional().size() != 1) {
    return UsageError(io, "mesh", "needs exactly one ROBOT_ID", kMeshUsage);
  }
  if (args->Get("out").empty()) return UsageError(io, "mesh", "needs --out DIR", kMeshUsage);
  auto since = args->GetInt("since", 0, 0, std::numeric_limits<long>::max());
  if (!since.ok()) return UsageError(io, "mesh", std::string(since.status().message()), kMeshUsage);
  auto resolution = args->GetDouble("resolution", 0, 0, 100);
  if (!resolution.ok())
    return UsageError(io, "mesh", std::string(resolution.status().message()), kMeshUsage);
  const std::string robot = args->positional()[0], dir = args->Get("out");

  auto client = ConnectFromArgs(*args);
  if (!client.ok()) return Fail(io, client.status());
  auto tiles = client->Session(robot).MeshTiles(uint64_t(*since), std::nullopt, float(*resolution));
  if (!tiles.ok()) return Fail(io, tiles.status());
  const absl::Status made = MakeDirs(dir);
  if (!made.ok()) return Fail(io, made);
  size_t bytes = 0;
  for (const DecodedTile& t : *tiles) {
    const std::string path = dir + "/" + TileName(t) + ".drc";
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(t.draco.data(), std::streamsize(t.draco.size()));
    out.close();
    if (!out) return Fail(io, absl::PermissionDeniedError("cannot write " + path));
    bytes += t.draco.size();
  }
  size_t tile_vertices = 0;
  for (const DecodedTile& t : *tiles) tile_vertices += t.mesh.vertices.size();
  const Mesh merged = MergeTiles(*tiles);
  const std::string ply = dir + "/mesh.ply";
  const absl::Status written = WriteMeshPly(ply, merged);
  if (!written.ok()) return Fail(io, written);
  io.out << absl::StrFormat(
                "tiles: %u, bytes: %u, vertices: %u, faces: %u (%u shared border vertices "
                "welded)\n",
                tiles->size(), bytes, merged.vertices.size(), merged.faces.size(),
                tile_vertices - merged.vertices.size())
         << "wrote " << tiles->size() << " .drc tiles and " << ply << "\n";
  return kExitOk;
}

int RunWatch(const std::vector<std::string>& words, const Io& io) {
  auto args = Args::Parse(words, WithGlobalFlags({{"count", FlagKind::kValue},
                                                  {"duration", FlagKind::kValue},
                                                  {"since", FlagKind::kValue},
                                                  {"resolution", FlagKind::kValue}}));
  if (!args.ok()) return UsageError(io, "watch", std::string(args.status().message()), kWatchUsage);
  if (args->help()) return PrintHelp(io, kWatchUsage);
  if (args->positional().size() != 1) {
    return UsageError(io, "watch", "needs exactly one ROBOT_ID", kWatchUsage);
  }
  auto count = args->GetInt("count", 0, 1, std::numeric_limits<int>::max());
  auto duration = args->GetDouble("duration", 0, 0.001, 1e7);
  auto since = args->GetInt("since", -1, 0, std::numeric_limits<long>::max());
  auto resolution = args->GetDouble("resolution", 0, 0, 100);
  for (const absl::Status& s :
       {count.status(), duration.status(), since.status(), resolution.status()}) {
    if (!s.ok()) return UsageError(io, "watch", std::string(s.message()), kWatchUsage);
  }
  const std::string robot = args->positional()[0];
  auto client = ConnectFromArgs(*args);
  if (!client.ok()) return Fail(io, client.status());
  const SessionHandle session = client->Session(robot);
  auto info = session.Info();
  if (!info.ok()) return Fail(io, info.status());

  WatchOptions options;
  options.since_version = *since >= 0 ? uint64_t(*since) : info->map_version();
  options.duration = std::chrono::milliseconds(long(*duration * 1000));
  options.resolution_m = float(*resolution);
  io.out << "watching " << robot << " from map version " << options.since_version << "\n"
         << std::flush;

  std::mutex out_mu;  // tile lines and stats lines come from two threads
  StatsPrinter stats(session, &out_mu, io.out);
  long seen = 0;
  const auto start = std::chrono::steady_clock::now();
  const absl::Status watched = session.Watch(
      [&](const DecodedTile& t) {
        std::lock_guard<std::mutex> lock(out_mu);
        ++seen;
        io.out << absl::StrFormat(
                      "tile (%d,%d,%d) version %u: %u faces, %u vertices, %u bytes, %g m\n",
                      t.key[0], t.key[1], t.key[2], t.version, t.mesh.faces.size(),
                      t.mesh.vertices.size(), t.draco.size(), t.resolution_m)
               << std::flush;
        return *count == 0 || seen < *count;
      },
      options);
  stats.Stop();
  if (!watched.ok()) return Fail(io, watched);
  io.out << absl::StrFormat(
      "watched %d tile updates in %.1f s\n", seen,
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  return kExitOk;
}

}  // namespace rim::rimctl
