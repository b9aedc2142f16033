"""Quaternion <-> rotation matrix."""

from torch import Tensor

from . import _formulas as F
from ._dispatch import run
from ._validation import prepare, restore

__all__ = ["quat_to_matrix", "matrix_to_quat"]


def quat_to_matrix(q: Tensor) -> Tensor:
    """Rotation matrix of a quaternion.

    Non-unit quaternions are accepted: the result is the rotation of ``q / |q|`` (the homogeneous
    form divided by ``|q|^2``, which stays orthogonal); the zero quaternion gives NaN.

    Args:
        q: quaternions ``(w, x, y, z)``.

    Returns:
        Rotation matrices acting on column vectors, ``R @ v``.

    Shape:
        ``(..., 4)`` -> ``(..., 3, 3)``.

    Example:
        >>> quat_to_matrix(torch.tensor([0., 0., 0., 1.]))  # 180 degrees about z
        tensor([[-1.,  0.,  0.],
                [ 0., -1.,  0.],
                [ 0.,  0.,  1.]])
    """
    q, dtype = prepare(q, "quat_to_matrix", "q", (4,))
    return restore(run(F.quat_to_matrix, (q,), (3, 3)), dtype)


def matrix_to_quat(R: Tensor) -> Tensor:
    """Quaternion of a rotation matrix (Shepperd 1978), with ``w >= 0``.

    ``R`` is assumed orthogonal with det +1; project noisy matrices with
    :func:`rot9d_to_matrix` first. Accurate at every angle including 180 degrees, and its
    gradient is finite at the identity (where square-root formulas give NaN).

    Args:
        R: rotation matrices acting on column vectors.

    Returns:
        Unit quaternions ``(w, x, y, z)``, standardised (``w >= 0``, see :func:`quat_standardize`).

    Shape:
        ``(..., 3, 3)`` -> ``(..., 4)``.

    Example:
        >>> matrix_to_quat(torch.eye(3))
        tensor([1., 0., 0., 0.])
    """
    R, dtype = prepare(R, "matrix_to_quat", "R", (3, 3))
    return restore(run(F.matrix_to_quat, (R,), (4,), 2), dtype)
