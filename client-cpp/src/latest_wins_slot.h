// Job: the client-side latest-wins slot of one query kind: at most one item
// in flight and one pending. Submitting while an item is pending replaces
// it and hands the displaced item back, so its ticket can be resolved as
// superseded. The query thread of the kind blocks in Take() (condition
// variable, no polling) until something is pending and nothing is in
// flight. The item in flight may first have to wait for something else
// (the writes a query must follow): WaitInFlight() does that wait while the
// item keeps its place, so a newer submission queues behind it instead of
// displacing it, exactly as behind an item already on the wire.
#ifndef HUMEM_SRC_LATEST_WINS_SLOT_H_
#define HUMEM_SRC_LATEST_WINS_SLOT_H_

#include <condition_variable>
#include <mutex>
#include <optional>
#include <utility>

namespace humem::internal {

template <typename T>
class LatestWinsSlot {
 public:
  enum class Submitted {
    kAccepted,         // now pending; nothing was displaced
    kReplacedPending,  // now pending; *displaced holds the item it replaced
    kClosed,           // refused: the slot is closed (item dropped)
  };

  Submitted Submit(T item, std::optional<T>* displaced) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (closed_) return Submitted::kClosed;
    Submitted outcome = Submitted::kAccepted;
    if (pending_) {
      *displaced = std::move(pending_);
      outcome = Submitted::kReplacedPending;
    }
    pending_ = std::move(item);
    changed_.notify_all();
    return outcome;
  }

  // Blocks until an item is pending and nothing is in flight, then moves it
  // in flight and returns it; returns nullopt once the slot is closed.
  std::optional<T> Take() {
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait(lock, [&] { return closed_ || (pending_ && !in_flight_); });
    if (closed_) return std::nullopt;
    in_flight_ = true;
    std::optional<T> item = std::move(pending_);
    pending_.reset();
    return item;
  }

  enum class Waited {
    kReady,     // ready() holds
    kTimedOut,  // the deadline passed first
    kClosed,    // the slot was closed first
  };

  // Called by the holder of the item in flight: blocks until ready() holds,
  // the deadline passes or the slot closes. The item stays in flight
  // meanwhile (newer submissions queue and replace each other behind it).
  // ready() runs under the slot's lock: it must be cheap and must not
  // block; whoever makes it become true calls Wake() afterwards.
  template <typename Ready, typename TimePoint>
  Waited WaitInFlight(Ready ready, TimePoint deadline) {
    std::unique_lock<std::mutex> lock(mutex_);
    const bool woken = changed_.wait_until(lock, deadline, [&] { return closed_ || ready(); });
    if (closed_) return Waited::kClosed;
    return woken ? Waited::kReady : Waited::kTimedOut;
  }

  // The in-flight item finished.
  void Done() {
    std::lock_guard<std::mutex> lock(mutex_);
    in_flight_ = false;
    changed_.notify_all();
  }

  // Something WaitInFlight()'s ready() reads has changed: re-check.
  void Wake() {
    std::lock_guard<std::mutex> lock(mutex_);
    changed_.notify_all();
  }

  // Refuses later submissions, wakes Take() and WaitInFlight(), and returns
  // the pending item.
  std::optional<T> Close() {
    std::lock_guard<std::mutex> lock(mutex_);
    closed_ = true;
    std::optional<T> left = std::move(pending_);
    pending_.reset();
    changed_.notify_all();
    return left;
  }

  bool in_flight() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return in_flight_;
  }
  bool has_pending() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return pending_.has_value();
  }

 private:
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::optional<T> pending_;
  bool in_flight_ = false;
  bool closed_ = false;
};

}  // namespace humem::internal

#endif  // HUMEM_SRC_LATEST_WINS_SLOT_H_
