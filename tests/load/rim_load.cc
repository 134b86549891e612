// rim_load: a bounded load generator for a rim_server on this machine (loopback only).
//
// N robots stream 64-beam synthetic-city scans at a fixed rate, M planners send query batches
// (back to back, or --query-rate batches per second each), K dashboards watch mesh tiles, all for
// a fixed duration. At the end it prints what the server sustained: frames integrated per robot,
// the median and lowest iterations per frame and the largest lag the acks reported, query latency
// quantiles, tiles received and their latency, and the sessions' host memory.
//
// Tile latency: from the integration that made a tile version (the first INTEGRATED ack whose map
// version reached it, as received here) to the tile's arrival at the watcher. Both ends are
// timed by this process's clock; the ack's own trip (loopback, well under a millisecond) makes it
// read a little short.
//
// The summary lines keep these forms, which scripts parse:
//   "  ROBOT: sent N, accepted N, integrated N (N frames/s), rejected N, lowest iterations/frame
//    N, median iterations/frame N, largest lag N frames"
//   "  ROBOT: median rays/frame N" (iterations × the batch each trained on: a robot streaming
//    in real time trains on sampler.paced_rays_per_iteration rays an iteration)
//   "  ROBOT: median rays trained per frame period N (frame and between frames)" (from the
//    map versions of consecutive acks, one version per iteration: a session that streams in
//    real time trains on between its frames, Mapper::TrainBetweenFrames)
//   "  queries: N batches, N points, latency p50 N ms, p99 N ms, N % within the bound"
// The last figure is the share of the planners' points that read a surface within the session's
// query.max_distance_m (not saturated). A query's cost grows with it: a planner asking around
// its robot finds more of its box mapped when the map keeps up with the robot.
//   "  tiles watched: N (N MB), tile latency p95 N ms"
//
// The server is expected to degrade by design (fewer iterations, then backpressure), never to
// fail or drop an accepted scan: the exit status is non-zero if any scan was rejected, any RPC
// failed, or a session's integrated count differs from its accepted count.
//
// Usage: rim_load --server 127.0.0.1:PORT [--robots 2] [--planners 2] [--dashboards 1]
//                 [--rate 10] [--duration 60] [--batch 10000] [--frames F] [--query-rate 0]
//                 [--baseline S] [--set key=value ...] [--json FILE] [--tile-resolution M]
//
// --tile-resolution M: the dashboards watch the tiles at level of detail M metres (one of the
// sessions' mesh_levels_m; default 0, the finest).
//
// --baseline S first runs the robots alone (no planners, no dashboards) for S seconds on sessions
// of their own ("baseline_robot_N", summary lines under "rim_load baseline: ..."), then the load
// as above, and ends with what the load left each robot of its training, measured on this host
// in this run:
//   "  ROBOT: rays trained per frame period alone N, under load N (N %)"
//
// --json FILE also writes the numbers of the summary to FILE (written by rim::io::DumpJson, each
// rounded as printed): {"options": {...}, "load": PHASE, "baseline": PHASE (with --baseline),
// "alone_vs_load": [{"robot", "alone", "under_load", "percent"}] (with --baseline), "ok"}, where
// PHASE is {"robots": [{"name", "sent", "accepted", "integrated", "frames_per_s", "rejected",
// "lowest_iterations_per_frame", "median_iterations_per_frame", "largest_lag_frames",
// "median_rays_per_frame", "median_rays_trained_per_frame_period"}], "queries": {"batches",
// "points", "latency_p50_ms", "latency_p99_ms", "within_bound_percent"}, "tiles": {"watched", "mb",
// "latency_p95_ms"}, "host_memory_mb"}. The printed text is the same with or without it.
//
// --set overrides a config value of the robots' maicity sessions (as `rimctl session create
// --set`), to compare settings under the same load; repeatable.
//
// The robots drive the city's loop road, 1 m per frame. --frames F city frames are cast before
// the run (default: enough for the whole run at --rate, at most 600); a robot that reaches the
// last one drives back along the same road, so the sensor never jumps (a jump would slide the
// whole local box at once, which no robot does between two frames).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "client/client.h"
#include "client/wire.h"
#include "rim/base/flags.h"
#include "rim/io/json.h"
#include "sim/city_frames.h"

namespace {

struct Options {
  std::string server;
  int robots = 2, planners = 2, dashboards = 1, batch = 10000;
  int frames = 0;  // 0: rate x duration, at most 600
  double rate_hz = 10, duration_s = 60;
  double query_rate_hz = 0;      // batches per second per planner; 0: back to back
  double baseline_s = 0;         // the robots alone for this long first; 0: no baseline phase
  double tile_resolution_m = 0;  // the dashboards' level of detail; 0: the finest
  std::vector<std::pair<std::string, std::string>> overrides;  // --set key=value
  std::string json_path;                                       // --json FILE; empty: none
};

bool Loopback(const std::string& address) {
  return address.rfind("127.", 0) == 0 || address.rfind("localhost:", 0) == 0 ||
         address.rfind("[::1]:", 0) == 0;
}

constexpr char kSynopsis[] =
    "usage: rim_load --server 127.0.0.1:PORT [--robots 2] [--planners 2] [--dashboards 1]\n"
    "                [--rate 10] [--duration 60] [--batch 10000] [--frames F] [--query-rate 0]\n"
    "                [--baseline S] [--set key=value ...] [--json FILE] [--tile-resolution M]";

// "--robots must be WANT, got 'VALUE'".
rim::cli::Message Must(std::string flag, std::string want) {
  return [flag = std::move(flag), want = std::move(want)](const std::string& value) {
    return flag + " must be " + want + ", got '" + value + "'";
  };
}

// rim_load's flags (rim/base/flags.h), into O. A flag given twice keeps its last value, as
// rim_load always did; --set adds one override each time.
void AddFlags(CLI::App& app, Options* o) {
  rim::cli::SetHelp(app, kSynopsis,
                    "A bounded load generator for a rim_server on this machine (loopback only):\n"
                    "robots stream synthetic-city scans, planners query, dashboards watch tiles,\n"
                    "for a fixed duration; then it prints what the server sustained.",
                    23);
  auto last = [](CLI::Option* opt) {
    return opt->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  };
  auto count = [&](const char* flag, int* out, int lo, int hi, const char* description) {
    const std::string want =
        "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
    return last(app.add_option(flag, *out, description)
                    ->transform(rim::cli::IntegerIn(lo, hi, Must(flag, want))));
  };
  auto number = [&](const char* flag, double* out, double lo, double hi, bool lo_inclusive,
                    const char* want, const char* description) {
    return last(app.add_option(flag, *out, description)
                    ->transform(rim::cli::NumberIn(lo, hi, lo_inclusive, Must(flag, want))));
  };
  const double kHuge = std::numeric_limits<double>::max();
  last(app.add_option("--server", o->server, "the server's address, loopback only (required)")
           ->type_name("ADDR"));
  count("--robots", &o->robots, 0, 16, "robots streaming scans (default 2)")->type_name("N");
  count("--planners", &o->planners, 0, 16, "planners sending query batches (default 2)")
      ->type_name("M");
  count("--dashboards", &o->dashboards, 0, 16, "dashboards watching mesh tiles (default 1)")
      ->type_name("K");
  number("--rate", &o->rate_hz, 0, kHuge, false, "a rate > 0 Hz",
         "each robot's scan rate in Hz (default 10)")
      ->type_name("HZ");
  number("--duration", &o->duration_s, 0, 3600, false, "in (0, 3600] s",
         "how long the load runs, in seconds (default 60)")
      ->type_name("S");
  count("--batch", &o->batch, 1, 1000000, "points per query batch (default 10000)")
      ->type_name("POINTS");
  count("--frames", &o->frames, 0, 1000,
        "city frames cast before the run (default 0: enough for the whole run at\n"
        "--rate, at most 600); a robot at the last one drives back")
      ->type_name("F");
  number("--query-rate", &o->query_rate_hz, 0, 1000, true, "in [0, 1000] Hz",
         "query batches per second per planner (default 0: back to back)")
      ->type_name("HZ");
  number("--baseline", &o->baseline_s, 0, 3600, true, "in [0, 3600] s",
         "first run the robots alone for S seconds on sessions of their own, then\n"
         "the load, and end with what the load left each robot of its training")
      ->type_name("S");
  app.add_option_function<std::vector<std::string>>(
         "--set",
         [o](const std::vector<std::string>& sets) {
           for (const std::string& v : sets)
             o->overrides.emplace_back(v.substr(0, v.find('=')), v.substr(v.find('=') + 1));
         },
         "override a config value of the robots' maicity sessions (as rimctl session\n"
         "create --set); repeatable")
      ->type_name("key=value")
      ->allow_extra_args(false)  // one value per --set
      ->transform(rim::cli::Check(
          [](std::string& v) { return v.find('=') != std::string::npos && v.find('=') > 0; },
          Must("--set", "key=value")));
  last(app.add_option("--json", o->json_path, "also write the summary's numbers to FILE as JSON")
           ->type_name("FILE")
           ->transform(rim::cli::Check([](std::string& v) { return !v.empty(); },
                                       Must("--json", "a file path"))));
  number("--tile-resolution", &o->tile_resolution_m, 0, kHuge, true, "a size >= 0 m",
         "the dashboards watch the tiles at this level of detail in metres (one of\n"
         "the sessions' mesh_levels_m; default 0, the finest)")
      ->type_name("M");
}

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * (v.size() - 1) + 0.5))];
}

}  // namespace

// What one phase of the run measured.
struct Phase {
  bool ok = true;  // no rejected scan, no failed RPC, integrated == accepted
  std::vector<double> trained_per_period;  // per robot: median rays trained per frame period
  nlohmann::ordered_json json;             // the summary's numbers, for --json
};

// Runs o.robots robots, o.planners planners and o.dashboards dashboards for o.duration_s on new
// sessions named PREFIX0, PREFIX1, ...; prints the summary (its first line "rim_load TITLE: ...")
// and closes the sessions.
Phase RunPhase(rim::Client& client, const Options& o, const std::vector<rim::PosedScan>& frames,
               const std::string& prefix, const char* title) {
  Phase phase;
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(o.duration_s);
  std::atomic<bool> failed{false};
  std::mutex mu;
  std::vector<double> query_ms;
  std::vector<std::string> robots;
  std::vector<rim::StreamSummary> summaries(o.robots);
  std::vector<uint32_t> min_iterations(o.robots, 1u << 30);
  std::vector<uint64_t> max_lag(o.robots, 0);
  std::vector<std::vector<double>> iterations(o.robots);
  // Rays trained per frame (iterations × the ack's batch): comparable across batch sizes.
  std::vector<std::vector<double>> rays_per_frame(o.robots);
  std::vector<std::vector<double>> trained_per_period(o.robots);
  std::vector<uint64_t> last_version(size_t(o.robots), 0);
  phase.trained_per_period.assign(size_t(o.robots), 0);
  // Per robot: the map version of each INTEGRATED ack and when it arrived, in arrival order
  // (map versions only grow).
  using Clock = std::chrono::steady_clock;
  std::vector<std::vector<std::pair<uint64_t, Clock::time_point>>> integrations(o.robots);
  std::vector<double> tile_latency_ms;
  std::atomic<uint64_t> tiles{0}, tile_bytes{0}, query_points{0}, query_within{0};

  for (int r = 0; r < o.robots; ++r) {
    robots.push_back(prefix + std::to_string(r));
    auto created = client.CreateSession(robots.back(), "maicity", o.overrides);
    if (!created.ok()) {
      std::fprintf(stderr, "rim_load: create %s: %s\n", robots.back().c_str(),
                   std::string(created.status().message()).c_str());
      phase.ok = false;
      return phase;
    }
  }
  // The frame each robot sent last: planners ask around it, as a planner plans around its robot.
  std::vector<std::atomic<size_t>> latest(size_t(std::max(o.robots, 1)));
  std::vector<std::thread> threads;
  for (int r = 0; r < o.robots; ++r) {
    threads.emplace_back([&, r] {
      size_t k = size_t(r) * 7;
      rim::StreamOptions options;
      options.rate_hz = o.rate_hz;
      options.on_ack = [&, r](const rim::v1::ScanAck& ack) {
        std::lock_guard<std::mutex> lock(mu);
        if (ack.state() == rim::v1::ScanAck::INTEGRATED) {
          min_iterations[r] = std::min(min_iterations[r], ack.iterations());
          iterations[r].push_back(ack.iterations());
          rays_per_frame[r].push_back(double(ack.iterations()) * ack.rays_per_iteration());
          // One map version per iteration: the versions since the last ack count the
          // iterations trained between the two frames as well as this frame's.
          if (last_version[r] > 0 && ack.map_version() >= last_version[r])
            trained_per_period[r].push_back(double(ack.map_version() - last_version[r]) *
                                            ack.rays_per_iteration());
          last_version[r] = ack.map_version();
          integrations[r].emplace_back(ack.map_version(), Clock::now());
        }
        max_lag[r] = std::max(max_lag[r], ack.lag_frames());
      };
      auto summary = client.Session(robots[r]).Stream(
          [&](rim::v1::Scan* scan) -> absl::StatusOr<bool> {
            if (std::chrono::steady_clock::now() >= deadline) return false;
            // Forward through the frames, then back: 0, 1, ..., n-1, n-2, ..., 1, 0, 1, ...
            const size_t n = frames.size(), period = n > 1 ? 2 * (n - 1) : 1;
            const size_t phase = k++ % period;
            const size_t index = phase < n ? phase : period - phase;
            latest[r] = index;
            *scan = rim::ScanToProto(frames[index], robots[r], 0);
            return true;
          },
          options);
      if (!summary.ok() || summary->rejected > 0) failed = true;
      if (summary.ok()) summaries[r] = *summary;
    });
  }
  for (int p = 0; p < o.planners && o.robots > 0; ++p) {
    threads.emplace_back([&, p] {
      std::mt19937 rng(p);
      std::uniform_real_distribution<float> u(-10.f, 10.f);
      auto next = Clock::now();
      while (std::chrono::steady_clock::now() < deadline) {
        if (o.query_rate_hz > 0) {
          // A fixed schedule: a late batch does not push the later ones back.
          std::this_thread::sleep_until(next);
          next += std::chrono::duration_cast<Clock::duration>(
              std::chrono::duration<double>(1.0 / o.query_rate_hz));
          if (Clock::now() >= deadline) break;
        }
        const rim::PosedScan& near = frames[latest[p % robots.size()].load()];
        const rim::Vec3d c = near.T_world_sensor.translation();
        std::vector<rim::Vec3f> points(o.batch);
        for (auto& q : points) q = rim::Vec3f(c.x() + u(rng), c.y() + u(rng), u(rng) * 0.2f);
        const auto start = std::chrono::steady_clock::now();
        auto answer = client.Session(robots[p % robots.size()]).Query(points);
        const double ms =
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                .count();
        if (!answer.ok()) {
          failed = true;
          return;
        }
        query_points += points.size();
        query_within +=
            uint64_t(std::count(answer->saturated.begin(), answer->saturated.end(), uint8_t(0)));
        std::lock_guard<std::mutex> lock(mu);
        query_ms.push_back(ms);
      }
    });
  }
  for (int d = 0; d < o.dashboards && o.robots > 0; ++d) {
    threads.emplace_back([&, d] {
      rim::WatchOptions options;
      options.duration = std::chrono::milliseconds(int64_t(o.duration_s * 1000));
      options.resolution_m = float(o.tile_resolution_m);
      const absl::Status s =
          client.Session(robots[d % robots.size()])
              .Watch(
                  [&, d](const rim::DecodedTile& t) {
                    const auto arrived = Clock::now();
                    ++tiles;
                    tile_bytes += t.draco.size();
                    const size_t r = size_t(d) % robots.size();
                    std::lock_guard<std::mutex> lock(mu);
                    const auto& made = integrations[r];
                    auto it =
                        std::lower_bound(made.begin(), made.end(), t.version,
                                         [](const auto& e, uint64_t v) { return e.first < v; });
                    // A version from before this run (or from an ack not yet
                    // seen) has no integration here to time from.
                    if (it != made.end())
                      tile_latency_ms.push_back(
                          std::chrono::duration<double, std::milli>(arrived - it->second).count());
                    return true;
                  },
                  options);
      if (!s.ok()) failed = true;
    });
  }
  for (auto& t : threads) t.join();

  bool consistent = true;
  uint64_t memory = 0;
  using rim::io::JsonNumber;
  nlohmann::ordered_json robot_json = nlohmann::ordered_json::array();
  std::printf("rim_load%s: %d robots at %.1f Hz, %d planners (%d points), %d dashboards, %.0f s\n",
              title, o.robots, o.rate_hz, o.planners, o.batch, o.dashboards, o.duration_s);
  for (int r = 0; r < o.robots; ++r) {
    auto info = client.GetSession(robots[r]);
    if (!info.ok()) {
      failed = true;
      continue;
    }
    consistent = consistent && info->integrated_frames() == info->accepted_frames();
    memory += info->host_memory_bytes();
    const rim::StreamSummary& s = summaries[r];
    std::printf(
        "  %s: sent %llu, accepted %llu, integrated %llu (%.2f frames/s), rejected %llu, "
        "lowest iterations/frame %u, median iterations/frame %.0f, largest lag %llu frames\n",
        robots[r].c_str(), (unsigned long long)s.sent, (unsigned long long)s.accepted,
        (unsigned long long)s.integrated, s.seconds > 0 ? s.integrated / s.seconds : 0.0,
        (unsigned long long)s.rejected, min_iterations[r] == (1u << 30) ? 0 : min_iterations[r],
        Quantile(iterations[r], 0.5), (unsigned long long)max_lag[r]);
    std::printf("  %s: median rays/frame %.0f\n", robots[r].c_str(),
                Quantile(rays_per_frame[r], 0.5));
    std::printf("  %s: median rays trained per frame period %.0f (frame and between frames)\n",
                robots[r].c_str(), Quantile(trained_per_period[r], 0.5));
    phase.trained_per_period[size_t(r)] = Quantile(trained_per_period[r], 0.5);
    robot_json.push_back(
        {{"name", robots[r]},
         {"sent", s.sent},
         {"accepted", s.accepted},
         {"integrated", s.integrated},
         {"frames_per_s", JsonNumber(s.seconds > 0 ? s.integrated / s.seconds : 0.0, 2)},
         {"rejected", s.rejected},
         {"lowest_iterations_per_frame", min_iterations[r] == (1u << 30) ? 0 : min_iterations[r]},
         {"median_iterations_per_frame", JsonNumber(Quantile(iterations[r], 0.5), 0)},
         {"largest_lag_frames", max_lag[r]},
         {"median_rays_per_frame", JsonNumber(Quantile(rays_per_frame[r], 0.5), 0)},
         {"median_rays_trained_per_frame_period",
          JsonNumber(Quantile(trained_per_period[r], 0.5), 0)}});
  }
  std::printf(
      "  queries: %zu batches, %llu points, latency p50 %.1f ms, p99 %.1f ms, %.1f %% within the "
      "bound\n",
      query_ms.size(), (unsigned long long)query_points.load(), Quantile(query_ms, 0.5),
      Quantile(query_ms, 0.99),
      query_points.load() > 0 ? 100.0 * double(query_within.load()) / double(query_points.load())
                              : 0.0);
  std::printf("  tiles watched: %llu (%.1f MB), tile latency p95 %.0f ms\n",
              (unsigned long long)tiles.load(), tile_bytes.load() / 1e6,
              Quantile(tile_latency_ms, 0.95));
  std::printf("  sessions' host memory at the end: %.0f MB\n", memory / 1e6);
  phase.json = {{"robots", std::move(robot_json)},
                {"queries",
                 {{"batches", query_ms.size()},
                  {"points", query_points.load()},
                  {"latency_p50_ms", JsonNumber(Quantile(query_ms, 0.5), 1)},
                  {"latency_p99_ms", JsonNumber(Quantile(query_ms, 0.99), 1)},
                  {"within_bound_percent",
                   JsonNumber(query_points.load() > 0 ? 100.0 * double(query_within.load()) /
                                                            double(query_points.load())
                                                      : 0.0,
                              1)}}},
                {"tiles",
                 {{"watched", tiles.load()},
                  {"mb", JsonNumber(tile_bytes.load() / 1e6, 1)},
                  {"latency_p95_ms", JsonNumber(Quantile(tile_latency_ms, 0.95), 0)}}},
                {"host_memory_mb", JsonNumber(memory / 1e6, 0)}};
  for (const auto& r : robots) (void)client.CloseSession(r, false);
  phase.ok = !failed && consistent;
  return phase;
}

int main(int argc, char** argv) {
  Options o;
  CLI::App app("", "rim_load");
  AddFlags(app, &o);
  absl::Status parsed = rim::cli::Parse(app, argc, argv);
  if (absl::IsCancelled(parsed)) {
    std::fputs(app.help().c_str(), stdout);
    return 0;
  }
  if (parsed.ok() && o.server.empty())
    parsed = absl::InvalidArgumentError("--server ADDR is required");
  if (!parsed.ok()) {
    std::fprintf(stderr, "rim_load: %s\n%s", std::string(parsed.message()).c_str(),
                 app.help().c_str());
    return 2;
  }
  if (!Loopback(o.server)) {
    std::fprintf(stderr, "rim_load: only loopback servers (127.x, localhost, [::1]): %s\n",
                 o.server.c_str());
    return 2;
  }
  auto client = rim::Client::Connect(o.server);
  if (!client.ok()) {
    std::fprintf(stderr, "rim_load: %s\n", std::string(client.status().message()).c_str());
    return 3;
  }
  // The scans: cast once, driven forward and back by every robot (robot r starts at a different
  // frame).
  if (o.frames == 0) o.frames = int(std::clamp(std::ceil(o.rate_hz * o.duration_s), 2.0, 600.0));
  std::fprintf(stderr, "rim_load: casting %d city frames...\n", o.frames);
  rim::sim::CityFrameOptions city;
  city.frames = o.frames;
  rim::sim::CityFrames source(city);
  std::vector<rim::PosedScan> frames;
  for (size_t k = 0; k < source.size(); ++k) frames.push_back(source.Frame(k));

  Phase alone;
  if (o.baseline_s > 0) {
    // The robots alone first, on sessions of their own: what the load below takes from them is
    // measured on this host, in this run.
    Options robots_only = o;
    robots_only.planners = 0;
    robots_only.dashboards = 0;
    robots_only.duration_s = o.baseline_s;
    alone = RunPhase(*client, robots_only, frames, "baseline_robot_", " baseline");
  }
  const Phase loaded = RunPhase(*client, o, frames, "load_robot_", "");
  nlohmann::ordered_json alone_vs_load = nlohmann::ordered_json::array();
  if (o.baseline_s > 0) {
    for (int r = 0; r < o.robots; ++r) {
      const double a = alone.trained_per_period[size_t(r)];
      const double l = loaded.trained_per_period[size_t(r)];
      std::printf(
          "  load_robot_%d: rays trained per frame period alone %.0f, under load %.0f (%.0f %%)\n",
          r, a, l, a > 0 ? 100.0 * l / a : 0.0);
      alone_vs_load.push_back({{"robot", "load_robot_" + std::to_string(r)},
                               {"alone", rim::io::JsonNumber(a, 0)},
                               {"under_load", rim::io::JsonNumber(l, 0)},
                               {"percent", rim::io::JsonNumber(a > 0 ? 100.0 * l / a : 0.0, 0)}});
    }
  }
  if (!o.json_path.empty()) {
    nlohmann::ordered_json json = {{"options",
                                    {{"robots", o.robots},
                                     {"planners", o.planners},
                                     {"dashboards", o.dashboards},
                                     {"rate_hz", o.rate_hz},
                                     {"duration_s", o.duration_s},
                                     {"batch", o.batch},
                                     {"frames", o.frames},
                                     {"query_rate_hz", o.query_rate_hz},
                                     {"baseline_s", o.baseline_s},
                                     {"tile_resolution_m", o.tile_resolution_m}}},
                                   {"load", loaded.json}};
    nlohmann::ordered_json set = nlohmann::ordered_json::object();
    for (const auto& [key, value] : o.overrides) set[key] = value;
    json["options"]["set"] = std::move(set);
    if (o.baseline_s > 0) {
      json["baseline"] = alone.json;
      json["alone_vs_load"] = std::move(alone_vs_load);
    }
    json["ok"] = alone.ok && loaded.ok;
    std::ofstream f(o.json_path);
    f << rim::io::DumpJson(json, 3);
    if (!f) {
      std::fprintf(stderr, "rim_load: cannot write %s\n", o.json_path.c_str());
      return 1;
    }
  }
  if (!alone.ok || !loaded.ok) {
    std::printf("rim_load: FAILED (a rejected scan, a failed RPC, or integrated != accepted)\n");
    return 1;
  }
  std::printf("rim_load: OK\n");
  return 0;
}
