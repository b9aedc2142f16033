"""The rotation formulas, each written once, on components.

Every function takes a namespace ``m`` (:mod:`torchquat._backends`: Python floats or tensor
columns) and the components of its inputs (a quaternion ``w, x, y, z``; a matrix's 9 entries
row-major; a vector's 3), and returns a tuple of output components. The dispatcher runs the same
function on one rotation's floats, on an eager batch's columns and inside ``torch.compile``.
Branches are selections (``m.where``); the side not taken gets a safe substitute so that its
gradient is finite.
"""

import math

# Below these, a series replaces a ratio whose numerator and denominator both vanish. Each series is
# cut after the term whose successor is below 1e-17 relative at the bound (double precision), and
# written in Horner form with reciprocal constants: it is evaluated on every row, and a division
# takes several products' time in a vectorised loop.
SMALL_ANGLE_SQUARED = 1e-4   # theta^2 for sin(theta / 2) / theta and cos(theta / 2)
SMALL_RATIO_SQUARED = 1e-8   # (|v| / w)^2 for atan(|v| / w) / |v|
SMALL_CHORD_ANGLE_SQUARED = 1e-6  # |p - q|^2 for slerp's sin(f theta) / sin(theta)


def safe_sqrt(m, s):
    """``sqrt(s)`` with a zero gradient (not inf) at ``s = 0`` (and 0 for NaN): the square root of
    a safe substitute, times the condition (a product costs less than a second selection)."""
    positive = s > 0
    return m.sqrt(m.where(positive, s, 1.0)) * positive


def standardize(m, w, x, y, z):
    """``q`` or ``-q``: ``w > 0``, or ``w == 0`` and the first non-zero of ``x, y, z`` positive.

    The first non-zero component is negative when ``w < 0``, or ``w <= 0`` (so ``w == 0``) and the
    same holds of ``x, y, z``: comparisons only (NaN compares false and is kept)."""
    negative = (w < 0.0) | ((w <= 0.0) & ((x < 0.0) | ((x <= 0.0) & ((y < 0.0) | ((y <= 0.0) & (z < 0.0))))))
    s = m.where(negative, -1.0, 1.0)
    return w * s, x * s, y * s, z * s


def multiply(m, pw, px, py, pz, qw, qx, qy, qz):
    """Hamilton product ``p q`` (``ij = k``)."""
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


def rotate(m, w, x, y, z, a, b, c):
    """``q (0, v) q*`` for ``q / |q|``, as ``t = 2 q_vec x v / |q|^2; v + w t + q_vec x t``."""
    s = 2.0 / (w * w + x * x + y * y + z * z)
    tx, ty, tz = (y * c - z * b) * s, (z * a - x * c) * s, (x * b - y * a) * s
    return (a + w * tx + (y * tz - z * ty),
            b + w * ty + (z * tx - x * tz),
            c + w * tz + (x * ty - y * tx))


def quat_to_matrix(m, w, x, y, z):
    """The homogeneous form divided by ``|q|^2``: the rotation of ``q / |q|``, orthogonal for any
    norm, NaN for ``q = 0``."""
    s = 2.0 / (w * w + x * x + y * y + z * z)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return (1.0 - (yy + zz), xy - wz, xz + wy,
            xy + wz, 1.0 - (xx + zz), yz - wx,
            xz - wy, yz + wx, 1.0 - (xx + yy))


# Shepperd (1978): the rows of 4 q q^T, each a linear function of R, as (coefficient, entry) terms;
# entry -1 is the constant 1. Row k is exact to rounding when 4 q_k^2 (its k-th entry) is largest.
_R = {name: i for i, name in enumerate(("r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22"))}


def _terms(text):
    """``"1 + r00 - r11"`` -> ``((1, -1), (1, 0), (-1, 4))``."""
    out, sign = [], 1
    for token in text.split():
        if token in "+-":
            sign = 1 if token == "+" else -1
        else:
            out.append((sign, -1 if token == "1" else _R[token]))
    return tuple(out)


def _linear(r, terms):
    total = None
    for coefficient, index in terms:
        value = 1.0 if index < 0 else r[index]
        total = (value if coefficient > 0 else -value) if total is None else \
            (total + value if coefficient > 0 else total - value)
    return total


OUTER = {  # (i, j) -> 4 q_i q_j, for i <= j, in R's entries
    (0, 0): _terms("1 + r00 + r11 + r22"), (1, 1): _terms("1 + r00 - r11 - r22"),
    (2, 2): _terms("1 - r00 + r11 - r22"), (3, 3): _terms("1 - r00 - r11 + r22"),
    (0, 1): _terms("r21 - r12"), (0, 2): _terms("r02 - r20"), (0, 3): _terms("r10 - r01"),
    (1, 2): _terms("r10 + r01"), (1, 3): _terms("r02 + r20"), (2, 3): _terms("r21 + r12"),
}


def outer_entry(r, i, j):
    """``4 q_i q_j`` of the unit quaternion of ``R`` (entries ``r``), linear in ``r``."""
    return _linear(r, OUTER[(min(i, j), max(i, j))])


def matrix_to_quat(m, *r):
    """Shepperd's method, branch-free: the row ``4 q_k q`` with the largest ``4 q_k^2`` (at least
    1, so its normalisation loses nothing, unlike the trace formula near 180 degrees), normalised
    and standardised (``w >= 0``). The first largest wins, as ``argmax``'s."""
    rows = [[outer_entry(r, k, j) for j in range(4)] for k in range(4)]
    best, row = rows[0][0], rows[0]
    for k in range(1, 4):
        take = rows[k][k] > best
        best = m.where(take, rows[k][k], best)
        row = [m.where(take, new, old) for new, old in zip(rows[k], row)]
    w, x, y, z = standardize(m, *row)
    scale = 1.0 / m.sqrt(w * w + x * x + y * y + z * z)
    return w * scale, x * scale, y * scale, z * scale


def axis_angle_to_quat(m, a, b, c):
    """``(cos(theta / 2), sin(theta / 2) v / theta)``, ``theta = |v|``, standardised; series of
    both factors in ``theta^2`` near 0, where the ratio is 0 / 0."""
    s = a * a + b * b + c * c
    small = s < SMALL_ANGLE_SQUARED
    half = 0.5 * m.sqrt(m.where(small, 1.0, s))
    w = m.where(small, 1.0 - s * (1.0 / 8.0 - s * (1.0 / 384.0)), m.cos(half))
    k = m.where(small, 0.5 - s * (1.0 / 48.0 - s * (1.0 / 3840.0)), m.sin(half) / m.where(small, 1.0, half + half))
    # standardised: w = cos(theta / 2) is never exactly 0 (no float is an odd multiple of pi / 2, and
    # the series is near 1), so the sign to take is w's own and standardize's tie-break cannot arise
    k = k * m.sign(w)
    return m.abs(w), a * k, b * k, c * k


def quat_to_axis_angle(m, w, x, y, z):
    """The shortest arc: ``v = 2 atan2(|u|, |w|) u / |u|`` of ``+-q`` with ``w >= 0``, angle in
    ``[0, pi]``; a series in ``(|u| / w)^2`` near the identity."""
    flip = m.where(w < 0, -1.0, 1.0)
    w, x, y, z = w * flip, x * flip, y * flip, z * flip
    n2 = x * x + y * y + z * z
    small = n2 < SMALL_RATIO_SQUARED * (w * w)
    n = m.sqrt(m.where(small, 1.0, n2))
    w_safe = m.where(small, w, 1.0)
    t2 = n2 / (w_safe * w_safe)
    k = m.where(small, (2.0 - t2 * (2.0 / 3.0)) / w_safe, 2.0 * m.atan2(n, w) / n)
    return x * k, y * k, z * k


def axis_angle_to_matrix(m, a, b, c):
    return quat_to_matrix(m, *axis_angle_to_quat(m, a, b, c))


def matrix_to_axis_angle(m, *r):
    return quat_to_axis_angle(m, *matrix_to_quat(m, *r))


def rot6d_to_matrix(m, a0, a1, a2, b0, b1, b2, noise: float):
    """Gram-Schmidt on the two columns (Zhou et al. 2019); the third column is their cross product.
    Zero or collinear columns give NaN, never a plausible rotation: collinear to rounding means
    that what is left of the second column is below ``noise`` (``16 eps``) times its norm, so
    its direction would be rounding noise."""
    inv = 1.0 / m.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    e0, e1, e2 = a0 * inv, a1 * inv, a2 * inv
    dot = e0 * b0 + e1 * b1 + e2 * b2
    u0, u1, u2 = b0 - dot * e0, b1 - dot * e1, b2 - dot * e2
    n2 = u0 * u0 + u1 * u1 + u2 * u2
    valid = m.where(n2 > (noise * noise) * (b0 * b0 + b1 * b1 + b2 * b2), 1.0, math.nan)
    inv = valid / m.sqrt(n2)
    e0, e1, e2 = e0 * valid, e1 * valid, e2 * valid
    f0, f1, f2 = u0 * inv, u1 * inv, u2 * inv
    g0, g1, g2 = e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0
    return e0, f0, g0, e1, f1, g1, e2, f2, g2


def quat_distance(m, pw, px, py, pz, qw, qx, qy, qz):
    """The angle between the rotations of ``p`` and ``q``: twice the angle between the lines of
    ``p`` and ``q`` in 4D, ``2 atan2(|p ^ q|, |<p, q>|)``, where ``|p ^ q|^2`` sums the squares
    of the six ``p_i q_j - p_j q_i`` (Lagrange: ``|p|^2 |q|^2 = <p, q>^2 + |p ^ q|^2``). Both
    arguments scale alike, so neither input is normalised; each is accurate in absolute terms at
    0 and pi (no ``acos``, no ``1 - c^2``) and sign-invariant; equal or opposite inputs give an
    exact 0 and a zero (finite) gradient; a zero quaternion gives NaN."""
    dot = pw * qw + px * qx + py * qy + pz * qz
    wx, wy, wz = pw * qx - px * qw, pw * qy - py * qw, pw * qz - pz * qw
    yz, zx, xy = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
    wedge = wx * wx + wy * wy + wz * wz + yz * yz + zx * zx + xy * xy
    undefined = m.where(wedge + dot * dot > 0.0, 0.0, math.nan)  # (a zero input; +0.0 leaves no -0.0)
    return (2.0 * m.atan2(safe_sqrt(m, wedge), m.abs(dot)) + undefined,)


def matrix_distance(m, a00, a01, a02, a10, a11, a12, a20, a21, a22, b00, b01, b02, b10, b11, b12, b20, b21, b22):
    """The angle of ``A^T B``: ``atan2(|u|, tr - 1)`` with ``u`` the axis of its skew part
    (``|u| = 2 sin theta``, ``tr - 1 = 2 cos theta``): accurate at 0 and pi, unlike ``acos``."""
    trace = (a00 * b00 + a10 * b10 + a20 * b20) + (a01 * b01 + a11 * b11 + a21 * b21) + (a02 * b02 + a12 * b12 + a22 * b22)
    u0 = (a01 * b02 + a11 * b12 + a21 * b22) - (a02 * b01 + a12 * b11 + a22 * b21)
    u1 = (a02 * b00 + a12 * b10 + a22 * b20) - (a00 * b02 + a10 * b12 + a20 * b22)
    u2 = (a00 * b01 + a10 * b11 + a20 * b21) - (a01 * b00 + a11 * b10 + a21 * b20)
    return (m.atan2(safe_sqrt(m, u0 * u0 + u1 * u1 + u2 * u2), trace - 1.0),)


def slerp(m, pw, px, py, pz, qw, qx, qy, qz, t, tie: float):
    """Shoemake's slerp on the shorter arc between ``p / |p|`` and ``+-q / |q|``.

    ``q`` is negated where ``<p, q> < -tie`` (unit inputs; ``tie = 8 eps``): within rounding of 0
    both arcs are equally short, and ``q`` is kept on every path. The angle is
    ``2 atan2(|p - q|, |p + q|)`` (chords: accurate at 0 and pi); near 0 its square is the series
    ``d^2 + d^4 / 12`` in the chord ``d`` and the weights ``sin((1 - t) theta) / sin theta`` and
    ``sin(t theta) / sin theta`` are their series in ``theta^2``, so that derivatives of every order
    are finite and continuous at ``p = q``."""
    ip = 1.0 / m.sqrt(pw * pw + px * px + py * py + pz * pz)
    iq = 1.0 / m.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    iq = m.where((pw * qw + px * qx + py * qy + pz * qz) * (ip * iq) < -tie, -iq, iq)
    pw, px, py, pz = pw * ip, px * ip, py * ip, pz * ip
    qw, qx, qy, qz = qw * iq, qx * iq, qy * iq, qz * iq
    dw, dx, dy, dz = pw - qw, px - qx, py - qy, pz - qz
    sw, sx, sy, sz = pw + qw, px + qx, py + qy, pz + qz
    d2 = dw * dw + dx * dx + dy * dy + dz * dz
    small = d2 < SMALL_CHORD_ANGLE_SQUARED
    angle = 2.0 * m.atan2(m.sqrt(m.where(small, 1.0, d2)), m.sqrt(sw * sw + sx * sx + sy * sy + sz * sz))
    a2 = d2 * (1.0 + d2 * (1.0 / 12.0))  # (4 asin(d / 2)^2, used where small)
    sine = m.sin(angle)
    u = 1.0 - t

    def weight(f):  # sin(f theta) / sin(theta) = f (1 + (1 - f^2) theta^2 / 6 + ...)
        f2 = f * f
        series = f * (1.0 + a2 * ((1.0 - f2) * (1.0 / 6.0) + (7.0 - f2 * (10.0 - 3.0 * f2)) * a2 * (1.0 / 360.0)))
        return m.where(small, series, m.sin(f * angle) / sine)

    k0, k1 = weight(u), weight(t)
    return pw * k0 + qw * k1, px * k0 + qx * k1, py * k0 + qy * k1, pz * k0 + qz * k1
