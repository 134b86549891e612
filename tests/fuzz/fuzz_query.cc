// Queries as QuerySdf and StreamQuerySdf receive them: bytes parsed as rim.v1.QuerySdfRequest and
// answered by AnswerQuery (service.cc), the function both handlers call, on a session trained once
// per process on the ground scans the server tests use. NaN, infinite and far-away points, odd
// byte counts and oversized batches must all be clear errors; answers must have one value per
// point.
#include <cmath>
#include <cstring>

#include "fuzz_session.h"
#include "support/small_session.h"

namespace {

// Static objects, not leaked ones: at exit the session manager closes the session and the
// scratch directory goes.
rim::fuzz::FuzzService& Service() {
  static rim::fuzz::FuzzService service("rim_fuzz_query");
  static const bool trained = [] {
    auto session =
        service.sessions.Create(rim::fuzz::kRobot, "", rim::testing_support::SmallMapOverrides());
    RIM_FUZZ_CHECK(session.ok());
    // Far enough along x that the box slides and sub-maps other than the first hold data.
    for (int i = 0; i < 6; ++i)
      RIM_FUZZ_CHECK((*session)->Submit(i, rim::testing_support::GroundScan(0.9 * i), {}).ok());
    (*session)->Drain();
    return (*session)->Stats().integrated == 6;
  }();
  RIM_FUZZ_CHECK(trained);
  return service;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  rim::fuzz::FuzzService& service = Service();
  rim::v1::QuerySdfRequest request;
  if (!request.ParseFromArray(data, int(size))) return 0;
  if (request.robot_id().empty()) request.set_robot_id(rim::fuzz::kRobot);
  rim::v1::QuerySdfResponse response;
  const absl::Status s =
      rim::server::AnswerQuery(service.sessions, service.limits, request, &response);
  if (!s.ok()) {
    RIM_FUZZ_CHECK(s.code() == absl::StatusCode::kInvalidArgument ||
                   s.code() == absl::StatusCode::kNotFound ||
                   s.code() == absl::StatusCode::kResourceExhausted);
    RIM_FUZZ_CHECK(!s.message().empty());
    return 0;
  }
  const size_t n = request.points_xyz().size() / 12;
  RIM_FUZZ_CHECK(request.points_xyz().size() % 12 == 0 && n > 0);
  RIM_FUZZ_CHECK(response.sdf().size() == 4 * n && response.observed().size() == n);
  RIM_FUZZ_CHECK(response.gradient().size() == (request.want_gradient() ? 12 * n : 0));
  for (size_t i = 0; i < n; ++i) {
    float sdf;
    std::memcpy(&sdf, response.sdf().data() + 4 * i, 4);
    // Every point was finite and within 1e6 m, and the trained decoder is finite there.
    RIM_FUZZ_CHECK(std::isfinite(sdf));
    RIM_FUZZ_CHECK(response.observed()[i] == 0 || response.observed()[i] == 1);
  }
  return 0;
}
