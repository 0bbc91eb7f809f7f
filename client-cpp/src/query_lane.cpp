// Job: the per-kind query lane declared in query_lane.h.
#include "query_lane.h"

#include <optional>
#include <utility>

#include "convert.h"

namespace humem::internal {

QueryLane::QueryLane(QueryKind kind, v1::PlaceRecognition::Stub* stub, CallRegistry* calls, ResultBoard* board,
                     std::chrono::milliseconds timeout, OnResult on_result, WritesFinished writes_finished)
    : kind_(kind),
      stub_(stub),
      calls_(calls),
      board_(board),
      timeout_(timeout),
      on_result_(std::move(on_result)),
      writes_finished_(std::move(writes_finished)) {
  thread_ = std::thread([this] { Run(); });
}

QueryLane::~QueryLane() { Close(); }

QueryResult QueryLane::Cancelled(Ticket ticket, const char* why) const {
  QueryResult r;
  r.ticket = ticket;
  r.kind = kind_;
  r.state = QueryState::kFailed;
  r.status = Status(StatusCode::kCancelled, why);
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
    Publish(Cancelled(ticket, "the client is closed"), false);
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
    // A query held back for writes stays pending (supersedable) until the
    // writer has finished them; WritesProgressed() wakes the re-check.
    std::optional<Pending> pending =
        slot_.Take([this](const Pending& p) { return p.after_write == 0 || writes_finished_() >= p.after_write; });
    if (!pending) return;
    board_->MarkInFlight(pending->ticket);
    QueryResult result;
    result.ticket = pending->ticket;
    result.kind = kind_;
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + timeout_);
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
  if (left) Publish(Cancelled(left->ticket, "the client closed before the query was sent"), false);
  if (thread_.joinable()) thread_.join();
}

}  // namespace humem::internal
