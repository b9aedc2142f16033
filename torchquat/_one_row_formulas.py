"""The kernels' formulas for one row, in Python floats (see ``torchquat._one_row``).

Each takes flat lists of floats (a matrix row-major) and the input's ``dtype`` (for the dtype's
own thresholds), and returns a flat list or one float. They read the tensor kernels' tables, so
that the choices are the same: Shepperd's rows, Bernardes and Viollet's forms and the Euler sign
tables.
"""

import math

import torch

from ._euler_forms import ABCD, forms_tables
from ._euler_rotations import _SIGN_TABLES
from ._euler_small import _TABLES as _EULER_LAYOUT_TABLES
from .conventions import EULER_CONVENTIONS, EulerConvention

_EPS = {torch.float32: torch.finfo(torch.float32).eps, torch.float64: torch.finfo(torch.float64).eps}
_atan2, _copysign, _cos, _hypot, _sin, _sqrt = math.atan2, math.copysign, math.cos, math.hypot, math.sin, math.sqrt
_PI, _MINUS_TWO_PI = math.pi, -2.0 * math.pi


# -- quaternions and matrices ----------------------------------------------------------------------

def _sign_of_first_nonzero(q) -> float:
    """The canonical sign (``torchquat.quaternion.standardize_sign``): that of ``w``, or of the first
    non-zero of ``x, y, z`` where ``w == 0`` (``-0.0`` counts as 0)."""
    for c in q:
        if c:
            return -1.0 if c < 0.0 else 1.0
    return 1.0


def quat_to_matrix(q, dtype=None):
    w, x, y, z = q
    s = 2.0 / (w * w + x * x + y * y + z * z)  # (q = 0: ZeroDivisionError, the kernel's NaN)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz, xx, xy, xz, yy, yz, zz = w * xs, w * ys, w * zs, x * xs, x * ys, x * zs, y * ys, y * zs, z * zs
    return [1.0 - (yy + zz), xy - wz, xz + wy,
            xy + wz, 1.0 - (xx + zz), yz - wx,
            xz - wy, yz + wx, 1.0 - (xx + yy)]


def _shepperd_row(R):
    """Shepperd (1978): the largest of 4w^2, 4x^2, 4y^2, 4z^2 (the first of equals, as argmax) picks
    the row of 4 q q^T to normalise (torchquat.matrix's table, written out). Returns its index, the
    row and the factor ``sign / |row|`` that makes it the canonical unit quaternion."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R
    t0, t1, t2, t3 = 1.0 + (r00 + r11 + r22), 1.0 + (r00 - r11 - r22), 1.0 + (r11 - r00 - r22), 1.0 + (r22 - r00 - r11)
    if t0 >= t1 and t0 >= t2 and t0 >= t3:
        best, row = 0, (t0, r21 - r12, r02 - r20, r10 - r01)
    elif t1 >= t2 and t1 >= t3:
        best, row = 1, (r21 - r12, t1, r10 + r01, r02 + r20)
    elif t2 >= t3:
        best, row = 2, (r02 - r20, r10 + r01, t2, r21 + r12)
    else:
        best, row = 3, (r10 - r01, r02 + r20, r21 + r12, t3)
    a, b, c, d = row
    return best, row, _sign_of_first_nonzero(row) / _sqrt(a * a + b * b + c * c + d * d)


def matrix_to_quat(R, dtype=None):
    _, row, scale = _shepperd_row(R)
    return [c * scale for c in row]


def hamilton_product(p, q, dtype=None):
    a, b, c, d = p
    w, x, y, z = q
    return [a * w - b * x - c * y - d * z,
            a * x + b * w + c * z - d * y,
            a * y - b * z + c * w + d * x,
            a * z + b * y - c * x + d * w]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def rotate(q, v, dtype=None):
    # t = 2 (u x v) / |q|^2, v' = v + w t + u x t (the rotation of q / |q|)
    w, u = q[0], q[1:]
    scale = 2.0 / (w * w + u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    t = [c * scale for c in _cross(u, v)]
    ut = _cross(u, t)
    return [v[i] + w * t[i] + ut[i] for i in range(3)]


# -- axis-angle ----------------------------------------------------------------------------------

def _axis_angle_quat(v):
    """``(cos x, h sin(x) / x)``, ``h = v / 2``, ``x = |h|`` (1 for ``sin(x) / x`` at ``x = 0``), with
    ``w >= 0`` by ``cos x``'s sign, as the kernel's values."""
    h = [0.5 * c for c in v]
    x = _hypot(*h)
    s = _sin(x) / x if x else 1.0
    w = _cos(x)
    sign = _copysign(1.0, w)
    return [w * sign, h[0] * s * sign, h[1] * s * sign, h[2] * s * sign]


def axis_angle_to_quat(v, dtype=None):
    return _axis_angle_quat(v)


def quat_to_axis_angle(q, dtype=None):
    # v = m u with m = 2 sign(w) atan2(|u|, |w|) / |u|, or its limit 2 sign(w) / |w| at u = 0
    # (in double, atan2(n, w) / n is accurate for any n > 0: no series is needed)
    w0, u = q[0], q[1:]
    w, n = abs(w0), _hypot(*u)
    m = _copysign(2.0, w0) * (_atan2(n, w) / n if n else 1.0 / w)
    return [c * m for c in u]


def axis_angle_to_matrix(v, dtype=None):
    return quat_to_matrix(_axis_angle_quat(v))


def matrix_to_axis_angle(R, dtype=None):
    return quat_to_axis_angle(matrix_to_quat(R))


# -- 6D and distances ----------------------------------------------------------------------------

def rot6d_to_matrix(x, dtype=None):
    # Gram-Schmidt on the two columns (Zhou et al. 2019); NaN where the second is collinear with the
    # first to rounding (its remainder under 16 eps of its norm, eps the input dtype's)
    a1, a2 = x[:3], x[3:]
    r1 = _hypot(*a1)
    b1 = [c / r1 for c in a1]
    d = b1[0] * a2[0] + b1[1] * a2[1] + b1[2] * a2[2]
    b2 = [a2[i] - d * b1[i] for i in range(3)]
    n = _hypot(*b2)
    if not n > _hypot(*a2) * (16.0 * _EPS[dtype]):
        return [math.nan] * 9
    b2 = [c / n for c in b2]
    b3 = _cross(b1, b2)
    return [b1[0], b2[0], b3[0], b1[1], b2[1], b3[1], b1[2], b2[2], b3[2]]


def _quat_distance_parts(a, b):
    """``<a, b>`` and the six minors ``a_i b_j - a_j b_i`` (``i < j``): float32 inputs' products are
    exact in double, so each is rounded once."""
    a0, a1, a2, a3 = a
    b0, b1, b2, b3 = b
    return (a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3, a0 * b1 - a1 * b0, a0 * b2 - a2 * b0, a0 * b3 - a3 * b0,
            a1 * b2 - a2 * b1, a1 * b3 - a3 * b1, a2 * b3 - a3 * b2)


def quat_geodesic_distance(q1, q2, dtype=None):
    # 2 atan2(|q1 ^ q2|, |<q1, q2>|) by Lagrange's identity (the large batches' form)
    dot, *minors = _quat_distance_parts(q1, q2)
    wedge = _hypot(*minors)
    if not (wedge or dot):  # a zero quaternion: NaN, as the kernel's
        return math.nan
    return 2.0 * _atan2(wedge, abs(dot))


def _matrix_distance_parts(R1, R2):
    """``vee(M - M^T) = sum_k R1[:, k] x (R2 - R1)[:, k]`` (exactly 0 for equal inputs) and
    ``tr M - 1 = sum(R1 * R2) - 1`` for ``M = R1^T R2``."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = R1
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = R2
    d00, d01, d02, d10, d11, d12, d20, d21, d22 = (b00 - a00, b01 - a01, b02 - a02, b10 - a10, b11 - a11,
                                                   b12 - a12, b20 - a20, b21 - a21, b22 - a22)
    v0 = (a10 * d20 - a20 * d10) + (a11 * d21 - a21 * d11) + (a12 * d22 - a22 * d12)
    v1 = (a20 * d00 - a00 * d20) + (a21 * d01 - a01 * d21) + (a22 * d02 - a02 * d22)
    v2 = (a00 * d10 - a10 * d00) + (a01 * d11 - a11 * d01) + (a02 * d12 - a12 * d02)
    trace = (a00 * b00 + a01 * b01 + a02 * b02) + (a10 * b10 + a11 * b11 + a12 * b12) + (a20 * b20 + a21 * b21 + a22 * b22)
    return v0, v1, v2, trace - 1.0


def matrix_geodesic_distance(R1, R2, dtype=None):
    # atan2(|vee(M - M^T)|, tr M - 1): both keep full precision at 0 and pi
    v0, v1, v2, cosine = _matrix_distance_parts(R1, R2)
    return _atan2(_hypot(v0, v1, v2), cosine)


# -- Euler angles --------------------------------------------------------------------------------

def _euler_constants(name: str):
    """Bernardes and Viollet's permuted quaternion ``(a, b, c, d) = q P`` as ``(index, coefficient)``
    pairs per component (one or two each; ``torchquat._euler_forms.abcd_table``), the Tait-Bryan
    sign ``tb`` of the double angles, ``Z``'s sign, and t3's flip near middle 0 and near pi
    (``t3 = D - flip t1``, flip = ``tb`` near 0, ``-tb`` near pi: ``torchquat._euler_small._FLIPS``)."""
    table, _ = ABCD[name]
    components = []
    for u in range(4):
        terms = [(i, table[i][u]) for i in range(4) if table[i][u]] + [(0, 0.0)]
        components.append((*terms[0], *terms[1]))  # (i0, c0, i1, c1): c0 q[i0] + c1 q[i1]
    symmetric = EULER_CONVENTIONS[name].symmetric
    tb = float(forms_tables(name)[3])
    return tuple(components), tb, 1.0 if symmetric else -1.0, (tb, -tb)


_EULER = {name: _euler_constants(name) for name in EULER_CONVENTIONS}


def _quat_layout(q, conv: EulerConvention):
    """The small kernels' layout of Bernardes and Viollet's forms of ``q`` (any non-zero scale;
    ``torchquat._euler_small``: ``t1``'s pair times 2, the double angles negated, so that their
    ``atan2`` is shifted by pi, and ``Z``), ``t1``'s pair and ``Z`` divided by ``|abcd|^2``; and
    ``(a, b, c, d)`` and ``1 / |abcd|^2`` for the gradient."""
    ((i0, c0, i1, c1), (j0, e0, j1, e1), (k0, f0, k1, f1), (l0, g0, l1, g1)), tb, z_sign, _ = _EULER[conv.name]
    a, b, c, d = (c0 * q[i0] + c1 * q[i1], e0 * q[j0] + e1 * q[j1], f0 * q[k0] + f1 * q[k1], g0 * q[l0] + g1 * q[l1])
    aa, bb, cc, dd = a * a, b * b, c * c, d * d
    scale = 1.0 / ((aa + bb) + (cc + dd))  # (q = 0: ZeroDivisionError, the kernel's NaN)
    # (+ 0.0: a zero form is +0, as the kernels' sums give it; atan2(-0.0, -1) would be -pi)
    return ((2.0 * (b * c - a * d) * scale + 0.0, 2.0 * (a * c + b * d) * scale, -2.0 * tb * a * b + 0.0, bb - aa,
             -2.0 * tb * c * d + 0.0, dd - cc, z_sign * ((aa + bb) - (cc + dd)) * scale + 0.0), (a, b, c, d), scale)


def _layout_choices(y0, x0, z, conv: EulerConvention, eps: float):
    """``2h`` (the middle angle's sine), the lock test, which double angle is taken (middle near 0) and
    t3's flip: the choices of the values and of the gradient."""
    two_h = _hypot(y0, x0)
    near_zero = z >= 0.0 if conv.symmetric else z <= 0.0
    return two_h, two_h <= _sin(eps), near_zero, _EULER[conv.name][3][0 if near_zero else 1]


def _layout_angles(y0, x0, y1, x1, y2, x2, z, conv: EulerConvention, eps: float):
    """The angles from the layout's pairs (the double angles' up to scale), as the small kernels'
    values path (``torchquat._euler_small._angles``)."""
    two_h, locked, near_zero, flip = _layout_choices(y0, x0, z, conv, eps)
    t1 = 0.0 if locked else _atan2(y0, x0)
    double = _atan2(y1, x1) if near_zero else _atan2(y2, x2)  # (scale-free)
    middle = _atan2(two_h, z) if conv.symmetric else _atan2(z, two_h)
    shifted = double - t1 * flip
    if locked and not conv.intrinsic:  # SciPy's rule: the rotation in the first angle
        shifted = shifted * flip
    t3 = shifted % _MINUS_TWO_PI + _PI  # into (-pi, pi]: an exact half turn is +pi
    if conv.intrinsic:
        return [t3, middle, t1]
    return [t3, middle, 0.0] if locked else [t1, middle, t3]


def quat_to_euler(q, dtype=None, *, convention: EulerConvention, eps: float):
    return _layout_angles(*_quat_layout(q, convention)[0], convention, eps)


def _matrix_layout_terms(name: str):
    """The layout's 7 entries as linear forms of R (``torchquat._euler_small._TABLES``: scaled so that
    ``|abcd|^2 = 1``): ``(offset, ((entry, coefficient), ...))`` each."""
    _, matrix, offset = _EULER_LAYOUT_TABLES[name][:3]
    return tuple((offset[c], tuple((r, matrix[r][c]) for r in range(9) if matrix[r][c])) for c in range(7))


_MATRIX_LAYOUT = {name: _matrix_layout_terms(name) for name in EULER_CONVENTIONS}


def _matrix_layout(R, convention: EulerConvention):
    """The layout's 7 entries, linear in R as the kernel's (the same angles for any input, a rotation
    or not)."""
    forms = []
    for total, terms in _MATRIX_LAYOUT[convention.name]:
        for r, coefficient in terms:
            total += coefficient * R[r]
        forms.append(total)
    return forms


def matrix_to_euler(R, dtype=None, *, convention: EulerConvention, eps: float):
    return _layout_angles(*_matrix_layout(R, convention), convention, eps)


_EULER_SIGNS = {name: tuple((next(k for k in range(4) if row[k]), float(sum(row))) for row in table)
                for name, table in _SIGN_TABLES.items()}  # each row a signed basis quaternion


def _euler_quat(angles, convention: EulerConvention):
    # the product of the three half-angle rotations: 8 products of cosines and sines, each onto a
    # signed basis quaternion (row m = 4 m1 + 2 m2 + m3 takes the sine of angle n where bit m_n is 1)
    f = [(_cos(0.5 * a), _sin(0.5 * a)) for a in angles]
    q = [0.0, 0.0, 0.0, 0.0]
    for m, (k, sign) in enumerate(_EULER_SIGNS[convention.name]):
        q[k] += sign * f[0][m >> 2] * f[1][(m >> 1) & 1] * f[2][m & 1]
    sign = _copysign(1.0, q[0])  # w >= 0, by w's sign alone (as the kernel)
    return [c * sign for c in q]


def euler_to_quat(angles, dtype=None, *, convention: EulerConvention):
    return _euler_quat(angles, convention)


def euler_to_matrix(angles, dtype=None, *, convention: EulerConvention):
    return quat_to_matrix(_euler_quat(angles, convention))


# -- slerp -----------------------------------------------------------------------------------------

def _slerp_parts(q0, q1, t, dtype):
    """torchquat.slerp's rows: the normalised inputs, q1 negated where ``<p, q> < -8 eps`` (the arcs
    equally short to rounding below that), the angle ``2 atan2(|p - q|, |p + q|)``, and below a
    chord^2 of sqrt(eps) the weights' series in ``a^2 = c^2 + c^4 / 12`` (eps the input dtype's, as
    the kernel's). Returns the output and what the gradient needs."""
    eps = _EPS[dtype]
    n0 = 1.0 / _sqrt(q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] + q0[3] * q0[3])
    n1 = 1.0 / _sqrt(q1[0] * q1[0] + q1[1] * q1[1] + q1[2] * q1[2] + q1[3] * q1[3])
    p = [c * n0 for c in q0]
    q = [c * n1 for c in q1]
    if p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3] < -8.0 * eps:
        q, n1 = [-c for c in q], -n1
    square = sum((a - b) * (a - b) for a, b in zip(p, q))
    times = (1.0 - t[0], t[0])
    small = square < eps ** 0.5
    angle2 = square + square * square / 12.0
    angle = sine = 1.0
    if small:
        w = [x + x * (1.0 - x * x) * angle2 * (1.0 / 6.0 + (4.0 + 3.0 * (1.0 - x * x)) * angle2 / 360.0) for x in times]
    else:
        angle = 2.0 * _atan2(_sqrt(square), _hypot(*(a + b for a, b in zip(p, q))))
        sine = _sin(angle)
        w = [_sin(x * angle) / sine for x in times]
    return [w[0] * a + w[1] * b for a, b in zip(p, q)], (p, q, n0, n1, square, small, angle, sine, angle2, times, w)


def quat_slerp(q0, q1, t, dtype=None):
    return _slerp_parts(q0, q1, t, dtype)[0]
