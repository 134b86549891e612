// Mapper configuration (DESIGN.md §3.7, §5.2 "bad input names the field"): presets, overrides,
// validation, config text and files, and the ToString round trip that checkpoints rely on.
#include "rim/config/config.h"

#include <stdlib.h>
#include <unistd.h>

#include <cstdint>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace rim {
namespace {

using ::testing::HasSubstr;

MapperConfig Preset(const std::string& name) {
  auto c = MakePreset(name);
  EXPECT_TRUE(c.ok()) << c.status();
  return c.ok() ? *c : MapperConfig{};
}

TEST(ConfigTest, EveryPresetValidates) {
  const std::vector<std::string> names = PresetNames();
  EXPECT_EQ(names.size(), 5u);
  for (const std::string& name : names) {
    auto c = MakePreset(name);
    ASSERT_TRUE(c.ok()) << name << ": " << c.status();
    EXPECT_EQ(c->preset, name);
    absl::Status s = c->Validate();
    EXPECT_TRUE(s.ok()) << name << ": " << s;
  }
  auto bad = MakePreset("atlantis");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(bad.status().message()), HasSubstr("atlantis"));
}

TEST(ConfigTest, PresetValuesFollowTheDesignTable) {
  const MapperConfig m = Preset("maicity");
  EXPECT_FLOAT_EQ(m.grid.half_extent_x_m, 10.f);
  EXPECT_FLOAT_EQ(m.grid.z_min_m, -3.f);
  EXPECT_FLOAT_EQ(m.grid.z_max_m, 3.f);
  EXPECT_FLOAT_EQ(m.grid.leaf_size_m, 0.1f);
  EXPECT_EQ(m.grid.levels, 3);
  EXPECT_EQ(m.grid.feature_dim, 8);
  EXPECT_EQ(m.train.iterations, 30);
  EXPECT_FLOAT_EQ(m.train.learning_rate, 1e-2f);
  EXPECT_FLOAT_EQ(m.train.sigma_m, 0.05f);
  EXPECT_FALSE(m.sampler.outside_rays);
  EXPECT_FALSE(m.buffer.outlier_removal);
  EXPECT_EQ(m.sampler.rays_per_iteration, 2048);
  EXPECT_FLOAT_EQ(m.sampler.newest_share, 0.5f);
  EXPECT_EQ(m.sampler.paced_rays_per_iteration, 512);
  EXPECT_EQ(m.buffer.max_points, 1000000);
  EXPECT_EQ(m.buffer.max_points_per_frame, 10000);
  EXPECT_EQ(m.decoder.freeze_after_frames, 20);
  EXPECT_EQ(m.decoder.hidden_layers, 1);
  EXPECT_FLOAT_EQ(m.sampler.free_min_ratio, 0.3f);
  EXPECT_FLOAT_EQ(m.sampler.free_max_ratio, 0.9f);

  const MapperConfig online = Preset("maicity_online");
  EXPECT_EQ(online.train.iterations, 10);
  EXPECT_TRUE(online.sampler.outside_rays);

  const MapperConfig k = Preset("kitti");
  EXPECT_FLOAT_EQ(k.grid.half_extent_x_m, 13.f);
  EXPECT_FLOAT_EQ(k.grid.z_min_m, -4.f);
  EXPECT_FLOAT_EQ(k.grid.z_max_m, 2.f);
  EXPECT_TRUE(k.sampler.outside_rays);
  EXPECT_TRUE(k.buffer.outlier_removal);
  EXPECT_EQ(k.buffer.outlier_period_frames, 10);
  EXPECT_FLOAT_EQ(k.buffer.outlier_threshold_m, 0.05f);

  const MapperConfig r = Preset("replica");
  EXPECT_FLOAT_EQ(r.grid.leaf_size_m, 0.05f);
  EXPECT_FLOAT_EQ(r.grid.half_extent_x_m, 7.f);
  EXPECT_FALSE(r.grid.sliding);
  EXPECT_EQ(r.train.iterations, 20);
  EXPECT_FLOAT_EQ(r.train.learning_rate, 5e-3f);
  EXPECT_FLOAT_EQ(r.train.sigma_m, 0.02f);
}

TEST(ConfigTest, OverridesSetEveryKindOfValue) {
  MapperConfig c = Preset("maicity");
  absl::Status s =
      ApplyOverrides({"train.iterations=42", " train.learning_rate = 0.003 ",
                      "sampler.outside_rays=true", "grid.sliding=off",
                      "submap.spill_dir=/tmp/rim spill", "submap.host_budget_bytes=123456789012",
                      "decoder.seed=18446744073709551615", "train.min_iterations=2"},
                     &c);
  ASSERT_TRUE(s.ok()) << s;
  EXPECT_EQ(c.train.iterations, 42);
  EXPECT_EQ(c.train.min_iterations, 2);
  EXPECT_EQ(c.train.learning_rate, 0.003f);
  EXPECT_TRUE(c.sampler.outside_rays);
  EXPECT_FALSE(c.grid.sliding);
  EXPECT_EQ(c.submap.spill_dir, "/tmp/rim spill");
  EXPECT_EQ(c.submap.host_budget_bytes, 123456789012);
  EXPECT_EQ(c.decoder.seed, std::numeric_limits<uint64_t>::max());
  EXPECT_EQ(c.preset, "maicity");

  // Booleans in their usual spellings.
  for (const char* t : {"1", "true", "TRUE", "on", "yes"}) {
    ASSERT_TRUE(ApplyOverride("buffer.outlier_removal", t, &c).ok()) << t;
    EXPECT_TRUE(c.buffer.outlier_removal) << t;
  }
  for (const char* f : {"0", "false", "Off", "no"}) {
    ASSERT_TRUE(ApplyOverride("buffer.outlier_removal", f, &c).ok()) << f;
    EXPECT_FALSE(c.buffer.outlier_removal) << f;
  }
  // Later overrides win.
  ASSERT_TRUE(ApplyOverrides({"train.iterations=5", "train.iterations=7"}, &c).ok());
  EXPECT_EQ(c.train.iterations, 7);
}

struct BadCase {
  std::vector<std::string> overrides;
  std::string field;  // must appear in the message
};

TEST(ConfigTest, BadOverridesAreInvalidArgumentNamingTheFieldAndChangeNothing) {
  const std::vector<BadCase> cases = {
      {{"grid.nope=1"}, "grid.nope"},
      {{"train.iterations=abc"}, "train.iterations"},
      {{"train.iterations=1.5"}, "train.iterations"},
      {{"train.iterations="}, "train.iterations"},
      {{"train.learning_rate=fast"}, "train.learning_rate"},
      {{"train.learning_rate=nan"}, "train.learning_rate"},
      {{"train.learning_rate=inf"}, "train.learning_rate"},
      {{"sampler.outside_rays=maybe"}, "sampler.outside_rays"},
      {{"decoder.seed=-1"}, "decoder.seed"},
      {{"grid.levels=99999999999"}, "grid.levels"},
      {{"grid.leaf_size_m=-1"}, "grid.leaf_size_m"},
      {{"grid.leaf_size_m=0"}, "grid.leaf_size_m"},
      {{"grid.half_extent_x_m=1.3"}, "grid.half_extent_x_m"},
      {{"grid.half_extent_y_m=0"}, "grid.half_extent_y_m"},
      {{"grid.z_max_m=-5"}, "grid.z_max_m"},
      {{"grid.z_max_m=3.1"}, "grid.z_max_m"},
      {{"grid.levels=0"}, "grid.levels"},
      {{"train.min_iterations=31"}, "train.min_iterations"},
      {{"train.sigma_m=0"}, "train.sigma_m"},
      {{"sampler.free_min_ratio=0.95"}, "sampler.free_min_ratio"},
      {{"sampler.newest_share=1.5"}, "sampler.newest_share"},
      {{"sampler.newest_share=-0.1"}, "sampler.newest_share"},
      {{"sampler.newest_share=nan"}, "sampler.newest_share"},
      {{"sampler.paced_rays_per_iteration=-1"}, "sampler.paced_rays_per_iteration"},
      {{"sampler.paced_rays_per_iteration=2000000"}, "sampler.paced_rays_per_iteration"},
      {{"buffer.max_points=0"}, "buffer.max_points"},
      {{"submap.block_size=1"}, "submap.block_size"},
      {{"submap.host_budget_bytes=1000"}, "submap.spill_dir"},
      {{"mesh.resolution_m=0.03"}, "mesh.resolution_m"},
      {{"preset=kitti"}, "preset"},
      {{"train.device=gpu"}, "train.device"},
      {{"train.device=cuda:"}, "train.device"},
      {{"train.device=cuda:x"}, "train.device"},
      {{"train.device=cuda", "train.step=libtorch"}, "train.device"},
      {{"train.iterations 5"}, "train.iterations 5"},
      // A valid override followed by a bad one: the valid one must not stick either.
      {{"train.iterations=5", "grid.nope=1"}, "grid.nope"},
      {{"train.iterations=5", "grid.leaf_size_m=-1"}, "grid.leaf_size_m"},
  };
  for (const BadCase& bc : cases) {
    MapperConfig c = Preset("kitti");
    const std::string before = c.ToString();
    absl::Status s = ApplyOverrides(bc.overrides, &c);
    const std::string what = bc.overrides.back();
    ASSERT_FALSE(s.ok()) << what;
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << what << ": " << s;
    EXPECT_THAT(std::string(s.message()), HasSubstr(bc.field)) << what;
    EXPECT_EQ(c.ToString(), before) << what << " changed the config although it failed";
  }
}

TEST(ConfigTest, ParseConfigTextWithCommentsAndPreset) {
  const std::string text =
      "# A config for the test\n"
      "\n"
      "train.iterations = 12   # fewer\n"
      "preset = kitti\n"
      "   grid.sliding=false\n"
      "submap.spill_dir = /var/spill\n"
      "  # indented comment = not a key\n";
  auto c = ParseConfigText(text, "test.conf");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->preset, "kitti");
  EXPECT_FLOAT_EQ(c->grid.half_extent_x_m, 13.f);  // from the preset
  EXPECT_TRUE(c->buffer.outlier_removal);
  EXPECT_EQ(c->train.iterations, 12);  // the file wins over the preset, wherever the preset line is
  EXPECT_FALSE(c->grid.sliding);
  EXPECT_EQ(c->submap.spill_dir, "/var/spill");

  auto plain = ParseConfigText("", "empty.conf");
  ASSERT_TRUE(plain.ok());
  EXPECT_EQ(plain->ToString(), Preset("maicity").ToString());

  auto no_eq = ParseConfigText("train.iterations = 3\njust words\n", "bad.conf");
  ASSERT_FALSE(no_eq.ok());
  EXPECT_EQ(no_eq.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(no_eq.status().message()), HasSubstr("bad.conf:2"));

  auto bad_value = ParseConfigText("train.iterations = many\n", "v.conf");
  ASSERT_FALSE(bad_value.ok());
  EXPECT_THAT(std::string(bad_value.status().message()), HasSubstr("v.conf"));
  EXPECT_THAT(std::string(bad_value.status().message()), HasSubstr("train.iterations"));

  auto bad_preset = ParseConfigText("preset = atlantis\n", "p.conf");
  ASSERT_FALSE(bad_preset.ok());
  EXPECT_THAT(std::string(bad_preset.status().message()), HasSubstr("p.conf"));
  EXPECT_THAT(std::string(bad_preset.status().message()), HasSubstr("atlantis"));

  auto invariant = ParseConfigText("grid.half_extent_x_m = 1.3\n", "i.conf");
  ASSERT_FALSE(invariant.ok());
  EXPECT_THAT(std::string(invariant.status().message()), HasSubstr("grid.half_extent_x_m"));
}

TEST(ConfigTest, ToStringParseRoundTrip) {
  for (const std::string& name : PresetNames()) {
    MapperConfig c = Preset(name);
    ASSERT_TRUE(
        ApplyOverrides({"train.iterations=17", "sampler.seed=99", "grid.sliding=false"}, &c).ok());
    const std::string text = c.ToString();
    EXPECT_THAT(text, HasSubstr("preset = " + name + "\n"));
    EXPECT_THAT(text, HasSubstr("train.iterations = 17\n"));
    auto parsed = ParseConfigText(text, "roundtrip");
    ASSERT_TRUE(parsed.ok()) << name << ": " << parsed.status();
    EXPECT_EQ(parsed->ToString(), text) << name;
    EXPECT_EQ(parsed->preset, name);
  }
}

TEST(ConfigTest, ToStringRoundTripIsExactForFloats) {
  // Checkpoints store the config as ToString text (mapper_persistence.cc); a reloaded session
  // must train with exactly the values it was created with.
  MapperConfig c = Preset("maicity");
  ASSERT_TRUE(ApplyOverrides({"train.learning_rate=0.0123456789", "train.adam_beta2=0.99987654",
                              "sampler.observed_band_m=0.123456789", "train.sigma_m=0.0498765432"},
                             &c)
                  .ok());
  auto parsed = ParseConfigText(c.ToString(), "roundtrip");
  ASSERT_TRUE(parsed.ok()) << parsed.status();
  EXPECT_EQ(parsed->train.learning_rate, c.train.learning_rate);
  EXPECT_EQ(parsed->train.adam_beta2, c.train.adam_beta2);
  EXPECT_EQ(parsed->sampler.observed_band_m, c.sampler.observed_band_m);
  EXPECT_EQ(parsed->train.sigma_m, c.train.sigma_m);
  EXPECT_EQ(parsed->ToString(), c.ToString());
}

std::string TempPath(const std::string& name) {
  std::string dir = ::testing::TempDir();
  if (dir.empty() || dir.back() != '/') dir += '/';
  return dir + name + "." + std::to_string(getpid());
}

TEST(ConfigTest, LoadConfigFile) {
  const std::string path = TempPath("rim_config_test.conf");
  {
    std::ofstream out(path);
    out << "preset = replica\n# comment\ntrain.iterations = 11\n";
  }
  auto c = LoadConfigFile(path);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->preset, "replica");
  EXPECT_EQ(c->train.iterations, 11);
  EXPECT_FLOAT_EQ(c->grid.leaf_size_m, 0.05f);

  // Overrides come last and win.
  auto o = LoadConfigFile(path, {"train.iterations=4"});
  ASSERT_TRUE(o.ok()) << o.status();
  EXPECT_EQ(o->train.iterations, 4);
  auto bad = LoadConfigFile(path, {"train.iterations=x"});
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(bad.status().message()), HasSubstr("train.iterations"));

  {
    std::ofstream out(path);
    out << "grid.leaf_size_m = -1\n";
  }
  auto invalid = LoadConfigFile(path);
  ASSERT_FALSE(invalid.ok());
  EXPECT_THAT(std::string(invalid.status().message()), HasSubstr(path));
  EXPECT_THAT(std::string(invalid.status().message()), HasSubstr("grid.leaf_size_m"));
  unlink(path.c_str());

  const std::string missing = TempPath("rim_config_test_missing.conf");
  auto m = LoadConfigFile(missing);
  ASSERT_FALSE(m.ok());
  EXPECT_EQ(m.status().code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(m.status().message()), HasSubstr(missing));
}

}  // namespace
}  // namespace rim
