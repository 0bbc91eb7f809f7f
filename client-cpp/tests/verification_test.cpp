// Job: server tests of ReportVerification: a verdict goes through the
// ordered write queue (reported right after the inserts it names, it is
// stored after them), Stats counts it, reporting the same pair again
// replaces it, and a verdict naming a keyframe the server does not hold is
// refused with NOT_FOUND through the write's result and on_write_failed,
// without stalling the queue.
#include <gtest/gtest.h>

#include <mutex>
#include <vector>

#include "humem/humem.h"
#include "humem_server.h"
#include "test_data.h"

namespace humem_test {
namespace {

using humem::StatusCode;
using humem::Verification;
using humem::VerificationKind;
using humem::WriteState;

class VerificationTest : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_TRUE(server_.Start()) << server_.error(); }

  TempDir dir_;
  HumemServer server_{dir_.path()};
};

TEST_F(VerificationTest, AVerdictReportedRightAfterItsInsertsIsStoredAndCounted) {
  auto client = Connect(server_);
  // Nothing waits here: each verdict is queued behind the inserts of the
  // keyframes it names, so the server holds them when it arrives.
  for (uint64_t id = 0; id < 6; ++id) client->Insert(MakeKeyframe(id, 0));
  Verification accepted;
  accepted.keyframe_id = 5;
  accepted.candidate_keyframe_id = 1;
  accepted.kind = VerificationKind::kLoop;
  accepted.accepted = true;
  accepted.relative = humem::RelativeTransform(humem::Pose(humem::Vec3(0.5, 0, 0), humem::Quaternion()), 1.0);
  accepted.score = 0.8f;
  accepted.inliers = 40;
  const humem::WriteResult queued = client->ReportVerification(accepted);
  EXPECT_EQ(queued.state, WriteState::kQueued);
  EXPECT_TRUE(queued.status.ok()) << queued.status.ToString();
  EXPECT_GT(queued.sequence, 0u);

  Verification rejected;
  rejected.keyframe_id = 5;
  rejected.candidate_keyframe_id = 2;
  rejected.kind = VerificationKind::kLoop;
  rejected.accepted = false;
  const humem::WriteResult second = client->ReportVerification(rejected, Ms(10000));
  ASSERT_EQ(second.state, WriteState::kApplied) << second.status.ToString();
  EXPECT_FALSE(second.replaced);
  EXPECT_EQ(second.store_verdicts, 2u);
  EXPECT_GT(second.sequence, queued.sequence);

  humem::StoreStats stats;
  ASSERT_TRUE(client->Stats(&stats).ok());
  EXPECT_EQ(stats.verdicts, 2u);
  EXPECT_EQ(stats.keyframes, 6u);

  // A verdict made from a candidate HuMem proposed; the newest verdict on
  // the same query, candidate and kind replaces the stored one.
  humem::QueryRequest q = QueryWith(Near(RandomDescriptor(1), 1));
  q.top_n = 10;
  const humem::QueryResult answer = client->WaitFor(client->SubmitQuery(q), Ms(10000));
  ASSERT_EQ(answer.state, humem::QueryState::kAnswered) << answer.status.ToString();
  const humem::Candidate* one = nullptr;
  for (const humem::Candidate& c : answer.candidates)
    if (c.keyframe_id == 1) one = &c;
  ASSERT_NE(one, nullptr);
  Verification again = Verification::Of(5, *one, VerificationKind::kLoop, false);
  EXPECT_EQ(again.candidate_robot_id, "robot");
  EXPECT_EQ(again.candidate_session_id.value(), "s1");
  const humem::WriteResult replaced = client->ReportVerification(again, Ms(10000));
  ASSERT_TRUE(replaced.applied()) << replaced.status.ToString();
  EXPECT_TRUE(replaced.replaced);
  EXPECT_EQ(replaced.store_verdicts, 2u);

  // Another kind on the same pair is another verdict.
  Verification merge = again;
  merge.kind = VerificationKind::kMerge;
  ASSERT_TRUE(client->ReportVerification(merge, Ms(10000)).applied());
  ASSERT_TRUE(client->Flush(Ms(10000)).ok());
  ASSERT_TRUE(client->Stats(&stats).ok());
  EXPECT_EQ(stats.verdicts, 3u);
  EXPECT_EQ(client->GetWriteStats().failed, 0u);
}

TEST_F(VerificationTest, AVerdictOnAKeyframeTheServerDoesNotHoldFailsWithNotFound) {
  std::mutex mutex;
  std::vector<humem::WriteFailure> failures;
  humem::ClientOptions options;
  options.on_write_failed = [&](const humem::WriteFailure& f) {
    std::lock_guard<std::mutex> lock(mutex);
    failures.push_back(f);
  };
  auto client = Connect(server_, "s1", options);
  for (uint64_t id = 0; id < 3; ++id) client->Insert(MakeKeyframe(id, 0));

  // An unknown candidate.
  Verification unknown_candidate;
  unknown_candidate.keyframe_id = 2;
  unknown_candidate.candidate_keyframe_id = 99;
  unknown_candidate.kind = VerificationKind::kLoop;
  unknown_candidate.accepted = false;
  const humem::WriteResult r1 = client->ReportVerification(unknown_candidate, Ms(10000));
  EXPECT_EQ(r1.state, WriteState::kFailed);
  EXPECT_EQ(r1.status.code, StatusCode::kNotFound) << r1.status.ToString();

  // A candidate of another session that does not exist.
  Verification other_session = unknown_candidate;
  other_session.candidate_keyframe_id = 1;
  other_session.candidate_session_id = "s2";
  other_session.kind = VerificationKind::kMerge;
  const humem::WriteResult r2 = client->ReportVerification(other_session, Ms(10000));
  EXPECT_EQ(r2.status.code, StatusCode::kNotFound) << r2.status.ToString();

  // An unknown query keyframe (e.g. a relocalisation without a stored keyframe).
  Verification unknown_query;
  unknown_query.keyframe_id = 50;
  unknown_query.candidate_keyframe_id = 1;
  unknown_query.kind = VerificationKind::kRelocalisation;
  unknown_query.accepted = true;
  const humem::WriteResult r3 = client->ReportVerification(unknown_query);  // no wait: the callback tells
  EXPECT_EQ(r3.state, WriteState::kQueued);

  // The queue goes on after the refusals, and nothing was stored.
  ASSERT_TRUE(client->Insert(MakeKeyframe(3, 0), Ms(10000)).applied());
  humem::StoreStats stats;
  ASSERT_TRUE(client->Stats(&stats).ok());
  EXPECT_EQ(stats.verdicts, 0u);
  EXPECT_EQ(stats.keyframes, 4u);
  {
    std::lock_guard<std::mutex> lock(mutex);
    ASSERT_EQ(failures.size(), 3u);
    for (const humem::WriteFailure& f : failures) {
      EXPECT_EQ(f.kind, humem::WriteKind::kReportVerification);
      EXPECT_EQ(f.status.code, StatusCode::kNotFound) << f.status.ToString();
    }
    EXPECT_EQ(failures[0].keyframe_id, 2u);
    EXPECT_EQ(failures[0].sequence, r1.sequence);
    EXPECT_EQ(failures[2].keyframe_id, 50u);
    EXPECT_EQ(failures[2].sequence, r3.sequence);
  }
  EXPECT_EQ(client->GetWriteStats().failed, 3u);
  EXPECT_EQ(client->GetWriteStats().retries, 0u);
}

}  // namespace
}  // namespace humem_test
