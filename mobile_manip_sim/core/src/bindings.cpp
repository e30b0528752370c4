// Python bindings of the compiled core (nanobind): `Dynamics`, one robot's model with a workspace
// per scalar type, and `build_info`. Arrays in and out are NumPy float64, C order.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <cstring>
#include <numeric>
#include <ctime>
#include <stdexcept>
#include <string>
#include <vector>

#include "mms/adaptive_solve.hpp"
#include "mms/articulated.hpp"
#include "mms/dynamics.hpp"
#include "mms/event_jacobians.hpp"
#include "mms/fixed_step.hpp"
#include "mms/adaptive_stepping.hpp"
#include "mms/lanes.hpp"
#include "mms/stepping.hpp"

namespace nb = nanobind;
using namespace nb::literals;

namespace mms {

// --- for the benchmarks (bench/) ------------------------------------------------------------
// A double that counts the arithmetic done on it: the kernels instantiated on it once count the
// flops of one evaluation, in the kernels' own operation order (bench/'s lanes section). Only
// operations on state-dependent numbers count: a product of two model constants is a double's.
struct FlopCounts {
  long add = 0, sub = 0, mul = 0, div = 0, neg = 0, sqrt = 0, sin = 0, cos = 0;
};
inline FlopCounts flop_counts;

struct Counted {
  double v = 0.0;
  Counted() = default;
  Counted(double a) : v(a) {}  // NOLINT: implicit, as a double's literal in the kernels
};
inline Counted operator+(Counted a, Counted b) { ++flop_counts.add; return a.v + b.v; }
inline Counted operator-(Counted a, Counted b) { ++flop_counts.sub; return a.v - b.v; }
inline Counted operator*(Counted a, Counted b) { ++flop_counts.mul; return a.v * b.v; }
inline Counted operator/(Counted a, Counted b) { ++flop_counts.div; return a.v / b.v; }
inline Counted operator-(Counted a) { ++flop_counts.neg; return -a.v; }
inline Counted& operator+=(Counted& a, Counted b) { return a = a + b; }
inline Counted& operator-=(Counted& a, Counted b) { return a = a - b; }
inline Counted& operator*=(Counted& a, Counted b) { return a = a * b; }
inline bool operator<(Counted a, Counted b) { return a.v < b.v; }
inline bool operator>(Counted a, Counted b) { return a.v > b.v; }
template <> struct Traits<Counted> {
  using Real = double;
  using Mask = bool;
};
inline double value(Counted a) { return a.v; }
inline Counted select(bool m, Counted a, Counted b) { return m ? a : b; }
inline Counted sin_(Counted a) { ++flop_counts.sin; return std::sin(a.v); }
inline Counted cos_(Counted a) { ++flop_counts.cos; return std::cos(a.v); }
inline Counted sqrt_(Counted a) { ++flop_counts.sqrt; return std::sqrt(a.v); }
inline void sincos_(Counted a, Counted& s, Counted& c) { s = sin_(a); c = cos_(a); }

namespace {

using In = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
using Out = nb::ndarray<nb::numpy, double>;
using Block = Lanes<kLaneWidth>;
constexpr int kDirections = 8;  // derivative directions per pass: one Lanes<8> per number
using Directions = Lanes<kDirections>;
using DualD = Dual<double, Directions>;

Out new_array(std::initializer_list<size_t> shape, double** data) {
  size_t count = 1;
  for (size_t s : shape) count *= s;
  double* buffer = new double[count ? count : 1];
  std::memset(buffer, 0, sizeof(double) * (count ? count : 1));
  nb::capsule owner(buffer, [](void* p) noexcept { delete[] static_cast<double*>(p); });
  *data = buffer;
  return Out(buffer, shape.size(), shape.begin(), owner);
}

template <class Array>
void need(const Array& a, size_t size, const char* name) {
  if (a.size() != size)
    throw std::invalid_argument(std::string(name) + ": expected " + std::to_string(size) +
                                " numbers, got " + std::to_string(a.size()));
}

Method method_of(const std::string& name) {
  if (name == "euler") return Method::Euler;
  if (name == "semi_implicit_euler") return Method::SemiImplicitEuler;
  if (name == "rk4") return Method::Rk4;
  throw std::invalid_argument("method: expected euler, semi_implicit_euler or rk4, got " + name);
}

// CPU seconds of this thread per call of `body`, over `calls` calls after one to warm up.
template <class F>
double per_call(int calls, F&& body) {
  body();
  timespec start, end;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &start);
  for (int i = 0; i < calls; ++i) body();
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &end);
  double seconds = (end.tv_sec - start.tv_sec) + 1e-9 * (end.tv_nsec - start.tv_nsec);
  return seconds / (calls > 0 ? calls : 1);
}

// The unit derivative direction j, in the pass of directions first … first + kDirections − 1
// (zero outside it).
Directions direction(int first, int j) {
  Directions d(0.0);
  if (j >= first && j < first + kDirections) d.set(j - first, 1.0);
  return d;
}

// Dual numbers seeded for the pass of directions first … first + kDirections − 1 of exact
// Jacobians: direction j seeds x_j (j < n_x: the first n_x entries of s), else the effort j − n_x,
// whose generalized forces are Q_cmd + B (τ − τ₀) (B: n_u × n_τ).
void seed_pass(int first, const double* s, int size, int nx, const double* Q_cmd, const double* B,
               int nu, int ntau, DualD* sd, DualD* Qd) {
  auto seed = [&](int j) { return direction(first, j); };
  for (int i = 0; i < size; ++i) sd[i] = DualD(s[i], i < nx ? seed(i) : Directions(0.0));
  for (int i = 0; i < nu; ++i) {
    Directions d(0.0);
    for (int j = 0; j < ntau; ++j) d = d + B[i * ntau + j] * seed(nx + j);
    Qd[i] = DualD(Q_cmd[i], d);
  }
}

// The pass's results out (n_x) into value (n_x), ∂/∂x (n_x × n_x), ∂/∂τ (n_x × n_τ), row-major.
void read_pass(int first, const DualD* out, int nx, int ntau, double* value, double* dx,
               double* dtau) {
  for (int r = 0; r < nx; ++r) {
    value[r] = out[r].val;
    for (int lane = 0; lane < kDirections && first + lane < nx + ntau; ++lane) {
      int j = first + lane;
      if (j < nx) dx[r * nx + j] = out[r].d[lane];
      else dtau[r * ntau + j - nx] = out[r].d[lane];
    }
  }
}

class Dynamics {
 public:
  Dynamics(BaseParameters base, In mount, In R0, In L, In mu, In J, double tip_mass)
      : ws_(0), system_(Model()) {
    size_t n = L.size();
    need(mount, 3, "mount");
    need(R0, 9 * n, "R0");
    need(mu, n, "mu");
    need(J, 9 * n, "J");
    model_.base = base;
    for (int i = 0; i < 3; ++i) model_.mount[i] = mount.data()[i];
    model_.R0.resize(n);
    model_.J.resize(n);
    for (size_t k = 0; k < n; ++k) {
      model_.L.push_back(L.data()[k]);
      model_.mu.push_back(mu.data()[k]);
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          model_.R0[k][i][j] = R0.data()[9 * k + 3 * i + j];
          model_.J[k][i][j] = J.data()[9 * k + 3 * i + j];
        }
    }
    model_.tip_mass = tip_mass;
    ws_ = Workspace<double>(model_.n());
    system_ = SystemWorkspace<double>(model_);
  }

  int n() const { return model_.n(); }
  int n_q() const { return model_.n_q(); }
  int n_u() const { return model_.n_u(); }
  const Model& model() const { return model_; }

  Out inverse_dynamics(In q, In u, In ud, double g) {
    check(q, u, ud);
    double* Q;
    Out out = new_array({size_t(n_u())}, &Q);
    frames(model_, q.data(), ws_);
    mms::inverse_dynamics(model_, q.data(), u.data(), ud.data(), g, ws_, Q);
    return out;
  }

  Out mass_matrix(In q) {
    need(q, n_q(), "q");
    double* M;
    Out out = new_array({size_t(n_u()), size_t(n_u())}, &M);
    frames(model_, q.data(), ws_);
    mms::mass_matrix(model_, ws_, q.data(), M);
    return out;
  }

  Out forward_dynamics(In q, In u, In Q, double g, In moving) {
    check(q, u, Q);
    need(moving, n_u(), "moving");
    double* ud;
    Out out = new_array({size_t(n_u())}, &ud);
    for (int k = 0; k < n_u(); ++k) ws_.moving[k] = moving.data()[k];
    frames(model_, q.data(), ws_);
    mms::forward_dynamics(model_, q.data(), u.data(), Q.data(), g, ws_, ud);
    return out;
  }

  // The force each slide transmits in the last forward_dynamics (index k = 1 … n; 0 unused).
  Out slide_forces() {
    double* f;
    Out out = new_array({size_t(n() + 1)}, &f);
    for (int k = 0; k <= n(); ++k) f[k] = ws_.slide_force[k];
    return out;
  }

  std::tuple<double, double> energy(In q, In u, double g) {
    need(q, n_q(), "q");
    need(u, n_u(), "u");
    frames(model_, q.data(), ws_);
    return {kinetic_energy(model_, q.data(), u.data(), ws_),
            potential_energy(model_, q.data(), g, ws_)};
  }

  Out joint_origins(In q) {
    need(q, n_q(), "q");
    double* p;
    Out out = new_array({size_t(n() + 2), 3}, &p);
    frames(model_, q.data(), ws_);
    for (int k = 0; k < n() + 2; ++k)
      for (int i = 0; i < 3; ++i) p[3 * k + i] = ws_.O[k][i];
    return out;
  }

  Out link_rotations(In q) {
    need(q, n_q(), "q");
    double* p;
    Out out = new_array({size_t(n() + 1), 3, 3}, &p);
    frames(model_, q.data(), ws_);
    for (int k = 0; k < n() + 1; ++k)
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p[9 * k + 3 * i + j] = ws_.R[k][i][j];
    return out;
  }

  Out configuration_rate(In q, In u) {
    need(q, n_q(), "q");
    need(u, n_u(), "u");
    double* qdot;
    Out out = new_array({size_t(n_q())}, &qdot);
    mms::configuration_rate(model_, q.data(), u.data(), qdot);
    return out;
  }

  // q̇ of each row of `samples` (m × at least n_q + n_u: a run's state rows (q, u, …)), m × n_q.
  Out configuration_rates(In samples) {
    const size_t m = samples.ndim() == 2 ? samples.shape(0) : 0;
    const size_t width = samples.ndim() == 2 ? samples.shape(1) : 0;
    if (samples.ndim() != 2 || width < size_t(n_q() + n_u()))
      throw std::invalid_argument("samples: expected rows of at least " +
                                  std::to_string(n_q() + n_u()) + " numbers (q, u, …)");
    double* qdot;
    Out out = new_array({m, size_t(n_q())}, &qdot);
    for (size_t i = 0; i < m; ++i) {
      const double* row = samples.data() + i * width;
      mms::configuration_rate(model_, row, row + n_q(), qdot + i * n_q());
    }
    return out;
  }

  // Many states at once, kLaneWidth per vector block: rows of q (m × n_q), u, Q, moving (m × n_u).
  Out forward_dynamics_lanes(In q, In u, In Q, double g, In moving) {
    size_t m = q.ndim() == 2 ? q.shape(0) : 0;
    if (q.ndim() != 2 || q.shape(1) != size_t(n_q()))
      throw std::invalid_argument("q: expected an array of shape (runs, " +
                                  std::to_string(n_q()) + ")");
    need(u, m * n_u(), "u");
    need(Q, m * n_u(), "Q");
    need(moving, m * n_u(), "moving");
    double* ud;
    Out out = new_array({m, size_t(n_u())}, &ud);
    const int W = kLaneWidth, nq = n_q(), nu = n_u();
    std::vector<Block> qb(nq), ub(nu), Qb(nu), udb(nu);
    for (size_t start = 0; start < m; start += W) {
      for (int lane = 0; lane < W; ++lane) {
        size_t row = start + lane < m ? start + lane : m - 1;  // a short block repeats its last
        for (int i = 0; i < nq; ++i) qb[i].set(lane, q.data()[row * nq + i]);
        for (int i = 0; i < nu; ++i) {
          ub[i].set(lane, u.data()[row * nu + i]);
          Qb[i].set(lane, Q.data()[row * nu + i]);
          block().moving[i].set(lane, moving.data()[row * nu + i]);
        }
      }
      frames(model_, qb.data(), block());
      mms::forward_dynamics(model_, qb.data(), ub.data(), Qb.data(), g, block(), udb.data());
      for (int lane = 0; lane < W && start + lane < m; ++lane)
        for (int i = 0; i < nu; ++i) ud[(start + lane) * nu + i] = udb[i][lane];
    }
    return out;
  }

  // ds/dt at s = (q, u, e, W) for a robot driven by efforts (system.hpp): Q_cmd (n_u), damping
  // (n_u, or empty: none), moving (n_u: 1 free, 0 locked).
  Out rates(In s, In Q_cmd, In damping, In moving, double g, const WheelLoop* wheels) {
    set_effects(s, Q_cmd, damping, moving);
    double* ds;
    Out out = new_array({size_t(state_size(model_))}, &ds);
    Effects<double> fx{g, Q_cmd.data(), damping.size() ? damping.data() : nullptr, wheels};
    mms::rates(model_, fx, s.data(), ds, system_);
    return out;
  }

  // One step of `method` (euler, semi_implicit_euler, rk4) of length h from s (fixed_step.hpp).
  Out step(const std::string& method, In s, double h, In Q_cmd, In damping, In moving, double g,
           const WheelLoop* wheels) {
    Method m = method_of(method);
    set_effects(s, Q_cmd, damping, moving);
    double* next;
    Out out = new_array({size_t(state_size(model_))}, &next);
    Effects<double> fx{g, Q_cmd.data(), damping.size() ? damping.data() : nullptr, wheels};
    mms::step(m, model_, fx, s.data(), h, next, system_);
    return out;
  }

  // Exact Jacobians by dual numbers (kDirections directions a pass, one vector register), of the
  // rates (method "" : f = (q̇, u̇)) or of one step of a method (s⁺'s (q, u); rk45 and dop853:
  // a step of length h, without error control), with respect to
  // x = (q, u) and the efforts τ, whose generalized forces are Q_cmd + B (τ − τ₀) (B: n_u × n_τ,
  // a zero column for an effort held at its limit): (value (n_x), ∂/∂x (n_x × n_x), ∂/∂τ
  // (n_x × n_τ)), n_x = n_q + n_u.
  std::tuple<Out, Out, Out> jacobians(const std::string& method, In s, double h, In Q_cmd, In B,
                                      In damping, In moving, double g) {
    set_effects(s, Q_cmd, damping, moving);
    const int nx = n_q() + n_u(), ntau = efforts_of(B, 2);
    double *value, *dx, *dtau;
    Out o_value = new_array({size_t(nx)}, &value), o_dx = new_array({size_t(nx), size_t(nx)}, &dx),
        o_dtau = new_array({size_t(nx), size_t(ntau)}, &dtau);
    jacobians_into(method, s.data(), h, Q_cmd.data(), B.data(), ntau,
                   damping.size() ? damping.data() : nullptr, moving.data(), g, value, dx, dtau);
    return {o_value, o_dx, o_dtau};
  }

  // The same at many states at once, one row each (m × state, m × n_u, m × n_u × n_τ,
  // m × n_u): (m × n_x, m × n_x × n_x, m × n_x × n_τ). The loop runs without the GIL.
  std::tuple<Out, Out, Out> jacobians_many(const std::string& method, In s, double h, In Q_cmd,
                                           In B, In damping, In moving, double g) {
    const int nu = n_u(), nx = n_q() + nu, ns = state_size(model_);
    if (s.ndim() != 2 || s.shape(1) != size_t(ns))
      throw std::invalid_argument("s: expected an array of shape (states, " +
                                  std::to_string(ns) + ")");
    const size_t m = s.shape(0);
    need(Q_cmd, m * nu, "Q_cmd");
    need(moving, m * nu, "moving");
    if (damping.size()) need(damping, nu, "damping");
    const int ntau = efforts_of(B, 3);
    if (B.shape(0) != m) throw std::invalid_argument("B: expected one matrix a state");
    if (!method.empty()) differentiated_step(method);  // a bad name fails before the loop
    double *value, *dx, *dtau;
    Out o_value = new_array({m, size_t(nx)}, &value),
        o_dx = new_array({m, size_t(nx), size_t(nx)}, &dx),
        o_dtau = new_array({m, size_t(nx), size_t(ntau)}, &dtau);
    {
      nb::gil_scoped_release free_the_interpreter;
      for (size_t i = 0; i < m; ++i)
        jacobians_into(method, s.data() + i * ns, h, Q_cmd.data() + i * nu,
                       B.data() + i * nu * ntau, ntau, damping.size() ? damping.data() : nullptr,
                       moving.data() + i * nu, g, value + i * nx, dx + i * nx * nx,
                       dtau + i * nx * ntau);
    }
    return {o_value, o_dx, o_dtau};
  }

  // Many runs of this robot advanced `steps` fixed steps of `method` (no events: stops and
  // impacts stay with the engine for now), one row a run: s (m × state), Q_cmd, moving (m × n_u).
  // With `lanes`, kLaneWidth runs at once in vector blocks (a short last block repeats its last
  // run), else one by one in double: each lane is its run bit for bit (the tests compare them).
  Out advance(const std::string& method, In s, double h, int steps, In Q_cmd, In damping,
              In moving, double g, bool lanes) {
    Method m = method_of(method);
    const int nu = n_u(), ns = state_size(model_), W = kLaneWidth;
    if (s.ndim() != 2 || s.shape(1) != size_t(ns))
      throw std::invalid_argument("s: expected an array of shape (runs, " + std::to_string(ns) +
                                  ")");
    const size_t runs = s.shape(0);
    need(Q_cmd, runs * nu, "Q_cmd");
    need(moving, runs * nu, "moving");
    if (damping.size()) need(damping, nu, "damping");
    const double* c = damping.size() ? damping.data() : nullptr;
    double* out;
    Out result = new_array({runs, size_t(ns)}, &out);
    nb::gil_scoped_release free_the_interpreter;
    if (!lanes) {
      std::vector<double> x(ns), next(ns);
      for (size_t r = 0; r < runs; ++r) {
        for (int k = 0; k < nu; ++k) system_.dynamics.moving[k] = moving.data()[r * nu + k];
        Effects<double> fx{g, Q_cmd.data() + r * nu, c};
        std::copy(s.data() + r * ns, s.data() + (r + 1) * ns, x.begin());
        for (int i = 0; i < steps; ++i) {
          mms::step(m, model_, fx, x.data(), h, next.data(), system_);
          std::swap(x, next);
        }
        std::copy(x.begin(), x.end(), out + r * ns);
      }
      return result;
    }
    std::vector<Block> x(ns), next(ns), Qb(nu);
    for (size_t start = 0; start < runs; start += W) {
      for (int lane = 0; lane < W; ++lane) {
        size_t r = start + lane < runs ? start + lane : runs - 1;
        for (int i = 0; i < ns; ++i) x[i].set(lane, s.data()[r * ns + i]);
        for (int k = 0; k < nu; ++k) {
          Qb[k].set(lane, Q_cmd.data()[r * nu + k]);
          block_system().dynamics.moving[k].set(lane, moving.data()[r * nu + k]);
        }
      }
      Effects<Block> fx{g, Qb.data(), c};
      for (int i = 0; i < steps; ++i) {
        mms::step(m, model_, fx, x.data(), h, next.data(), block_system());
        std::swap(x, next);
      }
      for (int lane = 0; lane < W && start + lane < runs; ++lane)
        for (int i = 0; i < ns; ++i) out[(start + lane) * ns + i] = x[i][lane];
    }
    return result;
  }

  // CPU seconds per call of this thread, over `calls` calls, for the benchmarks (bench/): the
  // kernels alone, without the Python call around them.
  double time_forward_dynamics(In q, In u, In Q, double g, In moving, int calls) {
    check(q, u, Q);
    need(moving, n_u(), "moving");
    for (int k = 0; k < n_u(); ++k) ws_.moving[k] = moving.data()[k];
    std::vector<double> ud(n_u());
    return per_call(calls, [&] {
      frames(model_, q.data(), ws_);
      mms::forward_dynamics(model_, q.data(), u.data(), Q.data(), g, ws_, ud.data());
    });
  }

  // … per lane-evaluation of one vector block of kLaneWidth runs (the rows of q, u, Q, moving).
  double time_forward_dynamics_lanes(In q, In u, In Q, double g, In moving, int calls) {
    const int W = kLaneWidth, nq = n_q(), nu = n_u();
    need(q, size_t(W) * nq, "q");
    need(u, size_t(W) * nu, "u");
    need(Q, size_t(W) * nu, "Q");
    need(moving, size_t(W) * nu, "moving");
    std::vector<Block> qb(nq), ub(nu), Qb(nu), udb(nu);
    for (int lane = 0; lane < W; ++lane) {
      for (int i = 0; i < nq; ++i) qb[i].set(lane, q.data()[lane * nq + i]);
      for (int i = 0; i < nu; ++i) {
        ub[i].set(lane, u.data()[lane * nu + i]);
        Qb[i].set(lane, Q.data()[lane * nu + i]);
        block().moving[i].set(lane, moving.data()[lane * nu + i]);
      }
    }
    return per_call(calls, [&] {
      frames(model_, qb.data(), block());
      mms::forward_dynamics(model_, qb.data(), ub.data(), Qb.data(), g, block(), udb.data());
    }) / W;
  }

  double time_jacobians(const std::string& method, In s, double h, In Q_cmd, In B, In damping,
                        In moving, double g, int calls) {
    return per_call(calls, [&] { jacobians(method, s, h, Q_cmd, B, damping, moving, g); });
  }

  // … of one of the dynamics' algorithms, every pseudo-velocity free (bench/'s scaling): x is
  // u̇ for the inverse dynamics, Q for the forward. "inverse": frames + one Gibbs–Appell pass;
  // "inverse_by_columns": Q = M u̇ + h with M assembled column by column (n_u passes);
  // "forward": frames + the articulated-body recursion; "forward_composite_cholesky" and
  // "forward_by_columns_cholesky": h by one pass, M by composite rigid bodies or by columns,
  // then Cholesky.
  double time_dynamics(const std::string& what, In q, In u, In x, double g, int calls) {
    check(q, u, x);
    const int nu = n_u();
    std::fill(ws_.moving.begin(), ws_.moving.end(), 1.0);
    std::vector<double> out(nu), h(nu), rhs(nu), zeros(nu, 0.0), unit(nu, 0.0), M(nu * nu),
        L(nu * nu);
    std::vector<int> free(nu);
    std::iota(free.begin(), free.end(), 0);
    // column j of M: the generalized forces of u̇ = e_j at u = 0 without gravity
    auto mass_matrix_by_columns = [&] {
      for (int j = 0; j < nu; ++j) {
        unit[j] = 1.0;
        mms::inverse_dynamics(model_, q.data(), zeros.data(), unit.data(), 0.0, ws_, rhs.data());
        for (int i = 0; i < nu; ++i) M[i * nu + j] = rhs[i];
        unit[j] = 0.0;
      }
    };
    auto by_cholesky = [&](bool by_columns) {
      frames(model_, q.data(), ws_);
      mms::inverse_dynamics(model_, q.data(), u.data(), zeros.data(), g, ws_, h.data());
      for (int i = 0; i < nu; ++i) rhs[i] = x.data()[i] - h[i];
      if (by_columns) mass_matrix_by_columns();
      else mms::mass_matrix(model_, ws_, q.data(), M.data());
      cholesky_solve(M.data(), nu, rhs.data(), free.data(), nu, L.data(), out.data());
    };
    if (what == "inverse")
      return per_call(calls, [&] {
        frames(model_, q.data(), ws_);
        mms::inverse_dynamics(model_, q.data(), u.data(), x.data(), g, ws_, out.data());
      });
    if (what == "inverse_by_columns")
      return per_call(calls, [&] {
        frames(model_, q.data(), ws_);
        mass_matrix_by_columns();
        mms::inverse_dynamics(model_, q.data(), u.data(), zeros.data(), g, ws_, h.data());
        for (int i = 0; i < nu; ++i) {
          double s = h[i];
          for (int j = 0; j < nu; ++j) s += M[i * nu + j] * x.data()[j];
          out[i] = s;
        }
      });
    if (what == "forward")
      return per_call(calls, [&] {
        frames(model_, q.data(), ws_);
        mms::forward_dynamics(model_, q.data(), u.data(), x.data(), g, ws_, out.data());
      });
    if (what == "forward_composite_cholesky")
      return per_call(calls, [&] { by_cholesky(false); });
    if (what == "forward_by_columns_cholesky")
      return per_call(calls, [&] { by_cholesky(true); });
    throw std::invalid_argument("what: expected inverse, inverse_by_columns, forward, "
                                "forward_composite_cholesky or forward_by_columns_cholesky, got " +
                                what);
  }

  // … of the engine's right-hand side ds/dt (as `rates`), and of one fixed step (as `step`).
  double time_rates(In s, In Q_cmd, In damping, In moving, double g, int calls) {
    set_effects(s, Q_cmd, damping, moving);
    std::vector<double> ds(state_size(model_));
    Effects<double> fx{g, Q_cmd.data(), damping.size() ? damping.data() : nullptr};
    return per_call(calls, [&] { mms::rates(model_, fx, s.data(), ds.data(), system_); });
  }

  double time_step(const std::string& method, In s, double h, In Q_cmd, In damping, In moving,
                   double g, int calls) {
    Method m = method_of(method);
    set_effects(s, Q_cmd, damping, moving);
    std::vector<double> next(state_size(model_));
    Effects<double> fx{g, Q_cmd.data(), damping.size() ? damping.data() : nullptr};
    return per_call(calls, [&] { mms::step(m, model_, fx, s.data(), h, next.data(), system_); });
  }

  // The arithmetic of one forward-dynamics evaluation (frames + articulated), counted on
  // `Counted` numbers, every pseudo-velocity free: ({add, sub, mul, div, neg, sqrt, sin, cos},
  // u̇ as the counted run computed it: the double kernel's, bit for bit, when the counted run
  // did the same operations).
  std::tuple<nb::dict, Out> count_forward_dynamics(In q, In u, In Q, double g) {
    check(q, u, Q);
    std::vector<Counted> qc(q.data(), q.data() + n_q()), uc(u.data(), u.data() + n_u()),
        Qc(Q.data(), Q.data() + n_u()), ud(n_u());
    Workspace<Counted> ws(n());
    flop_counts = FlopCounts();
    frames(model_, qc.data(), ws);
    mms::forward_dynamics(model_, qc.data(), uc.data(), Qc.data(), g, ws, ud.data());
    const FlopCounts c = flop_counts;
    nb::dict counts;
    counts["add"] = c.add, counts["sub"] = c.sub, counts["mul"] = c.mul, counts["div"] = c.div;
    counts["neg"] = c.neg, counts["sqrt"] = c.sqrt, counts["sin"] = c.sin, counts["cos"] = c.cos;
    double* values;
    Out out = new_array({size_t(n_u())}, &values);
    for (int k = 0; k < n_u(); ++k) values[k] = ud[k].v;
    return {counts, out};
  }

  int state_length() const { return state_size(model_); }

 private:
  // Exact Jacobians by dual numbers (kDirections directions a pass, one vector register) at one
  // state: value (n_x), ∂/∂x (n_x × n_x), ∂/∂τ (n_x × n_τ), all row-major.
  void jacobians_into(const std::string& method, const double* s, double h, const double* Q_cmd,
                      const double* B, int ntau, const double* damping, const double* moving,
                      double g, double* value, double* dx, double* dtau) {
    const bool of_step = !method.empty(), adaptive = of_step && differentiated_step(method);
    Method m = of_step && !adaptive ? method_of(method) : Method::Euler;
    const int nu = n_u(), nx = n_q() + nu, ns = state_size(model_), total = nx + ntau;
    for (int k = 0; k < nu; ++k) dual_system().dynamics.moving[k] = moving[k];
    std::vector<DualD> sd(ns), Qd(nu), out(ns);
    Effects<DualD> fx{g, Qd.data(), damping};
    for (int first = 0; first < total; first += kDirections) {
      seed_pass(first, s, ns, nx, Q_cmd, B, nu, ntau, sd.data(), Qd.data());
      if (adaptive) adaptive_step_map(adaptive_of(method), fx, sd.data(), h, out.data());
      else if (of_step) mms::step(m, model_, fx, sd.data(), h, out.data(), dual_system());
      else mms::rates(model_, fx, sd.data(), out.data(), dual_system());
      read_pass(first, out.data(), nx, ntau, value, dx, dtau);
    }
  }

  // The number of efforts of B (n_u × n_τ, or states × n_u × n_τ when ndim is 3).
  int efforts_of(const In& B, size_t ndim) {
    if (B.ndim() != ndim || B.shape(ndim - 2) != size_t(n_u()))
      throw std::invalid_argument("B: expected an array of shape (" +
                                  std::string(ndim == 3 ? "states, " : "") +
                                  std::to_string(n_u()) + ", efforts)");
    return static_cast<int>(B.shape(ndim - 1));
  }


  void set_effects(const In& s, const In& Q_cmd, const In& damping, const In& moving) {
    need(s, state_size(model_), "s");
    need(Q_cmd, n_u(), "Q_cmd");
    if (damping.size()) need(damping, n_u(), "damping");
    need(moving, n_u(), "moving");
    for (int k = 0; k < n_u(); ++k) system_.dynamics.moving[k] = moving.data()[k];
  }

  void check(const In& q, const In& u, const In& third) {
    need(q, n_q(), "q");
    need(u, n_u(), "u");
    need(third, n_u(), "third argument (n_u)");
  }

  Model model_;
  Workspace<double> ws_;
  SystemWorkspace<double> system_;
  // the workspaces of vector blocks and dual numbers, made at their first use (a batch's lane,
  // one Dynamics each, never uses them)
  std::unique_ptr<Workspace<Block>> block_;
  std::unique_ptr<SystemWorkspace<DualD>> dual_system_;
  std::unique_ptr<SystemWorkspace<Block>> block_system_;
  Workspace<Block>& block() {
    if (!block_) block_ = std::make_unique<Workspace<Block>>(model_.n());
    return *block_;
  }
  SystemWorkspace<DualD>& dual_system() {
    if (!dual_system_) dual_system_ = std::make_unique<SystemWorkspace<DualD>>(model_);
    return *dual_system_;
  }
  SystemWorkspace<Block>& block_system() {
    if (!block_system_) block_system_ = std::make_unique<SystemWorkspace<Block>>(model_);
    return *block_system_;
  }

  // --- the adaptive methods rk45 and dop853 (runge_kutta.hpp, adaptive_solve.hpp) ------------
 public:
  // Hairer's starting step (s) at s for a run over `span` seconds (`initial_step`).
  double initial_step(const std::string& method, In s, double span, double rtol, double atol,
                      double max_step, In Q_cmd, In damping, In moving, double g,
                      const WheelLoop* wheels) {
    Adaptive m = adaptive_of(method);
    check_tolerances(rtol, atol);
    set_effects(s, Q_cmd, damping, moving);
    check_finite(s, "s");
    Effects<double> fx{g, Q_cmd.data(), damping.size() ? damping.data() : nullptr, wheels};
    const int n = state_size(model_);
    std::vector<double> f0(n), y(n), f(n);
    mms::rates(model_, fx, s.data(), f0.data(), system_);
    SystemRhs<double> rhs{model_, fx, system_};
    return mms::initial_step(m, rhs, s.data(), f0.data(), span, rtol, atol, max_step, y.data(),
                             f.data());
  }

  // One accepted step of `method` from (t, s), trying h_abs first and never past t_bound
  // (`accepted_step`; f(s) is evaluated first and not counted): (y₁, h taken, next h to try,
  // right-hand sides, rejected tries); h = −1 when the step fell below 10 spacings of t. The
  // step stays in hand for `dense_output`, with the efforts it was taken with.
  std::tuple<Out, double, double, int, int> adaptive_step(const std::string& method, In s,
                                                          double t, double h_abs,
                                                          double t_bound, double rtol,
                                                          double atol, In Q_cmd, In damping,
                                                          In moving, double g,
                                                          const WheelLoop* wheels) {
    Adaptive m = adaptive_of(method);
    check_tolerances(rtol, atol);
    if (!(h_abs > 0.0)) throw std::invalid_argument("h_abs: expected a positive step");
    set_effects(s, Q_cmd, damping, moving);
    check_finite(s, "s");
    const int n = state_size(model_);
    in_hand_ = std::make_unique<InHand>(m, n, rtol, atol, Q_cmd, damping, moving, g, wheels);
    Solve<double>& solve = in_hand_->solve;
    Effects<double> fx = in_hand_->effects();
    solve.start.assign(s.data(), s.data() + n);
    mms::rates(model_, fx, s.data(), solve.work.f_start.data(), system_);
    SystemRhs<double> rhs{model_, fx, system_};
    AcceptedStep step = accepted_step(m, rhs, s.data(), t, h_abs, t_bound, rtol, atol, solve.work);
    solve.t0 = t;
    solve.h = step.h > 0.0 ? step.h : 0.0;
    double* end;
    Out out = new_array({size_t(n)}, &end);
    std::copy(solve.work.end.begin(), solve.work.end.end(), end);
    if (step.h < 0.0) std::copy(s.data(), s.data() + n, end);  // unchanged
    return {out, step.h, step.h_next, step.evaluations, step.rejections};
  }

  // The last `adaptive_step`'s dense output at each θ of `thetas` (θ ∈ [0, 1]): (rows
  // (len(thetas) × state), whether it came from the step's stages alone). `full`: the method's
  // own interpolant (dop853's 7th order, 3 more right-hand sides); otherwise dop853 reads its
  // stage-only extension where that is within the step's tolerance, as the solve does for samples.
  std::tuple<Out, bool> dense_output(In thetas, bool full) {
    if (!in_hand_ || in_hand_->solve.h <= 0.0)
      throw std::invalid_argument("dense_output: no accepted step in hand (call adaptive_step)");
    for (size_t i = 0; i < thetas.size(); ++i)
      if (!(thetas.data()[i] >= 0.0 && thetas.data()[i] <= 1.0))
        throw std::invalid_argument("thetas: expected values in [0, 1], got " +
                                    number(thetas.data()[i]));
    Solve<double>& solve = in_hand_->solve;
    for (int k = 0; k < n_u(); ++k) system_.dynamics.moving[k] = in_hand_->moving[k];
    solve.dense = DenseKind::None;
    Effects<double> fx = in_hand_->effects();
    SystemRhs<double> rhs{model_, fx, system_};
    interpolant(solve, rhs, full);
    const int n = state_size(model_);
    double* rows;
    Out out = new_array({thetas.size(), size_t(n)}, &rows);
    for (size_t i = 0; i < thetas.size(); ++i)
      dense_eval(solve.method, n, solve.work.dense, solve.start.data(), solve.h,
                 thetas.data()[i], rows + i * n);
    return {out, solve.dense == DenseKind::FromStages};
  }

  // A run of `method` from s at t = 0 (no events: stops and impacts are the engine's), its
  // state at each of the increasing `times` (s) read from the step in hand's dense output
  // (adaptive_solve.hpp): (rows (len(times) × state), accepted steps, right-hand sides, rejected
  // tries). The efforts change at each of the increasing `changes` (s) to the next row of Q_cmd
  // ((len(changes) + 1) × n_u), and the solve restarts there (a discontinuity of the right-hand
  // side): the run reaches that instant exactly, and a change at a sample's time comes first.
  std::tuple<Out, long, long, long> adaptive_run(const std::string& method, In s, In times,
                                                 double rtol, double atol, In Q_cmd, In damping,
                                                 In moving, double g, const WheelLoop* wheels,
                                                 long max_steps,
                                                 const std::vector<double>& changes) {
    Adaptive m = adaptive_of(method);
    check_tolerances(rtol, atol);
    const int n = state_size(model_), nu = n_u();
    need(s, n, "s");
    check_finite(s, "s");
    need(Q_cmd, (changes.size() + 1) * nu, "Q_cmd (a row of efforts before and after each change)");
    if (damping.size()) need(damping, nu, "damping");
    need(moving, nu, "moving");
    for (int k = 0; k < nu; ++k) system_.dynamics.moving[k] = moving.data()[k];
    check_times(times.data(), times.size(), "times");
    check_times(changes.data(), changes.size(), "changes");
    auto effects = [&](size_t segment) {
      return Effects<double>{g, Q_cmd.data() + segment * nu,
                             damping.size() ? damping.data() : nullptr, wheels};
    };
    Effects<double> fx = effects(0);
    Solve<double> solve(m, n, rtol, atol);
    std::vector<double> x(s.data(), s.data() + n);
    double t = 0.0;
    double* rows;
    Out out = new_array({times.size(), size_t(n)}, &rows);
    SolveStatus status = SolveStatus::Done;
    {
      nb::gil_scoped_release free_the_interpreter;
      size_t segment = 0;
      for (size_t i = 0; i < times.size() && status == SolveStatus::Done; ++i) {
        while (status == SolveStatus::Done && segment < changes.size() &&
               changes[segment] <= times.data()[i]) {
          SystemRhs<double> rhs{model_, fx, system_};
          status = mms::advance(solve, rhs, t, x.data(), changes[segment],
                                max_steps - solve.steps);
          restart(solve);
          fx = effects(++segment);
        }
        if (status == SolveStatus::Done) {
          SystemRhs<double> rhs{model_, fx, system_};
          status = mms::advance(solve, rhs, t, x.data(), times.data()[i], max_steps - solve.steps);
        }
        std::copy(x.begin(), x.end(), rows + i * n);
      }
    }
    if (status != SolveStatus::Done) throw std::runtime_error(solve_failure(status, solve));
    return {out, solve.steps, solve.evaluations, solve.rejections};
  }

 private:
  // The step in hand of `adaptive_step`, and the efforts it was taken with (`dense_output`'s
  // extra stages evaluate with them).
  struct InHand {
    Solve<double> solve;
    std::vector<double> Q_cmd, damping, moving;
    double g;
    WheelLoop wheels;
    bool has_wheels;
    InHand(Adaptive m, int n, double rtol, double atol, const In& Q, const In& c, const In& mv,
           double g_, const WheelLoop* w)
        : solve(m, n, rtol, atol), Q_cmd(Q.data(), Q.data() + Q.size()),
          damping(c.data(), c.data() + c.size()), moving(mv.data(), mv.data() + mv.size()),
          g(g_), wheels(w ? *w : WheelLoop()), has_wheels(w != nullptr) {}
    Effects<double> effects() const {
      return {g, Q_cmd.data(), damping.empty() ? nullptr : damping.data(),
              has_wheels ? &wheels : nullptr};
    }
  };

  // y₁ of one rk45 or dop853 step of the given length h from s (no error control), in dual
  // numbers: the step map whose derivatives `jacobians` gives for these methods.
  void adaptive_step_map(Adaptive m, const Effects<DualD>& fx, const DualD* s, double h,
                         DualD* out) {
    if (!dual_step_) dual_step_ = std::make_unique<StepWork<DualD>>(state_size(model_));
    mms::rates(model_, fx, s, dual_step_->f_start.data(), dual_system());
    SystemRhs<DualD> rhs{model_, fx, dual_system()};
    stages(m, rhs, s, h, *dual_step_);
    std::copy(dual_step_->end.begin(), dual_step_->end.end(), out);
  }

  // Whether `jacobians` differentiates a step of this adaptive method (else of a fixed-step one).
  static bool differentiated_step(const std::string& name) {
    if (name == "rk45" || name == "dop853") return true;
    if (name == "euler" || name == "semi_implicit_euler" || name == "rk4") return false;
    throw std::invalid_argument(
        "method: expected euler, semi_implicit_euler, rk4, rk45 or dop853, got " + name);
  }

  static Adaptive adaptive_of(const std::string& name) {
    if (name == "rk45") return Adaptive::Rk45;
    if (name == "dop853") return Adaptive::Dop853;
    throw std::invalid_argument("method: expected rk45 or dop853, got " + name);
  }

  static void check_tolerances(double rtol, double atol) {
    if (!(rtol > 0.0 && std::isfinite(rtol)))
      throw std::invalid_argument("rtol: expected a positive number, got " + number(rtol));
    if (!(atol > 0.0 && std::isfinite(atol)))
      throw std::invalid_argument("atol: expected a positive number, got " + number(atol));
  }

  // Finite, from 0 and never decreasing.
  static void check_times(const double* times, size_t count, const char* name) {
    double previous = 0.0;
    for (size_t i = 0; i < count; ++i) {
      if (!(std::isfinite(times[i]) && times[i] >= previous))
        throw std::invalid_argument(std::string(name) +
                                    ": expected finite increasing times from 0, got " +
                                    number(times[i]) + " at index " + std::to_string(i));
      previous = times[i];
    }
  }

  static void check_finite(const In& a, const char* name) {
    for (size_t i = 0; i < a.size(); ++i)
      if (!std::isfinite(a.data()[i]))
        throw std::invalid_argument(std::string(name) + ": expected finite numbers, got " +
                                    number(a.data()[i]) + " at index " + std::to_string(i));
  }

  static std::string number(double x) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", x);
    return text;
  }

  static std::string solve_failure(SolveStatus status, const Solve<double>& solve) {
    char text[160];
    if (status == SolveStatus::Budget)
      std::snprintf(text, sizeof text, "t = %.9g s: the run used its %ld steps", solve.t0,
                    solve.steps);
    else if (status == SolveStatus::NotFinite)
      std::snprintf(text, sizeof text, "t = %.9g s: the state became non-finite", solve.t0);
    else if (std::isnan(solve.h_next))
      std::snprintf(text, sizeof text, "t = %.9g s: a stage overflowed (its error estimate is NaN)",
                    solve.t0);
    else
      std::snprintf(text, sizeof text,
                    "t = %.9g s: the step fell below 10 spacings of t (h = %.3g s)", solve.t0,
                    solve.h_next);
    return text;
  }

  std::unique_ptr<InHand> in_hand_;
  std::unique_ptr<StepWork<DualD>> dual_step_;
};

// The engine of one simulation — a fixed-step method (stepping.hpp) or rk45, dop853 with their
// solve (adaptive_stepping.hpp) — on the engine's own arrays (run.hpp): the Python objects stay
// the owners, and hold what the run is between calls (but an adaptive run's step in hand).
using I64 = nb::ndarray<std::int64_t, nb::c_contig, nb::device::cpu>;
using Bools = nb::ndarray<bool, nb::c_contig, nb::device::cpu>;
using F64 = nb::ndarray<double, nb::c_contig, nb::device::cpu>;

class Stepper {
 public:
  Stepper(nb::object dynamics, const std::string& method, double gravity, In damping, I64 free,
          In Q_cmd, In control, I64 counters, F64 holding, Bools watched, I64 resting, In stroke,
          Bools permanent, int law, double restitution, double rest_speed, F64 log, F64 log_q,
          F64 log_u, Bools log_free, I64 count, F64 runs, I64 failed, F64 out, F64 trial,
          F64 stages, F64 forces, F64 samples, I64 crossed, double rtol, double atol, F64 watch,
          double rate, F64 held)
      : owner_(dynamics), run_(nb::cast<Dynamics&>(dynamics).model(), int(out.size())) {
    const Model& m = run_.model;
    const size_t n = m.n(), nu = m.n_u(), nq = m.n_q(), size = out.size();
    if (damping.size()) need(damping, nu, "damping");
    need(free, nu, "free");
    need(Q_cmd, nu, "Q_cmd");
    need(control, 7, "control");
    if (counters.size() < 5) throw std::invalid_argument("counters: expected 5 or more");
    counters_ = counters.size();
    need(holding, 2, "holding");
    need(watched, n, "watched");
    need(resting, n, "resting");
    need(stroke, 2 * n, "stroke");
    need(permanent, nu, "permanent");
    const size_t capacity = log.ndim() == 2 ? log.shape(0) : 0;
    if (log.ndim() != 2 || log.shape(1) != LOG_COLUMNS)
      throw std::invalid_argument("log: expected (capacity, " + std::to_string(LOG_COLUMNS) +
                                  ")");
    need(log_q, capacity * nq, "log_q");
    need(log_u, capacity * 2 * nu, "log_u");
    need(log_free, capacity * nu, "log_free");
    need(count, 1, "count");
    need(runs, n * 2 * RUN_FIELDS, "run");
    need(failed, 1, "failed");
    need(trial, size, "trial");
    need(stages, 4 * size, "stages");
    need(forces, size, "forces");
    if (samples.size() < size_t(N_SAMPLES) + 2 * n)
      throw std::invalid_argument("samples: too short");
    need(crossed, std::max<size_t>(n, 1), "crossed");
    need(watch, 3, "watch");
    need(held, nu, "held");
    if (!(rate >= 0.0)) throw std::invalid_argument("rate: expected a rate ≥ 0 (Hz)");
    const bool outside = method == "radau" || method == "bdf";  // SciPy's, steps handed in
    if (method == "rk45" || method == "dop853" || outside) {
      if (!(rtol > 0.0 && atol > 0.0))
        throw std::invalid_argument("rtol, atol: expected positive tolerances");
      adaptive_ = std::make_unique<AdaptiveRun>(
          method == "dop853" ? Adaptive::Dop853 : Adaptive::Rk45, int(size), rtol, atol,
          watch.data(), outside);
    } else {
      method_ = method_of(method);
    }
    if (size != size_t(state_size(m)) && size != size_t(arm_state_size(m)))
      throw std::invalid_argument("out: expected a state of " + std::to_string(state_size(m)) +
                                  " entries, or " + std::to_string(arm_state_size(m)) +
                                  " with an arm controller");
    arrays_ = nb::make_tuple(damping, free, Q_cmd, control, counters, holding, watched, resting,
                             stroke, permanent, log, log_q, log_u, log_free, count, runs, failed,
                             out, trial, stages, forces, samples, crossed, watch, held);
    run_.system = SystemArrays{.gravity = gravity,
                               .damping = damping.size() ? damping.data() : nullptr,
                               .free = free.data(),
                               .Q_cmd = Q_cmd.data(),
                               .control = control.data(),
                               .counters = counters.data(),
                               .holding = holding.data(),
                               .rate = rate,
                               .held = held.data()};
    run_.stops = StopsArrays{.watched = watched.data(),
                             .resting = resting.data(),
                             .stroke = stroke.data(),
                             .permanent = permanent.data(),
                             .law = law,
                             .restitution = restitution,
                             .rest_speed = rest_speed,
                             .log = log.data(),
                             .log_q = log_q.data(),
                             .log_u = log_u.data(),
                             .log_free = log_free.data(),
                             .capacity = int(capacity),
                             .count = count.data(),
                             .run = runs.data(),
                             .failed = failed.data()};
    run_.step = StepArrays{.out = out.data(),
                           .trial = trial.data(),
                           .stages = stages.data(),
                           .forces = forces.data(),
                           .samples = samples.data(),
                           .crossed = crossed.data()};
  }

  int advance(F64 s, F64 clock, double t_end, long max_steps) {
    check(s, clock);
    not_outside("advance");
    nb::gil_scoped_release free_the_interpreter;
    if (adaptive_) return mms::advance(run_, *adaptive_, s.data(), clock.data(), t_end, max_steps);
    return mms::advance(run_, method_, s.data(), clock.data(), t_end, max_steps);
  }

  std::tuple<int, long> advance_samples(F64 s, F64 clock, In times, F64 rows, long first,
                                        long max_steps) {
    check(s, clock);
    const long n_times = long(times.size());
    need(rows, size_t(n_times) * (run_.size + 1), "rows");
    if (first < 0 || first > n_times) throw std::invalid_argument("first: out of range");
    not_outside("advance_samples");
    nb::gil_scoped_release free_the_interpreter;
    Sampled done =
        adaptive_ ? mms::advance_samples(run_, *adaptive_, s.data(), clock.data(), times.data(),
                                         n_times, rows.data(), first, max_steps)
                  : mms::advance_samples(run_, method_, s.data(), clock.data(), times.data(),
                                         n_times, rows.data(), first, max_steps);
    return {int(done.status), done.next};
  }

  double total_energy(In s) {
    check_state(s);
    return mms::total_energy(run_, s.data());
  }

  // An adaptive run: a discontinuity now (a command changed): its solve restarts here.
  void restart() {
    if (adaptive_) mms::restart(*adaptive_);
  }

  // An adaptive run's step in hand (start, length; length 0: none) and its next step to try.
  std::tuple<double, double> step_in_hand() const {
    return adaptive_ ? std::tuple<double, double>{adaptive_->solve.t0, adaptive_->solve.h}
                     : std::tuple<double, double>{0.0, 0.0};
  }
  double next_step() const { return adaptive_ ? adaptive_->solve.h_next : 0.0; }

  // An adaptive run's step in hand's end state y₁.
  Out step_end() const {
    if (!adaptive_) throw std::invalid_argument("step_end: not an adaptive run");
    double* y;
    Out out = new_array({size_t(run_.size)}, &y);
    std::copy(adaptive_->solve.work.end.begin(), adaptive_->solve.work.end.end(), y);
    return out;
  }

  // The locks from the stops (the scene's and the resting rods'), after Python changed them.
  void relock() { mms::relock(run_); }

  // Free the resting rods their stops would have to pull at s (in place); how many left.
  int release(F64 s, bool at_root) {
    check_state(s);
    sync_locks(run_);
    return mms::release(run_, s.data(), at_root);
  }

  // The least force a resting rod's stop pushes with at s (N; +inf when none rests).
  double holding_margin(In s) {
    check_state(s);
    sync_locks(run_);
    return mms::holding_margin(run_, s.data(), run_.stage(3));
  }

  // The run and its method, for a batch's lanes (`LaneSet`): a fixed-step run only.
  Run& run() { return run_; }
  Method method() const {
    if (adaptive_) throw std::invalid_argument("lanes: a batch's lanes take fixed-step runs");
    return method_;
  }

  // ds/dt at s with the locks in force (counted as the run's own evaluations are).
  Out derivative(In s) {
    check_state(s);
    sync_locks(run_);
    double* ds;
    Out out = new_array({size_t(run_.size)}, &ds);
    mms::derivative(run_, s.data(), ds);
    return out;
  }

  // The generalized force each locked pseudo-velocity needs to stay locked at s, M u̇ + h − Q
  // with u̇ and Q of the right-hand side there (zero on the free ones up to round-off): one
  // inverse-dynamics pass after `derivative` (counted as it is).
  Out constraint_forces(In s) {
    check_state(s);
    sync_locks(run_);
    std::vector<double> ds(run_.size);
    mms::derivative(run_, s.data(), ds.data());
    const int nq = run_.n_q(), nu = run_.model.n_u();
    double* out;
    Out forces = new_array({size_t(nu)}, &out);
    mms::inverse_dynamics(run_.model, s.data(), s.data() + nq, ds.data() + nq,
                          run_.system.gravity, run_.ws.dynamics, out);
    for (int k = 0; k < nu; ++k) out[k] -= run_.ws.Q[k];
    return forces;
  }

  // (τ_R, τ_L), N·m: the continuous wheel-speed loop's torques at s (system.hpp's wheel_drive,
  // as `rates` computes them under velocity commands).
  std::tuple<double, double> wheel_torques(In s) {
    check_state(s);
    double tau_R, tau_L, rate_R, rate_L;
    wheels_drive(run_.model, wheel_loop(run_.system.control), s.data(), true, tau_R, tau_L,
                 rate_R, rate_L);
    return {tau_R, tau_L};
  }

  // (x⁺, A, C, events) of one whole step h of the run's fixed-step method from s at the time of
  // `clock`, with the run's efforts, locks, stops and controllers, through every event the step
  // holds (event_jacobians.hpp), and how many it held; the run's records are left as they were.
  // x = (q, u), then, with a controller driving the arm, its state: the PID integrals z (n_arm),
  // and for sampled controllers the arm efforts they hold (n_arm; an update due at the step's
  // start is applied first, as `advance` does). A = ∂x⁺/∂x; C = ∂x⁺/∂(τ, r): τ the efforts whose
  // generalized forces are Q_cmd + B_τ (τ − τ₀) (B_τ: n_u × n_τ), then r the held reference's
  // target (`target`, arm_control.hpp's TargetKind: n_arm columns, none for TARGET_NONE).
  std::tuple<Out, Out, Out, int> step_jacobians(In s, In clock, double h, In B_tau, int target) {
    check_state(s);
    need(clock, CLOCK_ENTRIES, "clock");
    if (adaptive_) throw std::invalid_argument("step_jacobians: a fixed-step run only");
    if (run_.velocity_mode())
      throw std::invalid_argument("step_jacobians: the base takes velocity commands");
    if (!(h > 0.0 && std::isfinite(h))) throw std::invalid_argument("h: expected a positive step");
    const bool arm = run_.arm_on(), sampled = arm && run_.system.rate > 0.0;
    if (target < TARGET_NONE || target > TARGET_VELOCITY || (target != TARGET_NONE && !arm))
      throw std::invalid_argument("target: expected 0 (none), or 1 (position) or 2 (velocity) "
                                  "with an arm controller");
    const Model& model = run_.model;
    const int nu = model.n_u(), nx = model.n_q() + nu, size = run_.size, n_arm = nu - 2;
    if (B_tau.ndim() != 2 || B_tau.shape(0) != size_t(nu))
      throw std::invalid_argument("B: expected an array of shape (" + std::to_string(nu) +
                                  ", efforts)");
    const int ntau = int(B_tau.shape(1)), n_ref = target != TARGET_NONE ? n_arm : 0;
    const int n_state = nx + (arm ? n_arm : 0), rows = n_state + (sampled ? n_arm : 0);
    const int i_z = arm ? arm_integrals_index(model) : 0;
    // the double run's step (after the update due at its start), its events recorded, the run's
    // records put back after it
    std::vector<double> x(s.data(), s.data() + size), clk(clock.data(), clock.data() + CLOCK_ENTRIES);
    const double t = clk[CLOCK_T0] + clk[CLOCK_K] * clk[CLOCK_DT];
    bool update_due = false;
    std::vector<double> update_moving;
    Status status = DONE;
    {
      Records kept(run_, counters_);
      sync_locks(run_);
      if (sampled) {
        const double period = 1.0 / run_.system.rate, t_update = next_update(run_, clk[CLOCK_UPDATES]);
        update_due = t_update <= t;
        if ((update_due ? t_update + period : t_update) < t + h - 1e-9 * h) {
          kept.restore(run_);
          throw std::invalid_argument("h: the controllers' next update falls inside the step "
                                      "(choose a step that divides 1/controller.rate)");
        }
        update_moving = run_.ws.dynamics.moving;
        if (update_due) status = update_controllers(run_, x.data());
      }
      EventScript script;
      run_.script = &script;
      if (status == DONE) status = step_with_events(run_, method_, x.data(), h, t, clk.data());
      run_.script = nullptr;
      kept.restore(run_);
      script_ = std::move(script);
    }
    if (status != DONE)
      throw std::runtime_error("the step did not complete (status " +
                               std::to_string(int(status)) + ")");
    if (!dual_) {
      dual_ = std::make_unique<SystemWorkspace<DualD>>(model);
      event_work_ = std::make_unique<EventWork<DualD>>(size, nu, std::max(model.n(), 1));
    }
    // sampled: the plant between updates takes the held efforts as its arm's (q, u, e, W only)
    const int stepped = sampled ? state_size(model) : size;
    std::vector<DualD> sd(size), Qd(nu), out(size), held(n_arm), x_rows(rows), law(size);
    Effects<DualD> fx{run_.system.gravity, Qd.data(), run_.system.damping, nullptr, nullptr,
                      arm && !sampled ? &run_.arm : nullptr};
    auto rates = [&](const DualD* at, DualD* rate) { mms::rates(model, fx, at, rate, *dual_); };
    dual_->arm.target_kind = target;
    double *value, *dx, *dc;
    Out o_value = new_array({size_t(rows)}, &value),
        o_dx = new_array({size_t(rows), size_t(rows)}, &dx),
        o_dc = new_array({size_t(rows), size_t(ntau + n_ref)}, &dc);
    const double* B = B_tau.data();
    // one pass of directions first … first + kDirections − 1 (none for kPlain: dg/dh* of the
    // events found)
    constexpr int kPlain = -2 * kDirections;
    auto pass = [&](int first) {
      auto along = [&](int j) { return direction(first, j); };
      for (int i = 0; i < size; ++i) {
        int j = i < nx ? i : (arm && i >= i_z && i < i_z + n_arm ? nx + i - i_z : -1);
        sd[i] = DualD(s.data()[i], j >= 0 ? along(j) : Directions(0.0));
      }
      for (int i = 0; i < nu; ++i) {
        Directions d(0.0);
        for (int j = 0; j < ntau; ++j) d = d + B[i * ntau + j] * along(rows + j);
        Qd[i] = DualD(run_.system.Q_cmd[i], d);
      }
      for (int j = 0; j < n_ref; ++j) dual_->arm.target[j] = DualD(0.0, along(rows + ntau + j));
      if (sampled) {
        for (int j = 0; j < n_arm; ++j)
          held[j] = DualD(run_.system.held[2 + j], along(n_state + j));
        if (update_due) {  // stepping.hpp's update_controllers, the arm's part
          const double period = 1.0 / run_.system.rate;
          std::vector<DualD> Q(Qd);
          std::copy(update_moving.begin(), update_moving.end(), dual_->dynamics.moving.begin());
          frames(model, sd.data(), dual_->dynamics);
          arm_efforts(model, run_.arm, run_.system.gravity, run_.system.damping, sd.data(),
                      law.data(), Q.data(), dual_->dynamics, dual_->arm);
          for (int j = 0; j < n_arm; ++j) {
            held[j] = Q[2 + j];
            sd[i_z + j] += period * law[i_z + j];
          }
        }
        for (int j = 0; j < n_arm; ++j) Qd[2 + j] = held[j];
      }
      step_through_events(method_, model, run_.stops, script_, rates, *dual_, sd.data(), h,
                          out.data(), *event_work_, stepped, slopes_, first == kPlain);
      if (first == kPlain) return;
      for (int j = 0; j < n_state; ++j)
        x_rows[j] = j < nx ? out[j] : (sampled ? sd[i_z + j - nx] : out[i_z + j - nx]);
      for (int j = n_state; j < rows; ++j) x_rows[j] = held[j - n_state];
      read_pass(first, x_rows.data(), rows, ntau + n_ref, value, dx, dc);
    };
    if (!script_.events.empty()) pass(kPlain);
    for (int first = 0; first < rows + ntau + n_ref; first += kDirections) pass(first);
    dual_->arm.target_kind = TARGET_NONE;
    return {o_value, o_dx, o_dc, int(script_.events.size())};
  }

  // --- the arm controller (arm_control.hpp) -------------------------------------------------
  // Drive the arm by its controller, on the system record's arrays (engine/system.py's
  // SystemData: arm, arm_gains, arm_limits, ref_starts, ref_coeffs, arm_ref, ff_masses); again
  // whenever the record's reference arrays are replaced (they grew).
  void drive_arm(F64 settings, In gains, In limits, In starts, In coeffs, F64 last,
                 In ff_masses) {
    const Model& m = run_.model;
    const size_t n = m.n(), n_arm = m.n_u() - 2;
    if (run_.size != arm_state_size(m))
      throw std::invalid_argument("drive_arm: the state has no arm controller's entries");
    need(settings, 4, "arm");
    need(gains, 3 * n_arm, "arm_gains");
    need(limits, n_arm, "arm_limits");
    const size_t capacity = starts.size();
    need(coeffs, capacity * n_arm * REF_WIDTH, "ref_coeffs");
    if (capacity == 0 || settings.data()[ARM_SEGMENTS] > double(capacity))
      throw std::invalid_argument("ref_starts: fewer segments than arm[ARM_SEGMENTS]");
    need(last, ARM_ROWS * n_arm, "arm_ref");
    if (ff_masses.size() != 0) need(ff_masses, 4 + 10 * n, "ff_masses");
    if (counters_ < 6)
      throw std::invalid_argument("counters: expected 6 or more with an arm controller");
    ff_model_ = m;
    if (ff_masses.size()) {  // a model error: its masses, inertias, payload; the plant's geometry
      const double* f = ff_masses.data();
      ff_model_.base.mass = f[0];
      ff_model_.base.yaw_inertia = f[1];
      ff_model_.base.wheel_inertia = f[2];
      ff_model_.tip_mass = f[3];
      for (size_t k = 0; k < n; ++k) {
        ff_model_.mu[k] = f[4 + k];
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j) ff_model_.J[k][i][j] = f[4 + n + 9 * k + 3 * i + j];
      }
    }
    arm_arrays_ = nb::make_tuple(settings, gains, limits, starts, coeffs, last, ff_masses);
    run_.arm = ArmControl{.settings = settings.data(),
                          .gains = gains.data(),
                          .limits = limits.data(),
                          .starts = starts.data(),
                          .coeffs = coeffs.data(),
                          .last = last.data(),
                          .model = &ff_model_,
                          .held = run_.system.rate > 0.0 ? run_.system.held : nullptr};
  }

  // The sampled controllers' update at s now (in place; the clock's count is the caller's):
  // true when the release it made failed its contact solve.
  bool update(F64 s) {
    check_state(s);
    if (!(run_.system.rate > 0.0)) throw std::invalid_argument("update: the controllers are "
                                                               "continuous (rate 0)");
    sync_locks(run_);
    return mms::update_controllers(run_, s.data()) != DONE;
  }

  // (q_ref, q̇_ref, q̈_ref) (3 × n_arm) of the arm's reference at clock τ.
  Out arm_reference(double tau) {
    if (!run_.arm.settings) throw std::invalid_argument("arm_reference: no arm controller");
    const int n_arm = run_.n_u() - 2;
    double* ref;
    Out out = new_array({3, size_t(n_arm)}, &ref);
    mms::reference(run_.arm.starts, run_.arm.coeffs, int(run_.arm.settings[ARM_SEGMENTS]), n_arm,
                   tau, ref, 0);
    return out;
  }
  // --- end of the arm controller ------------------------------------------------------------

  // --- radau and bdf: SciPy's solver steps from Python (engine/scipy_steps.py), each step handed
  // in as the adaptive run's step in hand; events, targets, impacts, releases and the Zeno guard
  // are the core's (adaptive_stepping.hpp). SciPy's right-hand side is `derivative` above.

  // The solver's next step starts at (t0, y0).
  void begin_step(double t0, In y0) {
    need(y0, run_.size, "y0");
    mms::begin_handed_step(run_, outside_run("begin_step"), t0, y0.data());
  }

  // Its step of length h (s): its end state y1 and its interpolant as a power series, rows of
  // (rows ≤ 7, state) coefficients c_j of y(θ) = y₀ + Σ_j c_j θ^(j+1) (engine/scipy_steps.py).
  void hand_in_step(double h, In y1, In series) {
    AdaptiveRun& a = outside_run("hand_in_step");
    need(y1, run_.size, "y1");
    const size_t rows = series.ndim() == 2 ? series.shape(0) : 0;
    if (series.ndim() != 2 || series.shape(1) != size_t(run_.size) || rows > size_t(kMaxDense))
      throw std::invalid_argument("series: expected (rows ≤ " + std::to_string(kMaxDense) +
                                  ", " + std::to_string(run_.size) + ") coefficients");
    mms::hand_in_step(run_, a, h, y1.data(), series.data(), int(rows));
  }

  // f(y₁) of the step in hand, counted and watched (the release check reads it).
  void step_end_derivative() {
    AdaptiveRun& a = outside_run("step_end_derivative");
    sync_locks(run_);
    mms::step_end_derivative(run_, a);
  }

  // The first event in the step in hand (an impact, or a resting rod's stop pulling).
  void locate_event() {
    AdaptiveRun& a = outside_run("locate_event");
    sync_locks(run_);
    mms::locate_event(run_, a);
  }

  // Move (t, s) to t_end inside the step in hand, or to its event (then applied) when t_end lies
  // past it: true at t_end, false when the solver must take a step.
  bool reach(F64 s, F64 clock, double t_end) {
    check(s, clock);
    AdaptiveRun& a = outside_run("reach");
    sync_locks(run_);
    return mms::reach(run_, a, s.data(), clock.data(), t_end);
  }

  // No step in hand: the next one starts a new solve.
  void drop_step() { outside_run("drop_step").solve.h = 0.0; }

  // After an accepted step h (s) from t_before (s): true when the solver crawls (step_watch).
  bool watch_step(double t_before, double h) {
    return mms::watch_step(outside_run("watch_step").watch, t_before, h);
  }

 private:
  void check(const F64& s, const F64& clock) {
    check_state(s);
    need(clock, CLOCK_ENTRIES, "clock");
  }

  // s has the run's entries, and the arm controller's are driven when s has them.
  template <class Array>
  void check_state(const Array& s) {
    need(s, run_.size, "s");
    if (run_.size != state_size(run_.model) && !run_.arm.settings)
      throw std::invalid_argument("s: an arm controller's state, and drive_arm not called");
  }

  AdaptiveRun& outside_run(const char* call) {
    if (!adaptive_ || !adaptive_->outside)
      throw std::invalid_argument(std::string(call) + ": only for radau and bdf (SciPy's steps)");
    return *adaptive_;
  }

  void not_outside(const char* call) const {
    if (adaptive_ && adaptive_->outside)
      throw std::invalid_argument(std::string(call) + ": radau and bdf are stepped from Python "
                                  "(hand_in_step, reach)");
  }

  // What a step changes of the run's records beyond its state (which rods rest and are watched,
  // the impact log's rows in use, the Zeno guard's records, the counters, the holding watch, the
  // locks, the arm's last evaluation, the efforts sampled controllers hold), kept to be put back
  // after a step taken for its derivative.
  struct Records {
    std::vector<std::int64_t> resting, counters, free;
    std::vector<char> watched;
    std::vector<double> runs, holding, last, held;
    std::int64_t count, failed;
    double segment = 0;
    Records(const Run& run, size_t n_counters)
        : resting(run.stops.resting, run.stops.resting + run.n()),
          counters(run.system.counters, run.system.counters + n_counters),
          free(run.system.free, run.system.free + run.n_u()),
          watched(run.stops.watched, run.stops.watched + run.n()),
          runs(run.stops.run, run.stops.run + run.n() * 2 * RUN_FIELDS),
          holding(run.system.holding, run.system.holding + 2),
          held(run.system.held, run.system.held + run.n_u()), count(run.stops.count[0]),
          failed(run.stops.failed[0]) {
      if (run.arm.settings != nullptr) {
        segment = run.arm.settings[ARM_SEGMENT];
        last.assign(run.arm.last, run.arm.last + ARM_ROWS * (run.n_u() - 2));
      }
    }
    void restore(Run& run) const {
      std::copy(resting.begin(), resting.end(), run.stops.resting);
      std::copy(counters.begin(), counters.end(), run.system.counters);
      std::copy(free.begin(), free.end(), run.system.free);
      for (int k = 0; k < run.n(); ++k) run.stops.watched[k] = watched[k] != 0;
      std::copy(runs.begin(), runs.end(), run.stops.run);
      std::copy(holding.begin(), holding.end(), run.system.holding);
      std::copy(held.begin(), held.end(), run.system.held);
      run.stops.count[0] = count;
      run.stops.failed[0] = failed;
      if (run.arm.settings != nullptr) {
        run.arm.settings[ARM_SEGMENT] = segment;
        std::copy(last.begin(), last.end(), run.arm.last);
      }
      sync_locks(run);
    }
  };

  EventScript script_;  // the events of the last step differentiated
  std::vector<double> slopes_;  // … dg/dh* of each
  std::unique_ptr<SystemWorkspace<DualD>> dual_;     // made at the first derivative
  std::unique_ptr<EventWork<DualD>> event_work_;
  nb::object owner_;   // the Dynamics whose model the run uses
  nb::object arrays_;  // the arrays the run points into, kept alive
  Method method_ = Method::Rk4;
  Run run_;
  std::unique_ptr<AdaptiveRun> adaptive_;  // rk45, dop853: the solve; null for a fixed step
  size_t counters_ = 0;    // entries of the counters array
  Model ff_model_;         // the arm's feed-forward model (drive_arm)
  nb::object arm_arrays_;  // the arm controller's arrays, kept alive
};


constexpr long kLaneGroup = 64;  // lanes per thread's group, among which vector blocks form

// A batch's lanes (lanes.hpp): the steppers of its simulations with their states and clocks,
// advanced together by `advance` over several threads, without the GIL. Each lane's records
// stay its simulation's; this only holds them (and keeps them alive) for the calls.
class LaneSet {
 public:
  LaneSet(nb::list steppers, nb::list states, nb::list clocks)
      : steppers_(steppers), states_(states), clocks_(clocks) {
    const size_t m = nb::len(steppers);
    if (nb::len(states) != m || nb::len(clocks) != m)
      throw std::invalid_argument("lanes: one stepper, state and clock per lane");
    for (size_t i = 0; i < m; ++i) {
      Stepper& stepper = nb::cast<Stepper&>(steppers[i]);
      F64 s = nb::cast<F64>(states[i]), clock = nb::cast<F64>(clocks[i]);
      Run& run = stepper.run();
      need(s, run.size, "s");
      need(clock, CLOCK_ENTRIES, "clock");
      if (i > 0 && run.size != lanes_[0].run->size)
        throw std::invalid_argument("lanes: the lanes of a batch have one state size");
      lanes_.push_back(Lane{&run, stepper.method(), s.data(), clock.data()});
    }
  }

  // Every lane lanes[j] (its records at index records[j]) from next_sample[lane] towards sample
  // `last`: code, next_sample and failure per lane as batch/runs.py reads
  // them; rows (N × samples × (size + 1)) and rows_t (N × samples) its samples with `write`
  // (else one row per lane, never written); log … count each lane's own impact log; paths
  // (N × 2) its grid steps taken in vector blocks and alone. `vector`: plain grid steps in
  // vector blocks; `threads` threads.
  void advance(I64 lanes, I64 records, In times, long last, F64 rows, F64 rows_t, bool write,
               long budget, I64 code, I64 next_sample, I64 failure, F64 log, F64 log_q, F64 log_u,
               Bools log_free, I64 count, I64 paths, bool vector, int threads) {
    const size_t m = lanes.size(), n_lanes = code.size();
    need(records, m, "records");
    need(next_sample, n_lanes, "next_sample");
    need(failure, n_lanes, "failure");
    need(count, n_lanes, "count");
    need(paths, 2 * n_lanes, "paths");
    if (last < 0 || size_t(last) > times.size()) throw std::invalid_argument("last: out of range");
    if (rows.ndim() != 3 || rows.shape(0) != n_lanes || rows_t.ndim() != 2 ||
        rows_t.shape(0) != n_lanes)
      throw std::invalid_argument("rows, rows_t: expected one block of rows per lane");
    const size_t size = lanes_.empty() ? 0 : lanes_[0].run->size;
    if (write && (rows.shape(1) < size_t(last) || rows.shape(2) != size + 1 ||
                  rows_t.shape(1) < size_t(last)))
      throw std::invalid_argument("rows: expected (lanes, samples, state + 1)");
    if (log.ndim() != 3 || log.shape(0) != n_lanes || log.shape(2) != LOG_COLUMNS)
      throw std::invalid_argument("log: expected (lanes, rows, " + std::to_string(LOG_COLUMNS) +
                                  ")");
    const size_t log_rows = log.shape(1);
    std::vector<long> chosen(m), record(m);
    for (size_t j = 0; j < m; ++j) {
      chosen[j] = long(lanes.data()[j]);
      record[j] = long(records.data()[j]);
      if (chosen[j] < 0 || size_t(chosen[j]) >= n_lanes || record[j] < 0 ||
          size_t(record[j]) >= lanes_.size())
        throw std::invalid_argument("lanes, records: out of range");
    }
    if (!lanes_.empty()) {
      const Run& run = *lanes_[0].run;
      need(log_q, n_lanes * log_rows * run.n_q(), "log_q");
      need(log_u, n_lanes * log_rows * 2 * run.n_u(), "log_u");
      need(log_free, n_lanes * log_rows * run.n_u(), "log_free");
    }
    const LaneCall call{times.data(), last, write, budget};
    auto out_of = [&, rows_stride = rows.shape(1) * rows.shape(2), t_stride = rows_t.shape(1)](
                      long lane) {
      const Run& run = *lanes_[0].run;
      return LaneOut{rows.data() + lane * rows_stride, rows_t.data() + lane * t_stride,
                     LaneLog{log.data() + lane * log_rows * LOG_COLUMNS,
                             log_q.data() + lane * log_rows * run.n_q(),
                             log_u.data() + lane * log_rows * 2 * run.n_u(),
                             log_free.data() + lane * log_rows * run.n_u(), count.data() + lane,
                             int(log_rows)}};
    };
    nb::gil_scoped_release free_the_interpreter;
    threads = std::max(threads, 1);
    if (vector) {  // groups of lanes, one thread's each, among which the blocks form
      const long group = std::min<long>(kLaneGroup, std::max<long>(kLaneWidth,
                                                                   (long(m) + threads - 1) / threads));
      on_threads(threads, (long(m) + group - 1) / group, [&](long g) {
        const long start = g * group, size = std::min<long>(group, long(m) - start);
        std::vector<Lane*> members(size);
        std::vector<LaneFlow> flows(size);
        std::vector<LaneOut> outs;
        std::vector<std::int64_t*> lane_paths(size);
        for (long j = 0; j < size; ++j) {
          const long lane = chosen[start + j];
          members[j] = &lanes_[record[start + j]];
          flows[j].at = next_sample.data()[lane];
          outs.push_back(out_of(lane));
          lane_paths[j] = paths.data() + 2 * lane;
        }
        run_group<kLaneWidth>(members.data(), flows.data(), outs.data(), lane_paths.data(),
                              int(size), call, [&](long j, int c, int status) {
                                const long lane = chosen[start + j];
                                code.data()[lane] = c;
                                next_sample.data()[lane] = flows[j].at;
                                failure.data()[lane] = status;
                              });
      });
      return;
    }
    on_threads(threads, long(m), [&](long j) {
      const long lane = chosen[j];
      LaneFlow flow;
      flow.at = next_sample.data()[lane];
      LaneOut out = out_of(lane);
      int status = DONE;
      code.data()[lane] = run_lane(lanes_[record[j]], flow, call, out, status,
                                   paths.data() + 2 * lane + 1);
      next_sample.data()[lane] = flow.at;
      failure.data()[lane] = status;
    });
  }

  size_t size() const { return lanes_.size(); }

 private:
  nb::object steppers_, states_, clocks_;  // kept alive while the lanes point into them
  std::vector<Lane> lanes_;
};

// The end stops' contact problem alone (stops.hpp `solve_contacts`, every contact unilateral):
// the LCP P ≥ 0, w = W P + q ≥ 0, Pᵀw = 0 for a symmetric positive definite W (m × m); (P, w).
std::tuple<Out, Out> contact_solve(In W, In q) {
  const size_t m = q.ndim() == 1 ? q.shape(0) : 0;
  if (q.ndim() != 1 || W.ndim() != 2 || W.shape(0) != m || W.shape(1) != m)
    throw std::invalid_argument("solve_contacts: expected W of shape (m, m) and q of (m,)");
  std::vector<char> bilateral(m, 0), active(m, 0);
  std::vector<double> L(m * (m + 1));
  std::vector<int> idx(m);
  double *P, *w;
  Out P_out = new_array({m}, &P), w_out = new_array({m}, &w);
  if (mms::solve_contacts(W.data(), int(m), q.data(), int(m), bilateral.data(), active.data(), P,
                          w, L.data(), int(m) + 1, idx.data()) < 0)
    throw std::runtime_error("solve_contacts: no solution found");
  return {P_out, w_out};
}

// The Zeno guard alone (stops.hpp `zeno_guard`) on a record of the stops' runs (n × 2 ×
// RUN_FIELDS, as `StopsData.run`): rod k meets its stop `side` at t with speed and kinetic
// energy T; the energy a hold may remove there beyond the law, or −1 without evidence.
double zeno_guard_alone(F64 runs, int k, int side, double t, double speed, double T) {
  const size_t n = runs.ndim() == 3 ? runs.shape(0) : 0;
  if (runs.ndim() != 3 || runs.shape(1) != 2 || runs.shape(2) != size_t(RUN_FIELDS))
    throw std::invalid_argument("runs: expected an array of shape (n, 2, RUN_FIELDS)");
  if (k < 1 || size_t(k) > n) throw std::invalid_argument("k: expected a rod 1 … n");
  return mms::zeno_guard(runs.data(), k, side, t, speed, T);
}

// The arm's reference (arm_control.hpp `reference`) of segments starting at `starts` (count)
// with coefficients `coeffs` (count × n_arm × WIDTH, engine/arm_reference.py's layout) at the
// reference clock tau, the search starting at segment `hint`: (3, n_arm) q_ref, q̇_ref, q̈_ref.
Out reference_alone(In starts, In coeffs, double tau, int hint) {
  const size_t count = starts.ndim() == 1 ? starts.shape(0) : 0;
  if (count == 0 || coeffs.ndim() != 3 || coeffs.shape(0) != count ||
      coeffs.shape(2) != size_t(REF_WIDTH))
    throw std::invalid_argument("reference: expected starts (count,) and coeffs (count, n_arm, " +
                                std::to_string(REF_WIDTH) + ")");
  if (hint < 0 || size_t(hint) >= count) throw std::invalid_argument("hint: expected a segment");
  const size_t n_arm = coeffs.shape(1);
  double* ref;
  Out out = new_array({3, n_arm}, &ref);
  mms::reference(starts.data(), coeffs.data(), int(count), int(n_arm), tau, ref, hint);
  return out;
}

// a*b + c, as this build computes it: a build that contracts it into one fused multiply-add
// rounds once and gives another result than IEEE's two roundings (the test checks).
double multiply_add(double a, double b, double c) { return a * b + c; }

// CPU seconds of this thread per round of 6 independent multiplies and 6 independent additions
// on vectors of kLaneWidth doubles (12 × kLaneWidth flops; no fused multiply-add in this build):
// enough chains in flight to hide their latency, few enough to stay in registers. bench/ takes
// the vector peak from it.
double time_multiply_add(int rounds) {
  const Block m(1.0000001);
  Block p[6], a[6];
  for (int i = 0; i < 6; ++i) p[i] = Block(1.0 + i), a[i] = Block(1.0 - i);
  double seconds = per_call(1, [&] {
    for (int r = 0; r < rounds; ++r)
      for (int i = 0; i < 6; ++i) p[i] = p[i] * m, a[i] = a[i] + m;
  });
  Block sum(0.0);
  for (int i = 0; i < 6; ++i) sum = sum + p[i] + a[i];
  volatile double keep = sum[0];  // the chains' results are used: the loop stays
  (void)keep;
  return seconds / (rounds > 0 ? rounds : 1);
}

nb::dict build_info() {
  nb::dict info;
  info["compiler"] = std::string(__VERSION__);
  info["flags"] = std::string(MMS_CXX_FLAGS);
  info["lane_width"] = kLaneWidth;
  info["derivative_directions"] = kDirections;
#ifdef __FAST_MATH__
  info["fast_math"] = true;
#else
  info["fast_math"] = false;
#endif
  return info;
}

// The core's vocabulary of the arrays Python hands it: the indices and sizes of the records and
// the constants of the event and stop laws, owned here and read by the engine's Python modules
// (engine/status.py, system.py, stepping.py, events.py, stops.py, impact_log.py, step_watch.py).
nb::dict vocabulary() {
  nb::dict v;
#define MMS_NAME(name) v[#name] = +name;
  MMS_NAME(RHS_EVALS) MMS_NAME(DAMPING_STAGE) MMS_NAME(REDUCED_SOLVE) MMS_NAME(CROSSING_CHECKS)
  MMS_NAME(CONTROL_STAGE) MMS_NAME(ARM_CONTROL_STAGE)
  MMS_NAME(HOLDING_ON) MMS_NAME(HOLDING_LEAST_MARGIN)
  MMS_NAME(WHEEL_VELOCITY_MODE) MMS_NAME(WHEEL_KP) MMS_NAME(WHEEL_KI) MMS_NAME(WHEEL_LIMIT_R)
  MMS_NAME(WHEEL_LIMIT_L) MMS_NAME(WHEEL_TARGET_R) MMS_NAME(WHEEL_TARGET_L)
  MMS_NAME(CLOCK_T0) MMS_NAME(CLOCK_DT) MMS_NAME(CLOCK_K) MMS_NAME(CLOCK_STEPS) MMS_NAME(CLOCK_LOST)
  MMS_NAME(CLOCK_HELD) MMS_NAME(CLOCK_HOLDS) MMS_NAME(CLOCK_UPDATES) MMS_NAME(CLOCK_ENTRIES)
  MMS_NAME(DONE) MMS_NAME(BUDGET) MMS_NAME(LOG_FULL) MMS_NAME(NOT_FINITE) MMS_NAME(CHATTER)
  MMS_NAME(STALLED) MMS_NAME(CRAWLING) MMS_NAME(CONTACT_FAILED)
  MMS_NAME(LOG_TIME) MMS_NAME(LOG_LINK) MMS_NAME(LOG_SIDE) MMS_NAME(LOG_LD_BEFORE)
  MMS_NAME(LOG_LD_AFTER) MMS_NAME(LOG_LOST) MMS_NAME(LOG_RESTING) MMS_NAME(LOG_HELD)
  MMS_NAME(LOG_HOLD_LOST) MMS_NAME(LOG_HOLD_BOUND) MMS_NAME(LOG_COLUMNS)
  MMS_NAME(IMPULSE) MMS_NAME(REFLECT)
  MMS_NAME(N_SAMPLES) MMS_NAME(SIMULTANEOUS) MMS_NAME(ZENO_TAIL) MMS_NAME(ZENO_RUN)
  MMS_NAME(ZENO_SHARE) MMS_NAME(RUN_FIELDS) MMS_NAME(CONTACT_SOLVE_FAILED)
  MMS_NAME(STEP_FLOOR) MMS_NAME(FLOOR_STEPS) MMS_NAME(BUDGET_STEPS) MMS_NAME(BUDGET_SPAN)
  MMS_NAME(WATCH_SHORT) MMS_NAME(WATCH_MARK) MMS_NAME(WATCH_STEPS)
  MMS_NAME(LANE_DONE) MMS_NAME(LANE_PAUSED) MMS_NAME(LANE_FAILED)
  MMS_NAME(REF_COEFFS) MMS_NAME(HELD_QD) MMS_NAME(HELD_QDD) MMS_NAME(REF_WIDTH)
#undef MMS_NAME
  return v;
}

}  // namespace
}  // namespace mms

NB_MODULE(_core, m) {
  using mms::BaseParameters;
  m.doc() = "mobile_manip_sim's compiled core: the Gibbs–Appell dynamics, generic in its scalar";
  nb::class_<BaseParameters>(m, "BaseParameters")
      .def(nb::init<>())
      .def_rw("mass", &BaseParameters::mass)
      .def_rw("yaw_inertia", &BaseParameters::yaw_inertia)
      .def_rw("com_offset", &BaseParameters::com_offset)
      .def_rw("wheel_radius", &BaseParameters::wheel_radius)
      .def_rw("half_track", &BaseParameters::half_track)
      .def_rw("wheel_inertia", &BaseParameters::wheel_inertia);
  nb::class_<mms::WheelLoop>(m, "WheelLoop")
      .def(nb::init<>())
      .def_rw("kp", &mms::WheelLoop::kp)
      .def_rw("ki", &mms::WheelLoop::ki)
      .def_rw("limit_R", &mms::WheelLoop::limit_R)
      .def_rw("limit_L", &mms::WheelLoop::limit_L)
      .def_rw("target_R", &mms::WheelLoop::target_R)
      .def_rw("target_L", &mms::WheelLoop::target_L);
  nb::class_<mms::Dynamics>(m, "Dynamics")
      .def(nb::init<BaseParameters, mms::In, mms::In, mms::In, mms::In, mms::In, double>(),
           "base"_a, "mount"_a, "R0"_a, "L"_a, "mu"_a, "J"_a, "tip_mass"_a)
      .def_prop_ro("n", &mms::Dynamics::n)
      .def_prop_ro("n_q", &mms::Dynamics::n_q)
      .def_prop_ro("n_u", &mms::Dynamics::n_u)
      .def("inverse_dynamics", &mms::Dynamics::inverse_dynamics, "q"_a, "u"_a, "ud"_a, "g"_a)
      .def("mass_matrix", &mms::Dynamics::mass_matrix, "q"_a)
      .def("forward_dynamics", &mms::Dynamics::forward_dynamics, "q"_a, "u"_a, "Q"_a, "g"_a,
           "moving"_a)
      .def("slide_forces", &mms::Dynamics::slide_forces)
      .def("energy", &mms::Dynamics::energy, "q"_a, "u"_a, "g"_a)
      .def("joint_origins", &mms::Dynamics::joint_origins, "q"_a)
      .def("link_rotations", &mms::Dynamics::link_rotations, "q"_a)
      .def("configuration_rates", &mms::Dynamics::configuration_rates, "samples"_a)
      .def("configuration_rate", &mms::Dynamics::configuration_rate, "q"_a, "u"_a)
      .def("forward_dynamics_lanes", &mms::Dynamics::forward_dynamics_lanes, "q"_a, "u"_a,
           "Q"_a, "g"_a, "moving"_a)
      .def("rates", &mms::Dynamics::rates, "s"_a, "Q_cmd"_a, "damping"_a, "moving"_a, "g"_a,
           "wheels"_a.none() = nb::none())
      .def("step", &mms::Dynamics::step, "method"_a, "s"_a, "h"_a, "Q_cmd"_a, "damping"_a,
           "moving"_a, "g"_a, "wheels"_a.none() = nb::none())
      .def("jacobians", &mms::Dynamics::jacobians, "method"_a, "s"_a, "h"_a, "Q_cmd"_a, "B"_a,
           "damping"_a, "moving"_a, "g"_a)
      .def("advance", &mms::Dynamics::advance, "method"_a, "s"_a, "h"_a, "steps"_a, "Q_cmd"_a,
           "damping"_a, "moving"_a, "g"_a, "lanes"_a)
      .def("jacobians_many", &mms::Dynamics::jacobians_many, "method"_a, "s"_a, "h"_a,
           "Q_cmd"_a, "B"_a, "damping"_a, "moving"_a, "g"_a)
      .def("time_forward_dynamics", &mms::Dynamics::time_forward_dynamics, "q"_a, "u"_a, "Q"_a,
           "g"_a, "moving"_a, "calls"_a)
      .def("time_forward_dynamics_lanes", &mms::Dynamics::time_forward_dynamics_lanes, "q"_a,
           "u"_a, "Q"_a, "g"_a, "moving"_a, "calls"_a)
      .def("time_jacobians", &mms::Dynamics::time_jacobians, "method"_a, "s"_a, "h"_a,
           "Q_cmd"_a, "B"_a, "damping"_a, "moving"_a, "g"_a, "calls"_a)
      .def("time_dynamics", &mms::Dynamics::time_dynamics, "what"_a, "q"_a, "u"_a, "x"_a, "g"_a,
           "calls"_a)
      .def("time_rates", &mms::Dynamics::time_rates, "s"_a, "Q_cmd"_a, "damping"_a, "moving"_a,
           "g"_a, "calls"_a)
      .def("time_step", &mms::Dynamics::time_step, "method"_a, "s"_a, "h"_a, "Q_cmd"_a,
           "damping"_a, "moving"_a, "g"_a, "calls"_a)
      .def("count_forward_dynamics", &mms::Dynamics::count_forward_dynamics, "q"_a, "u"_a,
           "Q"_a, "g"_a)
      .def_prop_ro("state_size", &mms::Dynamics::state_length)
      .def("initial_step", &mms::Dynamics::initial_step, "method"_a, "s"_a, "span"_a, "rtol"_a,
           "atol"_a, "max_step"_a, "Q_cmd"_a, "damping"_a, "moving"_a, "g"_a,
           "wheels"_a.none() = nb::none())
      .def("adaptive_step", &mms::Dynamics::adaptive_step, "method"_a, "s"_a, "t"_a, "h_abs"_a,
           "t_bound"_a, "rtol"_a, "atol"_a, "Q_cmd"_a, "damping"_a, "moving"_a, "g"_a,
           "wheels"_a.none() = nb::none())
      .def("dense_output", &mms::Dynamics::dense_output, "thetas"_a, "full"_a)
      .def("adaptive_run", &mms::Dynamics::adaptive_run, "method"_a, "s"_a, "times"_a, "rtol"_a,
           "atol"_a, "Q_cmd"_a, "damping"_a, "moving"_a, "g"_a, "wheels"_a.none() = nb::none(),
           "max_steps"_a = 10'000'000, "changes"_a = std::vector<double>());
  m.attr("vocabulary") = mms::vocabulary();
  m.def("build_info", &mms::build_info);
  m.def("solve_contacts", &mms::contact_solve, "W"_a, "q"_a);
  m.def("arm_reference", &mms::reference_alone, "starts"_a, "coeffs"_a, "tau"_a, "hint"_a = 0);
  m.def("zeno_guard", &mms::zeno_guard_alone, "runs"_a, "k"_a, "side"_a, "t"_a, "speed"_a,
        "T"_a);
  m.def("multiply_add", &mms::multiply_add, "a"_a, "b"_a, "c"_a);
  m.def("time_multiply_add", &mms::time_multiply_add, "rounds"_a);
  nb::class_<mms::Stepper>(m, "Stepper")
      .def(nb::init<nb::object, const std::string&, double, mms::In, mms::I64, mms::In, mms::In,
                    mms::I64, mms::F64, mms::Bools, mms::I64, mms::In, mms::Bools, int, double,
                    double, mms::F64, mms::F64, mms::F64, mms::Bools, mms::I64, mms::F64,
                    mms::I64, mms::F64, mms::F64, mms::F64, mms::F64, mms::F64, mms::I64, double,
                    double, mms::F64, double, mms::F64>(),
           "dynamics"_a, "method"_a, "gravity"_a, "damping"_a, "free"_a, "Q_cmd"_a, "control"_a,
           "counters"_a, "holding"_a, "watched"_a, "resting"_a, "stroke"_a, "permanent"_a,
           "law"_a, "restitution"_a, "rest_speed"_a, "log"_a, "log_q"_a, "log_u"_a,
           "log_free"_a, "count"_a, "run"_a, "failed"_a, "out"_a, "trial"_a, "stages"_a,
           "forces"_a, "samples"_a, "crossed"_a, "rtol"_a, "atol"_a, "watch"_a, "rate"_a,
           "held"_a)
      .def("advance", &mms::Stepper::advance, "s"_a, "clock"_a, "t_end"_a, "max_steps"_a)
      .def("advance_samples", &mms::Stepper::advance_samples, "s"_a, "clock"_a, "times"_a,
           "rows"_a, "first"_a, "max_steps"_a)
      .def("total_energy", &mms::Stepper::total_energy, "s"_a)
      .def("restart", &mms::Stepper::restart)
      .def("step_in_hand", &mms::Stepper::step_in_hand)
      .def("next_step", &mms::Stepper::next_step)
      .def("step_end", &mms::Stepper::step_end)
      .def("relock", &mms::Stepper::relock)
      .def("release", &mms::Stepper::release, "s"_a, "at_root"_a)
      .def("holding_margin", &mms::Stepper::holding_margin, "s"_a)
      .def("derivative", &mms::Stepper::derivative, "s"_a)
      .def("constraint_forces", &mms::Stepper::constraint_forces, "s"_a)
      .def("wheel_torques", &mms::Stepper::wheel_torques, "s"_a)
      .def("step_jacobians", &mms::Stepper::step_jacobians, "s"_a, "clock"_a, "h"_a, "B"_a,
           "target"_a = 0)
      // the arm controller
      .def("drive_arm", &mms::Stepper::drive_arm, "arm"_a, "arm_gains"_a, "arm_limits"_a,
           "ref_starts"_a, "ref_coeffs"_a, "arm_ref"_a, "ff_masses"_a)
      .def("update", &mms::Stepper::update, "s"_a)
      .def("arm_reference", &mms::Stepper::arm_reference, "tau"_a)
      // radau and bdf: SciPy's steps handed in
      .def("begin_step", &mms::Stepper::begin_step, "t0"_a, "y0"_a)
      .def("hand_in_step", &mms::Stepper::hand_in_step, "h"_a, "y1"_a, "series"_a)
      .def("step_end_derivative", &mms::Stepper::step_end_derivative)
      .def("locate_event", &mms::Stepper::locate_event)
      .def("reach", &mms::Stepper::reach, "s"_a, "clock"_a, "t_end"_a)
      .def("drop_step", &mms::Stepper::drop_step)
      .def("watch_step", &mms::Stepper::watch_step, "t_before"_a, "h"_a);
  nb::class_<mms::LaneSet>(m, "LaneSet")
      .def(nb::init<nb::list, nb::list, nb::list>(), "steppers"_a, "states"_a, "clocks"_a)
      .def("advance", &mms::LaneSet::advance, "lanes"_a, "records"_a, "times"_a, "last"_a,
           "rows"_a, "rows_t"_a, "write"_a, "budget"_a, "code"_a, "next_sample"_a, "failure"_a,
           "log"_a, "log_q"_a, "log_u"_a, "log_free"_a, "count"_a, "paths"_a, "vector"_a,
           "threads"_a)
      .def("__len__", &mms::LaneSet::size);
}
