"""Four runs side by side in one vector register: numba types for the lanes engine.

`Vec4` is a number that holds four float64 *lanes*, one per run, compiled to LLVM's
``<4 x double>``: on an AVX2 CPU one ``vaddpd``/``vmulpd``/``vdivpd`` does the four runs' operation
at once. `LaneArray` (`lane_arrays.py`) is an array of such numbers: a float64 array whose last
axis (length 4) is the lanes, read and written 32 bytes at a time (structure of arrays, lanes
innermost).

The point of the types is that the dynamics kernels need no second copy. Numba compiles a kernel
for the types it is called with, so the very source of `kernels.frames` or
`articulated.forward_dynamics`, called with a model whose constants are `Vec4` / `LaneArray` and a
workspace of `LaneArray`, becomes the four-lane body (`lanes.py`). Each lane then performs the
same IEEE operations, in the same order, as the scalar kernel does for that run alone, so every
lane equals its scalar run bit for bit:

- ``+ − × ÷`` and unary ``−`` are single IEEE vector instructions, without fast-math flags and
  without contraction into fused multiply-adds (a fused multiply-add rounds once where the scalar
  code rounds twice: it would change the last bits);
- a float or an integer meeting a `Vec4` is converted as numba converts it for a float operation,
  then broadcast to the four lanes: ``0.5 * L`` is ``0.5 * L`` in each lane;
- ``x ** k`` for a constant integer k repeats numba's own unrolled squarings (``x ** 3`` is
  ``x · (x · x)``), another exponent goes lane by lane through numba's scalar power;
- ``math.sqrt`` is LLVM's vector square root (correctly rounded, as the scalar one is);
  ``math.sin``, ``math.cos`` and every other function are taken lane by lane, by numba's scalar
  implementation of the function (libm): a vector sine would be a different approximation;
- a variable that starts as ``0.0`` and then accumulates `Vec4` terms becomes a `Vec4` (its
  start broadcast), as numba unifies an int with a float.

Branches cannot depend on a `Vec4` (there is no truth value of four lanes): what a kernel decides
by an ``if`` (a locked pseudo-velocity) must be the same in the four lanes of one call.

From Python, `Lanes` holds the four values of one `Vec4` argument (``Lanes((m0, m1, m2, m3))``) and
`LaneArray` wraps an (…, 4) C-contiguous float64 array. A compiled function receives them as
`Vec4` and `LaneArray` values; a returned `Vec4` comes back as `Lanes`.

Needs numba (there is no pure-Python form of these types).
"""
from __future__ import annotations

import math
import operator

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.extending import (
    NativeValue,
    box,
    intrinsic,
    lower_cast,
    models,
    overload,
    register_model,
    typeof_impl,
    unbox,
)
from numba.core.typeconv import Conversion

WIDTH = 4   # lanes per vector: four float64 in a 256-bit AVX register
VECTOR = ir.VectorType(ir.DoubleType(), WIDTH)


class Lanes:
    """The four values of a `Vec4` argument or result, from Python."""

    __slots__ = ("values",)

    def __init__(self, values):
        values = tuple(float(value) for value in values)
        if len(values) != WIDTH:
            raise ValueError(f"Lanes takes {WIDTH} values, not {len(values)}")
        self.values = values

    def __repr__(self):
        return f"Lanes({self.values})"

    def __eq__(self, other):
        return isinstance(other, Lanes) and np.array_equal(self.values, other.values)

    __hash__ = None


# ------------------------------------------------------------------------------------ the types

class Vec4Type(types.Type):
    """Four float64 lanes; a float or an integer unifies with it (broadcast)."""

    def __init__(self):
        super().__init__(name="Vec4")

    def unify(self, typingctx, other):
        if isinstance(other, (types.Float, types.Integer)):
            return self
        return None

    def can_convert_from(self, typingctx, other):
        if isinstance(other, (types.Float, types.Integer)):
            return Conversion.safe
        return None


vec4 = Vec4Type()


@register_model(Vec4Type)
class _Vec4Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, VECTOR)


@typeof_impl.register(Lanes)
def _typeof_lanes(value, c):
    return vec4


@unbox(Vec4Type)
def _unbox_vec4(typ, obj, c):
    values = c.pyapi.object_getattr_string(obj, "values")
    vector = ir.Constant(VECTOR, None)
    for i in range(WIDTH):
        item = c.pyapi.tuple_getitem(values, i)   # borrowed
        vector = c.builder.insert_element(vector, c.pyapi.float_as_double(item),
                                          ir.Constant(ir.IntType(32), i))
    c.pyapi.decref(values)
    return NativeValue(vector, is_error=cgutils.is_not_null(c.builder, c.pyapi.err_occurred()))


@box(Vec4Type)
def _box_vec4(typ, val, c):
    values = c.pyapi.tuple_new(WIDTH)
    for i in range(WIDTH):
        item = c.builder.extract_element(val, ir.Constant(ir.IntType(32), i))
        c.pyapi.tuple_setitem(values, i, c.pyapi.float_from_double(item))   # steals
    cls = c.pyapi.unserialize(c.pyapi.serialize_object(Lanes))
    result = c.pyapi.call_function_objargs(cls, [values])
    c.pyapi.decref(values)
    c.pyapi.decref(cls)
    return result


# ------------------------------------------------------------------------- conversions, lanes

def _broadcast(builder, scalar):
    vector = builder.insert_element(ir.Constant(VECTOR, None), scalar,
                                    ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(vector, ir.Constant(VECTOR, None),
                                  ir.Constant(ir.VectorType(ir.IntType(32), WIDTH), [0] * WIDTH))


@lower_cast(types.Float, Vec4Type)
@lower_cast(types.Integer, Vec4Type)
def _number_to_vec4(context, builder, fromty, toty, val):
    """A number meeting lanes: converted to float64 as numba converts it, then broadcast."""
    return _broadcast(builder, context.cast(builder, val, fromty, types.float64))


@intrinsic
def splat(typingctx, x):
    """The Vec4 whose four lanes are the number x."""
    if isinstance(x, (types.Float, types.Integer)):
        def codegen(context, builder, sig, args):
            return _number_to_vec4(context, builder, sig.args[0], vec4, args[0])
        return vec4(x), codegen
    return None


@intrinsic
def make_vec4(typingctx, a, b, c, d):
    """The Vec4 (a, b, c, d) of four numbers."""
    if all(isinstance(t, (types.Float, types.Integer)) for t in (a, b, c, d)):
        def codegen(context, builder, sig, args):
            vector = ir.Constant(VECTOR, None)
            for i, (value, typ) in enumerate(zip(args, sig.args, strict=True)):
                vector = builder.insert_element(
                    vector, context.cast(builder, value, typ, types.float64),
                    ir.Constant(ir.IntType(32), i))
            return vector
        return vec4(a, b, c, d), codegen
    return None


@intrinsic
def lane(typingctx, x, i):
    """Lane i (0 … 3) of the Vec4 x, a float64."""
    if x is vec4 and isinstance(i, types.Integer):
        def codegen(context, builder, sig, args):
            return builder.extract_element(args[0], args[1])
        return types.float64(x, i), codegen
    return None


@overload(operator.getitem)
def _vec4_getitem(x, i):
    if x is vec4 and isinstance(i, types.Integer):
        return lambda x, i: lane(x, i)
    return None


@intrinsic
def _as_vec4_tuple(typingctx, items):
    """A tuple of numbers and Vec4 as a tuple of Vec4 (numbers broadcast)."""
    result = types.UniTuple(vec4, len(items))

    def codegen(context, builder, sig, args):
        values = [context.cast(builder, builder.extract_value(args[0], i), typ, vec4)
                  for i, typ in enumerate(sig.args[0])]
        return context.make_tuple(builder, sig.return_type, values)
    return result(items), codegen


@overload(operator.getitem)
def _mixed_tuple_getitem(items, i):
    """``t[i]`` of a tuple that mixes numbers and Vec4 (``(0.0, 0.0, ω)``) with an index known
    only at run time: the item as a Vec4 (numba indexes such tuples only by constants)."""
    if (isinstance(items, types.Tuple) and isinstance(i, types.Integer)
            and any(t is vec4 for t in items) and all(lane_operand(t) for t in items)):
        return lambda items, i: _as_vec4_tuple(items)[i]
    return None


# ------------------------------------------------------------------------------- arithmetic

def lane_operand(t):
    return t is vec4 or isinstance(t, (types.Float, types.Integer))


def _binary(key, method):
    """operator `key` (and its in-place form) on Vec4 and numbers, one IEEE vector instruction."""
    @intrinsic
    def vector_op(typingctx, a, b):
        def codegen(context, builder, sig, args):
            x, y = (context.cast(builder, value, typ, vec4)
                    for value, typ in zip(args, sig.args, strict=True))
            return getattr(builder, method)(x, y)
        return vec4(a, b), codegen

    def implementation(a, b):
        if (a is vec4 or b is vec4) and lane_operand(a) and lane_operand(b):
            return lambda a, b: vector_op(a, b)
        return None

    overload(key)(implementation)
    return vector_op


add = _binary(operator.add, "fadd")
sub = _binary(operator.sub, "fsub")
mul = _binary(operator.mul, "fmul")
div = _binary(operator.truediv, "fdiv")
_binary(operator.iadd, "fadd")
_binary(operator.isub, "fsub")
_binary(operator.imul, "fmul")
_binary(operator.itruediv, "fdiv")


def _overload_for_vec4(key, function):
    """`function` (compiled, of one Vec4) as operator or math function `key` of a Vec4."""
    def implementation(x):
        if x is vec4:
            return lambda x: function(x)
        return None
    overload(key)(implementation)


def _unary(key, emit):
    """operator or math function `key` of a Vec4: the vector instruction(s) `emit` builds."""
    @intrinsic
    def vector_op(typingctx, x):
        def codegen(context, builder, sig, args):
            return emit(builder, args[0])
        return vec4(x), codegen

    _overload_for_vec4(key, vector_op)
    return vector_op


# numba's own negation of a float is −0.0 − x (it keeps signed zeros)
_unary(operator.neg, lambda builder, x: builder.fsub(
    _broadcast(builder, ir.Constant(ir.DoubleType(), -0.0)), x))
_unary(operator.pos, lambda builder, x: x)
_unary(abs, lambda builder, x: builder.call(cgutils.get_or_insert_function(
    builder.module, ir.FunctionType(VECTOR, [VECTOR]), f"llvm.fabs.v{WIDTH}f64"), [x]))
# LLVM's vector square root, correctly rounded as the scalar one is
_unary(math.sqrt, lambda builder, x: builder.call(cgutils.get_or_insert_function(
    builder.module, ir.FunctionType(VECTOR, [VECTOR]), f"llvm.sqrt.v{WIDTH}f64"), [x]))


@intrinsic(prefer_literal=True)
def _static_power(typingctx, x, k):
    """x ** k for a constant integer k ≥ 0: numba's unrolled squarings (numbers.py
    `static_power_impl`), the same multiplications in the same order."""
    if not isinstance(k, types.IntegerLiteral):
        return None
    exponent = k.literal_value

    def codegen(context, builder, sig, args):
        result, value, e = None, args[0], exponent
        while e != 0:
            if e & 1:
                # numba starts from 1.0 · x, which LLVM folds to x (exact)
                result = value if result is None else builder.fmul(result, value)
            e >>= 1
            if e:
                value = builder.fmul(value, value)
        return result if result is not None else _broadcast(
            builder, ir.Constant(ir.DoubleType(), 1.0))
    return vec4(x, k), codegen


@overload(operator.pow, prefer_literal=True)
def _vec4_pow(x, k):
    if isinstance(k, types.IntegerLiteral) and x is vec4 and 0 <= k.literal_value <= 0x10000:
        return lambda x, k: _static_power(x, k)
    if (x is vec4 or k is vec4) and lane_operand(x) and lane_operand(k):
        return lambda x, k: _power_per_lane(x, k)
    return None


@intrinsic
def _power_per_lane(typingctx, x, k):
    """x ** k lane by lane, through numba's own scalar power of the lanes' numbers."""
    def scalar_type(t):
        return types.float64 if t is vec4 else t
    scalar = typingctx.resolve_function_type(operator.pow, (scalar_type(x), scalar_type(k)), {})

    def codegen(context, builder, sig, args):
        power = context.get_function(operator.pow, scalar)

        def operand(value, typ, index, target):
            if typ is vec4:
                value, typ = builder.extract_element(value, index), types.float64
            return context.cast(builder, value, typ, target)

        result = ir.Constant(VECTOR, None)
        for i in range(WIDTH):
            index = ir.Constant(ir.IntType(32), i)
            value = power(builder, [operand(args[0], sig.args[0], index, scalar.args[0]),
                                    operand(args[1], sig.args[1], index, scalar.args[1])])
            result = builder.insert_element(
                result, context.cast(builder, value, scalar.return_type, types.float64), index)
        return result
    return vec4(x, k), codegen


def _each_lane(builder, vector, scalar_function):
    """The Vec4 of scalar_function (LLVM double → double) applied to each lane of vector."""
    result = ir.Constant(VECTOR, None)
    for i in range(WIDTH):
        index = ir.Constant(ir.IntType(32), i)
        result = builder.insert_element(
            result, scalar_function(builder.extract_element(vector, index)), index)
    return result


def _per_lane(function):
    """math.`function` of a Vec4, lane by lane through numba's own scalar implementation of it
    (for sin and cos, the C library's, as the scalar kernels call it)."""
    @intrinsic
    def mapped(typingctx, x):
        scalar = typingctx.resolve_function_type(function, (types.float64,), {})

        def codegen(context, builder, sig, args):
            implementation = context.get_function(function, scalar)
            return _each_lane(builder, args[0], lambda value: implementation(builder, [value]))
        return vec4(x), codegen

    _overload_for_vec4(function, mapped)


for _function in (math.sin, math.cos, math.tan, math.exp, math.log, math.atan, math.tanh):
    _per_lane(_function)
