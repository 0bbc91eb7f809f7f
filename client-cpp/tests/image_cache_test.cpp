// Job: unit tests of the frame image ring cache (humem/image_cache.h).
#include "humem/image_cache.h"

#include <gtest/gtest.h>

#include <atomic>
#include <stdexcept>
#include <thread>
#include <vector>

namespace {

TEST(RingCache, EvictsTheOldestEntryWhenFull) {
  humem::RingCache<int> cache(3);
  for (uint64_t id = 1; id <= 4; ++id) cache.Put(id, static_cast<int>(id) * 10);
  EXPECT_EQ(cache.size(), 3u);
  int value = 0;
  EXPECT_FALSE(cache.Get(1, &value));
  for (uint64_t id = 2; id <= 4; ++id) {
    ASSERT_TRUE(cache.Get(id, &value)) << id;
    EXPECT_EQ(value, static_cast<int>(id) * 10);
  }
}

TEST(RingCache, PuttingAnIdAgainReplacesAndRenewsIt) {
  humem::RingCache<int> cache(3);
  cache.Put(1, 1);
  cache.Put(2, 2);
  cache.Put(3, 3);
  cache.Put(1, 100);  // 1 is now the newest
  cache.Put(4, 4);    // evicts 2, the oldest
  int value = 0;
  ASSERT_TRUE(cache.Get(1, &value));
  EXPECT_EQ(value, 100);
  EXPECT_FALSE(cache.Contains(2));
  EXPECT_TRUE(cache.Contains(3));
  EXPECT_TRUE(cache.Contains(4));
  EXPECT_EQ(cache.size(), 3u);
}

TEST(RingCache, LookupsDoNotRefreshAndEraseAndClearWork) {
  humem::RingCache<int> cache(2);
  cache.Put(1, 1);
  cache.Put(2, 2);
  int value = 0;
  ASSERT_TRUE(cache.Get(1, &value));  // does not make 1 newer
  cache.Put(3, 3);
  EXPECT_FALSE(cache.Contains(1));
  EXPECT_TRUE(cache.Erase(2));
  EXPECT_FALSE(cache.Erase(2));
  EXPECT_EQ(cache.size(), 1u);
  cache.Clear();
  EXPECT_EQ(cache.size(), 0u);
  EXPECT_EQ(cache.capacity(), 2u);
}

TEST(RingCache, ZeroCapacityIsRefused) {
  EXPECT_THROW(humem::RingCache<int>(0), std::invalid_argument);
}

TEST(ImageCache, SharesImagesWithoutCopying) {
  humem::ImageCache cache(4);
  const uint8_t pixels[4 * 2] = {1, 2, 3, 4, 5, 6, 7, 8};
  auto image = std::make_shared<const humem::Image>(
      humem::Image::Raw(humem::Image::kGray8, pixels, 2, 2, /*stride=*/4));
  cache.Put(42, image);
  std::shared_ptr<const humem::Image> got;
  ASSERT_TRUE(cache.Get(42, &got));
  EXPECT_EQ(got.get(), image.get());
  // Raw() packed the rows (stride 4 -> 2).
  EXPECT_EQ(got->data, (std::vector<uint8_t>{1, 2, 5, 6}));
  EXPECT_EQ(got->width, 2u);
  EXPECT_EQ(got->height, 2u);
}

TEST(RingCache, ConcurrentPutsAndGetsKeepItConsistent) {
  humem::RingCache<uint64_t> cache(16);
  std::atomic<bool> wrong{false};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (uint64_t i = 0; i < 5000; ++i) {
        const uint64_t id = i * 4 + static_cast<uint64_t>(t);
        cache.Put(id, id * 2);
        uint64_t value = 0;
        for (uint64_t probe = id; probe + 8 > id && probe > 0; --probe) {
          if (cache.Get(probe, &value) && value != probe * 2) wrong = true;
        }
        if (cache.size() > 16) wrong = true;
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_FALSE(wrong);
  EXPECT_EQ(cache.size(), 16u);
}

}  // namespace
