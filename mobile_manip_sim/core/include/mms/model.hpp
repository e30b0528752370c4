// The robot's constants (`Model`, shared, never written) and one evaluation's scratch
// (`Workspace<S>`, preallocated, one per simulation or thread), as in Pinocchio's Model/Data.
//
// Workspace vectors are in the world frame `odom`, SI units; k = 0 is the base, k = 1 … n the arm
// links. Spatial vectors are 6 numbers (angular part first), taken about A, the base's axle
// midpoint at the current instant. The coordinates follow docs/model.md:
// q = (x, y, yaw, θ_R, θ_L, q_1, l_1, …, q_n, l_n), u = (v, ω, q̇_1, l̇_1, …).
#pragma once

#include <array>
#include <vector>

#include "scalar.hpp"
#include "vec3.hpp"

namespace mms {

// Positions in q and u (scene/coordinates.py owns them; these restate its formulas).
constexpr int X = 0, Y = 1, YAW = 2, WHEEL_R = 3, WHEEL_L = 4;
constexpr int V = 0, OMEGA = 1;
inline int q_turn(int k) { return 3 + 2 * k; }   // q_k (k = 1 … n)
inline int q_slide(int k) { return 4 + 2 * k; }  // l_k
inline int u_turn(int k) { return 2 * k; }       // q̇_k, and τ_k in Q
inline int u_slide(int k) { return 2 * k + 1; }  // l̇_k, and F_k in Q

// The constants are of a type P: double for one robot, or a lane type (scalar.hpp) for a vector
// block of runs whose robots differ in their numbers (a batch's lanes, lanes.hpp), each lane
// holding its own run's constants.
template <class P>
struct BaseParametersOf {
  P mass = 0.0;           // M_pw, kg: base + wheels
  P yaw_inertia = 0.0;    // I_pw, kg·m²: about the vertical through G
  P com_offset = 0.0;     // d, m: from A forward to G
  P wheel_radius = 0.0;   // r, m
  P half_track = 0.0;     // b, m: from A to each wheel centre
  P wheel_inertia = 0.0;  // I_w, kg·m²: one wheel's spin inertia (0 when the effect is off)
};
using BaseParameters = BaseParametersOf<double>;

template <class P>
struct ModelOf {
  BaseParametersOf<P> base;
  Vec3<P> mount{};           // m: O_1 in base_link
  std::vector<Mat3<P>> R0;   // (n) R0_k: parent joint frame → joint frame k before Rz(q_k)
  std::vector<P> L;          // (n) m: rod lengths
  std::vector<P> mu;         // (n) kg/m: mass per length
  std::vector<Mat3<P>> J;    // (n) kg·m: cross-section inertia per length, link frame
  P tip_mass = 0.0;          // kg: point payload at the distal end of rod n
  int n() const { return static_cast<int>(L.size()); }
  int n_q() const { return 2 * n() + 5; }
  int n_u() const { return 2 * n() + 2; }
};
using Model = ModelOf<double>;

template <class S> using Spatial = std::array<S, 6>;
template <class S> using Subspace = std::array<Spatial<S>, 2>;  // columns (turn, slide)

template <class S>
struct Workspace {
  using Real = RealOf<S>;
  std::vector<Mat3<S>> R;      // (n+1) orientation of joint frame k (R[0]: base_link)
  std::vector<Vec3<S>> O;      // (n+2) m: O[0] = A, O[k] = O_k, O[n+1] = tip
  std::vector<Vec3<S>> x, z;   // (n+1) x_k the rod's axis, z_k the joint's axis (x[0] heading)
  std::vector<Vec3<S>> F, N;   // (n+2) N, N·m: Gibbs–Appell rod force Σμa and moment about O_k
  std::vector<Subspace<S>> Sk; // (n+1) motion subspace about A; Sk[0]: (v, ω)
  std::vector<Spatial<S>> Vk;  // (n+1) spatial velocity of rod k (Vk[0]: the base)
  std::vector<Spatial<S>> Ck;  // (n+1) velocity-product acceleration of pair k, Ṡ_k u_k
  std::vector<Subspace<S>> Uk; // (n+1) I^A_k S_k
  std::vector<std::array<S, 3>> D_inv;  // (n+1) (S_kᵀ I^A_k S_k)⁻¹ as (00, 11, 01)
  std::vector<std::array<S, 2>> u_art;  // (n+1) Q_k − S_kᵀ p^A_k
  std::array<std::array<S, 6>, 6> I_art;  // articulated inertia of the subchain so far
  Spatial<S> p_art;                       // … and its bias force
  std::vector<Real> moving;    // (n_u) 1 for a free pseudo-velocity, 0 for a locked one
  std::vector<std::array<S, 7>> slide;  // (n+1) s_lᵀ I^A_k (6), then s_lᵀ p^A_k
  std::vector<S> slide_force;  // (n+1) N: the force a slide transmits, s_lᵀ (I^A_k a_k + p^A_k)

  explicit Workspace(int n)
      : R(n + 1), O(n + 2), x(n + 1), z(n + 1), F(n + 2), N(n + 2), Sk(n + 1), Vk(n + 1),
        Ck(n + 1), Uk(n + 1), D_inv(n + 1), u_art(n + 1), moving(2 * n + 2, Real(1.0)),
        slide(n + 1), slide_force(n + 1, S(0.0)) {
    for (auto& c : Ck) c.fill(S(0.0));
  }
};

}  // namespace mms
