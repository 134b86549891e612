#include "rimctl/progress.h"

#include <algorithm>
#include <string>

namespace rim::rimctl {

StreamProgress::StreamProgress(uint64_t total, bool tty, std::FILE* out)
    : total_(total), tty_(tty), out_(out), start_(std::chrono::steady_clock::now()) {}

void StreamProgress::OnSent(uint64_t sent) {
  std::lock_guard<std::mutex> lock(mu_);
  sent_ = sent;
  DrawLocked(false);
}

void StreamProgress::OnAck(const rim::v1::ScanAck& ack) {
  std::lock_guard<std::mutex> lock(mu_);
  switch (ack.state()) {
    case rim::v1::ScanAck::ACCEPTED:
      ++accepted_;
      break;
    case rim::v1::ScanAck::INTEGRATED:
      ++integrated_;
      break;
    case rim::v1::ScanAck::REJECTED:
      ++rejected_;
      break;
    default:
      break;
  }
  lag_ = ack.lag_frames();
  DrawLocked(false);
}

void StreamProgress::Note(const std::string& line) {
  std::lock_guard<std::mutex> lock(mu_);
  std::fprintf(out_, tty_ ? "\r%s\x1b[K\n" : "%s\n", line.c_str());
  std::fflush(out_);
  if (tty_) DrawLocked(true);
}

void StreamProgress::Finish() {
  std::lock_guard<std::mutex> lock(mu_);
  DrawLocked(true);
  if (tty_) std::fputc('\n', out_);
  std::fflush(out_);
}

void StreamProgress::DrawLocked(bool force) {
  const auto now = std::chrono::steady_clock::now();
  const double seconds = std::chrono::duration<double>(now - start_).count();
  const double rate = seconds > 0 ? double(integrated_) / seconds : 0.0;
  // A scan is done once integrated or rejected.
  const uint64_t done = std::min(total_, integrated_ + rejected_);
  if (tty_) {
    // Redrawing more often than 10 times a second only costs terminal bandwidth.
    if (!force && now - last_draw_ < std::chrono::milliseconds(100)) return;
    last_draw_ = now;
    constexpr int kWidth = 30;
    const int filled = total_ ? int(kWidth * done / total_) : kWidth;
    std::fprintf(out_,
                 "\r[%s%s] sent %llu/%llu  accepted %llu  integrated %llu  rejected %llu  lag %llu"
                 "  %.2f frames/s\x1b[K",
                 std::string(filled, '#').c_str(), std::string(kWidth - filled, '.').c_str(),
                 (unsigned long long)sent_, (unsigned long long)total_,
                 (unsigned long long)accepted_, (unsigned long long)integrated_,
                 (unsigned long long)rejected_, (unsigned long long)lag_, rate);
    std::fflush(out_);
    return;
  }
  const bool crossed = total_ > 0 && done * 10 >= uint64_t(next_decile_) * total_;
  if (crossed) {
    while (next_decile_ <= 10 && done * 10 >= uint64_t(next_decile_) * total_) ++next_decile_;
  } else if (!force || next_decile_ > 10) {
    return;  // between tenths, or the final state was already printed at 100%
  }
  last_draw_ = now;
  std::fprintf(out_,
               "stream: %3d%%  sent %llu/%llu  accepted %llu  integrated %llu  rejected %llu  "
               "lag %llu  %.2f frames/s\n",
               total_ ? int(100 * done / total_) : 100, (unsigned long long)sent_,
               (unsigned long long)total_, (unsigned long long)accepted_,
               (unsigned long long)integrated_, (unsigned long long)rejected_,
               (unsigned long long)lag_, rate);
  std::fflush(out_);
}

}  // namespace rim::rimctl
