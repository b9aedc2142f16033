"""Euler angles to quaternions and matrices: the products of half-angle (or angle) cosines and
sines, the constant tables they are contracted with, and the closed-form rules built on them.

The quaternion of three elementary rotations ``cos(a/2) + sin(a/2) e_axis`` is a trilinear form in
the three ``(cos, sin)`` pairs (8 products against a sign table); the matrix is one in the
``(1, cos, sin)`` triples (27 products). Small batches contract one outer product with the table
(one matmul); large ones (and ``torch.compile``) write the same sums column by column. The public
functions and the kernels' dispatch are in ``torchquat.euler``.
"""

from typing import Dict, Tuple

import torch
from torch import Tensor

from ._closed_form import Rule, jacobian_rule, traced_rule
from ._math import HALF_IDENTITY, bilinear, bilinear_terms, constant, contract, copysign
from ._polynomials import cos_sin_up_to_sign
from ._planes import columns, plane_buffer, rows, slot
from .conventions import EULER_CONVENTIONS, EulerConvention
from .quaternion import basis_product

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
    if not torch.compiler.is_compiling() and triples.numel() <= 512:
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
    return q * copysign(constant("one", 1.0, q), q.narrow(-1, 0, 1))


def _euler_to_quat_with_jacobian(angles: Tensor, convention: EulerConvention):
    rows = contract(_outer_products(angles * constant("half", 0.5, angles), False, slots=True, scale=0.5),
                    "euler_signs_" + convention.name,
                    _SIGN_TABLES[convention.name])  # (..., 4, 4): q, then dq / d angle n
    rows = rows * copysign(constant("one", 1.0, rows), rows[..., :1, :1])
    return rows[..., 0, :], rows[..., 1:, :]


EULER_TO_QUAT = jacobian_rule(_euler_to_quat_small, _euler_to_quat_with_jacobian)


def _euler_to_quat_columnwise_parts(angles: Tensor, convention: EulerConvention, values: bool = False):
    """Column by column (fewer passes; under compile one fused loop): the quaternion, and what the
    closed-form backward needs (its columns, and the left factor's half-angle cosine and sine).
    ``values``: nothing keeps those (so the columns may be the output rows' own memory, which a
    caller may write in place; see ``_planes.plane_buffer``)."""
    # (each pair up to a sign in the compiled float32 kernels: it flips q, and w >= 0 below undoes that)
    cs = [cos_sin_up_to_sign(h) for h in columns(angles, HALF_IDENTITY[3], "half3")]
    pairs = [u * v for u in cs[0] for v in cs[1]]
    # the table's row 4 m1 + 2 m2 + m3 is pair 2 m1 + m2 times factor m3 of the third angle:
    # two terms per component (one product of three elementary quaternions)
    q = bilinear(pairs, cs[2], _SIGN_BILINEAR[convention.name])
    sign = copysign(constant("one", 1.0, q[0]), q[0])  # w >= 0 (a where on w < 0 mispredicts)
    buffer = plane_buffer(4, q, output=values)
    q = [torch.mul(c, sign, out=slot(buffer, i)) for i, c in enumerate(q)]
    return rows(q if buffer is None else buffer), (*q, *cs[_ANGLE_TERMS[convention.name][0]])


def euler_to_quat_columnwise(angles: Tensor, convention: EulerConvention) -> Tensor:
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


EULER_TO_QUAT_COLUMNWISE = Rule(euler_to_quat_columnwise, _euler_to_quat_columnwise_parts,
                                 _euler_to_quat_columnwise_backward,
                                 lambda angles, convention: _euler_to_quat_columnwise_parts(angles, convention, values=True)[0])
EULER_TO_QUAT_TRACED = traced_rule(EULER_TO_QUAT_COLUMNWISE)


def euler_to_matrix_small(angles: Tensor, convention: EulerConvention) -> Tensor:
    # one trilinear form: the trig, a gather and the products, one matmul
    R = contract(_outer_products(angles, with_one=True), "euler_matrix_" + convention.name, _MATRIX_TABLES[convention.name])
    return R.unflatten(-1, (3, 3))


def _euler_to_matrix_with_jacobian(angles: Tensor, convention: EulerConvention):
    rows = contract(_outer_products(angles, True, slots=True), "euler_matrix_" + convention.name,
                    _MATRIX_TABLES[convention.name])  # (..., 4, 9): R, then dR / d angle n
    return rows[..., 0, :].unflatten(-1, (3, 3)), rows[..., 1:, :]


EULER_TO_MATRIX = jacobian_rule(euler_to_matrix_small, _euler_to_matrix_with_jacobian)
