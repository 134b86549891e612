// StreamQuerySdf: batches beyond the unary limit, sent as a stream of requests, each answered in
// order by one response. A bad message ends the stream with its status (INVALID_ARGUMENT naming
// the field, NOT_FOUND for an unknown session, PERMISSION_DENIED for another robot's session); the
// answers already sent stand.
#include "server/service/service.h"
#include "server/service/status_mapping.h"

namespace rim::server {
namespace {

class QueryStreamReactor
    : public grpc::ServerBidiReactor<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse> {
 public:
  QueryStreamReactor(SessionManager* sessions, const ServiceLimits& limits,
                     const Principal& principal, StreamLimiter::Slot slot)
      : sessions_(sessions), limits_(limits), principal_(principal), slot_(std::move(slot)) {
    StartRead(&request_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) {  // the client half-closed: every request has its answer
      Finish(grpc::Status::OK);
      return;
    }
    response_.Clear();
    absl::Status s = CheckRobot(principal_, request_.robot_id());
    if (s.ok()) s = AnswerQuery(*sessions_, limits_, request_, &response_);
    if (!s.ok()) {
      Finish(ToGrpcStatus(s));
      return;
    }
    StartWrite(&response_);
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      Finish(grpc::Status(grpc::StatusCode::CANCELLED, "the client went away"));
      return;
    }
    StartRead(&request_);
  }

  void OnDone() override { delete this; }

 private:
  SessionManager* sessions_;
  const ServiceLimits limits_;
  const Principal principal_;
  rim::v1::QuerySdfRequest request_;
  rim::v1::QuerySdfResponse response_;
  const StreamLimiter::Slot slot_;  // released when the stream is done
};

}  // namespace

grpc::ServerBidiReactor<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse>* NewQueryStreamReactor(
    SessionManager* sessions, const ServiceLimits& limits, const Principal& principal,
    StreamLimiter::Slot slot) {
  return new QueryStreamReactor(sessions, limits, principal, std::move(slot));
}

}  // namespace rim::server
