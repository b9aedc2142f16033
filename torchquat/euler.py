"""Euler angles in all 24 conventions <-> quaternions and matrices."""

import math
from typing import Optional

from torch import Tensor

from . import _euler_formulas as E
from ._backends import TENSORS
from ._dispatch import run
from ._validation import prepare, restore, tensor_or_as_is
from .errors import ShapeError
from .conventions import check_degrees, gimbal_threshold, parse_convention

__all__ = ["euler_to_quat", "quat_to_euler", "euler_to_matrix", "matrix_to_euler", "euler_gimbal_lock"]


def euler_to_quat(angles: Tensor, convention: str, degrees: bool = False) -> Tensor:
    """Quaternion of Euler angles in any of the 24 conventions.

    Args:
        angles: the three angles in the order the convention's letters name them.
        convention: 3 letters, upper case intrinsic (``'ZYX'``: yaw, pitch, roll about the
            moving body's axes) or lower case extrinsic (``'xyz'``: about the fixed axes).
            ``'ZYX'`` with ``(yaw, pitch, roll)`` equals ``'xyz'`` with ``(roll, pitch, yaw)``.
        degrees: angles in degrees instead of radians.

    Returns:
        Unit quaternions ``(w, x, y, z)`` with ``w >= 0``.

    Shape:
        ``(..., 3)`` -> ``(..., 4)``.

    Example:
        >>> euler_to_quat(torch.tensor([0., 0., 90.]), "YZX", degrees=True)  # bank 90 degrees
        tensor([0.7071, 0.7071, 0.0000, 0.0000])
    """
    name = parse_convention(convention, "euler_to_quat").name
    degrees = check_degrees("euler_to_quat", degrees)
    angles, dtype = prepare(angles, "euler_to_quat", "angles", (3,))
    return restore(run(E.euler_to_quat, (angles,), (4,), name=name, degrees=degrees), dtype)


def euler_to_matrix(angles: Tensor, convention: str, degrees: bool = False) -> Tensor:
    """Rotation matrix of Euler angles in any of the 24 conventions.

    Args:
        angles: the three angles in the order the convention's letters name them.
        convention: as in :func:`euler_to_quat` (no default: say which one you mean).
        degrees: angles in degrees instead of radians.

    Returns:
        Rotation matrices acting on column vectors; intrinsic ``'ZYX'`` gives
        ``Rz(a1) @ Ry(a2) @ Rx(a3)``.

    Shape:
        ``(..., 3)`` -> ``(..., 3, 3)``.

    Example:
        >>> euler_to_matrix(torch.tensor([90., 0., 0.]), "ZYX", degrees=True).round(decimals=6) + 0.0  # + 0.0 turns -0. into 0.
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    name = parse_convention(convention, "euler_to_matrix").name
    degrees = check_degrees("euler_to_matrix", degrees)
    angles, dtype = prepare(angles, "euler_to_matrix", "angles", (3,))
    return restore(run(E.euler_to_matrix, (angles,), (3, 3), name=name, degrees=degrees), dtype)


def quat_to_euler(q: Tensor, convention: str, degrees: bool = False, eps: Optional[float] = None) -> Tensor:
    """Euler angles of a quaternion in any of the 24 conventions (Bernardes and Viollet 2022).

    Args:
        q: quaternions ``(w, x, y, z)``; need not be unit (the method is scale-invariant).
        convention: as in :func:`euler_to_quat`.
        degrees: return degrees instead of radians.
        eps: gimbal-lock threshold in radians on the middle angle; default 1e-7 in float64 and
            1e-6 in float32 and below. Within it the third angle is 0 and the first carries the
            rotation (SciPy's rule); :func:`euler_gimbal_lock` returns the mask.

    Returns:
        Angles in the convention's letter order: first and third in ``[-pi, pi]``; the middle in
        ``[-pi/2, pi/2]`` (Tait-Bryan) or ``[0, pi]`` (proper Euler). Gradients are finite
        everywhere, gimbal lock included.

    Shape:
        ``(..., 4)`` -> ``(..., 3)``.

    Example:
        >>> q = euler_to_quat(torch.tensor([30., 20., 10.]), "ZYX", degrees=True)
        >>> quat_to_euler(q, "ZYX", degrees=True)
        tensor([30., 20., 10.])
    """
    name = parse_convention(convention, "quat_to_euler").name
    degrees = check_degrees("quat_to_euler", degrees)
    q, dtype = prepare(q, "quat_to_euler", "q", (4,))
    eps = gimbal_threshold("quat_to_euler", eps, q.dtype)
    return restore(run(E.quat_to_euler, (q,), (3,), name=name, lock_sine=math.sin(eps), degrees=degrees), dtype)


def matrix_to_euler(R: Tensor, convention: str, degrees: bool = False, eps: Optional[float] = None) -> Tensor:
    """Euler angles of a rotation matrix in any of the 24 conventions.

    The same Bernardes-Viollet angles as :func:`quat_to_euler`, with their quadratic forms read
    off R's entries directly (no quaternion, no square root): every angle is an ``atan2`` of
    two linear combinations of entries, which keeps full precision next to gimbal lock where
    ``asin`` of an entry does not. ``R`` is assumed orthogonal with det +1.

    Args:
        R: rotation matrices.
        convention: as in :func:`euler_to_quat`.
        degrees: return degrees instead of radians.
        eps: gimbal-lock threshold, as in :func:`quat_to_euler`.

    Returns:
        Angles as :func:`quat_to_euler` returns them.

    Shape:
        ``(..., 3, 3)`` -> ``(..., 3)``.

    Example:
        >>> matrix_to_euler(torch.eye(3), "zxz")
        tensor([0., 0., 0.])
    """
    name = parse_convention(convention, "matrix_to_euler").name
    degrees = check_degrees("matrix_to_euler", degrees)
    R, dtype = prepare(R, "matrix_to_euler", "R", (3, 3))
    eps = gimbal_threshold("matrix_to_euler", eps, R.dtype)
    return restore(run(E.matrix_to_euler, (R,), (3,), 2, name=name, lock_sine=math.sin(eps), degrees=degrees), dtype)


def euler_gimbal_lock(q: Tensor, convention: str, eps: Optional[float] = None) -> Tensor:
    """Which rotations are within ``eps`` of gimbal lock for ``convention``.

    Uses exactly the test :func:`quat_to_euler` (for quaternions) or :func:`matrix_to_euler`
    (for matrices) uses on a batch of this size, with the same arithmetic, so a ``True`` row is one
    whose third angle was set to 0. (Within rounding of ``eps`` small and large batches can decide
    differently; either answer gives the rotation.) A matrix is
    tested on its own entries: for a rotation exactly ``eps`` from lock, a matrix and its
    quaternion may round to different answers. No warning is raised anywhere (that would need a
    device sync).

    Args:
        q: quaternions ``(w, x, y, z)``, or rotation matrices.
        convention: as in :func:`euler_to_quat`.
        eps: threshold in radians on the middle angle, default as in :func:`quat_to_euler`.

    Returns:
        A boolean mask.

    Shape:
        ``(..., 4)`` or ``(..., 3, 3)`` -> ``(...)``.

    Example:
        >>> q = euler_to_quat(torch.tensor([10., 90., 0.], dtype=torch.float64), "ZYX", degrees=True)
        >>> euler_gimbal_lock(q, "ZYX")
        tensor(True)
        >>> euler_gimbal_lock(quat_to_matrix(q), "zyx")  # extrinsic zyx: not at its lock
        tensor(False)
    """
    name = parse_convention(convention, "euler_gimbal_lock").name
    q = tensor_or_as_is(q)
    matrix = isinstance(q, Tensor) and q.dim() >= 2 and q.shape[-2:] == (3, 3)
    try:
        q, _ = prepare(q, "euler_gimbal_lock", "q", (3, 3) if matrix else (4,))
    except ShapeError:
        raise ShapeError("euler_gimbal_lock: expected q of shape (..., 4) or (..., 3, 3), "
                         f"got {tuple(q.shape)}") from None
    eps = gimbal_threshold("euler_gimbal_lock", eps, q.dtype)
    columns = q.flatten(-2).unbind(-1) if matrix else q.unbind(-1)
    forms = E.forms_of_matrix(name, columns) if matrix else E.forms_of_quat(name, columns)
    return E.lock(TENSORS, forms, math.sin(eps))
