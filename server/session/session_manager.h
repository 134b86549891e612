// The service's sessions by robot id (DESIGN.md §5.1-5.3): creation from a preset and overrides
// under the --max-sessions limit, lookup, close, and checkpoints under
// <data-dir>/sessions/<robot_id>/. Thread-safe. Sessions are shared with the handlers using them,
// so closing one never pulls it from under an in-flight RPC.
#pragma once

#include <atomic>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "server/session/session.h"

namespace rim::server {

struct SessionManagerOptions {
  std::string data_dir;
  std::string default_preset = "maicity";
  std::string default_device = "cpu";  // train.device of sessions whose config does not set it
  int max_sessions = 16;
  int queue_length = 8;
  int checkpoint_every_frames = 100;
  // Host memory all sessions together may hold (maps, optimiser state, point buffers); 0: none.
  uint64_t host_memory_budget_bytes = 0;
  // Receives what sessions do, for metrics; not owned; may be null.
  SessionEvents* events = nullptr;
  // Shares the compute between the sessions' trainers; not owned; may be null.
  ComputeScheduler* scheduler = nullptr;
  int background_nice = 0;                  // SessionOptions::background_nice
  MeshingBudget* meshing_budget = nullptr;  // SessionOptions::meshing_budget; not owned
  // This replica's name in the session leases (docs/service.md, "Replicas and shared storage").
  std::string replica_id = "rim_server";
  // Replicas share the data dir: a call about a session that no replica has open opens it here
  // (its last checkpoint, then its log), as LoadSession would.
  bool take_over = false;
  // Receives a line for each take-over (who held the session, how long opening it took, or why it
  // failed); rim_server writes them to its log. May be empty.
  std::function<void(const std::string&)> log;
};

// Host memory a session's map holds: live grids with optimiser state, sub-maps in memory, and the
// historical point buffer.
uint64_t SessionHostBytes(const Session& session);

// OK for 1-64 characters of [A-Za-z0-9_.-]; otherwise INVALID_ARGUMENT naming robot_id.
absl::Status ValidateRobotId(const std::string& robot_id);

class SessionManager {
 public:
  explicit SessionManager(SessionManagerOptions options);
  ~SessionManager();  // closes every session (drains, no save)

  // ALREADY_EXISTS for a duplicate id, RESOURCE_EXHAUSTED over max_sessions, INVALID_ARGUMENT for
  // a bad id, preset or override (naming it). An empty preset is the server default.
  absl::StatusOr<std::shared_ptr<Session>> Create(
      const std::string& robot_id, const std::string& preset,
      const std::vector<std::pair<std::string, std::string>>& overrides);
  // NOT_FOUND for an unknown session. With take_over, a session saved (or left by a replica
  // that died) in the data dir is opened here first; FAILED_PRECONDITION naming the owner when a
  // live replica holds it.
  absl::StatusOr<std::shared_ptr<Session>> Get(const std::string& robot_id);
  // The session if it is open here (no take-over).
  absl::StatusOr<std::shared_ptr<Session>> Find(const std::string& robot_id) const;
  // Every session, ordered by robot id.
  std::vector<std::shared_ptr<Session>> List() const;
  // Drains and stops the session, after saving it when `save` is set; it is removed even if the
  // save fails (the error is returned).
  absl::Status Close(const std::string& robot_id, bool save);
  // Writes a checkpoint; returns its directory relative to the data dir.
  absl::StatusOr<std::string> Save(const std::string& robot_id);
  // Restores a saved session: ALREADY_EXISTS when it is open, NOT_FOUND when never saved.
  absl::StatusOr<std::shared_ptr<Session>> Load(const std::string& robot_id);
  // Closes every session (for shutdown), saving each when `save` is set; returns the first error.
  absl::Status CloseAll(bool save);

  // Sum of SessionHostBytes over the open sessions.
  uint64_t HostMemoryBytes() const;
  // RESOURCE_EXHAUSTED naming the budget when the sessions hold more than it (OK without one).
  absl::Status CheckHostMemoryBudget() const;

  // Shutdown has begun (SIGTERM): streams stop accepting scans and end.
  void BeginShutdown() { stopping_ = true; }
  bool stopping() const { return stopping_; }

  const SessionManagerOptions& options() const { return options_; }

 private:
  std::string RelativeDir(const std::string& robot_id) const;
  std::string AbsoluteDir(const std::string& robot_id) const;
  absl::Status SaveLocked(Session& session);
  SessionOptions MakeSessionOptions(const std::string& robot_id) const;
  // After a session was built: RESOURCE_EXHAUSTED if adding it breaks the budget.
  absl::Status AdmitUnderBudget(const Session& session) const;
  // Host memory the open sessions leave of the budget (at least 1); 0 without a budget.
  uint64_t BudgetLeft() const;
  // FAILED_PRECONDITION when sessions/ or anything in the session's folder is a symbolic link:
  // session folders never lead out of the data dir.
  absl::Status RefuseLinksToSession(const std::string& robot_id) const;
  // A new session folder: config, empty write-ahead log.
  absl::StatusOr<std::unique_ptr<Session>> CreateOnDisk(const std::string& robot_id,
                                                        const MapperConfig& config,
                                                        SessionOptions options);
  // The mapper of a saved or crashed session, its log replayed, and the log. A map needing more
  // than `max_host_bytes` at start (0: no limit) is RESOURCE_EXHAUSTED before it is allocated.
  // *last_sequence: the highest scan sequence the session had accepted (none: never known).
  static absl::StatusOr<std::pair<std::unique_ptr<Mapper>, std::unique_ptr<WriteAheadLog>>> Restore(
      const std::string& dir, uint64_t max_host_bytes, std::optional<uint64_t>* last_sequence);

  const SessionManagerOptions options_;
  std::atomic<bool> stopping_{false};
  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<Session>> sessions_;
  // Ids being created or loaded (outside the lock), counted against the limit.
  std::map<std::string, bool> pending_;
  // The lease of each open session's folder, released when it closes.
  std::map<std::string, std::shared_ptr<SessionLease>> leases_;
  // Takes the lease of a session folder (FAILED_PRECONDITION naming a live owner).
  absl::StatusOr<std::shared_ptr<SessionLease>> TakeLease(const std::string& robot_id) const;
  void ReleaseLease(const std::string& robot_id);
};

}  // namespace rim::server
