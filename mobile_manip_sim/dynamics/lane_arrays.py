"""Arrays of four-lane numbers for the lanes engine: `LaneArray`, a float64 array whose last axis
(length 4) holds the lanes, seen by compiled code as an array of `Vec4` (`vector.py`) — read and
written 32 bytes at a time (structure of arrays, lanes innermost). ``a[i, j]`` is the `Vec4` at
``array[i, j, :]``, ``a[i]`` the `LaneArray` of the row, ``a.shape`` leaves the lane axis out,
and `wrap` makes one from a float64 array inside compiled code.

Registered with numba in every process beside `vector.py` (`jit.py` imports both).
"""
from __future__ import annotations

import operator

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.extending import (
    NativeValue,
    intrinsic,
    make_attribute_wrapper,
    models,
    overload,
    overload_attribute,
    register_model,
    typeof_impl,
    unbox,
)

from .vector import VECTOR, WIDTH, lane_operand, vec4


class LaneArray:
    """An (…, 4) C-contiguous float64 array seen by compiled code as an array of `Vec4`:
    ``a[i, j]`` is the four lanes ``array[i, j, :]``; ``a.shape`` leaves the lane axis out."""

    __slots__ = ("array",)

    def __init__(self, array):
        if not (isinstance(array, np.ndarray) and array.dtype == np.float64
                and array.ndim >= 2 and array.shape[-1] == WIDTH
                and array.flags.c_contiguous):
            raise ValueError(f"LaneArray takes a C-contiguous float64 array of at least two axes, "
                             f"the last of length {WIDTH}")
        self.array = array

    @property
    def shape(self):
        return self.array.shape[:-1]


class LaneArrayType(types.Type):
    """An array of `Vec4` of ``ndim`` axes, stored as a C-contiguous float64 array of ndim + 1."""

    def __init__(self, ndim):
        self.ndim = ndim
        self.array = types.Array(types.float64, ndim + 1, "C")
        super().__init__(name=f"LaneArray({ndim})")

    @property
    def key(self):
        return self.ndim


@register_model(LaneArrayType)
class _LaneArrayModel(models.StructModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, [("array", fe_type.array)])


make_attribute_wrapper(LaneArrayType, "array", "array")


@typeof_impl.register(LaneArray)
def _typeof_lane_array(value, c):
    return LaneArrayType(value.array.ndim - 1)


@unbox(LaneArrayType)
def _unbox_lane_array(typ, obj, c):
    array = c.pyapi.object_getattr_string(obj, "array")
    native = c.unbox(typ.array, array)
    c.pyapi.decref(array)
    lanes = cgutils.create_struct_proxy(typ)(c.context, c.builder)
    lanes.array = native.value
    return NativeValue(lanes._getvalue(), is_error=native.is_error, cleanup=native.cleanup)


# ----------------------------------------------------------------------- arrays of lanes

def _lane_pointer(context, builder, lanes_type, lanes_value, index_type, index_value):
    """Pointer to the Vec4 at a full index of a LaneArray: the flat C-order offset of the index
    over the leading axes (negative indices counted from the end, as numpy does), times the
    four lanes. One multiply per axis after the first, as the scalar kernels' own indexing."""
    proxy = cgutils.create_struct_proxy(lanes_type)(context, builder, value=lanes_value)
    array = context.make_array(lanes_type.array)(context, builder, value=proxy.array)
    shape = cgutils.unpack_tuple(builder, array.shape, lanes_type.ndim + 1)
    if isinstance(index_type, types.BaseTuple):
        indices = zip(cgutils.unpack_tuple(builder, index_value, len(index_type)), index_type,
                      strict=True)
    else:
        indices = [(index_value, index_type)]
    flat = None
    zero = ir.Constant(context.get_value_type(types.intp), 0)
    for axis, (value, typ) in enumerate(indices):
        value = context.cast(builder, value, typ, types.intp)
        if typ.signed:
            value = builder.select(builder.icmp_signed("<", value, zero),
                                   builder.add(value, shape[axis]), value)
        flat = value if flat is None else builder.add(builder.mul(flat, shape[axis]), value)
    offset = builder.mul(flat, ir.Constant(flat.type, WIDTH))
    return builder.bitcast(builder.gep(array.data, [offset], inbounds=True),
                           VECTOR.as_pointer())


@intrinsic
def _load(typingctx, lanes, index):
    """The Vec4 at a full index of a LaneArray."""
    def codegen(context, builder, sig, args):
        pointer = _lane_pointer(context, builder, sig.args[0], args[0], sig.args[1], args[1])
        return builder.load(pointer, align=8)
    return vec4(lanes, index), codegen


@intrinsic
def _store(typingctx, lanes, index, value):
    """Store a Vec4 (or a number, broadcast) at a full index of a LaneArray."""
    def codegen(context, builder, sig, args):
        pointer = _lane_pointer(context, builder, sig.args[0], args[0], sig.args[1], args[1])
        builder.store(context.cast(builder, args[2], sig.args[2], vec4), pointer, align=8)
        return context.get_dummy_value()
    return types.none(lanes, index, value), codegen


@intrinsic
def wrap(typingctx, array):
    """The LaneArray over a C-contiguous float64 array whose last axis is the lanes."""
    if (isinstance(array, types.Array) and array.dtype == types.float64 and array.ndim >= 2
            and array.layout == "C"):
        result = LaneArrayType(array.ndim - 1)

        def codegen(context, builder, sig, args):
            if context.enable_nrt:   # the result holds a reference
                context.nrt.incref(builder, sig.args[0], args[0])
            lanes = cgutils.create_struct_proxy(sig.return_type)(context, builder)
            lanes.array = args[0]
            return lanes._getvalue()
        return result(array), codegen
    return None


def _index_count(index):
    if isinstance(index, types.Integer):
        return 1
    if isinstance(index, types.BaseTuple) and all(isinstance(i, types.Integer) for i in index):
        return len(index)
    return None


@overload(operator.getitem)
def _lane_array_getitem(a, index):
    if not isinstance(a, LaneArrayType):
        return None
    count = _index_count(index)
    if count == a.ndim:
        return lambda a, index: _load(a, index)
    if count is not None and count < a.ndim:
        return lambda a, index: wrap(a.array[index])
    return None


@overload(operator.setitem)
def _lane_array_setitem(a, index, value):
    if isinstance(a, LaneArrayType) and _index_count(index) == a.ndim and lane_operand(value):
        def implementation(a, index, value):
            _store(a, index, value)
        return implementation
    return None


@overload_attribute(LaneArrayType, "shape")
def _lane_array_shape(a):
    return lambda a: a.array.shape[:-1]
