// rim/base/flags.h: the conventions every rim binary's command line keeps on top of CLI11
// (docs/clients.md, "Command lines: one flag library").
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "rim/base/flags.h"

namespace rim::cli {
namespace {

using ::testing::HasSubstr;

struct Flags {
  int count = 3;
  double scale = 1.0;
  std::string name;
  bool verbose = false;
  std::string input;
};

void Add(CLI::App& app, Flags& f) {
  SetHelp(app, "usage: tool INPUT [--count N] [--scale X] [--name S] [--verbose]", "A tool.");
  app.add_option("INPUT", f.input, "the input")->type_name("");
  app.add_option("--count", f.count, "how many (default 3)")
      ->type_name("N")
      ->transform(IntegerIn(0, 100, [](const std::string& v) {
        return "--count must be an integer in [0, 100], got '" + v + "'";
      }));
  app.add_option("--scale", f.scale, "a factor (default 1)")
      ->type_name("X")
      ->transform(NumberIn(0.0, 10.0, false, [](const std::string& v) {
        return "--scale '" + v + "' is not in (0, 10]";
      }));
  app.add_option("--name", f.name, "a name")
      ->type_name("S")
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  app.add_flag("--verbose", f.verbose, "say more");
}

absl::Status ParseInto(Flags& f, std::vector<std::string> args) {
  CLI::App app("", "tool");
  Add(app, f);
  return Parse(app, std::move(args));
}

TEST(CliFlagsTest, BothValueFormsAndSwitches) {
  Flags f;
  ASSERT_TRUE(ParseInto(f, {"in.ply", "--count", "7", "--scale=2.5", "--verbose"}).ok());
  EXPECT_EQ(f.input, "in.ply");
  EXPECT_EQ(f.count, 7);
  EXPECT_EQ(f.scale, 2.5);
  EXPECT_TRUE(f.verbose);
  Flags defaults;
  ASSERT_TRUE(ParseInto(defaults, {"in.ply"}).ok());
  EXPECT_EQ(defaults.count, 3);
  EXPECT_EQ(defaults.scale, 1.0);
  EXPECT_FALSE(defaults.verbose);
}

TEST(CliFlagsTest, NumbersAreDecimalAsAbseilReadsThem) {
  Flags f;
  ASSERT_TRUE(ParseInto(f, {"--count", "010"}).ok());
  EXPECT_EQ(f.count, 10) << "CLI11 alone reads 010 as octal";
  ASSERT_TRUE(ParseInto(f, {"--count=-0", "--scale", "1e-3"}).ok());
  EXPECT_EQ(f.count, 0);
  EXPECT_EQ(f.scale, 1e-3);
  Flags g;
  ASSERT_TRUE(ParseInto(g, {"--scale", "0.1"}).ok());
  EXPECT_EQ(g.scale, 0.1) << "the text reaches CLI11 with every digit";
}

TEST(CliFlagsTest, UsageErrorsNameTheFlag) {
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--count", "0x10"}, "--count must be an integer in [0, 100], got '0x10'"},
      {{"--count", "101"}, "--count must be an integer in [0, 100], got '101'"},
      {{"--count=-1"}, "--count must be an integer in [0, 100], got '-1'"},
      {{"--scale", "nan"}, "--scale 'nan' is not in (0, 10]"},
      {{"--scale", "0"}, "--scale '0' is not in (0, 10]"},
      {{"--scale", "inf"}, "--scale 'inf' is not in (0, 10]"},
      {{"in", "--count"}, "--count needs a value"},
      {{"--count", "1", "--count", "2"}, "--count given more than once"},
      {{"in", "--bogus", "1"}, "unknown flag '--bogus'"},
      {{"in", "--bogus=1"}, "unknown flag '--bogus'"},
      {{"in", "stray"}, "unexpected argument 'stray'"},
      {{"in", "--verbose=yes"}, "--verbose takes no value"},
  };
  for (const auto& [args, message] : cases) {
    Flags f;
    const absl::Status s = ParseInto(f, args);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << message;
    EXPECT_EQ(s.message(), message);
  }
}

TEST(CliFlagsTest, DoubleDashEndsTheFlags) {
  Flags f;
  ASSERT_TRUE(ParseInto(f, {"--count", "4", "--", "-in-"}).ok());
  EXPECT_EQ(f.input, "-in-");
  EXPECT_EQ(f.count, 4);
  EXPECT_EQ(ParseInto(f, {"--", "a", "b"}).message(), "unexpected argument 'b'");
}

TEST(CliFlagsTest, TakeLastKeepsTheLastValue) {
  Flags f;
  ASSERT_TRUE(ParseInto(f, {"--name", "a", "--name=b"}).ok());
  EXPECT_EQ(f.name, "b");
}

TEST(CliFlagsTest, HelpListsEveryFlagWithItsDescription) {
  for (const char* help : {"-h", "--help"}) {
    Flags f;
    CLI::App app("", "tool");
    Add(app, f);
    EXPECT_TRUE(absl::IsCancelled(Parse(app, {"in", help})));
    const std::string text = app.help();
    EXPECT_EQ(text.rfind("usage: tool INPUT [--count N]", 0), 0u) << text;
    EXPECT_THAT(text, HasSubstr("A tool."));
    EXPECT_THAT(text, HasSubstr("--count N"));
    EXPECT_THAT(text, HasSubstr("how many (default 3)"));
    EXPECT_THAT(text, HasSubstr("--verbose"));
    EXPECT_THAT(text, HasSubstr("say more"));
  }
}

}  // namespace
}  // namespace rim::cli
