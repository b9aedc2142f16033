"""Validation and reduction shared by the modules of :mod:`torchquat.nn` (private)."""

from typing import Sequence

from torch import Tensor

from .._validation import shape_text
from ..errors import ShapeError

REDUCTIONS = ("none", "mean", "sum")


def check_reduction(module: str, reduction) -> str:
    """Return ``reduction`` if it is one of ``'none' | 'mean' | 'sum'``, else raise ``ValueError``."""
    if reduction not in REDUCTIONS:
        raise ValueError(f"{module}: expected reduction 'none', 'mean' or 'sum', got {reduction!r}")
    return reduction


def reduce(loss: Tensor, reduction: str) -> Tensor:
    """Apply a validated reduction (a Python choice fixed at construction: no graph break)."""
    if reduction == "mean":
        return loss.mean()
    if reduction == "sum":
        return loss.sum()
    return loss


def check_tensor(module: str, name: str, x, trailing: Sequence[int]) -> None:
    """Raise ``TypeError``/``ShapeError`` naming ``module`` unless ``x`` is a float tensor ``(..., *trailing)``.

    Looks at shapes and dtypes only (static under ``torch.compile``), never at values.
    """
    if not isinstance(x, Tensor):
        raise TypeError(f"{module}: expected {name} to be a tensor, got {type(x).__name__}")
    if not x.dtype.is_floating_point:
        raise TypeError(f"{module}: expected {name} to be a floating-point tensor, got dtype {x.dtype}")
    n = len(trailing)
    if x.dim() < n or tuple(x.shape[x.dim() - n:]) != tuple(trailing):
        raise ShapeError(f"{module}: expected {name} of shape {shape_text(trailing)}, got {tuple(x.shape)}")
