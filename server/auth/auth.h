// rim_server's access control (docs/security.md). With --tokens FILE every rim.v1 call carries
// `authorization: Bearer <token>`; the file maps the SHA-256 of each token (never the token) to a
// role: a robot acts on its own session only, a viewer reads, an admin does everything. Every
// handler authorizes first, before it touches a session, so a refused call changes nothing and
// does not tell whether a session exists. Health checking and reflection stay open: probes carry
// no tokens. Without --tokens the Authorizer is open and every call is allowed.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace grpc {
class ServerContextBase;
}

namespace rim::server {

enum class Role { kRobot, kViewer, kAdmin };
const char* RoleName(Role role);

// The rim.v1.Rim methods, for the role table.
enum class Rpc {
  kCreateSession,
  kGetSession,
  kListSessions,
  kCloseSession,
  kSaveSession,
  kLoadSession,
  kStreamScans,
  kQuerySdf,
  kStreamQuerySdf,
  kGetMeshTiles,
  kWatchMeshTiles,
  kGetServerInfo,
};
const char* RpcName(Rpc rpc);

// The role table of docs/security.md: whether `role` may call `rpc` at all. A robot may call its
// methods only about its own robot id (CheckRobot).
bool RoleAllows(Role role, Rpc rpc);

// Who a call comes from: the role and subject of its token's line.
struct Principal {
  Role role = Role::kAdmin;
  std::string subject;  // robot id for a robot; a name for a viewer or admin
};

// One line of the tokens file: `ROLE SUBJECT SHA256HEX`.
struct TokenEntry {
  Role role = Role::kViewer;
  std::string subject;
  std::array<uint8_t, 32> sha256{};
};

// Lower-case hex SHA-256 of `token` (what a tokens file line stores; rim_server --hash-token).
std::string HashToken(absl::string_view token);

// Parses a tokens file: lines `ROLE SUBJECT SHA256HEX`, '#' comments, blank lines ignored.
// INVALID_ARGUMENT naming `origin` and the line for an unknown role, a robot subject that is not
// a valid robot id, a digest that is not 64 hex digits, a digest given twice, or no tokens.
absl::StatusOr<std::vector<TokenEntry>> ParseTokens(absl::string_view text,
                                                    absl::string_view origin);
// Reads and parses the file at `path` (NOT_FOUND when it cannot be read).
absl::StatusOr<std::vector<TokenEntry>> ReadTokensFile(const std::string& path);

// PERMISSION_DENIED unless `principal` may act on `robot_id`: a robot only on its own id, viewers
// and admins on any (whether a viewer may call the method at all is RoleAllows' business).
absl::Status CheckRobot(const Principal& principal, absl::string_view robot_id);

class Authorizer {
 public:
  // Open: no --tokens, every call allowed as an admin.
  Authorizer() = default;
  explicit Authorizer(std::vector<TokenEntry> tokens);

  bool enabled() const { return enabled_; }
  size_t CountRole(Role role) const;

  // The principal of an `authorization` header value ("Bearer <token>"; nullptr: no header).
  // UNAUTHENTICATED for a missing header, another scheme, or a token not in the file. The digest
  // is compared with every line in constant time.
  absl::StatusOr<Principal> Authenticate(const std::string* authorization) const;

  // Authenticates the call and checks that its role may call `rpc`: the principal, or
  // UNAUTHENTICATED, or PERMISSION_DENIED naming the role and the method.
  absl::StatusOr<Principal> Authorize(const grpc::ServerContextBase& ctx, Rpc rpc) const;
  // The same, and CheckRobot for a call about one session.
  absl::Status Authorize(const grpc::ServerContextBase& ctx, Rpc rpc,
                         absl::string_view robot_id) const;

 private:
  bool enabled_ = false;
  std::vector<TokenEntry> tokens_;
};

}  // namespace rim::server
