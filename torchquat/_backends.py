"""The few functions a formula takes from a namespace, for Python floats and for tensors.

A formula in :mod:`torchquat._formulas` is written with ``+ - * /``, comparisons, ``&``, ``|`` and
the functions below, taken from its first argument ``m``. :data:`FLOATS` runs it on one rotation's
Python floats (no dispatch cost), :data:`ARRAYS` on NumPy columns of a CPU batch, :data:`TENSORS`
on tensor columns, eagerly or traced by ``torch.compile``. ``where`` is a selection, never a Python branch on data, so the tensor form has
no graph breaks and no device syncs; its discarded side must still be finite (the "safe
substitute" pattern), since autograd multiplies its gradient by zero.
"""

import math

import numpy
import torch


def _float_where(condition, a, b):
    return a if condition else b


def _float_sign(x):
    return math.copysign(1.0, x) if x != 0 else 0.0 * x  # (NaN stays NaN)


class _Floats:
    """``math`` for one row: double precision, the input's dtype restored by the caller."""

    sqrt = staticmethod(math.sqrt)
    sin = staticmethod(math.sin)
    cos = staticmethod(math.cos)
    atan2 = staticmethod(math.atan2)
    fmod = staticmethod(math.fmod)
    abs = staticmethod(abs)
    copysign = staticmethod(math.copysign)
    sign = staticmethod(_float_sign)
    where = staticmethod(_float_where)
    maximum = staticmethod(max)
    pi = math.pi


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
    maximum = staticmethod(torch.maximum)
    pi = math.pi

    @staticmethod
    def copysign(a, b):
        return torch.copysign(torch.as_tensor(a, dtype=b.dtype, device=b.device), b) if isinstance(a, float) \
            else torch.copysign(a, b)


class _Arrays:
    """NumPy for columns of a CPU batch: a tenth to a half of PyTorch's cost an operation on
    thousands of rows (both read and write memory at the same speed on larger ones)."""

    sqrt = staticmethod(numpy.sqrt)
    sin = staticmethod(numpy.sin)
    cos = staticmethod(numpy.cos)
    atan2 = staticmethod(numpy.arctan2)
    fmod = staticmethod(numpy.fmod)
    abs = staticmethod(numpy.abs)
    sign = staticmethod(numpy.sign)
    where = staticmethod(numpy.where)
    maximum = staticmethod(numpy.maximum)
    copysign = staticmethod(numpy.copysign)
    pi = math.pi


FLOATS = _Floats()
ARRAYS = _Arrays()
TENSORS = _Tensors()
