"""Euler angles <-> quaternions and matrices, for all 24 conventions.

One general path serves every convention (SciPy's rule: ``'ZYX'`` intrinsic, ``'zyx'``
extrinsic). Quaternion to Euler follows Bernardes and Viollet, "Quaternion to Euler angles
conversion: A direct, general and computationally efficient method", PLoS ONE 17(11), 2022,
with SciPy's gimbal-lock rule: within ``eps`` of lock the third angle is 0 and the first
carries the whole rotation. Its angles are rewritten as ``atan2`` of quadratic forms of ``q``,
which are linear in R's entries, so matrices need no quaternion (see ``_build_forms_tables``).

Each kernel has two forms that give the same results to rounding (tested against each other):
constant tables contracted by one small matmul for small batches, where every dispatch counts,
and column-wise formulas for large batches and ``torch.compile`` (one fused loop).
"""

import math
from typing import Dict, Optional, Tuple

import torch
from torch import Tensor

from ._dispatch import kernel
from ._math import constant, contract, is_small, safe_sqrt
from ._validation import prepare, restore
from .conventions import EULER_CONVENTIONS, EulerConvention, gimbal_eps, parse_convention
from .matrix import _SHEPPERD, _SHEPPERD_OFFSET, _SHEPPERD_ROWS, quat_to_matrix_unchecked
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


# Which of the flattened per-angle factors each product takes: ``(cos, sin)`` of angle n at
# 2n, 2n + 1; ``(1, cos, sin)`` at 3n, 3n + 1, 3n + 2. Product m multiplies one factor per angle.
_OUTER_INDEX = {
    False: [2 * n + ((m >> (2 - n)) & 1) for m in range(8) for n in range(3)],
    True: [3 * n + (u // 3 ** (2 - n)) % 3 for u in range(27) for n in range(3)],
}


def _trig_outer(angles: Tensor, with_one: bool) -> Tensor:
    """Outer product over the three angles of ``(cos, sin)`` (``with_one``: ``(1, cos, sin)``),
    flattened: ``(..., 3) -> (..., 8)`` or ``(..., 27)``. One gather of the factors and two
    multiplications: fewer dispatches than broadcasting, in both passes."""
    cs = torch.stack((torch.cos(angles), torch.sin(angles)), dim=-1)
    if with_one:
        cs = torch.nn.functional.pad(cs, (1, 0), value=1.0)
    index = constant(f"outer_index_{with_one}", _OUTER_INDEX[with_one], cs, dtype=torch.long)
    a, b, c = cs.flatten(-2).index_select(-1, index).unflatten(-1, (-1, 3)).unbind(-1)
    return a * b * c


@kernel
def euler_to_quat_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    if not is_small(angles, 3, share=0.25):  # column by column: fewer passes; under compile one fused loop
        half = [0.5 * a for a in angles.unbind(-1)]
        cs = [(torch.cos(h), torch.sin(h)) for h in half]
        pairs = [u * v for u in cs[0] for v in cs[1]]
        products = [p * w for p in pairs for w in cs[2]]  # index 4 m1 + 2 m2 + m3, as the table's rows
        table = _SIGN_TABLES[convention.name]
        q = [sum(products[m] * table[m][k] for m in range(8) if table[m][k]) for k in range(4)]
        sign = torch.where(q[0] < 0, -1.0, 1.0)
        return torch.stack([c * sign for c in q], dim=-1)
    products = _trig_outer(angles * constant("half", 0.5, angles), with_one=False)
    q = contract(products, "euler_signs_" + convention.name, _SIGN_TABLES[convention.name])
    # w >= 0 from w's sign alone (cheaper than standardize_sign; w == 0 exactly would need
    # a product of float cosines and sines to cancel exactly, and then either sign is right)
    return q * torch.copysign(constant("one", 1.0, q), q.narrow(-1, 0, 1))


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


@kernel
def euler_to_matrix_unchecked(angles: Tensor, convention: EulerConvention) -> Tensor:
    if is_small(angles, 3):
        # one trilinear form: the trig, a gather and two products, one matmul
        R = contract(_trig_outer(angles, with_one=True), "euler_matrix_" + convention.name,
                     _MATRIX_TABLES[convention.name])
        return R.unflatten(-1, (3, 3))
    # large batches: the 27-column outer product costs more memory passes than the quaternion
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

# Where each product q_i q_j sits among Shepperd's ten entries of 4 q q^T (see matrix.py).
_PAIR_SLOT = {(i, j): _SHEPPERD_ROWS[i][j] for i in range(4) for j in range(4)}


def _build_forms_tables(name: str):
    """The 14 quadratic forms in ``(a, b, c, d)`` that give the angles, as linear maps of
    ``q q^T`` (16 x 14) and of ``R`` (9 x 14 plus an offset, using ``|q| = 1``).

    Bernardes and Viollet's angles (extrinsic order) are ``t1 = atan2(b, a) - atan2(d, c)``,
    ``t3 = atan2(b, a) + atan2(d, c)`` and ``t2 = 2 atan2(|(c, d)|, |(a, b)|)``. By the
    angle-sum identities each is an ``atan2`` of two quadratic forms: ``t1 = atan2(bc - ad,
    ac + bd)``, ``t2 = atan2(2h, |ab|^2 - |cd|^2)`` with ``h = |(a, b)| |(c, d)|``, the norm of
    ``t1``'s pair, and the well-conditioned double angles ``2 atan2(b, a) = atan2(2ab, a^2 - b^2)``
    and ``2 atan2(d, c) = atan2(2cd, c^2 - d^2)``. Near lock ``t1`` and ``t3`` are each
    ill-conditioned but their sum (middle near 0) or difference (near pi) is not, so ``t3`` is
    formed as ``D -+ t1`` from the dominant double angle ``D``: the returned angles then
    reproduce the rotation to rounding right up to the lock. Quadratic forms of ``q`` are
    linear in ``R``, so a matrix needs no quaternion and no square root. The lock test
    ``|(c, d)| <= tan(eps/2) |(a, b)|`` (or the reverse) is ``h <= tan(eps/2) max(|ab|^2, |cd|^2)``:
    no cancellation near lock, so an exact lock is caught in float32 too.

    Columns: 0-1 ``t1`` (times 2, so the pair's norm is ``2h``); 2-3 and 4-5 the double angles
    ``2 atan2(b, a)`` and ``2 atan2(d, c)`` (times the Tait-Bryan sign); 6-7 and 8-9 ``t1`` at
    lock near 0 and near pi (extrinsic only: SciPy's rule puts the rotation in the first
    letter's angle, which is ``t1`` there and ``t3`` for intrinsic); 10-11 ``(|ab|^2, |cd|^2)``; 12 the middle angle's other argument (``Z = |ab|^2 - |cd|^2``, or ``-Z``
    for Tait-Bryan, whose middle ``atan2(2h, Z) - pi/2`` is ``atan2(-Z, 2h)``); 13 ``|abcd|^2``.
    """
    conv = EULER_CONVENTIONS[name]
    P, sign = _ABCD[name]
    tb = 1 if conv.symmetric else sign  # Tait-Bryan third angle's sign
    a, b, c, d = range(4)

    def form(*terms):  # terms: (coefficient, u, v) for coefficient * u * v over (a, b, c, d)
        M = [[0.0] * 4 for _ in range(4)]
        for coef, u, v in terms:
            M[u][v] += coef / 2.0
            M[v][u] += coef / 2.0
        return M

    zero = form()
    z_sign = 1 if conv.symmetric else -1
    forms = [
        form((2, b, c), (-2, a, d)), form((2, a, c), (2, b, d)),
        form((2 * tb, a, b)), form((1, a, a), (-1, b, b)),
        form((2 * tb, c, d)), form((1, c, c), (-1, d, d)),
        zero if conv.intrinsic else form((2, a, b)), zero if conv.intrinsic else form((1, a, a), (-1, b, b)),
        zero if conv.intrinsic else form((-2, c, d)), zero if conv.intrinsic else form((1, c, c), (-1, d, d)),
        form((1, a, a), (1, b, b)), form((1, c, c), (1, d, d)),
        form((z_sign, a, a), (z_sign, b, b), (-z_sign, c, c), (-z_sign, d, d)),
        form((1, a, a), (1, b, b), (1, c, c), (1, d, d)),
    ]
    # in q: A = P M P^T; in R: q_i q_j = (R.flatten() @ S + s0)[slot(i, j)] / 4 (Shepperd)
    abcd_table = [[M[u][v] for M in forms] for u in range(4) for v in range(4)]
    quat_table = [[0.0] * len(forms) for _ in range(16)]
    matrix_table = [[0.0] * len(forms) for _ in range(9)]
    offset = [0.0] * len(forms)
    for f, M in enumerate(forms):
        for i in range(4):
            for j in range(4):
                A_ij = sum(P[i][u] * M[u][v] * P[j][v] for u in range(4) for v in range(4))
                quat_table[4 * i + j][f] = A_ij
                slot = _PAIR_SLOT[(i, j)]
                for r in range(9):
                    matrix_table[r][f] += A_ij * _SHEPPERD[r][slot] / 4.0
                offset[f] += A_ij * _SHEPPERD_OFFSET[slot] / 4.0
    return quat_table, matrix_table, offset, tb, abcd_table


_FORMS_TABLES = {name: _build_forms_tables(name) for name in EULER_CONVENTIONS}


def _forms_tables(name: str):
    return _FORMS_TABLES[name]


def _quat_forms(q: Tensor, conv: EulerConvention) -> Tensor:
    return contract((q.unsqueeze(-1) * q.unsqueeze(-2)).flatten(-2), "euler_q_forms_" + conv.name,
                    _forms_tables(conv.name)[0])


def _matrix_forms(R: Tensor, conv: EulerConvention) -> Tensor:
    _, table, offset = _forms_tables(conv.name)[:3]
    return (contract(R.flatten(-2), "euler_R_forms_" + conv.name, table)
            + constant("euler_R_offset_" + conv.name, offset, R))


def _lock(forms: Tensor, eps: float):
    """``2h`` and the lock mask ``2h <= 2 tan(eps/2) max(|ab|^2, |cd|^2)``, from the forms (the
    one test every function uses)."""
    two_h = torch.linalg.vector_norm(forms.narrow(-1, 0, 2), dim=-1)  # its gradient is 0 at h = 0
    scale = 2.0 * math.tan(eps / 2.0)
    if not torch.compiler.is_compiling():  # (under compile eps may be symbolic: no cache key)
        scale = constant(f"lock_scale_{eps!r}", scale, forms)
    return two_h, two_h <= forms.narrow(-1, 10, 2).amax(-1) * scale


def _angles_from_forms(forms: Tensor, conv: EulerConvention, eps: float) -> Tensor:
    two_h, locked = _lock(forms, eps)
    t1, double_zero, double_pi, t1_lock_zero, t1_lock_pi = forms.narrow(-1, 0, 10).unflatten(-1, (5, 2)).unbind(-2)
    other = forms.select(-1, 12)
    middle = torch.stack((two_h, other) if conv.symmetric else (other, two_h), dim=-1)
    near_zero = (forms.select(-1, 10) >= forms.select(-1, 11)).unsqueeze(-1)
    # Choose each (Y, X) pair *before* atan2, so a discarded pair (which is (0, 0) at an exact
    # lock, where atan2's gradient is NaN) never reaches it.
    if conv.intrinsic:
        t1_locked = constant("atan2_zero", [0.0, 1.0], forms)
    else:
        t1_locked = torch.where(near_zero, t1_lock_zero, t1_lock_pi)
    t1 = torch.where(locked.unsqueeze(-1), t1_locked, t1)
    double = torch.where(near_zero, double_zero, double_pi)
    t1, middle, double = torch.atan2(*torch.stack((t1, middle, double), dim=-1).unbind(-2)).unbind(-1)
    # t3 = D - t1 (middle near 0) or D + t1 (near pi), times the Tait-Bryan sign, in [-pi, pi]
    tb = _forms_tables(conv.name)[3]
    step = torch.where(near_zero.squeeze(-1), constant(f"t3_near_zero{tb}", -float(tb), forms),
                       constant(f"t3_near_pi{tb}", float(tb), forms))
    pi = constant("pi", math.pi, forms)
    t3 = torch.remainder(torch.addcmul(double + pi, t1, step), constant("two_pi", 2.0 * math.pi, forms)) - pi
    if conv.intrinsic:  # the letters' third angle is t1, exactly atan2(0, 1) = 0 at lock
        return torch.stack((t3, middle, t1), dim=-1)
    # at lock t3 = D - D is 0 only to rounding; SciPy's rule makes it exactly 0
    return torch.stack((t1, middle, torch.where(locked, constant("zero", 0.0, forms), t3)), dim=-1)


def _sparse_columns(table, offset=None):
    """Each column of ``table`` as a tuple of its non-zero ``(row, coefficient)`` terms (and the
    offset), so the column-wise path traces a few terms per form instead of a dense loop."""
    columns = []
    for k in range(len(table[0])):
        terms = tuple((r, row[k]) for r, row in enumerate(table) if row[k] != 0)
        columns.append((terms, offset[k] if offset else 0.0))
    return tuple(columns)


_PAIRS = tuple((i, j) for i in range(4) for j in range(i, 4))  # the 10 distinct products u v


def _columnwise_tables(name: str):
    """Sparse terms: ``(a, b, c, d)`` from q's components, the 14 forms from the 10 products of
    ``(a, b, c, d)``, and the 14 forms from R's 9 entries."""
    quat_table, matrix_table, offset, _, abcd_table = _forms_tables(name)
    pair_table = [[0.0] * len(abcd_table[0]) for _ in _PAIRS]
    for p, (u, v) in enumerate(_PAIRS):
        for k in range(len(abcd_table[0])):  # M[u][v] + M[v][u] multiplies u v (u != v)
            pair_table[p][k] = abcd_table[4 * u + v][k] * (1 if u == v else 2)
    return _sparse_columns(_ABCD[name][0]), _sparse_columns(pair_table), _sparse_columns(matrix_table, offset)


_COLUMNWISE = {name: _columnwise_tables(name) for name in EULER_CONVENTIONS}


def _combine(columns, terms):
    total = None
    for r, k in terms[0]:
        term = columns[r] if k == 1 else (-columns[r] if k == -1 else columns[r] * k)
        total = term if total is None else total + term
    if total is None:  # an unused form (intrinsic conventions' lock columns)
        return terms[1]
    return total + terms[1] if terms[1] else total


def _angles_columnwise(forms, conv: EulerConvention, eps: float) -> Tensor:
    """The same angles as :func:`_angles_from_forms`, written column by column with the tables'
    numbers as literals: for large batches (a handful of passes over 1-D columns instead of
    strided pair tensors) and for ``torch.compile``, which fuses it into one vectorised loop."""
    f = forms
    two_h = safe_sqrt(f[0] * f[0] + f[1] * f[1])
    ab2, cd2 = f[10], f[11]
    near_zero = ab2 >= cd2
    locked = two_h <= torch.maximum(ab2, cd2) * (2.0 * math.tan(eps / 2.0))
    y1, x1 = f[0], f[1]
    if conv.intrinsic:
        y1, x1 = torch.where(locked, 0.0, y1), torch.where(locked, 1.0, x1)
    else:
        y1 = torch.where(locked, torch.where(near_zero, f[6], f[8]), y1)
        x1 = torch.where(locked, torch.where(near_zero, f[7], f[9]), x1)
    t1 = torch.atan2(y1, x1)
    middle = torch.atan2(two_h, f[12]) if conv.symmetric else torch.atan2(f[12], two_h)
    double = torch.atan2(torch.where(near_zero, f[2], f[4]), torch.where(near_zero, f[3], f[5]))
    tb = _forms_tables(conv.name)[3]
    t3 = double + torch.where(near_zero, -float(tb), float(tb)) * t1
    t3 = torch.where(t3 > math.pi, t3 - 2.0 * math.pi, torch.where(t3 < -math.pi, t3 + 2.0 * math.pi, t3))
    if conv.intrinsic:
        return torch.stack((t3, middle, t1), dim=-1)
    return torch.stack((t1, middle, torch.where(locked, 0.0, t3)), dim=-1)


@kernel
def quat_to_euler_unchecked(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    if not is_small(q, 4, share=0.25):  # crossover measured near 1000 rows
        abcd_terms, pair_terms, _ = _COLUMNWISE[convention.name]
        abcd = [_combine(q.unbind(-1), terms) for terms in abcd_terms]
        products = [abcd[u] * abcd[v] for u, v in _PAIRS]
        forms = [_combine(products, terms) for terms in pair_terms]
        # Every atan2 pair and the lock test are scale-invariant; only q = 0 (all forms 0) must
        # come out as NaN, not a plausible (0, 0, 0). Eager: one where on the result (13 fewer
        # passes); compiled: dividing by |abcd|^2 fuses for free, and a where on the result does not.
        if torch.compiler.is_compiling():
            inverse = 1.0 / forms[13]
            return _angles_columnwise([form * inverse for form in forms[:13]], convention, eps)
        angles = _angles_columnwise(forms, convention, eps)
        return torch.where((forms[13] == 0).unsqueeze(-1), torch.nan, angles)
    forms = _quat_forms(q, convention)
    # scale-invariant, so any |q| > 0 is fine; q = 0 gives 0 / 0 = NaN, not a plausible angle
    return _angles_from_forms(forms / forms.narrow(-1, 13, 1), convention, eps)


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


@kernel
def matrix_to_euler_unchecked(R: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    if not is_small(R, 9, share=0.125):  # crossover measured near 500 rows
        entries = R.flatten(-2).unbind(-1)
        return _angles_columnwise([_combine(entries, terms) for terms in _COLUMNWISE[convention.name][2]], convention, eps)
    return _angles_from_forms(_matrix_forms(R, convention), convention, eps)


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
    (for matrices) uses, so a ``True`` row is one whose third angle was set to 0. A matrix is
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
    x, _ = prepare(q, "euler_gimbal_lock", "q", (3, 3) if is_matrix else (4,))
    eps = gimbal_eps(x.dtype) if eps is None else float(eps)
    return _lock(_matrix_forms(x, conv) if is_matrix else _quat_forms(x, conv), eps)[1]
