// 3-vectors and 3x3 matrices of any scalar, with the operations of the kernels. Each function
// keeps the operation order of its formula as written (left to right), so that every scalar type
// computes the same rounding sequence: bit-identity between a lane and its run depends on it.
#pragma once

#include <array>

namespace mms {

template <class S> using Vec3 = std::array<S, 3>;
template <class S> using Mat3 = std::array<std::array<S, 3>, 3>;
using Vec3d = Vec3<double>;
using Mat3d = Mat3<double>;

template <class S>
inline Vec3<S> add(const Vec3<S>& a, const Vec3<S>& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
template <class S>
inline Vec3<S> sub(const Vec3<S>& a, const Vec3<S>& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
template <class A, class S>
inline Vec3<S> scale(const A& s, const Vec3<S>& a) { return {s * a[0], s * a[1], s * a[2]}; }
// s·a + b
template <class A, class S>
inline Vec3<S> axpy(const A& s, const Vec3<S>& a, const Vec3<S>& b) {
  return {s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2]};
}
template <class S>
inline S dot(const Vec3<S>& a, const Vec3<S>& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
template <class S>
inline Vec3<S> cross(const Vec3<S>& a, const Vec3<S>& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
// R · a (R may hold constants: a model's rotation or inertia)
template <class M, class S>
inline Vec3<S> matvec(const Mat3<M>& R, const Vec3<S>& a) {
  return {R[0][0] * a[0] + R[0][1] * a[1] + R[0][2] * a[2],
          R[1][0] * a[0] + R[1][1] * a[1] + R[1][2] * a[2],
          R[2][0] * a[0] + R[2][1] * a[1] + R[2][2] * a[2]};
}
// Rᵀ · a
template <class S>
inline Vec3<S> tmatvec(const Mat3<S>& R, const Vec3<S>& a) {
  return {R[0][0] * a[0] + R[1][0] * a[1] + R[2][0] * a[2],
          R[0][1] * a[0] + R[1][1] * a[1] + R[2][1] * a[2],
          R[0][2] * a[0] + R[1][2] * a[1] + R[2][2] * a[2]};
}
template <class S>
inline Vec3<S> zero3() { return {S(0.0), S(0.0), S(0.0)}; }

}  // namespace mms
