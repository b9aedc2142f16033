"""Euler angles <-> quaternions and matrices, for all 24 conventions.

One general path serves every convention (SciPy's rule: ``'ZYX'`` intrinsic, ``'zyx'``
extrinsic). Quaternion to Euler follows Bernardes and Viollet, "Quaternion to Euler angles
conversion: A direct, general and computationally efficient method", PLoS ONE 17(11), 2022,
with SciPy's gimbal-lock rule: within ``eps`` of lock the third angle is 0 and the first
carries the whole rotation. Its angles are rewritten as ``atan2`` of quadratic forms of ``q``,
which are linear in R's entries, so matrices need no quaternion (see ``torchquat._euler_forms``).

Each kernel has two forms that give the same results to rounding (tested against each other):
constant tables contracted by one small matmul for small batches, where every dispatch counts,
and column-wise formulas for large batches and ``torch.compile`` (one fused loop).
"""

import math
from typing import Dict, Optional, Tuple

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule, jacobian_rule
from ._dispatch import kernel
from ._euler_forms import (COLUMNWISE, LOCKED, MATRIX_TO_EULER_COLUMNWISE, PAIRS, QUAT_TO_EULER_PLANAR,
                           QUAT_TO_EULER_PLANAR_SHARE, angles_columnwise, angles_parts, matrix_lock_columnwise,
                           matrix_to_euler_columnwise, quat_lock_planar)
from ._euler_small import euler_angles, lock, matrix_layout, quat_layout
from ._math import HALF_IDENTITY, bilinear, bilinear_terms, combine, constant, contract, is_small
from ._planes import columns, planar, plane_buffer, rows, slot
from ._validation import prepare, restore
from .conventions import EULER_CONVENTIONS, EulerConvention, gimbal_eps, parse_convention
from .errors import ShapeError
from .matrix import quat_to_matrix_unchecked
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


def _elementary_rotation_terms(axis: int):
    """``(A0, A1, A2)`` with ``R_axis(a) = A0 + cos(a) A1 + sin(a) A2`` (3 x 3 integer lists)."""
    e = [1 if i == axis else 0 for i in range(3)]
    a0 = [[e[i] * e[j] for j in range(3)] for i in range(3)]
    a1 = [[(1 if i == j else 0) - e[i] * e[j] for j in range(3)] for i in range(3)]
    cross = [[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]]  # [e]x
    return a0, a1, cross


def _matmul3(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def _matrix_table(convention: EulerConvention):
    """27 x 9 table: ``R.flatten() = (b1 x b2 x b3).flatten() @ T`` with ``b_n = (1, cos a_n, sin a_n)``.

    Each elementary rotation is ``A0 + c A1 + s A2``, so their product is a trilinear form in the
    three ``b_n``: 27 constant matrices, one per choice of term from each factor (exact integers).
    Intrinsic ``ABC`` is ``R_A R_B R_C``; extrinsic ``abc`` is ``R_c R_b R_a``.
    """
    terms = [_elementary_rotation_terms(axis) for axis in convention.axes]
    table = []
    for u in range(27):
        factors = [terms[0][u // 9], terms[1][(u // 3) % 3], terms[2][u % 3]]
        if not convention.intrinsic:
            factors.reverse()
        product = _matmul3(_matmul3(factors[0], factors[1]), factors[2])
        table.append([float(v) for row in product for v in row])
    return table


_SIGN_TABLES: Dict[str, Tuple[Tuple[int, ...], ...]] = {
    name: _sign_table(conv) for name, conv in EULER_CONVENTIONS.items()
}
_MATRIX_TABLES = {name: _matrix_table(conv) for name, conv in EULER_CONVENTIONS.items()}
_SIGN_BILINEAR = {name: bilinear_terms(table, 2) for name, table in _SIGN_TABLES.items()}  # (column-wise form)


# Which of the flattened per-angle factors each product takes: ``(cos, sin)`` of angle n at
# 2n, 2n + 1; ``(1, cos, sin)`` at 3n, 3n + 1, 3n + 2. Product m multiplies one factor per angle.
_OUTER_INDEX = {
    False: [2 * n + ((m >> (2 - n)) & 1) for m in range(8) for n in range(3)],
    True: [3 * n + (u // 3 ** (2 - n)) % 3 for u in range(27) for n in range(3)],
}

# Entry j of an angle's factor row, then (after the k factors) of its derivative row, as
# (which of the angle's (cos, sin), coefficient, offset): (1, cos, sin) and (0, -sin, cos), or
# (cos, sin) and (-sin, cos). A 1 or a 0 is an offset on a coefficient of 0.
_FACTOR_ENTRIES = {
    True: ((0, 0.0, 1.0), (0, 1.0, 0.0), (1, 1.0, 0.0), (0, 0.0, 0.0), (1, -1.0, 0.0), (0, 1.0, 0.0)),
    False: ((0, 1.0, 0.0), (1, 1.0, 0.0), (1, -1.0, 0.0), (0, 1.0, 0.0)),
}


def _gather_plan(with_one: bool, slots: bool, scale: float):
    """The factors of every product of :func:`_outer_products`, as a gather from the three angles'
    flattened ``(cos, sin)`` and a coefficient and offset each. ``slots``: four copies, copy
    ``n + 1`` with angle n's factors replaced by their derivatives (times ``scale``, the chain
    rule's factor for half angles)."""
    k = 3 if with_one else 2
    index, coefficient, offset = [], [], []
    for copy in range(4 if slots else 1):
        for flat in _OUTER_INDEX[with_one]:
            n, j = divmod(flat, k)
            derivative = copy == n + 1
            trig, c, o = _FACTOR_ENTRIES[with_one][j + (k if derivative else 0)]
            index.append(2 * n + trig)
            coefficient.append(c * scale if derivative else c)
            offset.append(o)
    return index, coefficient, offset


# (constant names formatted once: an f-string of the key costs 0.3 us a call)
# The four in use: Euler -> quat (half angles; with the Jacobian, scale 0.5) and Euler -> matrix.
_GATHER_PLANS = {key: (f"euler_gather_{key[0]}_{key[1]}_{key[2]}", _gather_plan(*key))
                 for key in ((False, False, 1.0), (False, True, 0.5), (True, False, 1.0), (True, True, 1.0))}


def _products_of_triples(triples: Tensor) -> Tensor:
    """``(..., 3) -> (...)``: ``prod`` for a few rows (one dispatch instead of an ``unbind`` and two
    multiplications: 3 us at one rotation), two multiplications above (``prod``'s backward, which
    guards against zeros, is 1.4x slower at 1,000 rows, and its forward is slower from ~10 rows).
    The same numbers either way."""
    if triples.numel() <= 512:
        return triples.prod(-1)
    a, b, c = triples.unbind(-1)
    return a * b * c


def _outer_products(angles: Tensor, with_one: bool, slots: bool = False, scale: float = 1.0) -> Tensor:
    """The outer product over the three angles of their trig factors, ``(1, cos, sin)``
    (``with_one``) or ``(cos, sin)``: ``(..., 3) -> (..., 27 or 8)``. With ``slots``, the values in
    slot 0 and their derivatives with respect to each angle in slots 1-3, ``(..., 4, 27 or 8)``: a
    trilinear form's derivative in one angle is the same product with that angle's factors
    differentiated, so one outer product gives the values and the Jacobian.

    One gather from the ``(cos, sin)`` pairs and one ``addcmul`` (its 1s and 0s are offsets) make
    every product's three factors: fewer dispatches than padding and gathering twice."""
    name, (index, coefficient, offset) = _GATHER_PLANS[(with_one, slots, scale)]
    cs = torch.stack((torch.cos(angles), torch.sin(angles)), dim=-1).flatten(-2)
    factors = cs.index_select(-1, constant(name, index, cs, dtype=torch.long))
    if with_one:
        factors = torch.addcmul(constant(name + "_offset", offset, cs), factors, constant(name + "_coefficient", coefficient, cs))
    elif slots:  # (no offsets; the derivatives' signs and scale)
        factors = factors * constant(name + "_coefficient", coefficient, cs)
    return _products_of_triples(factors.unflatten(-1, (4, -1, 3) if slots else (-1, 3)))


def _euler_to_quat_small(angles: Tensor, convention: EulerConvention) -> Tensor:
    products = _outer_products(angles * constant("half", 0.5, angles), with_one=False)
    q = contract(products, "euler_signs_" + convention.name, _SIGN_TABLES[convention.name])
    # w >= 0 from w's sign alone (cheaper than standardize_sign; w == 0 exactly would need
    # a product of float cosines and sines to cancel exactly, and then either sign is right)
    return q * torch.copysign(constant("one", 1.0, q), q.narrow(-1, 0, 1))


def _euler_to_quat_with_jacobian(angles: Tensor, convention: EulerConvention):
    rows = contract(_outer_products(angles * constant("half", 0.5, angles), False, slots=True, scale=0.5),
                    "euler_signs_" + convention.name,
                    _SIGN_TABLES[convention.name])  # (..., 4, 4): q, then dq / d angle n
    rows = rows * torch.copysign(constant("one", 1.0, rows), rows[..., :1, :1])
    return rows[..., 0, :], rows[..., 1:, :]


_EULER_TO_QUAT = jacobian_rule(_euler_to_quat_small, _euler_to_quat_with_jacobian)


def _euler_to_quat_columnwise_parts(angles: Tensor, convention: EulerConvention):
    """Column by column (fewer passes; under compile one fused loop): the quaternion, and what the
    closed-form backward needs (its columns, and the left factor's half-angle cosine and sine)."""
    cs = [(torch.cos(h), torch.sin(h)) for h in columns(angles, HALF_IDENTITY[3], "half3")]
    pairs = [u * v for u in cs[0] for v in cs[1]]
    # the table's row 4 m1 + 2 m2 + m3 is pair 2 m1 + m2 times factor m3 of the third angle:
    # two terms per component (one product of three elementary quaternions)
    q = bilinear(pairs, cs[2], _SIGN_BILINEAR[convention.name])
    sign = torch.copysign(constant("one", 1.0, q[0]), q[0])  # w >= 0 (a where on w < 0 mispredicts)
    buffer = plane_buffer(4, q)
    q = [torch.mul(c, sign, out=slot(buffer, i)) for i, c in enumerate(q)]
    return rows(q if buffer is None else buffer), (*q, *cs[_ANGLE_TERMS[convention.name][0]])


def _euler_to_quat_columnwise(angles: Tensor, convention: EulerConvention) -> Tensor:
    return _euler_to_quat_columnwise_parts(angles, convention)[0]


def _angle_terms(convention: EulerConvention):
    """For the closed-form backward of Euler -> quat: the left factor's angle, and the bilinear
    terms of ``<g, e_L q>``, ``<g, e_M q>``, ``<g, (e_L x e_M) q>`` and ``<g, q e_R>`` (g, q as columns).

    ``q = L M R``, three elementary quaternions ``cos(a/2) + sin(a/2) e`` (intrinsic: the angles
    in letter order; extrinsic: reversed). ``dL/da = e_L L / 2`` gives ``dq = e_L q da / 2`` for the
    left angle, ``q e_R da / 2`` for the right one, and ``L e_M L^-1 q da / 2`` for the middle, where
    ``L e_M L^-1 = cos(a_L) e_M + sin(a_L) e_L x e_M`` (``e_L`` is perpendicular to ``e_M``)."""
    order = (0, 1, 2) if convention.intrinsic else (2, 1, 0)
    left, right = order[0], order[2]
    e_left, e_middle, e_right = (convention.axes[n] + 1 for n in order)  # basis quaternions 1-3
    cross_quat = basis_product(_UNIT[e_left], _UNIT[e_middle])  # e_L x e_M = e_L e_M (perpendicular)
    table = []  # row 4 i + j: coefficients of g_i q_j in the four forms
    for i in range(4):
        for j in range(4):
            table.append([basis_product(_UNIT[e_left], _UNIT[j])[i],
                          basis_product(_UNIT[e_middle], _UNIT[j])[i],
                          basis_product(cross_quat, _UNIT[j])[i],
                          basis_product(_UNIT[j], _UNIT[e_right])[i]])
    return left, right, bilinear_terms(table, 4)


_ANGLE_TERMS = {name: _angle_terms(conv) for name, conv in EULER_CONVENTIONS.items()}


def _euler_to_quat_columnwise_backward(grad: Tensor, inputs, saved, convention: EulerConvention):
    q, (c, s) = saved[:4], saved[4:]
    left, right, terms = _ANGLE_TERMS[convention.name]
    half = columns(grad, HALF_IDENTITY[4], "half4")  # (the chain rule's 1/2 of half angles, in the transpose)
    buffer = plane_buffer(3, half)
    g_left, g_middle, g_cross, g_right = bilinear(half, q, terms, out=(slot(buffer, left), None, None, slot(buffer, right)))
    # middle: cos(a_L) <g, e_M q> + sin(a_L) <g, (e_L x e_M) q>, from the half angle's c and s
    cosine = torch.addcmul(c * c, s, s, value=-1.0)
    g_middle = torch.addcmul(cosine * g_middle, s * c, g_cross, value=2.0, out=slot(buffer, 1))
    gradient = [g_middle] * 3
    gradient[left], gradient[right] = g_left, g_right
    return (rows(gradient if buffer is None else buffer),)


_EULER_TO_QUAT_COLUMNWISE = Rule(_euler_to_quat_columnwise, _euler_to_quat_columnwise_parts,
                                 _euler_to_quat_columnwise_backward)


@kernel(blocked_row_dims=(1,))
def euler_to_quat_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    # column by column from 513 rows, with its closed-form backward (forward+backward: 1.6x faster
    # than the tables at 1,024 rows, even at 512; the tables' forward leads by 10% up to ~1,500)
    if not is_small(angles, 3, share=0.125, gpu_share=0.25):
        if torch.compiler.is_compiling():
            return _euler_to_quat_columnwise(angles, convention)
        return closed_form.apply(_EULER_TO_QUAT_COLUMNWISE, angles, convention=convention)
    return closed_form.apply(_EULER_TO_QUAT, angles, convention=convention)


def _to_radians(angles: Tensor, degrees: bool) -> Tensor:
    return angles * constant("radians_per_degree", math.pi / 180.0, angles) if degrees else angles


def _to_degrees(angles: Tensor, degrees: bool) -> Tensor:
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
    angles, dtype = prepare(angles, "euler_to_quat", "angles", (3,))
    return restore(euler_to_quat_unchecked(_to_radians(angles, degrees), convention=conv), dtype)


def _euler_to_matrix_small(angles: Tensor, convention: EulerConvention) -> Tensor:
    # one trilinear form: the trig, a gather and the products, one matmul
    R = contract(_outer_products(angles, with_one=True), "euler_matrix_" + convention.name, _MATRIX_TABLES[convention.name])
    return R.unflatten(-1, (3, 3))


def _euler_to_matrix_with_jacobian(angles: Tensor, convention: EulerConvention):
    rows = contract(_outer_products(angles, True, slots=True), "euler_matrix_" + convention.name,
                    _MATRIX_TABLES[convention.name])  # (..., 4, 9): R, then dR / d angle n
    return rows[..., 0, :].unflatten(-1, (3, 3)), rows[..., 1:, :]


_EULER_TO_MATRIX = jacobian_rule(_euler_to_matrix_small, _euler_to_matrix_with_jacobian)


@kernel(blocked_row_dims=(1,))
def euler_to_matrix_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    if is_small(angles, 3, share=1 / 16, gpu_share=0.25):  # the 4-slot, 27-column outer product: pays up to ~250 rows
        return closed_form.apply(_EULER_TO_MATRIX, angles, convention=convention)
    if is_small(angles, 3, share=0.25, gpu_share=0.25):
        return _euler_to_matrix_small(angles, convention)
    # from 1,025 rows: the 27-column outer product costs more memory passes than the quaternion
    # (forward 0.8x and 0.27x of the outer product's time, forward+backward 0.66x and 0.49x, at 2,048 and 4,096 rows)
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


@kernel(blocked_row_dims=(1,))
def quat_to_euler_unchecked(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    path = _quat_euler_path(q)
    if path == "planar":
        return closed_form.apply(QUAT_TO_EULER_PLANAR, q, convention=convention, eps=eps)
    if path == "columnwise":
        forms, abcd2 = _quat_columnwise_forms(q, convention)
        return angles_columnwise(forms, convention, eps, abcd2)
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
    abcd_terms, pair_terms = COLUMNWISE[convention.name]
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
        return angles_parts(forms, convention, eps, abcd2)[1][LOCKED]
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
    q, dtype = prepare(q, "quat_to_euler", "q", (4,))
    angles = quat_to_euler_unchecked(q, convention=conv, eps=gimbal_eps(q.dtype) if eps is None else float(eps))
    return restore(_to_degrees(angles, degrees), dtype)


@kernel(blocked_row_dims=(2,))
def matrix_to_euler_unchecked(R: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    if not _matrix_euler_small(R):
        if torch.compiler.is_compiling():
            return matrix_to_euler_columnwise(R, convention, eps)
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
    R, dtype = prepare(R, "matrix_to_euler", "R", (3, 3))
    angles = matrix_to_euler_unchecked(R, convention=conv, eps=gimbal_eps(R.dtype) if eps is None else float(eps))
    return restore(_to_degrees(angles, degrees), dtype)


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
    is_matrix = isinstance(q, Tensor) and q.dim() >= 2 and tuple(q.shape[-2:]) == (3, 3)
    try:
        x, _ = prepare(q, "euler_gimbal_lock", "q", (3, 3) if is_matrix else (4,))
    except ShapeError:
        raise ShapeError("euler_gimbal_lock: expected q of shape (..., 4) or (..., 3, 3), "
                         f"got {tuple(torch.as_tensor(q).shape)}") from None
    eps = gimbal_eps(x.dtype) if eps is None else float(eps)
    return (matrix_gimbal_lock_unchecked if is_matrix else quat_gimbal_lock_unchecked)(x, convention=conv, eps=eps)
