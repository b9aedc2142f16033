"""Axis-angle (rotation vectors) <-> quaternions and matrices."""

from torch import Tensor

from . import _formulas as F
from ._dispatch import run
from ._validation import prepare, restore

__all__ = ["axis_angle_to_quat", "quat_to_axis_angle", "axis_angle_to_matrix", "matrix_to_axis_angle"]


def axis_angle_to_quat(v: Tensor) -> Tensor:
    """Quaternion of a rotation vector.

    Args:
        v: unit axis times angle (radians); any length, zero included.

    Returns:
        Unit quaternions ``(w, x, y, z)`` with ``w >= 0``.

    Shape:
        ``(..., 3)`` -> ``(..., 4)``.

    Example:
        >>> axis_angle_to_quat(torch.tensor([0., 0., torch.pi / 2]))
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    v, dtype = prepare(v, "axis_angle_to_quat", "v", (3,))
    return restore(run(F.axis_angle_to_quat, (v,), (4,)), dtype)


def quat_to_axis_angle(q: Tensor) -> Tensor:
    """Rotation vector of a quaternion, along the shortest arc (angle in ``[0, pi]``).

    Args:
        q: quaternions ``(w, x, y, z)``; need not be unit. The zero quaternion gives NaN.

    Returns:
        Unit axis times angle.

    Shape:
        ``(..., 4)`` -> ``(..., 3)``.

    Example:
        >>> quat_to_axis_angle(torch.tensor([-0.5, -0.5, -0.5, -0.5]))  # = 120 deg about (1, 1, 1)
        tensor([1.2092, 1.2092, 1.2092])
    """
    q, dtype = prepare(q, "quat_to_axis_angle", "q", (4,))
    return restore(run(F.quat_to_axis_angle, (q,), (3,)), dtype)


def axis_angle_to_matrix(v: Tensor) -> Tensor:
    """Rotation matrix of a rotation vector (Rodrigues' formula).

    Args:
        v: unit axis times angle (radians).

    Returns:
        Rotation matrices acting on column vectors.

    Shape:
        ``(..., 3)`` -> ``(..., 3, 3)``.

    Example:
        >>> axis_angle_to_matrix(torch.tensor([0., 0., torch.pi / 2])).round(decimals=6) + 0.0  # + 0.0 turns -0. into 0.
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    v, dtype = prepare(v, "axis_angle_to_matrix", "v", (3,))
    return restore(run(F.axis_angle_to_matrix, (v,), (3, 3)), dtype)


def matrix_to_axis_angle(R: Tensor) -> Tensor:
    """Rotation vector of a rotation matrix, along the shortest arc (angle in ``[0, pi]``).

    Goes through Shepperd's quaternion, which is accurate at 180 degrees where the
    ``acos((tr R - 1) / 2)`` formula loses half its digits. Each row is computed on its own.

    Shape:
        ``(..., 3, 3)`` -> ``(..., 3)``.

    Example:
        >>> matrix_to_axis_angle(torch.eye(3))
        tensor([0., 0., 0.])
    """
    R, dtype = prepare(R, "matrix_to_axis_angle", "R", (3, 3))
    return restore(run(F.matrix_to_axis_angle, (R,), (3,), 2), dtype)
