// Job: the per-kind query lane declared in query_lane.h.
#include "query_lane.h"

#include <optional>
#include <string>
#include <utility>

#include "convert.h"

namespace humem::internal {

QueryLane::QueryLane(QueryKind kind, v1::PlaceRecognition::Stub* stub, CallRegistry* calls, ResultBoard* board,
                     std::chrono::milliseconds timeout, OnResult on_result, WritesFinished writes_finished,
                     LogPosition log_position)
    : kind_(kind),
      stub_(stub),
      calls_(calls),
      board_(board),
      timeout_(timeout),
      on_result_(std::move(on_result)),
      writes_finished_(std::move(writes_finished)),
      log_position_(std::move(log_position)) {
  thread_ = std::thread([this] { Run(); });
}

QueryLane::~QueryLane() { Close(); }

QueryResult QueryLane::Unsent(Ticket ticket, Status why) const {
  QueryResult r;
  r.ticket = ticket;
  r.kind = kind_;
  r.state = QueryState::kFailed;
  r.status = std::move(why);
  return r;
}

Ticket QueryLane::Submit(v1::QueryRequest request, uint64_t after_write) {
  std::optional<Pending> displaced;
  Ticket ticket;
  LatestWinsSlot<Pending>::Submitted outcome;
  {
    std::lock_guard<std::mutex> lock(submit_mutex_);
    ticket = board_->Issue(kind_);
    Pending pending;
    pending.ticket = ticket;
    pending.after_write = writes_finished_ ? after_write : 0;
    pending.request = std::move(request);
    outcome = slot_.Submit(std::move(pending), &displaced);
  }
  if (outcome == LatestWinsSlot<Pending>::Submitted::kClosed) {
    Publish(Unsent(ticket, Status(StatusCode::kCancelled, "the client is closed")), false);
  } else if (displaced) {
    QueryResult r;
    r.ticket = displaced->ticket;
    r.kind = kind_;
    r.state = QueryState::kSuperseded;
    Publish(r, false);
  }
  return ticket;
}

void QueryLane::Run() {
  for (;;) {
    std::optional<Pending> pending = slot_.Take();
    if (!pending) return;
    // The query timeout runs from here: the wait for writes is part of it.
    const auto deadline = std::chrono::system_clock::now() + timeout_;
    if (pending->after_write > 0) {
      // Held back for writes, the query keeps the lane's place in flight, so
      // newer ones queue behind it as they would behind a query on the wire.
      // WritesProgressed() wakes the re-check.
      const uint64_t after = pending->after_write;
      const auto waited = slot_.WaitInFlight([&] { return writes_finished_() >= after; }, deadline);
      if (waited != LatestWinsSlot<Pending>::Waited::kReady) {
        const Status why =
            waited == LatestWinsSlot<Pending>::Waited::kClosed
                ? Status(StatusCode::kCancelled, "the client closed before the writes the query follows were applied")
                : Status(StatusCode::kDeadlineExceeded, "not sent: the writes queued before it were not applied within " +
                                                            std::to_string(timeout_.count()) + " ms (query_timeout)");
        const QueryResult r = Unsent(pending->ticket, why);
        slot_.Done();
        Publish(r, false);
        continue;
      }
    }
    // Read-your-writes across cluster replicas: whichever replica answers
    // has applied this client's writes first.
    if (log_position_ && !pending->request.has_min_log_sequence()) {
      const uint64_t position = log_position_();
      if (position > 0) pending->request.set_min_log_sequence(position);
    }
    board_->MarkInFlight(pending->ticket);
    QueryResult result;
    result.ticket = pending->ticket;
    result.kind = kind_;
    grpc::ClientContext context;
    context.set_deadline(deadline);
    v1::QueryResponse response;
    const auto sent = std::chrono::steady_clock::now();
    grpc::Status status;
    {
      ScopedCall call(calls_, &context);
      status = stub_->Query(&context, pending->request, &response);
    }
    result.round_trip_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - sent).count();
    if (status.ok()) {
      FromProto(response, &result);
    } else {
      result.state = QueryState::kFailed;
      result.status = FromGrpc(status);
    }
    slot_.Done();
    Publish(result, true);
  }
}

void QueryLane::Publish(const QueryResult& result, bool from_server) {
  // The callback runs before waiters wake: once WaitFor() returns a
  // resolved ticket, its callback has run.
  if (on_result_) on_result_(result);
  board_->Resolve(result, from_server);
}

void QueryLane::Close() {
  std::optional<Pending> left = slot_.Close();
  if (left) Publish(Unsent(left->ticket, Status(StatusCode::kCancelled, "the client closed before the query was sent")), false);
  if (thread_.joinable()) thread_.join();
}

}  // namespace humem::internal
