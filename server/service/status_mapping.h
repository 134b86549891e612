// The one mapping between core absl::Status codes and gRPC status codes (DESIGN.md §5.2): every
// handler converts its result here, so a code means the same thing at every RPC.
#pragma once

#include <grpcpp/support/status.h>

#include "absl/status/status.h"

namespace rim::server {

// Maps each absl::StatusCode to the grpc::StatusCode of the same meaning (both enumerate
// google.rpc.Code) and keeps the message. A code outside the known set (e.g. a value cast from a
// newer library) becomes UNKNOWN with the message kept, so a client never sees OK for a failure.
grpc::Status ToGrpcStatus(const absl::Status& status);

// The inverse of ToGrpcStatus, for clients and tests that call the service and want core types.
// An unknown grpc code becomes absl UNKNOWN with the message kept.
absl::Status FromGrpcStatus(const grpc::Status& status);

}  // namespace rim::server
