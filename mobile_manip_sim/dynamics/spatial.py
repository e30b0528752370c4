"""Spatial (6-D) algebra for the composite- and articulated-body passes, as pairs of 3-tuples.

Featherstone's conventions, all in the world frame `odom` and about one reference point (the
kernels use A, the base's axle midpoint, at the current instant, so no transforms are needed):

- a motion vector (twist, spatial acceleration) is ``(w, v)``: angular part, then the linear
  velocity (acceleration) of the body point at the reference point;
- a force vector is ``(n, f)``: moment about the reference point, then force;
- a rigid-body inertia is ``(m, h, I)``: mass (kg), first moment h = ∫(p − A) dm (kg·m) and
  the rotational inertia about A, I = ∫(|p − A|² 1 − (p − A)(p − A)ᵀ) dm (kg·m²), stored as the
  symmetric 6-tuple ``(xx, yy, zz, xy, xz, yz)``. As a 6×6 matrix it is
  ``[[I, [h×]], [[h×]ᵀ, m 1]]``.
"""
from .jit import jit_inline
from .vec3 import add, cross, sub


@jit_inline
def sym_matvec(I, w):
    """I · w for a symmetric 3×3 stored as (xx, yy, zz, xy, xz, yz)."""
    return (I[0] * w[0] + I[3] * w[1] + I[4] * w[2],
            I[3] * w[0] + I[1] * w[1] + I[5] * w[2],
            I[4] * w[0] + I[5] * w[1] + I[2] * w[2])


@jit_inline
def sym_add(A, B):
    return (A[0] + B[0], A[1] + B[1], A[2] + B[2], A[3] + B[3], A[4] + B[4], A[5] + B[5])


@jit_inline
def inertia_times(m, h, I, w, v):
    """Momentum of the twist (w, v): (I w + h × v, m v − h × w)."""
    n = add(sym_matvec(I, w), cross(h, v))
    f = sub((m * v[0], m * v[1], m * v[2]), cross(h, w))
    return n, f


@jit_inline
def motion_cross(w1, v1, w2, v2):
    """(w1, v1) × (w2, v2) = (w1 × w2, w1 × v2 + v1 × w2)."""
    return cross(w1, w2), add(cross(w1, v2), cross(v1, w2))


@jit_inline
def force_cross(w, v, n, f):
    """(w, v) ×* (n, f) = (w × n + v × f, w × f)."""
    return add(cross(w, n), cross(v, f)), cross(w, f)
