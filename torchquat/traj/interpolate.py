"""Resampling a trajectory at given times: positions linearly, rotations by slerp."""

from typing import Tuple

import torch
from torch import Tensor

from .. import ShapeError
from .. import quat_slerp

__all__ = ["interpolate"]


def interpolate(times: Tensor, positions: Tensor, quats: Tensor, query_times: Tensor) -> Tuple[Tensor, Tensor]:
    """Poses at ``query_times``, between the two samples around each: positions by linear
    interpolation (``numpy.interp``'s formula ``p_k + (p_{k+1} - p_k) (t - t_k) / (t_{k+1} - t_k)``),
    rotations by :func:`torchquat.quat_slerp` on the shortest arc (as SciPy's ``Slerp``, Shoemake
    1985). Differentiable in positions, quaternions and query times.

    Args:
        times: increasing sample times ``(..., N)``, ``N >= 2``.
        positions: ``(..., N, 3)``.
        quats: ``(..., N, 4)``, ``(w, x, y, z)``.
        query_times: ``(..., M)`` within ``[times[0], times[-1]]``; batch dims broadcast.

    Returns:
        ``(positions, quats)``: ``(..., M, 3)`` and ``(..., M, 4)``.

    Raises:
        ValueError: a query time outside the range of ``times``, or times not increasing.

    Shape:
        ``(..., N)``, ``(..., N, 3)``, ``(..., N, 4)``, ``(..., M)`` -> ``(..., M, 3)``, ``(..., M, 4)``.

    Example:
        >>> t = torch.tensor([0.0, 2.0])
        >>> q = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
        >>> p, r = torchquat.traj.interpolate(t, torch.zeros(2, 3), q, torch.tensor([1.0]))
        >>> r
        tensor([[0.7071, 0.0000, 0.0000, 0.7071]])
    """
    n = times.shape[-1] if times.dim() else 0
    if n < 2:
        raise ShapeError(f"interpolate: expected times of shape (..., N) with N >= 2, got {tuple(times.shape)}")
    if positions.shape[-2:] != (n, 3):
        raise ShapeError(f"interpolate: expected positions of shape (..., {n}, 3), got {tuple(positions.shape)}")
    if quats.shape[-2:] != (n, 4):
        raise ShapeError(f"interpolate: expected quats of shape (..., {n}, 4), got {tuple(quats.shape)}")
    if query_times.dim() < 1:
        raise ShapeError(f"interpolate: expected query_times of shape (..., M), got {tuple(query_times.shape)}")
    try:
        batch = torch.broadcast_shapes(times.shape[:-1], positions.shape[:-2], quats.shape[:-2],
                                       query_times.shape[:-1])
    except RuntimeError:
        raise ShapeError(f"interpolate: batch shapes of times {tuple(times.shape)}, positions "
                         f"{tuple(positions.shape)}, quats {tuple(quats.shape)} and query_times "
                         f"{tuple(query_times.shape)} do not broadcast") from None
    if not torch.compiler.is_compiling():  # input checks (a device sync), skipped under torch.compile
        if bool((times[..., 1:] <= times[..., :-1]).any()):
            raise ValueError("interpolate: expected times strictly increasing")
        outside = (query_times < times[..., :1]) | (query_times > times[..., -1:])
        if bool(outside.any()):
            first = query_times[outside][0]
            raise ValueError(f"interpolate: expected query_times within [times[0], times[-1]] (no "
                             f"extrapolation), got {float(first)!r} outside")
    m = query_times.shape[-1]
    t = times.expand(*batch, n).contiguous()
    x = query_times.to(t.dtype).expand(*batch, m).contiguous()
    k = torch.searchsorted(t, x, right=True).clamp(1, n - 1)  # the segment [k - 1, k] of each query
    t0, t1 = torch.gather(t, -1, k - 1), torch.gather(t, -1, k)
    frac = (x - t0) / (t1 - t0)

    def pick(values: Tensor, index: Tensor) -> Tensor:
        v = values.expand(*batch, n, values.shape[-1])
        return torch.gather(v, -2, index.unsqueeze(-1).expand(*index.shape, values.shape[-1]))
    p0, p1 = pick(positions, k - 1), pick(positions, k)
    slope = (p1 - p0) / (t1 - t0).unsqueeze(-1)
    out_positions = p0 + slope * (x - t0).unsqueeze(-1)
    out_quats = quat_slerp(pick(quats, k - 1), pick(quats, k), frac.to(quats.dtype))
    return out_positions, out_quats
