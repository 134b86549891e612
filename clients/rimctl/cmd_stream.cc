// rimctl stream ROBOT_ID DATASET: streams a dataset's scans into a session over one StreamScans
// call, shows progress, and waits until every scan is integrated.
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <iostream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/wire.h"
#include "rimctl/commands.h"
#include "rimctl/frame_source.h"
#include "rimctl/progress.h"

namespace rim::rimctl {
namespace {

constexpr char kStreamUsage[] =
    R"(usage: rimctl stream ROBOT_ID DATASET [--rate HZ] [--frames A:B] [--retries N]

Streams posed scans into the session ROBOT_ID and waits until every scan is integrated (trained).
DATASET is a dataset folder in any layout rim reads (KITTI, PLY frames, PCD frames, 7-Scenes,
Replica), or sim:city for the built-in synthetic city, generated in memory, with options as
sim:city?frames=N&seed=S&step=M&columns=C&noise=M&walkers=K&threads=T (quote it in a shell;
defaults: 100 frames, seed 1, 1 m steps, 1800 LiDAR columns, no noise, no walkers).

  --rate HZ      send at most HZ scans per second, as a live robot would: the session then
                 trains what keeps up with the rate (default: as fast as the server takes them,
                 a replay: every frame trains the session's full iterations, as rim_map does)
  --frames A:B   only frames A (inclusive) to B (exclusive); either end may be left out
  --retries N    when the stream breaks (server, proxy or connection gone), open a new one up to
                 N times, a second apart, and send again every scan not yet integrated; the
                 server skips those it had accepted (default 3; 0: give up at once)

Progress goes to stderr (a live bar on a terminal, a line per 10% otherwise). The last line on
stdout reads "stream ROBOT_ID: sent: N, accepted: N, integrated: N, rejected: N, ...". Scan
sequence numbers are the frame indices, so a drive resumed later with --frames A: keeps them
increasing, as retries need. Exit 4 when any scan was rejected (reasons on stderr).
)";

constexpr size_t kMaxRejectionsShown = 20;

// Opens DATASET and resolves --frames against its size into [*first, *last).
absl::StatusOr<std::unique_ptr<FrameSource>> OpenSource(const std::string& dataset,
                                                        const FrameRange& range,
                                                        const std::string& range_text, long* first,
                                                        long* last) {
  auto source = OpenFrameSource(dataset);
  if (!source.ok()) return source.status();
  const long size = long((*source)->size());
  *first = range.first;
  *last = range.last < 0 ? size : range.last;
  if (*first >= size || *last > size) {
    return absl::OutOfRangeError(absl::StrFormat(
        "--frames %s is outside %s, which has %d frames (0:%d)", range_text, dataset, size, size));
  }
  return source;
}

// Rejection reasons on stderr, the summary line scripts read on stdout.
void PrintSummary(const std::string& robot, const StreamSummary& summary, const Io& io) {
  for (size_t i = 0; i < summary.rejections.size() && i < kMaxRejectionsShown; ++i) {
    const auto& r = summary.rejections[i];
    io.err << "rejected scan " << r.sequence << " (gRPC code " << r.code << "): " << r.reason
           << "\n";
  }
  if (summary.rejections.size() > kMaxRejectionsShown) {
    io.err << "... and " << summary.rejections.size() - kMaxRejectionsShown << " more rejections\n";
  }
  const double fps = summary.seconds > 0 ? double(summary.integrated) / summary.seconds : 0.0;
  io.out << absl::StrFormat(
      "stream %s: sent: %u, accepted: %u, integrated: %u, rejected: %u, %.1f s, %.2f frames/s, "
      "map version %u\n",
      robot, summary.sent, summary.accepted, summary.integrated, summary.rejected, summary.seconds,
      fps, summary.map_version);
}

}  // namespace

int RunStream(const std::vector<std::string>& words, const Io& io) {
  auto args = Args::Parse(words, WithGlobalFlags({{"rate", FlagKind::kValue},
                                                  {"frames", FlagKind::kValue},
                                                  {"retries", FlagKind::kValue}}));
  if (!args.ok()) {
    return UsageError(io, "stream", std::string(args.status().message()), kStreamUsage);
  }
  if (args->help()) return PrintHelp(io, kStreamUsage);
  if (args->positional().size() != 2) {
    return UsageError(io, "stream", "needs ROBOT_ID and DATASET", kStreamUsage);
  }
  const std::string robot = args->positional()[0];
  const std::string dataset = args->positional()[1];
  auto rate = args->GetDouble("rate", 0, 0, 1e6);
  if (!rate.ok())
    return UsageError(io, "stream", std::string(rate.status().message()), kStreamUsage);
  auto retries = args->GetDouble("retries", 3, 0, 1000);
  if (!retries.ok() || *retries != double(int(*retries)))
    return UsageError(io, "stream", "--retries: expected a whole number in [0, 1000]",
                      kStreamUsage);
  FrameRange range;
  if (args->Has("frames")) {
    auto parsed = ParseFrameRange(args->Get("frames"));
    if (!parsed.ok()) {
      return UsageError(io, "stream", std::string(parsed.status().message()), kStreamUsage);
    }
    range = *parsed;
  }

  long first = 0, last = 0;
  auto source = OpenSource(dataset, range, args->Get("frames"), &first, &last);
  if (!source.ok()) return Fail(io, source.status());

  auto client = ConnectFromArgs(*args);
  if (!client.ok()) return Fail(io, client.status());
  // An unknown session would reject every scan; say so once, before reading any.
  auto before = client->GetSession(robot);
  if (!before.ok()) return Fail(io, before.status());

  io.err << "streaming " << (*source)->Describe() << ", frames " << first << ":" << last
         << " into session " << robot << " at " << client->address() << "\n";
  StreamProgress progress(uint64_t(last - first), isatty(STDERR_FILENO) != 0);
  StreamOptions options;
  options.rate_hz = *rate;
  options.first_sequence = uint64_t(first);
  options.max_retries = int(*retries);
  options.on_ack = [&](const rim::v1::ScanAck& ack) { progress.OnAck(ack); };
  options.on_sent = [&](uint64_t sent) { progress.OnSent(sent); };
  options.on_stuck = [&] {
    progress.Note(absl::StrCat(
        "stream: the cancelled stream to ", client->address(),
        " has not ended; giving up (gRPC leaves such a call blocked when a proxy answers it with ",
        "a response that is not gRPC, e.g. an HTML error page: docs/clients.md)"));
    std::fflush(stdout);
    std::_Exit(kExitUnreachable);
  };
  options.on_retry = [&](int retry, const absl::Status& why) {
    progress.Note(absl::StrCat("stream: broken (", why.ToString(), "); opening it again (retry ",
                               retry, " of ", options.max_retries, ")"));
  };
  long next = first;
  const FrameSource& frames = **source;
  auto summary = client->Session(robot).Stream(
      [&](rim::v1::Scan* scan) -> absl::StatusOr<bool> {
        if (next >= last) return false;
        auto frame = frames.Read(size_t(next));
        if (!frame.ok()) return frame.status();
        *scan = ScanToProto(*frame, robot, uint64_t(next));
        ++next;
        return true;
      },
      options);
  progress.Finish();
  if (!summary.ok()) return Fail(io, summary.status());
  if (summary->retries > 0)
    io.err << "the stream broke and was opened again " << summary->retries << " time(s); "
           << summary->duplicates << " resent scan(s) had been accepted before\n";

  PrintSummary(robot, *summary, io);
  return summary->rejected > 0 ? kExitRejected : kExitOk;
}

}  // namespace rim::rimctl
