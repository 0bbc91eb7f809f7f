// Job: the retry classification and back-off of backoff.h.
#include "backoff.h"

#include <algorithm>

namespace humem::internal {

bool IsTransient(StatusCode code) {
  switch (code) {
    case StatusCode::kUnavailable:
    case StatusCode::kResourceExhausted:
    case StatusCode::kDeadlineExceeded:
    case StatusCode::kCancelled:
    case StatusCode::kAborted:
      return true;
    default:
      return false;
  }
}

Backoff::Backoff(ms initial, ms max, uint32_t seed)
    : initial_(std::max(initial, ms(1))), max_(std::max(max, std::max(initial, ms(1)))), step_(initial_),
      rng_(seed == 0 ? 1 : seed) {}

Backoff::ms Backoff::Next(ms hint) {
  std::uniform_real_distribution<double> jitter(0.8, 1.2);
  ms wait(static_cast<ms::rep>(static_cast<double>(step_.count()) * jitter(rng_)));
  step_ = std::min(step_ * 2, max_);
  return std::max(wait, hint);
}

void Backoff::Reset() { step_ = initial_; }

}  // namespace humem::internal
