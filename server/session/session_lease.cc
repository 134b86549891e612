#include "server/session/session_lease.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <ctime>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"

namespace rim::server {
namespace {

constexpr size_t kMaxLeaseBytes = 4096;

std::map<std::string, std::string> ParseLease(const std::string& text) {
  std::map<std::string, std::string> out;
  for (absl::string_view line : absl::StrSplit(text.substr(0, kMaxLeaseBytes), '\n')) {
    const size_t eq = line.find('=');
    if (eq != absl::string_view::npos)
      out[std::string(line.substr(0, eq))] = std::string(line.substr(eq + 1));
  }
  return out;
}

std::string ReadLeaseFile(const std::string& path, bool* exists) {
  std::ifstream in(path, std::ios::binary);
  *exists = bool(in);
  std::string text(kMaxLeaseBytes, '\0');
  in.read(text.data(), std::streamsize(text.size()));
  text.resize(size_t(in.gcount()));
  return text;
}

std::string RandomToken() {
  std::random_device rd;  // the kernel's entropy
  return absl::StrFormat("%08x%08x%08x%08x", rd(), rd(), rd(), rd());
}

std::string Errno(const char* what) { return absl::StrCat(what, ": ", std::strerror(errno)); }

}  // namespace

absl::StatusOr<std::unique_ptr<SessionLease>> SessionLease::Acquire(const std::string& dir,
                                                                    const std::string& owner) {
  std::unique_ptr<SessionLease> lease(new SessionLease());
  lease->path_ = dir + "/LEASE";
  lease->owner_ = owner;
  lease->fd_ = open(lease->path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0644);
  if (lease->fd_ < 0)
    return absl::UnavailableError(Errno(absl::StrCat("opening ", lease->path_).c_str()));
  if (flock(lease->fd_, LOCK_EX | LOCK_NB) != 0) {
    if (errno == EWOULDBLOCK) {
      const std::string holder = DescribeOwner(dir);
      return absl::FailedPreconditionError(absl::StrCat(
          "session folder ", dir, " is owned by ", holder.empty() ? "another process" : holder,
          ", which is alive and holds its lease: send the robot's calls to that replica"));
    }
    return absl::UnavailableError(Errno(absl::StrCat("locking ", lease->path_).c_str()));
  }
  // The lock is ours. The file may have been replaced between open and flock (a racing owner
  // that removed it): then the lock is on a file nobody else sees; start again on the new one.
  struct stat by_fd = {}, by_path = {};
  if (fstat(lease->fd_, &by_fd) != 0 || stat(lease->path_.c_str(), &by_path) != 0 ||
      by_fd.st_ino != by_path.st_ino || by_fd.st_dev != by_path.st_dev)
    return absl::UnavailableError(
        absl::StrCat(lease->path_, " changed while it was being locked; try again"));
  bool exists = false;
  const auto previous = ParseLease(ReadLeaseFile(lease->path_, &exists));
  uint64_t epoch = 0;
  if (auto it = previous.find("epoch"); it != previous.end()) {
    if (!absl::SimpleAtoi(it->second, &epoch)) epoch = 0;
  }
  lease->epoch_ = epoch + 1;
  lease->token_ = RandomToken();
  const std::string text =
      absl::StrCat("owner=", owner, "\nepoch=", lease->epoch_, "\ntoken=", lease->token_,
                   "\nsince=", int64_t(std::time(nullptr)), "\npid=", int64_t(getpid()), "\n");
  if (ftruncate(lease->fd_, 0) != 0 ||
      pwrite(lease->fd_, text.data(), text.size(), 0) != ssize_t(text.size()) ||
      fsync(lease->fd_) != 0)
    return absl::UnavailableError(Errno(absl::StrCat("writing ", lease->path_).c_str()));
  return lease;
}

SessionLease::~SessionLease() { Release(); }

void SessionLease::Release() {
  std::lock_guard<std::mutex> lock(mu_);
  if (fd_ >= 0) close(fd_);  // closing the last descriptor drops the flock
  fd_ = -1;
}

absl::Status SessionLease::Check() const {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (fd_ < 0)
      return absl::FailedPreconditionError(
          absl::StrCat("the lease of ", path_, " was released: the session is closed here"));
  }
  bool exists = false;
  const auto now = ParseLease(ReadLeaseFile(path_, &exists));
  if (!exists)
    return absl::FailedPreconditionError(absl::StrCat("fenced: the lease file ", path_,
                                                      " is gone; this replica no longer owns the "
                                                      "session and writes nothing more to it"));
  auto token = now.find("token");
  if (token == now.end() || token->second != token_) {
    auto holder = now.find("owner");
    return absl::FailedPreconditionError(absl::StrCat(
        "fenced: ", holder == now.end() ? "another process" : holder->second,
        " has taken the session over (", path_, "); this replica writes nothing more to it"));
  }
  return absl::OkStatus();
}

std::string SessionLease::DescribeOwner(const std::string& dir) {
  bool exists = false;
  const auto lease = ParseLease(ReadLeaseFile(dir + "/LEASE", &exists));
  auto owner = lease.find("owner");
  if (owner == lease.end() || owner->second.empty()) return "";
  std::string out = absl::StrCat("replica ", owner->second.substr(0, 200));
  if (auto since = lease.find("since"); since != lease.end())
    absl::StrAppend(&out, " (owner since unix time ", since->second.substr(0, 20), ")");
  return out;
}

}  // namespace rim::server
