// Job: server test of latest-wins on the client: while the server is frozen
// (SIGSTOP) one query of a kind is in flight; a burst of newer ones leaves
// only the newest pending and supersedes the rest at once, the other kind
// is untouched, and after the server thaws the in-flight and newest
// tickets are answered. Deterministic: the freeze pins the in-flight query.
#include <gtest/gtest.h>

#include <chrono>
#include <mutex>
#include <set>
#include <vector>

#include "humem/humem.h"
#include "humem_server.h"
#include "test_data.h"

namespace humem_test {
namespace {

using humem::QueryKind;
using humem::QueryResult;
using humem::QueryState;
using humem::Ticket;
using Clock = std::chrono::steady_clock;

// Waits (bounded) until the ticket has been sent.
bool WaitUntilInFlight(humem::VprClient& client, Ticket ticket) {
  const auto give_up = Clock::now() + std::chrono::seconds(10);
  while (Clock::now() < give_up) {
    if (client.WaitFor(ticket, Ms(20)).state == QueryState::kInFlight) return true;
  }
  return false;
}

TEST(LatestWins, ABurstKeepsTheRunningAndTheNewestQueryAndSupersedesTheRest) {
  TempDir dir;
  HumemServer server(dir.path());
  ASSERT_TRUE(server.Start()) << server.error();
  std::mutex mutex;
  std::vector<QueryResult> published;
  humem::ClientOptions options;
  options.on_query_result = [&](const QueryResult& r) {
    std::lock_guard<std::mutex> lock(mutex);
    published.push_back(r);
  };
  auto client = Connect(server, "s1", options);
  for (uint64_t id = 1; id <= 8; ++id) client->Insert(MakeKeyframe(id, 0));
  ASSERT_TRUE(client->Flush(Ms(10000)).ok());

  server.Freeze();
  const Ticket first = client->SubmitQuery(QueryWith(Near(RandomDescriptor(1), 1)));
  ASSERT_TRUE(WaitUntilInFlight(*client, first));
  std::vector<Ticket> burst;
  for (uint64_t id = 2; id <= 6; ++id) burst.push_back(client->SubmitQuery(QueryWith(Near(RandomDescriptor(id), id))));
  const Ticket reloc = client->SubmitQuery(QueryWith(Near(RandomDescriptor(7), 7), QueryKind::kRelocalisation));

  // Every burst ticket but the newest resolved as superseded at once.
  for (size_t i = 0; i + 1 < burst.size(); ++i) {
    const QueryResult r = client->WaitFor(burst[i], Clock::now());
    EXPECT_EQ(r.state, QueryState::kSuperseded) << "ticket " << burst[i];
    EXPECT_TRUE(r.status.ok());
    EXPECT_TRUE(r.candidates.empty());
  }
  EXPECT_EQ(client->WaitFor(burst.back(), Clock::now()).state, QueryState::kQueued);
  EXPECT_EQ(client->WaitFor(first, Clock::now()).state, QueryState::kInFlight);
  // The other kind has its own slot.
  EXPECT_FALSE(client->WaitFor(reloc, Clock::now()).resolved());
  QueryResult latest;
  EXPECT_FALSE(client->Latest(QueryKind::kLoopClosure, &latest));

  server.Thaw();
  const QueryResult running = client->WaitFor(first, Ms(10000));
  ASSERT_EQ(running.state, QueryState::kAnswered) << running.status.ToString();
  EXPECT_EQ(running.candidates.at(0).keyframe_id, 1u);
  const QueryResult newest = client->WaitFor(burst.back(), Ms(10000));
  ASSERT_EQ(newest.state, QueryState::kAnswered) << newest.status.ToString();
  EXPECT_EQ(newest.candidates.at(0).keyframe_id, 6u);
  const QueryResult relocalised = client->WaitFor(reloc, Ms(10000));
  ASSERT_EQ(relocalised.state, QueryState::kAnswered) << relocalised.status.ToString();
  EXPECT_EQ(relocalised.candidates.at(0).keyframe_id, 7u);

  // Latest: the newest loop-closure answer, once.
  ASSERT_TRUE(client->Latest(QueryKind::kLoopClosure, &latest));
  EXPECT_EQ(latest.ticket, burst.back());
  EXPECT_FALSE(client->Latest(QueryKind::kLoopClosure, &latest));

  // The callback saw every ticket resolve exactly once.
  std::lock_guard<std::mutex> lock(mutex);
  std::set<Ticket> seen;
  size_t superseded = 0;
  for (const QueryResult& r : published) {
    EXPECT_TRUE(seen.insert(r.ticket).second) << "ticket " << r.ticket << " published twice";
    if (r.state == QueryState::kSuperseded) ++superseded;
  }
  EXPECT_EQ(seen.size(), burst.size() + 2);
  EXPECT_EQ(superseded, burst.size() - 1);
}

}  // namespace
}  // namespace humem_test
