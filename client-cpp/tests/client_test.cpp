// Job: server tests of the basic client contract against the real `humem
// serve`: insert/query round trip, errors surfaced with the field named,
// WaitFor deadlines, query deadlines, back-pressure retries, the bounded
// insert queue, and Close() reporting undelivered writes.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <thread>
#include <vector>

#include "humem/humem.h"
#include "humem_server.h"
#include "test_data.h"

namespace humem_test {
namespace {

using humem::QueryKind;
using humem::QueryResult;
using humem::QueryState;
using humem::StatusCode;
using humem::WriteState;
using Clock = std::chrono::steady_clock;

class ClientTest : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_TRUE(server_.Start()) << server_.error(); }
  TempDir dir_;
  HumemServer server_{dir_.path()};
};

TEST_F(ClientTest, InsertedKeyframesComeBackNearestFirst) {
  auto client = Connect(server_);
  for (uint64_t id = 0; id < 20; ++id) {
    const humem::WriteResult queued = client->Insert(MakeKeyframe(id, 0));
    ASSERT_EQ(queued.state, WriteState::kQueued) << queued.status.ToString();
    ASSERT_TRUE(queued.status.ok());
  }
  ASSERT_TRUE(client->Flush(Ms(10000)).ok());
  EXPECT_EQ(client->GetWriteStats().applied, 20u);

  humem::StoreStats stats;
  ASSERT_TRUE(client->Stats(&stats).ok());
  EXPECT_EQ(stats.keyframes, 20u);
  EXPECT_EQ(stats.descriptor_dim, kDim);
  EXPECT_EQ(stats.KeyframesIn("robot", "s1", 0), 20u);

  for (uint64_t target : {3u, 7u, 15u}) {
    const humem::Ticket ticket = client->SubmitQuery(QueryWith(Near(RandomDescriptor(target), target)));
    const QueryResult r = client->WaitFor(ticket, Ms(10000));
    ASSERT_EQ(r.state, QueryState::kAnswered) << r.status.ToString();
    ASSERT_FALSE(r.candidates.empty()) << "target " << target;
    const humem::Candidate& best = r.candidates[0];
    EXPECT_EQ(best.keyframe_id, target);
    EXPECT_EQ(best.robot_id, "robot");
    EXPECT_EQ(best.session_id, "s1");
    EXPECT_EQ(best.frame_id, 10 * target);
    EXPECT_DOUBLE_EQ(best.pose.translation.x, static_cast<double>(target));
    EXPECT_GT(best.score, 0.9f);
    EXPECT_EQ(r.eligible_keyframes, 20u);
    for (size_t i = 1; i < r.candidates.size(); ++i) EXPECT_LT(r.candidates[i].score, best.score);
  }

  // Latest() hands out the newest answer once.
  QueryResult latest;
  ASSERT_TRUE(client->Latest(QueryKind::kLoopClosure, &latest));
  EXPECT_EQ(latest.candidates.at(0).keyframe_id, 15u);
  EXPECT_FALSE(client->Latest(QueryKind::kLoopClosure, &latest));
  EXPECT_FALSE(client->Latest(QueryKind::kRelocalisation, &latest));

  // A waited-for insert reports what the server said.
  const humem::WriteResult replaced = client->Insert(MakeKeyframe(3, 0), Ms(10000));
  ASSERT_EQ(replaced.state, WriteState::kApplied) << replaced.status.ToString();
  EXPECT_TRUE(replaced.replaced);
  EXPECT_EQ(replaced.store_keyframes, 20u);
}

TEST_F(ClientTest, BadInputIsRefusedWithTheFieldNamedAndDoesNotStallTheQueue) {
  std::mutex mutex;
  std::vector<humem::WriteFailure> failures;
  humem::ClientOptions options;
  options.on_write_failed = [&](const humem::WriteFailure& f) {
    std::lock_guard<std::mutex> lock(mutex);
    failures.push_back(f);
  };
  auto client = Connect(server_, "s1", options);
  ASSERT_TRUE(client->Insert(MakeKeyframe(0, 0), Ms(10000)).applied());

  humem::Keyframe nan = MakeKeyframe(1, 0);
  nan.features.descriptor[3] = std::numeric_limits<float>::quiet_NaN();
  const humem::WriteResult refused = client->Insert(nan, Ms(10000));
  EXPECT_EQ(refused.state, WriteState::kFailed);
  EXPECT_EQ(refused.status.code, StatusCode::kInvalidArgument);
  EXPECT_EQ(refused.status.message, "keyframe.features.global_descriptor[3]: not a finite number");

  humem::Keyframe short_descriptor = MakeKeyframe(2, 0);
  short_descriptor.features.descriptor.resize(10);
  const humem::WriteResult wrong_dim = client->Insert(short_descriptor, Ms(10000));
  EXPECT_EQ(wrong_dim.status.code, StatusCode::kInvalidArgument);
  EXPECT_NE(wrong_dim.status.message.find("64-value"), std::string::npos) << wrong_dim.status.message;

  // An image sent to a server without perception models.
  humem::Keyframe with_image = MakeKeyframe(3, 0);
  std::vector<uint8_t> pixels(32 * 32, 128);
  with_image.image = std::make_shared<const humem::Image>(
      humem::Image::Raw(humem::Image::kGray8, pixels.data(), 32, 32));
  const humem::WriteResult no_models = client->Insert(with_image, Ms(10000));
  EXPECT_EQ(no_models.status.code, StatusCode::kFailedPrecondition);
  EXPECT_NE(no_models.status.message.find("perception.enabled = false"), std::string::npos)
      << no_models.status.message;

  // The queue goes on after refusals.
  ASSERT_TRUE(client->Insert(MakeKeyframe(4, 0), Ms(10000)).applied());
  humem::StoreStats stats;
  ASSERT_TRUE(client->Stats(&stats).ok());
  EXPECT_EQ(stats.keyframes, 2u);
  {
    std::lock_guard<std::mutex> lock(mutex);
    ASSERT_EQ(failures.size(), 3u);
    EXPECT_EQ(failures[0].kind, humem::WriteKind::kInsert);
    EXPECT_EQ(failures[0].keyframe_id, 1u);
    EXPECT_EQ(failures[0].status.code, StatusCode::kInvalidArgument);
    EXPECT_EQ(failures[2].keyframe_id, 3u);
  }
  EXPECT_EQ(client->GetWriteStats().failed, 3u);
  EXPECT_EQ(client->GetWriteStats().retries, 0u);

  // A bad query: the error is the ticket's.
  humem::QueryRequest bad = QueryWith(RandomDescriptor(0));
  bad.threshold = 1.5f;
  const QueryResult r = client->WaitFor(client->SubmitQuery(bad), Ms(10000));
  EXPECT_EQ(r.state, QueryState::kFailed);
  EXPECT_EQ(r.status.code, StatusCode::kInvalidArgument);
  EXPECT_NE(r.status.message.find("threshold"), std::string::npos) << r.status.message;

  // Tickets that were never issued.
  EXPECT_EQ(client->WaitFor(999, Ms(0)).state, QueryState::kUnknownTicket);

  // Bad options.
  humem::Status status;
  humem::ClientOptions no_robot;
  server_.Connect(&no_robot);
  EXPECT_EQ(humem::VprClient::Create(no_robot, &status), nullptr);
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_EQ(status.message, "ClientOptions.robot_id: required");

  // TLS options that do not fit, or files that cannot be read.
  humem::ClientOptions tls = no_robot;
  tls.robot_id = "robot";
  tls.target = server_.address();
  tls.tls_ca_file = "ca.crt";
  EXPECT_EQ(humem::VprClient::Create(tls, &status), nullptr);
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_NE(status.message.find("is not an https:// URL"), std::string::npos) << status.message;
  tls.target = "https://" + server_.address();
  tls.tls_ca_file = "/nonexistent/ca.crt";
  EXPECT_EQ(humem::VprClient::Create(tls, &status), nullptr);
  EXPECT_EQ(status.message, "ClientOptions.tls_ca_file: cannot read /nonexistent/ca.crt");
  tls.tls_ca_file.clear();
  tls.tls_cert_file = "client.crt";
  EXPECT_EQ(humem::VprClient::Create(tls, &status), nullptr);
  EXPECT_EQ(status.message, "ClientOptions.tls_cert_file/tls_key_file: give both or neither");
  humem::ClientOptions plain_token = no_robot;
  plain_token.robot_id = "robot";
  plain_token.target = server_.address();
  plain_token.tls_ca_file.clear();
  plain_token.tls_server_name.clear();
  plain_token.auth_token = "hm1.x";
  EXPECT_EQ(humem::VprClient::Create(plain_token, &status), nullptr);
  EXPECT_NE(status.message.find("auth_token: only sent over TLS"), std::string::npos) << status.message;
}

// Over TLS (HUMEM_TEST_TLS_DIR), a client that speaks plaintext or trusts
// another CA gets no answer, and the server goes on serving.
TEST_F(ClientTest, OverTlsOnlyAClientThatTrustsTheServerIsAnswered) {
  const std::string tls = HumemServer::TlsDir();
  if (tls.empty()) GTEST_SKIP() << "plaintext run (set HUMEM_TEST_TLS_DIR to run over TLS)";
  auto stats = [&](humem::ClientOptions options) {
    options.robot_id = "robot";
    options.call_timeout = Ms(3000);
    humem::Status status;
    std::unique_ptr<humem::VprClient> client = humem::VprClient::Create(options, &status);
    if (!client) return status;
    humem::StoreStats out;
    return client->Stats(&out);
  };
  humem::ClientOptions trusted;
  server_.Connect(&trusted);
  EXPECT_TRUE(stats(trusted).ok()) << stats(trusted).ToString();

  humem::ClientOptions plaintext;
  plaintext.target = server_.address();
  EXPECT_EQ(stats(plaintext).code, StatusCode::kUnavailable);

  humem::ClientOptions no_token = trusted;
  no_token.auth_token.clear();
  EXPECT_EQ(stats(no_token).code, StatusCode::kUnauthenticated);
  humem::ClientOptions wrong_token = trusted;
  wrong_token.auth_token = "hm1.00000000." + std::string(64, '0');
  EXPECT_EQ(stats(wrong_token).code, StatusCode::kUnauthenticated);

  humem::ClientOptions other_ca = trusted;
  other_ca.tls_ca_file = tls + "/other-ca.crt";
  EXPECT_EQ(stats(other_ca).code, StatusCode::kUnavailable);

  humem::ClientOptions wrong_name = trusted;
  wrong_name.tls_server_name = "humem.example";
  EXPECT_EQ(stats(wrong_name).code, StatusCode::kUnavailable);

  EXPECT_TRUE(stats(trusted).ok());
}

TEST_F(ClientTest, WaitForNeverBlocksPastItsDeadline) {
  auto client = Connect(server_);
  ASSERT_TRUE(client->Insert(MakeKeyframe(1, 0), Ms(10000)).applied());
  server_.Freeze();  // the query is sent but not answered
  const humem::Ticket ticket = client->SubmitQuery(QueryWith(RandomDescriptor(1)));
  const auto start = Clock::now();
  const QueryResult pending = client->WaitFor(ticket, Ms(150));
  const auto waited = Clock::now() - start;
  EXPECT_GE(waited, Ms(150));
  EXPECT_LT(waited, Ms(1000));
  EXPECT_FALSE(pending.resolved());
  EXPECT_EQ(pending.status.code, StatusCode::kDeadlineExceeded);
  EXPECT_EQ(pending.ticket, ticket);
  // A deadline in the past returns at once.
  const auto again = Clock::now();
  EXPECT_FALSE(client->WaitFor(ticket, Clock::now() - Ms(10)).resolved());
  EXPECT_LT(Clock::now() - again, Ms(100));
  server_.Thaw();
  const QueryResult answered = client->WaitFor(ticket, Ms(10000));
  ASSERT_EQ(answered.state, QueryState::kAnswered) << answered.status.ToString();
  EXPECT_EQ(answered.candidates.at(0).keyframe_id, 1u);
}

TEST_F(ClientTest, AQueryThatOutlivesItsDeadlineFails) {
  humem::ClientOptions options;
  options.query_timeout = Ms(300);
  auto client = Connect(server_, "s1", options);
  ASSERT_TRUE(client->Insert(MakeKeyframe(1, 0), Ms(10000)).applied());
  server_.Freeze();
  const auto start = Clock::now();
  const QueryResult r = client->WaitFor(client->SubmitQuery(QueryWith(RandomDescriptor(1))), Ms(10000));
  const auto took = Clock::now() - start;
  server_.Thaw();
  EXPECT_EQ(r.state, QueryState::kFailed);
  EXPECT_EQ(r.status.code, StatusCode::kDeadlineExceeded) << r.status.ToString();
  EXPECT_GE(took, Ms(250));
  EXPECT_LT(took, Ms(3000));
  // The lane is free again.
  const QueryResult next = client->WaitFor(client->SubmitQuery(QueryWith(RandomDescriptor(1))), Ms(10000));
  EXPECT_EQ(next.state, QueryState::kAnswered) << next.status.ToString();
}

TEST(BackPressure, ResourceExhaustedWritesAreRetriedUntilStored) {
  TempDir dir;
  // A write queue of one: concurrent writers overflow it.
  HumemServer server(dir.path(), {"HUMEM_STORE__WRITE_QUEUE=1"});
  ASSERT_TRUE(server.Start()) << server.error();
  constexpr int kClients = 6;
  constexpr uint64_t kEach = 40;
  std::vector<std::unique_ptr<humem::VprClient>> clients;
  for (int c = 0; c < kClients; ++c) clients.push_back(Connect(server, "s" + std::to_string(c)));
  std::vector<std::thread> threads;
  for (int c = 0; c < kClients; ++c) {
    threads.emplace_back([&, c] {
      for (uint64_t id = 0; id < kEach; ++id) {
        if (clients[c]->Insert(MakeKeyframe(id, 0), Ms(30000)).state == WriteState::kFailed) {
          ADD_FAILURE() << "insert refused";
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  uint64_t exhausted = 0;
  for (auto& client : clients) {
    ASSERT_TRUE(client->Flush(Ms(30000)).ok());
    const humem::WriteStats s = client->GetWriteStats();
    EXPECT_EQ(s.applied, kEach);
    EXPECT_EQ(s.failed, 0u);
    exhausted += s.resource_exhausted;
  }
  humem::StoreStats stats;
  ASSERT_TRUE(clients[0]->Stats(&stats).ok());
  EXPECT_EQ(stats.keyframes, kClients * kEach);
  // The server did push back (so the retry path ran), yet nothing was lost.
  EXPECT_GT(exhausted, 0u);
  std::printf("[          ] RESOURCE_EXHAUSTED retries: %llu\n", static_cast<unsigned long long>(exhausted));
}

TEST(Shutdown, AFullQueuePushesBackAndCloseReportsUndeliveredWrites) {
  TempDir dir;
  HumemServer server(dir.path());
  ASSERT_TRUE(server.Start()) << server.error();
  std::mutex mutex;
  std::vector<humem::WriteFailure> failures;
  humem::ClientOptions options;
  options.insert_queue_capacity = 2;
  options.on_write_failed = [&](const humem::WriteFailure& f) {
    std::lock_guard<std::mutex> lock(mutex);
    failures.push_back(f);
  };
  auto client = Connect(server, "s1", options);
  server.Kill();

  // Two wait in the queue and at most one more in flight; the fourth is refused.
  uint64_t accepted = 0;
  for (uint64_t id = 0; id < 3; ++id) {
    if (client->Insert(MakeKeyframe(id, 0)).state == WriteState::kQueued) ++accepted;
  }
  EXPECT_GE(accepted, 2u);
  const auto start = Clock::now();
  const humem::WriteResult full = client->Insert(MakeKeyframe(9, 0), Ms(100));
  const auto waited = Clock::now() - start;
  if (accepted == 3) {
    EXPECT_EQ(full.state, WriteState::kFailed);
    EXPECT_EQ(full.status.code, StatusCode::kResourceExhausted);
    EXPECT_NE(full.status.message.find("insert queue full"), std::string::npos);
    EXPECT_GE(waited, Ms(100));
  } else if (full.state == WriteState::kQueued) {
    ++accepted;
  }
  EXPECT_LT(waited, Ms(2000));
  // Maintenance writes are not bounded.
  EXPECT_EQ(client->ResetMap(5).state, WriteState::kQueued);
  ++accepted;

  const auto closing = Clock::now();
  const humem::Status closed = client->Close(Ms(200));
  EXPECT_LT(Clock::now() - closing, Ms(3000));
  EXPECT_EQ(closed.code, StatusCode::kAborted);
  EXPECT_NE(closed.message.find(std::to_string(accepted) + " writes"), std::string::npos) << closed.message;
  EXPECT_EQ(client->GetWriteStats().abandoned, accepted);
  {
    std::lock_guard<std::mutex> lock(mutex);
    EXPECT_EQ(failures.size(), accepted);
    for (const humem::WriteFailure& f : failures) EXPECT_EQ(f.status.code, StatusCode::kCancelled);
    EXPECT_EQ(failures.back().kind, humem::WriteKind::kResetMap);
  }
  // After Close everything is refused clearly.
  EXPECT_EQ(client->Insert(MakeKeyframe(20, 0)).status.code, StatusCode::kCancelled);
  const QueryResult q = client->WaitFor(client->SubmitQuery(QueryWith(RandomDescriptor(1))), Ms(1000));
  EXPECT_EQ(q.state, QueryState::kFailed);
  EXPECT_EQ(q.status.code, StatusCode::kCancelled);
  EXPECT_EQ(client->Close(Ms(0)).code, StatusCode::kAborted);  // idempotent
}

}  // namespace
}  // namespace humem_test
