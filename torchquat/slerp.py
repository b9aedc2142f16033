"""Spherical linear interpolation (Shoemake 1985): row by row for a few rows, column by column for
many, each with a closed-form backward pass."""

import numbers
from typing import Union

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule
from ._dispatch import kernel
from ._one_row import OneRow
from ._math import constant, copysign, is_small, sum_of_products, sum_of_squares
from ._planes import columns, plane_buffer, rows, slot
from ._validation import check_broadcast, prepare_pair, restore

__all__ = ["quat_slerp"]
_PLANAR_SHARE = 0.25  # contiguous columns from 8,192 rows, as the product's (not measured for slerp alone)


def _slerp_series(s: Tensor, angle2: Tensor) -> Tensor:
    """``sin(s a) / sin(a)`` near ``a = 0``: ``s (1 + u a^2 / 6 + u (4 + 3 u) a^4 / 360 + O(a^6))``,
    ``u = 1 - s^2``, from ``a^2`` (checked with mpmath)."""
    u = torch.addcmul(constant("one", 1.0, s), s, s, value=-1.0)
    inner = torch.addcmul(constant("one_sixth", 1.0 / 6.0, s), torch.add(constant("four", 4.0, s), u, alpha=3.0),
                          angle2, value=1.0 / 360.0)
    return torch.addcmul(s, s * u * angle2, inner)


def _arc_tie(x: Tensor, sign: float) -> Tensor:
    """``sign * 8 eps``. ``q1`` is negated where ``<p, q> < -8 eps`` (``p``, ``q`` the unit inputs):
    within that bound the two arcs are equally short to rounding, and each path's dot product
    rounds differently (fused multiply-adds in the columns' and the compiled loop's), so every
    path keeps ``q1`` there, and exactly orthogonal inputs give one answer at every batch size."""
    return constant("arc_tie_minus" if sign < 0 else "arc_tie_plus", sign * 8.0 * torch.finfo(x.dtype).eps, x)


def _slerp_rows_parts(q0: Tensor, q1: Tensor, t: Tensor):
    """Small batches, row by row (few dispatches); ``t`` of the batch shape. Returns the output and
    what the closed-form backward needs."""
    # (constants as tensors: a Python number is wrapped into a tensor on every call, 1 us each)
    one = constant("one", 1.0, q0)
    # (as normalized(): a zero quaternion gives NaN, as everywhere, not a plausible rotation)
    scale0, scale1 = torch.rsqrt((q0 * q0).sum(-1, keepdim=True)), torch.rsqrt((q1 * q1).sum(-1, keepdim=True))
    p, q = q0 * scale0, q1 * scale1
    sign = torch.where((p * q).sum(-1, keepdim=True) < _arc_tie(q0, -1.0), constant("minus_one", -1.0, q0), one)
    q = q * sign
    difference = p - q
    square = (difference * difference).sum(-1, keepdim=True)
    # Below |q0 - q1|^2 = sqrt(eps) the series: autograd's second derivatives of the closed form
    # lose eps / angle^2 relative, and the series' next term is below eps
    small = square < constant("sqrt_eps", torch.finfo(q0.dtype).eps ** 0.5, q0)
    # (the square root of 1 where the chord is that short: smooth to any order at q0 = q1, where a
    # norm's second derivative is NaN; |q0 + q1| >= sqrt(2) after the flip)
    chord = torch.sqrt(torch.where(small, one, square))
    angle = torch.where(small, one, constant("two", 2.0, q0) * torch.atan2(chord, torch.linalg.vector_norm(p + q, dim=-1, keepdim=True)))
    t = t.unsqueeze(-1)
    times = torch.cat((one - t, t), dim=-1)  # both weights, one sine
    # a^2 = c^2 + c^4 / 12 + O(c^6) for the chord c = |q0 - q1| = 2 sin(a / 2)
    angle2 = torch.addcmul(square, square, square, value=1.0 / 12.0)
    sine = torch.sin(angle)
    weights = torch.where(small, _slerp_series(times, angle2), torch.sin(times * angle) / sine)
    out = torch.addcmul(weights[..., :1] * p, weights[..., 1:], q)
    return out, (p, q, difference, scale0, scale1, sign, square, small, angle, sine, angle2, times, weights)


def _slerp_rows(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    return _slerp_rows_parts(q0, q1, t)[0]


def _slerp_rows_backward(grad: Tensor, inputs, saved):
    # The columns' closed form (below) for the pair (p, q) at once: with G = (<g, p>, <g, q>) and
    # W = G . dw/dS, the gradients are scale_k (w_k g +- 2 W (p - q) - (w_k G_k + W S) x_k) for
    # x = (p, q), and G . (-dw0/ds0, dw1/ds1) for t (one node in place of autograd's 38)
    p, q, difference, scale0, scale1, sign, square, small, angle, sine, angle2, times, weights = saved
    scale1 = scale1 * sign  # (q's scale, signed by the short arc)
    if p.shape != q.shape:  # (broadcast batch shapes)
        (p, q), (scale0, scale1) = torch.broadcast_tensors(p, q), torch.broadcast_tensors(scale0, scale1)
    pair = torch.stack((p, q), dim=-2)  # (..., 2, 4)
    g_pair = (pair * grad.unsqueeze(-2)).sum(-1)
    d_square, d_s = _slerp_weight_derivatives(times, square, small, angle, sine, torch.cos(angle), angle2, weights)
    w = (g_pair * d_square).sum(-1, keepdim=True)
    along = torch.addcmul(w * square, weights, g_pair)
    signs = constant("slerp_pair_signs", (-1.0, 1.0), grad)
    twice = w * (signs * -2.0)  # (2 W, -2 W)
    scales = torch.cat((scale0, scale1), dim=-1).unsqueeze(-1)
    grads = scales * torch.addcmul(torch.addcmul(weights.unsqueeze(-1) * grad.unsqueeze(-2), twice.unsqueeze(-1),
                                                 difference.unsqueeze(-2)), pair, along.unsqueeze(-1), value=-1.0)
    g_q0, g_q1 = grads.unbind(-2)
    return g_q0, g_q1, (g_pair * d_s * signs).sum(-1)


_SLERP_ROWS = Rule(_slerp_rows, _slerp_rows_parts, _slerp_rows_backward)


def _slerp_columns_parts(q0: Tensor, q1: Tensor, t: Tensor):
    """Large batches and compiled kernels, column by column: the rows' steps with the
    normalisations and the sign of the short arc folded into one scale per input. About 70 passes
    over columns in place of 25 over rows and their broadcasts, yet faster: per 1e6 rows (float32,
    one thread) 47 ms forward against the rows' 110, 34 in blocks. Returns the output and what the
    closed-form backward needs."""
    a, b = columns(q0, share=_PLANAR_SHARE), columns(q1, share=_PLANAR_SHARE)
    one = constant("one", 1.0, t)
    scale0 = torch.rsqrt(sum_of_squares(a))  # (inf for a zero quaternion: 0 * inf is NaN below)
    scale1 = torch.rsqrt(sum_of_squares(b))
    # q1's scale takes the sign of the short arc, as the rows' test: - where <p, q> < -8 eps
    scale1 = copysign(scale1, torch.addcmul(_arc_tie(scale1, 1.0), sum_of_products(a, b), scale0 * scale1))
    chord = [torch.addcmul(x * scale0, y, scale1, value=-1.0) for x, y in zip(a, b)]  # p - q, unit p and q
    square = sum_of_squares(chord)
    small = square < constant("sqrt_eps", torch.finfo(square.dtype).eps ** 0.5, square)
    # the angle between p and q is 2 asin(c / 2) for the chord c: accurate at 0, and c^2 <= 2 after
    # the flip, far from asin's end; 1 in the series' band (smooth there to any order)
    angle = torch.asin(torch.sqrt(torch.where(small, one, square) * constant("quarter", 0.25, square)))
    angle = angle * constant("two", 2.0, angle)
    sine = torch.sin(angle)
    angle2 = torch.addcmul(square, square, square, value=1.0 / 12.0)
    times = (one - t, t)
    weights = [torch.where(small, _slerp_series(s, angle2), torch.sin(s * angle) / sine) for s in times]
    scales = (weights[0] * scale0, weights[1] * scale1)
    buffer = plane_buffer(4, [*a, *b, *scales], _PLANAR_SHARE)
    out = [torch.addcmul(scales[0] * x, scales[1], y, out=slot(buffer, i)) for i, (x, y) in enumerate(zip(a, b))]
    out = rows(out if buffer is None else buffer, share=_PLANAR_SHARE)
    return out, (*a, *b, *chord, scale0, scale1, square, small, angle, sine, angle2, *weights)


def _slerp_columns(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    return _slerp_columns_parts(q0, q1, t)[0]


def _slerp_weight_derivatives(s: Tensor, square: Tensor, small: Tensor, angle: Tensor, sine: Tensor,
                              cosine: Tensor, angle2: Tensor, weight: Tensor):
    """``d w / d square`` and ``d w / d s`` of the weight ``w = sin(s a) / sin(a)``, ``a`` the angle
    of the chord ``c`` (``square = c^2``, ``d a / d square = 1 / (2 sin a)``), or of its series."""
    s_angle = s * angle
    cos_s_angle = torch.cos(s_angle)
    # d w / d a = (s cos(s a) - w cos(a)) / sin(a)
    d_square = torch.addcmul(s * cos_s_angle, weight, cosine, value=-1.0) / (sine * sine * 2.0)
    d_s = angle * cos_s_angle / sine
    # the series w = s + s u A (1/6 + (4 + 3 u) A / 360), u = 1 - s^2, A = square + square^2 / 12
    u = torch.addcmul(constant("one", 1.0, s), s, s, value=-1.0)
    four_3u = torch.add(constant("four", 4.0, s), u, alpha=3.0)
    inner = torch.addcmul(constant("one_sixth", 1.0 / 6.0, s), four_3u, angle2, value=1.0 / 360.0)
    series_d_square = (s * u) * torch.addcmul(constant("one_sixth", 1.0 / 6.0, s), four_3u, angle2, value=1.0 / 180.0)
    series_d_square = series_d_square * torch.add(constant("one", 1.0, s), square, alpha=1.0 / 6.0)
    # d w / d s = 1 + u A I - 2 s^2 A (I + u A / 120)
    series_d_s = torch.addcmul(constant("one", 1.0, s), u * angle2, inner)
    series_d_s = torch.addcmul(series_d_s, (s * s) * angle2, torch.addcmul(inner, u, angle2, value=1.0 / 120.0), value=-2.0)
    return torch.where(small, series_d_square, d_square), torch.where(small, series_d_s, d_s)


def _slerp_columns_backward(grad: Tensor, inputs, saved):
    # out = w0 p + w1 q with unit p = scale0 a and q = scale1 b: with G0 = <g, p>, G1 = <g, q> and
    # W = G0 dw0/dS + G1 dw1/dS (S = |p - q|^2, dS = 2 <p - q, dp - dq>), the gradients are
    # scale0 (I - p p^T)(w0 g + 2 W (p - q)) and scale1 (I - q q^T)(w1 g - 2 W (p - q)), where
    # <p, p - q> = S / 2 = -<q, p - q> for unit p and q; and for t, G1 dw1/ds1 - G0 dw0/ds0
    # (about 80 passes, in place of autograd's backward through the forward's 70)
    t = inputs[2]
    a, b, chord = saved[:4], saved[4:8], saved[8:12]
    scale0, scale1, square, small, angle, sine, angle2, weight0, weight1 = saved[12:]
    g = columns(grad, share=_PLANAR_SHARE)
    g_p, g_q = scale0 * sum_of_products(g, a), scale1 * sum_of_products(g, b)
    cosine = torch.cos(angle)
    d0_square, d0_s = _slerp_weight_derivatives(constant("one", 1.0, t) - t, square, small, angle, sine, cosine, angle2, weight0)
    d1_square, d1_s = _slerp_weight_derivatives(t, square, small, angle, sine, cosine, angle2, weight1)
    w = torch.addcmul(g_p * d0_square, g_q, d1_square)
    w_square = w * square
    grads = []
    # scale0 (w0 g - (w0 G0 + W S) p + 2 W (p - q)), and scale1 (w1 g - (w1 G1 + W S) q - 2 W (p - q))
    for x, weight, g_x, scale, sign in ((a, weight0, g_p, scale0, 1.0), (b, weight1, g_q, scale1, -1.0)):
        along = torch.addcmul(w_square, weight, g_x) * (scale * scale)
        across, twice = weight * scale, w * (scale * (2.0 * sign))
        buffer = plane_buffer(4, [*x, *g, along], _PLANAR_SHARE)
        out = [torch.addcmul(torch.addcmul(across * gi, along, xi, value=-1.0), twice, ci, out=slot(buffer, i))
               for i, (gi, xi, ci) in enumerate(zip(g, x, chord))]
        grads.append(rows(out if buffer is None else buffer, share=_PLANAR_SHARE))
    return grads[0], grads[1], torch.addcmul(g_q * d1_s, g_p, d0_s, value=-1.0)


_SLERP_COLUMNWISE = Rule(_slerp_columns, _slerp_columns_parts, _slerp_columns_backward)


def _slerp_small(q0: Tensor, q1: Tensor, t: Tensor, share: float) -> bool:
    return is_small(q0, 4, share) and is_small(q1, 4, share) and is_small(t, 1, share)


@kernel(blocked_row_dims=(1, 1, 0), one_row=OneRow("quat_slerp", (4, 4, 1), (4,)))
def quat_slerp_unchecked(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    """Unchecked :func:`quat_slerp` of ``(..., 4)`` inputs with ``t`` of (broadcasting) batch shape."""
    if torch.compiler.is_compiling():  # (one fused loop, and autograd of it)
        return _slerp_columns(q0, q1, t)
    # both paths have a closed-form backward: with a gradient to record the columns' wins above
    # 1,024 rows (forward and backward 0.81x the rows' time at 2,048); without one, above 2,048
    # (forward 0.87x at 3,072, 0.79x at 4,096)
    if _slerp_small(q0, q1, t, 0.25) or (_slerp_small(q0, q1, t, 0.5) and not closed_form.records_graph((q0, q1, t))):
        return closed_form.apply(_SLERP_ROWS, q0, q1, t)
    return closed_form.apply(_SLERP_COLUMNWISE, q0, q1, t)


def quat_slerp(q0: Tensor, q1: Tensor, t: Union[float, Tensor]) -> Tensor:
    """Spherical linear interpolation along the shortest path (Shoemake 1985).

    ``q1`` is negated where ``<q0, q1> < 0`` so the arc is the short one (within ``8 eps`` of 0, for
    unit inputs, the arcs are equally short and ``q1`` is kept on every path). The angle comes from
    the chord ``|q0 - q1|`` of the normalised inputs (accurate near 0 and pi), and where its
    square is below ``sqrt(eps)`` the weights are their Taylor series to fourth order in the
    angle, so gradients, and second derivatives, are finite and exact at and near ``q0 == q1``.
    Batches up to 1,024 rows (2,048 without a gradient to record) go row by row, in few dispatches;
    larger ones column by column; both with a closed-form backward pass.

    Args:
        q0: start quaternions; other norms than 1 are normalised first (zero gives NaN).
        q1: end quaternions, likewise; batch dims broadcast with ``q0``'s.
        t: interpolation parameter, a float or a tensor broadcasting with the batch dims (a tensor
            on another device or in another dtype is copied to ``q0``'s: for a CPU ``t`` with GPU
            quaternions, a host-to-device copy; a float is filled in on the device, no copy).

    Returns:
        Unit quaternions; ``t = 0`` gives ``q0`` and ``t = 1`` gives ``+-q1``.

    Shape:
        ``(..., 4)``, ``(..., 4)``, ``(...)`` -> ``(..., 4)``.

    Example:
        >>> q0 = quat_identity(); q1 = torch.tensor([0., 0., 0., 1.])  # 180 deg about z
        >>> quat_slerp(q0, q1, 0.5)  # 90 deg about z
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    q0, q1, dtype = prepare_pair("quat_slerp", ("q0", "q1"), q0, q1, (4,), (4,))
    if isinstance(t, numbers.Real):  # (a number is filled in on the device: as_tensor would copy it from the host, a sync)
        t = torch.full((), float(t), dtype=q0.dtype, device=q0.device)
    elif isinstance(t, Tensor):
        if not t.dtype.is_floating_point:
            raise TypeError(f"quat_slerp: expected t to be a number or a floating-point tensor, got dtype {t.dtype}")
        t = t.to(device=q0.device, dtype=q0.dtype)
    else:  # a sequence of numbers
        try:
            t = torch.as_tensor(t, dtype=q0.dtype, device=q0.device)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(f"quat_slerp: expected t to be a number, numbers or a floating-point tensor, "
                            f"got {t!r}") from None
    if t.dim() > 0:  # (a number always broadcasts)
        check_broadcast("quat_slerp", ("q0", "q1", "t"), (q0, q1, t), (1, 1, 0))
    return restore(quat_slerp_unchecked(q0, q1, t), dtype)
