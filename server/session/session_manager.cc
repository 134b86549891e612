#include "server/session/session_manager.h"

#include <chrono>
#include <filesystem>
#include <optional>
#include <thread>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/binary_io.h"
#include "rim/base/status_macros.h"
#include "rim/config/config.h"
#include "rim/mapper.h"

namespace rim::server {

absl::Status ValidateRobotId(const std::string& robot_id) {
  bool ok = !robot_id.empty() && robot_id.size() <= 64;
  for (char c : robot_id) {
    const bool allowed = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') ||
                         (c >= '0' && c <= '9') || c == '_' || c == '.' || c == '-';
    ok = ok && allowed;
  }
  // "." and ".." would name directories other than the session's own.
  if (robot_id == "." || robot_id == "..") ok = false;
  if (!ok)
    return absl::InvalidArgumentError(absl::StrCat("robot_id '", robot_id.substr(0, 80),
                                                   "' must be 1-64 characters of [A-Za-z0-9_.-]"));
  return absl::OkStatus();
}

uint64_t SessionHostBytes(const Session& session) {
  const MapperStats stats = session.mapper().Stats();
  // Each buffered point keeps its endpoint and its ray origin; the deferred rays (seen outside the
  // box, waiting for it) are counted by their tables' capacity, the distance field by its surfels
  // and their k-d trees, the mesh blocks cached for its dashboards by their arrays.
  return uint64_t(stats.local_map_bytes + stats.submap_bytes + stats.deferred_bytes +
                  stats.distance_bytes + stats.mesh_cache_bytes) +
         uint64_t(stats.buffer_points) * 2 * sizeof(Vec3f);
}

namespace {

std::string Megabytes(uint64_t bytes) { return absl::StrFormat("%.1f MB", bytes / 1e6); }

}  // namespace

SessionManager::SessionManager(SessionManagerOptions options) : options_(std::move(options)) {}

uint64_t SessionManager::HostMemoryBytes() const {
  uint64_t total = 0;
  for (const auto& session : List()) total += SessionHostBytes(*session);
  return total;
}

absl::Status SessionManager::CheckHostMemoryBudget() const {
  const uint64_t budget = options_.host_memory_budget_bytes;
  if (budget == 0) return absl::OkStatus();
  const uint64_t used = HostMemoryBytes();
  if (used <= budget) return absl::OkStatus();
  return absl::ResourceExhaustedError(
      absl::StrCat("host memory budget exceeded: sessions hold ", Megabytes(used), " of ",
                   Megabytes(budget), " (--host-memory-budget-bytes); save and close sessions"));
}

uint64_t SessionManager::BudgetLeft() const {
  const uint64_t budget = options_.host_memory_budget_bytes;
  if (budget == 0) return 0;
  const uint64_t used = HostMemoryBytes();
  // 1, not 0, when nothing is left: 0 means "no budget", and every map needs more than a byte.
  return used < budget ? budget - used : 1;
}

absl::Status SessionManager::AdmitUnderBudget(const Session& session) const {
  const uint64_t budget = options_.host_memory_budget_bytes;
  if (budget == 0) return absl::OkStatus();
  const uint64_t used = HostMemoryBytes(), need = SessionHostBytes(session);
  if (used + need <= budget) return absl::OkStatus();
  return absl::ResourceExhaustedError(
      absl::StrCat("host memory budget: session ", session.robot_id(), " needs ", Megabytes(need),
                   ", open sessions hold ", Megabytes(used), " of ", Megabytes(budget),
                   " (--host-memory-budget-bytes)"));
}

SessionOptions SessionManager::MakeSessionOptions(const std::string& robot_id) const {
  SessionOptions o;
  o.queue_length = options_.queue_length;
  o.checkpoint_every_frames = options_.checkpoint_every_frames;
  o.checkpoint_dir = AbsoluteDir(robot_id);
  o.events = options_.events;
  o.scheduler = options_.scheduler;
  o.background_nice = options_.background_nice;
  o.meshing_budget = options_.meshing_budget;
  return o;
}

SessionManager::~SessionManager() { CloseAll(/*save=*/false).IgnoreError(); }

std::string SessionManager::RelativeDir(const std::string& robot_id) const {
  return "sessions/" + robot_id;
}

std::string SessionManager::AbsoluteDir(const std::string& robot_id) const {
  return (std::filesystem::path(options_.data_dir) / RelativeDir(robot_id)).string();
}

absl::Status SessionManager::RefuseLinksToSession(const std::string& robot_id) const {
  // The data dir itself may be a link (an administrator's choice); nothing below it may be.
  RIM_RETURN_IF_ERROR(
      RefuseSymlink((std::filesystem::path(options_.data_dir) / "sessions").string()));
  return RefuseSymlinksUnder(AbsoluteDir(robot_id));
}

absl::StatusOr<std::shared_ptr<Session>> SessionManager::Create(
    const std::string& robot_id, const std::string& preset,
    const std::vector<std::pair<std::string, std::string>>& overrides) {
  if (absl::Status s = ValidateRobotId(robot_id); !s.ok()) return s;
  const std::string preset_name = preset.empty() ? options_.default_preset : preset;
  auto config = MakePreset(preset_name);
  if (!config.ok())
    return absl::InvalidArgumentError(absl::StrCat("preset: ", config.status().message()));
  config->train.device = options_.default_device;  // an override may still choose
  for (const auto& [key, value] : overrides) {
    absl::Status s = ApplyOverride(key, value, &*config);
    if (!s.ok()) return absl::InvalidArgumentError(absl::StrCat("overrides: ", s.message()));
  }
  if (absl::Status s = config->Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("overrides: ", s.message()));
  // Before the mapper allocates its grids, not after (AdmitUnderBudget): overrides may ask for
  // gigabytes.
  if (const uint64_t left = BudgetLeft(); left > 0 && Mapper::InitialHostBytes(*config) > left)
    return absl::ResourceExhaustedError(
        absl::StrCat("host memory budget: the map of session ", robot_id, " needs ",
                     Megabytes(Mapper::InitialHostBytes(*config)), ", ", Megabytes(left),
                     " left of the budget (--host-memory-budget-bytes)"));
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (sessions_.count(robot_id) || pending_.count(robot_id))
      return absl::AlreadyExistsError(absl::StrCat("session ", robot_id, " already exists"));
    if (int(sessions_.size() + pending_.size()) >= options_.max_sessions)
      return absl::ResourceExhaustedError(absl::StrCat(
          "session limit reached: ", options_.max_sessions, " sessions (--max-sessions)"));
    pending_[robot_id] = true;
  }
  auto session = CreateOnDisk(robot_id, *config, MakeSessionOptions(robot_id));
  absl::Status admitted = session.ok() ? AdmitUnderBudget(**session) : session.status();
  if (!admitted.ok()) ReleaseLease(robot_id);
  if (session.ok() && !admitted.ok()) {
    // Refused: nothing of it stays, on disk or in memory.
    session->reset();
    std::error_code ec;
    std::filesystem::remove_all(AbsoluteDir(robot_id), ec);
  }
  std::lock_guard<std::mutex> lock(mu_);
  pending_.erase(robot_id);
  if (!admitted.ok()) return admitted;
  std::shared_ptr<Session> shared(std::move(*session));
  sessions_[robot_id] = shared;
  return shared;
}

absl::StatusOr<std::shared_ptr<Session>> SessionManager::Find(const std::string& robot_id) const {
  if (absl::Status s = ValidateRobotId(robot_id); !s.ok()) return s;
  std::lock_guard<std::mutex> lock(mu_);
  auto it = sessions_.find(robot_id);
  if (it == sessions_.end())
    return absl::NotFoundError(absl::StrCat("no session for robot_id ", robot_id));
  return it->second;
}

absl::StatusOr<std::shared_ptr<Session>> SessionManager::Get(const std::string& robot_id) {
  auto found = Find(robot_id);
  if (found.ok() && (*found)->fenced()) {
    // Another replica took the session over: drop it here (what it still had queued was logged
    // before the take-over, so the new owner has it), then answer as for any session held
    // elsewhere.
    std::shared_ptr<Session> gone;
    {
      std::lock_guard<std::mutex> lock(mu_);
      auto it = sessions_.find(robot_id);
      if (it != sessions_.end() && it->second == *found) {
        gone = std::move(it->second);
        sessions_.erase(it);
      }
    }
    if (gone) {
      gone->Close();
      ReleaseLease(robot_id);
    }
    found = absl::NotFoundError(absl::StrCat("no session for robot_id ", robot_id));
  }
  if (found.ok() || !options_.take_over || found.status().code() != absl::StatusCode::kNotFound ||
      stopping_)
    return found;
  // Another replica's session (saved, or left when it died): take it over if its folder holds
  // one. Two calls racing here both try; one loads, the other finds it open (ALREADY_EXISTS).
  std::error_code ec;
  if (!std::filesystem::exists(AbsoluteDir(robot_id) + "/config.rimf", ec)) return found;
  const std::string previous = SessionLease::DescribeOwner(AbsoluteDir(robot_id));
  const auto load_start = std::chrono::steady_clock::now();
  auto loaded = Load(robot_id);
  if (options_.log && (loaded.ok() || loaded.status().code() != absl::StatusCode::kAlreadyExists)) {
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - load_start).count();
    options_.log(loaded.ok() ? absl::StrFormat("session %s taken over (last held by %s): %d "
                                               "frames, opened in %.2f s",
                                               robot_id, previous.empty() ? "nobody" : previous,
                                               (*loaded)->mapper().frames(), seconds)
                             : absl::StrFormat("session %s: take-over failed after %.2f s: %s",
                                               robot_id, seconds, loaded.status().ToString()));
  }
  if (loaded.ok() || loaded.status().code() != absl::StatusCode::kAlreadyExists) return loaded;
  for (int i = 0; i < 600; ++i) {  // the racing load finishes (pending_), then it is open
    auto open = Find(robot_id);
    if (open.ok()) return open;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return loaded;
}

absl::StatusOr<std::shared_ptr<SessionLease>> SessionManager::TakeLease(
    const std::string& robot_id) const {
  auto lease = SessionLease::Acquire(AbsoluteDir(robot_id), options_.replica_id);
  if (!lease.ok()) {
    if (lease.status().code() == absl::StatusCode::kFailedPrecondition)
      return absl::FailedPreconditionError(absl::StrCat(
          "session ", robot_id,
          " is open on another replica: ", SessionLease::DescribeOwner(AbsoluteDir(robot_id)),
          " holds its lease; send the robot's calls there"));
    return lease.status();
  }
  return std::shared_ptr<SessionLease>(std::move(*lease));
}

void SessionManager::ReleaseLease(const std::string& robot_id) {
  std::shared_ptr<SessionLease> lease;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = leases_.find(robot_id);
    if (it == leases_.end()) return;
    lease = std::move(it->second);
    leases_.erase(it);
  }
  lease->Release();
}

std::vector<std::shared_ptr<Session>> SessionManager::List() const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<std::shared_ptr<Session>> out;
  for (const auto& [id, session] : sessions_) out.push_back(session);
  return out;
}

absl::StatusOr<std::unique_ptr<Session>> SessionManager::CreateOnDisk(const std::string& robot_id,
                                                                      const MapperConfig& config,
                                                                      SessionOptions options) {
  RIM_RETURN_IF_ERROR(RefuseLinksToSession(robot_id));
  const std::string dir = AbsoluteDir(robot_id);
  std::error_code ec;
  const bool existed = std::filesystem::exists(dir, ec);
  RIM_RETURN_IF_ERROR(MakeDirs(dir));
  // The folder's lease first: a session another live replica has open is that replica's.
  auto lease = TakeLease(robot_id);
  if (!lease.ok()) {
    if (!existed) std::filesystem::remove_all(dir, ec);
    return lease.status();
  }
  // A folder left by a saved or crashed session is its data: never overwrite it silently.
  if (std::filesystem::exists(dir + "/CURRENT", ec) ||
      std::filesystem::exists(dir + "/config.rimf", ec))
    return absl::FailedPreconditionError(absl::StrCat(
        "robot_id ", robot_id, " has a saved session in the data directory: LoadSession it"));
  options.lease = *lease;
  {
    std::lock_guard<std::mutex> lock(mu_);
    leases_[robot_id] = *lease;  // released by Close, or below when the session is refused
  }
  // The config comes first, so that a crash before any checkpoint can still be replayed.
  RIM_RETURN_IF_ERROR(WriteFileAtomic(dir + "/config.rimf", "CONF", config.ToString()));
  auto wal = WriteAheadLog::Open(dir + "/wal");
  if (!wal.ok()) return wal.status();
  return Session::Create(robot_id, config, options, std::move(*wal));
}

absl::Status SessionManager::SaveLocked(Session& session) {
  return session.Checkpoint(AbsoluteDir(session.robot_id()));
}

absl::Status SessionManager::Close(const std::string& robot_id, bool save) {
  if (absl::Status s = ValidateRobotId(robot_id); !s.ok()) return s;
  std::shared_ptr<Session> session;
  {
    // Found and removed in one step, so that of two concurrent closes (a client retrying) the
    // second is NOT_FOUND rather than closing, saving or deleting the session a second time. The
    // id stays pending until the close is done: a Create or Load of it must not start on the
    // folder this close is still saving or deleting.
    std::lock_guard<std::mutex> lock(mu_);
    auto it = sessions_.find(robot_id);
    if (it == sessions_.end())
      return absl::NotFoundError(absl::StrCat("no session for robot_id ", robot_id));
    session = std::move(it->second);
    sessions_.erase(it);
    pending_[robot_id] = true;
  }
  session->Close();  // drains first: everything accepted is in the map before saving
  absl::Status closed;
  if (save) {
    closed = SaveLocked(*session);
  } else {
    // Closed without saving: the session is discarded, its log and config with it.
    std::error_code ec;
    std::filesystem::remove_all(AbsoluteDir(robot_id), ec);
  }
  ReleaseLease(robot_id);  // another replica may open it from now on
  std::lock_guard<std::mutex> lock(mu_);
  pending_.erase(robot_id);
  return closed;
}

absl::StatusOr<std::string> SessionManager::Save(const std::string& robot_id) {
  auto session = Get(robot_id);
  if (!session.ok()) return session.status();
  if (absl::Status s = SaveLocked(**session); !s.ok()) return s;
  return RelativeDir(robot_id);
}

absl::StatusOr<std::shared_ptr<Session>> SessionManager::Load(const std::string& robot_id) {
  if (absl::Status s = ValidateRobotId(robot_id); !s.ok()) return s;
  if (absl::Status s = RefuseLinksToSession(robot_id); !s.ok()) return s;
  const std::string dir = AbsoluteDir(robot_id);
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (sessions_.count(robot_id) || pending_.count(robot_id))
      return absl::AlreadyExistsError(absl::StrCat("session ", robot_id, " is already open"));
    if (int(sessions_.size() + pending_.size()) >= options_.max_sessions)
      return absl::ResourceExhaustedError(absl::StrCat(
          "session limit reached: ", options_.max_sessions, " sessions (--max-sessions)"));
    std::error_code ec;
    if (!std::filesystem::is_directory(dir, ec))
      return absl::NotFoundError(absl::StrCat("no saved session for robot_id ", robot_id));
    pending_[robot_id] = true;
  }
  // The lease before reading anything: the log must not grow under the replay.
  auto lease = TakeLease(robot_id);
  if (!lease.ok()) {
    std::lock_guard<std::mutex> lock(mu_);
    pending_.erase(robot_id);
    return lease.status();
  }
  std::optional<uint64_t> last_sequence;
  auto restored = Restore(dir, BudgetLeft(), &last_sequence);
  std::shared_ptr<Session> shared;
  absl::Status admitted = restored.status();
  if (restored.ok()) {
    SessionOptions options = MakeSessionOptions(robot_id);
    options.lease = *lease;
    shared =
        Session::Adopt(robot_id, std::move(restored->first), options, std::move(restored->second));
    if (last_sequence) shared->RestoreLastSequence(*last_sequence);
    admitted = AdmitUnderBudget(*shared);
    if (!admitted.ok()) shared.reset();  // the saved session stays on disk, untouched
  }
  if (!admitted.ok()) (*lease)->Release();
  std::lock_guard<std::mutex> lock(mu_);
  pending_.erase(robot_id);
  if (!admitted.ok()) return admitted;
  sessions_[robot_id] = shared;
  leases_[robot_id] = *lease;
  return shared;
}

absl::StatusOr<std::pair<std::unique_ptr<Mapper>, std::unique_ptr<WriteAheadLog>>>
SessionManager::Restore(const std::string& dir, uint64_t max_host_bytes,
                        std::optional<uint64_t>* last_sequence) {
  // The last checkpoint if there is one, else a fresh map from the session's config...
  std::unique_ptr<Mapper> mapper;
  std::error_code ec;
  if (std::filesystem::exists(dir + "/CURRENT", ec)) {
    RIM_ASSIGN_OR_RETURN(mapper, Mapper::Load(dir, max_host_bytes));
  } else {
    RIM_ASSIGN_OR_RETURN(std::string text, ReadFileChecked(dir + "/config.rimf", "CONF"));
    RIM_ASSIGN_OR_RETURN(MapperConfig config, ParseConfigText(text, dir + "/config.rimf"));
    if (max_host_bytes > 0 && Mapper::InitialHostBytes(config) > max_host_bytes)
      return absl::ResourceExhaustedError(absl::StrCat(
          dir, "/config.rimf: the map needs ", Megabytes(Mapper::InitialHostBytes(config)), ", ",
          Megabytes(max_host_bytes), " left of the host memory budget"));
    RIM_ASSIGN_OR_RETURN(mapper, Mapper::Create(config));
  }
  // ...then every scan accepted after it, from the write-ahead log (§5.3: a kill -9 loses no
  // accepted scan). Replay integrates with the configured iterations.
  RIM_ASSIGN_OR_RETURN(std::unique_ptr<WriteAheadLog> wal, WriteAheadLog::Open(dir + "/wal"));
  Mapper* m = mapper.get();
  // The highest sequence accepted: the checkpoint's record of it, then the log's.
  if (std::filesystem::exists(dir + "/" + Session::kSequenceFile, ec)) {
    RIM_ASSIGN_OR_RETURN(std::string text,
                         ReadFileChecked(dir + "/" + Session::kSequenceFile, "SEQN"));
    uint64_t v = 0;
    if (!absl::SimpleAtoi(text, &v))
      return absl::DataLossError(absl::StrCat(dir, "/", Session::kSequenceFile, ": not a number"));
    *last_sequence = v;
  }
  RIM_RETURN_IF_ERROR(wal->Replay(
      uint64_t(m->frames()),
      [m, &dir, last_sequence](uint64_t index, uint64_t sequence, PosedScan scan) -> absl::Status {
        *last_sequence = std::max(last_sequence->value_or(sequence), sequence);
        absl::Status s = m->IntegrateScan(scan);
        if (s.ok()) return s;
        return absl::Status(s.code(),
                            absl::StrCat(dir, "/wal: replaying record ", index, ": ", s.message()));
      }));
  return std::make_pair(std::move(mapper), std::move(wal));
}

absl::Status SessionManager::CloseAll(bool save) {
  std::map<std::string, std::shared_ptr<Session>> sessions;
  {
    std::lock_guard<std::mutex> lock(mu_);
    sessions.swap(sessions_);
  }
  absl::Status first;
  for (auto& [id, session] : sessions) {
    session->Close();
    if (save) {
      absl::Status s = SaveLocked(*session);
      if (!s.ok() && first.ok()) first = s;
    }
    ReleaseLease(id);
  }
  return first;
}

}  // namespace rim::server
