"""Euler angles <-> quaternions and matrices, for all 24 conventions.

One general path serves every convention (SciPy's rule: ``'ZYX'`` intrinsic, ``'zyx'``
extrinsic). Quaternion to Euler follows Bernardes and Viollet, "Quaternion to Euler angles
conversion: A direct, general and computationally efficient method", PLoS ONE 17(11), 2022,
with SciPy's gimbal-lock rule: within ``eps`` of lock the third angle is 0 and the first
carries the whole rotation. Its angles are rewritten as ``atan2`` of quadratic forms of ``q``,
which are linear in R's entries, so matrices need no quaternion (see ``torchquat._euler_forms``).

Each kernel has two forms that give the same results to rounding (tested against each other):
constant tables contracted by one small matmul for small batches, where every dispatch counts,
and column-wise formulas for large batches and ``torch.compile`` (one fused loop). The products
and tables of Euler -> quaternion and matrix are in ``torchquat._euler_rotations``.
"""

import math
from typing import Optional

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._dispatch import compiled_without_gradient, kernel
from ._one_row import OneRow
from ._polynomials import DIRECT_EULER_ANGLES
from ._euler_forms import (COLUMNWISE, MATRIX_TO_EULER_COLUMNWISE, MATRIX_TO_EULER_TRACED, PAIRS, QUAT_TO_EULER_PLANAR,
                           QUAT_TO_EULER_PLANAR_SHARE, angles_columnwise, lock_columnwise, matrix_lock_columnwise,
                           quat_lock_planar)
from ._euler_small import euler_angles, lock, matrix_layout, quat_layout
from ._euler_rotations import (EULER_TO_MATRIX, EULER_TO_QUAT, EULER_TO_QUAT_COLUMNWISE, EULER_TO_QUAT_TRACED,
                               _euler_to_quat_columnwise_parts, euler_to_matrix_small)
from ._math import combine, constant, is_small, literal
from ._planes import columns, planar
from ._validation import prepare, restore, tensor_or_as_is
from .conventions import EulerConvention, check_degrees, gimbal_eps, gimbal_threshold, parse_convention
from .errors import ShapeError
from .matrix import quat_columns_to_matrix, quat_to_matrix_unchecked

__all__ = ["euler_to_quat", "quat_to_euler", "euler_to_matrix", "matrix_to_euler", "euler_gimbal_lock"]


@kernel(blocked_row_dims=(1,), compiled_from_rows=512, polynomial_sincos=DIRECT_EULER_ANGLES,
        one_row=OneRow("euler_to_quat", (3,), (4,)))
def euler_to_quat_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    # column by column from 513 rows, with its closed-form backward (forward+backward: 1.6x faster
    # than the tables at 1,024 rows, even at 512; the tables' forward leads by 10% up to ~1,500)
    if not is_small(angles, 3, share=0.125, gpu_share=0.25):
        if torch.compiler.is_compiling():
            return EULER_TO_QUAT_TRACED(angles, convention=convention)
        return closed_form.apply(EULER_TO_QUAT_COLUMNWISE, angles, convention=convention)
    return closed_form.apply(EULER_TO_QUAT, angles, convention=convention)


def to_radians(angles: Tensor, degrees: bool) -> Tensor:
    """``angles`` in radians. Degrees are first reduced modulo 360 by ``fmod``, which is exact:
    a large angle (1e6 degrees in float32) keeps its rotation, where the product alone would
    round away its fraction of a turn; angles within a turn are unchanged bit for bit."""
    if not degrees:
        return angles
    return torch.fmod(angles, constant("full_turn_degrees", 360.0, angles)) * constant("radians_per_degree", math.pi / 180.0, angles)


def to_degrees(angles: Tensor, degrees: bool) -> Tensor:
    return angles * constant("degrees_per_radian", 180.0 / math.pi, angles) if degrees else angles


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
    if degrees is False and (out := euler_to_quat_unchecked.at_one_row(angles, convention=conv)) is not None:
        return out
    angles, dtype = prepare(angles, "euler_to_quat", "angles", (3,))
    return restore(euler_to_quat_unchecked(to_radians(angles, check_degrees("euler_to_quat", degrees)), convention=conv), dtype)


@kernel(blocked_row_dims=(1,), compiled_from_rows=256, polynomial_sincos=DIRECT_EULER_ANGLES,
        one_row=OneRow("euler_to_matrix", (3,), (3, 3)))
def euler_to_matrix_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    if is_small(angles, 3, share=1 / 16, gpu_share=0.25):  # the 4-slot, 27-column outer product: pays up to ~250 rows
        return closed_form.apply(EULER_TO_MATRIX, angles, convention=convention)
    # (with a graph to record, through the quaternion from 769 rows: forward+backward 0.77x the time at 1,000)
    if is_small(angles, 3, share=0.1875 if closed_form.records_graph((angles,)) else 0.25, gpu_share=0.25):
        return euler_to_matrix_small(angles, convention)
    # from 1,025 rows: the 27-column outer product costs more memory passes than the quaternion
    # (forward 0.8x and 0.27x of the outer product's time, forward+backward 0.66x and 0.49x, at 2,048 and 4,096 rows)
    if compiled_without_gradient(angles):  # (the quaternion's columns passed on: one loop)
        return quat_columns_to_matrix(_euler_to_quat_columnwise_parts(angles, convention)[1][:4])
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
    if degrees is False and (out := euler_to_matrix_unchecked.at_one_row(angles, convention=conv)) is not None:
        return out
    angles, dtype = prepare(angles, "euler_to_matrix", "angles", (3,))
    return restore(euler_to_matrix_unchecked(to_radians(angles, check_degrees("euler_to_matrix", degrees)), convention=conv), dtype)


@kernel(blocked_row_dims=(1,), polynomial_atan2=True, one_row=OneRow("quat_to_euler", (4,), (3,)))
def quat_to_euler_unchecked(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    path = _quat_euler_path(q)
    if path == "planar":
        return closed_form.apply(QUAT_TO_EULER_PLANAR, q, convention=convention, eps=eps)
    if path == "columnwise":
        forms, abcd2 = _quat_columnwise_forms(q, convention)
        # (the value forms where nothing differentiates: compiled, 0.92x the time of ZXZ at 1e6 rows, 0.99x ZYX)
        return angles_columnwise(forms, convention, eps, abcd2, values=closed_form.VALUE_FORMS and not closed_form.differentiated((q,)))
    return euler_angles(q, convention, eps, is_matrix=False)


def _quat_euler_path(q: Tensor) -> str:
    """Which forms quat -> Euler computes (and :func:`euler_gimbal_lock` with it)."""
    if planar(q, 4, QUAT_TO_EULER_PLANAR_SHARE):
        return "planar"
    return "small" if is_small(q, 4, share=0.25) else "columnwise"  # crossover measured near 1000 rows


def _matrix_euler_small(R: Tensor) -> bool:
    """Whether matrix -> Euler (and :func:`euler_gimbal_lock` with it) takes the small batches' forms."""
    return is_small(R, 9, share=0.25, gpu_share=4)  # crossover measured near 1000 rows (with the closed-form backward)


def _quat_columnwise_forms(q: Tensor, convention: EulerConvention):
    """The forms :data:`~torchquat._euler_forms.ANGLE_FORMS` of ``q`` and ``|abcd|^2``, column by column."""
    abcd_terms, pair_terms = literal(COLUMNWISE[convention.name])
    components = columns(q)  # once: under compile each unbind's backward is an (N, 4) buffer of its own
    abcd = [combine(components, terms) for terms in abcd_terms]
    products = [abcd[u] * abcd[v] for u, v in PAIRS]
    *forms, abcd2 = [combine(products, terms) for terms in pair_terms]
    # The angles are scale-invariant, but squares of the forms underflow for tiny q, and q = 0
    # (all forms 0) must come out as NaN: the forms divided by |abcd|^2. Eager: only t1's pair
    # and Z, in angles_parts; compiled: every form (it fuses for free).
    if torch.compiler.is_compiling():
        inverse = 1.0 / abcd2
        return [form * inverse for form in forms], 1.0
    return forms, abcd2


# The lock masks of quat_to_euler_unchecked and matrix_to_euler_unchecked: the same path for the
# same batch (size, device, compiled or not, blocks), so the same forms, test and rows.
@kernel(blocked_row_dims=(1,))
def quat_gimbal_lock_unchecked(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    path = _quat_euler_path(q)
    if path == "planar":
        return quat_lock_planar(q, convention, eps)
    if path == "columnwise":
        forms, abcd2 = _quat_columnwise_forms(q, convention)
        return lock_columnwise(forms, eps, abcd2)
    return lock(quat_layout(q, convention), eps)[1]


@kernel(blocked_row_dims=(2,))
def matrix_gimbal_lock_unchecked(R: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    if not _matrix_euler_small(R):
        return matrix_lock_columnwise(R, convention, eps)
    return lock(matrix_layout(R, convention), eps)[1]


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
        tensor([30.0000, 20.0000, 10.0000])
    """
    conv = parse_convention(convention, "quat_to_euler")
    if (degrees is False and eps is None and (out := quat_to_euler_unchecked.at_one_row(
            q, convention=conv, eps=gimbal_eps(getattr(q, "dtype", None)))) is not None):
        return out
    q, dtype = prepare(q, "quat_to_euler", "q", (4,))
    angles = quat_to_euler_unchecked(q, convention=conv, eps=gimbal_threshold("quat_to_euler", eps, q.dtype))
    return restore(to_degrees(angles, check_degrees("quat_to_euler", degrees)), dtype)


@kernel(blocked_row_dims=(2,), polynomial_atan2=True, one_row=OneRow("matrix_to_euler", (9,), (3,)), vector_bits=256)
def matrix_to_euler_unchecked(R: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    if not _matrix_euler_small(R):
        if torch.compiler.is_compiling():
            return MATRIX_TO_EULER_TRACED(R, convention=convention, eps=eps)
        return closed_form.apply(MATRIX_TO_EULER_COLUMNWISE, R, convention=convention, eps=eps)
    return euler_angles(R, convention, eps, is_matrix=True)


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
    conv = parse_convention(convention, "matrix_to_euler")
    if (degrees is False and eps is None and (out := matrix_to_euler_unchecked.at_one_row(
            R, convention=conv, eps=gimbal_eps(getattr(R, "dtype", None)))) is not None):
        return out
    R, dtype = prepare(R, "matrix_to_euler", "R", (3, 3))
    angles = matrix_to_euler_unchecked(R, convention=conv, eps=gimbal_threshold("matrix_to_euler", eps, R.dtype))
    return restore(to_degrees(angles, check_degrees("matrix_to_euler", degrees)), dtype)


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
    conv = parse_convention(convention, "euler_gimbal_lock")
    q = tensor_or_as_is(q)  # (lists and NumPy arrays, as everywhere: read before the shape decides)
    is_matrix = isinstance(q, Tensor) and q.dim() >= 2 and tuple(q.shape[-2:]) == (3, 3)
    try:
        x, _ = prepare(q, "euler_gimbal_lock", "q", (3, 3) if is_matrix else (4,))
    except ShapeError:
        raise ShapeError("euler_gimbal_lock: expected q of shape (..., 4) or (..., 3, 3), "
                         f"got {tuple(torch.as_tensor(q).shape)}") from None
    eps = gimbal_threshold("euler_gimbal_lock", eps, x.dtype)
    return (matrix_gimbal_lock_unchecked if is_matrix else quat_gimbal_lock_unchecked)(x, convention=conv, eps=eps)
