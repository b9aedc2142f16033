"""Summary statistics of an error sequence, with evo's names and definitions."""

from typing import Dict

import torch
from torch import Tensor

from .. import ShapeError

__all__ = ["STATISTICS", "error_statistics"]

STATISTICS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def error_statistics(errors: Tensor, ignore_nan: bool = False) -> Dict[str, Tensor]:
    """evo's statistics of errors (``evo.core.metrics.PE.get_statistic``) over the last dim.

    ``rmse = sqrt(mean(e^2))``, ``mean``, ``median`` (the mean of the two middle values for an
    even count, as ``numpy.median``), ``std`` (population, ``ddof = 0``, as ``numpy.std``),
    ``min``, ``max``, ``sse = sum(e^2)``.

    Args:
        errors: ``(..., N)`` errors, e.g. from :func:`ape` or :func:`rpe`.
        ignore_nan: leave NaN errors out (each trajectory of a batch its own count); otherwise
            any NaN makes every statistic of its row NaN, as in NumPy.

    Returns:
        A dict from the names above to tensors of shape ``(...)``.

    Shape:
        ``(..., N)`` -> ``(...)`` for each statistic.

    Example:
        >>> s = torchquat.traj.error_statistics(torch.tensor([1.0, 2.0, 3.0, 6.0]))
        >>> {k: round(float(v), 4) for k, v in s.items()}
        {'rmse': 3.5355, 'mean': 3.0, 'median': 2.5, 'std': 1.8708, 'min': 1.0, 'max': 6.0, 'sse': 50.0}
    """
    if not isinstance(errors, Tensor) or errors.dim() < 1 or not errors.is_floating_point():
        got = (tuple(errors.shape), errors.dtype) if isinstance(errors, Tensor) else type(errors).__name__
        raise ShapeError(f"error_statistics: expected errors as a floating tensor of shape (..., N), got {got}")
    finite = ~torch.isnan(errors)
    if ignore_nan:
        count = finite.sum(-1)
        zero = torch.zeros((), dtype=errors.dtype, device=errors.device)
        kept = torch.where(finite, errors, zero)
        inf = torch.full((), float("inf"), dtype=errors.dtype, device=errors.device)
        low = torch.where(finite, errors, inf).amin(-1)
        high = torch.where(finite, errors, -inf).amax(-1)
    else:
        count = torch.full(errors.shape[:-1], errors.shape[-1], dtype=torch.int64, device=errors.device)
        kept, low, high = errors, errors.amin(-1), errors.amax(-1)
    n = count.to(errors.dtype)
    sse = (kept * kept).sum(-1)
    mean = kept.sum(-1) / n
    centred = torch.where(finite, kept - mean.unsqueeze(-1), 0.0) if ignore_nan else kept - mean.unsqueeze(-1)
    std = torch.sqrt((centred * centred).sum(-1) / n)
    ordered = errors.sort(-1).values  # NaN sort last
    lower = ((count - 1).clamp(min=0) // 2).unsqueeze(-1)
    upper = (count // 2).clamp(max=errors.shape[-1] - 1).unsqueeze(-1)
    median = (ordered.gather(-1, lower) + ordered.gather(-1, upper)).squeeze(-1) / 2
    if not ignore_nan:
        median = torch.where(finite.all(-1), median, torch.nan)
    else:
        median = torch.where(count > 0, median, torch.nan)
    return {"rmse": torch.sqrt(sse / n), "mean": mean, "median": median, "std": std, "min": low, "max": high,
            "sse": sse}
