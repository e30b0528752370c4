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

Many blocks in one compiled call: `model_stack` and `block_states` lay N = 4 × blocks runs out as
(blocks, …, 4) arrays (run i in lane i % 4 of block i // 4), and `rates_blocks` evaluates them
all, block after block, reusing one workspace; compiled code reads block b's model with
`block_model` and its states with ``lane_arrays.wrap(q[b])``.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..scene.coordinates import u_size
from .articulated import articulated_forward_dynamics
from .jit import jit, jit_inline
from .kernels import configuration_rate, frames
from .lane_arrays import LaneArray, wrap
from .records import BaseParameters, Model, Workspace, make_workspace
from .vector import WIDTH, Lanes

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


# ------------------------------------------------------------------- many blocks in one call

ModelStack = namedtuple("ModelStack", [
    "base",      # (blocks, 6, 4) BaseParameters' six fields, lanes innermost
    "mount",     # (blocks, 3, 4)
    "R0",        # (blocks, n, 3, 3, 4)
    "L",         # (blocks, n, 4)
    "mu",        # (blocks, n, 4)
    "J",         # (blocks, n, 3, 3, 4)
    "tip_mass",  # (blocks, 1, 4)
])


def model_stack(models) -> ModelStack:
    """The models of N = 4 × blocks runs (`records.make_model`, one topology), as blocks of
    four lanes: run i is lane i % 4 of block i // 4 (`block_model` reads one block)."""
    models = list(models)
    if not models or len(models) % WIDTH:
        raise ValueError(f"model_stack takes a multiple of {WIDTH} models, not {len(models)}")
    blocks = [lanes_model(models[i:i + WIDTH]) for i in range(0, len(models), WIDTH)]
    return ModelStack(
        base=np.stack([_stack([[m.base[f] for f in range(6)] for m in models[i:i + WIDTH]])
                       for i in range(0, len(models), WIDTH)]),
        mount=np.stack([b.mount.array for b in blocks]),
        R0=np.stack([b.R0.array for b in blocks]), L=np.stack([b.L.array for b in blocks]),
        mu=np.stack([b.mu.array for b in blocks]), J=np.stack([b.J.array for b in blocks]),
        tip_mass=np.stack([[b.tip_mass.values] for b in blocks]))


def block_states(vectors) -> np.ndarray:
    """(blocks, size, 4) of N = 4 × blocks equally long vectors: run i in lane i % 4 of block
    i // 4 (the layout `rates_blocks` takes for q, u, Q and their rates)."""
    vectors = [np.asarray(v, dtype=float) for v in vectors]
    if not vectors or len(vectors) % WIDTH:
        raise ValueError(f"block_states takes a multiple of {WIDTH} vectors, not {len(vectors)}")
    return np.stack([_stack(vectors[i:i + WIDTH]) for i in range(0, len(vectors), WIDTH)])


@jit_inline
def block_model(stack, b):
    """The `records.Model` of block b of a `ModelStack`, as lanes, in compiled code."""
    base = wrap(stack.base[b])
    return Model(BaseParameters(base[0], base[1], base[2], base[3], base[4], base[5]),
                 wrap(stack.mount[b]), wrap(stack.R0[b]), wrap(stack.L[b]), wrap(stack.mu[b]),
                 wrap(stack.J[b]), wrap(stack.tip_mass[b])[0])


@jit
def rates_blocks(stack, q, u, Q, g, free, ws, qdot, ud):
    """`rates` for every block of runs: q, u, Q, qdot, ud are (blocks, size, 4) (`block_states`),
    g (blocks, 1, 4); ``ws`` (`lanes_workspace`) is scratch shared by the blocks, ``free`` the
    locks of them all."""
    for b in range(q.shape[0]):
        rates(block_model(stack, b), wrap(q[b]), wrap(u[b]), wrap(Q[b]), wrap(g[b])[0], free, ws,
              wrap(qdot[b]), wrap(ud[b]))
