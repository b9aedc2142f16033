"""The functions a formula takes, on each kind of value.

A formula in :mod:`torchquat._formulas` is written with ``+ - * /``, comparisons, ``&``, ``|`` and
the functions ``sqrt, sin, cos, atan2, fmod, abs, sign, where``, taken from its first argument
``m``. :data:`TENSORS` runs it directly on tensor columns, eagerly or traced by ``torch.compile``.
The straight-line code that :mod:`torchquat._codegen` writes out from a formula calls the same
functions from :data:`FLOAT_FUNCTIONS` (one rotation's Python floats) or
:data:`ARRAY_FUNCTIONS` (NumPy columns of a CPU batch).

``where`` is a selection, never a Python branch on data, so the tensor form has no graph breaks
and no device syncs; its discarded side must still be finite (the "safe substitute" pattern),
since autograd multiplies its gradient by zero.
"""

import math

import numpy
import torch


def _float_where(condition, a, b):
    return a if condition else b


def _float_sign(x):
    return math.copysign(1.0, x) if x != 0 else 0.0 * x  # (NaN stays NaN)


class _Tensors:
    """``torch`` for columns (1-D or broadcasting batch tensors)."""

    sqrt = staticmethod(torch.sqrt)
    sin = staticmethod(torch.sin)
    cos = staticmethod(torch.cos)
    atan2 = staticmethod(torch.atan2)
    fmod = staticmethod(torch.fmod)
    abs = staticmethod(torch.abs)
    sign = staticmethod(torch.sign)
    where = staticmethod(torch.where)
    pi = math.pi


TENSORS = _Tensors()

FLOAT_FUNCTIONS = {"sqrt": math.sqrt, "sin": math.sin, "cos": math.cos, "atan2": math.atan2, "fmod": math.fmod,
                   "abs": abs, "sign": _float_sign, "where": _float_where}

_BITS = {numpy.dtype(numpy.float32): numpy.int32, numpy.dtype(numpy.float64): numpy.int64}
# From this many rows a selection is made on the values' bits: NumPy's where branches on each
# element, and a condition that varies from row to row (a sign, the largest of four) mispredicts
# half of those branches: 55-65 us at 16,384 float32 rows, where a product takes 3.6 and the
# five integer steps below 11-13.
_BLEND_ROWS = 2048


def _array_where(condition, a, b):
    """``numpy.where(condition, a, b)``, for large blocks as ``b ^ ((a ^ b) & mask)`` on the bits
    (exact for every value, NaN and infinities included)."""
    if not isinstance(condition, numpy.ndarray) or condition.size < _BLEND_ROWS:
        return numpy.where(condition, a, b)
    dtype = numpy.result_type(a, b)  # (before asarray: a Python float stays weak, as in numpy.where)
    bits = _BITS.get(dtype)
    if bits is None:
        return numpy.where(condition, a, b)
    mask = numpy.negative(condition.astype(bits))  # (all bits set where true)
    a, b = numpy.asarray(a, dtype).view(bits), numpy.asarray(b, dtype).view(bits)
    return (b ^ ((a ^ b) & mask)).view(dtype)


ARRAY_FUNCTIONS = {"sqrt": numpy.sqrt, "sin": numpy.sin, "cos": numpy.cos, "atan2": numpy.arctan2,
                   "fmod": numpy.fmod, "abs": numpy.abs, "sign": numpy.sign, "where": _array_where}
