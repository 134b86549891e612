// What the INTEGRATED acks of one StreamScans call said, in order, for the tests that compare how
// a session paced two streams (server_pacing_test, server_replay_test).
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <vector>

#include "rim/v1/rim.pb.h"

namespace rim::testing_support {

struct StreamAcks {
  std::vector<int> iterations, rays, lag;
  std::vector<uint64_t> versions;  // the map version each ack reported
  double seconds = 0;              // from the first scan sent to the last ack, when set

  // A StreamOptions::on_ack that records each INTEGRATED ack here (the client's reader thread
  // calls it). The log must outlive the stream.
  std::function<void(const rim::v1::ScanAck&)> Recorder() {
    return [this, mu = std::make_shared<std::mutex>()](const rim::v1::ScanAck& ack) {
      if (ack.state() != rim::v1::ScanAck::INTEGRATED) return;
      std::lock_guard<std::mutex> lock(*mu);
      iterations.push_back(int(ack.iterations()));
      rays.push_back(int(ack.rays_per_iteration()));
      lag.push_back(int(ack.lag_frames()));
      versions.push_back(ack.map_version());
    };
  }
};

// The median (the upper one of an even count); -1 for none.
inline int Median(std::vector<int> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? -1 : v[v.size() / 2];
}

// The median of the second half: once a stream's pace and costs are known.
inline int SecondHalfMedian(std::vector<int> v) {
  v.erase(v.begin(), v.begin() + std::ptrdiff_t(v.size() / 2));
  return Median(std::move(v));
}

}  // namespace rim::testing_support
