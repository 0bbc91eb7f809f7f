// Job: Pose <-> 4x4 matrix conversions (rotation matrix <-> quaternion,
// Shepperd's method, numerically safe for every rotation).
#include <cmath>

#include "humem/types.h"

namespace humem {
namespace {

// m(r, c) of a 16-value matrix in either storage order.
template <typename T>
struct MatrixView {
  const T* m;
  bool row_major;
  double operator()(int r, int c) const {
    return static_cast<double>(row_major ? m[r * 4 + c] : m[c * 4 + r]);
  }
};

template <typename T>
Pose FromMatrix(MatrixView<T> m) {
  Pose pose;
  pose.translation = Vec3(m(0, 3), m(1, 3), m(2, 3));
  const double trace = m(0, 0) + m(1, 1) + m(2, 2);
  Quaternion& q = pose.rotation;
  if (trace > 0) {
    const double s = std::sqrt(trace + 1.0) * 2;  // 4w
    q.w = 0.25 * s;
    q.x = (m(2, 1) - m(1, 2)) / s;
    q.y = (m(0, 2) - m(2, 0)) / s;
    q.z = (m(1, 0) - m(0, 1)) / s;
  } else if (m(0, 0) > m(1, 1) && m(0, 0) > m(2, 2)) {
    const double s = std::sqrt(1.0 + m(0, 0) - m(1, 1) - m(2, 2)) * 2;  // 4x
    q.w = (m(2, 1) - m(1, 2)) / s;
    q.x = 0.25 * s;
    q.y = (m(0, 1) + m(1, 0)) / s;
    q.z = (m(0, 2) + m(2, 0)) / s;
  } else if (m(1, 1) > m(2, 2)) {
    const double s = std::sqrt(1.0 + m(1, 1) - m(0, 0) - m(2, 2)) * 2;  // 4y
    q.w = (m(0, 2) - m(2, 0)) / s;
    q.x = (m(0, 1) + m(1, 0)) / s;
    q.y = 0.25 * s;
    q.z = (m(1, 2) + m(2, 1)) / s;
  } else {
    const double s = std::sqrt(1.0 + m(2, 2) - m(0, 0) - m(1, 1)) * 2;  // 4z
    q.w = (m(1, 0) - m(0, 1)) / s;
    q.x = (m(0, 2) + m(2, 0)) / s;
    q.y = (m(1, 2) + m(2, 1)) / s;
    q.z = 0.25 * s;
  }
  return pose;
}

}  // namespace

Pose Pose::FromMatrixRowMajor(const double* m16) { return FromMatrix(MatrixView<double>{m16, true}); }
Pose Pose::FromMatrixRowMajor(const float* m16) { return FromMatrix(MatrixView<float>{m16, true}); }
Pose Pose::FromMatrixColumnMajor(const double* m16) { return FromMatrix(MatrixView<double>{m16, false}); }
Pose Pose::FromMatrixColumnMajor(const float* m16) { return FromMatrix(MatrixView<float>{m16, false}); }

void Pose::ToMatrixRowMajor(double* m) const {
  double w = rotation.w, x = rotation.x, y = rotation.y, z = rotation.z;
  const double n = std::sqrt(w * w + x * x + y * y + z * z);
  if (n > 0) {
    w /= n;
    x /= n;
    y /= n;
    z /= n;
  } else {
    w = 1;
  }
  m[0] = 1 - 2 * (y * y + z * z);
  m[1] = 2 * (x * y - w * z);
  m[2] = 2 * (x * z + w * y);
  m[3] = translation.x;
  m[4] = 2 * (x * y + w * z);
  m[5] = 1 - 2 * (x * x + z * z);
  m[6] = 2 * (y * z - w * x);
  m[7] = translation.y;
  m[8] = 2 * (x * z - w * y);
  m[9] = 2 * (y * z + w * x);
  m[10] = 1 - 2 * (x * x + y * y);
  m[11] = translation.z;
  m[12] = 0;
  m[13] = 0;
  m[14] = 0;
  m[15] = 1;
}

}  // namespace humem
