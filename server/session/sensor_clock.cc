#include "server/session/sensor_clock.h"

#include <algorithm>

namespace rim::server {

double SensorClock::AheadLimit() const {
  const double period_s = scans_ > 1 ? (last_timestamp_s_ - first_timestamp_s_) / (scans_ - 1) : 0;
  return std::max(kAheadMinS, 2 * period_s);
}

void SensorClock::Arrive(double arrival_s, double timestamp_s, bool pushed_back) {
  // A gap the session made (it held the stream back) is no pause of the sender's.
  const bool pause =
      last_arrival_s_ < 0 || (!pushed_back && arrival_s - last_arrival_s_ >= kPauseS);
  const bool forward = timestamp_s > last_timestamp_s_;
  last_arrival_s_ = arrival_s;
  last_timestamp_s_ = timestamp_s;
  if (pause || !forward) {
    offset_s_ = arrival_s - timestamp_s;
    first_timestamp_s_ = timestamp_s;
    scans_ = 1;
    lead_s_ = 0;
    ahead_ = false;
    return;
  }
  ++scans_;
  lead_s_ = offset_s_ - (arrival_s - timestamp_s);
  const bool past = lead_s_ > AheadLimit();
  ahead_ = past || (pushed_back && ahead_);
}

}  // namespace rim::server
