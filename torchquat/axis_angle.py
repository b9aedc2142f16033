"""Axis-angle (rotation vector) <-> quaternion and matrix.

A rotation vector is the unit axis times the angle in radians. The functions switch to Taylor
series below ``angle^2 < sqrt(eps)`` (thresholds from ``torch.finfo``), so values and gradients
are exact to rounding at and near the zero rotation.
"""

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule, jacobian_rule
from ._dispatch import compiled_without_gradient, kernel
from ._one_row import OneRow
from ._math import (HALF_IDENTITY, constant, contract, copysign, is_small, outer_product, small_angle_threshold,
                    sum_of_products, sum_of_squares)
from ._polynomials import DIRECT_ROTATION_VECTOR_ENTRIES, atan2, cos_sin_up_to_sign, cos_sinc_of_squares
from ._planes import columns, plane_buffer, rows, slot
from ._validation import prepare, restore
from .matrix import (HOMOGENEOUS, _shepperd_columnwise, matrix_to_quat_unchecked, quat_columns_to_matrix,
                     quat_to_matrix_unchecked)

__all__ = ["axis_angle_to_quat", "quat_to_axis_angle", "axis_angle_to_matrix", "matrix_to_axis_angle"]


def _half_angle(v: Tensor, for_autograd: bool = True, twice: bool = False):
    """``theta``, the small-angle mask, ``theta`` with 1 there (for autograd; values need no
    substitute: where a closed form would be NaN the series is taken), ``theta / 2`` of that, and
    ``cos(theta / 2)``, ``sin(theta / 2) / theta``. ``twice`` (the forward autograd differentiates:
    double backward, ``torch.func``): no norm of a vector that can be 0 takes part, since a norm's
    second derivative there is NaN even where no gradient flows; the same numbers."""
    one = constant("one", 1.0, v)
    theta = torch.linalg.vector_norm(v, dim=-1, keepdim=True)  # gradient 0 (not NaN) at v = 0
    # Below theta^2 = sqrt(eps) the next series terms (theta^4/384, theta^4/3840) are under eps.
    small = theta < constant("axis_angle_small", small_angle_threshold(v.dtype) ** 0.5, v)
    if twice:  # theta of a stand-in vector of norm 1 where the series applies; the series in v . v
        # (theta^2 to an ulp, which 1 - theta^2 / 8 and 1/2 - theta^2 / 48 round away)
        theta_safe = torch.linalg.vector_norm(torch.where(small, constant("unit_3_x", (1.0, 0.0, 0.0), v), v), dim=-1, keepdim=True)
        square = (v * v).sum(-1, keepdim=True)
        cos_series = torch.add(one, square, alpha=-0.125)
        sinc_series = torch.add(constant("half", 0.5, v), square, alpha=-1.0 / 48.0)
    else:
        theta_safe = torch.where(small, one, theta) if for_autograd else theta
        cos_series = torch.addcmul(one, theta, theta, value=-0.125)
        sinc_series = torch.addcmul(constant("half", 0.5, v), theta, theta, value=-1.0 / 48.0)
    half = theta_safe * constant("half", 0.5, v)
    cos_half = torch.where(small, cos_series, torch.cos(half))
    sinc_half = torch.where(small, sinc_series, torch.sin(half) / theta_safe)
    return theta, small, theta_safe, half, cos_half, sinc_half


def _axis_angle_to_quat_small(v: Tensor, for_autograd: bool = True) -> Tensor:
    _, _, _, _, cos_half, sinc_half = _half_angle(v, for_autograd, twice=for_autograd)
    # w >= 0: cos(theta / 2) of a float angle is never exactly 0, so its sign alone decides.
    return torch.cat((cos_half, v * sinc_half), dim=-1) * copysign(constant("one", 1.0, v), cos_half)


def _half_turn_quat(v: Tensor) -> Tensor:
    """The quaternion of ``v`` up to sign, for values only: ``(cos x, h sin(x) / x)`` with ``h = v / 2``
    and ``x = |h|`` at least the smallest normal number, where ``sin(x) / x`` is 1 (and at ``v = 0``
    0 / 0 is avoided): no series and no substitutes, 8 operations in place of 13 (0.65x the time
    at one rotation). Nothing differentiates it. (Not ``torch.sinc(x / pi)``: its argument's
    rounding at large angles, 0.06 rad at 1e6 in float32, unpairs it from ``cos x``.)"""
    half = v * constant("half", 0.5, v)
    x = torch.linalg.vector_norm(half, dim=-1, keepdim=True).clamp_min(torch.finfo(v.dtype).tiny)
    return torch.cat((torch.cos(x), half * (torch.sin(x) / x)), dim=-1)


def _axis_angle_to_quat_values(v: Tensor) -> Tensor:
    q = _half_turn_quat(v)
    return q * copysign(constant("one", 1.0, v), q.narrow(-1, 0, 1))  # w >= 0, as above


# (..., 3, 4) Jacobian rows: d q / d v_i. Row i is s e_{i+1} plus v_i times (-s / 2, t v) with
# s = sin(theta / 2) / theta and t = s'(theta) / theta = (cos(theta / 2) / 2 - s) / theta^2.
_SHIFTED_EYE = ((0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def _axis_angle_to_quat_with_jacobian(v: Tensor):
    theta, small, theta_safe, half, cos_half, sinc_half = _half_angle(v)
    sign = copysign(constant("one", 1.0, v), cos_half)
    q = torch.cat((cos_half, v * sinc_half), dim=-1) * sign
    # minus_2t = -2t = (s - c / 2) / (theta^2 / 2); its cancellation (eps / theta^2 relative)
    # multiplies v v^T ~ theta^2, so it costs eps absolute. Series: 1/12 - theta^2 / 480.
    series = torch.addcmul(constant("one_twelfth", 1.0 / 12.0, v), theta, theta, value=-1.0 / 480.0)
    minus_2t = torch.where(small, series, torch.sub(sinc_half, cos_half, alpha=0.5) / (half * theta_safe))
    row = torch.cat((sinc_half, minus_2t * v), dim=-1)  # times -v_i / 2: (-s v_i / 2, t v_i v)
    eye = sinc_half.unsqueeze(-1) * constant("shifted_eye_3x4", _SHIFTED_EYE, v)
    jacobian = torch.addcmul(eye, v.unsqueeze(-1), row.unsqueeze(-2), value=-0.5)
    return q, jacobian * sign.unsqueeze(-1)


_AXIS_ANGLE_TO_QUAT = jacobian_rule(_axis_angle_to_quat_small, _axis_angle_to_quat_with_jacobian, _axis_angle_to_quat_values)


@kernel(blocked_row_dims=(1,), compiled_from_rows=1_024, polynomial_sincos=DIRECT_ROTATION_VECTOR_ENTRIES,
        one_row=OneRow("axis_angle_to_quat", (3,), (4,)))
def axis_angle_to_quat_unchecked(v: Tensor) -> Tensor:
    # Up to 1,024 rows one closed-form node on the table path; above, its broadcast (..., 3, 4)
    # products cost more per row, and the columns with their own closed form are 1.4-1.9x faster
    # forward+backward at 2,048-4,096 rows (their forward is 0.8-1.0x of the table's there).
    # With a gradient to record, the columns' closed form from 769 rows (0.89x the time at 1,000).
    if is_small(v, 3, share=0.1875) or (is_small(v, 3, share=0.25) and not closed_form.records_graph((v,))):
        return closed_form.apply(_AXIS_ANGLE_TO_QUAT, v)
    if torch.compiler.is_compiling():
        return _AXIS_ANGLE_TO_QUAT_TRACED(v)
    return closed_form.apply(_AXIS_ANGLE_TO_QUAT_COLUMNWISE, v)


def axis_angle_to_quat(v: Tensor) -> Tensor:
    """Quaternion of a rotation vector.

    Args:
        v: unit axis times angle (radians); any length, zero included.

    Returns:
        Unit quaternions ``(w, x, y, z)`` with ``w >= 0``.

    Shape:
        ``(..., 3)`` -> ``(..., 4)``.

    Example:
        >>> axis_angle_to_quat(torch.tensor([0., 0., torch.pi / 2]))
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    if (out := axis_angle_to_quat_unchecked.at_one_row(v)) is not None:
        return out
    v, dtype = prepare(v, "axis_angle_to_quat", "v", (3,))
    return restore(axis_angle_to_quat_unchecked(v), dtype)


def _axis_angle_scale(q: Tensor, for_autograd: bool = True, twice: bool = False):
    """``w`` (signed), ``u``, ``|w|``, ``|u|``, ``|u|`` with 1 where the series applies (for
    autograd; values need no substitutes: where a closed form would be NaN or inf the other is
    taken), and the factor ``m`` (``angle / |u|``, signed by the hemisphere) of ``u`` in the
    rotation vector ``m u``. ``twice``: as for :func:`_half_angle`."""
    # shortest arc: use the w >= 0 copy (at w == 0 both copies are half turns, either is right)
    w0, u = q.narrow(-1, 0, 1), q.narrow(-1, 1, 3)
    hemisphere = copysign(constant("two", 2.0, q), w0)  # the factor 2 of the angle, signed
    w = w0.abs()
    # angle / |u| = 2 atan2(|u|, w) / |u| = (2 / w)(1 - r^2/3 + ...) with r = |u| / w: below
    # r^2 = eps the limit 2 / w is exact to rounding. Above it the closed form is accurate, and
    # its gradient's cancellation costs at most eps / r relative, on a term of size r.
    n = torch.linalg.vector_norm(u, dim=-1, keepdim=True)  # gradient 0 (not NaN) at u = 0
    small = n <= constant("sqrt_eps", torch.finfo(q.dtype).eps ** 0.5, q) * w
    n_safe, w_safe = n, w
    if for_autograd:
        if twice:  # |u| of a stand-in of norm 1 where the series applies (the series takes no |u|)
            n_safe = torch.linalg.vector_norm(torch.where(small, constant("unit_3_x", (1.0, 0.0, 0.0), q), u), dim=-1, keepdim=True)
        else:
            n_safe = torch.where(small, constant("one", 1.0, q), n)
        w_safe = torch.where(small, w, constant("one", 1.0, q))  # w = 0 (a half turn) only reaches the closed form
    scale = torch.where(small, torch.reciprocal(w_safe), torch.atan2(n_safe, w) / n_safe)
    return w0, u, w, n, n_safe, scale * hemisphere


def _quat_to_axis_angle_small(q: Tensor, for_autograd: bool = True) -> Tensor:
    _, u, _, _, _, m = _axis_angle_scale(q, for_autograd, twice=for_autograd)
    return u * m


def _quat_to_axis_angle_values(q: Tensor) -> Tensor:
    return _quat_to_axis_angle_small(q, for_autograd=False)


# (..., 4, 3) Jacobian rows of v = m(n, w) u, m = 2 sign(w0) atan2(n, w) / n, n = |u|, w = |w0|:
# d v / d w0 = -2 u / (n^2 + w^2) (0 at w0 = 0, as autograd's |w0|), d v / d u_i = m e_i + k u_i u
# with k = (2 w0 / (n^2 + w^2) - m) / n^2. In the series branch (m = 2 sign(w0) / w, n_safe = 1)
# the same expression is a k of at most 2 eps / w on u_i u of at most eps w^2: nothing, as the series'.
# k's cancellation (eps / r^2 relative, r = n / w) multiplies u_i u ~ n^2: eps relative to m.
_SHIFTED_EYE_T = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _quat_to_axis_angle_with_jacobian(q: Tensor):
    w0, u, w, n, n_safe, m = _axis_angle_scale(q)
    two_rho = constant("two", 2.0, q) / torch.addcmul(w * w, n, n)  # 2 / (n^2 + w^2)
    minus_k = torch.addcmul(m, w0, two_rho, value=-1.0) / (n_safe * n_safe)
    column = torch.cat((torch.sgn(w) * two_rho, minus_k * u), dim=-1)  # minus u's factor in each row
    eye = m.unsqueeze(-1) * constant("shifted_eye_4x3", _SHIFTED_EYE_T, q)
    return u * m, torch.addcmul(eye, column.unsqueeze(-1), u.unsqueeze(-2), value=-1.0)


# Without a gradient to record, the columns from 32,768 rows (the table's forward stays ahead up
# to ~100k, 1.16x at 32k); with one, their closed form from 513 rows (see below; 0.47x at 1e6)
_COLUMNWISE_SHARE = 8.0
_QUAT_TO_AXIS_ANGLE = jacobian_rule(_quat_to_axis_angle_small, _quat_to_axis_angle_with_jacobian, _quat_to_axis_angle_values)


@kernel(blocked_row_dims=(1,), compiled_from_rows=2_048, polynomial_atan2=True,
        one_row=OneRow("quat_to_axis_angle", (4,), (3,)))
def quat_to_axis_angle_unchecked(q: Tensor) -> Tensor:
    if torch.compiler.is_compiling():
        return _QUAT_TO_AXIS_ANGLE_TRACED(q)
    if is_small(q, 4, share=0.125, gpu_share=4):  # closed form vs autograd: crossover measured near 700 rows
        return closed_form.apply(_QUAT_TO_AXIS_ANGLE, q)
    # with a gradient to record, the columns' closed form beats the table's autograd from here
    # (forward+backward 0.96x the time at 768 rows, 0.95x at 1,000, 0.85x at 2,048, 0.73x at 4,096)
    if closed_form.records_graph((q,)) or not is_small(q, 4, share=_COLUMNWISE_SHARE):
        return closed_form.apply(_QUAT_TO_AXIS_ANGLE_COLUMNWISE, q)
    return closed_form.apply_without_closed_form(_QUAT_TO_AXIS_ANGLE, q)


# Column by column: the same formulas on 1-D columns with Python-number constants. Under
# torch.compile they fuse into one vectorised loop (broadcast (N, 1) factors and table buffers
# do not); axis_angle_to_quat also takes it for large eager batches, where it is faster.


def _axis_angle_to_quat_columnwise_parts(v: Tensor, for_autograd: bool = False, values: bool = False):
    """The quaternion column by column, and what the closed-form backward needs. ``for_autograd``
    (the plain forward: double backward, ``torch.func``, compile): Taylor series below
    ``theta^2 < sqrt(eps)``, so that autograd's gradients stay exact there and never see 0 / 0.
    Otherwise nothing differentiates these values: ``sin(x) / x`` of the half angle is exact to
    rounding down to ``x^2 < eps^2``, where it is 1 (the next term, ``x^2 / 6``, is below rounding).
    ``values``: nothing keeps the saved parts (the output's columns among them), so those columns
    may be the output rows' own memory (``_planes.plane_buffer``)."""
    h = columns(v, HALF_IDENTITY[3], "half3")  # v / 2: its norm is the half angle
    x2 = sum_of_squares(h)
    direct = cos_sinc_of_squares(x2) if for_autograd else None  # (compiled float32, no gradient, x <= pi)
    if direct is not None:
        cos_half, sinc = direct
    elif for_autograd:
        small = x2 < small_angle_threshold(v.dtype) * 0.25  # (theta^2 = 4 x^2)
        x = torch.sqrt(torch.where(small, 1.0, x2))
        # (cos x, sin x) up to a common sign in the compiled float32 kernels: sign below undoes it
        cos_x, sin_x = cos_sin_up_to_sign(x)
        cos_half = torch.where(small, 1.0 - 0.5 * x2, cos_x)
        sinc = torch.where(small, 1.0 - x2 / 6.0, sin_x / x)
    else:  # (x at least the smallest normal: sin(x) / x is 1 there, and 0 / 0 at x = 0 is avoided)
        x = torch.sqrt(x2).clamp_min_(torch.finfo(v.dtype).tiny)
        cos_half = torch.cos(x)
        sinc = torch.sin(x) / x
    sign = copysign(constant("one", 1.0, cos_half), cos_half)  # (an eager where on a random sign mispredicts)
    s = sinc * sign
    buffer = plane_buffer(4, h, output=values)
    q = [torch.mul(cos_half, sign, out=slot(buffer, 0))] + [torch.mul(c, s, out=slot(buffer, i)) for i, c in enumerate(h, 1)]
    return rows(q if buffer is None else buffer), (*h, x2, q[0], s)


def _axis_angle_to_quat_columnwise(v: Tensor) -> Tensor:
    return _axis_angle_to_quat_columnwise_parts(v, for_autograd=True)[0]


def _axis_angle_to_quat_columnwise_backward(grad: Tensor, inputs, saved):
    # q = sign (cos x, r h) with h = v / 2, x = |h|, r = sin(x) / x: d q_w = -r h.dh,
    # d q_u = r dh + k h (h.dh) with k = r'(x) / x = (cos x - r) / x^2 (series -1/3 + x^2 / 30 below
    # x^2 = sqrt(eps): its cancellation, eps / x^2 relative, multiplies h h^T ~ x^2: eps absolute).
    # Saved: q_w = sign cos x and s = sign r, so sign k = (q_w - s) / x^2 (sign = 1 in the series branch)
    *h, x2, w, s = saved
    g_w, *g_u = columns(grad, HALF_IDENTITY[4], "half4")  # (dh = dv / 2, in the transpose)
    small = x2 < torch.finfo(x2.dtype).eps ** 0.5
    # (nothing differentiates this backward, so the dropped branch's 0 / 0 at x = 0 is harmless)
    series = torch.addcmul(constant("minus_third", -1.0 / 3.0, x2), x2, constant("thirtieth", 1.0 / 30.0, x2))
    k = torch.where(small, series, (w - s) / x2)
    along = torch.addcmul(k * sum_of_products(g_u, h), s, g_w, value=-1.0)
    buffer = plane_buffer(3, h)
    g_v = [torch.addcmul(s * g, along, c, out=slot(buffer, i)) for i, (g, c) in enumerate(zip(g_u, h))]
    return (rows(g_v if buffer is None else buffer),)


_AXIS_ANGLE_TO_QUAT_COLUMNWISE = Rule(_axis_angle_to_quat_columnwise, _axis_angle_to_quat_columnwise_parts,
                                      _axis_angle_to_quat_columnwise_backward,
                                      lambda v: _axis_angle_to_quat_columnwise_parts(v, values=True)[0])
# (its value form takes torch's cos and sin, where the plain one has the compiled polynomials)
_AXIS_ANGLE_TO_QUAT_TRACED = closed_form.traced_rule(_AXIS_ANGLE_TO_QUAT_COLUMNWISE._replace(values=None))


def _quat_to_axis_angle_columnwise_parts(q: Tensor, for_autograd: bool = False):
    """The rotation vector column by column, and what the closed-form backward needs.
    ``for_autograd`` (the plain forward): the series branch's rows get substitutes that keep
    autograd away from 0 / 0; otherwise a NaN in a branch that ``where`` drops is harmless.
    ``q``: quaternions, or a list of their four columns (a composite kernel's trace)."""
    w0, *u = q if isinstance(q, list) else columns(q)
    n2 = sum_of_squares(u)
    w = w0.abs()
    small = torch.addcmul(n2, w, w, value=-torch.finfo(w0.dtype).eps) <= 0  # n^2 <= eps w^2
    if for_autograd:
        n, inverse = torch.sqrt(torch.where(small, 1.0, n2)), torch.reciprocal(torch.where(small, w, 1.0))
    else:
        n, inverse = torch.sqrt(n2), torch.reciprocal(w)
    # angle / (2 n), signed by the hemisphere (as the table path, copysign: -0.0 takes -1); rows() doubles it
    # (atan2's (0, 0) is a small row; at (inf, inf) its result over n is 0 or NaN, times u's infinity NaN)
    angle = atan2(n, w, y_nonnegative=True, x_nonnegative=True, special_values=False)
    m = copysign(torch.where(small, inverse, angle / n), w0)
    buffer = plane_buffer(3, u, output=False)  # (rows() applies a table)
    v = [torch.mul(c, m, out=slot(buffer, i)) for i, c in enumerate(u)]
    return rows(v if buffer is None else buffer, _DOUBLE, "double3"), (w0, *u, n2, small, m)


def _quat_to_axis_angle_columnwise(q: Tensor) -> Tensor:
    return _quat_to_axis_angle_columnwise_parts(q, for_autograd=True)[0]


# m in the column code is half the rotation vector's factor: rows() doubles the output and the
# gradient (whose first row, g_w0 = -(u.g) 2 / (n^2 + w^2), it also negates)
_DOUBLE = ((2.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 2.0))
_NEGATE_FIRST_DOUBLE = ((-2.0, 0.0, 0.0, 0.0), (0.0, 2.0, 0.0, 0.0), (0.0, 0.0, 2.0, 0.0), (0.0, 0.0, 0.0, 2.0))


def _quat_to_axis_angle_columnwise_backward(grad: Tensor, inputs, saved):
    # the Jacobian of _quat_to_axis_angle_with_jacobian (g_u = m g + k (u.g) u), column by column, halved
    w0, *rest = saved
    u, (n2, small, m) = rest[:3], rest[3:]
    g = columns(grad)
    dot = g[0] * u[0]
    for a, b in zip(g[1:], u[1:]):
        dot = torch.addcmul(dot, a, b)
    rho = torch.reciprocal(torch.addcmul(n2, w0, w0))  # 1 / (n^2 + w^2)
    buffer = plane_buffer(4, g, output=False)  # (rows() applies a table)
    g_w0 = torch.where(w0 == 0, constant("zero", 0.0, w0), dot * rho, out=slot(buffer, 0))  # (0 at w0 = 0, as autograd's |w0|)
    # -k / 2 = (m - w0 rho) / n^2 (the series branch: n^2 -> 1, a term below rounding)
    minus_k_dot = torch.addcmul(m, w0, rho, value=-1.0) / torch.where(small, 1.0, n2) * dot
    g_q = [g_w0] + [torch.addcmul(m * a, minus_k_dot, b, value=-1.0, out=slot(buffer, i)) for i, (a, b) in enumerate(zip(g, u), 1)]
    return (rows(g_q if buffer is None else buffer, _NEGATE_FIRST_DOUBLE, "negate_first_double"),)


_QUAT_TO_AXIS_ANGLE_COLUMNWISE = Rule(_quat_to_axis_angle_columnwise, _quat_to_axis_angle_columnwise_parts,
                                      _quat_to_axis_angle_columnwise_backward,
                                      lambda q: _quat_to_axis_angle_columnwise_parts(q)[0])
_QUAT_TO_AXIS_ANGLE_TRACED = closed_form.traced_rule(_QUAT_TO_AXIS_ANGLE_COLUMNWISE)


def quat_to_axis_angle(q: Tensor) -> Tensor:
    """Rotation vector of a quaternion, along the shortest arc (angle in ``[0, pi]``).

    Args:
        q: quaternions ``(w, x, y, z)``; need not be unit. The zero quaternion gives NaN.

    Returns:
        Unit axis times angle.

    Shape:
        ``(..., 4)`` -> ``(..., 3)``.

    Example:
        >>> quat_to_axis_angle(torch.tensor([-0.5, -0.5, -0.5, -0.5]))  # = 120 deg about (1, 1, 1)
        tensor([1.2092, 1.2092, 1.2092])
    """
    if (out := quat_to_axis_angle_unchecked.at_one_row(q)) is not None:
        return out
    q, dtype = prepare(q, "quat_to_axis_angle", "q", (4,))
    return restore(quat_to_axis_angle_unchecked(q), dtype)


# R = H(q) for the unit quaternion of v, H the homogeneous form (16 x 9: the entries of |q|^2 R
# from q q^T, with |q|^2 = 1 to rounding); dR/dq = q^T D, D[j][9 i + k] = H[4 i + j][k] + H[4 j + i][k]
_ROTATION_FORM = tuple(row[:9] for row in HOMOGENEOUS)
_ROTATION_FORM_GRADIENT = tuple(tuple(HOMOGENEOUS[4 * i + j][k] + HOMOGENEOUS[4 * j + i][k] for i in range(4) for k in range(9))
                                for j in range(4))


def _rotation_form(q: Tensor) -> Tensor:
    return contract(outer_product(q, q), "rotation_form", _ROTATION_FORM).unflatten(-1, (3, 3))


def _axis_angle_to_matrix_small(v: Tensor, for_autograd: bool = True) -> Tensor:
    return _rotation_form(_axis_angle_to_quat_small(v, for_autograd))


def _axis_angle_to_matrix_with_jacobian(v: Tensor):
    q, jacobian = _axis_angle_to_quat_with_jacobian(v)  # (..., 3, 4)
    to_matrix = (q @ constant("rotation_form_gradient", _ROTATION_FORM_GRADIENT, v)).unflatten(-1, (4, 9))
    return _rotation_form(q), jacobian @ to_matrix  # (..., 3, 9): R's Jacobian, one node


_AXIS_ANGLE_TO_MATRIX = jacobian_rule(_axis_angle_to_matrix_small, _axis_angle_to_matrix_with_jacobian,
                                      lambda v: _rotation_form(_half_turn_quat(v)))  # (R is even in q)


@kernel(blocked_row_dims=(1,), compiled_from_rows=512, polynomial_sincos=DIRECT_ROTATION_VECTOR_ENTRIES,
        one_row=OneRow("axis_angle_to_matrix", (3,), (3, 3)))
def axis_angle_to_matrix_unchecked(v: Tensor) -> Tensor:
    # Through the quaternion, where Rodrigues' formula written out is about 50 eager operations:
    # a few rows in one closed-form node (the quaternion's series and its quadratic form, with
    # the chained Jacobian), many through the two kernels.
    if is_small(v, 3, share=0.25):
        return closed_form.apply(_AXIS_ANGLE_TO_MATRIX, v)
    if compiled_without_gradient(v):  # (the quaternion's columns passed on: one loop)
        _, (*h, _, w, s) = _axis_angle_to_quat_columnwise_parts(v, for_autograd=True)
        return quat_columns_to_matrix([w] + [c * s for c in h])
    return quat_to_matrix_unchecked(axis_angle_to_quat_unchecked(v))


@kernel(blocked_row_dims=(2,), polynomial_atan2=True, one_row=OneRow("matrix_to_axis_angle", (9,), (3,)))
def matrix_to_axis_angle_unchecked(R: Tensor) -> Tensor:
    if compiled_without_gradient(R):
        # Shepperd's row 4 q_k q passed on as columns: one loop. The rotation vector depends on
        # neither q's scale nor its sign (-q negates u and copysign(., w) together, signed zeros
        # included), so the row goes unnormalised and unstandardised: 0.81-0.90x the time at 1e6 rows.
        # (the value form, without the series branch's substitutes, where nothing differentiates)
        for_autograd = not closed_form.VALUE_FORMS or closed_form.differentiated((R,))
        return _quat_to_axis_angle_columnwise_parts(_shepperd_columnwise(R, raw_columns=True), for_autograd=for_autograd)[0]
    return quat_to_axis_angle_unchecked(matrix_to_quat_unchecked(R))


def axis_angle_to_matrix(v: Tensor) -> Tensor:
    """Rotation matrix of a rotation vector (Rodrigues' formula).

    Args:
        v: unit axis times angle (radians).

    Returns:
        Rotation matrices acting on column vectors.

    Shape:
        ``(..., 3)`` -> ``(..., 3, 3)``.

    Example:
        >>> axis_angle_to_matrix(torch.tensor([0., 0., torch.pi / 2])).round(decimals=6) + 0.0  # + 0.0 turns -0. into 0.
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    if (out := axis_angle_to_matrix_unchecked.at_one_row(v)) is not None:
        return out
    v, dtype = prepare(v, "axis_angle_to_matrix", "v", (3,))
    return restore(axis_angle_to_matrix_unchecked(v), dtype)


def matrix_to_axis_angle(R: Tensor) -> Tensor:
    """Rotation vector of a rotation matrix, along the shortest arc (angle in ``[0, pi]``).

    Goes through Shepperd's quaternion, which is accurate at 180 degrees where the
    ``acos((tr R - 1) / 2)`` formula loses half its digits. Each row is computed on its own.

    Shape:
        ``(..., 3, 3)`` -> ``(..., 3)``.

    Example:
        >>> matrix_to_axis_angle(torch.eye(3))
        tensor([0., 0., 0.])
    """
    if (out := matrix_to_axis_angle_unchecked.at_one_row(R)) is not None:
        return out
    R, dtype = prepare(R, "matrix_to_axis_angle", "R", (3, 3))
    return restore(matrix_to_axis_angle_unchecked(R), dtype)
