"""Small numerical helpers shared by the conversion modules."""

import torch
from torch import Tensor


def safe_sqrt(x2: Tensor) -> Tensor:
    """``sqrt(x2)`` whose gradient is 0 (not NaN or inf) where ``x2 == 0``.

    The kink of a norm at zero has no derivative; a zero subgradient keeps training finite.
    The discarded branch is fed 1 so autograd never evaluates ``1 / sqrt(0)`` (kornia's pattern).
    """
    positive = x2 > 0
    return torch.where(positive, torch.sqrt(torch.where(positive, x2, 1.0)), 0.0)


def small_angle_threshold(dtype: torch.dtype) -> float:
    """Squared angle below which Taylor series replace ``sin(t)/t`` and friends: ``sqrt(eps)``.

    The series kept (to ``t^4``) are exact to rounding there, and above it the closed forms have
    no cancellation worse than ``eps / t``, so both values and gradients stay accurate.
    """
    return torch.finfo(dtype).eps ** 0.5


SMALL_BATCH_ROWS = 4096
"""Batches up to this many rows take the few-operation paths (constant tables and small matmuls),
where per-operation dispatch dominates; larger ones take elementwise paths that make fewer passes
over memory. Both give the same results to rounding; the tests run both."""


def is_small(x: Tensor, row_numel: int) -> bool:
    """Whether ``x`` (rows of ``row_numel`` numbers) is a small batch (a shape test, not data).

    Inside a ``torch.compile`` trace the answer is no: inductor fuses elementwise code into one
    loop, and a matmul would split it.
    """
    return x.numel() <= SMALL_BATCH_ROWS * row_numel and not torch.compiler.is_compiling()


_CONSTANTS = {}


def constant(name: str, values, like: Tensor) -> Tensor:
    """A constant table in ``like``'s dtype and device, built once per (dtype, device).

    Inside a ``torch.compile`` trace it is built inline (it becomes a graph constant) rather than
    taken from the cache, so tracing has no side effects.
    """
    if torch.compiler.is_compiling():
        return torch.tensor(values, dtype=like.dtype, device=like.device)
    key = (name, like.dtype, like.device)
    table = _CONSTANTS.get(key)
    if table is None:
        table = _CONSTANTS[key] = torch.tensor(values, dtype=like.dtype, device=like.device)
    return table


def contract(x: Tensor, name: str, values) -> Tensor:
    """``x @ table`` for a small constant ``table`` (a vector or a matrix of a few columns).

    Eager: one matmul, the fewest dispatches. Under ``torch.compile``: the same sum written as a
    broadcast product and a reduction over a handful of terms, which inductor fuses with its
    neighbours instead of calling BLAS.
    """
    table = constant(name, values, x)
    if torch.compiler.is_compiling():
        return (x * table).sum(-1) if table.dim() == 1 else (x.unsqueeze(-1) * table).sum(-2)
    return x @ table
