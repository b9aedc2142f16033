"""Nearest-timestamp association of two trajectories (the TUM RGB-D benchmark's and evo's)."""

from typing import Tuple

import numpy as np
import torch
from torch import Tensor

from .. import ShapeError

__all__ = ["associate"]


def _stamps(name: str, times) -> np.ndarray:
    if isinstance(times, Tensor):
        times = times.detach().cpu().double().numpy()
    a = np.asarray(times, dtype=np.float64)
    if a.ndim != 1:
        raise ShapeError(f"associate: expected {name} of shape (N,), got {a.shape}")
    return a


def associate(times_a, times_b, max_difference: float = 0.02, offset: float = 0.0) -> Tuple[Tensor, Tensor]:
    """Pairs of indices whose times match: the TUM RGB-D benchmark's ``associate.py`` (Sturm et al.
    2012), on which evo's ``sync.associate_trajectories`` is modelled.

    Every pair ``(i, j)`` with ``|times_a[i] - (times_b[j] + offset)| < max_difference`` is a
    candidate; the closest candidates are taken first (ties: the smaller ``i``, then ``j``) and
    each index is used at most once. Where every time has at most one candidate (the usual case:
    ``max_difference`` below half the sampling interval) this is evo's nearest-time matching.
    Runs on the CPU in NumPy (it selects, it does not compute); the sorted candidates are built
    with ``searchsorted``, so it is ``O((N + M) log M)``.

    Args:
        times_a: ``(N,)`` seconds (tensor or array), e.g. the reference's.
        times_b: ``(M,)`` seconds, e.g. the estimate's.
        max_difference: largest time difference of a pair, seconds (exclusive).
        offset: added to ``times_b`` before matching.

    Returns:
        ``(index_a, index_b)``: int64 tensors ``(K,)``, in increasing ``index_a``.

    Shape:
        ``(N,)``, ``(M,)`` -> ``(K,)``, ``(K,)``.

    Example:
        >>> torchquat.traj.associate(torch.tensor([0.0, 1.0, 2.0]), torch.tensor([0.99, 2.05, 3.0]), 0.1)
        (tensor([1, 2]), tensor([0, 1]))
    """
    a, b = _stamps("times_a", times_a), _stamps("times_b", times_b) + offset
    order_b = np.argsort(b, kind="stable")
    sorted_b = b[order_b]
    lo = np.searchsorted(sorted_b, a - max_difference, side="left")
    hi = np.searchsorted(sorted_b, a + max_difference, side="right")
    counts = np.maximum(hi - lo, 0)
    i = np.repeat(np.arange(len(a)), counts)
    starts = np.repeat(lo - np.concatenate(([0], np.cumsum(counts)[:-1])), counts)
    j = order_b[np.arange(len(i)) + starts] if len(i) else np.zeros(0, dtype=np.int64)
    diff = np.abs(a[i] - b[j])
    keep = diff < max_difference
    i, j, diff = i[keep], j[keep], diff[keep]
    # Fast path: a candidate that is the only one of its i and of its j is taken whatever the order.
    lonely = (np.bincount(i, minlength=len(a))[i] == 1) & (np.bincount(j, minlength=len(b))[j] == 1)
    take_i, take_j = [i[lonely]], [j[lonely]]
    rest = ~lonely
    if rest.any():
        ri, rj, rd = i[rest], j[rest], diff[rest]
        order = np.lexsort((rj, ri, rd))
        used_a, used_b, pi, pj = set(), set(), [], []
        for k in order.tolist():
            x, y = int(ri[k]), int(rj[k])
            if x not in used_a and y not in used_b:
                used_a.add(x)
                used_b.add(y)
                pi.append(x)
                pj.append(y)
        take_i.append(np.array(pi, dtype=np.int64))
        take_j.append(np.array(pj, dtype=np.int64))
    index_a, index_b = np.concatenate(take_i).astype(np.int64), np.concatenate(take_j).astype(np.int64)
    order = np.argsort(index_a, kind="stable")
    return torch.from_numpy(index_a[order]), torch.from_numpy(index_b[order])
