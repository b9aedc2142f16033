"""Geodesic distances between rotations (the rotation angle of ``a^-1 b``), in radians."""

import torch
from torch import Tensor

from ._dispatch import kernel
from ._math import safe_sqrt
from ._validation import check_broadcast, common_dtype, prepare, restore
from .quaternion import normalized

__all__ = ["quat_geodesic_distance", "matrix_geodesic_distance"]


@kernel
def quat_geodesic_distance_unchecked(q1: Tensor, q2: Tensor) -> Tensor:
    q1, q2 = normalized(q1), normalized(q2)
    q2 = torch.where((q1 * q2).sum(-1, keepdim=True) < 0, -q2, q2)  # q and -q: same rotation
    diff2 = ((q1 - q2) ** 2).sum(-1)
    sum2 = ((q1 + q2) ** 2).sum(-1)  # >= 2 after the sign choice: never 0
    return 4.0 * torch.atan2(safe_sqrt(diff2), torch.sqrt(sum2))


def quat_geodesic_distance(q1: Tensor, q2: Tensor) -> Tensor:
    """Angle of the rotation between two quaternions, sign-invariant (``q`` and ``-q`` agree).

    Computed as ``4 atan2(|q1 - q2|, |q1 + q2|)`` after choosing the sign of ``q2`` that makes
    ``<q1, q2> >= 0``: accurate near 0 and pi, where ``2 acos(|<q1, q2>|)`` loses half its
    digits and has an infinite gradient. The gradient is finite everywhere (0 at distance 0,
    the kink of the distance function).

    Args:
        q1: quaternions ``(w, x, y, z)`` (normalised inside).
        q2: quaternions; batch dims broadcast with ``q1``'s.

    Returns:
        Angles in ``[0, pi]``.

    Shape:
        ``(..., 4)`` and ``(..., 4)`` -> ``(...)``.

    Example:
        >>> quat_geodesic_distance(torch.tensor([1., 0., 0., 0.]), torch.tensor([0., 0., 0., -1.]))
        tensor(3.1416)
    """
    q1, dtype = prepare(q1, "quat_geodesic_distance", "q1", (4,))
    q2, _ = prepare(q2, "quat_geodesic_distance", "q2", (4,))
    check_broadcast("quat_geodesic_distance", ("q1", "q2"), (q1, q2), (1, 1))
    q1, q2 = common_dtype("quat_geodesic_distance", q1, q2)
    return restore(quat_geodesic_distance_unchecked(q1, q2), dtype)


@kernel
def matrix_geodesic_distance_unchecked(R1: Tensor, R2: Tensor) -> Tensor:
    M = R1.mT @ R2
    trace = M.diagonal(dim1=-2, dim2=-1).sum(-1)
    vee = torch.stack((M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]), -1)
    # tan(angle) = |vee(M - M^T)| / (tr M - 1): both sides keep full precision at 0 and pi.
    return torch.atan2(safe_sqrt((vee * vee).sum(-1)), trace - 1.0)


def matrix_geodesic_distance(R1: Tensor, R2: Tensor) -> Tensor:
    """Angle of the rotation ``R1^T R2``, from ``atan2(|vee(M - M^T)|, tr M - 1)``.

    Unlike ``acos((tr M - 1) / 2)`` this is accurate near 0 and pi and its gradient is finite
    there (0 at distance 0).

    Args:
        R1: rotation matrices.
        R2: rotation matrices; batch dims broadcast with ``R1``'s.

    Returns:
        Angles in ``[0, pi]``.

    Shape:
        ``(..., 3, 3)`` and ``(..., 3, 3)`` -> ``(...)``.

    Example:
        >>> Rz = torch.tensor([[0., -1., 0.], [1., 0., 0.], [0., 0., 1.]])
        >>> matrix_geodesic_distance(torch.eye(3), Rz)
        tensor(1.5708)
    """
    R1, dtype = prepare(R1, "matrix_geodesic_distance", "R1", (3, 3))
    R2, _ = prepare(R2, "matrix_geodesic_distance", "R2", (3, 3))
    check_broadcast("matrix_geodesic_distance", ("R1", "R2"), (R1, R2), (2, 2))
    R1, R2 = common_dtype("matrix_geodesic_distance", R1, R2)
    return restore(matrix_geodesic_distance_unchecked(R1, R2), dtype)
