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

TEST(LatestWinsSlot, AnItemThatIsNotReadyStaysPendingAndReplaceableUntilWoken) {
  Slot slot;
  std::atomic<int> threshold{100};  // items below it are ready
  auto ready = [&](const int& item) { return item < threshold.load(); };
  std::optional<int> displaced;
  slot.Submit(150, &displaced);
  auto next = std::async(std::launch::async, [&] { return slot.Take(ready); });
  EXPECT_EQ(next.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  // Still pending: a newer item replaces it (and is not ready either).
  EXPECT_EQ(slot.Submit(160, &displaced), Slot::Submitted::kReplacedPending);
  EXPECT_EQ(displaced, 150);
  EXPECT_FALSE(slot.in_flight());
  threshold = 155;
  slot.Wake();
  EXPECT_EQ(next.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  threshold = 200;
  slot.Wake();
  ASSERT_EQ(next.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_EQ(next.get(), 160);
  EXPECT_TRUE(slot.in_flight());
}

}  // namespace
