#include "rim/io/file_util.h"

#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <system_error>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "rim/base/status_macros.h"

namespace rim::io {

absl::StatusOr<std::string> ReadFileToString(const std::string& path, uint64_t max_bytes) {
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) {
    const int err = errno;
    const std::string what = absl::StrCat(path, ": cannot open: ", std::strerror(err));
    return err == ENOENT ? absl::NotFoundError(what) : absl::UnavailableError(what);
  }
  struct stat st;
  if (fstat(fileno(file), &st) != 0 || !S_ISREG(st.st_mode)) {
    std::fclose(file);
    return absl::FailedPreconditionError(absl::StrCat(path, ": not a regular file"));
  }
  if (static_cast<uint64_t>(st.st_size) > max_bytes) {
    std::fclose(file);
    return absl::FailedPreconditionError(
        absl::StrCat(path, ": file is ", st.st_size, " bytes, more than the limit of ", max_bytes));
  }
  std::string data;
  data.reserve(static_cast<size_t>(st.st_size));
  char buf[1 << 16];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof(buf), file)) > 0) {
    if (data.size() + n > max_bytes) {
      std::fclose(file);
      return absl::FailedPreconditionError(
          absl::StrCat(path, ": file grew beyond the limit of ", max_bytes, " bytes"));
    }
    data.append(buf, n);
  }
  const bool read_error = std::ferror(file) != 0;
  std::fclose(file);
  if (read_error) return absl::DataLossError(absl::StrCat(path, ": read error"));
  return data;
}

absl::Status WriteStringToFile(const std::string& path, absl::string_view data) {
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) {
    return absl::UnavailableError(
        absl::StrCat(path, ": cannot open for writing: ", std::strerror(errno)));
  }
  const size_t written = data.empty() ? 0 : std::fwrite(data.data(), 1, data.size(), file);
  const int close_result = std::fclose(file);
  if (written != data.size() || close_result != 0) {
    return absl::DataLossError(absl::StrCat(path, ": write failed: ", std::strerror(errno)));
  }
  return absl::OkStatus();
}

bool IsDirectory(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_directory(path, ec);
}

bool IsRegularFile(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_regular_file(path, ec);
}

std::string JoinPath(const std::string& dir, const std::string& name) {
  if (dir.empty()) return name;
  if (dir.back() == '/') return dir + name;
  return dir + "/" + name;
}

bool NaturalLess(absl::string_view a, absl::string_view b) {
  auto is_digit = [](char c) { return c >= '0' && c <= '9'; };
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (is_digit(a[i]) && is_digit(b[j])) {
      size_t ie = i, je = j;
      while (ie < a.size() && is_digit(a[ie])) ++ie;
      while (je < b.size() && is_digit(b[je])) ++je;
      // Compare the digit runs as numbers: skip leading zeros, then longer is larger.
      size_t is = i, js = j;
      while (is + 1 < ie && a[is] == '0') ++is;
      while (js + 1 < je && b[js] == '0') ++js;
      const absl::string_view na = a.substr(is, ie - is), nb = b.substr(js, je - js);
      if (na.size() != nb.size()) return na.size() < nb.size();
      if (na != nb) return na < nb;
      i = ie;
      j = je;
      continue;
    }
    if (a[i] != b[j]) return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
    ++i;
    ++j;
  }
  if ((a.size() - i) != (b.size() - j)) return (a.size() - i) < (b.size() - j);
  return a < b;
}

std::vector<std::string> ListFiles(const std::string& dir, absl::string_view prefix,
                                   absl::string_view suffix) {
  std::vector<std::string> names;
  std::error_code ec;
  std::filesystem::directory_iterator it(dir, ec), end;
  if (ec) return names;
  for (; it != end; it.increment(ec)) {
    if (ec) break;
    std::error_code type_ec;
    if (!it->is_regular_file(type_ec)) continue;
    std::string name = it->path().filename().string();
    if (name.size() < prefix.size() + suffix.size()) continue;
    const absl::string_view view(name);
    if (view.substr(0, prefix.size()) != prefix) continue;
    if (view.substr(view.size() - suffix.size()) != suffix) continue;
    names.push_back(std::move(name));
  }
  std::sort(names.begin(), names.end(),
            [](const std::string& a, const std::string& b) { return NaturalLess(a, b); });
  return names;
}

std::vector<TextLine> SplitLines(absl::string_view data, char comment) {
  std::vector<TextLine> lines;
  int number = 0;
  size_t pos = 0;
  while (pos < data.size()) {
    size_t eol = data.find('\n', pos);
    if (eol == absl::string_view::npos) eol = data.size();
    ++number;
    absl::string_view text = absl::StripAsciiWhitespace(data.substr(pos, eol - pos));
    pos = eol + 1;
    if (text.empty() || (comment != 0 && text.front() == comment)) continue;
    lines.push_back({number, text});
  }
  return lines;
}

absl::StatusOr<std::vector<double>> ParseNumbers(absl::string_view text, const std::string& path,
                                                 int line) {
  std::vector<double> values;
  for (absl::string_view token : absl::StrSplit(text, absl::ByAnyChar(" \t,"), absl::SkipEmpty())) {
    double v;
    if (!absl::SimpleAtod(token, &v)) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ":", line, ": '", token.substr(0, 40), "' is not a number"));
    }
    values.push_back(v);
  }
  return values;
}

absl::StatusOr<std::vector<double>> ParseFiniteNumbers(absl::string_view text, size_t count,
                                                       const std::string& path, int line,
                                                       absl::string_view what) {
  RIM_ASSIGN_OR_RETURN(std::vector<double> values, ParseNumbers(text, path, line));
  if (values.size() != count) {
    return absl::InvalidArgumentError(absl::StrCat(path, ":", line, ": expected ", count,
                                                   " numbers (", what, "), found ", values.size()));
  }
  for (size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) {
      return absl::InvalidArgumentError(absl::StrCat(path, ":", line, ": value ", i + 1, " of ",
                                                     what, " is not finite (", values[i], ")"));
    }
  }
  return values;
}

}  // namespace rim::io
