"""Index pairs of the relative pose error: evo's consecutive pairs by frames, meters or seconds."""

from typing import List, Tuple

import numpy as np
import torch
from torch import Tensor

__all__ = ["DELTA_UNITS", "pair_indices"]

DELTA_UNITS = ("frames", "meters", "seconds")


def _consecutive(steps: np.ndarray, delta: float) -> List[int]:
    """evo's ``filters.filter_pairs_by_path`` (consecutive mode): from index 0, the next index is
    the first at which the amount accumulated since the last chosen one reaches ``delta``;
    accumulated step by step and reset, in the same order as evo, so ties round the same way."""
    ids, current = [0], 0.0
    for i, step in enumerate(steps.tolist(), start=1):
        current += step
        if current >= delta:
            ids.append(i)
            current = 0.0
    return ids


def pair_indices(n: int, delta: float, delta_unit: str, positions: Tensor = None,
                 times: Tensor = None) -> Tuple[Tensor, Tensor]:
    """Pairs ``(i, j)`` for the relative pose error of ``n`` poses, as ``evo.core.metrics.RPE``.

    ``frames``: ``(0, d), (d, 2d), ...`` (``filters.filter_pairs_by_index``). ``meters``: the
    path travelled by ``positions`` ``(..., n, 3)`` (``filters.filter_pairs_by_path``), per
    trajectory. ``seconds``: the same rule on the time elapsed, ``times`` ``(..., n)`` (evo has no
    time filter; this is its path rule with seconds for meters).

    Returns:
        ``(i, j, valid)``: int64 ``(..., M)`` index tensors and a boolean mask; trajectories of a
        batch with fewer than ``M`` pairs are padded with ``(0, 0)`` and ``valid = False``.
    """
    device = positions.device if positions is not None else times.device
    if delta_unit == "frames":
        ids = torch.arange(0, n, int(delta), device=device)
        return ids[:-1], ids[1:], torch.ones(max(len(ids) - 1, 0), dtype=torch.bool, device=device)
    if delta_unit == "meters":
        p = positions.detach().cpu().double().numpy()
        steps = np.linalg.norm(p[..., 1:, :] - p[..., :-1, :], axis=-1)  # evo: norm of each step
        batch = p.shape[:-2]
    else:
        t = times.detach().cpu().double().numpy()
        steps = np.diff(t, axis=-1)
        batch = t.shape[:-1]
    flat = steps.reshape(-1, max(n - 1, 0))
    chosen = [_consecutive(row, float(delta)) for row in flat]
    m = max(len(c) for c in chosen) - 1 if chosen else 0
    ids = np.zeros((len(chosen), m + 1), dtype=np.int64)
    valid = np.zeros((len(chosen), m), dtype=bool)
    for row, c in enumerate(chosen):
        ids[row, :len(c)] = c
        valid[row, :len(c) - 1] = True
    first = np.where(valid, ids[:, :-1], 0)
    second = np.where(valid, ids[:, 1:], 0)

    def back(a):
        return torch.from_numpy(a.reshape(*batch, m)).to(device)
    return back(first), back(second), back(valid)
