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
from ._math import constant, contract, safe_sqrt
from ._validation import prepare, restore
from .conventions import EULER_CONVENTIONS, EulerConvention, gimbal_eps, parse_convention
from .matrix import matrix_to_quat_unchecked, quat_to_matrix_unchecked
from .quaternion import basis_product

__all__ = ["euler_to_quat", "quat_to_euler", "euler_to_matrix", "matrix_to_euler", "euler_gimbal_lock"]

_UNIT = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))  # 1, i, j, k


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
        rows.append(basis_product(basis_product(factors[0], factors[1]), factors[2]))
    return tuple(rows)


_SIGN_TABLES: Dict[str, Tuple[Tuple[int, ...], ...]] = {
    name: _sign_table(conv) for name, conv in EULER_CONVENTIONS.items()
}


@kernel
def euler_to_quat_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    half = angles * 0.5
    cs = torch.stack((torch.cos(half), torch.sin(half)), dim=-1)  # (..., 3, 2)
    c1, c2, c3 = cs.unbind(-2)
    products = (c1[..., :, None, None] * c2[..., None, :, None] * c3[..., None, None, :]).flatten(-3)
    q = contract(products, "euler_signs_" + convention.name, _SIGN_TABLES[convention.name])
    # w >= 0 from w's sign alone (cheaper than standardize_sign; w == 0 exactly would need
    # a product of float cosines and sines to cancel exactly)
    return q * torch.where(q[..., :1] < 0, -1.0, 1.0)


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
        >>> euler_to_matrix(torch.tensor([90., 0., 0.]), "ZYX", degrees=True).round(decimals=6) + 0.0  # + 0.0 turns -0. into 0.
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    conv = parse_convention(convention, "euler_to_matrix")
    angles, dtype = prepare(angles, "euler_to_matrix", "angles", (3,))
    return restore(euler_to_matrix_unchecked(_to_radians(angles, degrees), convention=conv), dtype)


def _abcd_table(conv: EulerConvention):
    """Bernardes and Viollet's permuted quaternion ``(a, b, c, d) = q @ P`` and the sign.

    The method works on extrinsic sequences; an intrinsic one is the reversed extrinsic one
    with its angles reversed. A Tait-Bryan sequence is rotated onto the proper-Euler form by
    the fixed 90-degree change ``a = w - q_j`` etc. and its middle angle shifted by pi/2.
    The change is linear in ``q``, so it is one 4 x 4 matrix per convention.
    """
    i, j, k = conv.axes if not conv.intrinsic else conv.axes[::-1]
    if conv.symmetric:
        k = 3 - i - j
    sign = (i - j) * (j - k) * (k - i) // 2  # +1 for an even permutation of xyz, -1 otherwise
    w, qi, qj, qk = 0, i + 1, j + 1, k + 1  # rows of P: which input component
    if conv.symmetric:
        columns = [{w: 1}, {qi: 1}, {qj: 1}, {qk: sign}]
    else:
        columns = [{w: 1, qj: -1}, {qi: 1, qk: sign}, {qj: 1, w: 1}, {qk: sign, qi: -1}]
    table = [[float(col.get(row, 0)) for col in columns] for row in range(4)]
    return table, sign


_ABCD = {name: _abcd_table(conv) for name, conv in EULER_CONVENTIONS.items()}


def _lock_cases(q: Tensor, conv: EulerConvention, eps: float):
    """``(a, b, c, d)``, ``(|(a, b)|^2, |(c, d)|^2)`` and which rows are within ``eps`` of lock.

    The middle angle (before any pi/2 shift) is ``2 atan2(|(c, d)|, |(a, b)|)``; it is within
    ``eps`` of 0 iff ``|(c, d)| <= tan(eps / 2) |(a, b)|`` and within ``eps`` of pi iff
    ``|(a, b)| <= tan(eps / 2) |(c, d)|``. Neither side subtracts nearly equal numbers.
    """
    abcd = contract(q, "abcd_" + conv.name, _ABCD[conv.name][0])
    norms2 = (abcd * abcd).unflatten(-1, (2, 2)).sum(-1)
    ab2, cd2 = norms2.unbind(-1)
    t2 = math.tan(eps / 2.0) ** 2
    return abcd, norms2, cd2 <= t2 * ab2, ab2 <= t2 * cd2


@kernel
def quat_to_euler_unchecked(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    conv, sign = convention, _ABCD[convention.name][1]
    abcd, norms2, near_zero, near_pi = _lock_cases(q, conv, eps)
    norms = safe_sqrt(norms2)
    middle = 2.0 * torch.atan2(norms[..., 1], norms[..., 0])
    # (half sum, half difference) = (atan2(b, a), atan2(d, c)). Near lock one of them is
    # atan2(0, 0), whose gradient is NaN: feed the unused one a safe (0, 1) argument.
    unused = torch.stack((near_pi, near_zero), dim=-1)
    halves = torch.atan2(torch.where(unused, 0.0, abcd[..., 1::2]), torch.where(unused, 1.0, abcd[..., 0::2]))
    half_sum, half_diff = halves.unbind(-1)
    extrinsic = not conv.intrinsic
    # SciPy's rule at lock: the third angle is 0 and the first carries the rotation.
    locked = 2.0 * torch.where(near_zero, half_sum, half_diff * (-1.0 if extrinsic else 1.0))
    locked_pair = locked.unsqueeze(-1) * constant("lock_first" if extrinsic else "lock_third",
                                                  [1.0, 0.0] if extrinsic else [0.0, 1.0], q)
    regular = ~(near_zero | near_pi)
    # (first, third) in the extrinsic order the method computes: (half_sum -+ half_diff)
    pair = torch.where(regular.unsqueeze(-1), contract(halves, "sum_diff", [[1.0, 1.0], [-1.0, 1.0]]), locked_pair)
    if not conv.symmetric:
        pair = pair * constant(f"tait_bryan_sign{sign}", [1.0, float(sign)], q)
        middle = middle - math.pi / 2.0
    first, third = (torch.remainder(pair + math.pi, 2.0 * math.pi) - math.pi).unbind(-1)
    angles = torch.stack((first, middle, third) if extrinsic else (third, middle, first), dim=-1)
    # |(a, b)|^2 + |(c, d)|^2 = 0 only for q = 0: no rotation, so NaN, not a plausible (0, -pi/2, 0).
    return torch.where((norms2.sum(-1) == 0).unsqueeze(-1), torch.nan, angles)


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
    _, _, near_zero, near_pi = _lock_cases(q, conv, eps)
    return near_zero | near_pi
