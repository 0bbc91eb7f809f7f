// Job: one query kind's lane: a latest-wins slot and the thread that sends
// its queries one at a time. Submitting while a query is pending resolves
// the pending ticket as kSuperseded; the lane's thread takes the pending
// query, waits (holding the lane) for the writes it must follow, if any,
// sends it (fail-fast, with the query deadline, which the wait for writes
// counts against) and resolves its ticket with the answer, the server's
// QUERY_STATUS_SUPERSEDED, or the error.
#ifndef HUMEM_SRC_QUERY_LANE_H_
#define HUMEM_SRC_QUERY_LANE_H_

#include <chrono>
#include <functional>
#include <mutex>
#include <thread>

#include "humem/types.h"
#include "humem/v1/humem.grpc.pb.h"
#include "latest_wins_slot.h"
#include "result_board.h"
#include "rpc.h"

namespace humem::internal {

class QueryLane {
 public:
  using OnResult = std::function<void(const QueryResult&)>;
  // The sequence through which every write is applied or failed (lock-free).
  using WritesFinished = std::function<uint64_t()>;
  // Cluster mode: the write-log position of the client's applied writes;
  // each query asks the server to have applied it (0: nothing asked).
  using LogPosition = std::function<uint64_t()>;

  QueryLane(QueryKind kind, v1::PlaceRecognition::Stub* stub, CallRegistry* calls, ResultBoard* board,
            std::chrono::milliseconds timeout, OnResult on_result, WritesFinished writes_finished = nullptr,
            LogPosition log_position = nullptr);
  ~QueryLane();
  QueryLane(const QueryLane&) = delete;
  QueryLane& operator=(const QueryLane&) = delete;

  // Issues a ticket and makes the query this kind's pending one.
  // With after_write > 0 the lane, once it takes the query, holds it until
  // writes_finished() reaches after_write (at most the query timeout) and
  // only then sends it; newer queries wait behind it meanwhile.
  Ticket Submit(v1::QueryRequest request, uint64_t after_write = 0);

  // The writer finished a write: re-check a query held back for writes.
  void WritesProgressed() { slot_.Wake(); }

  // Refuses later queries, resolves the pending one as CANCELLED and joins
  // the thread (the caller cancels the call in flight through the
  // CallRegistry first). Idempotent.
  void Close();

 private:
  struct Pending {
    Ticket ticket = 0;
    uint64_t after_write = 0;  // send once writes through this one are finished
    v1::QueryRequest request;
  };

  void Run();
  void Publish(const QueryResult& result, bool from_server);
  // A ticket resolved as failed without being sent (closed, or its writes late).
  QueryResult Unsent(Ticket ticket, Status why) const;

  const QueryKind kind_;
  v1::PlaceRecognition::Stub* const stub_;
  CallRegistry* const calls_;
  ResultBoard* const board_;
  const std::chrono::milliseconds timeout_;
  const OnResult on_result_;
  const WritesFinished writes_finished_;
  const LogPosition log_position_;
  std::mutex submit_mutex_;  // tickets reach the slot in issue order
  LatestWinsSlot<Pending> slot_;
  std::thread thread_;
};

}  // namespace humem::internal

#endif  // HUMEM_SRC_QUERY_LANE_H_
