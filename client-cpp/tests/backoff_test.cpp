// Job: unit tests of the writer's retry classification and back-off
// (src/backoff.h).
#include "backoff.h"

#include <gtest/gtest.h>

namespace {

using humem::StatusCode;
using humem::internal::Backoff;
using humem::internal::IsTransient;
using ms = std::chrono::milliseconds;

TEST(Backoff, OnlyTransientErrorsAreRetried) {
  EXPECT_TRUE(IsTransient(StatusCode::kUnavailable));
  EXPECT_TRUE(IsTransient(StatusCode::kResourceExhausted));
  EXPECT_TRUE(IsTransient(StatusCode::kDeadlineExceeded));
  EXPECT_TRUE(IsTransient(StatusCode::kCancelled));
  EXPECT_TRUE(IsTransient(StatusCode::kAborted));
  EXPECT_FALSE(IsTransient(StatusCode::kInvalidArgument));
  EXPECT_FALSE(IsTransient(StatusCode::kFailedPrecondition));
  EXPECT_FALSE(IsTransient(StatusCode::kNotFound));
  EXPECT_FALSE(IsTransient(StatusCode::kInternal));
  EXPECT_FALSE(IsTransient(StatusCode::kOk));
}

TEST(Backoff, DoublesWithJitterUpToTheMaximum) {
  Backoff backoff(ms(100), ms(800), 42);
  const long long steps[] = {100, 200, 400, 800, 800, 800};
  for (long long step : steps) {
    const ms wait = backoff.Next(ms(0));
    EXPECT_GE(wait.count(), step * 8 / 10 - 1) << step;
    EXPECT_LE(wait.count(), step * 12 / 10 + 1) << step;
  }
  backoff.Reset();
  const ms first = backoff.Next(ms(0));
  EXPECT_GE(first.count(), 79);
  EXPECT_LE(first.count(), 121);
}

TEST(Backoff, NeverUndercutsTheServersHint) {
  Backoff backoff(ms(10), ms(20), 7);
  EXPECT_EQ(backoff.Next(ms(500)).count(), 500);
  // A hint shorter than the step does not shorten it.
  EXPECT_GE(backoff.Next(ms(1)).count(), 16);
}

}  // namespace
