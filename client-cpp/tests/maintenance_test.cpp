// Job: server tests of the maintenance writes: Erase, ResetMap,
// ResetSession and UpdatePoses change what Stats and Query see, and all
// writes are applied in the order they were made.
#include <gtest/gtest.h>

#include "humem/humem.h"
#include "humem_server.h"
#include "test_data.h"

namespace humem_test {
namespace {

using humem::QueryResult;
using humem::QueryState;
using humem::WriteState;

class MaintenanceTest : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_TRUE(server_.Start()) << server_.error(); }

  // The candidate of session `session` and keyframe `id` in a query near
  // keyframe `id`'s descriptor, or null.
  const humem::Candidate* Find(humem::VprClient& client, const std::string& session, uint64_t id) {
    humem::QueryRequest q = QueryWith(Near(RandomDescriptor(static_cast<uint32_t>(id)), static_cast<uint32_t>(id)));
    q.top_n = 100;
    last_ = client.WaitFor(client.SubmitQuery(q), Ms(10000));
    EXPECT_EQ(last_.state, QueryState::kAnswered) << last_.status.ToString();
    for (const humem::Candidate& c : last_.candidates) {
      if (c.session_id == session && c.keyframe_id == id) return &c;
    }
    return nullptr;
  }

  TempDir dir_;
  HumemServer server_{dir_.path()};
  QueryResult last_;
};

TEST_F(MaintenanceTest, EraseResetsAndPoseUpdatesShowInStatsAndQueries) {
  auto s1 = Connect(server_, "s1");
  auto s2 = Connect(server_, "s2");
  for (uint64_t id = 0; id < 10; ++id) {
    s1->Insert(MakeKeyframe(id, 0));
    s1->Insert(MakeKeyframe(100 + id, 1));
    s2->Insert(MakeKeyframe(id, 0));
  }
  ASSERT_TRUE(s1->Flush(Ms(10000)).ok());
  ASSERT_TRUE(s2->Flush(Ms(10000)).ok());
  ASSERT_NE(Find(*s1, "s1", 1), nullptr);

  // Erase: ids not stored are ignored.
  const humem::WriteResult erased = s1->Erase({0, 1, 2, 999}, Ms(10000));
  ASSERT_EQ(erased.state, WriteState::kApplied) << erased.status.ToString();
  EXPECT_EQ(erased.affected, 3u);
  humem::StoreStats stats;
  ASSERT_TRUE(s1->Stats(&stats).ok());
  EXPECT_EQ(stats.KeyframesIn("robot", "s1", 0), 7u);
  EXPECT_EQ(Find(*s1, "s1", 1), nullptr);
  EXPECT_NE(Find(*s1, "s2", 1), nullptr);  // same descriptor, other session

  // ResetMap: only map 1 of s1.
  const humem::WriteResult reset_map = s1->ResetMap(1, Ms(10000));
  ASSERT_TRUE(reset_map.applied()) << reset_map.status.ToString();
  EXPECT_EQ(reset_map.affected, 10u);
  ASSERT_TRUE(s1->Stats(&stats).ok());
  EXPECT_EQ(stats.KeyframesIn("robot", "s1", 1), 0u);
  EXPECT_EQ(stats.KeyframesIn("robot", "s1", 0), 7u);
  EXPECT_EQ(Find(*s1, "s1", 105), nullptr);

  // UpdatePoses: keyframe 5 moves and is merged into map 7.
  humem::PoseUpdate moved;
  moved.keyframe_id = 5;
  moved.pose = humem::Pose(humem::Vec3(1, 2, 3), humem::Quaternion(0, 0, 0, 2));
  moved.map_id = 7;
  humem::PoseUpdate unknown;
  unknown.keyframe_id = 555;
  const humem::WriteResult updated = s1->UpdatePoses({moved, unknown}, Ms(10000));
  ASSERT_TRUE(updated.applied()) << updated.status.ToString();
  EXPECT_EQ(updated.affected, 1u);
  EXPECT_EQ(updated.missing_keyframe_ids, std::vector<uint64_t>{555});
  ASSERT_TRUE(s1->Stats(&stats).ok());
  EXPECT_EQ(stats.KeyframesIn("robot", "s1", 7), 1u);
  const humem::Candidate* c = Find(*s1, "s1", 5);
  ASSERT_NE(c, nullptr);
  EXPECT_EQ(c->map_id, 7u);
  EXPECT_DOUBLE_EQ(c->pose.translation.x, 1);
  EXPECT_DOUBLE_EQ(c->pose.translation.z, 3);
  EXPECT_NEAR(c->pose.rotation.z, 1.0, 1e-9);  // normalised by the server

  // ResetSession: all of s2, nothing of s1; then ids can be reused.
  const humem::WriteResult reset = s2->ResetSession(Ms(10000));
  ASSERT_TRUE(reset.applied()) << reset.status.ToString();
  EXPECT_EQ(reset.affected, 10u);
  ASSERT_TRUE(s1->Stats(&stats).ok());
  EXPECT_EQ(stats.KeyframesIn("robot", "s2", 0), 0u);
  EXPECT_EQ(stats.keyframes, 7u);
  const humem::WriteResult reused = s2->Insert(MakeKeyframe(3, 0), Ms(10000));
  ASSERT_TRUE(reused.applied());
  EXPECT_FALSE(reused.replaced);

  // SetSession switches later requests to another session.
  s1->SetSession("s3");
  EXPECT_EQ(s1->session_id(), "s3");
  ASSERT_TRUE(s1->Insert(MakeKeyframe(1, 0), Ms(10000)).applied());
  ASSERT_TRUE(s1->Stats(&stats).ok());
  EXPECT_EQ(stats.KeyframesIn("robot", "s3", 0), 1u);
}

TEST_F(MaintenanceTest, WritesAreAppliedInTheOrderTheyWereMade) {
  auto client = Connect(server_);
  // Insert each keyframe and erase every even one right away, without
  // waiting: an erase overtaking its insert would leave the keyframe stored.
  for (uint64_t id = 0; id < 30; ++id) {
    client->Insert(MakeKeyframe(id, 0));
    if (id % 2 == 0) client->Erase({id});
  }
  // A reset queued before more inserts only removes the earlier ones.
  client->ResetMap(0);
  for (uint64_t id = 100; id < 105; ++id) client->Insert(MakeKeyframe(id, 0));
  ASSERT_TRUE(client->Flush(Ms(20000)).ok());
  humem::StoreStats stats;
  ASSERT_TRUE(client->Stats(&stats).ok());
  EXPECT_EQ(stats.keyframes, 5u);
  EXPECT_NE(Find(*client, "s1", 102), nullptr);
  EXPECT_EQ(client->GetWriteStats().failed, 0u);
}

}  // namespace
}  // namespace humem_test
