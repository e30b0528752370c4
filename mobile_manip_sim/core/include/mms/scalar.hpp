// The scalar types the core is instantiated for, and the few functions every kernel needs of
// them (sin, cos, sqrt, select). One source, many scalars, as in Pinocchio and Drake:
//
//   double                  one run;
//   Lanes<W>                W runs side by side, one per lane of a vector register (W = 4 with
//                           AVX2, 8 with AVX-512: `kLaneWidth`, chosen when the core is built);
//   Dual<T, D>              a value T and its derivatives along several directions D (a Lanes:
//                           the directions sit in the lanes of one register).
//
// IEEE arithmetic throughout: the core is built with -ffp-contract=off and without fast-math
// (`build_info` reports both), so that a lane is bit for bit the run it stands for and the value
// part of a Dual bit for bit the double computation. sin and cos are libm's, lane by lane: a
// vector approximation would differ from the scalar run in the last bits.
#pragma once

#include <cmath>

namespace mms {

#if defined(__AVX512F__)
constexpr int kLaneWidth = 8;
#else
constexpr int kLaneWidth = 4;
#endif

// ---------------------------------------------------------------------------------------------
// Lanes<W>: W doubles, one per run, in a GCC/Clang vector (the compiler emits packed vmulpd etc.)
// GCC ignores vector_size on a typedef whose size depends on a template parameter: one
// specialisation per width.
template <int W> struct VectorOf;
template <> struct VectorOf<4> {
  typedef double Vector __attribute__((vector_size(32)));
  typedef long long Mask __attribute__((vector_size(32)));
};
template <> struct VectorOf<8> {
  typedef double Vector __attribute__((vector_size(64)));
  typedef long long Mask __attribute__((vector_size(64)));
};

template <int W>
struct Lanes {
  typedef typename VectorOf<W>::Vector Vector;
  typedef typename VectorOf<W>::Mask Mask;
  static constexpr int width = W;
  Vector v;

  Lanes() = default;
  Lanes(double a) {  // broadcast (a loop, not 0 + a, which would turn -0.0 into +0.0)
    for (int i = 0; i < W; ++i) v[i] = a;
  }
  static Lanes of(Vector x) {
    Lanes r;
    r.v = x;
    return r;
  }
  double operator[](int i) const { return v[i]; }
  void set(int i, double a) { v[i] = a; }
};

template <int W> inline Lanes<W> operator+(Lanes<W> a, Lanes<W> b) { return Lanes<W>::of(a.v + b.v); }
template <int W> inline Lanes<W> operator-(Lanes<W> a, Lanes<W> b) { return Lanes<W>::of(a.v - b.v); }
template <int W> inline Lanes<W> operator*(Lanes<W> a, Lanes<W> b) { return Lanes<W>::of(a.v * b.v); }
template <int W> inline Lanes<W> operator/(Lanes<W> a, Lanes<W> b) { return Lanes<W>::of(a.v / b.v); }
template <int W> inline Lanes<W> operator-(Lanes<W> a) { return Lanes<W>::of(-a.v); }
template <int W> inline Lanes<W> operator+(double a, Lanes<W> b) { return Lanes<W>(a) + b; }
template <int W> inline Lanes<W> operator-(double a, Lanes<W> b) { return Lanes<W>(a) - b; }
template <int W> inline Lanes<W> operator*(double a, Lanes<W> b) { return Lanes<W>(a) * b; }
template <int W> inline Lanes<W> operator/(double a, Lanes<W> b) { return Lanes<W>(a) / b; }
template <int W> inline Lanes<W> operator+(Lanes<W> a, double b) { return a + Lanes<W>(b); }
template <int W> inline Lanes<W> operator-(Lanes<W> a, double b) { return a - Lanes<W>(b); }
template <int W> inline Lanes<W> operator*(Lanes<W> a, double b) { return a * Lanes<W>(b); }
template <int W> inline Lanes<W> operator/(Lanes<W> a, double b) { return a / Lanes<W>(b); }
template <int W, class B> inline Lanes<W>& operator+=(Lanes<W>& a, B b) { return a = a + b; }
template <int W, class B> inline Lanes<W>& operator-=(Lanes<W>& a, B b) { return a = a - b; }
template <int W, class B> inline Lanes<W>& operator*=(Lanes<W>& a, B b) { return a = a * b; }

// ---------------------------------------------------------------------------------------------
// Dual<T, D>: value and derivatives along the directions of D, forward mode.
template <class T, class D>
struct Dual {
  T val;
  D d;
  Dual() = default;
  Dual(double a) : val(a), d(0.0) {}
  Dual(T a, D b) : val(a), d(b) {}
};

template <class T, class D>
inline Dual<T, D> operator+(const Dual<T, D>& a, const Dual<T, D>& b) { return {a.val + b.val, a.d + b.d}; }
template <class T, class D>
inline Dual<T, D> operator-(const Dual<T, D>& a, const Dual<T, D>& b) { return {a.val - b.val, a.d - b.d}; }
template <class T, class D>
inline Dual<T, D> operator-(const Dual<T, D>& a) { return {-a.val, -a.d}; }
template <class T, class D>
inline Dual<T, D> operator*(const Dual<T, D>& a, const Dual<T, D>& b) {
  return {a.val * b.val, a.d * b.val + a.val * b.d};
}
template <class T, class D>
inline Dual<T, D> operator/(const Dual<T, D>& a, const Dual<T, D>& b) {
  T q = a.val / b.val;
  return {q, (a.d - q * b.d) / b.val};
}
template <class T, class D>
inline Dual<T, D> operator+(double a, const Dual<T, D>& b) { return {a + b.val, b.d}; }
template <class T, class D>
inline Dual<T, D> operator+(const Dual<T, D>& a, double b) { return {a.val + b, a.d}; }
template <class T, class D>
inline Dual<T, D> operator-(double a, const Dual<T, D>& b) { return {a - b.val, -b.d}; }
template <class T, class D>
inline Dual<T, D> operator-(const Dual<T, D>& a, double b) { return {a.val - b, a.d}; }
template <class T, class D>
inline Dual<T, D> operator*(double a, const Dual<T, D>& b) { return {a * b.val, a * b.d}; }
template <class T, class D>
inline Dual<T, D> operator*(const Dual<T, D>& a, double b) { return {a.val * b, a.d * b}; }
template <class T, class D>
inline Dual<T, D> operator/(const Dual<T, D>& a, double b) { return {a.val / b, a.d / b}; }
template <class T, class D>
inline Dual<T, D> operator/(double a, const Dual<T, D>& b) {
  T q = a / b.val;
  return {q, -(q * b.d) / b.val};
}
template <class T, class D, class B> inline Dual<T, D>& operator+=(Dual<T, D>& a, const B& b) { return a = a + b; }
template <class T, class D, class B> inline Dual<T, D>& operator-=(Dual<T, D>& a, const B& b) { return a = a - b; }
template <class T, class D, class B> inline Dual<T, D>& operator*=(Dual<T, D>& a, const B& b) { return a = a * b; }

// ---------------------------------------------------------------------------------------------
// The plain number under a scalar: what masks, comparisons and selections act on.
template <class S> struct Traits;
template <> struct Traits<double> {
  using Real = double;
  using Mask = bool;
};
template <int W> struct Traits<Lanes<W>> {
  using Real = Lanes<W>;
  using Mask = typename Lanes<W>::Mask;
};
template <class T, class D> struct Traits<Dual<T, D>> {
  using Real = typename Traits<T>::Real;
  using Mask = typename Traits<T>::Mask;
};
template <class S> using RealOf = typename Traits<S>::Real;
template <class S> using MaskOf = typename Traits<S>::Mask;

inline double value(double a) { return a; }
template <int W> inline Lanes<W> value(Lanes<W> a) { return a; }
template <class T, class D> inline T value(const Dual<T, D>& a) { return a.val; }

// comparisons of lanes, lane by lane: masks for `select`
template <int W> inline typename Lanes<W>::Mask operator<(Lanes<W> a, Lanes<W> b) { return a.v < b.v; }
template <int W> inline typename Lanes<W>::Mask operator>(Lanes<W> a, Lanes<W> b) { return a.v > b.v; }
template <int W> inline typename Lanes<W>::Mask operator<(Lanes<W> a, double b) { return a.v < b; }
template <int W> inline typename Lanes<W>::Mask operator>(Lanes<W> a, double b) { return a.v > b; }
template <int W> inline typename Lanes<W>::Mask operator<(double a, Lanes<W> b) { return a < b.v; }
template <int W> inline typename Lanes<W>::Mask operator>(double a, Lanes<W> b) { return a > b.v; }

// is_zero(a): a == 0.0 per lane (the mask of `select`)
inline bool is_zero(double a) { return a == 0.0; }
template <int W> inline typename Lanes<W>::Mask is_zero(Lanes<W> a) { return a.v == 0.0; }
inline bool is_positive(double a) { return a > 0.0; }
template <int W> inline typename Lanes<W>::Mask is_positive(Lanes<W> a) { return a.v > 0.0; }

// select(m, a, b): a where m holds, else b, lane by lane
inline double select(bool m, double a, double b) { return m ? a : b; }
template <int W>
inline Lanes<W> select(typename Lanes<W>::Mask m, Lanes<W> a, Lanes<W> b) {
  return Lanes<W>::of(m ? a.v : b.v);
}
template <class T, class D, class M>
inline Dual<T, D> select(M m, const Dual<T, D>& a, const Dual<T, D>& b) {
  return {select(m, a.val, b.val), select(m, a.d, b.d)};
}
template <int W>
inline Lanes<W> select(bool m, Lanes<W> a, Lanes<W> b) { return m ? a : b; }

// ---------------------------------------------------------------------------------------------
// sin, cos, sqrt
inline double sin_(double a) { return std::sin(a); }
inline double cos_(double a) { return std::cos(a); }
inline double sqrt_(double a) { return std::sqrt(a); }
template <int W> inline Lanes<W> sin_(Lanes<W> a) {
  Lanes<W> r;
  for (int i = 0; i < W; ++i) r.v[i] = std::sin(a.v[i]);
  return r;
}
template <int W> inline Lanes<W> cos_(Lanes<W> a) {
  Lanes<W> r;
  for (int i = 0; i < W; ++i) r.v[i] = std::cos(a.v[i]);
  return r;
}
template <int W> inline Lanes<W> sqrt_(Lanes<W> a) {
  Lanes<W> r;
  for (int i = 0; i < W; ++i) r.v[i] = std::sqrt(a.v[i]);
  return r;
}
// sin and cos of one angle at once: libm's sincos, lane by lane, one range reduction for both
// (its results are libm's sin and cos, bit for bit; GCC already turns a double's sin(x) and
// cos(x) into it)
inline void sincos_(double a, double& s, double& c) {
  s = std::sin(a);
  c = std::cos(a);
}
template <int W> inline void sincos_(Lanes<W> a, Lanes<W>& s, Lanes<W>& c) {
  for (int i = 0; i < W; ++i) {
    double si, ci;
    ::sincos(a.v[i], &si, &ci);
    s.v[i] = si;
    c.v[i] = ci;
  }
}
template <class T, class D> inline Dual<T, D> sin_(const Dual<T, D>& a) {
  return {sin_(a.val), cos_(a.val) * a.d};
}
template <class T, class D> inline Dual<T, D> cos_(const Dual<T, D>& a) {
  return {cos_(a.val), -sin_(a.val) * a.d};
}
template <class T, class D> inline void sincos_(const Dual<T, D>& a, Dual<T, D>& s, Dual<T, D>& c) {
  T sv, cv;
  sincos_(a.val, sv, cv);
  s = {sv, cv * a.d};
  c = {cv, -sv * a.d};
}
template <class T, class D> inline Dual<T, D> sqrt_(const Dual<T, D>& a) {
  T r = sqrt_(a.val);
  return {r, a.d / (2.0 * r)};
}

}  // namespace mms
