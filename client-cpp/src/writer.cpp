// Job: the ordered writer declared in writer.h.
#include "writer.h"

#include <string>
#include <utility>

#include "backoff.h"

namespace humem::internal {

Writer::Writer(Stub* stub, CallRegistry* calls, const ClientOptions& options)
    : stub_(stub), calls_(calls), options_(options) {
  thread_ = std::thread([this] { Run(); });
}

Writer::~Writer() { Close(Clock::now()); }

Status Writer::Enqueue(WriteOp op, Clock::time_point deadline, uint64_t* sequence) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (closing_) return Status(StatusCode::kCancelled, "the client is closed");
  if (op.bounded) {
    const bool room = changed_.wait_until(lock, deadline, [this] {
      return closing_ || bounded_queued_ < options_.insert_queue_capacity;
    });
    if (closing_) return Status(StatusCode::kCancelled, "the client is closed");
    if (!room) {
      return Status(StatusCode::kResourceExhausted,
                    "insert queue full (" + std::to_string(options_.insert_queue_capacity) +
                        " inserts waiting: the server is unreachable or slower than the inserts)");
    }
    ++bounded_queued_;
  }
  op.sequence = next_sequence_++;
  *sequence = op.sequence;
  queue_.push_back(std::move(op));
  changed_.notify_all();
  return Status::Ok();
}

Status Writer::Flush(Clock::time_point deadline) {
  std::unique_lock<std::mutex> lock(mutex_);
  const uint64_t target = next_sequence_ - 1;
  changed_.wait_until(lock, deadline, [&] { return finished_through_ >= target || joined_; });
  if (joined_ && stats_.abandoned > 0) {
    return Status(StatusCode::kCancelled, "the client closed and dropped " + std::to_string(stats_.abandoned) +
                                              " undelivered writes");
  }
  if (finished_through_ >= target) return Status::Ok();
  return Status(StatusCode::kDeadlineExceeded,
                std::to_string(target - finished_through_) + " writes still queued or in flight at the deadline");
}

WriteStats Writer::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  WriteStats s = stats_;
  s.queued = queue_.size();
  s.in_flight = in_flight_;
  return s;
}

uint64_t Writer::last_queued() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return next_sequence_ - 1;
}

void Writer::SetOnProgress(std::function<void()> on_progress) {
  std::lock_guard<std::mutex> lock(mutex_);
  on_progress_ = std::move(on_progress);
}

void Writer::Run() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    changed_.wait(lock, [this] { return stop_ || !queue_.empty(); });
    if (stop_) return;
    WriteOp op = std::move(queue_.front());
    queue_.pop_front();
    if (op.bounded) --bounded_queued_;
    in_flight_ = true;
    changed_.notify_all();  // room for a waiting insert
    lock.unlock();
    const bool finished = Deliver(op);
    lock.lock();
    in_flight_ = false;
    if (!finished) {  // abandoned writes never count as finished
      changed_.notify_all();
      continue;
    }
    finished_through_ = op.sequence;
    finished_atomic_.store(op.sequence, std::memory_order_release);
    changed_.notify_all();
    if (on_progress_) {
      // Outside the lock: the listener takes the query lanes' locks.
      std::function<void()> on_progress = on_progress_;
      lock.unlock();
      on_progress();
      lock.lock();
    }
  }
}

bool Writer::Deliver(WriteOp& op) {
  Backoff backoff(options_.retry_backoff_initial, options_.retry_backoff_max,
                  static_cast<uint32_t>(op.sequence * 2654435761u));
  for (;;) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stop_) {
        Finish(op, WriteResult(), true);
        return false;
      }
    }
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + options_.write_attempt_timeout);
    context.set_wait_for_ready(true);  // wait out a restart instead of failing fast
    WriteResult result;
    grpc::Status status;
    {
      ScopedCall call(calls_, &context);
      status = op.send(*stub_, context, result);
    }
    if (status.ok()) {
      result.state = WriteState::kApplied;
      Finish(op, std::move(result), false);
      return true;
    }
    const Status error = FromGrpc(status);
    std::unique_lock<std::mutex> lock(mutex_);
    if (stop_) {
      lock.unlock();
      Finish(op, WriteResult(), true);
      return false;
    }
    if (!IsTransient(error.code)) {
      lock.unlock();
      result.state = WriteState::kFailed;
      result.status = error;
      Finish(op, std::move(result), false);
      return true;
    }
    ++stats_.retries;
    if (error.code == StatusCode::kResourceExhausted) ++stats_.resource_exhausted;
    stats_.last_transient = error;
    const Clock::time_point wake = Clock::now() + backoff.Next(RetryAfter(context));
    changed_.wait_until(lock, wake, [this] { return stop_; });
  }
}

void Writer::Finish(WriteOp& op, WriteResult result, bool abandoned) {
  result.sequence = op.sequence;
  if (abandoned) {
    result = WriteResult();
    result.sequence = op.sequence;
    result.state = WriteState::kFailed;
    result.status = Status(StatusCode::kCancelled, "the client closed before the write was delivered");
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (abandoned) {
      ++stats_.abandoned;
    } else if (result.state == WriteState::kApplied) {
      ++stats_.applied;
      if (result.log_sequence > log_position_.load(std::memory_order_relaxed)) {
        log_position_.store(result.log_sequence, std::memory_order_release);
      }
    } else {
      ++stats_.failed;
    }
  }
  if (result.state == WriteState::kFailed && options_.on_write_failed) {
    WriteFailure failure;
    failure.sequence = op.sequence;
    failure.kind = op.kind;
    failure.keyframe_id = op.keyframe_id;
    failure.status = result.status;
    options_.on_write_failed(failure);
  }
  if (op.done) op.done->set_value(std::move(result));
}

uint64_t Writer::Close(Clock::time_point drain_deadline) {
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (closing_) {
      // Closed already (or closing in another thread): wait for it.
      changed_.wait(lock, [this] { return joined_; });
      return stats_.abandoned;
    }
    closing_ = true;
    changed_.notify_all();  // inserts waiting for room give up
    changed_.wait_until(lock, drain_deadline, [this] { return queue_.empty() && !in_flight_; });
    stop_ = true;
    changed_.notify_all();
  }
  calls_->CancelAll();
  if (thread_.joinable()) thread_.join();
  std::deque<WriteOp> left;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    left.swap(queue_);
    bounded_queued_ = 0;
  }
  for (WriteOp& op : left) Finish(op, WriteResult(), true);
  std::lock_guard<std::mutex> lock(mutex_);
  joined_ = true;
  changed_.notify_all();
  return stats_.abandoned;
}

}  // namespace humem::internal
