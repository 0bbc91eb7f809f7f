// Job: the tickets of submitted queries and their results. Issues tickets,
// records each one's state (queued, in flight, resolved), lets callers wait
// for a ticket with a deadline (condition variable), keeps the newest
// server-visited result per kind for Latest(), and forgets the oldest
// resolved results beyond the configured history.
#ifndef HUMEM_SRC_RESULT_BOARD_H_
#define HUMEM_SRC_RESULT_BOARD_H_

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>
#include <optional>
#include <unordered_map>

#include "humem/types.h"

namespace humem::internal {

class ResultBoard {
 public:
  using Clock = std::chrono::steady_clock;

  explicit ResultBoard(size_t history);

  // A new ticket of `kind`, in state kQueued.
  Ticket Issue(QueryKind kind);
  void MarkInFlight(Ticket ticket);

  // Records the final result of result.ticket and wakes its waiters.
  // `from_server`: the query was sent (answered, superseded by the server,
  // or failed), so it becomes the kind's latest result.
  void Resolve(const QueryResult& result, bool from_server);

  // The ticket's result once resolved, or its current state with
  // DEADLINE_EXCEEDED when `deadline` passes first; kUnknownTicket for a
  // ticket never issued or forgotten.
  QueryResult WaitFor(Ticket ticket, Clock::time_point deadline);

  // Moves out the newest server-visited result of `kind` not taken yet.
  bool TakeLatest(QueryKind kind, QueryResult* out);

 private:
  static size_t KindIndex(QueryKind kind) { return kind == QueryKind::kRelocalisation ? 1 : 0; }

  const size_t history_;
  std::mutex mutex_;
  std::condition_variable resolved_;
  Ticket last_issued_ = 0;
  std::unordered_map<Ticket, QueryResult> entries_;
  std::deque<Ticket> resolved_order_;  // oldest first
  std::optional<QueryResult> latest_[2];
};

}  // namespace humem::internal

#endif  // HUMEM_SRC_RESULT_BOARD_H_
