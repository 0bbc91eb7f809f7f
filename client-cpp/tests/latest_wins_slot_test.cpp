// Job: unit tests of the client-side latest-wins slot (src/latest_wins_slot.h).
#include "latest_wins_slot.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>

namespace {

using Slot = humem::internal::LatestWinsSlot<int>;

TEST(LatestWinsSlot, ANewerSubmissionReplacesOnlyThePendingItem) {
  Slot slot;
  std::optional<int> displaced;
  EXPECT_EQ(slot.Submit(1, &displaced), Slot::Submitted::kAccepted);
  EXPECT_FALSE(displaced);
  EXPECT_EQ(slot.Take(), 1);  // 1 in flight
  EXPECT_TRUE(slot.in_flight());
  EXPECT_EQ(slot.Submit(2, &displaced), Slot::Submitted::kAccepted);
  EXPECT_FALSE(displaced);
  EXPECT_EQ(slot.Submit(3, &displaced), Slot::Submitted::kReplacedPending);
  EXPECT_EQ(displaced, 2);
  displaced.reset();
  EXPECT_EQ(slot.Submit(4, &displaced), Slot::Submitted::kReplacedPending);
  EXPECT_EQ(displaced, 3);
  slot.Done();
  EXPECT_EQ(slot.Take(), 4);  // the newest
  EXPECT_FALSE(slot.has_pending());
}

TEST(LatestWinsSlot, TakeWaitsForTheFlightInProgressToFinish) {
  Slot slot;
  std::optional<int> displaced;
  slot.Submit(1, &displaced);
  ASSERT_EQ(slot.Take(), 1);
  slot.Submit(2, &displaced);
  auto next = std::async(std::launch::async, [&] { return slot.Take(); });
  // One in flight at a time: 2 is not handed out while 1 is in flight.
  EXPECT_EQ(next.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  slot.Done();
  ASSERT_EQ(next.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_EQ(next.get(), 2);
}

TEST(LatestWinsSlot, TakeWaitsForASubmission) {
  Slot slot;
  auto next = std::async(std::launch::async, [&] { return slot.Take(); });
  EXPECT_EQ(next.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  std::optional<int> displaced;
  slot.Submit(9, &displaced);
  ASSERT_EQ(next.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_EQ(next.get(), 9);
}

TEST(LatestWinsSlot, CloseHandsBackThePendingItemAndWakesTake) {
  Slot slot;
  std::optional<int> displaced;
  slot.Submit(1, &displaced);
  ASSERT_EQ(slot.Take(), 1);
  slot.Submit(2, &displaced);
  auto blocked = std::async(std::launch::async, [&] { return slot.Take(); });
  EXPECT_EQ(slot.Close(), 2);
  ASSERT_EQ(blocked.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_FALSE(blocked.get());
  EXPECT_EQ(slot.Submit(3, &displaced), Slot::Submitted::kClosed);
  EXPECT_FALSE(slot.Take());
}

TEST(LatestWinsSlot, AnItemWaitingInFlightKeepsItsPlaceWhileNewerOnesReplaceEachOther) {
  Slot slot;
  std::atomic<bool> ready{false};
  std::optional<int> displaced;
  slot.Submit(1, &displaced);
  ASSERT_EQ(slot.Take(), 1);
  const auto far = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  auto waiting = std::async(std::launch::async, [&] { return slot.WaitInFlight([&] { return ready.load(); }, far); });
  EXPECT_EQ(waiting.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  // 1 holds the place in flight: 2 queues behind it, 3 replaces 2, never 1.
  EXPECT_EQ(slot.Submit(2, &displaced), Slot::Submitted::kAccepted);
  EXPECT_EQ(slot.Submit(3, &displaced), Slot::Submitted::kReplacedPending);
  EXPECT_EQ(displaced, 2);
  EXPECT_TRUE(slot.in_flight());
  slot.Wake();  // nothing changed: still waiting
  EXPECT_EQ(waiting.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  ready = true;
  slot.Wake();
  ASSERT_EQ(waiting.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_EQ(waiting.get(), Slot::Waited::kReady);
  slot.Done();
  EXPECT_EQ(slot.Take(), 3);
}

TEST(LatestWinsSlot, WaitInFlightEndsAtItsDeadlineOrWhenTheSlotCloses) {
  Slot slot;
  std::optional<int> displaced;
  slot.Submit(1, &displaced);
  ASSERT_EQ(slot.Take(), 1);
  const auto soon = std::chrono::steady_clock::now() + std::chrono::milliseconds(50);
  EXPECT_EQ(slot.WaitInFlight([] { return false; }, soon), Slot::Waited::kTimedOut);
  EXPECT_EQ(slot.WaitInFlight([] { return true; }, soon), Slot::Waited::kReady);  // checked first

  const auto far = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  auto waiting = std::async(std::launch::async, [&] { return slot.WaitInFlight([] { return false; }, far); });
  EXPECT_EQ(waiting.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  slot.Close();
  ASSERT_EQ(waiting.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_EQ(waiting.get(), Slot::Waited::kClosed);
}

}  // namespace
