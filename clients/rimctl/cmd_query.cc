// rimctl query: SDF values at points from a CSV file, or an SDF slice picture over a grid.
#include <fstream>
#include <iostream>
#include <iterator>
#include <sstream>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "rim/io/png_io.h"
#include "rimctl/commands.h"
#include "rimctl/points_io.h"
#include "rimctl/slice.h"

namespace rim::rimctl {
namespace {

constexpr char kQueryUsage[] = R"(usage:
  rimctl query ROBOT_ID --points FILE|- [--gradient] [--format csv|npy] [--out FILE]
  rimctl query ROBOT_ID --grid x0,y0,z0,x1,y1,z1,res --out slice.png [--range M] [--contours M]

--points reads CSV x,y,z lines (world frame, metres; a header line is optional; '-' is stdin)
and writes CSV with the header x,y,z,sdf,observed (plus ,gx,gy,gz with --gradient), observed as
0/1, one row per input point, to --out or stdout. --format npy (the default when --out ends in
.npy) writes a NumPy float32 array of N x 5 (N x 8 with --gradient) with the same columns.
Batches above the server's max query points are sent in chunks.

--grid queries a regular grid on an axis-aligned plane (one extent flat, e.g. z0 == z1) with
cells of res metres and writes a PNG: blue inside, red outside, the surface dark, never observed
cells grey. --range M sets the |sdf| at the ends of the colour scale (default: the 98th
percentile over observed cells). Contour lines are drawn every --contours M metres of distance
(default 0.25; 0 draws none).
)";

absl::StatusOr<std::string> ReadInput(const std::string& path) {
  if (path == "-") {
    return std::string(std::istreambuf_iterator<char>(std::cin), std::istreambuf_iterator<char>());
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open points file ", path));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

absl::Status WriteOutput(const std::string& path, const std::string& bytes, std::ostream& out) {
  if (path.empty() || path == "-") {
    out << bytes;
    return out ? absl::OkStatus() : absl::DataLossError("cannot write to stdout");
  }
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  file << bytes;
  file.close();
  if (!file) return absl::PermissionDeniedError(absl::StrCat("cannot write ", path));
  return absl::OkStatus();
}

int QueryPoints(const Args& args, const std::string& robot, const Io& io) {
  const std::string out_path = args.Get("out");
  const std::string format = args.Get("format", absl::EndsWith(out_path, ".npy") ? "npy" : "csv");
  if (format != "csv" && format != "npy") {
    return UsageError(io, "query", absl::StrCat("--format '", format, "' is not csv or npy"),
                      kQueryUsage);
  }
  const std::string source = args.Get("points");
  auto text = ReadInput(source);
  if (!text.ok()) return Fail(io, text.status());
  auto points = ParsePointsCsv(*text, source == "-" ? "stdin" : source);
  if (!points.ok()) return Fail(io, points.status());

  auto client = ConnectFromArgs(args);
  if (!client.ok()) return Fail(io, client.status());
  const bool gradient = args.Has("gradient");
  auto result = client->Session(robot).Query(*points, gradient);
  if (!result.ok()) return Fail(io, result.status());
  const std::string bytes = format == "npy" ? FormatQueryNpy(*points, *result, gradient)
                                            : FormatQueryCsv(*points, *result, gradient);
  const absl::Status written = WriteOutput(out_path, bytes, io.out);
  if (!written.ok()) return Fail(io, written);
  size_t observed = 0;
  for (uint8_t o : result->observed) observed += o != 0;
  io.err << absl::StrFormat("queried %u points (%u observed), map version %u, server %.1f ms\n",
                            points->size(), observed, result->map_version,
                            1e3 * result->server_seconds);
  return kExitOk;
}

int QueryGrid(const Args& args, const std::string& robot, const Io& io) {
  const std::string out_path = args.Get("out");
  if (out_path.empty() || !absl::EndsWithIgnoreCase(out_path, ".png")) {
    return UsageError(io, "query", "--grid needs --out FILE.png", kQueryUsage);
  }
  for (const char* flag : {"gradient", "format"}) {
    if (args.Has(flag)) {
      return UsageError(io, "query", absl::StrCat("--", flag, " does not apply to --grid"),
                        kQueryUsage);
    }
  }
  auto grid = ParseSliceGrid(args.Get("grid"));
  if (!grid.ok()) return UsageError(io, "query", std::string(grid.status().message()), kQueryUsage);
  auto range = args.GetDouble("range", 0, 0, 1e6);
  if (!range.ok())
    return UsageError(io, "query", std::string(range.status().message()), kQueryUsage);
  auto contours = args.GetDouble("contours", 0.25, 0, 1e3);
  if (!contours.ok())
    return UsageError(io, "query", std::string(contours.status().message()), kQueryUsage);

  auto client = ConnectFromArgs(args);
  if (!client.ok()) return Fail(io, client.status());
  auto result = client->Session(robot).Query(grid->Points(), false);
  if (!result.ok()) return Fail(io, result.status());
  const SliceImage image = RenderSlice(*grid, *result, *range, 256, *contours);
  const absl::Status written =
      io::WritePngRgb8(out_path, image.width, image.height, image.rgb.data());
  if (!written.ok()) return Fail(io, written);
  io.out << absl::StrFormat(
      "slice %s: %d x %d cells of %g m (%u observed), distance colour range +-%.3g m, contours "
      "every %g m, map version %u -> %s\n",
      grid->PlaneName(), grid->width, grid->height, grid->resolution_m, image.observed_cells,
      image.range_m, *contours, result->map_version, out_path);
  return kExitOk;
}

}  // namespace

int RunQuery(const std::vector<std::string>& words, const Io& io) {
  auto args = Args::Parse(words, WithGlobalFlags({{"points", FlagKind::kValue},
                                                  {"grid", FlagKind::kValue},
                                                  {"gradient", FlagKind::kBool},
                                                  {"format", FlagKind::kValue},
                                                  {"out", FlagKind::kValue},
                                                  {"range", FlagKind::kValue},
                                                  {"contours", FlagKind::kValue}}));
  if (!args.ok()) {
    return UsageError(io, "query", std::string(args.status().message()), kQueryUsage);
  }
  if (args->help()) return PrintHelp(io, kQueryUsage);
  if (args->positional().size() != 1) {
    return UsageError(io, "query", "needs exactly one ROBOT_ID", kQueryUsage);
  }
  if (args->Has("points") == args->Has("grid")) {
    return UsageError(io, "query", "give either --points FILE or --grid SPEC", kQueryUsage);
  }
  for (const char* flag : {"range", "contours"}) {
    if (args->Has(flag) && !args->Has("grid")) {
      return UsageError(io, "query", absl::StrCat("--", flag, " only applies to --grid"),
                        kQueryUsage);
    }
  }
  const std::string& robot = args->positional()[0];
  return args->Has("grid") ? QueryGrid(*args, robot, io) : QueryPoints(*args, robot, io);
}

}  // namespace rim::rimctl
