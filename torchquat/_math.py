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
