// The watchers' meshing budget (server/session/meshing_budget.h): a token bucket in CPU-seconds,
// driven here by explicit time points so that the arithmetic is checked exactly, not by timing.
#include <gtest/gtest.h>

#include <chrono>
#include <limits>
#include <thread>

#include "server/session/meshing_budget.h"

namespace rim::server {
namespace {

using Clock = MeshingBudget::Clock;
using std::chrono::milliseconds;

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

TEST(MeshingBudgetTest, DebtIsPaidAtTheBudgetsRateAndCreditIsCappedAtTheBurst) {
  MeshingBudget budget(0.5, /*burst_s=*/1.0);  // 0.5 CPU-seconds per second, 0.5 s of credit
  ASSERT_TRUE(budget.limited());
  const Clock::time_point t0 = Clock::now();
  EXPECT_EQ(budget.Delay(t0), Clock::duration::zero());  // starts with its burst
  // 0.5 s of credit, 0.8 s spent: 0.3 s in debt, paid after 0.6 s at 0.5 cores.
  budget.Charge(0.8, t0);
  EXPECT_NEAR(Seconds(budget.Delay(t0)), 0.6, 1e-6);
  EXPECT_NEAR(Seconds(budget.Delay(t0 + milliseconds(400))), 0.2, 1e-6);
  EXPECT_EQ(budget.Delay(t0 + milliseconds(600)), Clock::duration::zero());
  // A long idle spell saves no more than the burst: after 10 s, 0.5 s of credit, not 5.
  const Clock::time_point t1 = t0 + std::chrono::seconds(10);
  EXPECT_EQ(budget.Delay(t1), Clock::duration::zero());
  budget.Charge(0.6, t1);
  EXPECT_NEAR(Seconds(budget.Delay(t1)), 0.2, 1e-6);
  // Time never runs backwards for the bucket: an earlier time point refills nothing.
  EXPECT_NEAR(Seconds(budget.Delay(t0)), 0.2, 1e-6);
  // Nothing, or nonsense, charged changes nothing.
  budget.Charge(0.0, t1);
  budget.Charge(-5.0, t1);
  budget.Charge(std::numeric_limits<double>::quiet_NaN(), t1);
  EXPECT_NEAR(Seconds(budget.Delay(t1)), 0.2, 1e-6);
}

TEST(MeshingBudgetTest, ZeroOrNegativeCoresMeansNoBudget) {
  for (double cores : {0.0, -1.0}) {
    MeshingBudget budget(cores);
    EXPECT_FALSE(budget.limited());
    budget.Charge(100.0);
    EXPECT_EQ(budget.Delay(), Clock::duration::zero());
  }
}

TEST(MeshingBudgetTest, ThreadCpuTimeCountsWorkAndNotSleep) {
  const double start = ThreadCpuSeconds();
  std::this_thread::sleep_for(milliseconds(50));
  const double slept = ThreadCpuSeconds() - start;
  EXPECT_LT(slept, 0.02);  // sleeping uses (next to) no CPU
  volatile double x = 0;
  const double work_start = ThreadCpuSeconds();
  while (ThreadCpuSeconds() - work_start < 0.02) x = x + 1;
  EXPECT_GE(ThreadCpuSeconds() - work_start, 0.02);
}

}  // namespace
}  // namespace rim::server
