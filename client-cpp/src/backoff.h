// Job: when and how long the writer waits before repeating a write: which
// status codes are transient, and an exponential back-off with jitter that
// never undercuts the server's retry-after-ms hint.
#ifndef HUMEM_SRC_BACKOFF_H_
#define HUMEM_SRC_BACKOFF_H_

#include <chrono>
#include <cstdint>
#include <random>

#include "humem/status.h"

namespace humem::internal {

// True for errors after which the same write may succeed later: the server
// is down or restarting (UNAVAILABLE), overloaded (RESOURCE_EXHAUSTED), too
// slow or frozen (DEADLINE_EXCEEDED; tonic reports a passed deadline as
// CANCELLED), or the call was aborted. Every HuMem write is idempotent
// (insert replaces, erase and resets remove, pose updates overwrite), so
// repeating one whose first attempt did land is harmless.
bool IsTransient(StatusCode code);

class Backoff {
 public:
  using ms = std::chrono::milliseconds;

  Backoff(ms initial, ms max, uint32_t seed);

  // The next wait: the current step with ±20% jitter, at least `hint`
  // (the server's retry-after-ms, 0 if none). Doubles the step, up to max.
  ms Next(ms hint);

  // Back to the initial step (after a success).
  void Reset();

 private:
  ms initial_;
  ms max_;
  ms step_;
  std::minstd_rand rng_;
};

}  // namespace humem::internal

#endif  // HUMEM_SRC_BACKOFF_H_
