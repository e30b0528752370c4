"""Four runs' dynamics at once: the right-hand side of `kernels` and `articulated` in vector lanes.

A block of `WIDTH` = 4 runs of one topology (the same number of links; every constant may differ:
masses, lengths, joint rotations, payload, gravity) is held as structure of arrays, lanes
innermost: ``q`` is an (n_q, 4) array whose column j is run j's configuration, the model's rod
lengths an (n, 4) array, the base mass one `Vec4`, … (`vector.py`). `rates` then evaluates

    q̇ = configuration rate (nonholonomic base),  u̇ = M(q)⁻¹ (Q − h(q, u))  (articulated bodies)

for the four runs in one pass of 256-bit vector instructions. It is not a second copy of the
dynamics: it calls `kernels.frames`, `kernels.configuration_rate` and
`articulated.articulated_forward_dynamics` themselves, which numba compiles anew for lane types,
so every lane performs the scalar kernel's operations in the scalar kernel's order and equals the
scalar run of that lane bit for bit (`vector.py` says why).

Locks: ``free`` (the free pseudo-velocities, padded with −1, as the scalar kernel takes it) is
one array for the block: the four lanes of one call share their locked pseudo-velocities (a
kernel's ``if`` cannot differ between lanes). Runs whose locks differ go in different blocks,
or wait for a lane mask.

    model = lanes_model([make_model(robot_j, …) for j in range(4)])
    ws = lanes_workspace(n)
    rates(model, LaneArray(q), LaneArray(u), LaneArray(Q), Lanes(g), free, ws,
          LaneArray(qdot), LaneArray(ud))
"""
from __future__ import annotations

import numpy as np

from ..scene.coordinates import u_size
from .articulated import articulated_forward_dynamics
from .jit import jit
from .kernels import configuration_rate, frames
from .records import BaseParameters, Model, Workspace, make_workspace
from .vector import WIDTH, LaneArray, Lanes

ALIGNMENT = 64   # bytes: a lane vector (32 bytes) never straddles two cache lines


def lane_zeros(shape) -> np.ndarray:
    """Zeros of ``shape`` + (4,), C-contiguous, starting on a cache line (numpy's own arrays are
    only 16-byte aligned, and a 32-byte load across two cache lines costs more)."""
    shape = tuple(shape) + (WIDTH,)
    size = int(np.prod(shape))
    buffer = np.zeros(size + ALIGNMENT // 8)
    start = (-buffer.ctypes.data % ALIGNMENT) // 8
    return buffer[start:start + size].reshape(shape)


def _stack(values) -> np.ndarray:
    """Lanes innermost: the (…, 4) aligned array of four equally shaped values."""
    values = [np.asarray(v, dtype=float) for v in values]
    out = lane_zeros(values[0].shape)
    for j, value in enumerate(values):
        out[..., j] = value
    return out


def lanes_model(models) -> Model:
    """The `records.Model` of four runs' models (`records.make_model`), one per lane, as lanes:
    every number a `Lanes`, every array a `LaneArray`. Their links must be as many."""
    models = list(models)
    if len(models) != WIDTH:
        raise ValueError(f"lanes_model takes {WIDTH} models, one per lane, not {len(models)}")
    if len({m.L.shape[0] for m in models}) != 1:
        raise ValueError("lanes_model: the lanes' robots have different numbers of links")
    base = BaseParameters(*(Lanes([getattr(m.base, name) for m in models])
                            for name in BaseParameters._fields))
    return Model(base=base,
                 mount=LaneArray(_stack([m.mount for m in models])),
                 R0=LaneArray(_stack([m.R0 for m in models])),
                 L=LaneArray(_stack([m.L for m in models])),
                 mu=LaneArray(_stack([m.mu for m in models])),
                 J=LaneArray(_stack([m.J for m in models])),
                 tip_mass=Lanes([m.tip_mass for m in models]))


def lanes_workspace(n_links: int) -> Workspace:
    """The `records.Workspace` of a block of runs with n links: every field (…, 4), lanes
    innermost, except ``moving``, the block's one set of locks."""
    scalar = make_workspace(n_links)
    return Workspace(**{
        name: (value if name == "moving"
               else LaneArray(lane_zeros(value.shape)))
        for name, value in scalar._asdict().items()})


def lanes_state(values) -> LaneArray:
    """The LaneArray of four equally long vectors (q, u, Q, …), one per lane."""
    return LaneArray(_stack(values))


def all_free(n_links: int) -> np.ndarray:
    """``free`` with every pseudo-velocity free."""
    return np.arange(u_size(n_links))


@jit
def rates(model, q, u, Q, g, free, ws, qdot, ud):
    """q̇ into ``qdot`` and u̇ into ``ud`` for applied generalized forces Q and gravity g: the
    scalar right-hand side's dynamics (`kernels.frames`, `kernels.configuration_rate`,
    `articulated.articulated_forward_dynamics`), for scalar records or four lanes alike."""
    frames(model, q, ws)
    configuration_rate(model, q, u, qdot)
    articulated_forward_dynamics(model, q, u, Q, g, free, ws, ud)
