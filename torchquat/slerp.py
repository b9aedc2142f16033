"""Spherical linear interpolation."""

import numbers
from typing import Union

import torch
from torch import Tensor

from . import _formulas as F
from ._dispatch import run
from ._validation import check_broadcast, prepare_pair, restore

__all__ = ["quat_slerp"]


def quat_slerp(q0: Tensor, q1: Tensor, t: Union[float, Tensor]) -> Tensor:
    """Spherical linear interpolation along the shortest path (Shoemake 1985).

    ``q1`` is negated where ``<q0, q1> < 0`` so the arc is the short one. The angle comes from the
    chords ``|q0 - q1|`` and ``|q0 + q1|`` of the normalised inputs (accurate near 0 and pi), and
    near 0 the weights are their series in the angle, so gradients, and second derivatives, are
    finite and exact at and near ``q0 == q1``.

    Args:
        q0: start quaternions; other norms than 1 are normalised first (zero gives NaN).
        q1: end quaternions, likewise; batch dims broadcast with ``q0``'s.
        t: interpolation parameter, a float or a tensor broadcasting with the batch dims (a tensor
            on another device or in another dtype is copied to ``q0``'s: for a CPU ``t`` with GPU
            quaternions, a host-to-device copy; a float is filled in on the device, no copy).

    Returns:
        Unit quaternions; ``t = 0`` gives ``q0`` and ``t = 1`` gives ``+-q1``.

    Shape:
        ``(..., 4)``, ``(..., 4)``, ``(...)`` -> ``(..., 4)``.

    Example:
        >>> q0 = quat_identity(); q1 = torch.tensor([0., 0., 0., 1.])  # 180 deg about z
        >>> quat_slerp(q0, q1, 0.5)  # 90 deg about z
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    q0, q1, dtype = prepare_pair("quat_slerp", ("q0", "q1"), q0, q1, (4,), (4,))
    if isinstance(t, numbers.Real):  # (a number is filled in on the device: as_tensor would copy it from the host, a sync)
        t = torch.full((), float(t), dtype=q0.dtype, device=q0.device)
    elif isinstance(t, Tensor):
        if not t.dtype.is_floating_point:
            raise TypeError(f"quat_slerp: expected t to be a number or a floating-point tensor, got dtype {t.dtype}")
        t = t.to(device=q0.device, dtype=q0.dtype)
    else:  # a sequence of numbers
        try:
            t = torch.as_tensor(t, dtype=q0.dtype, device=q0.device)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(f"quat_slerp: expected t to be a number, numbers or a floating-point tensor, "
                            f"got {t!r}") from None
    if t.dim() > 0:  # (a number always broadcasts)
        check_broadcast("quat_slerp", ("q0", "q1", "t"), (q0, q1, t), (1, 1, 0))
    tie = 8.0 * torch.finfo(q0.dtype).eps
    return restore(run(F.slerp, (q0, q1, t.unsqueeze(-1)), (4,), tie=tie), dtype)
