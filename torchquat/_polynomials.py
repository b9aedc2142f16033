"""Float32 stand-ins for ``atan2``, ``cos`` and ``sin`` in plain arithmetic, which inductor's CPU
loops vectorise where SLEEF's functions cost more than the rest of a kernel: taken only in the
compiled kernels' own float32 CPU graphs (``torchquat._dispatch`` marks those calls in
:data:`KERNEL_CALL`), never eagerly or in a user's own ``torch.compile``; ``cos`` and ``sin`` only
where no gradient is recorded, ``atan2`` in training graphs too, with ``torch.atan2``'s derivative.
See ``docs/bench_profile.md``, "A polynomial ``atan2``", "A polynomial cos and sin" and "Training
graphs"."""

import math
import threading

import torch
from torch import Tensor

from ._math import _assume_constant_result, copysign, literal, sign_bit

# atan(a) / a as a polynomial in s = a^2 on [0, 1], coefficients of s^0 .. s^8: a least-squares fit
# of the relative error, reweighted towards its peaks (near minimax), made in float64 for this
# project. Relative error 1.5e-8 on [0, 1], a quarter of float32's half ulp.
_ATAN_POLYNOMIAL = (0.9999999847681496, -0.33333073352527315, 0.19992619449107119, -0.14203644566395404,
                    0.10640933574603807, -0.07504292329681422, 0.04269148190998183, -0.01606860033028519,
                    0.002849881261071871)
_ATAN2_CONSTANTS = (0.0, 1.0, 0.5 * math.pi, math.pi)


def _atan_of_ratio(a: Tensor) -> Tensor:
    """``atan(a)`` for ``a`` in ``[0, 1]``: ``a P(a^2)``, ``P`` (:data:`_ATAN_POLYNOMIAL`) evaluated by
    Estrin's scheme (pairs of coefficients, then pairs of pairs): 4 dependent multiply-adds where
    Horner's rule chains 8. Inductor's loop bodies are long (strided loads, a division, a square
    root) and leave little else to overlap with that chain: the compiled quaternion distance took
    7.4-7.6 ms per 1e6 rows with Horner's rule, 5.9-6.3 with this."""
    c = literal(_ATAN_POLYNOMIAL)
    s = a * a
    s2 = s * s
    s4 = s2 * s2
    tail = ((c[1] + c[2] * s) + s2 * (c[3] + c[4] * s)) + s4 * ((c[5] + c[6] * s) + s2 * (c[7] + c[8] * s))
    # a c0 + (a s) tail: the leading term rounded once, and the tail's roundings (at most a third
    # of it) a fraction of an ulp: within 1.52 ulp of atan on [0, 1] (the whole sum by Estrin's
    # scheme, c0 + s tail then times a: 2.65; by Horner's rule about 2)
    return a * c[0] + (a * s) * tail


def polynomial_atan2(y: Tensor, x: Tensor, y_nonnegative: bool = False, x_nonnegative: bool = False,
                     special_values: bool = True) -> Tensor:
    """``atan2(y, x)`` in plain arithmetic that a compiled loop vectorises: the octant's ratio
    ``a = min(|x|, |y|) / max(|x|, |y|)`` in ``[0, 1]``, ``atan(a)`` by :data:`_ATAN_POLYNOMIAL`,
    then ``pi/2 - r`` above the diagonal, ``pi - r`` for ``x`` negative (its sign bit: ``-0.0``
    too) and ``y``'s sign. In float32 within 1.9 ulp of the exact value (``torch.atan2``: 0.9 ulp)
    and keeps ``atan2``'s special values: signed zeros (``atan2(-0.0, -1) = -pi``), ``(0, 0)``,
    infinities and NaN. Accurate relative to the result near 0 (``a`` and the polynomial are).

    Args:
        y, x: float32 tensors of one shape.
        y_nonnegative, x_nonnegative: the caller knows that every ``y`` (or ``x``) is ``+0.0``,
            positive or NaN (a square root, an ``abs``): the half plane's or quadrant's tests are
            skipped. A ``-0.0`` or a negative value there gives a wrong angle.
        special_values: False for a caller whose rows with both arguments 0 or both infinite come
            out NaN (or are discarded) anyway: those give NaN here, one test and one select fewer.

    Returns:
        The angle in radians, in ``[-pi, pi]`` (``[0, pi]`` for ``y_nonnegative``, ``[-pi/2, pi/2]``
        for ``x_nonnegative``), of the inputs' shape.

    Inductor's CPU loops call SLEEF's ``atan2`` at about 3 ns an element on an AMD EPYC (12 ms per
    4e6 elements); session 19's form of this took 6 ms there. In the compiled quaternion distance (1e6
    rows; 3.1-3.5 ms without any ``atan2``) this one adds about 1 ms and SLEEF's about 4.5 (see
    ``docs/bench_profile.md``).
    For float32 only: float64 would need a longer polynomial.

    Example:
        >>> y, x = torch.tensor([1.0, -0.0, 3.0]), torch.tensor([1.0, -1.0, -4.0])
        >>> torch.allclose(polynomial_atan2(y, x), torch.atan2(y, x))
        True
        >>> torch.allclose(polynomial_atan2(y.abs(), x.abs(), True, True), torch.atan2(y.abs(), x.abs()))
        True
    """
    zero, one, half_pi, pi = literal(_ATAN2_CONSTANTS)
    ax = x if x_nonnegative else x.abs()
    ay = y if y_nonnegative else y.abs()
    larger, smaller = torch.maximum(ax, ay), torch.minimum(ax, ay)  # (NaN propagates)
    a = smaller / larger
    if special_values:  # (0, 0) -> 0 and (inf, inf) -> 1 (the diagonal), as atan2's
        a = torch.where(larger == zero, zero, torch.where(smaller == larger, one, a))
    r = _atan_of_ratio(a)
    above = ay > ax
    if x_nonnegative:
        angle = torch.where(above, half_pi - r, r)
    else:
        # pi/2 - r above the diagonal, pi - that for x negative (its sign bit: _math.sign_bit, since
        # signbit is no vectorised loop in inductor's CPU code): K + S r, one rounding
        negative = sign_bit(x)
        offset = torch.where(above, half_pi, torch.where(negative, pi, zero))
        angle = offset + torch.where(above != negative, -one, one) * r
    return angle if y_nonnegative else copysign(angle, y)


# Set by the compiled kernels' dispatcher (torchquat._dispatch) while it calls a kernel marked
# ``polynomial_atan2`` (attribute ``polynomial_atan2``), or one marked ``polynomial_sincos`` whose
# angles lie within POLYNOMIAL_SINCOS_RANGE (``polynomial_sincos``); inductor compiles their graphs
# with the option that makes the polynomials' compile affordable.
KERNEL_CALL = threading.local()


@_assume_constant_result
def _in_polynomial_atan2_kernel() -> bool:
    """Whether this trace is one of those kernels' (read at trace time, with no guard on it)."""
    return getattr(KERNEL_CALL, "polynomial_atan2", False)


def atan2(y: Tensor, x: Tensor, out=None, *, y_nonnegative: bool = False, x_nonnegative: bool = False,
          special_values: bool = True) -> Tensor:
    """``torch.atan2(y, x)``; in the compiled kernels' own graphs of float32 CPU tensors,
    :func:`polynomial_atan2` (2x faster in inductor's loops, within 1.9 ulp), told what the caller
    knows of the arguments (see there; ``torch.atan2`` ignores it).

    Where a gradient is recorded, the polynomial's value with ``torch.atan2``'s exact derivative
    (:class:`_PolynomialAtan2`): the polynomial's own, through ``min``/``max``, is 0 on the diagonal
    ``|x| = |y|``. Inductor calls SLEEF's ``atan2`` out of line, which spills every vector register
    of the loop: the polynomial took 0.88x the time of the compiled quaternion distance's training
    graph at 1e6 rows, 0.95x the matrix distance's (``docs/bench_profile.md``). Not in a user's own
    ``torch.compile`` of code that calls torchquat: inductor inlines the polynomial into every
    reader of its result, which multiplied the kernels' compile time by 5-17 with the default
    options (the kernels' graphs are compiled with ``realize_cpu_opcount_threshold``; see
    ``_dispatch``)."""
    if (out is None and torch.compiler.is_compiling() and y.dtype == torch.float32 and y.is_cpu
            and _in_polynomial_atan2_kernel()):
        if not (torch.is_grad_enabled() and (y.requires_grad or x.requires_grad)):
            return polynomial_atan2(y, x, y_nonnegative, x_nonnegative, special_values)
        if TRAINING_POLYNOMIAL:
            return _PolynomialAtan2.apply(y, x, y_nonnegative, x_nonnegative, special_values)
    return torch.atan2(y, x, out=out)


TRAINING_POLYNOMIAL = True  # (False: training graphs call torch.atan2, for an A/B in one process)


class _PolynomialAtan2(torch.autograd.Function):
    """:func:`polynomial_atan2`'s value with ``torch.atan2``'s derivative, by the same formula
    (``atan2_backward``: ``grad * x / (y^2 + x^2)``, ``grad * -y / (y^2 + x^2)``), so that a training
    graph's gradients are those of its ``torch.atan2``. Saves only ``y`` and ``x`` (which inductor's
    partitioner may recompute from the kernel's inputs in the backward's loop)."""

    @staticmethod
    def forward(y, x, y_nonnegative, x_nonnegative, special_values):
        return polynomial_atan2(y, x, y_nonnegative, x_nonnegative, special_values)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(inputs[0], inputs[1])

    @staticmethod
    def backward(ctx, grad):
        y, x = ctx.saved_tensors
        recip = (y * y + x * x).reciprocal()
        return grad * x * recip, grad * -y * recip, None, None, None


# cos and sin up to a common sign, for rotations built from half angles (a quaternion and its
# negative are one rotation). Cody and Waite's reduction by pi/2 in three float32 parts, exact with
# or without fma (the kernels' polynomial graphs contract multiply-adds, see _dispatch; Moshier's
# Cephes sinf.c split: k * 1.5703125 is exact for |k| < 2^16), then Cephes' float32 polynomials on
# [-pi/4, pi/4] (minimax for float32).
_PI_2_PARTS = (2.0 / math.pi, 1.5703125, 4.837512969970703125e-4, 7.54978995489188216e-8)
_SIN_POLYNOMIAL = (-1.6666654611e-1, 8.3321608736e-3, -1.9515295891e-4)  # sin r = r + r^3 P(r^2)
_COS_POLYNOMIAL = (4.166664568298827e-2, -1.388731625493765e-3, 2.443315711809948e-5)  # 1 - r^2/2 + r^4 P(r^2)
_SINCOS_CONSTANTS = (0.0, 0.5, 1.0)
# Where the three-part reduction holds (measured: within 9.2e-8 of float64's cos and sin up to
# |x| = 1e4, 1e-6 at 1e5, 0.03 at 1e6): the dispatcher sends larger angles to torch.cos and sin.
POLYNOMIAL_SINCOS_RANGE = 8192.0


def polynomial_cos_sin(x: Tensor):
    """``(cos x, sin x)`` up to a sign common to both (so ``(-cos x, -sin x)`` in some rows), in
    plain arithmetic that a compiled loop vectorises: ``k = round(2x / pi)``, ``r = x - k pi / 2``
    by Cody and Waite's three-part reduction (:data:`_PI_2_PARTS`), Cephes' polynomials in ``r``,
    and ``(-sin r, cos r)`` for odd ``k``, which is ``(cos x, sin x)`` up to the sign of
    ``(-1)^((k - 1) / 2)``; even ``k``: ``(cos r, sin r)``, up to ``(-1)^(k / 2)``. Skipping that
    sign saves the quadrant's tests: its callers build rotations from half angles, where it
    flips a quaternion that they then standardise (``w >= 0``) or square (a matrix).

    Float32 only, for ``|x| <=`` :data:`POLYNOMIAL_SINCOS_RANGE` (within 9.2e-8 of the exact values,
    against 3.6e-8 for ``torch.sin``; beyond about 1e4 the reduction loses digits). ``sin(+-0)`` is
    ``+-0``; infinities and NaN give NaN, as ``torch.sin`` does.

    Inductor's CPU loops compute ``cos`` and ``sin`` with SLEEF at about 0.9 ns an element each
    on an AMD EPYC: Euler angles to a quaternion spent 5.5 of 8.3 ms per 1e6 rows in them, and
    2.5 with this (see ``docs/bench_profile.md``).

    Example:
        >>> x = torch.tensor([0.5, 2.0, -4.0, 100.0])
        >>> c, s = polynomial_cos_sin(x)
        >>> sign = torch.sign(c * torch.cos(x) + s * torch.sin(x))
        >>> torch.allclose(c * sign, torch.cos(x)) and torch.allclose(s * sign, torch.sin(x))
        True
    """
    two_over_pi, a, b, c = literal(_PI_2_PARTS)
    zero, half, one = literal(_SINCOS_CONSTANTS)
    k = torch.round(x * two_over_pi)
    r = ((x - k * a) - k * b) - k * c
    r2 = r * r
    p_sin, p_cos = literal(_SIN_POLYNOMIAL), literal(_COS_POLYNOMIAL)
    sin_r = r + r * r2 * (p_sin[0] + r2 * (p_sin[1] + r2 * p_sin[2]))
    cos_r = (one - half * r2) + r2 * r2 * (p_cos[0] + r2 * (p_cos[1] + r2 * p_cos[2]))
    odd = k - 2.0 * torch.round(k * half) != zero
    # x itself at x = +-0, so that sin(-0.0) = -0.0 (both the reduction and the polynomial's sum round it to +0.0)
    return torch.where(odd, -sin_r, cos_r), torch.where(x == zero, x, torch.where(odd, cos_r, sin_r))


# cos y = 1 + w P(w) and sin(y) / y = 1 + w Q(w) in w = y^2, for |y| <= pi / 2: least-squares fits of
# the absolute error on [0, 1.001 (pi / 2)^2] (Chebyshev nodes), reweighted towards their peaks (near
# minimax), made in float64 for this project: 2.4e-10 and 4.9e-9. The constant terms are exactly 1.
_HALF_COS_POLYNOMIAL = (-0.4999999954731587, 0.04166664062504585, -0.0013888402066986544,
                        2.4761808036084104e-05, -2.6075660439217607e-07)
_HALF_SINC_POLYNOMIAL = (-0.16666660437726408, 0.008333087439247563, -0.0001981105333743352,
                         2.6087893664743927e-06)
# Where the dispatcher takes them, on a kernel's input entries (radians; the fits reach 1.0005 pi / 2,
# so float32's pi, 8.7e-8 above pi, is in): Euler angles, whose half angles half_cos_sinc takes, and
# rotation vectors, whose half angle |v| / 2 <= sqrt(3) max |v_i| / 2 direct_cos_sinc takes.
DIRECT_EULER_ANGLES = 1.0005 * math.pi
DIRECT_ROTATION_VECTOR_ENTRIES = 1.0005 * 2.0 * math.pi / math.sqrt(3.0)
# KERNEL_CALL.polynomial_sincos: which cos and sin a marked kernel's call takes
SINCOS_TORCH, SINCOS_REDUCED, SINCOS_DIRECT = 0, 1, 2


def half_cos_sinc(w: Tensor):
    """``(cos y, sin(y) / y)`` of ``y = sqrt(w)``, for ``0 <= w <= (pi / 2)^2``: the polynomials
    :data:`_HALF_COS_POLYNOMIAL` and :data:`_HALF_SINC_POLYNOMIAL` in ``w``, with no range reduction,
    square root or quadrant's tests, each by Estrin's scheme (short chains overlap in a long loop
    body, fma or not) with the leading terms ``1 - w / 2`` and ``1 - w / 6``
    rounded apart from the rest. Within 7.8e-8 of the exact cos and 2.1e-7 of the sin (``y`` times
    the ratio; mean errors 2e-8), ``cos 0 = 1`` and ``sin(y) / y = 1`` at 0 (so ``y`` times it keeps
    ``-0.0``).

    Example:
        >>> y = torch.tensor([0.0, 0.5, 1.5])
        >>> c, sinc = half_cos_sinc(y * y)
        >>> torch.allclose(c, torch.cos(y)) and torch.allclose(sinc * y, torch.sin(y))
        True
    """
    p, q = literal(_HALF_COS_POLYNOMIAL), literal(_HALF_SINC_POLYNOMIAL)
    one = literal(_SINCOS_CONSTANTS)[2]
    w2 = w * w
    c = (one + p[0] * w) + w2 * ((p[1] + p[2] * w) + w2 * (p[3] + p[4] * w))
    r = (one + q[0] * w) + w2 * ((q[1] + q[2] * w) + w2 * q[3])
    return c, r


def direct_cos_sinc(u: Tensor):
    """``(cos x, sin(x) / x)`` of ``x = sqrt(u)``, for ``0 <= u <= pi^2``: :func:`half_cos_sinc` of
    the half, ``c = cos(x / 2)`` and ``r = sin(x / 2) / (x / 2)`` from ``w = u / 4``, then ``cos x =
    c^2 - w r^2`` and ``sin(x) / x = r c`` (one polynomial over all of ``[0, pi]`` sums terms up to 5
    in size to -1 at ``pi``: 6.6e-7 off there). Within 3.6e-7 of the exact cos and 2.6e-7 of the
    sin (1.9e-7 for ``x`` up to ``pi / 2``, the half angle of every rotation of at most a half turn).

    Example:
        >>> x = torch.tensor([0.0, 0.5, 1.5, 3.0])
        >>> c, sinc = direct_cos_sinc(x * x)
        >>> torch.allclose(c, torch.cos(x)) and torch.allclose(sinc * x, torch.sin(x))
        True
    """
    half = literal(_SINCOS_CONSTANTS)[1]
    w = (half * half) * u
    c, r = half_cos_sinc(w)
    return c * c - w * (r * r), r * c


@_assume_constant_result
def _in_polynomial_sincos_kernel() -> int:
    """Which cos and sin this trace takes (:data:`SINCOS_TORCH`; :data:`SINCOS_REDUCED` where the
    dispatcher found every angle within :data:`POLYNOMIAL_SINCOS_RANGE`; :data:`SINCOS_DIRECT` within
    the kernel's direct bound, :data:`DIRECT_EULER_ANGLES` or :data:`DIRECT_ROTATION_VECTOR_ENTRIES`).
    Read at trace time; the dispatcher keeps their graphs apart."""
    return getattr(KERNEL_CALL, "polynomial_sincos", SINCOS_TORCH)


def _polynomial_sincos_mode(x: Tensor) -> int:
    """The trace's :func:`_in_polynomial_sincos_kernel` for float32 CPU values that record no
    gradient; :data:`SINCOS_TORCH` for any other (and eagerly)."""
    if (torch.compiler.is_compiling() and x.dtype == torch.float32 and x.is_cpu
            and not (torch.is_grad_enabled() and x.requires_grad)):
        return _in_polynomial_sincos_kernel()
    return SINCOS_TORCH


def cos_sin_up_to_sign(x: Tensor):
    """``(torch.cos(x), torch.sin(x))``; in the compiled kernels' own graphs of float32 CPU tensors
    that record no gradient, and whose angles the dispatcher found within
    :data:`POLYNOMIAL_SINCOS_RANGE`, :func:`polynomial_cos_sin`: the same up to a sign common to
    both, 2x faster in inductor's loops; with every angle within :data:`DIRECT_EULER_ANGLES` (its
    half ``x`` within ``pi / 2``), :func:`half_cos_sinc` (the signs exact). For callers that build
    rotations from the half angles of Euler angles."""
    mode = _polynomial_sincos_mode(x)
    if mode == SINCOS_DIRECT:
        c, sinc = half_cos_sinc(x * x)
        return c, x * sinc
    if mode == SINCOS_REDUCED:
        return polynomial_cos_sin(x)
    return torch.cos(x), torch.sin(x)


def cos_sinc_of_squares(x2: Tensor):
    """``(cos x, sin(x) / x)`` from ``x2 = x^2`` by :func:`direct_cos_sinc`, for the half angle ``x``
    of a rotation vector, in the graphs of calls whose entries the dispatcher found within
    :data:`DIRECT_ROTATION_VECTOR_ENTRIES` (no square root, division or series near 0); else ``None``."""
    return direct_cos_sinc(x2) if _polynomial_sincos_mode(x2) == SINCOS_DIRECT else None
