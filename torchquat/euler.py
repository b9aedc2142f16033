"""Euler angles <-> quaternions and matrices, for all 24 conventions.

One general path serves every convention (SciPy's rule: ``'ZYX'`` intrinsic, ``'zyx'``
extrinsic). Quaternion to Euler follows Bernardes and Viollet, "Quaternion to Euler angles
conversion: A direct, general and computationally efficient method", PLoS ONE 17(11), 2022,
with SciPy's gimbal-lock rule: within ``eps`` of lock the third angle is 0 and the first
carries the whole rotation.
"""

import math
from typing import Dict, Optional, Tuple

import torch
from torch import Tensor

from ._dispatch import kernel
from ._math import constant, safe_sqrt
from ._validation import prepare, restore
from .conventions import EULER_CONVENTIONS, EulerConvention, gimbal_eps, parse_convention
from .matrix import matrix_to_quat_unchecked, quat_to_matrix_unchecked
from .quaternion import standardize_sign

__all__ = ["euler_to_quat", "quat_to_euler", "euler_to_matrix", "matrix_to_euler", "euler_gimbal_lock"]

_UNIT = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))  # 1, i, j, k


def _basis_product(p, q):
    """Hamilton product of two signed basis quaternions given as 4-tuples (exact integers)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw)


def _sign_table(convention: EulerConvention) -> Tuple[Tuple[int, ...], ...]:
    """The 8 x 4 table T with ``q = sum_m (c/s products)_m T[m]`` for this convention.

    The quaternion is a product of three elementary ones ``cos(a/2) + sin(a/2) e_axis``;
    expanding it gives 8 products of half-angle cosines and sines, each times a signed basis
    quaternion. Row ``m = 4 m1 + 2 m2 + m3`` uses the sine of angle ``n`` where bit ``m_n`` is 1.
    Intrinsic ``ABC`` is ``e_A e_B e_C``; extrinsic ``abc`` is ``e_c e_b e_a``.
    """
    rows = []
    for m in range(8):
        bits = ((m >> 2) & 1, (m >> 1) & 1, m & 1)
        factors = [_UNIT[axis + 1] if bit else _UNIT[0] for axis, bit in zip(convention.axes, bits)]
        if not convention.intrinsic:
            factors.reverse()
        rows.append(_basis_product(_basis_product(factors[0], factors[1]), factors[2]))
    return tuple(rows)


_SIGN_TABLES: Dict[str, Tuple[Tuple[int, ...], ...]] = {
    name: _sign_table(conv) for name, conv in EULER_CONVENTIONS.items()
}


def _table(convention: EulerConvention, like: Tensor) -> Tensor:
    return constant("euler_signs_" + convention.name, _SIGN_TABLES[convention.name], like)


@kernel
def euler_to_quat_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    half = angles * 0.5
    cs = torch.stack((torch.cos(half), torch.sin(half)), dim=-1)  # (..., 3, 2)
    c1, c2, c3 = cs.unbind(-2)
    products = (c1[..., :, None, None] * c2[..., None, :, None] * c3[..., None, None, :]).flatten(-3)
    q = products @ _table(convention, angles)
    return q * standardize_sign(q)


def _to_radians(angles: Tensor, degrees: bool) -> Tensor:
    return angles * (math.pi / 180.0) if degrees else angles


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
    conv = parse_convention(convention, "euler_to_quat")
    angles, dtype = prepare(angles, "euler_to_quat", "angles", (3,))
    return restore(euler_to_quat_unchecked(_to_radians(angles, degrees), convention=conv), dtype)


@kernel
def euler_to_matrix_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    return quat_to_matrix_unchecked(euler_to_quat_unchecked(angles, convention=convention))


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
        >>> euler_to_matrix(torch.tensor([90., 0., 0.]), "ZYX", degrees=True).round(decimals=6)
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    conv = parse_convention(convention, "euler_to_matrix")
    angles, dtype = prepare(angles, "euler_to_matrix", "angles", (3,))
    return restore(euler_to_matrix_unchecked(_to_radians(angles, degrees), convention=conv), dtype)


def _abcd(q: Tensor, conv: EulerConvention):
    """Bernardes and Viollet's permuted quaternion ``(a, b, c, d)`` and the axis bookkeeping.

    The method works on extrinsic sequences; an intrinsic one is the reversed extrinsic one
    with its angles reversed. A Tait-Bryan sequence is rotated onto the proper-Euler form by
    the fixed 90-degree change ``a = w - q_j`` etc. and its middle angle shifted by pi/2.
    """
    i, j, k = conv.axes if not conv.intrinsic else conv.axes[::-1]
    if conv.symmetric:
        k = 3 - i - j
    sign = (i - j) * (j - k) * (k - i) // 2  # +1 for an even permutation of xyz, -1 otherwise
    w, qi, qj, qk = q[..., 0], q[..., i + 1], q[..., j + 1], q[..., k + 1] * sign
    if conv.symmetric:
        return (w, qi, qj, qk), sign
    return (w - qj, qi + qk, qj + w, qk - qi), sign


def _lock_cases(a, b, c, d, eps: float):
    """Which rows are within ``eps`` of gimbal lock, tested without losing precision.

    The middle angle (before any pi/2 shift) is ``2 atan2(|(c, d)|, |(a, b)|)``; it is within
    ``eps`` of 0 iff ``|(c, d)| <= tan(eps / 2) |(a, b)|`` and within ``eps`` of pi iff
    ``|(a, b)| <= tan(eps / 2) |(c, d)|``. Neither side subtracts nearly equal numbers.
    """
    ab2, cd2 = a * a + b * b, c * c + d * d
    t2 = math.tan(eps / 2.0) ** 2
    return ab2, cd2, cd2 <= t2 * ab2, ab2 <= t2 * cd2


@kernel
def quat_to_euler_unchecked(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    conv = convention
    (a, b, c, d), sign = _abcd(q, conv)
    ab2, cd2, near_zero, near_pi = _lock_cases(a, b, c, d, eps)
    regular = ~(near_zero | near_pi)
    middle = 2.0 * torch.atan2(safe_sqrt(cd2), safe_sqrt(ab2))
    # atan2(0, 0) has a NaN gradient: feed each discarded half-angle a safe (0, 1) argument.
    half_sum = torch.atan2(torch.where(near_pi, 0.0, b), torch.where(near_pi, 1.0, a))
    half_diff = torch.atan2(torch.where(near_zero, 0.0, d), torch.where(near_zero, 1.0, c))
    extrinsic = not conv.intrinsic
    locked = torch.where(near_zero, 2.0 * half_sum, 2.0 * half_diff * (-1.0 if extrinsic else 1.0))
    zero = torch.zeros_like(locked)
    first = torch.where(regular, half_sum - half_diff, locked if extrinsic else zero)
    third = torch.where(regular, half_sum + half_diff, zero if extrinsic else locked)
    if not conv.symmetric:
        third = third * sign
        middle = middle - math.pi / 2.0
    first = torch.remainder(first + math.pi, 2.0 * math.pi) - math.pi
    third = torch.remainder(third + math.pi, 2.0 * math.pi) - math.pi
    angles = torch.stack((first, middle, third) if extrinsic else (third, middle, first), dim=-1)
    # a + b + c + d = 0 only for q = 0: no rotation, so NaN rather than a plausible (0, -pi/2, 0).
    return torch.where((ab2 + cd2 == 0).unsqueeze(-1), torch.nan, angles)


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
        Angles in the convention's letter order: first and third in ``[-pi, pi)``; the middle in
        ``[-pi/2, pi/2]`` (Tait-Bryan) or ``[0, pi]`` (proper Euler). Gradients are finite
        everywhere, gimbal lock included.

    Shape:
        ``(..., 4)`` -> ``(..., 3)``.

    Example:
        >>> q = euler_to_quat(torch.tensor([30., 20., 10.]), "ZYX", degrees=True)
        >>> quat_to_euler(q, "ZYX", degrees=True)
        tensor([30.0000, 20.0000, 10.0000])
    """
    conv = parse_convention(convention, "quat_to_euler")
    q, dtype = prepare(q, "quat_to_euler", "q", (4,))
    angles = quat_to_euler_unchecked(q, convention=conv, eps=gimbal_eps(q.dtype) if eps is None else float(eps))
    return restore(angles * (180.0 / math.pi) if degrees else angles, dtype)


@kernel
def matrix_to_euler_unchecked(R: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    return quat_to_euler_unchecked(matrix_to_quat_unchecked(R), convention=convention, eps=eps)


def matrix_to_euler(R: Tensor, convention: str, degrees: bool = False, eps: Optional[float] = None) -> Tensor:
    """Euler angles of a rotation matrix in any of the 24 conventions.

    Goes through the quaternion (Shepperd), which keeps full precision next to gimbal lock
    where ``asin`` of a matrix entry does not.

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
    conv = parse_convention(convention, "matrix_to_euler")
    R, dtype = prepare(R, "matrix_to_euler", "R", (3, 3))
    angles = matrix_to_euler_unchecked(R, convention=conv, eps=gimbal_eps(R.dtype) if eps is None else float(eps))
    return restore(angles * (180.0 / math.pi) if degrees else angles, dtype)


def euler_gimbal_lock(q: Tensor, convention: str, eps: Optional[float] = None) -> Tensor:
    """Which rotations are within ``eps`` of gimbal lock for ``convention``.

    Uses exactly the test :func:`quat_to_euler` uses, so a ``True`` row is one whose third
    angle was set to 0. No warning is raised anywhere (that would need a device sync).

    Args:
        q: quaternions ``(w, x, y, z)``.
        convention: as in :func:`euler_to_quat`.
        eps: threshold in radians on the middle angle, default as in :func:`quat_to_euler`.

    Returns:
        A boolean mask.

    Shape:
        ``(..., 4)`` -> ``(...)``.

    Example:
        >>> q = euler_to_quat(torch.tensor([10., 90., 0.], dtype=torch.float64), "ZYX", degrees=True)
        >>> euler_gimbal_lock(q, "ZYX")
        tensor(True)
    """
    conv = parse_convention(convention, "euler_gimbal_lock")
    q, _ = prepare(q, "euler_gimbal_lock", "q", (4,))
    eps = gimbal_eps(q.dtype) if eps is None else float(eps)
    (a, b, c, d), _ = _abcd(q, conv)
    _, _, near_zero, near_pi = _lock_cases(a, b, c, d, eps)
    return near_zero | near_pi
