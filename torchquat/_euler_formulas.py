"""Euler-angle formulas for all 24 conventions, each written once (see :mod:`torchquat._formulas`).

To angles: Bernardes and Viollet (2022), "Quaternion to Euler angles conversion: A direct, general
and computationally efficient method", PLoS ONE 17(11), as SciPy implements it. A permuted
quaternion ``(a, b, c, d)``, linear in ``q``, gives ``t1 = atan2(b, a) - atan2(d, c)``,
``t3 = atan2(b, a) + atan2(d, c)`` and the middle angle ``2 atan2(|(c, d)|, |(a, b)|)``. Each is
written here as an ``atan2`` of quadratic forms in ``(a, b, c, d)``, and quadratic forms of a unit
``q`` are linear in R's entries (Shepperd's ``4 q q^T``), so one formula serves quaternions and
matrices, the latter without a square root or a quaternion in between.

From angles: the product of the three elementary rotations, expanded with its zeros left out.
"""

import math

from ._formulas import OUTER, safe_sqrt, standardize
from .conventions import EULER_CONVENTIONS



def _permutation(name: str):
    """``(a, b, c, d)`` as coefficient dicts over ``(w, x, y, z)`` and the sign of the permutation
    (Bernardes and Viollet's extrinsic form; an intrinsic sequence is the reversed extrinsic one)."""
    conv = EULER_CONVENTIONS[name]
    i, j, k = conv.axes[::-1] if conv.intrinsic else conv.axes
    if conv.symmetric:
        k = 3 - i - j
    sign = (i - j) * (j - k) * (k - i) // 2  # +1 for an even permutation of xyz
    w, qi, qj, qk = 0, i + 1, j + 1, k + 1
    if conv.symmetric:
        abcd = ({w: 1}, {qi: 1}, {qj: 1}, {qk: sign})
    else:
        abcd = ({w: 1, qj: -1}, {qi: 1, qk: sign}, {qj: 1, w: 1}, {qk: sign, qi: -1})
    return abcd, sign


def _combine(coefficients, values):
    """``sum(c * values[i])`` over ``{i: c}``, with no product for a coefficient of +-1."""
    total = None
    for index, coefficient in coefficients.items():
        if coefficient == 0:
            continue
        term = values[index] if abs(coefficient) == 1 else float(abs(coefficient)) * values[index]
        if total is None:
            total = term if coefficient > 0 else -term
        else:
            total = total + term if coefficient > 0 else total - term
    return 0.0 if total is None else total


# The forms the angles read, as coefficients over products of (a, b, c, d): |ab|^2, |cd|^2, the pair
# of t1 = atan2(b, a) - atan2(d, c), and the double angles 2 atan2(b, a) and 2 atan2(d, c).
_FORMS = {"ab2": {"aa": 1, "bb": 1}, "cd2": {"cc": 1, "dd": 1}, "y1": {"bc": 1, "ad": -1}, "x1": {"ac": 1, "bd": 1},
          "day": {"ab": 2}, "dax": {"aa": 1, "bb": -1}, "dcy": {"cd": 2}, "dcx": {"cc": 1, "dd": -1}}


def forms_of_quat(name: str, q):
    """The forms from a quaternion's components (any norm: the angles are ratios)."""
    a, b, c, d = (_combine(coefficients, q) for coefficients in permutation(name)[0])
    aa, bb, cc, dd = a * a, b * b, c * c, d * d
    return {"ab2": aa + bb, "cd2": cc + dd, "y1": b * c - a * d, "x1": a * c + b * d,
            "day": 2.0 * (a * b), "dax": aa - bb, "dcy": 2.0 * (c * d), "dcx": cc - dd}


def _form_terms(name: str):
    """Each form as a linear function of R's entries (index -1: the constant), from
    ``q_u q_v = (4 q q^T)_uv / 4`` (the common factor 4 dropped: the angles are ratios). A few
    entries each, where the products they sum would take a dozen."""
    abcd = dict(zip("abcd", _permutation(name)[0]))
    terms = {}
    for form, products in _FORMS.items():
        total = {}
        for p, weight in products.items():
            for u, cu in abcd[p[0]].items():
                for v, cv in abcd[p[1]].items():
                    for sign, index in OUTER[(min(u, v), max(u, v))]:
                        total[index] = total.get(index, 0) + weight * cu * cv * sign
        terms[form] = {index: c for index, c in total.items() if c != 0}
    # a power of two common to every coefficient is dropped: the angles are ratios, and the lock test
    # compares two of the forms, so results are the same to the bit, with fewer products
    common = math.gcd(*(int(c) for form in terms.values() for c in form.values()))
    common &= -common
    return {name: {index: c // common for index, c in form.items()} for name, form in terms.items()}


# (tables built once at import, read as plain dicts: torch.compile traces through them as constants)
_PERMUTATIONS = {name: _permutation(name) for name in EULER_CONVENTIONS}
_MATRIX_FORMS = {name: _form_terms(name) for name in EULER_CONVENTIONS}


def permutation(name: str):
    return _PERMUTATIONS[name]


def forms_of_matrix(name: str, r):
    values = dict(enumerate(r))
    values[-1] = 1.0
    return {form: _combine(coefficients, values) for form, coefficients in _MATRIX_FORMS[name].items()}


def angles(m, f, name: str, lock_sine: float, degrees: bool):
    """Euler angles from the forms ``f`` (:func:`forms_of_quat` or :func:`forms_of_matrix`).

    Gimbal lock (middle angle within ``eps`` of 0 or pi) is ``sin(middle) <= lock_sine = sin(eps)``,
    tested as ``2 h <= lock_sine (|ab|^2 + |cd|^2)`` with ``h = |ab| |cd|``: no cancellation near the lock, so
    an exact lock is found in float32 too. There, as in SciPy, the third angle is 0 and the first
    carries the rotation. Elsewhere the third angle is formed from the well-conditioned double
    angle (``2 atan2(b, a)`` near 0, ``2 atan2(d, c)`` near pi) and the first, so the angles
    reproduce the rotation to rounding right up to the lock."""
    conv = EULER_CONVENTIONS[name]
    sign = 1 if conv.symmetric else permutation(name)[1]
    ab2, cd2, y1, x1, h2, lock = _lock_test(m, f, lock_sine)
    near0 = ab2 >= cd2
    z = ab2 - cd2
    middle = m.atan2(h2, z) if conv.symmetric else m.atan2(-z, h2)
    t1 = m.atan2(m.where(lock, 0.0, y1), m.where(lock, 1.0, x1))
    # the double angle of the larger pair (its norm is |ab|^2 or |cd|^2, the larger: never 0 / 0)
    double = m.atan2(m.where(near0, f["day"], f["dcy"]), m.where(near0, f["dax"], f["dcx"]))
    t3 = double + m.where(near0, -t1, t1)
    # into [-pi, pi] by 2 pi sign(t3) where |t3| > pi: products, not selections, whose adjoint would
    # pass through both sides (the sign keeps t3's dtype, where a comparison times a Python float
    # takes torch's default one; -0.0 becomes +0.0, as with every output below)
    t3 = t3 - (m.sign(t3) * (m.abs(t3) > math.pi)) * (2.0 * math.pi)
    at_lock = double if conv.intrinsic else m.where(near0, double, -double)
    if conv.intrinsic:  # (computed as the reversed extrinsic sequence: its first angle is the last)
        out = (m.where(lock, at_lock, t3) * float(sign), middle, m.where(lock, 0.0, t1))
    else:
        out = (m.where(lock, at_lock, t1), middle, m.where(lock, 0.0, t3) * float(sign))
    undefined = m.where(ab2 + cd2 > 0.0, 0.0, math.nan)  # (NaN for a zero quaternion; adding +0.0 leaves no -0.0)
    return tuple((angle * (180.0 / math.pi) if degrees else angle) + undefined for angle in out)


def _lock_test(m, f, lock_sine: float):
    """``|ab|^2``, ``|cd|^2``, ``t1``'s pair, ``2 h`` and the lock mask. ``h = |ab| |cd|`` is the norm
    of ``t1``'s pair: off-diagonal forms, small near the lock with small errors (from R, the
    product ``|ab|^2 |cd|^2`` carries the absolute rounding of ``1 + r00 + ...``: sqrt(eps) in h)."""
    ab2, cd2, y1, x1 = f["ab2"], f["cd2"], f["y1"], f["x1"]
    h2 = safe_sqrt(m, y1 * y1 + x1 * x1) * 2.0
    return ab2, cd2, y1, x1, h2, h2 <= lock_sine * (ab2 + cd2)


def lock(m, f, lock_sine: float):
    """The gimbal-lock test of :func:`angles` alone."""
    return _lock_test(m, f, lock_sine)[-1]


def quat_to_euler(m, w, x, y, z, name: str, lock_sine: float, degrees: bool):
    return angles(m, forms_of_quat(name, (w, x, y, z)), name, lock_sine, degrees)


def matrix_to_euler(m, *r, name: str, lock_sine: float, degrees: bool):
    return angles(m, forms_of_matrix(name, r), name, lock_sine, degrees)


# The Hamilton product's terms: output component -> (sign, i, j) for p_i q_j.
_PRODUCT_TERMS = (((1, 0, 0), (-1, 1, 1), (-1, 2, 2), (-1, 3, 3)),
                  ((1, 0, 1), (1, 1, 0), (1, 2, 3), (-1, 3, 2)),
                  ((1, 0, 2), (-1, 1, 3), (1, 2, 0), (1, 3, 1)),
                  ((1, 0, 3), (1, 1, 2), (-1, 2, 1), (1, 3, 0)))


def _sparse_sum(terms):
    """Sum of ``(sign, value)`` terms, ``None`` (zero) left out; ``None`` if all are zero."""
    total = None
    for sign, value in terms:
        if value is None:
            continue
        if total is None:
            total = value if sign > 0 else -value
        else:
            total = total + value if sign > 0 else total - value
    return total


def _times(a, b):
    """``a * b`` with ``None`` for a structural zero and a float 1.0 left out."""
    if a is None or b is None:
        return None
    if type(a) is float and a == 1.0:
        return b
    return a if type(b) is float and b == 1.0 else a * b


def _radians(m, angle, degrees: bool):
    """Degrees are first reduced modulo 360 by ``fmod``, which is exact: a large angle keeps its
    fraction of a turn, which the product alone would round away."""
    return m.fmod(angle, 360.0) * (math.pi / 180.0) if degrees else angle


def _elementary(m, axes, angle_values, degrees: bool):
    """The three elementary half-angle quaternions ``(cos, sin on the axis)`` in product order."""
    out = []
    for axis, angle in zip(axes, angle_values):
        half = _radians(m, angle, degrees) * 0.5
        q = [m.cos(half), None, None, None]
        q[axis + 1] = m.sin(half)
        out.append(q)
    return out


def euler_to_quat(m, a1, a2, a3, name: str, degrees: bool):
    """``q = q_1 q_2 q_3`` (intrinsic: body axes, in the order named) or ``q_3 q_2 q_1``
    (extrinsic: fixed axes), expanded with the elementary quaternions' zeros left out; ``w >= 0``."""
    conv = EULER_CONVENTIONS[name]
    factors = _elementary(m, conv.axes, (a1, a2, a3), degrees)
    if not conv.intrinsic:
        factors = factors[::-1]
    q = factors[0]
    for p in factors[1:]:
        q = [_sparse_sum((s, _times(q[i], p[j])) for s, i, j in terms) for terms in _PRODUCT_TERMS]
    return standardize(m, *(0.0 if c is None else c for c in q))


def _elementary_matrix(m, axis, angle):
    c, s = m.cos(angle), m.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R = [[None] * 3 for _ in range(3)]
    R[axis][axis] = 1.0
    R[i][i], R[j][j], R[i][j], R[j][i] = c, c, -s, s
    return R


def _matmul(A, B):
    return [[_sparse_sum((1, _times(A[i][k], B[k][j])) for k in range(3)) for j in range(3)] for i in range(3)]


def euler_to_matrix(m, a1, a2, a3, name: str, degrees: bool):
    """``R = R_1 R_2 R_3`` (intrinsic) or ``R_3 R_2 R_1`` (extrinsic), zeros and ones left out."""
    conv = EULER_CONVENTIONS[name]
    factors = [_elementary_matrix(m, axis, _radians(m, angle, degrees)) for axis, angle in zip(conv.axes, (a1, a2, a3))]
    if not conv.intrinsic:
        factors = factors[::-1]
    R = _matmul(_matmul(factors[0], factors[1]), factors[2])
    return tuple(0.0 if e is None else e for row in R for e in row)
