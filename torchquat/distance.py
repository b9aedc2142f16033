"""Geodesic distances: the angle of the rotation between two rotations."""

from torch import Tensor

from . import _formulas as F
from ._dispatch import run
from ._validation import prepare_pair, restore

__all__ = ["quat_geodesic_distance", "matrix_geodesic_distance"]


def quat_geodesic_distance(q1: Tensor, q2: Tensor) -> Tensor:
    """Angle of the rotation between two quaternions, sign-invariant (``q`` and ``-q`` agree).

    ``2 atan2(|q1 ^ q2|, |<q1, q2>|)``: twice the angle between the lines of ``q1`` and ``q2`` in
    4D, with ``|q1 ^ q2|`` the norm of the six ``q1_i q2_j - q1_j q2_i``. Accurate near 0 and pi,
    where ``2 acos(|<q1, q2>|)`` loses half its digits and has an infinite gradient; both arguments
    scale alike, so the inputs need no normalising. The gradient is finite everywhere (0 at
    distance 0, the kink of the distance). A zero quaternion gives NaN.

    Args:
        q1: quaternions ``(w, x, y, z)``, any non-zero norm.
        q2: quaternions; batch dims broadcast with ``q1``'s. ``|q1|^2 |q2|^2`` must be a normal
            number of the dtype (float32: ``|q1| |q2|`` between about 1e-19 and 1e19).

    Returns:
        Angles in ``[0, pi]``.

    Shape:
        ``(..., 4)`` and ``(..., 4)`` -> ``(...)``.

    Example:
        >>> quat_geodesic_distance(torch.tensor([1., 0., 0., 0.]), torch.tensor([0., 0., 0., -1.]))
        tensor(3.1416)
    """
    q1, q2, dtype = prepare_pair("quat_geodesic_distance", ("q1", "q2"), q1, q2, (4,), (4,))
    return restore(run(F.quat_distance, (q1, q2), ()), dtype)


def matrix_geodesic_distance(R1: Tensor, R2: Tensor) -> Tensor:
    """Angle of the rotation ``R1^T R2``, from ``atan2(|vee(M - M^T)|, tr M - 1)`` with ``M = R1^T R2``.

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
    R1, R2, dtype = prepare_pair("matrix_geodesic_distance", ("R1", "R2"), R1, R2, (3, 3), (3, 3))
    return restore(run(F.matrix_distance, (R1, R2), (), 2), dtype)
