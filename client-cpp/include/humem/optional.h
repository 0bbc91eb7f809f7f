// Job: a minimal optional value for C++11 callers (std::optional is C++17).
// The proto's `optional` fields map to it, so "not set" is told apart from 0.
#ifndef HUMEM_OPTIONAL_H_
#define HUMEM_OPTIONAL_H_

namespace humem {

// Holds a T or nothing. Assigning a T sets it: `request.map_id = 3;`.
template <typename T>
class Optional {
 public:
  Optional() : has_(false), value_() {}
  Optional(const T& value) : has_(true), value_(value) {}  // NOLINT: implicit on purpose

  Optional& operator=(const T& value) {
    has_ = true;
    value_ = value;
    return *this;
  }

  bool has_value() const { return has_; }
  // The value; T() when unset.
  const T& value() const { return value_; }
  T& value() { return value_; }
  const T& value_or(const T& fallback) const { return has_ ? value_ : fallback; }
  void reset() {
    has_ = false;
    value_ = T();
  }

  bool operator==(const Optional& other) const {
    return has_ == other.has_ && (!has_ || value_ == other.value_);
  }
  bool operator!=(const Optional& other) const { return !(*this == other); }

 private:
  bool has_;
  T value_;
};

}  // namespace humem

#endif  // HUMEM_OPTIONAL_H_
