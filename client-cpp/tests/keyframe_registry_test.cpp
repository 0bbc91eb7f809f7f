// Job: unit tests of the keyframe-id -> object registry
// (humem/keyframe_registry.h).
#include "humem/keyframe_registry.h"

#include <gtest/gtest.h>

#include <thread>
#include <vector>

namespace {

struct FakeKeyFrame {
  uint64_t id;
};

TEST(KeyframeRegistry, ResolvesRegisteredIdsOnly) {
  humem::KeyframeRegistry<FakeKeyFrame> registry;
  FakeKeyFrame a{1}, b{2};
  registry.Add(1, &a);
  registry.Add(2, &b);
  EXPECT_EQ(registry.Find(1), &a);
  EXPECT_EQ(registry.Find(2), &b);
  EXPECT_EQ(registry.Find(3), nullptr);
  EXPECT_EQ(registry.FindAll({2, 3, 1}), (std::vector<FakeKeyFrame*>{&b, nullptr, &a}));
  EXPECT_TRUE(registry.Remove(1));
  EXPECT_FALSE(registry.Remove(1));
  EXPECT_EQ(registry.Find(1), nullptr);
  EXPECT_EQ(registry.size(), 1u);
}

TEST(KeyframeRegistry, AddRepointsAndClearForgetsEverything) {
  humem::KeyframeRegistry<FakeKeyFrame> registry;
  FakeKeyFrame old_kf{7}, new_kf{7};
  registry.Add(7, &old_kf);
  registry.Add(7, &new_kf);  // ids restart after a full reset
  EXPECT_EQ(registry.Find(7), &new_kf);
  EXPECT_EQ(registry.size(), 1u);
  registry.Clear();
  EXPECT_EQ(registry.size(), 0u);
  EXPECT_EQ(registry.Find(7), nullptr);
}

TEST(KeyframeRegistry, WorksWithVoidPointers) {
  humem::KeyframeRegistry<void> registry;
  int x = 0;
  registry.Add(5, &x);
  EXPECT_EQ(registry.Find(5), static_cast<void*>(&x));
}

TEST(KeyframeRegistry, ConcurrentAddsFindsAndRemoves) {
  humem::KeyframeRegistry<FakeKeyFrame> registry;
  std::vector<FakeKeyFrame> frames(4000);
  for (size_t i = 0; i < frames.size(); ++i) frames[i].id = i;
  std::vector<std::thread> threads;
  for (size_t t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (size_t i = t; i < frames.size(); i += 4) {
        registry.Add(i, &frames[i]);
        FakeKeyFrame* found = registry.Find(i);
        if (found == nullptr || found->id != i) ADD_FAILURE() << "id " << i;
        if (i % 2 == 1) registry.Remove(i);
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(registry.size(), frames.size() / 2);
  EXPECT_EQ(registry.Find(10), &frames[10]);
  EXPECT_EQ(registry.Find(11), nullptr);
}

}  // namespace
