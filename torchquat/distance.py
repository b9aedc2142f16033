"""Geodesic distances between rotations (the rotation angle of ``a^-1 b``), in radians."""

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule
from ._dispatch import kernel
from ._one_row import OneRow
from ._polynomials import atan2
from ._math import constant, is_small, literal, norm_twice_differentiable, safe_sqrt, sum_of_products, sum_of_squares, zero_to_inf
from ._planes import columns, planar, plane_buffer, rows, slot
from ._validation import prepare_pair, restore

__all__ = ["quat_geodesic_distance", "matrix_geodesic_distance"]
# contiguous columns from 16,384 rows (quaternions) and 8,192 (matrices): measured crossovers
_QUAT_PLANAR_SHARE, _MATRIX_PLANAR_SHARE = 0.5, 0.25


def _quat_distance_parts(q1: Tensor, q2: Tensor, differentiable_twice: bool = False):
    """The distance, and what the closed-form backward needs. ``differentiable_twice``: chord
    lengths whose derivatives of every order are 0 at a zero chord (``vector_norm``'s second
    derivative there is NaN), the same numbers: for the plain forward, which serves double
    backward and ``torch.func``."""
    # For unit p, q at half-angle a apart (<p, q> = cos a): |p - q| = 2 sin(a/2) and
    # |p + q| = 2 cos(a/2), so the angle 2a is 4 atan2(|p - q|, |p + q|); taking the smaller of
    # the two norms over the larger picks the nearer of q and -q (sign invariance). Both norms
    # keep full precision at 0 and pi, the difference is exactly 0 for equal inputs, and
    # vector_norm's gradient there is 0 (not NaN): the kink of the distance.
    r1 = torch.linalg.vector_norm(q1, dim=-1, keepdim=True)
    r2 = torch.linalg.vector_norm(q2, dim=-1, keepdim=True)
    p = q1 / r1  # 0 / 0 = NaN for a zero quaternion
    q = q2 / r2
    chords = torch.stack((p - q, p + q), dim=-2)
    lengths = norm_twice_differentiable(chords) if differentiable_twice else torch.linalg.vector_norm(chords, dim=-1)
    shorter, longer = lengths.amin(-1), lengths.amax(-1)  # (torch 2.11's aminmax has no derivative)
    return torch.atan2(shorter, longer) * constant("four", 4.0, shorter), (p, q, r1, r2, chords, lengths)


def _quat_distance_small(q1: Tensor, q2: Tensor) -> Tensor:
    return _quat_distance_parts(q1, q2, differentiable_twice=True)[0]


def _tangent(g: Tensor, p: Tensor, r: Tensor) -> Tensor:
    """The gradient through ``p = q / r`` (``|p| = 1``): ``g`` less its component along ``p``, over ``r``."""
    return torch.addcmul(g, p, (p * g).sum(-1, keepdim=True), value=-1.0) / r


def _quat_distance_backward(grad: Tensor, inputs, saved):
    p, q, r1, r2, chords, n = saved
    # With n0^2 + n1^2 = 4, d 4 atan2(min, max) = sigma (n1 dn0 - n0 dn1), sigma = sign(n1 - n0):
    # 0 at the tie (distance pi, a maximum), where amin and amax split the gradient evenly.
    v = n @ constant("swap_negate", ((0.0, -1.0), (1.0, 0.0)), n)  # (n1, -n0)
    dn = v * (torch.sign(v.sum(-1, keepdim=True)) * grad.unsqueeze(-1))
    # dn = u . dC with u = C / |C|, or 0 for a zero chord (as vector_norm's gradient)
    g0, g1 = (chords * (dn / zero_to_inf(n)).unsqueeze(-1)).unbind(-2)
    # C = (p - q, p + q). The sums are tangent only in exact arithmetic: near distance 0 the
    # rounding of |p| = 1 is amplified by n1 / n0, so the projection is not skipped.
    return _tangent(g0 + g1, p, r1), _tangent(g1 - g0, q, r2)


def _quat_distance_values(q1: Tensor, q2: Tensor) -> Tensor:
    return _quat_distance_parts(q1, q2)[0]  # (the plain forward's numbers, with vector_norm: 12 operations, not 17)


_QUAT_DISTANCE = Rule(_quat_distance_small, _quat_distance_parts, _quat_distance_backward, _quat_distance_values)


@kernel(blocked_row_dims=(1, 1), compiled_from_rows=512, polynomial_atan2=True, one_row=OneRow("quat_geodesic_distance", (4, 4), ()))
def quat_geodesic_distance_unchecked(q1: Tensor, q2: Tensor) -> Tensor:
    # (the columns' forward wins from about 1,536 rows, 0.63x the time at 4,096, but squares
    # products of the inputs: their narrower norm range stays above 4,096 rows, on both modes)
    if is_small(q1, 4) and is_small(q2, 4):
        return closed_form.apply(_QUAT_DISTANCE, q1, q2)
    if torch.compiler.is_compiling():
        return _QUAT_DISTANCE_TRACED(q1, q2)
    return closed_form.apply(_QUAT_DISTANCE_COLUMNWISE, q1, q2)


_MINOR_PAIRS = tuple((i, j) for i in range(4) for j in range(i + 1, 4))


def _quat_distance_columnwise_parts(q1: Tensor, q2: Tensor, safe: bool = False):
    """The same distance from Lagrange's identity, column by column, with no normalisation: fewer
    passes for large batches (39 against 57 ms per 1e6, eager), one fused loop under ``torch.compile``.

    The 6 minors ``p_i q_j - p_j q_i`` have ``sum m^2 = |p|^2 |q|^2 - <p, q>^2``, so half the
    distance is ``atan2(|m|, |<p, q>|)`` for any non-zero scale. Each minor keeps full absolute
    precision at distance 0 (exactly 0 for equal inputs, where ``safe_sqrt``'s gradient is 0) and
    ``<p, q>`` at pi (where ``abs``'s gradient is 0, the maximum's kink). ``sum m^2 + <p, q>^2`` is 0
    only for a zero quaternion, which gives NaN. Returns the distance and what the closed-form
    backward needs; ``safe``: a norm whose gradient is 0 at 0 (for autograd; the closed form sets it).
    """
    a, b = columns_a, columns_b = columns(q1, share=_QUAT_PLANAR_SHARE), columns(q2, share=_QUAT_PLANAR_SHARE)
    dot = sum_of_products(a, b)
    if torch.compiler.is_compiling():
        # Code generators contract a*b - c*d into fma(a, b, -(c*d)), which leaves c*d's rounding
        # error (not 0) for equal inputs, and so an O(1) gradient at the kink instead of 0 (seen
        # with Triton). With d = b -+ a, exactly 0 for b = +-a, the minors a_i d_j - a_j d_i are
        # the same numbers and exactly 0 there, contracted or not.
        sign = torch.where(dot < 0, -1.0, 1.0)
        b = [torch.addcmul(y, x, sign, value=-1.0) for x, y in zip(a, b)]
    minors = [a[i] * b[j] - a[j] * b[i] for i, j in _MINOR_PAIRS]
    wedge2 = minors[0] * minors[0]
    for m in minors[1:]:
        wedge2 = torch.addcmul(wedge2, m, m)
    norms2 = torch.addcmul(wedge2, dot, dot)  # |q1|^2 |q2|^2: 0 only for a zero quaternion
    wedge = safe_sqrt(wedge2) if safe else torch.sqrt(wedge2)
    # (atan2's (0, 0) and (inf, inf) cases: a zero quaternion, or an infinity, is NaN below anyway)
    angle = 2.0 * atan2(wedge, dot.abs(), y_nonnegative=True, x_nonnegative=True, special_values=False)
    if safe:  # (under autograd: (n - n) / n is exactly 0, and its gradient too, for n > 0, and NaN
        # for n = 0, value and gradient; a where's NaN branch would give that row a zero gradient)
        distance = angle + (norms2 - norms2) / norms2
    else:
        distance = torch.where(norms2 > 0, angle, torch.nan)
    return distance, (dot, wedge, wedge2, *minors, *columns_a, *columns_b)


def _quat_distance_columnwise(q1: Tensor, q2: Tensor) -> Tensor:
    return _quat_distance_columnwise_parts(q1, q2, safe=True)[0]


def _minor_contraction(minors, v, k: int):
    """``sum_j M[k][j] v_j`` for the antisymmetric M of the minors (``M[i][j] = m_ij`` for ``i < j``),
    as ``(s, sum)`` with the sum to be multiplied by the sign ``s``."""
    terms = [(1.0, m, v[j]) if i == k else (-1.0, m, v[i]) for (i, j), m in zip(_MINOR_PAIRS, minors) if k in (i, j)]
    sign, m, x = terms[0]
    total = m * x
    for s, m, x in terms[1:]:
        total = torch.addcmul(total, m, x, value=s * sign)
    return sign, total


def _quat_distance_columnwise_backward(grad: Tensor, inputs, saved):
    # theta = 2 atan2(W, |d|), W = |minors|, d = <a, b>: d theta = 2 (|d| dW - W sign(d) dd) / (W^2 + d^2),
    # dW/da = M b / W and dW/db = -M a / W (the minors keep them accurate near distance 0, where
    # |b|^2 a - d b would cancel); 0 at W = 0 (the kink, as safe_sqrt's) and at d = 0 (abs's).
    dot, wedge, wedge2, *rest = saved
    minors, a, b = rest[:6], rest[6:10], rest[10:]  # (the forward's columns: no second transpose)
    c = grad * 2.0 / torch.addcmul(wedge2, dot, dot)
    alpha = c * dot.abs() / zero_to_inf(wedge)
    beta = c * wedge * torch.sign(dot)
    alphas = {1.0: alpha, -1.0: -alpha}
    buffers = plane_buffer(4, a + b, _QUAT_PLANAR_SHARE), plane_buffer(4, a + b, _QUAT_PLANAR_SHARE)
    g_a, g_b = [], []
    for k in range(4):
        sign, total = _minor_contraction(minors, b, k)
        g_a.append(torch.addcmul(alphas[sign] * total, beta, b[k], value=-1.0, out=slot(buffers[0], k)))
        sign, total = _minor_contraction(minors, a, k)
        g_b.append(torch.addcmul(alphas[-sign] * total, beta, a[k], value=-1.0, out=slot(buffers[1], k)))
    return tuple(rows(g if buffer is None else buffer, share=_QUAT_PLANAR_SHARE) for g, buffer in zip((g_a, g_b), buffers))


_QUAT_DISTANCE_COLUMNWISE = Rule(_quat_distance_columnwise, _quat_distance_columnwise_parts,
                                 _quat_distance_columnwise_backward,
                                 lambda q1, q2: _quat_distance_columnwise_parts(q1, q2)[0])


_QUAT_DISTANCE_TRACED = closed_form.traced_rule(_QUAT_DISTANCE_COLUMNWISE)


def quat_geodesic_distance(q1: Tensor, q2: Tensor) -> Tensor:
    """Angle of the rotation between two quaternions, sign-invariant (``q`` and ``-q`` agree).

    Computed as ``4 atan2(min(|p - q|, |p + q|), max(...))`` of the normalised inputs (small
    batches), or as the equal ``2 atan2(|q1 ^ q2|, |<q1, q2>|)`` by Lagrange's identity (large
    batches and compiled kernels: no normalisation, fewer passes). Both are accurate near 0 and
    pi, where ``2 acos(|<q1, q2>|)`` loses half its digits and has an infinite gradient. The
    gradient is finite everywhere (0 at distance 0, the kink of the distance).

    Args:
        q1: quaternions ``(w, x, y, z)``, any non-zero norm whose square is a normal number
            (about 1e-19 to 1e19 in float32, 1e-153 to 1e154 in float64); on the large-batch path (above
            4,096 rows on the CPU, and compiled), norms between about 3e-10 and 4e9 (float32) or
            1e-77 and 1e77 (float64), where the squared minors neither underflow (below, the
            distance loses precision, and is NaN below about 6e-12 in float32) nor overflow
            (above, it is wrong). Normalise other inputs first (:func:`quat_normalize`).
        q2: quaternions; batch dims broadcast with ``q1``'s.

    Returns:
        Angles in ``[0, pi]``.

    Shape:
        ``(..., 4)`` and ``(..., 4)`` -> ``(...)``.

    Example:
        >>> quat_geodesic_distance(torch.tensor([1., 0., 0., 0.]), torch.tensor([0., 0., 0., -1.]))
        tensor(3.1416)
    """
    if (out := quat_geodesic_distance_unchecked.at_one_row(q1, q2)) is not None:
        return out
    q1, q2, dtype = prepare_pair("quat_geodesic_distance", ("q1", "q2"), q1, q2, (4,), (4,))
    return restore(quat_geodesic_distance_unchecked(q1, q2), dtype)


@kernel(blocked_row_dims=(2, 2), compiled_from_rows=1_024, polynomial_atan2=True,
        one_row=OneRow("matrix_geodesic_distance", (9, 9), ()))
def matrix_geodesic_distance_unchecked(R1: Tensor, R2: Tensor) -> Tensor:
    if torch.compiler.is_compiling():
        return _MATRIX_DISTANCE_TRACED(R1, R2)
    if planar(R1, 9, _MATRIX_PLANAR_SHARE) or planar(R2, 9, _MATRIX_PLANAR_SHARE):
        return closed_form.apply(_MATRIX_DISTANCE_COLUMNWISE, R1, R2)
    if R1.dim() != R2.dim():  # linalg.cross broadcasts batch dims but needs equal ranks
        R1, R2 = torch.broadcast_tensors(R1, R2)
    # For M = R1^T R2, tr M = sum(R1 * R2): no matrix product is needed.
    # vee(M - M^T) = sum_k (R1 column k) x (R2 column k), and R1's own columns contribute
    # nothing, so cross with R2 - R1: exactly 0 for equal inputs (no rounding noise, hence a zero
    # gradient at zero distance) and no cancellation for close ones.
    vee = torch.linalg.cross(R1, R2 - R1, dim=-2).sum(-1)
    trace = (R1 * R2).sum((-2, -1))
    # tan(angle) = |vee| / (tr M - 1): both keep full precision at 0 and pi.
    return torch.atan2(torch.linalg.vector_norm(vee, dim=-1), trace - constant("one", 1.0, trace))


def _matrix_distance_columnwise_parts(R1: Tensor, R2: Tensor, safe: bool = False):
    """The same, column by column: for large eager batches (contiguous columns: 45 passes of 1-D
    columns beat ``linalg.cross`` and reductions over dimensions of 3) and for ``torch.compile``
    (one fused vectorised loop). Returns the distance and what the closed-form backward needs;
    ``safe``: a norm whose gradient is 0 at 0 (for autograd; the closed form sets it)."""
    a, b = (columns(R.flatten(-2), share=_MATRIX_PLANAR_SHARE) for R in (R1, R2))
    d = [y - x for x, y in zip(a, b)]
    vee = []
    for j, l in ((1, 2), (2, 0), (0, 1)):  # sum over columns k of (R1 col k) x (d col k)
        total = a[3 * j] * d[3 * l]
        for k in range(3):
            if k:
                total = torch.addcmul(total, a[3 * j + k], d[3 * l + k])
            total = torch.addcmul(total, a[3 * l + k], d[3 * j + k], value=-1.0)
        vee.append(total)
    trace = sum_of_products(a, b)
    wedge2 = sum_of_squares(vee)
    wedge, cosine = safe_sqrt(wedge2) if safe else torch.sqrt(wedge2), trace - 1.0
    return atan2(wedge, cosine, y_nonnegative=True), (wedge2, wedge, cosine, *vee, *a, *b)


def _matrix_distance_columnwise(R1: Tensor, R2: Tensor) -> Tensor:
    return _matrix_distance_columnwise_parts(R1, R2, safe=True)[0]


# K = alpha A - beta I as (sign, factor) per entry, A the antisymmetric matrix of the cross terms:
# A[1][2] = v0, A[2][0] = v1, A[0][1] = v2 (factor k: u_k = alpha v_k; factor 3: beta)
_DISTANCE_K = (((-1.0, 3), (1.0, 2), (-1.0, 1)), ((-1.0, 2), (-1.0, 3), (1.0, 0)), ((1.0, 1), (-1.0, 0), (-1.0, 3)))


def _signed_terms(transpose: bool):
    """For each entry ``(i, j)`` of ``K X`` (or ``K^T X``): ``(sign, factor, row of X)`` for its three
    terms, a positive one first (each row and column of K has one), built once."""
    entry = (lambda i, m: _DISTANCE_K[m][i]) if transpose else (lambda i, m: _DISTANCE_K[i][m])
    return tuple(tuple(sorted(((*entry(i, m), m) for m in range(3)), key=lambda t: -t[0])) for i in range(3))


_DISTANCE_TERMS = {False: _signed_terms(False), True: _signed_terms(True)}


def _times_matrix(factors, X, transpose: bool):
    """``K X`` (or ``K^T X``) entry by entry, K's entries as signed ``factors``, X as 9 columns:
    side by side (written into a ``plane_buffer`` where there is one)."""
    buffer = plane_buffer(9, [*factors, *X], _MATRIX_PLANAR_SHARE)
    out = []
    for terms in literal(_DISTANCE_TERMS[transpose]):  # (read as literals of a trace, not its inputs)
        (_, k, m), rest = terms[0], terms[1:]
        for j in range(3):
            total = factors[k] * X[3 * m + j]
            for n, (sign, k2, m2) in enumerate(rest, 1):
                total = torch.addcmul(total, factors[k2], X[3 * m2 + j], value=sign,
                                      out=slot(buffer, len(out)) if n == len(rest) else None)
            out.append(total)
    return rows(out if buffer is None else buffer, share=_MATRIX_PLANAR_SHARE)


def _matrix_distance_columnwise_backward(grad: Tensor, inputs, saved):
    # theta = atan2(W, c), W = |v|, c = tr(R1 R2^T) - 1: d theta = (c dW - W dc) / (W^2 + c^2), with
    # W dW = <dN, A> for N = R1 R2^T and A antisymmetric in v, and dc = <dN, I>. So the gradients
    # are K R2 and K^T R1 with K = g (c / (W (W^2 + c^2)) A - W / (W^2 + c^2) I): 54 products in
    # place of autograd's backward through the 45 forward passes. 0 at W = 0 (safe_sqrt's kink).
    wedge2, wedge, cosine, *rest = saved
    vee, a, b = rest[:3], rest[3:12], rest[12:]  # (the forward's columns: no second transpose)
    s = grad / torch.addcmul(wedge2, cosine, cosine)
    alpha = s * cosine / zero_to_inf(wedge)
    factors = [alpha * v for v in vee] + [s * wedge]
    return (_times_matrix(factors, b, transpose=False).unflatten(-1, (3, 3)),
            _times_matrix(factors, a, transpose=True).unflatten(-1, (3, 3)))


_MATRIX_DISTANCE_COLUMNWISE = Rule(_matrix_distance_columnwise, _matrix_distance_columnwise_parts,
                                   _matrix_distance_columnwise_backward,
                                   lambda R1, R2: _matrix_distance_columnwise_parts(R1, R2)[0])


_MATRIX_DISTANCE_TRACED = closed_form.traced_rule(_MATRIX_DISTANCE_COLUMNWISE)


def matrix_geodesic_distance(R1: Tensor, R2: Tensor) -> Tensor:
    """Angle of the rotation ``R1^T R2``, from ``atan2(|vee(M - M^T)|, tr M - 1)`` with ``M = R1^T R2``.

    Unlike ``acos((tr M - 1) / 2)`` this is accurate near 0 and pi and its gradient is finite
    there (0 at distance 0).

    Args:
        R1: rotation matrices.
        R2: rotation matrices; batch dims broadcast with ``R1``'s.

    Returns:
        Angles in ``[0, pi]``.

    Shape:
        ``(..., 3, 3)`` and ``(..., 3, 3)`` -> ``(...)``.

    Example:
        >>> Rz = torch.tensor([[0., -1., 0.], [1., 0., 0.], [0., 0., 1.]])
        >>> matrix_geodesic_distance(torch.eye(3), Rz)
        tensor(1.5708)
    """
    if (out := matrix_geodesic_distance_unchecked.at_one_row(R1, R2)) is not None:
        return out
    R1, R2, dtype = prepare_pair("matrix_geodesic_distance", ("R1", "R2"), R1, R2, (3, 3), (3, 3))
    return restore(matrix_geodesic_distance_unchecked(R1, R2), dtype)
