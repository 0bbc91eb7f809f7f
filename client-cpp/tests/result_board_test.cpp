// Job: unit tests of the ticket board (src/result_board.h): waiting with a
// deadline, waking waiters, forgetting old results, Latest() semantics.
#include "result_board.h"

#include <gtest/gtest.h>

#include <chrono>
#include <future>
#include <thread>

namespace {

using namespace humem;
using humem::internal::ResultBoard;
using Clock = std::chrono::steady_clock;

QueryResult Resolved(Ticket t, QueryKind kind, QueryState state) {
  QueryResult r;
  r.ticket = t;
  r.kind = kind;
  r.state = state;
  return r;
}

TEST(ResultBoard, WaitForReturnsAtTheDeadlineWithTheCurrentState) {
  ResultBoard board(8);
  const Ticket t = board.Issue(QueryKind::kLoopClosure);
  const auto start = Clock::now();
  QueryResult r = board.WaitFor(t, start + std::chrono::milliseconds(60));
  const auto waited = Clock::now() - start;
  EXPECT_GE(waited, std::chrono::milliseconds(60));
  EXPECT_LT(waited, std::chrono::milliseconds(1000));
  EXPECT_EQ(r.state, QueryState::kQueued);
  EXPECT_EQ(r.status.code, StatusCode::kDeadlineExceeded);
  board.MarkInFlight(t);
  r = board.WaitFor(t, Clock::now());
  EXPECT_EQ(r.state, QueryState::kInFlight);
  EXPECT_FALSE(r.resolved());
}

TEST(ResultBoard, ResolveWakesAWaiter) {
  ResultBoard board(8);
  const Ticket t = board.Issue(QueryKind::kLoopClosure);
  auto waiter = std::async(std::launch::async, [&] { return board.WaitFor(t, Clock::now() + std::chrono::seconds(10)); });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  board.Resolve(Resolved(t, QueryKind::kLoopClosure, QueryState::kAnswered), true);
  ASSERT_EQ(waiter.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  const QueryResult r = waiter.get();
  EXPECT_EQ(r.state, QueryState::kAnswered);
  EXPECT_TRUE(r.status.ok());
}

TEST(ResultBoard, UnknownAndForgottenTickets) {
  ResultBoard board(2);
  EXPECT_EQ(board.WaitFor(0, Clock::now()).state, QueryState::kUnknownTicket);
  QueryResult never = board.WaitFor(5, Clock::now());
  EXPECT_EQ(never.state, QueryState::kUnknownTicket);
  EXPECT_EQ(never.status.code, StatusCode::kInvalidArgument);
  Ticket t[3];
  for (Ticket& x : t) {
    x = board.Issue(QueryKind::kLoopClosure);
    board.Resolve(Resolved(x, QueryKind::kLoopClosure, QueryState::kAnswered), true);
  }
  QueryResult forgotten = board.WaitFor(t[0], Clock::now());
  EXPECT_EQ(forgotten.state, QueryState::kUnknownTicket);
  EXPECT_EQ(forgotten.status.code, StatusCode::kNotFound);
  EXPECT_EQ(board.WaitFor(t[2], Clock::now()).state, QueryState::kAnswered);
}

TEST(ResultBoard, LatestIsTheNewestServerResultPerKindTakenOnce) {
  ResultBoard board(8);
  QueryResult out;
  EXPECT_FALSE(board.TakeLatest(QueryKind::kLoopClosure, &out));
  const Ticket a = board.Issue(QueryKind::kLoopClosure);
  const Ticket b = board.Issue(QueryKind::kLoopClosure);
  const Ticket c = board.Issue(QueryKind::kRelocalisation);
  board.Resolve(Resolved(a, QueryKind::kLoopClosure, QueryState::kAnswered), true);
  board.Resolve(Resolved(b, QueryKind::kLoopClosure, QueryState::kSuperseded), false);  // client-side
  board.Resolve(Resolved(c, QueryKind::kRelocalisation, QueryState::kSupersededByServer), true);
  ASSERT_TRUE(board.TakeLatest(QueryKind::kLoopClosure, &out));
  EXPECT_EQ(out.ticket, a);
  EXPECT_FALSE(board.TakeLatest(QueryKind::kLoopClosure, &out));
  ASSERT_TRUE(board.TakeLatest(QueryKind::kRelocalisation, &out));
  EXPECT_EQ(out.ticket, c);
  EXPECT_EQ(out.state, QueryState::kSupersededByServer);
  // Taking does not forget the ticket.
  EXPECT_EQ(board.WaitFor(a, Clock::now()).state, QueryState::kAnswered);
}

}  // namespace
