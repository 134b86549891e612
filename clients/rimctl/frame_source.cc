#include "rimctl/frame_source.h"

#include <cmath>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "rim/io/dataset.h"

namespace rim::rimctl {
namespace {

class DatasetSource : public FrameSource {
 public:
  DatasetSource(std::string path, std::unique_ptr<io::Dataset> dataset)
      : path_(std::move(path)), dataset_(std::move(dataset)) {}
  size_t size() const override { return dataset_->size(); }
  absl::StatusOr<PosedScan> Read(size_t index) const override { return dataset_->Read(index); }
  std::string Describe() const override {
    return absl::StrCat(io::LayoutName(dataset_->layout()), " dataset ", path_, " (", size(),
                        " frames)");
  }

 private:
  std::string path_;
  std::unique_ptr<io::Dataset> dataset_;
};

class CitySource : public FrameSource {
 public:
  explicit CitySource(const sim::CityFrameOptions& options) : options_(options), frames_(options) {}
  size_t size() const override { return frames_.size(); }
  absl::StatusOr<PosedScan> Read(size_t index) const override { return frames_.Frame(index); }
  std::string Describe() const override {
    return absl::StrCat("synthetic city (", size(), " frames, seed ", options_.seed, ", ",
                        options_.columns, " LiDAR columns, noise ", options_.noise, " m)");
  }

 private:
  sim::CityFrameOptions options_;
  sim::CityFrames frames_;
};

absl::Status BadValue(const std::string& key, const std::string& value, const char* want) {
  return absl::InvalidArgumentError(
      absl::StrCat("sim:city option ", key, "='", value, "' is not ", want));
}

}  // namespace

absl::StatusOr<sim::CityFrameOptions> ParseSimCitySpec(const std::string& spec) {
  const std::string kPrefix = "sim:city";
  if (spec.rfind(kPrefix, 0) != 0 ||
      (spec.size() > kPrefix.size() && spec[kPrefix.size()] != '?')) {
    return absl::InvalidArgumentError(
        absl::StrCat("unknown synthetic scene '", spec, "' (the one built in is sim:city)"));
  }
  sim::CityFrameOptions o;
  if (spec.size() <= kPrefix.size() + 1) return o;
  for (absl::string_view item :
       absl::StrSplit(spec.substr(kPrefix.size() + 1), absl::ByAnyChar("&,"), absl::SkipEmpty())) {
    const std::vector<std::string> kv = absl::StrSplit(item, absl::MaxSplits('=', 1));
    if (kv.size() != 2) {
      return absl::InvalidArgumentError(
          absl::StrCat("sim:city option '", item, "' is not key=value"));
    }
    const std::string& key = kv[0];
    const std::string& value = kv[1];
    double d = 0;
    long n = 0;
    const bool is_int = absl::SimpleAtoi(value, &n);
    const bool is_num = absl::SimpleAtod(value, &d) && std::isfinite(d);
    if (key == "frames") {
      if (!is_int || n < 1 || n > 1000000)
        return BadValue(key, value, "an integer in [1, 1000000]");
      o.frames = int(n);
    } else if (key == "seed") {
      if (!is_int || n < 0) return BadValue(key, value, "a non-negative integer");
      o.seed = uint64_t(n);
    } else if (key == "step") {
      if (!is_num || d <= 0 || d > 100) return BadValue(key, value, "in (0, 100] m");
      o.step = d;
    } else if (key == "columns") {
      if (!is_int || n < 16 || n > 36000) return BadValue(key, value, "an integer in [16, 36000]");
      o.columns = int(n);
    } else if (key == "noise") {
      if (!is_num || d < 0 || d > 10) return BadValue(key, value, "in [0, 10] m");
      o.noise = d;
    } else if (key == "walkers") {
      if (!is_int || n < 0 || n > 10000) return BadValue(key, value, "an integer in [0, 10000]");
      o.walkers = int(n);
    } else if (key == "threads") {
      if (!is_int || n < 1 || n > 256) return BadValue(key, value, "an integer in [1, 256]");
      o.threads = int(n);
    } else {
      return absl::InvalidArgumentError(
          absl::StrCat("unknown sim:city option '", key,
                       "' (known: frames, seed, step, columns, noise, walkers, threads)"));
    }
  }
  return o;
}

absl::StatusOr<std::unique_ptr<FrameSource>> OpenFrameSource(const std::string& spec) {
  if (spec.rfind("sim:", 0) == 0) {
    auto options = ParseSimCitySpec(spec);
    if (!options.ok()) return options.status();
    return std::make_unique<CitySource>(*options);
  }
  auto dataset = io::Dataset::Open(spec);
  if (!dataset.ok()) return dataset.status();
  return std::make_unique<DatasetSource>(spec, std::move(*dataset));
}

}  // namespace rim::rimctl
