"""The one-row formulas' vector-Jacobian products, in Python floats (see ``torchquat._one_row``).

Each ``name_vjp`` returns the formula's output (``torchquat._one_row_formulas.name``'s) and a
function of the output's gradient (a flat list) returning one flat list per input: the derivatives
of the tensor kernels' closed-form backward passes (``torchquat._closed_form``'s rules), with their
choices at the kinks (0 where a norm is 0, at distance 0, and for the pair or angle a lock or a
branch discards).
"""

from ._one_row import Fallback
from ._one_row_formulas import (_EULER, _EULER_SIGNS, _MATRIX_LAYOUT, _atan2, _copysign, _cos, _cross, _hypot,
                                _layout_angles, _layout_choices, _matrix_distance_parts, _matrix_layout,
                                _quat_distance_parts, _quat_layout, _shepperd_row, _sin, _slerp_parts,
                                hamilton_product, quat_to_matrix, rot6d_to_matrix, rotate)
from .conventions import EulerConvention

def _quat_to_matrix_pullback(q, R):
    """``g`` (9 entries) -> its gradient on ``q`` through ``R = N(q) / |q|^2`` (N the homogeneous
    form): ``(dN^T g - 2 q <g, R>) / |q|^2``."""
    w, x, y, z = q
    inverse = 1.0 / (w * w + x * x + y * y + z * z)

    def pullback(g):
        g00, g01, g02, g10, g11, g12, g20, g21, g22 = g
        along = 2.0 * sum(a * b for a, b in zip(g, R))
        return [(2.0 * (w * (g00 + g11 + g22) + z * (g10 - g01) + y * (g02 - g20) + x * (g21 - g12)) - w * along) * inverse,
                (2.0 * (x * (g00 - g11 - g22) + y * (g01 + g10) + z * (g02 + g20) + w * (g21 - g12)) - x * along) * inverse,
                (2.0 * (y * (g11 - g00 - g22) + x * (g01 + g10) + w * (g02 - g20) + z * (g12 + g21)) - y * along) * inverse,
                (2.0 * (z * (g22 - g00 - g11) + w * (g10 - g01) + x * (g02 + g20) + y * (g12 + g21)) - z * along) * inverse]

    return pullback


def quat_to_matrix_vjp(q, dtype=None):
    R = quat_to_matrix(q)
    pullback = _quat_to_matrix_pullback(q, R)
    return R, lambda g: (pullback(g),)


def _matrix_to_quat_with_pullback(R):
    """Shepperd's quaternion and ``g`` (4) -> its gradient on R: ``q = row / |row|`` (signed), so
    ``d q = (d row - q <q, d row>) / |row|``, and the chosen row is linear in R."""
    best, row, scale = _shepperd_row(R)
    q = [c * scale for c in row]

    def pullback(g):
        along = sum(x * y for x, y in zip(q, g))
        g0, g1, g2, g3 = ((gi - qi * along) * scale for gi, qi in zip(g, q))
        if best == 0:  # row (1 + r00 + r11 + r22, r21 - r12, r02 - r20, r10 - r01)
            return [g0, -g3, g2, g3, g0, -g1, -g2, g1, g0]
        if best == 1:  # (r21 - r12, 1 + r00 - r11 - r22, r10 + r01, r02 + r20)
            return [g1, g2, g3, g2, -g1, -g0, g3, g0, -g1]
        if best == 2:  # (r02 - r20, r10 + r01, 1 + r11 - r00 - r22, r21 + r12)
            return [-g2, g1, g0, g1, g2, g3, -g0, g3, -g2]
        return [-g3, -g0, g1, g0, -g3, g2, g1, g2, g3]  # (r10 - r01, r02 + r20, r21 + r12, 1 + r22 - r00 - r11)

    return q, pullback


def matrix_to_quat_vjp(R, dtype=None):
    q, pullback = _matrix_to_quat_with_pullback(R)
    return q, lambda g: (pullback(g),)


def _conjugate(q):
    return [q[0], -q[1], -q[2], -q[3]]


def hamilton_product_vjp(p, q, dtype=None):
    # <g, p q> = <g q*, p> = <p* g, q>
    return hamilton_product(p, q), lambda g: (hamilton_product(g, _conjugate(q)), hamilton_product(_conjugate(p), g))


def rotate_vjp(q, v, dtype=None):
    # v' = R(q / |q|) v: the gradient on v is R^T g, on q that of R against g v^T
    R = quat_to_matrix(q)
    pullback = _quat_to_matrix_pullback(q, R)

    def vjp(g):
        g_v = [R[j] * g[0] + R[3 + j] * g[1] + R[6 + j] * g[2] for j in range(3)]
        return pullback([g[i] * v[j] for i in range(3) for j in range(3)]), g_v

    return rotate(q, v), vjp


def _axis_angle_quat_with_pullback(v):
    # q = sign (cos x, s h), h = v / 2, x = |h|, s = sin(x) / x: dq_w / dv_i = -s h_i / 2 and
    # dq_j / dv_i = (s delta_ij + t h_i h_j) / 2 with t = s'(x) / x = (cos x - s) / x^2 (its series
    # below x = 0.01, where the difference cancels)
    h = [0.5 * c for c in v]
    x = _hypot(*h)
    s = _sin(x) / x if x else 1.0
    c = _cos(x)
    xx = x * x
    t = (c - s) / xx if x > 0.01 else -1.0 / 3.0 + xx * (1.0 / 30.0 + xx * (-1.0 / 840.0 + xx / 45360.0))
    sign = _copysign(1.0, c)
    q = [c * sign, h[0] * s * sign, h[1] * s * sign, h[2] * s * sign]

    def pullback(g):
        gw, gx, gy, gz = (gi * sign for gi in g)
        along = t * (h[0] * gx + h[1] * gy + h[2] * gz) - s * gw
        return [0.5 * (s * gi + along * hi) for gi, hi in zip((gx, gy, gz), h)]

    return q, pullback


def axis_angle_to_quat_vjp(v, dtype=None):
    q, pullback = _axis_angle_quat_with_pullback(v)
    return q, lambda g: (pullback(g),)


def _quat_to_axis_angle_with_pullback(q):
    # v = m u, m = 2 sign(w0) atan2(n, w) / n (n = |u|, w = |w0|): dv / dw0 = -2 u / (n^2 + w^2)
    # (0 at w0 = 0, as autograd's |w0|) and dv / du_i = m e_i + k u_i u, k = (2 w0 / (n^2 + w^2) - m) / n^2,
    # by its series 2 sign(w0) / w^3 (-2/3 + 4 r^2 / 5) below r^2 = (n / w)^2 = 1e-6 (the difference cancels)
    w0, u = q[0], q[1:]
    w, n = abs(w0), _hypot(*u)
    sigma2 = _copysign(2.0, w0)
    m = sigma2 * (_atan2(n, w) / n if n else 1.0 / w)
    nn, ww = n * n, w * w
    rho = 1.0 / (nn + ww)
    k = (2.0 * w0 * rho - m) / nn if nn > 1e-6 * ww else sigma2 / (ww * w) * (-2.0 / 3.0 + 0.8 * nn / ww)
    g_w0_factor = -2.0 * rho if w0 else 0.0

    def pullback(g):
        ug = u[0] * g[0] + u[1] * g[1] + u[2] * g[2]
        return [g_w0_factor * ug] + [m * gi + k * ui * ug for gi, ui in zip(g, u)]

    return [c * m for c in u], pullback


def quat_to_axis_angle_vjp(q, dtype=None):
    v, pullback = _quat_to_axis_angle_with_pullback(q)
    return v, lambda g: (pullback(g),)


def axis_angle_to_matrix_vjp(v, dtype=None):
    q, to_v = _axis_angle_quat_with_pullback(v)
    R = quat_to_matrix(q)
    to_q = _quat_to_matrix_pullback(q, R)
    return R, lambda g: (to_v(to_q(g)),)


def matrix_to_axis_angle_vjp(R, dtype=None):
    q, to_R = _matrix_to_quat_with_pullback(R)
    v, to_q = _quat_to_axis_angle_with_pullback(q)
    return v, lambda g: (to_R(to_q(g)),)


def rot6d_to_matrix_vjp(x, dtype=None):
    R = rot6d_to_matrix(x, dtype)
    if R[0] != R[0]:  # collinear columns (NaN): the tensor kernel's gradient
        raise Fallback
    a1, a2 = x[:3], x[3:]
    r1 = _hypot(*a1)
    b1, b3 = R[0::3], R[2::3]
    d = (a1[0] * a2[0] + a1[1] * a2[1] + a1[2] * a2[2]) / r1
    n = _hypot(*(a2[i] - d * b1[i] for i in range(3)))

    def vjp(g):
        # the skew part of R^T G: w = sum_k b_k x G_k; a2's gradient (b1 . w / n) b3, a1's
        # (w x b1 - d g2) / r1 (torchquat.rot6d's closed form)
        w = [0.0, 0.0, 0.0]
        for k in range(3):
            c = _cross(R[k::3], g[k::3])
            w = [w[i] + c[i] for i in range(3)]
        f = (b1[0] * w[0] + b1[1] * w[1] + b1[2] * w[2]) / n
        g2 = [f * c for c in b3]
        wb = _cross(w, b1)
        return ([(wb[i] - d * g2[i]) / r1 for i in range(3)] + g2,)

    return R, vjp


def quat_geodesic_distance_vjp(q1, q2, dtype=None):
    # theta = 2 atan2(W, |d|), W = |minors|, d = <a, b>: d theta = 2 (|d| dW - W sign(d) dd) / (W^2 + d^2),
    # dW / da = M b / W, dW / db = -M a / W (M the antisymmetric matrix of the minors); 0 at W = 0
    # (the kink) and at d = 0 (the maximum's)
    a0, a1, a2, a3 = q1
    b0, b1, b2, b3 = q2
    dot, m01, m02, m03, m12, m13, m23 = _quat_distance_parts(q1, q2)
    wedge = _hypot(m01, m02, m03, m12, m13, m23)
    if not (wedge or dot):
        raise Fallback  # a zero quaternion: NaN
    c = 2.0 / (wedge * wedge + dot * dot)
    alpha = c * abs(dot) / wedge if wedge else 0.0
    beta = c * wedge * ((dot > 0.0) - (dot < 0.0))

    def vjp(g):
        p, r = g[0] * alpha, g[0] * beta
        return ([p * (m01 * b1 + m02 * b2 + m03 * b3) - r * b0, p * (m12 * b2 + m13 * b3 - m01 * b0) - r * b1,
                 p * (m23 * b3 - m02 * b0 - m12 * b1) - r * b2, p * (-m03 * b0 - m13 * b1 - m23 * b2) - r * b3],
                [-p * (m01 * a1 + m02 * a2 + m03 * a3) - r * a0, -p * (m12 * a2 + m13 * a3 - m01 * a0) - r * a1,
                 -p * (m23 * a3 - m02 * a0 - m12 * a1) - r * a2, -p * (-m03 * a0 - m13 * a1 - m23 * a2) - r * a3])

    return 2.0 * _atan2(wedge, abs(dot)), vjp


def matrix_geodesic_distance_vjp(R1, R2, dtype=None):
    # theta = atan2(W, c), W = |v|, c = tr(R1^T R2) - 1: the gradients are K R2 and K^T R1 with
    # K = s (c / W A - W I), s = g / (W^2 + c^2), A antisymmetric in v (A[1][2] = v0, A[2][0] = v1,
    # A[0][1] = v2); 0 at W = 0 (torchquat.distance's closed form)
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = R1
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = R2
    v0, v1, v2, cosine = _matrix_distance_parts(R1, R2)
    wedge = _hypot(v0, v1, v2)
    s = 1.0 / (wedge * wedge + cosine * cosine)
    alpha = s * cosine / wedge if wedge else 0.0

    def vjp(g):
        p, e = g[0] * alpha, -g[0] * s * wedge
        k01, k02, k12 = p * v2, -p * v1, p * v0  # K = [[e, k01, k02], [-k01, e, k12], [-k02, -k12, e]]
        return ([e * b00 + k01 * b10 + k02 * b20, e * b01 + k01 * b11 + k02 * b21, e * b02 + k01 * b12 + k02 * b22,
                 e * b10 - k01 * b00 + k12 * b20, e * b11 - k01 * b01 + k12 * b21, e * b12 - k01 * b02 + k12 * b22,
                 e * b20 - k02 * b00 - k12 * b10, e * b21 - k02 * b01 - k12 * b11, e * b22 - k02 * b02 - k12 * b12],
                [e * a00 - k01 * a10 - k02 * a20, e * a01 - k01 * a11 - k02 * a21, e * a02 - k01 * a12 - k02 * a22,
                 e * a10 + k01 * a00 - k12 * a20, e * a11 + k01 * a01 - k12 * a21, e * a12 + k01 * a02 - k12 * a22,
                 e * a20 + k02 * a00 + k12 * a10, e * a21 + k02 * a01 + k12 * a11, e * a22 + k02 * a02 + k12 * a12])

    return _atan2(wedge, cosine), vjp


def _layout_angles_vjp(y0, x0, y1, x1, y2, x2, z, conv: EulerConvention, eps: float):
    """The angles (:func:`_layout_angles`) and ``g`` (3) -> its gradient on the 7 layout entries
    (``torchquat._euler_small._forms_gradient``): ``d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)``
    for t1 (0 at lock), the chosen double angle and the middle, with ``d 2h`` 0 at ``2h = 0``."""
    angles = _layout_angles(y0, x0, y1, x1, y2, x2, z, conv, eps)
    two_h, locked, near_zero, flip = _layout_choices(y0, x0, z, conv, eps)
    pair = (y1, x1) if near_zero else (y2, x2)
    pair_square = pair[0] * pair[0] + pair[1] * pair[1]
    middle_square = z * z + two_h * two_h

    def vjp(g):
        g0, g_middle, g2 = g
        if conv.intrinsic:  # (t3, middle, t1), t3 = D - flip t1
            g_double, g_t1 = g0, g2 - flip * g0
        else:  # (t1 or flip D at lock, middle, t3 or 0 at lock)
            g_double, g_t1 = (flip * g0 if locked else g2), g0 - flip * g2
        g_y0 = g_x0 = 0.0
        if not locked:
            g_y0, g_x0 = g_t1 * x0 / (two_h * two_h), -g_t1 * y0 / (two_h * two_h)
        g_py, g_px = g_double * pair[1] / pair_square, -g_double * pair[0] / pair_square
        # middle = atan2(2h, z) (proper Euler) or atan2(z, 2h)
        sign = 1.0 if conv.symmetric else -1.0
        g_two_h, g_z = sign * g_middle * z / middle_square, -sign * g_middle * two_h / middle_square
        if two_h:
            g_y0 += g_two_h * y0 / two_h
            g_x0 += g_two_h * x0 / two_h
        if near_zero:
            return g_y0, g_x0, g_py, g_px, 0.0, 0.0, g_z
        return g_y0, g_x0, 0.0, 0.0, g_py, g_px, g_z

    return angles, vjp


def quat_to_euler_vjp(q, dtype=None, *, convention: EulerConvention, eps: float):
    _, tb, z_sign, _ = _EULER[convention.name]
    entries, (a, b, c, d), scale = _quat_layout(q, convention)
    angles, entries_vjp = _layout_angles_vjp(*entries, convention, eps)

    def vjp(g):
        # through the entries' forms in (a, b, c, d); the scaled ones (y0, x0, z) by 1 / |abcd|^2
        # alone: the angles are scale-invariant, so the derivative through the scale is 0
        e_y0, e_x0, e_y1, e_x1, e_y2, e_x2, e_z = entries_vjp(g)
        e_y0, e_x0, e_z = 2.0 * e_y0 * scale, 2.0 * e_x0 * scale, 2.0 * z_sign * e_z * scale
        tb2 = -2.0 * tb
        g_a = -d * e_y0 + c * e_x0 + tb2 * b * e_y1 - 2.0 * a * e_x1 + a * e_z
        g_b = c * e_y0 + d * e_x0 + tb2 * a * e_y1 + 2.0 * b * e_x1 + b * e_z
        g_c = b * e_y0 + a * e_x0 + tb2 * d * e_y2 - 2.0 * c * e_x2 - c * e_z
        g_d = -a * e_y0 + b * e_x0 + tb2 * c * e_y2 + 2.0 * d * e_x2 - d * e_z
        g_q = [0.0, 0.0, 0.0, 0.0]
        for (i, ci, j, cj), g_u in zip(_EULER[convention.name][0], (g_a, g_b, g_c, g_d)):
            g_q[i] += ci * g_u
            g_q[j] += cj * g_u
        return (g_q,)

    return angles, vjp


def matrix_to_euler_vjp(R, dtype=None, *, convention: EulerConvention, eps: float):
    angles, entries_vjp = _layout_angles_vjp(*_matrix_layout(R, convention), convention, eps)

    def vjp(g):  # the forms are linear in R: the table's transpose
        g_R = [0.0] * 9
        for g_form, (_, terms) in zip(entries_vjp(g), _MATRIX_LAYOUT[convention.name]):
            for r, coefficient in terms:
                g_R[r] += coefficient * g_form
        return (g_R,)

    return angles, vjp


def _euler_quat_with_pullback(angles, convention: EulerConvention):
    # dq / d angle_n: the same 8 products with angle n's (cos, sin) of its half replaced by their
    # derivative (-sin, cos) / 2
    f = [(_cos(0.5 * a), _sin(0.5 * a)) for a in angles]
    df = [(-0.5 * s, 0.5 * c) for c, s in f]
    q = [0.0, 0.0, 0.0, 0.0]
    dq = [[0.0, 0.0, 0.0, 0.0] for _ in range(3)]
    for m, (k, sign) in enumerate(_EULER_SIGNS[convention.name]):
        m0, m1, m2 = m >> 2, (m >> 1) & 1, m & 1
        q[k] += sign * f[0][m0] * f[1][m1] * f[2][m2]
        dq[0][k] += sign * df[0][m0] * f[1][m1] * f[2][m2]
        dq[1][k] += sign * f[0][m0] * df[1][m1] * f[2][m2]
        dq[2][k] += sign * f[0][m0] * f[1][m1] * df[2][m2]
    sign = _copysign(1.0, q[0])

    def pullback(g):
        return [sign * (row[0] * g[0] + row[1] * g[1] + row[2] * g[2] + row[3] * g[3]) for row in dq]

    return [c * sign for c in q], pullback


def euler_to_quat_vjp(angles, dtype=None, *, convention: EulerConvention):
    q, pullback = _euler_quat_with_pullback(angles, convention)
    return q, lambda g: (pullback(g),)


def euler_to_matrix_vjp(angles, dtype=None, *, convention: EulerConvention):
    q, to_angles = _euler_quat_with_pullback(angles, convention)
    R = quat_to_matrix(q)
    to_q = _quat_to_matrix_pullback(q, R)
    return R, lambda g: (to_angles(to_q(g)),)


def _slerp_weight_derivatives(x, square, small, angle, sine, angle2, weight):
    """``d w / d square`` and ``d w / d x`` of the weight ``w = sin(x a) / sin(a)``, ``a`` the angle of
    the chord (``d a / d square = 1 / (2 sin a)``), or of its series (``torchquat.slerp``'s)."""
    if small:  # w = x + x u A (1/6 + (4 + 3 u) A / 360), u = 1 - x^2, A = square + square^2 / 12
        u = 1.0 - x * x
        inner = 1.0 / 6.0 + (4.0 + 3.0 * u) * angle2 / 360.0
        d_square = x * u * (1.0 / 6.0 + (4.0 + 3.0 * u) * angle2 / 180.0) * (1.0 + square / 6.0)
        return d_square, 1.0 + u * angle2 * inner - 2.0 * x * x * angle2 * (inner + u * angle2 / 120.0)
    cos_x_angle = _cos(x * angle)  # d w / d a = (x cos(x a) - w cos(a)) / sin(a)
    return (x * cos_x_angle - weight * _cos(angle)) / (2.0 * sine * sine), angle * cos_x_angle / sine


def quat_slerp_vjp(q0, q1, t, dtype=None):
    # torchquat.slerp's closed form for the pair (p, q): with G = (<g, p>, <g, q>) and W = G . dw / dsquare,
    # the gradients are scale_k (w_k g +- 2 W (p - q) - (w_k G_k + W square) x_k) for x = (p, q), and
    # G . (-dw0 / dx0, dw1 / dx1) for t
    out, (p, q, n0, n1, square, small, angle, sine, angle2, times, w) = _slerp_parts(q0, q1, t, dtype)
    (d_square0, d_x0), (d_square1, d_x1) = (_slerp_weight_derivatives(x, square, small, angle, sine, angle2, wk)
                                            for x, wk in zip(times, w))
    difference = [a - b for a, b in zip(p, q)]

    def vjp(g):
        G0 = g[0] * p[0] + g[1] * p[1] + g[2] * p[2] + g[3] * p[3]
        G1 = g[0] * q[0] + g[1] * q[1] + g[2] * q[2] + g[3] * q[3]
        W = G0 * d_square0 + G1 * d_square1
        along0, along1 = W * square + w[0] * G0, W * square + w[1] * G1
        return ([n0 * (w[0] * gi + 2.0 * W * di - along0 * pi) for gi, di, pi in zip(g, difference, p)],
                [n1 * (w[1] * gi - 2.0 * W * di - along1 * qi) for gi, di, qi in zip(g, difference, q)],
                [G1 * d_x1 - G0 * d_x0])

    return out, vjp

