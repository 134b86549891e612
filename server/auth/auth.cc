#include "server/auth/auth.h"

#include <grpcpp/server_context.h>
#include <openssl/crypto.h>
#include <openssl/sha.h>

#include <fstream>
#include <set>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "server/session/session_manager.h"

namespace rim::server {
namespace {

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  c = absl::ascii_tolower(c);
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

bool ParseDigest(absl::string_view hex, std::array<uint8_t, 32>* out) {
  if (hex.size() != 64) return false;
  for (size_t i = 0; i < 32; ++i) {
    const int hi = HexValue(hex[2 * i]), lo = HexValue(hex[2 * i + 1]);
    if (hi < 0 || lo < 0) return false;
    (*out)[i] = uint8_t(hi * 16 + lo);
  }
  return true;
}

std::array<uint8_t, 32> Sha256(absl::string_view data) {
  std::array<uint8_t, 32> digest{};
  SHA256(reinterpret_cast<const unsigned char*>(data.data()), data.size(), digest.data());
  return digest;
}

bool ParseRole(absl::string_view name, Role* role) {
  if (name == "robot") {
    *role = Role::kRobot;
  } else if (name == "viewer") {
    *role = Role::kViewer;
  } else if (name == "admin") {
    *role = Role::kAdmin;
  } else {
    return false;
  }
  return true;
}

}  // namespace

const char* RoleName(Role role) {
  switch (role) {
    case Role::kRobot:
      return "robot";
    case Role::kViewer:
      return "viewer";
    case Role::kAdmin:
      return "admin";
  }
  return "unknown";
}

const char* RpcName(Rpc rpc) {
  switch (rpc) {
    case Rpc::kCreateSession:
      return "CreateSession";
    case Rpc::kGetSession:
      return "GetSession";
    case Rpc::kListSessions:
      return "ListSessions";
    case Rpc::kCloseSession:
      return "CloseSession";
    case Rpc::kSaveSession:
      return "SaveSession";
    case Rpc::kLoadSession:
      return "LoadSession";
    case Rpc::kStreamScans:
      return "StreamScans";
    case Rpc::kQuerySdf:
      return "QuerySdf";
    case Rpc::kStreamQuerySdf:
      return "StreamQuerySdf";
    case Rpc::kGetMeshTiles:
      return "GetMeshTiles";
    case Rpc::kWatchMeshTiles:
      return "WatchMeshTiles";
    case Rpc::kGetServerInfo:
      return "GetServerInfo";
  }
  return "unknown";
}

bool RoleAllows(Role role, Rpc rpc) {
  switch (role) {
    case Role::kAdmin:
      return true;
    case Role::kViewer:
      return rpc == Rpc::kQuerySdf || rpc == Rpc::kStreamQuerySdf || rpc == Rpc::kGetMeshTiles ||
             rpc == Rpc::kWatchMeshTiles || rpc == Rpc::kGetSession || rpc == Rpc::kListSessions ||
             rpc == Rpc::kGetServerInfo;
    case Role::kRobot:
      // Its own session's life and data; loading, closing and listing are for operators.
      return rpc == Rpc::kCreateSession || rpc == Rpc::kGetSession || rpc == Rpc::kStreamScans ||
             rpc == Rpc::kQuerySdf || rpc == Rpc::kStreamQuerySdf || rpc == Rpc::kGetMeshTiles ||
             rpc == Rpc::kWatchMeshTiles || rpc == Rpc::kSaveSession || rpc == Rpc::kGetServerInfo;
  }
  return false;
}

std::string HashToken(absl::string_view token) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string hex;
  for (uint8_t byte : Sha256(token)) {
    hex.push_back(kHex[byte >> 4]);
    hex.push_back(kHex[byte & 15]);
  }
  return hex;
}

absl::StatusOr<std::vector<TokenEntry>> ParseTokens(absl::string_view text,
                                                    absl::string_view origin) {
  std::vector<TokenEntry> entries;
  std::set<std::array<uint8_t, 32>> seen;
  int line_no = 0;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    ++line_no;
    line = line.substr(0, line.find('#'));
    const std::vector<absl::string_view> fields =
        absl::StrSplit(line, absl::ByAnyChar(" \t\r"), absl::SkipEmpty());
    if (fields.empty()) continue;
    const std::string where = absl::StrCat(origin, ":", line_no, ": ");
    if (fields.size() != 3)
      return absl::InvalidArgumentError(
          absl::StrCat(where, "expected 'ROLE SUBJECT SHA256HEX', got ", fields.size(), " fields"));
    TokenEntry entry;
    if (!ParseRole(fields[0], &entry.role))
      return absl::InvalidArgumentError(
          absl::StrCat(where, "unknown role '", fields[0], "' (robot, viewer or admin)"));
    entry.subject = std::string(fields[1]);
    if (entry.role == Role::kRobot) {
      const absl::Status id = ValidateRobotId(entry.subject);
      if (!id.ok()) return absl::InvalidArgumentError(absl::StrCat(where, id.message()));
    }
    if (!ParseDigest(fields[2], &entry.sha256))
      return absl::InvalidArgumentError(absl::StrCat(
          where, "the digest must be 64 hex digits (rim_server --hash-token TOKEN prints it)"));
    if (!seen.insert(entry.sha256).second)
      return absl::InvalidArgumentError(
          absl::StrCat(where, "this token's digest is already on an earlier line"));
    entries.push_back(std::move(entry));
  }
  // Most likely the wrong file; a server that nobody may call is not what anyone asked for.
  if (entries.empty()) return absl::InvalidArgumentError(absl::StrCat(origin, ": holds no tokens"));
  return entries;
}

absl::StatusOr<std::vector<TokenEntry>> ReadTokensFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("--tokens: cannot read ", path));
  std::stringstream text;
  text << in.rdbuf();
  return ParseTokens(text.str(), path);
}

absl::Status CheckRobot(const Principal& principal, absl::string_view robot_id) {
  if (principal.role != Role::kRobot || robot_id == principal.subject) return absl::OkStatus();
  return absl::PermissionDeniedError(absl::StrCat("the token of robot '", principal.subject,
                                                  "' may not act on robot '", robot_id, "'"));
}

Authorizer::Authorizer(std::vector<TokenEntry> tokens)
    : enabled_(true), tokens_(std::move(tokens)) {}

size_t Authorizer::CountRole(Role role) const {
  size_t n = 0;
  for (const TokenEntry& t : tokens_) n += t.role == role ? 1 : 0;
  return n;
}

absl::StatusOr<Principal> Authorizer::Authenticate(const std::string* authorization) const {
  if (!enabled_) return Principal{Role::kAdmin, ""};
  if (authorization == nullptr)
    return absl::UnauthenticatedError("this server needs a token: 'authorization: Bearer <token>'");
  constexpr absl::string_view kScheme = "bearer ";
  if (authorization->size() <= kScheme.size() ||
      !absl::StartsWithIgnoreCase(*authorization, kScheme))
    return absl::UnauthenticatedError("the authorization header must be 'Bearer <token>'");
  const std::array<uint8_t, 32> digest =
      Sha256(absl::string_view(*authorization).substr(kScheme.size()));
  // Every line is compared, in constant time, so that timing tells nothing about the digests.
  const TokenEntry* match = nullptr;
  for (const TokenEntry& entry : tokens_) {
    if (CRYPTO_memcmp(entry.sha256.data(), digest.data(), digest.size()) == 0) match = &entry;
  }
  if (match == nullptr) return absl::UnauthenticatedError("unknown token");
  return Principal{match->role, match->subject};
}

absl::StatusOr<Principal> Authorizer::Authorize(const grpc::ServerContextBase& ctx, Rpc rpc) const {
  if (!enabled_) return Principal{Role::kAdmin, ""};
  const auto& metadata = ctx.client_metadata();
  const auto it = metadata.find("authorization");
  std::string header;
  if (it != metadata.end()) header.assign(it->second.data(), it->second.size());
  absl::StatusOr<Principal> principal = Authenticate(it == metadata.end() ? nullptr : &header);
  if (!principal.ok()) return principal.status();
  if (!RoleAllows(principal->role, rpc))
    return absl::PermissionDeniedError(
        absl::StrCat("a ", RoleName(principal->role), " token may not call ", RpcName(rpc)));
  return principal;
}

absl::Status Authorizer::Authorize(const grpc::ServerContextBase& ctx, Rpc rpc,
                                   absl::string_view robot_id) const {
  absl::StatusOr<Principal> principal = Authorize(ctx, rpc);
  if (!principal.ok()) return principal.status();
  return CheckRobot(*principal, robot_id);
}

}  // namespace rim::server
