// Job: server tests of QueryRequest::after_queued_writes: a query by keyframe
// id alone, submitted right after that keyframe's Insert, is held back (kQueued)
// until the writer has finished the writes queued before it, then answered
// from the stored keyframe; without the option the same query can overtake
// the insert and get NOT_FOUND; a failed insert releases the query
// (NOT_FOUND) instead of holding it forever; a held query keeps the lane's
// place (newer queries queue behind it, latest wins among them) for at most
// the query timeout; the other kind's lane is never held. The writer is held
// deterministically by blocking on_write_failed (it runs on the writer
// thread) after a refused write, or by freezing the server (SIGSTOP).
#include <gtest/gtest.h>

#include <chrono>
#include <condition_variable>
#include <limits>
#include <memory>
#include <mutex>

#include "humem/humem.h"
#include "humem_server.h"
#include "test_data.h"

namespace humem_test {
namespace {

using humem::QueryKind;
using humem::QueryResult;
using humem::QueryState;
using humem::StatusCode;
using humem::Ticket;
using humem::WriteState;
using Clock = std::chrono::steady_clock;

// Holds the writer thread inside on_write_failed until Release().
class WriterGate {
 public:
  void Install(humem::ClientOptions* options) {
    options->on_write_failed = [this](const humem::WriteFailure&) {
      std::unique_lock<std::mutex> lock(mutex_);
      entered_ = true;
      changed_.notify_all();
      changed_.wait(lock, [this] { return released_; });
    };
  }
  bool WaitEntered() {
    std::unique_lock<std::mutex> lock(mutex_);
    return changed_.wait_for(lock, std::chrono::seconds(10), [this] { return entered_; });
  }
  void Release() {
    std::lock_guard<std::mutex> lock(mutex_);
    released_ = true;
    changed_.notify_all();
  }
  ~WriterGate() { Release(); }

 private:
  std::mutex mutex_;
  std::condition_variable changed_;
  bool entered_ = false;
  bool released_ = false;
};

// A keyframe the server refuses (INVALID_ARGUMENT): its failure report holds the writer.
humem::Keyframe Refused(uint64_t id) {
  humem::Keyframe kf = MakeKeyframe(id, 0);
  kf.features.descriptor[0] = std::numeric_limits<float>::quiet_NaN();
  return kf;
}

// Keyframe `id` that looks like keyframe `like` (its nearest neighbour).
humem::Keyframe LookingLike(uint64_t id, uint32_t like) {
  humem::Keyframe kf = MakeKeyframe(id, 0);
  kf.features.descriptor = Near(RandomDescriptor(like), static_cast<uint32_t>(id));
  // Back where keyframe `like` stands: a revisit, within the map's drift.
  kf.pose.translation = humem::Vec3(static_cast<double>(like), 0, 0);
  return kf;
}

// A loop query by keyframe id alone (no content, no frame id: the stored ones).
humem::QueryRequest ById(uint64_t keyframe_id, bool after_queued_writes) {
  humem::QueryRequest q;
  q.kind = QueryKind::kLoopClosure;
  q.keyframe_id = keyframe_id;
  q.after_queued_writes = after_queued_writes;
  return q;
}

bool WaitUntilInFlight(humem::VprClient& client, Ticket ticket) {
  const auto give_up = Clock::now() + std::chrono::seconds(10);
  while (Clock::now() < give_up) {
    if (client.WaitFor(ticket, Ms(20)).state == QueryState::kInFlight) return true;
  }
  return false;
}

class AfterWritesTest : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_TRUE(server_.Start()) << server_.error(); }
  // Keyframes 1..10 stored (frame ids 10..100).
  void StoreTen(humem::VprClient& client) {
    for (uint64_t id = 1; id <= 10; ++id) client.Insert(MakeKeyframe(id, 0));
    ASSERT_TRUE(client.Flush(Ms(10000)).ok());
  }
  // A client with keyframes 1..10 stored whose writer `gate` then holds
  // after a refused write: writes queued from now on stay queued in the
  // client until gate.Release(). Null (and a failure) if it was not held.
  std::unique_ptr<humem::VprClient> ConnectWithWriterHeld(WriterGate& gate,
                                                          humem::ClientOptions options = humem::ClientOptions()) {
    gate.Install(&options);
    auto client = Connect(server_, "s1", options);
    StoreTen(*client);
    client->Insert(Refused(100));
    if (!gate.WaitEntered()) {
      ADD_FAILURE() << "the writer was not held";
      return nullptr;
    }
    return client;
  }
  TempDir dir_;
  HumemServer server_{dir_.path()};
};

TEST_F(AfterWritesTest, QueryByIdRightAfterInsertIsAnsweredEvenWithTheServerFrozen) {
  auto client = Connect(server_);
  StoreTen(*client);

  server_.Freeze();  // the insert below cannot be applied before the thaw
  ASSERT_EQ(client->Insert(LookingLike(200, 5)).state, WriteState::kQueued);
  const Ticket ticket = client->SubmitQuery(ById(200, true));
  // A relocalisation query is not held: it goes out at once.
  const Ticket reloc = client->SubmitQuery(QueryWith(Near(RandomDescriptor(3), 3), QueryKind::kRelocalisation));
  ASSERT_TRUE(WaitUntilInFlight(*client, reloc));
  // The loop query waits for the insert: not sent while the server is frozen.
  const QueryResult held = client->WaitFor(ticket, Ms(300));
  EXPECT_EQ(held.state, QueryState::kQueued) << QueryStateName(held.state);
  server_.Thaw();

  const QueryResult r = client->WaitFor(ticket, Ms(15000));
  ASSERT_EQ(r.state, QueryState::kAnswered) << r.status.ToString();
  ASSERT_FALSE(r.candidates.empty());
  EXPECT_EQ(r.candidates[0].keyframe_id, 5u);
  for (const humem::Candidate& c : r.candidates) EXPECT_NE(c.keyframe_id, 200u);
  EXPECT_EQ(client->WaitFor(reloc, Ms(15000)).state, QueryState::kAnswered);
  EXPECT_EQ(client->GetWriteStats().applied, 11u);

  // Back to back, unfrozen: every id-only query finds its fresh keyframe.
  // (Frames 3000..3090: within the minimum frame gap of each other.)
  for (uint64_t id = 300; id < 310; ++id) {
    const uint32_t like = static_cast<uint32_t>(id - 299);
    if (like == 5) continue;  // keyframe 200 looks like 5 too
    client->Insert(LookingLike(id, like));
    const QueryResult q = client->WaitFor(client->SubmitQuery(ById(id, true)), Ms(15000));
    ASSERT_EQ(q.state, QueryState::kAnswered) << "keyframe " << id << ": " << q.status.ToString();
    ASSERT_FALSE(q.candidates.empty()) << "keyframe " << id;
    EXPECT_EQ(q.candidates[0].keyframe_id, like) << "keyframe " << id;
  }
}

TEST_F(AfterWritesTest, WithoutTheOptionTheQueryOvertakesTheQueuedInsertWithItTheQueryWaits) {
  // The writer is held after a refused write; the insert of 200 stays queued in the client.
  WriterGate gate;
  auto client = ConnectWithWriterHeld(gate);
  ASSERT_TRUE(client);
  ASSERT_EQ(client->Insert(LookingLike(200, 7)).state, WriteState::kQueued);

  const QueryResult overtaking = client->WaitFor(client->SubmitQuery(ById(200, false)), Ms(15000));
  EXPECT_EQ(overtaking.state, QueryState::kFailed);
  EXPECT_EQ(overtaking.status.code, StatusCode::kNotFound) << overtaking.status.ToString();

  const Ticket waiting = client->SubmitQuery(ById(200, true));
  EXPECT_EQ(client->WaitFor(waiting, Ms(300)).state, QueryState::kQueued);
  gate.Release();
  const QueryResult r = client->WaitFor(waiting, Ms(15000));
  ASSERT_EQ(r.state, QueryState::kAnswered) << r.status.ToString();
  ASSERT_FALSE(r.candidates.empty());
  EXPECT_EQ(r.candidates[0].keyframe_id, 7u);
}

TEST_F(AfterWritesTest, AFailedInsertReleasesTheQueryWhichGetsNotFound) {
  auto client = Connect(server_);
  StoreTen(*client);
  client->Insert(Refused(200));
  const QueryResult r = client->WaitFor(client->SubmitQuery(ById(200, true)), Ms(15000));
  EXPECT_EQ(r.state, QueryState::kFailed);
  EXPECT_EQ(r.status.code, StatusCode::kNotFound) << r.status.ToString();
  EXPECT_EQ(client->GetWriteStats().failed, 1u);
}

TEST_F(AfterWritesTest, AHeldQueryKeepsTheLaneAndNewerOnesQueueBehindIt) {
  WriterGate gate;
  auto client = ConnectWithWriterHeld(gate);
  ASSERT_TRUE(client);
  client->Insert(LookingLike(200, 2));
  client->Insert(LookingLike(201, 4));

  // The lane takes the held-back query (the lane thread is idle, so within
  // the 200 ms) and keeps its place while the writes are held.
  const Ticket first = client->SubmitQuery(ById(200, true));
  EXPECT_EQ(client->WaitFor(first, Ms(200)).state, QueryState::kQueued);
  // Newer queries queue behind it, and the newest of them wins, as behind a
  // query on the wire: the held one is not superseded.
  const Ticket second = client->SubmitQuery(ById(201, true));
  const Ticket third = client->SubmitQuery(QueryWith(Near(RandomDescriptor(6), 6)));  // without the option
  EXPECT_EQ(client->WaitFor(second, Clock::now()).state, QueryState::kSuperseded);
  EXPECT_EQ(client->WaitFor(first, Clock::now()).state, QueryState::kQueued);
  EXPECT_EQ(client->WaitFor(third, Ms(200)).state, QueryState::kQueued);  // not sent past the held one

  // The other kind is not held meanwhile.
  const QueryResult reloc =
      client->WaitFor(client->SubmitQuery(QueryWith(Near(RandomDescriptor(9), 9), QueryKind::kRelocalisation)),
                      Ms(15000));
  ASSERT_EQ(reloc.state, QueryState::kAnswered) << reloc.status.ToString();
  EXPECT_EQ(reloc.candidates.at(0).keyframe_id, 9u);

  // Released: the held query is answered from its stored keyframe, then the newest.
  gate.Release();
  const QueryResult r = client->WaitFor(first, Ms(15000));
  ASSERT_EQ(r.state, QueryState::kAnswered) << r.status.ToString();
  EXPECT_EQ(r.candidates.at(0).keyframe_id, 2u);
  const QueryResult newest = client->WaitFor(third, Ms(15000));
  ASSERT_EQ(newest.state, QueryState::kAnswered) << newest.status.ToString();
  EXPECT_EQ(newest.candidates.at(0).keyframe_id, 6u);
  QueryResult latest;
  ASSERT_TRUE(client->Latest(QueryKind::kLoopClosure, &latest));
  EXPECT_EQ(latest.ticket, third);
}

TEST_F(AfterWritesTest, AQueryWhoseWritesAreNotAppliedWithinTheQueryTimeoutFailsUnsentAndFreesTheLane) {
  WriterGate gate;
  humem::ClientOptions options;
  options.query_timeout = Ms(300);
  auto client = ConnectWithWriterHeld(gate, options);
  ASSERT_TRUE(client);
  client->Insert(LookingLike(200, 2));

  const auto submitted = Clock::now();
  const Ticket held = client->SubmitQuery(ById(200, true));
  const QueryResult r = client->WaitFor(held, Ms(10000));
  EXPECT_EQ(r.state, QueryState::kFailed) << QueryStateName(r.state);
  EXPECT_EQ(r.status.code, StatusCode::kDeadlineExceeded) << r.status.ToString();
  EXPECT_EQ(r.round_trip_seconds, 0.0);  // never sent
  EXPECT_GE(Clock::now() - submitted, Ms(250));

  // The lane is free again: the next query goes out while the writes are still held.
  const QueryResult next = client->WaitFor(client->SubmitQuery(QueryWith(Near(RandomDescriptor(6), 6))), Ms(10000));
  ASSERT_EQ(next.state, QueryState::kAnswered) << next.status.ToString();
  EXPECT_EQ(next.candidates.at(0).keyframe_id, 6u);
  gate.Release();
}

}  // namespace
}  // namespace humem_test
