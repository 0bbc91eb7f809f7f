// Job: server test of a restart in the middle: the server is killed
// (SIGKILL), inserts are made while it is down, it comes back on the same
// port and data directory, the queued inserts are delivered, and what was
// stored before the restart is still found.
#include <gtest/gtest.h>

#include <thread>

#include "humem/humem.h"
#include "humem_server.h"
#include "test_data.h"

namespace humem_test {
namespace {

using humem::QueryState;
using humem::StatusCode;
using humem::WriteState;

TEST(Restart, InsertsQueuedWhileTheServerIsDownAreDeliveredAfterItReturns) {
  TempDir dir;
  HumemServer server(dir.path());
  ASSERT_TRUE(server.Start()) << server.error();
  const int port = server.port();
  humem::ClientOptions options;
  auto client = Connect(server, "s1", options);
  for (uint64_t id = 0; id < 10; ++id) client->Insert(MakeKeyframe(id, 0));
  ASSERT_TRUE(client->Flush(Ms(10000)).ok());

  server.Kill();
  for (uint64_t id = 10; id < 20; ++id) {
    const humem::WriteResult r = client->Insert(MakeKeyframe(id, 0));
    ASSERT_EQ(r.state, WriteState::kQueued) << r.status.ToString();
  }
  // A query while the server is down fails (fast) instead of hanging.
  const humem::QueryResult down = client->WaitFor(client->SubmitQuery(QueryWith(RandomDescriptor(3))), Ms(10000));
  EXPECT_EQ(down.state, QueryState::kFailed);
  EXPECT_TRUE(down.status.code == StatusCode::kUnavailable || down.status.code == StatusCode::kDeadlineExceeded)
      << down.status.ToString();
  // Long enough for attempts (2 s each) to time out and be retried.
  EXPECT_EQ(client->Flush(Ms(2500)).code, StatusCode::kDeadlineExceeded);
  humem::WriteStats stats = client->GetWriteStats();
  EXPECT_EQ(stats.applied, 10u);
  EXPECT_EQ(stats.queued + (stats.in_flight ? 1 : 0), 10u);
  EXPECT_GT(stats.retries, 0u);
  EXPECT_EQ(stats.failed, 0u);

  ASSERT_TRUE(server.Start()) << server.error();
  ASSERT_EQ(server.port(), port);
  const humem::Status flushed = client->Flush(Ms(30000));
  ASSERT_TRUE(flushed.ok()) << flushed.ToString();
  stats = client->GetWriteStats();
  EXPECT_EQ(stats.applied, 20u);
  EXPECT_EQ(stats.failed, 0u);

  humem::StoreStats store;
  ASSERT_TRUE(client->Stats(&store).ok());
  EXPECT_EQ(store.keyframes, 20u);
  for (uint64_t target : {3u, 15u}) {  // stored before and after the restart
    const humem::QueryResult r =
        client->WaitFor(client->SubmitQuery(QueryWith(Near(RandomDescriptor(target), target))), Ms(10000));
    ASSERT_EQ(r.state, QueryState::kAnswered) << r.status.ToString();
    ASSERT_FALSE(r.candidates.empty());
    EXPECT_EQ(r.candidates[0].keyframe_id, target);
  }
}

TEST(Restart, AGracefulRestartUnderContinuousInsertsLosesNothing) {
  TempDir dir;
  HumemServer server(dir.path());
  ASSERT_TRUE(server.Start()) << server.error();
  auto client = Connect(server);
  std::thread writer([&] {
    for (uint64_t id = 0; id < 200; ++id) {
      if (client->Insert(MakeKeyframe(id, 0), Ms(30000)).state == WriteState::kFailed) ADD_FAILURE() << id;
      std::this_thread::sleep_for(Ms(5));
    }
  });
  std::this_thread::sleep_for(Ms(300));
  EXPECT_EQ(server.Terminate(), 0);
  std::this_thread::sleep_for(Ms(300));
  ASSERT_TRUE(server.Start()) << server.error();
  writer.join();
  ASSERT_TRUE(client->Flush(Ms(30000)).ok());
  humem::StoreStats store;
  ASSERT_TRUE(client->Stats(&store).ok());
  EXPECT_EQ(store.keyframes, 200u);
  EXPECT_EQ(client->GetWriteStats().failed, 0u);
}

}  // namespace
}  // namespace humem_test
