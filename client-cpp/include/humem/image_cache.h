// Job: a small thread-safe ring cache of frame images keyed by frame id.
//
// ORB-SLAM3 keyframes do not keep their image, and the monocular initial
// keyframe is made from a frame many frames old; the tracking thread puts
// every frame's image here and the plugin looks the keyframe's frame up
// when it inserts it. Fixed capacity; when full, the entry put longest ago
// is evicted (lookups do not refresh it). Header-only, C++11.
#ifndef HUMEM_IMAGE_CACHE_H_
#define HUMEM_IMAGE_CACHE_H_

#include <cstddef>
#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <unordered_map>
#include <utility>

#include "humem/types.h"

namespace humem {

// Frame id -> T, holding at most `capacity` entries.
template <typename T>
class RingCache {
 public:
  explicit RingCache(size_t capacity) : capacity_(capacity) {
    if (capacity == 0) throw std::invalid_argument("humem::RingCache: capacity must be at least 1");
  }

  // Stores `value` for `frame_id`, replacing (and renewing) an entry with the
  // same id; evicts the oldest entry when full.
  void Put(uint64_t frame_id, T value) {
    std::lock_guard<std::mutex> lock(mutex_);
    typename Index::iterator it = index_.find(frame_id);
    if (it != index_.end()) {
      order_.erase(it->second);
      index_.erase(it);
    } else if (order_.size() == capacity_) {
      index_.erase(order_.front().first);
      order_.pop_front();
    }
    order_.push_back(std::make_pair(frame_id, std::move(value)));
    typename Order::iterator last = order_.end();
    --last;
    index_[frame_id] = last;
  }

  // Copies the value of `frame_id` to *out; false if absent (or evicted).
  bool Get(uint64_t frame_id, T* out) const {
    std::lock_guard<std::mutex> lock(mutex_);
    typename Index::const_iterator it = index_.find(frame_id);
    if (it == index_.end()) return false;
    *out = it->second->second;
    return true;
  }

  bool Contains(uint64_t frame_id) const {
    std::lock_guard<std::mutex> lock(mutex_);
    return index_.count(frame_id) != 0;
  }

  bool Erase(uint64_t frame_id) {
    std::lock_guard<std::mutex> lock(mutex_);
    typename Index::iterator it = index_.find(frame_id);
    if (it == index_.end()) return false;
    order_.erase(it->second);
    index_.erase(it);
    return true;
  }

  void Clear() {
    std::lock_guard<std::mutex> lock(mutex_);
    order_.clear();
    index_.clear();
  }

  size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return order_.size();
  }
  size_t capacity() const { return capacity_; }

 private:
  typedef std::list<std::pair<uint64_t, T> > Order;  // oldest first
  typedef std::unordered_map<uint64_t, typename Order::iterator> Index;

  const size_t capacity_;
  mutable std::mutex mutex_;
  Order order_;
  Index index_;
};

// The cache of camera images: shared, immutable images, so a lookup costs a
// reference count, and the image can go straight into Keyframe::image.
typedef RingCache<std::shared_ptr<const Image> > ImageCache;

}  // namespace humem

#endif  // HUMEM_IMAGE_CACHE_H_
