"""Turning the pose arguments of :func:`ape` and :func:`rpe` into rotation matrices and positions."""

from typing import Tuple, Union

import torch
from torch import Tensor

from .. import ShapeError
from .. import convert

__all__ = ["as_matrices", "PoseLike", "check_pair", "apply_similarity"]

PoseLike = Union["torchquat.io.Poses", Tuple[Tensor, Tensor]]  # noqa: F821


def as_matrices(poses, function: str, name: str, rotations_needed: bool = True) -> Tuple[Tensor, Tensor]:
    """``(R, p)``: rotation matrices ``(..., N, 3, 3)`` and positions ``(..., N, 3)`` of ``poses``.

    ``poses`` is a :class:`torchquat.io.Poses` with positions, or a pair ``(rotations, positions)``
    whose rotations are quaternions ``(..., N, 4)`` (w, x, y, z) or matrices ``(..., N, 3, 3)``.
    Matrices are used as given (as evo does: a KITTI file's rounding is kept, not projected).
    Without ``rotations_needed`` (the translation relations) the rotations are checked, not
    converted, and ``R`` is None.
    """
    if hasattr(poses, "representation") and hasattr(poses, "rotations"):  # a torchquat.io.Poses
        if poses.positions is None:
            raise ShapeError(f"{function}: expected {name} with positions, got Poses without positions")
        if not rotations_needed:
            return None, _check_positions(function, name, poses.positions, (len(poses.positions),))
        rotations = poses.rotations if poses.representation == "matrix" else poses.to("matrix").rotations
        positions = poses.positions
    elif isinstance(poses, (tuple, list)) and len(poses) == 2:
        rotations, positions = poses
    else:
        raise TypeError(f"{function}: expected {name} as Poses or a pair (quats, positions), "
                        f"got {type(poses).__name__}")
    if not isinstance(rotations, Tensor) or not isinstance(positions, Tensor):
        raise TypeError(f"{function}: expected {name} as tensors, got {type(rotations).__name__} and "
                        f"{type(positions).__name__}")
    if rotations.shape[-1:] == (4,) and rotations.dim() >= 2:
        batch = rotations.shape[:-1]
        if rotations_needed:
            rotations = convert(rotations, "quat", "matrix")
    elif rotations.dim() >= 3 and rotations.shape[-2:] == (3, 3):
        batch = rotations.shape[:-2]
    else:
        raise ShapeError(f"{function}: expected {name} rotations of shape (..., N, 4) or (..., N, 3, 3), "
                         f"got {tuple(rotations.shape)}")
    return (rotations if rotations_needed else None), _check_positions(function, name, positions, batch)


def _check_positions(function: str, name: str, positions: Tensor, batch) -> Tensor:
    if positions.dim() < 2 or positions.shape[-1] != 3 or positions.shape[:-1] != batch:
        raise ShapeError(f"{function}: expected {name} positions of shape {(*batch, 3)}, "
                         f"got {tuple(positions.shape)}")
    if not positions.is_floating_point():
        raise TypeError(f"{function}: expected {name} positions of a floating dtype, got {positions.dtype}")
    return positions


def check_pair(function: str, ref: Tuple[Tensor, Tensor], est: Tuple[Tensor, Tensor]):
    """Broadcast reference and estimate to one batch shape; equal numbers of poses or ShapeError."""
    (r_ref, p_ref), (r_est, p_est) = ref, est
    if p_ref.shape[-2] != p_est.shape[-2]:
        raise ShapeError(f"{function}: expected reference and estimate with the same number of poses "
                         f"(associate them by time first), got reference {tuple(p_ref.shape[:-1])} "
                         f"and estimate {tuple(p_est.shape[:-1])}")
    try:
        batch = torch.broadcast_shapes(p_ref.shape[:-2], p_est.shape[:-2])
    except RuntimeError:
        raise ShapeError(f"{function}: batch shapes of reference {tuple(p_ref.shape[:-2])} and estimate "
                         f"{tuple(p_est.shape[:-2])} do not broadcast") from None
    n = p_ref.shape[-2]
    dtype = torch.promote_types(p_ref.dtype, p_est.dtype)
    for r in (r_ref, r_est):
        dtype = dtype if r is None else torch.promote_types(dtype, r.dtype)
    out = []
    for r, p in ((r_ref, p_ref), (r_est, p_est)):
        out.append((None if r is None else r.to(dtype).expand(*batch, n, 3, 3), p.to(dtype).expand(*batch, n, 3)))
    return out

def apply_similarity(reference, estimate, align: bool, scale: bool):
    """evo's ``align``/``correct_scale`` (``evo.main_ape.ape``): Umeyama on the positions, then
    ``s`` scales the estimate's positions, and with ``align`` ``(R, t)`` moves its poses
    (``T @ P``); ``scale`` without ``align`` corrects the scale alone. Poses with a NaN or
    infinite position (in either trajectory) get weight 0, so the others still align."""
    from .align import align as umeyama
    (_, p_ref), (r_est, p_est) = reference, estimate
    if not (align or scale):
        return r_est, p_est
    valid = torch.isfinite(p_ref.sum(-1) + p_est.sum(-1))  # (a NaN or infinity anywhere in the row)
    zero = torch.zeros((), dtype=p_est.dtype, device=p_est.device)
    rot, t, s = umeyama(torch.where(valid.unsqueeze(-1), p_est, zero),
                        torch.where(valid.unsqueeze(-1), p_ref, zero), weights=valid.to(p_est.dtype), scale=scale)
    if scale:
        p_est = p_est * s[..., None, None]
    if align:
        r_est = None if r_est is None else rot.unsqueeze(-3) @ r_est
        p_est = torch.baddbmm(t.unsqueeze(-2).reshape(-1, 1, 3), p_est.reshape(-1, *p_est.shape[-2:]),
                              rot.transpose(-1, -2).reshape(-1, 3, 3)).reshape(p_est.shape)
    return r_est, p_est
