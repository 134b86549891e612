// The clock of the sensor behind a session's real-time stream, read from its scans' timestamps
// against their arrival (DESIGN.md §5.2, "Sensor time, not client speed"). A live sensor cannot
// send a scan before it took it: counted from the first scan of a run, its timestamps advance no
// faster than the scans arrive, give or take how late that first scan was. A sender whose
// timestamps run ahead of their arrival by more than AheadLimit() holds scans the sensor's clock
// has not reached yet: a recorded drive sent faster than real time. The session then trains it
// as a replay: the configured iterations every frame, and backpressure when its queue is full
// (docs/service.md, "Replays keep the offline map").
#pragma once

namespace rim::server {

class SensorClock {
 public:
  // A scan's timestamp may run ahead of its arrival by the larger of this and two sensor periods
  // (the mean interval between the run's timestamps) before the sender counts as ahead: a live
  // sensor's first scan may come that much later than the rest. A replay gets that far ahead
  // before its queue is full (a queue of 8 holds 0.7 s of a 10 Hz drive).
  static constexpr double kAheadMinS = 0.15;
  // A gap this long between two scans, none of them held back by the session, is a pause: the
  // next scan starts a new run (and reads the clock afresh).
  static constexpr double kPauseS = 2.0;

  // A scan accepted at `arrival_s` (steady clock seconds) with sensor time `timestamp_s`.
  // `pushed_back`: the session refused or held back the stream since the last scan, so this scan
  // came later than its sender had it: past the limit it shows the sender ahead, below it it
  // shows nothing, and leaves ahead() as it was.
  // Timestamps that do not increase (absent: all 0, or a new drive) start a new run: without a
  // clock, the sender's word (the stream's real-time header) decides alone.
  void Arrive(double arrival_s, double timestamp_s, bool pushed_back);
  // Forgets the clock: the next scan starts a new run.
  void Reset() { *this = SensorClock(); }

  // The sender was ahead of the sensor's clock at the last scan it sent at its own pace.
  bool ahead() const { return ahead_; }
  // Seconds the last scan's timestamp ran ahead of its arrival, from the run's first scan
  // (negative: it came later than the clock says).
  double lead_s() const { return lead_s_; }
  // How far ahead a scan may run: kAheadMinS, or two sensor periods when longer.
  double AheadLimit() const;

 private:
  double offset_s_ = 0;  // arrival less timestamp of the run's first scan
  double first_timestamp_s_ = 0;
  int scans_ = 0;  // in the run
  double last_arrival_s_ = -1, last_timestamp_s_ = 0;
  double lead_s_ = 0;
  bool ahead_ = false;
};

}  // namespace rim::server
