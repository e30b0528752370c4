"""The index functions of `coordinates.py` (their one owner), compiled to inline into the kernels
and the engine's compiled cores; Python code calls the plain ones there."""
from ..scene import coordinates
from .jit import jit_inline

q_turn = jit_inline(coordinates.q_turn)
q_slide = jit_inline(coordinates.q_slide)
u_turn = jit_inline(coordinates.u_turn)
u_slide = jit_inline(coordinates.u_slide)
q_joint = jit_inline(coordinates.q_joint)
arm_u = jit_inline(coordinates.arm_u)
arm_turn = jit_inline(coordinates.arm_turn)
arm_slide = jit_inline(coordinates.arm_slide)
arm_size = jit_inline(coordinates.arm_size)
arm_width = jit_inline(coordinates.arm_width)
