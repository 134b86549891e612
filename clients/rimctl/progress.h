// `rimctl stream`'s live progress on stderr: a redrawn bar when stderr is a terminal, otherwise
// (logs, CI) one line per tenth of the frames, so that the output stays readable in a file.
#pragma once

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <mutex>
#include <string>

#include "rim/v1/rim.pb.h"

namespace rim::rimctl {

class StreamProgress {
 public:
  // `total`: frames to send; `tty`: redraw one line in place (else print lines at each 10%).
  StreamProgress(uint64_t total, bool tty, std::FILE* out = stderr);

  // Thread-safe: called from the writer and the ack reader threads.
  void OnSent(uint64_t sent);
  void OnAck(const rim::v1::ScanAck& ack);
  // Prints a line of its own (on a terminal: above the bar, which is then drawn again).
  void Note(const std::string& line);
  // Draws the final state (and ends the bar's line on a terminal).
  void Finish();

 private:
  void DrawLocked(bool force);

  const uint64_t total_;
  const bool tty_;
  std::FILE* const out_;
  const std::chrono::steady_clock::time_point start_;
  std::mutex mu_;
  uint64_t sent_ = 0, accepted_ = 0, integrated_ = 0, rejected_ = 0, lag_ = 0;
  int next_decile_ = 1;  // non-terminal output: the next tenth to report
  std::chrono::steady_clock::time_point last_draw_{};
};

}  // namespace rim::rimctl
