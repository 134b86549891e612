// One writer per session folder (docs/service.md, "Replicas and shared storage"). A replica that
// opens a session, by CreateSession, LoadSession or a takeover, holds an exclusive flock on the
// folder's LEASE file for as long as the session is open, and writes into it who it is and a
// random token. The kernel (or the NFS server) drops the lock when the process dies, however it
// dies, so a dead owner's session can be taken over at once, and a lease file left behind or
// written by hand counts for nothing: only a held lock does.
//
// Fencing: before every write to the folder (a write-ahead-log append, a checkpoint) the owner
// reads the file back and checks that its token is still there. A replica that took the session
// over wrote its own token first, so a writer that lost its lock (a stale NFS lock, the file
// removed and made anew) stops at its next write instead of writing beside the new owner.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace rim::server {

class SessionLease {
 public:
  // Takes the lease of the session folder `dir` (which must exist) for `owner` (a replica's
  // name, shown to others). FAILED_PRECONDITION naming the owner when a live process holds it.
  static absl::StatusOr<std::unique_ptr<SessionLease>> Acquire(const std::string& dir,
                                                               const std::string& owner);
  ~SessionLease();  // releases the lock (the file stays: it only records the last owner)
  SessionLease(const SessionLease&) = delete;
  SessionLease& operator=(const SessionLease&) = delete;

  // OK while this lease is still the folder's: FAILED_PRECONDITION ("fenced") once another
  // owner's token is in the file, the file is gone, or the lease was released.
  absl::Status Check() const;
  // Drops the lock now (a session closed while handlers still hold it). Idempotent.
  void Release();

  const std::string& owner() const { return owner_; }
  uint64_t epoch() const { return epoch_; }  // counts the folder's owners so far, from 1

  // Who the LEASE file in `dir` names, for messages ("" when there is none).
  static std::string DescribeOwner(const std::string& dir);

 private:
  SessionLease() = default;
  std::string path_, owner_, token_;
  uint64_t epoch_ = 0;
  mutable std::mutex mu_;
  int fd_ = -1;  // guarded by mu_; -1 once released
};

}  // namespace rim::server
