// One writer per session folder: the lease (server/session/session_lease.h) and the session
// manager's use of it when replicas share a data dir. A live holder keeps others out and is named
// to them; a dead one's lease is free at once; a forged or stale lease file counts for nothing; a
// holder whose lease was replaced is fenced off; a replica opens (takes over) a session that no
// live replica holds, and knows the highest scan sequence it had accepted.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "server/session/session_lease.h"
#include "server/session/session_manager.h"
#include "support/small_session.h"
#include "support/temp_dir.h"

namespace rim::server {
namespace {

using ::testing::HasSubstr;

std::string ReadAll(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

TEST(SessionLeaseTest, ALiveHolderKeepsOthersOutAndIsNamed) {
  const std::string dir = testing_support::MakeTempDir("rim_lease_live");
  auto a = SessionLease::Acquire(dir, "replica-a");
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ((*a)->epoch(), 1u);
  EXPECT_TRUE((*a)->Check().ok());
  EXPECT_THAT(ReadAll(dir + "/LEASE"), HasSubstr("owner=replica-a\n"));
  auto b = SessionLease::Acquire(dir, "replica-b");
  ASSERT_FALSE(b.ok());
  EXPECT_EQ(b.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(b.status().message()), HasSubstr("replica replica-a"));
  EXPECT_TRUE((*a)->Check().ok());  // the refused attempt changed nothing
  a->reset();
  auto c = SessionLease::Acquire(dir, "replica-c");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ((*c)->epoch(), 2u);
  (*c)->Release();
  EXPECT_EQ((*c)->Check().code(), absl::StatusCode::kFailedPrecondition);
}

TEST(SessionLeaseTest, ADeadHoldersLeaseIsFreeAtOnce) {
  const std::string dir = testing_support::MakeTempDir("rim_lease_dead");
  int ready[2];
  ASSERT_EQ(pipe(ready), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    auto lease = SessionLease::Acquire(dir, "replica-dies");
    const char c = lease.ok() ? 'y' : 'n';
    if (write(ready[1], &c, 1) != 1) _exit(2);
    pause();  // holds the lease until killed
    _exit(0);
  }
  char c = 0;
  ASSERT_EQ(read(ready[0], &c, 1), 1);
  ASSERT_EQ(c, 'y');
  auto refused = SessionLease::Acquire(dir, "replica-b");
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(refused.status().message()), HasSubstr("replica-dies"));
  kill(child, SIGKILL);  // kill -9: no chance to release anything
  int status = 0;
  waitpid(child, &status, 0);
  auto taken = SessionLease::Acquire(dir, "replica-b");
  ASSERT_TRUE(taken.ok()) << taken.status();
  EXPECT_EQ((*taken)->epoch(), 2u);
  close(ready[0]);
  close(ready[1]);
}

TEST(SessionLeaseTest, AForgedOrStaleLeaseFileCountsForNothing) {
  const std::string dir = testing_support::MakeTempDir("rim_lease_forged");
  {
    std::ofstream out(dir + "/LEASE");
    out << "owner=somebody-else\nepoch=41\ntoken=0123\nsince=1\n";
  }
  auto lease = SessionLease::Acquire(dir, "replica-a");
  ASSERT_TRUE(lease.ok()) << lease.status();
  EXPECT_EQ((*lease)->epoch(), 42u);
  EXPECT_THAT(ReadAll(dir + "/LEASE"), HasSubstr("owner=replica-a\n"));
  // Rewriting the file by hand while it is held fences the holder instead of adding a writer.
  {
    std::ofstream out(dir + "/LEASE");
    out << "owner=forger\nepoch=99\ntoken=feed\n";
  }
  const absl::Status fenced = (*lease)->Check();
  EXPECT_EQ(fenced.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(fenced.message()), HasSubstr("fenced: forger"));
}

TEST(SessionLeaseTest, AHolderWhoseLeaseWasReplacedIsFenced) {
  const std::string dir = testing_support::MakeTempDir("rim_lease_fence");
  auto a = SessionLease::Acquire(dir, "replica-a");
  ASSERT_TRUE(a.ok());
  // The file removed and made anew (as a lost NFS lock would allow): a second holder gets in...
  std::filesystem::remove(dir + "/LEASE");
  auto b = SessionLease::Acquire(dir, "replica-b");
  ASSERT_TRUE(b.ok()) << b.status();
  // ...and the first one stops at its next write.
  const absl::Status fenced = (*a)->Check();
  EXPECT_EQ(fenced.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(fenced.message()), HasSubstr("replica-b has taken the session over"));
  EXPECT_TRUE((*b)->Check().ok());
}

SessionManagerOptions Replica(const std::string& data_dir, const std::string& name) {
  SessionManagerOptions options;
  options.data_dir = data_dir;
  options.replica_id = name;
  options.take_over = true;
  return options;
}

TEST(SessionManagerSharingTest, OneReplicaAtATimeAndTakeOverOfWhatIsFree) {
  const std::string data = testing_support::MakeTempDir("rim_shared_sessions");
  SessionManager a(Replica(data, "rim-a"));
  SessionManager b(Replica(data, "rim-b"));
  auto created = a.Create("robot_s", "", testing_support::SmallMapOverrides());
  ASSERT_TRUE(created.ok()) << created.status();
  for (int i = 0; i < 3; ++i)
    ASSERT_TRUE(
        (*created)->Submit(uint64_t(10 + i), testing_support::GroundScan(0.05 * i), nullptr).ok());
  EXPECT_TRUE((*created)->Accepted(12));
  EXPECT_FALSE((*created)->Accepted(13));
  created->reset();

  // Open on a: b neither creates, loads nor takes it over, and names a.
  for (const absl::Status& s :
       {b.Get("robot_s").status(), b.Load("robot_s").status(),
        b.Create("robot_s", "", testing_support::SmallMapOverrides()).status()}) {
    EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
    EXPECT_THAT(std::string(s.message()), HasSubstr("rim-a")) << s;
  }
  // a lets go (saved): b's next call about it opens it, with a's scans, and the sequence.
  ASSERT_TRUE(a.Close("robot_s", /*save=*/true).ok());
  auto taken = b.Get("robot_s");
  ASSERT_TRUE(taken.ok()) << taken.status();
  EXPECT_EQ((*taken)->mapper().frames(), 3);
  EXPECT_TRUE((*taken)->Accepted(12));
  EXPECT_FALSE((*taken)->Accepted(13));
  // Now a is the outsider.
  const absl::Status back = a.Get("robot_s").status();
  EXPECT_EQ(back.code(), absl::StatusCode::kFailedPrecondition) << back;
  EXPECT_THAT(std::string(back.message()), HasSubstr("rim-b"));
  // Without take_over a replica answers NOT_FOUND, as a single server always did.
  SessionManagerOptions plain = Replica(data, "rim-c");
  plain.take_over = false;
  SessionManager c(plain);
  EXPECT_EQ(c.Get("robot_s").status().code(), absl::StatusCode::kNotFound);
}

TEST(SessionManagerSharingTest, AFencedReplicaStopsWritingAndDropsTheSession) {
  const std::string data = testing_support::MakeTempDir("rim_shared_fenced");
  SessionManager a(Replica(data, "rim-a"));
  auto created = a.Create("robot_f", "", testing_support::SmallMapOverrides());
  ASSERT_TRUE(created.ok()) << created.status();
  ASSERT_TRUE((*created)->Submit(0, testing_support::GroundScan(0.0), nullptr).ok());
  // a's lock is lost without a noticing (as a stale NFS lock would be): another replica makes the
  // lease file anew and holds it.
  const std::string dir = data + "/sessions/robot_f";
  std::filesystem::remove(dir + "/LEASE");
  auto b = SessionLease::Acquire(dir, "rim-b");
  ASSERT_TRUE(b.ok()) << b.status();
  const absl::Status refused = (*created)->Submit(1, testing_support::GroundScan(0.05), nullptr);
  EXPECT_EQ(refused.code(), absl::StatusCode::kFailedPrecondition) << refused;
  EXPECT_THAT(std::string(refused.message()), HasSubstr("fenced: rim-b"));
  EXPECT_TRUE((*created)->fenced());
  EXPECT_FALSE((*created)->Accepted(1));
  created->reset();
  // a's next call about it drops the session and names the owner.
  const absl::Status now = a.Get("robot_f").status();
  EXPECT_EQ(now.code(), absl::StatusCode::kFailedPrecondition) << now;
  EXPECT_THAT(std::string(now.message()), HasSubstr("rim-b"));
  EXPECT_TRUE(a.List().empty());
}

TEST(SessionManagerSharingTest, TheHighestSequenceSurvivesACheckpointThatEmptiesTheLog) {
  const std::string data = testing_support::MakeTempDir("rim_shared_sequence");
  {
    SessionManager a(Replica(data, "rim-a"));
    auto created = a.Create("robot_q", "", testing_support::SmallMapOverrides());
    ASSERT_TRUE(created.ok()) << created.status();
    for (int i = 0; i < 2; ++i)
      ASSERT_TRUE(
          (*created)->Submit(uint64_t(7 + i), testing_support::GroundScan(0.05 * i), nullptr).ok());
    (*created)->Drain();
    created->reset();
    ASSERT_TRUE(a.Save("robot_q").ok());  // checkpoint: the log's records are dropped
  }  // a goes away without closing the session properly, as a killed replica would
  SessionManager b(Replica(data, "rim-b"));
  auto taken = b.Get("robot_q");
  ASSERT_TRUE(taken.ok()) << taken.status();
  EXPECT_EQ((*taken)->mapper().frames(), 2);
  EXPECT_TRUE((*taken)->Accepted(8));
  EXPECT_FALSE((*taken)->Accepted(9));
}

}  // namespace
}  // namespace rim::server
