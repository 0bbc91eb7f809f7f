// Job: the ticket board declared in result_board.h.
#include "result_board.h"

#include <string>

namespace humem::internal {

ResultBoard::ResultBoard(size_t history) : history_(history == 0 ? 1 : history) {}

Ticket ResultBoard::Issue(QueryKind kind) {
  std::lock_guard<std::mutex> lock(mutex_);
  QueryResult entry;
  entry.ticket = ++last_issued_;
  entry.kind = kind;
  entry.state = QueryState::kQueued;
  entries_[entry.ticket] = entry;
  return entry.ticket;
}

void ResultBoard::MarkInFlight(Ticket ticket) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = entries_.find(ticket);
  if (it != entries_.end() && !it->second.resolved()) it->second.state = QueryState::kInFlight;
}

void ResultBoard::Resolve(const QueryResult& result, bool from_server) {
  std::lock_guard<std::mutex> lock(mutex_);
  entries_[result.ticket] = result;
  resolved_order_.push_back(result.ticket);
  while (resolved_order_.size() > history_) {
    entries_.erase(resolved_order_.front());
    resolved_order_.pop_front();
  }
  if (from_server) {
    std::optional<QueryResult>& latest = latest_[KindIndex(result.kind)];
    if (!latest || latest->ticket < result.ticket) latest = result;
  }
  resolved_.notify_all();
}

QueryResult ResultBoard::WaitFor(Ticket ticket, Clock::time_point deadline) {
  std::unique_lock<std::mutex> lock(mutex_);
  QueryResult unknown;
  unknown.ticket = ticket;
  unknown.state = QueryState::kUnknownTicket;
  if (ticket == 0 || ticket > last_issued_) {
    unknown.status = Status(StatusCode::kInvalidArgument, "ticket " + std::to_string(ticket) + " was never issued");
    return unknown;
  }
  resolved_.wait_until(lock, deadline, [&] {
    auto it = entries_.find(ticket);
    return it == entries_.end() || it->second.resolved();
  });
  auto it = entries_.find(ticket);
  if (it == entries_.end()) {
    unknown.status = Status(StatusCode::kNotFound, "the result of ticket " + std::to_string(ticket) +
                                                       " is no longer kept (result_history = " +
                                                       std::to_string(history_) + ")");
    return unknown;
  }
  QueryResult result = it->second;
  if (!result.resolved()) {
    result.status = Status(StatusCode::kDeadlineExceeded, "ticket " + std::to_string(ticket) + " still " +
                                                              QueryStateName(result.state) + " at the deadline");
  }
  return result;
}

bool ResultBoard::TakeLatest(QueryKind kind, QueryResult* out) {
  std::lock_guard<std::mutex> lock(mutex_);
  std::optional<QueryResult>& latest = latest_[KindIndex(kind)];
  if (!latest) return false;
  *out = std::move(*latest);
  latest.reset();
  return true;
}

}  // namespace humem::internal
