#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "server/service/status_mapping.h"

namespace rim::server {
namespace {

struct CodePair {
  absl::StatusCode absl_code;
  grpc::StatusCode grpc_code;
};

// The contract, written out independently of the implementation.
const std::vector<CodePair>& AllCodes() {
  static const std::vector<CodePair> pairs = {
      {absl::StatusCode::kOk, grpc::StatusCode::OK},
      {absl::StatusCode::kCancelled, grpc::StatusCode::CANCELLED},
      {absl::StatusCode::kUnknown, grpc::StatusCode::UNKNOWN},
      {absl::StatusCode::kInvalidArgument, grpc::StatusCode::INVALID_ARGUMENT},
      {absl::StatusCode::kDeadlineExceeded, grpc::StatusCode::DEADLINE_EXCEEDED},
      {absl::StatusCode::kNotFound, grpc::StatusCode::NOT_FOUND},
      {absl::StatusCode::kAlreadyExists, grpc::StatusCode::ALREADY_EXISTS},
      {absl::StatusCode::kPermissionDenied, grpc::StatusCode::PERMISSION_DENIED},
      {absl::StatusCode::kResourceExhausted, grpc::StatusCode::RESOURCE_EXHAUSTED},
      {absl::StatusCode::kFailedPrecondition, grpc::StatusCode::FAILED_PRECONDITION},
      {absl::StatusCode::kAborted, grpc::StatusCode::ABORTED},
      {absl::StatusCode::kOutOfRange, grpc::StatusCode::OUT_OF_RANGE},
      {absl::StatusCode::kUnimplemented, grpc::StatusCode::UNIMPLEMENTED},
      {absl::StatusCode::kInternal, grpc::StatusCode::INTERNAL},
      {absl::StatusCode::kUnavailable, grpc::StatusCode::UNAVAILABLE},
      {absl::StatusCode::kDataLoss, grpc::StatusCode::DATA_LOSS},
      {absl::StatusCode::kUnauthenticated, grpc::StatusCode::UNAUTHENTICATED},
  };
  return pairs;
}

TEST(StatusMappingTest, TableCoversEveryCanonicalCode) {
  // google.rpc.Code defines 0..16; the table must hold each exactly once.
  ASSERT_EQ(AllCodes().size(), 17u);
  for (int raw = 0; raw <= 16; ++raw) {
    int found = 0;
    for (const CodePair& p : AllCodes()) found += static_cast<int>(p.absl_code) == raw;
    EXPECT_EQ(found, 1) << "absl code " << raw;
  }
}

TEST(StatusMappingTest, OkMapsToOk) {
  EXPECT_TRUE(ToGrpcStatus(absl::OkStatus()).ok());
  EXPECT_TRUE(FromGrpcStatus(grpc::Status::OK).ok());
}

TEST(StatusMappingTest, EveryErrorCodeMapsToItsGrpcCodeWithMessage) {
  for (const CodePair& p : AllCodes()) {
    if (p.absl_code == absl::StatusCode::kOk) continue;
    const std::string message = "session 'r1': " + absl::StatusCodeToString(p.absl_code);
    const grpc::Status g = ToGrpcStatus(absl::Status(p.absl_code, message));
    EXPECT_EQ(g.error_code(), p.grpc_code) << absl::StatusCodeToString(p.absl_code);
    EXPECT_EQ(g.error_message(), message);
  }
}

TEST(StatusMappingTest, EveryGrpcErrorCodeMapsBackWithMessage) {
  for (const CodePair& p : AllCodes()) {
    if (p.grpc_code == grpc::StatusCode::OK) continue;
    const std::string message = "points[17].x is NaN";
    const absl::Status s = FromGrpcStatus(grpc::Status(p.grpc_code, message));
    EXPECT_EQ(s.code(), p.absl_code) << static_cast<int>(p.grpc_code);
    EXPECT_EQ(s.message(), message);
  }
}

TEST(StatusMappingTest, EveryCodeRoundTrips) {
  for (const CodePair& p : AllCodes()) {
    const absl::Status original(p.absl_code, "why: \"quoted\", unicode \xC3\xA9, newline\nend");
    const absl::Status back = FromGrpcStatus(ToGrpcStatus(original));
    EXPECT_EQ(back, original) << absl::StatusCodeToString(p.absl_code);
  }
}

TEST(StatusMappingTest, EmptyMessageIsKept) {
  const grpc::Status g = ToGrpcStatus(absl::Status(absl::StatusCode::kInternal, ""));
  EXPECT_EQ(g.error_code(), grpc::StatusCode::INTERNAL);
  EXPECT_EQ(g.error_message(), "");
}

TEST(StatusMappingTest, OutOfRangeAbslCodeBecomesUnknown) {
  for (int raw : {17, 42, 1000, -1}) {
    const absl::Status s(static_cast<absl::StatusCode>(raw), "from the future");
    const grpc::Status g = ToGrpcStatus(s);
    EXPECT_EQ(g.error_code(), grpc::StatusCode::UNKNOWN) << raw;
    EXPECT_EQ(g.error_message(), "from the future");
  }
}

TEST(StatusMappingTest, OutOfRangeGrpcCodeBecomesUnknown) {
  // 31 is the largest code a peer can hand over: grpc::StatusCode has no fixed underlying type,
  // so values beyond its enumerators' bits (-32..31) cannot be made without undefined behaviour.
  for (grpc::StatusCode code : {grpc::StatusCode::DO_NOT_USE, static_cast<grpc::StatusCode>(17),
                                static_cast<grpc::StatusCode>(31)}) {
    const absl::Status s = FromGrpcStatus(grpc::Status(code, "odd peer"));
    EXPECT_EQ(s.code(), absl::StatusCode::kUnknown) << static_cast<int>(code);
    EXPECT_EQ(s.message(), "odd peer");
  }
}

}  // namespace
}  // namespace rim::server
