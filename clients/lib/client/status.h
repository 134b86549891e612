// gRPC status -> absl::Status for the client library: callers of rim::Client see the same code
// the server chose (both enumerate google.rpc.Code) and a message that says which call failed.
#pragma once

#include <grpcpp/support/status.h>

#include "absl/status/status.h"
#include "absl/strings/string_view.h"

namespace rim {

// The absl::Status with the same code and message as `status`. A code outside google.rpc.Code
// becomes UNKNOWN (message kept), so a failure can never read as OK.
absl::Status FromGrpc(const grpc::Status& status);

// FromGrpc with `what` (e.g. "GetSession robot_1") put in front of the message, so that an error
// printed far from the call still says where it came from. OK stays OK.
absl::Status FromGrpc(const grpc::Status& status, absl::string_view what);

}  // namespace rim
