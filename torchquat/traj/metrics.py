"""Absolute and relative pose errors with evo's pose relations, batched and differentiable."""

import math
from typing import Optional

import torch
from torch import Tensor

from .. import matrix_geodesic_distance, rot9d_to_matrix
from .. import ShapeError
from .pairs import DELTA_UNITS, pair_indices
from .poses import apply_similarity, as_matrices, check_pair

__all__ = ["RELATIONS", "ape", "rpe", "relation_errors"]

RELATIONS = ("translation_part", "rotation_part", "full_transformation", "rotation_angle_rad",
             "rotation_angle_deg", "point_distance")


def _check_relation(function: str, relation: str) -> None:
    if relation not in RELATIONS:
        raise ValueError(f"{function}: expected relation one of {', '.join(RELATIONS)}, got {relation!r}")


def relation_errors(r_a: Tensor, t_a: Tensor, r_b: Tensor, t_b: Tensor, relation: str) -> Tensor:
    """The error of evo's ``relation`` for ``E = inv(A) @ B`` of SE(3) poses ``A = (r_a, t_a)``,
    ``B = (r_b, t_b)`` (``evo.core.lie_algebra.relative_se3``: the inverse takes ``R^T``, so a
    matrix read with rounding is used as evo uses it). ``translation_part``: ``|t_E|``;
    ``rotation_part``: ``|R_E - I|_F``; ``full_transformation``: ``|E - I_4|_F``;
    ``rotation_angle_*``: the angle of ``R_E`` (evo: ``|so3_log(R_E)|``).

    Shape:
        ``(..., 3, 3)``, ``(..., 3)``, ``(..., 3, 3)``, ``(..., 3)`` -> ``(...)``.
    """
    if relation in ("rotation_angle_rad", "rotation_angle_deg"):
        # evo: |as_rotvec()| of scipy's Rotation.from_matrix(R_E), which (SciPy >= 1.15) first
        # projects R_E onto the nearest rotation by SVD: so does rot9d_to_matrix (Levinson et al.
        # 2020), which matters for matrices read with rounding (KITTI: |R^T R - I| ~ 2e-7).
        projected = rot9d_to_matrix((r_a.transpose(-1, -2) @ r_b).flatten(-2))
        eye = torch.eye(3, dtype=projected.dtype, device=projected.device).expand_as(projected)
        angle = matrix_geodesic_distance(eye, projected)
        return angle * (180.0 / math.pi) if relation == "rotation_angle_deg" else angle
    t_e = (r_a.transpose(-1, -2) @ (t_b - t_a).unsqueeze(-1)).squeeze(-1)
    if relation == "translation_part":
        return torch.linalg.vector_norm(t_e, dim=-1)
    eye = torch.eye(3, dtype=r_a.dtype, device=r_a.device)
    rotation = torch.linalg.matrix_norm(r_a.transpose(-1, -2) @ r_b - eye)
    if relation == "rotation_part":
        return rotation
    return torch.linalg.vector_norm(torch.stack((rotation, torch.linalg.vector_norm(t_e, dim=-1)), -1), dim=-1)


def ape(reference, estimate, relation: str = "translation_part", align: bool = False,
        scale: bool = False) -> Tensor:
    """Absolute pose error of each pose, evo's ``evo.main_ape.ape`` batched over trajectories.

    With ``align`` the estimate is first moved by the Umeyama SE(3) transform (Sim(3) with
    ``scale``) that best fits its positions to the reference's; with ``scale`` alone only its
    scale is corrected (evo's ``correct_only_scale``). The error pose is evo's
    ``E = inv(P_est) @ P_ref`` (Kümmerle et al. 2009); ``translation_part`` and
    ``point_distance`` are ``|p_est - p_ref|``. Poses with NaN give NaN errors and are left out of
    the alignment.

    Args:
        reference: :class:`torchquat.io.Poses`, or ``(rotations, positions)`` with rotations
            quaternions ``(..., N, 4)`` or matrices ``(..., N, 3, 3)`` and positions ``(..., N, 3)``.
        estimate: the same kinds, the same ``N`` (associate by time first); batch dims broadcast.
        relation: one of ``translation_part``, ``rotation_part``, ``full_transformation``,
            ``rotation_angle_rad``, ``rotation_angle_deg``, ``point_distance``.
        align: Umeyama alignment of the estimate to the reference first.
        scale: correct the scale too (alone when ``align`` is False).

    Returns:
        Errors ``(..., N)``: meters, radians, degrees or unitless as the relation says.

    Shape:
        ``(..., N, 4)`` + ``(..., N, 3)`` twice -> ``(..., N)``.

    Example:
        >>> q = torch.tensor([[1., 0., 0., 0.]]).expand(4, 4)
        >>> p = torch.tensor([[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [1., 1., 1.]])
        >>> torchquat.traj.ape((q, p), (q, p + 0.5))
        tensor([0.8660, 0.8660, 0.8660, 0.8660])
        >>> torchquat.traj.ape((q, p), (q, 2 * p + 0.5), align=True, scale=True).abs().max() < 1e-6
        tensor(True)
    """
    _check_relation("ape", relation)
    needed = relation not in ("translation_part", "point_distance")  # (no rotation converted for these)
    ref, est = check_pair("ape", as_matrices(reference, "ape", "reference", needed),
                          as_matrices(estimate, "ape", "estimate", needed))
    r_est, p_est = apply_similarity(ref, est, align, scale)
    r_ref, p_ref = ref
    if relation in ("translation_part", "point_distance"):
        return torch.linalg.vector_norm(p_est - p_ref, dim=-1)
    return relation_errors(r_est, p_est, r_ref, p_ref, relation)


def _gather(x: Tensor, index: Tensor, trailing: int) -> Tensor:
    """``x[..., index, <trailing dims>]`` with ``index`` ``(M,)`` or batched ``(..., M)``."""
    if index.dim() == 1:
        return x.index_select(x.dim() - 1 - trailing, index)
    shape = index.shape + x.shape[x.dim() - trailing:]
    expanded = index.reshape(*index.shape, *([1] * trailing)).expand(shape)
    return torch.gather(x, x.dim() - 1 - trailing, expanded)


def rpe(reference, estimate, delta: float = 1, delta_unit: str = "frames",
        relation: str = "translation_part", align: bool = False, scale: bool = False,
        times: Optional[Tensor] = None) -> Tensor:
    """Relative pose error over pairs of poses ``delta`` apart, evo's ``evo.main_rpe.rpe``.

    Pairs are consecutive (evo's default, ``all_pairs=False``) and chosen on the estimate after the
    optional alignment (evo's ``pairs_from_reference=False``): ``frames``: ``(0, d), (d, 2d), ...``;
    ``meters``: a new pair end where the path travelled since the last reaches ``delta``
    (``filters.filter_pairs_by_path``); ``seconds``: the same on elapsed time. The error pose is
    ``E = inv(inv(Q_i) Q_j) @ inv(P_i) P_j`` (Sturm et al. 2012, TUM RGB-D benchmark, eq. 2) with
    ``Q`` the reference and ``P`` the estimate; ``point_distance`` is
    ``| |q_i - q_j| - |p_i - p_j| |`` of positions. ``align`` and ``scale`` as in :func:`ape`.

    Args:
        reference: :class:`torchquat.io.Poses` or ``(rotations, positions)`` as for :func:`ape`.
        estimate: the same kinds, the same ``N``.
        delta: pair distance in ``delta_unit`` (a positive integer for frames).
        delta_unit: ``"frames"``, ``"meters"`` or ``"seconds"``.
        relation: an evo relation name, as for :func:`ape`.
        align: Umeyama alignment first.
        scale: correct the scale too (alone when ``align`` is False).
        times: ``(..., N)`` seconds for ``"seconds"`` (default: the estimate's ``timestamps``).

    Returns:
        Errors ``(..., M)``, one a pair; for ``meters`` and ``seconds`` a batch's trajectories with
        fewer pairs than the most are padded with NaN at the end.

    Shape:
        ``(..., N, 4)`` + ``(..., N, 3)`` twice -> ``(..., M)``.

    Example:
        >>> q = torch.tensor([[1., 0., 0., 0.]]).expand(5, 4)
        >>> p = torch.arange(15.).reshape(5, 3)
        >>> torchquat.traj.rpe((q, p), (q, 2 * p), delta=2)
        tensor([10.3923, 10.3923])
    """
    _check_relation("rpe", relation)
    if delta_unit not in DELTA_UNITS:
        raise ValueError(f"rpe: expected delta_unit one of {', '.join(DELTA_UNITS)}, got {delta_unit!r}")
    if not delta > 0 or (delta_unit == "frames" and float(delta) != int(delta)):
        raise ValueError(f"rpe: expected delta a positive {'integer' if delta_unit == 'frames' else 'number'} "
                         f"for {delta_unit}, got {delta!r}")
    needed = relation != "point_distance"
    ref, est = check_pair("rpe", as_matrices(reference, "rpe", "reference", needed),
                          as_matrices(estimate, "rpe", "estimate", needed))
    r_est, p_est = apply_similarity(ref, est, align, scale)
    r_ref, p_ref = ref
    n = p_ref.shape[-2]
    if delta_unit == "seconds":
        times = _times(estimate, times, n)
    i, j, valid = pair_indices(n, delta, delta_unit, positions=p_est, times=times)
    if i.dim() > 1:
        i, j, valid = (torch.broadcast_to(a, (*p_est.shape[:-2], a.shape[-1])) for a in (i, j, valid))
    pri, prj, pei, pej = (_gather(x, k, 1) for x, k in ((p_ref, i), (p_ref, j), (p_est, i), (p_est, j)))
    if relation == "point_distance":
        error = (torch.linalg.vector_norm(pri - prj, dim=-1) - torch.linalg.vector_norm(pei - pej, dim=-1)).abs()
    else:
        ri, rj, ei, ej = (_gather(x, k, 2) for x, k in ((r_ref, i), (r_ref, j), (r_est, i), (r_est, j)))
        # Q_rel = inv(Q_i) Q_j and P_rel = inv(P_i) P_j, then E = inv(Q_rel) P_rel (evo's rpe_base)
        q_rot = ri.transpose(-1, -2) @ rj
        q_pos = (ri.transpose(-1, -2) @ (prj - pri).unsqueeze(-1)).squeeze(-1)
        p_rot = ei.transpose(-1, -2) @ ej
        p_pos = (ei.transpose(-1, -2) @ (pej - pei).unsqueeze(-1)).squeeze(-1)
        error = relation_errors(q_rot, q_pos, p_rot, p_pos, relation)
    return torch.where(valid, error, torch.full((), float("nan"), dtype=error.dtype, device=error.device))


def _times(estimate, times: Optional[Tensor], n: int) -> Tensor:
    if times is None:
        stamps = getattr(estimate, "timestamps", None)
        if stamps is None:
            raise ValueError("rpe: delta_unit 'seconds' needs times: pass times=, or Poses with timestamps")
        times = torch.as_tensor(stamps, dtype=torch.float64)
    times = torch.as_tensor(times)
    if times.shape[-1:] != (n,):
        raise ShapeError(f"rpe: expected times of shape (..., {n}), got {tuple(times.shape)}")
    return times
