// Job: a thread-safe map from keyframe id to the SLAM system's keyframe
// object, so the plugin can turn the ids HuMem returns into live
// KeyFrame* (HuMem only knows ids).
//
// The registry stores plain pointers and owns nothing: the caller keeps the
// objects alive while registered (ORB-SLAM3 never deletes a KeyFrame while
// the system runs; it marks culled ones bad, and the plugin removes them
// here when it erases them from HuMem). Ids are those of the client's own
// robot and session: resolve only candidates whose robot_id and session_id
// are the client's, and Clear() after a full reset, when ids restart.
// Header-only, C++11.
#ifndef HUMEM_KEYFRAME_REGISTRY_H_
#define HUMEM_KEYFRAME_REGISTRY_H_

#include <cstddef>
#include <cstdint>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace humem {

template <typename KeyFrameT>
class KeyframeRegistry {
 public:
  // Registers (or re-points) `keyframe_id`.
  void Add(uint64_t keyframe_id, KeyFrameT* keyframe) {
    std::lock_guard<std::mutex> lock(mutex_);
    map_[keyframe_id] = keyframe;
  }

  // Unregisters; false if it was not registered.
  bool Remove(uint64_t keyframe_id) {
    std::lock_guard<std::mutex> lock(mutex_);
    return map_.erase(keyframe_id) != 0;
  }

  // The keyframe of `keyframe_id`, or null.
  KeyFrameT* Find(uint64_t keyframe_id) const {
    std::lock_guard<std::mutex> lock(mutex_);
    typename Map::const_iterator it = map_.find(keyframe_id);
    return it == map_.end() ? nullptr : it->second;
  }

  // Finds each id in one locked pass; unknown ids give null entries.
  std::vector<KeyFrameT*> FindAll(const std::vector<uint64_t>& keyframe_ids) const {
    std::vector<KeyFrameT*> found;
    found.reserve(keyframe_ids.size());
    std::lock_guard<std::mutex> lock(mutex_);
    for (size_t i = 0; i < keyframe_ids.size(); ++i) {
      typename Map::const_iterator it = map_.find(keyframe_ids[i]);
      found.push_back(it == map_.end() ? nullptr : it->second);
    }
    return found;
  }

  void Clear() {
    std::lock_guard<std::mutex> lock(mutex_);
    map_.clear();
  }

  size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return map_.size();
  }

 private:
  typedef std::unordered_map<uint64_t, KeyFrameT*> Map;
  mutable std::mutex mutex_;
  Map map_;
};

}  // namespace humem

#endif  // HUMEM_KEYFRAME_REGISTRY_H_
