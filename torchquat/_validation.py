"""The one validation helper: shapes, dtypes, broadcasting and half-precision handling.

Every public function calls :func:`prepare` on each tensor argument and :func:`restore` on its
result. Checks look only at shapes and dtypes (static under ``torch.compile``), never at values,
so they cost no device synchronisation.
"""

from typing import Sequence, Tuple

import torch
from torch import Tensor

from .errors import ShapeError

_HALF_DTYPES = (torch.float16, torch.bfloat16)


def shape_text(trailing: Sequence[int]) -> str:
    """``(4,)`` -> ``"(..., 4)"``; ``(3, 3)`` -> ``"(..., 3, 3)"``."""
    return "(..., " + ", ".join(str(n) for n in trailing) + ")"


def tensor_or_as_is(x):
    """``x`` as a tensor where ``torch.as_tensor`` reads it (lists, NumPy arrays), else ``x`` itself,
    for :func:`prepare` to name: for functions whose accepted shape depends on ``x``'s dimensions."""
    if isinstance(x, Tensor):
        return x
    try:
        return torch.as_tensor(x)
    except (TypeError, ValueError, RuntimeError):
        return x


def prepare(x, fn: str, name: str, trailing: Tuple[int, ...]) -> Tuple[Tensor, torch.dtype]:
    """Check ``x`` and return it in the dtype to compute in, with the dtype to return.

    Raises ``TypeError`` for non-tensors of non-floating type and ``ShapeError`` when the
    trailing dimensions are not ``trailing`` (a tuple). float16/bfloat16 are computed in float32.
    """
    if not isinstance(x, Tensor):
        try:
            x = torch.as_tensor(x)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(f"{fn}: expected {name} to be a tensor, got {type(x).__name__}") from None
    dtype = x.dtype
    if not dtype.is_floating_point:
        raise TypeError(f"{fn}: expected {name} to be a floating-point tensor, got dtype {dtype}")
    # (a torch.Size equals a tuple; a shorter shape's slice is the whole, shorter shape)
    if trailing and x.shape[-len(trailing):] != trailing:
        raise ShapeError(f"{fn}: expected {name} of shape {shape_text(trailing)}, got {tuple(x.shape)}")
    if dtype in _HALF_DTYPES:
        return x.float(), dtype
    return x, dtype


def restore(y: Tensor, dtype: torch.dtype) -> Tensor:
    """Round a float32 result back to the caller's half-precision dtype (no-op otherwise)."""
    return y if y.dtype == dtype else y.to(dtype)


def check_broadcast(fn: str, names: Sequence[str], tensors: Sequence[Tensor],
                    trailing: Sequence[int]) -> None:
    """Raise ``ShapeError`` unless the batch shapes (all but the trailing dims) broadcast."""
    batches = [tuple(t.shape[: t.dim() - n]) for t, n in zip(tensors, trailing)]
    ndim = max(len(b) for b in batches)
    for axis in range(1, ndim + 1):
        size = None  # (compared, never hashed: a set of symbolic sizes made torch.compile specialise
        # every batch size, recompiling until fullgraph=True failed, and torch.export refuse them)
        for b in batches:
            if len(b) >= axis and b[-axis] != 1:
                if size is not None and b[-axis] != size:
                    got = " and ".join(str(b) for b in batches)
                    raise ShapeError(f"{fn}: expected {' and '.join(names)} with broadcastable batch shapes, got {got}")
                size = b[-axis]


def prepare_pair(fn: str, names: Sequence[str], a, b, trailing_a: Tuple[int, ...],
                 trailing_b: Tuple[int, ...]) -> Tuple[Tensor, Tensor, torch.dtype]:
    """:func:`prepare` both arguments of a two-argument function, check that their batch shapes
    broadcast, and promote them to one dtype; returns them and the dtype to return in."""
    a, dtype = prepare(a, fn, names[0], trailing_a)
    b, dtype_b = prepare(b, fn, names[1], trailing_b)
    if a.is_cpu != b.is_cpu:  # (is_cpu: 0.05 us, where .device costs 0.2; GPU against GPU: PyTorch's error)
        raise RuntimeError(f"{fn}: expected {names[0]} and {names[1]} on one device, got {a.device} and {b.device}")
    if (a.shape != b.shape or trailing_a != trailing_b) and \
            a.shape[: a.dim() - len(trailing_a)] != b.shape[: b.dim() - len(trailing_b)]:  # (equal: nothing to check)
        check_broadcast(fn, names, (a, b), (len(trailing_a), len(trailing_b)))
    if dtype == dtype_b:
        return a, b, dtype
    # mixed dtypes compute in and return the promoted one whatever the order (float32 with float64:
    # float64; a half-precision one with float32: float32)
    computed = torch.promote_types(a.dtype, b.dtype)
    return a.to(computed), b.to(computed), torch.promote_types(dtype, dtype_b)
