// rimctl's pieces that need no server: flag parsing, the CSV / .npy formats, the slice grid and
// picture, sim:city options and the non-terminal progress output.
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "rimctl/args.h"
#include "rimctl/frame_source.h"
#include "rimctl/points_io.h"
#include "rimctl/progress.h"
#include "rimctl/slice.h"

namespace rim::rimctl {
namespace {

using ::testing::HasSubstr;

TEST(RimctlArgsTest, FlagsAnywhereAndTyped) {
  const std::vector<FlagSpec> specs = {
      {"out", FlagKind::kValue}, {"set", FlagKind::kRepeated}, {"gradient", FlagKind::kBool}};
  auto args = Args::Parse(
      {"--set", "a=1", "robot", "--out=x.csv", "-", "--gradient", "--set", "b=2"}, specs);
  ASSERT_TRUE(args.ok()) << args.status();
  EXPECT_EQ(args->positional(), (std::vector<std::string>{"robot", "-"}));
  EXPECT_EQ(args->Get("out"), "x.csv");
  EXPECT_EQ(args->GetAll("set"), (std::vector<std::string>{"a=1", "b=2"}));
  EXPECT_TRUE(args->Has("gradient"));
  EXPECT_FALSE(args->help());

  auto rate = Args::Parse({"--out", "7.5"}, specs)->GetDouble("out", 0, 0, 5);
  EXPECT_THAT(rate.status().message(), HasSubstr("--out '7.5' is not a number in [0, 5]"));
}

TEST(RimctlArgsTest, MistakesNameTheFlag) {
  const std::vector<FlagSpec> specs = {{"out", FlagKind::kValue}, {"save", FlagKind::kBool}};
  EXPECT_THAT(Args::Parse({"--outt", "x"}, specs).status().message(), HasSubstr("'--outt'"));
  EXPECT_THAT(Args::Parse({"--out"}, specs).status().message(), HasSubstr("--out needs a value"));
  EXPECT_THAT(Args::Parse({"--out", "a", "--out", "b"}, specs).status().message(),
              HasSubstr("--out given more than once"));
  EXPECT_THAT(Args::Parse({"--save=yes"}, specs).status().message(),
              HasSubstr("--save takes no value"));
  EXPECT_TRUE(Args::Parse({"-h"}, specs)->help());
  auto after_dashes = Args::Parse({"a", "--", "--save", "-"}, specs);  // "--" ends the flags
  ASSERT_TRUE(after_dashes.ok()) << after_dashes.status();
  EXPECT_EQ(after_dashes->positional(), (std::vector<std::string>{"a", "--save", "-"}));
  EXPECT_FALSE(after_dashes->Has("save"));
}

TEST(RimctlArgsTest, FrameRanges) {
  auto r = ParseFrameRange("5:20");
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->first, 5);
  EXPECT_EQ(r->last, 20);
  EXPECT_EQ(ParseFrameRange("3:")->last, -1);
  EXPECT_EQ(ParseFrameRange(":4")->first, 0);
  for (const char* bad : {"5", "5:5", "9:2", "-1:3", "a:b", "1:2:3"}) {
    EXPECT_FALSE(ParseFrameRange(bad).ok()) << bad;
  }
}

TEST(RimctlPointsTest, CsvWithHeaderCommentsAndExtraColumns) {
  auto points = ParsePointsCsv("x,y,z\n# note\n1, 2, 3\n\n-0.5,0.25,1e-3,9,1\n", "p.csv");
  ASSERT_TRUE(points.ok()) << points.status();
  ASSERT_EQ(points->size(), 2u);
  EXPECT_EQ((*points)[0], Vec3f(1, 2, 3));
  EXPECT_EQ((*points)[1], Vec3f(-0.5f, 0.25f, 1e-3f));
  EXPECT_EQ(ParsePointsCsv("1,2,3", "p.csv")->size(), 1u);  // no header, no final newline
}

TEST(RimctlPointsTest, BadCsvNamesFileAndLine) {
  EXPECT_THAT(ParsePointsCsv("x,y,z\n1,2,3\n4,5\n", "p.csv").status().message(),
              HasSubstr("p.csv:3: expected x,y,z"));
  EXPECT_THAT(ParsePointsCsv("1,2\n", "p.csv").status().message(), HasSubstr("p.csv:1:"));
  EXPECT_THAT(ParsePointsCsv("1,nan,3\n", "p.csv").status().message(),
              HasSubstr("p.csv:1: point '1,nan,3' is not finite"));
  EXPECT_THAT(ParsePointsCsv("x,y,z\n", "p.csv").status().message(), HasSubstr("no points"));
}

QueryResult TwoPointAnswer() {
  QueryResult r;
  r.sdf = {0.125f, -0.0123456789f};
  r.observed = {1, 0};
  r.gradient = {1, 0, 0, 0, 0.6f, -0.8f};
  return r;
}

TEST(RimctlPointsTest, CsvOutputRoundTrips) {
  const std::vector<Vec3f> points = {Vec3f(1.1f, 2, 3), Vec3f(-4, 5.5f, 1e-7f)};
  const std::string csv = FormatQueryCsv(points, TwoPointAnswer(), false);
  EXPECT_EQ(csv.substr(0, csv.find('\n')), "x,y,z,sdf,observed");
  EXPECT_THAT(csv, HasSubstr("\n1.10000002,2,3,0.125,1\n"));
  // Fed back as input, the rows give the same points bit for bit.
  auto back = ParsePointsCsv(csv, "out.csv");
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(*back, points);
  const std::string with_gradient = FormatQueryCsv(points, TwoPointAnswer(), true);
  EXPECT_EQ(with_gradient.substr(0, with_gradient.find('\n')), "x,y,z,sdf,observed,gx,gy,gz");
  EXPECT_THAT(with_gradient, HasSubstr(",-0.0123456791,0,0,0.600000024,-0.800000012\n"));
}

TEST(RimctlPointsTest, NpyHeaderAndData) {
  const std::vector<Vec3f> points = {Vec3f(1, 2, 3), Vec3f(4, 5, 6)};
  const std::string npy = FormatQueryNpy(points, TwoPointAnswer(), true);
  ASSERT_EQ(npy.substr(0, 6), "\x93NUMPY");
  EXPECT_EQ(npy[6], 1);
  const size_t header_len = uint8_t(npy[8]) | (uint8_t(npy[9]) << 8);
  EXPECT_EQ((10 + header_len) % 64, 0u);  // data aligned as NumPy writes it
  const std::string header = npy.substr(10, header_len);
  EXPECT_THAT(header, HasSubstr("'descr': '<f4'"));
  EXPECT_THAT(header, HasSubstr("'shape': (2, 8)"));
  EXPECT_EQ(header.back(), '\n');
  ASSERT_EQ(npy.size(), 10 + header_len + 2 * 8 * 4);
  float row1[8];
  std::memcpy(row1, npy.data() + 10 + header_len + 8 * 4, sizeof(row1));
  EXPECT_EQ(row1[0], 4.f);
  EXPECT_EQ(row1[3], -0.0123456789f);
  EXPECT_EQ(row1[4], 0.f);  // not observed
  EXPECT_EQ(row1[7], -0.8f);
}

TEST(RimctlSliceTest, GridOnTheFlatAxis) {
  auto grid = ParseSliceGrid("2,-1,0.5,0,1,0.5,0.5");  // corners in any order
  ASSERT_TRUE(grid.ok()) << grid.status();
  EXPECT_EQ(grid->flat_axis, 2);
  EXPECT_EQ(grid->width, 5);                        // x from 0 to 2
  EXPECT_EQ(grid->height, 5);                       // y from -1 to 1
  EXPECT_EQ(grid->Point(0, 0), Vec3f(0, 1, 0.5f));  // top-left: smallest x, largest y
  EXPECT_EQ(grid->Point(4, 4), Vec3f(2, -1, 0.5f));
  EXPECT_EQ(grid->Points().size(), 25u);
  EXPECT_EQ(grid->PlaneName(), "z = 0.5 m");
  auto vertical = ParseSliceGrid("0,3,0,4,3,2,1");
  ASSERT_TRUE(vertical.ok());
  EXPECT_EQ(vertical->flat_axis, 1);
  EXPECT_EQ(vertical->Point(0, 0), Vec3f(0, 3, 2));  // up is +z
}

TEST(RimctlSliceTest, BadGridsAreExplained) {
  EXPECT_THAT(ParseSliceGrid("0,0,0,1,1,1,0.1").status().message(), HasSubstr("found 0 flat"));
  EXPECT_THAT(ParseSliceGrid("0,0,0,1,0,0,0.1").status().message(), HasSubstr("found 2 flat"));
  EXPECT_THAT(ParseSliceGrid("0,0,0,1,1,0,0").status().message(), HasSubstr("must be > 0"));
  EXPECT_THAT(ParseSliceGrid("0,0,0,1,1").status().message(), HasSubstr("7 comma-separated"));
  EXPECT_THAT(ParseSliceGrid("0,0,0,1000,1,0,0.01").status().message(),
              HasSubstr("at most 4096 per side"));
}

TEST(RimctlSliceTest, ColoursSurfaceAndUnobservedCells) {
  const auto inside = DivergingColour(-1), zero = DivergingColour(0), outside = DivergingColour(1);
  EXPECT_GT(inside[2], inside[0]);    // blue inside
  EXPECT_GT(outside[0], outside[2]);  // red outside
  EXPECT_GT(zero[0], 240);            // near white at zero

  auto grid = ParseSliceGrid("0,0,0,3,1,0,1");  // 4 x 2 cells
  ASSERT_TRUE(grid.ok());
  QueryResult r;
  // Row 0: inside, outside (next to inside: the surface), far outside, unobserved.
  r.sdf = {-0.2f, 0.2f, 1.0f, 0.f, 0.5f, 0.5f, 0.5f, 0.5f};
  r.observed = {1, 1, 1, 0, 1, 1, 1, 1};
  const SliceImage image = RenderSlice(*grid, r, 1.0, /*min_side_px=*/8);
  EXPECT_EQ(image.width, 8);  // scaled by 2
  EXPECT_EQ(image.height, 4);
  EXPECT_EQ(image.observed_cells, 7u);
  auto pixel = [&](int col, int row) {
    const uint8_t* p = &image.rgb[(size_t(row * 2) * image.width + col * 2) * 3];
    return std::array<uint8_t, 3>{p[0], p[1], p[2]};
  };
  EXPECT_EQ(pixel(0, 0), DivergingColour(-0.2));
  EXPECT_LT(pixel(1, 0)[0], 40);                                    // the zero crossing, dark
  EXPECT_EQ(pixel(2, 0), outside);                                  // saturated at the range
  EXPECT_EQ(pixel(3, 0), (std::array<uint8_t, 3>{128, 128, 128}));  // never observed
  EXPECT_LT(pixel(0, 1)[0], 40);  // below an inside cell: also on the surface
}

TEST(RimctlSliceTest, ContourLinesFollowTheDistance) {
  // A row of 6 cells whose distance grows 0.1 m per cell from 0.07 m: bands of 0.25 m start at
  // cells 2 (0.27 m) and 5 (0.57 m), so those two carry the lines.
  auto grid = ParseSliceGrid("0,0,0,5,0.5,0,1");
  ASSERT_TRUE(grid.ok());
  ASSERT_EQ(grid->width, 6);
  QueryResult r;
  for (int row = 0; row < grid->height; ++row)
    for (int col = 0; col < 6; ++col) {
      r.sdf.push_back(0.1f * col + 0.07f);
      r.observed.push_back(1);
    }
  const SliceImage plain = RenderSlice(*grid, r, 1.0, 6, 0.0);
  const SliceImage lined = RenderSlice(*grid, r, 1.0, 6, 0.25);
  for (int col = 0; col < 6; ++col) {
    const bool line = col == 2 || col == 5;
    const size_t p = size_t(col) * 3;
    if (line)
      EXPECT_LT(lined.rgb[p], plain.rgb[p]) << col;
    else
      EXPECT_EQ(lined.rgb[p], plain.rgb[p]) << col;
  }
}

TEST(RimctlSimTest, CityOptions) {
  auto o = ParseSimCitySpec("sim:city?frames=12&seed=3,columns=900&noise=0.02");
  ASSERT_TRUE(o.ok()) << o.status();
  EXPECT_EQ(o->frames, 12);
  EXPECT_EQ(o->seed, 3u);
  EXPECT_EQ(o->columns, 900);
  EXPECT_EQ(o->noise, 0.02);
  EXPECT_EQ(ParseSimCitySpec("sim:city")->frames, 100);
  EXPECT_THAT(ParseSimCitySpec("sim:city?frame=3").status().message(),
              HasSubstr("unknown sim:city option 'frame'"));
  EXPECT_THAT(ParseSimCitySpec("sim:city?frames=0").status().message(),
              HasSubstr("frames='0' is not an integer in [1, 1000000]"));
  EXPECT_THAT(ParseSimCitySpec("sim:room").status().message(), HasSubstr("sim:room"));
  EXPECT_THAT(OpenFrameSource("/no/such/folder").status().message(), HasSubstr("/no/such/folder"));
}

TEST(RimctlProgressTest, OneLinePerTenthWithoutATerminal) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  {
    StreamProgress progress(20, /*tty=*/false, f);
    rim::v1::ScanAck ack;
    for (int i = 0; i < 20; ++i) {
      progress.OnSent(uint64_t(i + 1));
      ack.set_state(rim::v1::ScanAck::ACCEPTED);
      progress.OnAck(ack);
      ack.set_state(i == 7 ? rim::v1::ScanAck::REJECTED : rim::v1::ScanAck::INTEGRATED);
      progress.OnAck(ack);
    }
    progress.Finish();
  }
  std::rewind(f);
  std::string text(4096, '\0');
  text.resize(std::fread(text.data(), 1, text.size(), f));
  std::fclose(f);
  int lines = 0;
  for (char c : text) lines += c == '\n';
  EXPECT_EQ(lines, 10) << text;
  EXPECT_THAT(text, HasSubstr("stream: 100%  sent 20/20  accepted 20  integrated 19  rejected 1"));
}

}  // namespace
}  // namespace rim::rimctl
