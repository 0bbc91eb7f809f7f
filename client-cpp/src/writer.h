// Job: the ordered write queue and its writer thread. Every write (insert,
// erase, resets, pose updates, verdicts) is delivered in the order it was
// queued, one at a time, each attempt waiting for the connection (wait_for_ready) up to
// its deadline; transient errors are retried with back-off, so queued writes
// survive a server restart; permanent errors fail that write only and are
// reported. Inserts are bounded by the queue capacity; other writes always
// fit (they are few, and dropping one would break the order's meaning).
#ifndef HUMEM_SRC_WRITER_H_
#define HUMEM_SRC_WRITER_H_

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <thread>

#include "humem/vpr_client.h"
#include "humem/v1/humem.grpc.pb.h"
#include "rpc.h"

namespace humem::internal {

using Clock = std::chrono::steady_clock;
using Stub = v1::PlaceRecognition::Stub;

struct WriteOp {
  WriteKind kind = WriteKind::kInsert;
  uint64_t keyframe_id = 0;  // inserts, for failure reports
  bool bounded = false;      // counts against insert_queue_capacity
  // Makes one attempt; on success fills the applied fields of the result.
  std::function<grpc::Status(Stub&, grpc::ClientContext&, WriteResult&)> send;
  // Resolved once the write is applied or failed for good.
  std::shared_ptr<std::promise<WriteResult>> done;
  uint64_t sequence = 0;  // set by Writer::Enqueue
};

class Writer {
 public:
  Writer(Stub* stub, CallRegistry* calls, const ClientOptions& options);
  ~Writer();
  Writer(const Writer&) = delete;
  Writer& operator=(const Writer&) = delete;

  // Queues `op`. A bounded write (op.bounded: an insert) waits until
  // `deadline` for room;
  // fails with RESOURCE_EXHAUSTED if there is none, CANCELLED once closing.
  Status Enqueue(WriteOp op, Clock::time_point deadline, uint64_t* sequence);

  // Waits until every write queued so far is applied or failed.
  Status Flush(Clock::time_point deadline);

  WriteStats stats() const;

  // The sequence of the newest write queued so far (0: none yet).
  uint64_t last_queued() const;
  // Every write up to this sequence is applied or failed for good
  // (lock-free: read under other components' locks).
  uint64_t finished_through() const { return finished_atomic_.load(std::memory_order_acquire); }
  // Cluster mode: the highest write-log position of this client's applied
  // writes (0 from a server not in cluster mode). Lock-free.
  uint64_t log_position() const { return log_position_.load(std::memory_order_acquire); }
  // Called from the writer thread (no lock held) each time
  // finished_through() advances. Set it before queueing writes.
  void SetOnProgress(std::function<void()> on_progress);

  // Refuses new writes, lets the queue drain until `drain_deadline`, then
  // cancels the write in flight, joins the thread and drops (and reports)
  // what is left. Returns how many writes were dropped. Idempotent.
  uint64_t Close(Clock::time_point drain_deadline);

 private:
  void Run();
  // Delivers one write, retrying transient errors, until it is applied or
  // refused (true), or abandoned because the writer stopped (false).
  bool Deliver(WriteOp& op);
  // Resolves the write's promise, updates counters, reports failures.
  void Finish(WriteOp& op, WriteResult result, bool abandoned);

  Stub* const stub_;
  CallRegistry* const calls_;
  const ClientOptions options_;

  mutable std::mutex mutex_;
  std::condition_variable changed_;  // queue, room, progress or stop
  std::deque<WriteOp> queue_;
  size_t bounded_queued_ = 0;
  uint64_t next_sequence_ = 1;
  uint64_t finished_through_ = 0;  // every write up to this one is finished
  std::atomic<uint64_t> finished_atomic_{0};  // a copy of finished_through_
  std::atomic<uint64_t> log_position_{0};
  std::function<void()> on_progress_;
  bool in_flight_ = false;
  bool closing_ = false;  // no new writes
  bool stop_ = false;     // abandon delivery
  bool joined_ = false;   // Close() finished
  WriteStats stats_;
  std::thread thread_;
};

}  // namespace humem::internal

#endif  // HUMEM_SRC_WRITER_H_
