"""Quaternion algebra: products, conjugates, normalisation, rotation of vectors, slerp, sampling.

Quaternions are ``(..., 4)`` tensors ``(w, x, y, z)`` with the Hamilton product (``ij = k``).
These functions keep signs as the mathematics gives them; only the conversions that *produce*
a quaternion from another representation standardise to ``w >= 0``.
"""

import math
import numbers
from typing import Optional, Sequence, Union

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule
from ._dispatch import kernel
from ._math import (bilinear, bilinear_terms, constant, contract, is_small, outer_product, sum_of_products,
                    sum_of_squares)
from ._planes import columns, planar, plane_buffer, rows, slot
from ._validation import check_broadcast, prepare, prepare_pair, restore

__all__ = [
    "quat_multiply", "quat_conjugate", "quat_inverse", "quat_normalize", "quat_standardize",
    "quat_rotate", "quat_slerp", "quat_identity", "random_quat",
    "quat_wxyz_to_xyzw", "quat_xyzw_to_wxyz", "quat_from_jpl", "quat_to_jpl",
]


def _product_table():
    """16 x 4 table: ``(p q^T).flatten() @ T`` is the Hamilton product ``p q``."""
    basis = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))
    table = []
    for i in range(4):
        for j in range(4):
            table.append([float(c) for c in basis_product(basis[i], basis[j])])
    return table


def basis_product(a, b):
    """Hamilton product of two quaternions given as 4-tuples of Python numbers (exact for integers)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


_PRODUCT = _product_table()
_PLANAR_SHARE = 0.25  # the product and rotating vectors: contiguous columns from 8,192 rows (measured)
CONJUGATE_SIGNS = [1.0, -1.0, -1.0, -1.0]
# p conj(q) and conj(p) q, for the product's gradients
_PRODUCT_TERMS = bilinear_terms(_PRODUCT, 4)
_PRODUCT_CONJUGATE_RIGHT = bilinear_terms([[c * CONJUGATE_SIGNS[r % 4] for c in row] for r, row in enumerate(_PRODUCT)], 4)
_PRODUCT_CONJUGATE_LEFT = bilinear_terms([[c * CONJUGATE_SIGNS[r // 4] for c in row] for r, row in enumerate(_PRODUCT)], 4)


def _product_columnwise_parts(p: Tensor, q: Tensor):
    """The product column by column, and its inputs' columns (for the closed-form backward)."""
    a, b = columns(p, share=_PLANAR_SHARE), columns(q, share=_PLANAR_SHARE)
    return rows(bilinear(a, b, _PRODUCT_TERMS, out=plane_buffer(4, a + b, _PLANAR_SHARE)), share=_PLANAR_SHARE), (*a, *b)


def _product_columnwise(p: Tensor, q: Tensor) -> Tensor:
    return _product_columnwise_parts(p, q)[0]


def _product_columnwise_backward(grad: Tensor, inputs, saved):
    # d(p q) = dp q + p dq, and right (left) multiplication by q has the transpose of right (left)
    # multiplication by conj(q): 2 products of 16 terms, against autograd's ~100 nodes.
    p, q = saved[:4], saved[4:]  # (the forward's columns: no second transpose)
    g = columns(grad, share=_PLANAR_SHARE)
    return (rows(bilinear(g, q, _PRODUCT_CONJUGATE_RIGHT, out=plane_buffer(4, g, _PLANAR_SHARE)), share=_PLANAR_SHARE),
            rows(bilinear(p, g, _PRODUCT_CONJUGATE_LEFT, out=plane_buffer(4, g, _PLANAR_SHARE)), share=_PLANAR_SHARE))


_PRODUCT_COLUMNWISE = Rule(_product_columnwise, _product_columnwise_parts, _product_columnwise_backward,
                           _product_columnwise)


@kernel(blocked_row_dims=(1, 1))
def hamilton_product(p: Tensor, q: Tensor) -> Tensor:
    """Unchecked Hamilton product of prepared tensors (used internally)."""
    if is_small(p, 4, gpu_share=4) and is_small(q, 4, gpu_share=4):
        return contract(outer_product(p, q), "product", _PRODUCT)
    if torch.compiler.is_compiling():
        return _product_columnwise(p, q)
    return closed_form.apply(_PRODUCT_COLUMNWISE, p, q)


def quat_multiply(p: Tensor, q: Tensor) -> Tensor:
    """Hamilton product ``p * q`` (apply ``q`` first, then ``p``).

    Args:
        p: quaternions ``(w, x, y, z)``.
        q: quaternions ``(w, x, y, z)``; batch dims broadcast with ``p``'s.

    Returns:
        The product, unnormalised, with signs as the algebra gives them.

    Shape:
        ``(..., 4)`` and ``(..., 4)`` -> ``(..., 4)`` (broadcast batch).

    Example:
        >>> i = torch.tensor([0., 1., 0., 0.]); j = torch.tensor([0., 0., 1., 0.])
        >>> quat_multiply(i, j)  # ij = k
        tensor([0., 0., 0., 1.])
    """
    p, q, dtype = prepare_pair("quat_multiply", ("p", "q"), p, q, (4,), (4,))
    return restore(hamilton_product(p, q), dtype)


def quat_conjugate(q: Tensor) -> Tensor:
    """Conjugate ``(w, -x, -y, -z)``: the inverse rotation for a unit quaternion.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_conjugate(torch.tensor([1., 2., 3., 4.]))
        tensor([ 1., -2., -3., -4.])
    """
    q, dtype = prepare(q, "quat_conjugate", "q", (4,))
    return restore(q * constant("conjugate", CONJUGATE_SIGNS, q), dtype)


def quat_inverse(q: Tensor) -> Tensor:
    """Multiplicative inverse ``conj(q) / |q|^2`` (NaN for the zero quaternion).

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_inverse(torch.tensor([0., 2., 0., 0.]))
        tensor([ 0.0000, -0.5000, -0.0000, -0.0000])
    """
    q, dtype = prepare(q, "quat_inverse", "q", (4,))
    inv = q * constant("conjugate", CONJUGATE_SIGNS, q) / (q * q).sum(-1, keepdim=True)
    return restore(inv, dtype)


def quat_normalize(q: Tensor) -> Tensor:
    """Scale to unit norm; the zero quaternion gives NaN (no rotation is plausible for it).

    Any finite norm works, even where ``|q|^2`` would overflow or underflow (1e20 or 1e-20 in
    float32): ``q`` is first divided by its largest ``|component|``. So this is the cure for
    quaternions whose norm the other functions' squares cannot take.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_normalize(torch.tensor([2., 0., 0., 0.]))
        tensor([1., 0., 0., 0.])
    """
    q, dtype = prepare(q, "quat_normalize", "q", (4,))
    return restore(normalized(q / q.abs().amax(-1, keepdim=True)), dtype)  # (0 / 0: NaN for q = 0)


def normalized(q: Tensor) -> Tensor:
    """Unchecked ``q / |q|`` with NaN (not inf or 0) for zero vectors."""
    return q * torch.rsqrt((q * q).sum(-1, keepdim=True))


def standardize_sign(q: Tensor, magnitude: Optional[Tensor] = None) -> Tensor:
    """Unchecked: the sign (+-1, shape ``(..., 1)``) that makes ``q`` canonical, or ``magnitude``
    (broadcasting with ``(..., 1)``) with that sign.

    Canonical means ``w > 0``, or ``w == 0`` and the first non-zero of ``x, y, z`` positive,
    so that every rotation has exactly one representative (SciPy's canonical form).
    """
    # sign(8 sign(w) + 4 sign(x) + 2 sign(y) + sign(z)) is the sign of the first non-zero
    # component (each weight exceeds the sum of the later ones): 3 ops instead of nested wheres.
    key = contract(torch.sign(q), "lexicographic", [8.0, 4.0, 2.0, 1.0])
    return torch.copysign(constant("one", 1.0, q) if magnitude is None else magnitude,
                          key.unsqueeze(-1))  # key = +0 only for q = 0


@kernel
def standardized(q: Tensor) -> Tensor:
    """Unchecked ``q * standardize_sign(q)``."""
    return q * standardize_sign(q)


def quat_standardize(q: Tensor) -> Tensor:
    """Pick the representative with ``w >= 0`` (``q`` and ``-q`` are the same rotation).

    When ``w == 0`` (a half turn) the first non-zero of ``x, y, z`` is made positive, so the
    result is unique for every rotation.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_standardize(torch.tensor([-1., 0., 0., 0.]))
        tensor([1., -0., -0., -0.])
    """
    q, dtype = prepare(q, "quat_standardize", "q", (4,))
    return restore(standardized(q), dtype)


def quat_rotate(q: Tensor, v: Tensor) -> Tensor:
    """Rotate 3-vectors: ``q (0, v) q*`` for unit ``q``, computed as ``t = 2 q_vec x v``,
    ``v' = v + w t + q_vec x t``.

    A non-unit ``q`` rotates by ``q / |q|`` (``t`` is divided by ``|q|^2``), matching
    :func:`quat_to_matrix`; the zero quaternion gives NaN.

    Args:
        q: quaternions ``(w, x, y, z)``.
        v: vectors; batch dims broadcast with ``q``'s (one rotation for many points or one each).

    Returns:
        The rotated vectors.

    Shape:
        ``(..., 4)`` and ``(..., 3)`` -> ``(..., 3)`` (broadcast batch).

    Example:
        >>> q = torch.tensor([math.cos(math.pi / 4), 0., 0., math.sin(math.pi / 4)])  # 90 deg about z
        >>> quat_rotate(q, torch.tensor([1., 0., 0.])).round(decimals=6) + 0.0  # + 0.0 turns -0. into 0.
        tensor([0., 1., 0.])
    """
    q, v, dtype = prepare_pair("quat_rotate", ("q", "v"), q, v, (4,), (3,))
    return restore(rotate_unchecked(q, v), dtype)


@kernel(blocked_row_dims=(1, 1))
def rotate_unchecked(q: Tensor, v: Tensor) -> Tensor:
    if torch.compiler.is_compiling() or planar(q, 4, _PLANAR_SHARE) or planar(v, 3, _PLANAR_SHARE):  # (one fused loop under compile)
        q, (a, b, c) = columns(q, share=_PLANAR_SHARE), columns(v, share=_PLANAR_SHARE)
        w, x, y, z = q
        scale = 2.0 / sum_of_squares(q)
        tx = torch.addcmul(y * c, z, b, value=-1.0) * scale
        ty = torch.addcmul(z * a, x, c, value=-1.0) * scale
        tz = torch.addcmul(x * b, y, a, value=-1.0) * scale
        buffer = plane_buffer(3, (*q, a), _PLANAR_SHARE)  # (forward only: autograd refuses out=)
        rotated = [torch.addcmul(torch.addcmul(torch.addcmul(a, w, tx), y, tz), z, ty, value=-1.0, out=slot(buffer, 0)),
                   torch.addcmul(torch.addcmul(torch.addcmul(b, w, ty), z, tx), x, tz, value=-1.0, out=slot(buffer, 1)),
                   torch.addcmul(torch.addcmul(torch.addcmul(c, w, tz), x, ty), y, tx, value=-1.0, out=slot(buffer, 2))]
        return rows(rotated if buffer is None else buffer, share=_PLANAR_SHARE)
    w, u = q.narrow(-1, 0, 1), q.narrow(-1, 1, 3)
    u, v = torch.broadcast_tensors(u, v)  # linalg.cross wants equal ndim; these are views
    t = torch.linalg.cross(u, v, dim=-1) * (constant("two", 2.0, q) / (q * q).sum(-1, keepdim=True))
    return v + w * t + torch.linalg.cross(u, t, dim=-1)


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


def _slerp_rows(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    """Small batches, row by row (few dispatches); ``t`` shaped ``(..., 1)``."""
    # (constants as tensors: a Python number is wrapped into a tensor on every call, 1 us each)
    one = constant("one", 1.0, q0)
    q0, q1 = normalized(q0), normalized(q1)  # (a zero quaternion gives NaN, as everywhere, not a plausible rotation)
    q1 = q1 * torch.where((q0 * q1).sum(-1, keepdim=True) < _arc_tie(q0, -1.0), constant("minus_one", -1.0, q0), one)
    difference = q0 - q1
    square = (difference * difference).sum(-1, keepdim=True)
    # Below |q0 - q1|^2 = sqrt(eps) the series: autograd's second derivatives of the closed form
    # lose eps / angle^2 relative, and the series' next term is below eps
    small = square < constant("sqrt_eps", torch.finfo(q0.dtype).eps ** 0.5, q0)
    # (the square root of 1 where the chord is that short: smooth to any order at q0 = q1, where a
    # norm's second derivative is NaN; |q0 + q1| >= sqrt(2) after the flip)
    chord = torch.sqrt(torch.where(small, one, square))
    angle = torch.where(small, one, constant("two", 2.0, q0) * torch.atan2(chord, torch.linalg.vector_norm(q0 + q1, dim=-1, keepdim=True)))
    times = torch.cat((one - t, t), dim=-1)  # both weights, one sine
    # a^2 = c^2 + c^4 / 12 + O(c^6) for the chord c = |q0 - q1| = 2 sin(a / 2)
    series = _slerp_series(times, torch.addcmul(square, square, square, value=1.0 / 12.0))
    weights = torch.where(small, series, torch.sin(times * angle) / torch.sin(angle))
    return torch.addcmul(weights[..., :1] * q0, weights[..., 1:], q1)


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
    scale1 = torch.copysign(scale1, torch.addcmul(_arc_tie(scale1, 1.0), sum_of_products(a, b), scale0 * scale1))
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


@kernel(blocked_row_dims=(1, 1, 0))
def quat_slerp_unchecked(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    """Unchecked :func:`quat_slerp` of ``(..., 4)`` inputs with ``t`` of (broadcasting) batch shape."""
    if torch.compiler.is_compiling():  # (one fused loop, and autograd of it)
        return _slerp_columns(q0, q1, t)
    # with a gradient to record, the columns' closed form wins above 512 rows (forward and backward
    # 0.87x the rows' time at 1,000); without one, above 2,048 (0.87x at 3,072, 0.79x at 4,096)
    if _slerp_small(q0, q1, t, 0.125) or (_slerp_small(q0, q1, t, 0.5) and not closed_form.records_graph((q0, q1, t))):
        return _slerp_rows(q0, q1, t.unsqueeze(-1))
    return closed_form.apply(_SLERP_COLUMNWISE, q0, q1, t)


def quat_slerp(q0: Tensor, q1: Tensor, t: Union[float, Tensor]) -> Tensor:
    """Spherical linear interpolation along the shortest path (Shoemake 1985).

    ``q1`` is negated where ``<q0, q1> < 0`` so the arc is the short one (within ``8 eps`` of 0, for
    unit inputs, the arcs are equally short and ``q1`` is kept on every path). The angle comes from
    the chord ``|q0 - q1|`` of the normalised inputs (accurate near 0 and pi), and where its
    square is below ``sqrt(eps)`` the weights are their Taylor series to fourth order in the
    angle, so gradients, and second derivatives, are finite and exact at and near ``q0 == q1``.
    Batches up to 512 rows (2,048 without a gradient to record) go row by row, in few dispatches;
    larger ones column by column, with a closed-form backward pass.

    Args:
        q0: start quaternions; other norms than 1 are normalised first (zero gives NaN).
        q1: end quaternions, likewise; batch dims broadcast with ``q0``'s.
        t: interpolation parameter, a float or a tensor broadcasting with the batch dims.

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
        t = torch.as_tensor(t, dtype=q0.dtype, device=q0.device)
    if t.dim() > 0:  # (a number always broadcasts)
        check_broadcast("quat_slerp", ("q0", "q1", "t"), (q0, q1, t), (1, 1, 0))
    return restore(quat_slerp_unchecked(q0, q1, t), dtype)


def quat_identity(shape: Union[int, Sequence[int]] = (), *, dtype=None, device=None) -> Tensor:
    """Identity quaternions ``(1, 0, 0, 0)``.

    Shape:
        ``shape`` -> ``(*shape, 4)``.

    Example:
        >>> quat_identity(2)
        tensor([[1., 0., 0., 0.],
                [1., 0., 0., 0.]])
    """
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    q = torch.zeros(shape + (4,), dtype=dtype, device=device)
    q[..., 0] = 1.0  # a fresh tensor we own: writing into it changes no input
    return q


def random_quat(shape: Union[int, Sequence[int]] = (), *, generator=None, dtype=None,
                device=None) -> Tensor:
    """Rotations drawn uniformly from SO(3) (Shoemake 1992, "Uniform random rotations").

    Args:
        shape: batch shape.
        generator: a ``torch.Generator`` for reproducible draws.
        dtype: defaults to ``torch.get_default_dtype()``.
        device: where to create the tensor.

    Returns:
        Unit quaternions; signs are as drawn (both hemispheres occur).

    Shape:
        ``shape`` -> ``(*shape, 4)``.

    Example:
        >>> q = random_quat(1000, generator=torch.Generator().manual_seed(0))
        >>> bool(torch.allclose(q.norm(dim=-1), torch.ones(1000)))
        True
    """
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    dtype = torch.get_default_dtype() if dtype is None else dtype
    work = torch.float32 if dtype in (torch.float16, torch.bfloat16) else dtype
    u = torch.rand(shape + (3,), generator=generator, dtype=work, device=device)
    u1, u2, u3 = u.unbind(-1)
    r1, r2 = torch.sqrt(1.0 - u1), torch.sqrt(u1)
    a2, a3 = 2.0 * math.pi * u2, 2.0 * math.pi * u3
    q = torch.stack((r2 * torch.cos(a3), r1 * torch.sin(a2), r1 * torch.cos(a2), r2 * torch.sin(a3)), -1)
    return q.to(dtype)


def quat_wxyz_to_xyzw(q: Tensor) -> Tensor:
    """Reorder scalar-first ``(w, x, y, z)`` to scalar-last ``(x, y, z, w)`` (SciPy, ROS, RoMa).

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_wxyz_to_xyzw(torch.tensor([1., 2., 3., 4.]))
        tensor([2., 3., 4., 1.])
    """
    q, dtype = prepare(q, "quat_wxyz_to_xyzw", "q", (4,))
    return restore(q.roll(-1, dims=-1), dtype)


def quat_xyzw_to_wxyz(q: Tensor) -> Tensor:
    """Reorder scalar-last ``(x, y, z, w)`` to scalar-first ``(w, x, y, z)``.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_xyzw_to_wxyz(torch.tensor([2., 3., 4., 1.]))
        tensor([1., 2., 3., 4.])
    """
    q, dtype = prepare(q, "quat_xyzw_to_wxyz", "q", (4,))
    return restore(q.roll(1, dims=-1), dtype)


def quat_from_jpl(q: Tensor) -> Tensor:
    """JPL quaternion ``(x, y, z, w)`` (scalar last, ``ij = -k``) to the Hamilton quaternion with
    the same rotation matrix.

    Trawny and Roumeliotis (2005) give ``C(q) = (2w^2 - 1) I - 2w [q_vec x] + 2 q_vec q_vec^T``,
    which is ``quat_to_matrix((w, -x, -y, -z))``.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_from_jpl(torch.tensor([1., 2., 3., 4.]))
        tensor([ 4., -1., -2., -3.])
    """
    q, dtype = prepare(q, "quat_from_jpl", "q", (4,))
    return restore(q.roll(1, dims=-1) * constant("conjugate", CONJUGATE_SIGNS, q), dtype)


def quat_to_jpl(q: Tensor) -> Tensor:
    """Hamilton quaternion ``(w, x, y, z)`` to the JPL quaternion ``(-x, -y, -z, w)``; inverse of
    :func:`quat_from_jpl`.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_to_jpl(torch.tensor([4., -1., -2., -3.]))
        tensor([1., 2., 3., 4.])
    """
    q, dtype = prepare(q, "quat_to_jpl", "q", (4,))
    return restore(q.roll(-1, dims=-1) * constant("jpl_signs", [-1.0, -1.0, -1.0, 1.0], q), dtype)
