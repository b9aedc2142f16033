"""Euler angles for small batches: the Bernardes-Viollet forms as one ``(..., 4, 2)`` tensor,
and a closed-form backward.

For a few rows every dispatch counts, in the forward and (more so) in autograd's backward, which
runs one node per forward operation. So the forms (see ``torchquat._euler_forms``) come out of one
matmul already laid out as four ``(y, x)`` pairs for one ``atan2``: ``t1``'s, the double angle
used near middle 0, the one used near pi, and ``(Z, |abcd|^2)``. Both double angles are negated:
``atan2(-y, -x)`` is ``atan2(y, x) + pi`` modulo ``2 pi``, the shift that wrapping the third angle
into ``[-pi, pi]`` needs anyway. Forms are scaled by
``1 / |abcd|^2`` (a quaternion's at run time, a matrix's in the table), so ``2h`` is the sine of
the middle angle, the gimbal-lock test is ``2h <= sin(eps)``, and the last pair's x is exactly 1.

Values alone take ``atan2`` of every pair and then choose; under autograd the pairs are chosen
first, the discarded ones replaced by ``(0, 1)``: at an exact lock a discarded pair is
``(0, 0)``, where ``atan2``'s gradient is NaN even when a later ``where`` drops it. The chosen
pairs are the same numbers, so both give the same angles bit for bit.

With gradients, the rule :data:`EULER_ANGLES` (see ``torchquat._closed_form``) returns them
from their closed form (each angle is an ``atan2`` of two forms, linear in ``R`` or ``q q^T``):
one backward node instead of about thirty.
"""

import math

import torch
from torch import Tensor

from ._euler_forms import forms_tables
from . import _closed_form as closed_form
from ._closed_form import Rule
from ._math import constant, norm_twice_differentiable, outer_product, zero_to_inf
from .conventions import EULER_CONVENTIONS, EulerConvention, gimbal_eps

_DEFAULT_EPS = (gimbal_eps(torch.float32), gimbal_eps(torch.float64))

# (form, sign) of each pair's y and x; forms are numbered as in _euler_forms
_LAYOUT = ((0, 1.0), (1, 1.0), (2, -1.0), (3, -1.0), (4, -1.0), (5, -1.0), (12, 1.0), (13, 1.0))


def _layout_tables(name: str):
    """The quaternion table (16 x 8, symmetric in ``q_i q_j``) and the matrix table (9 x 8, with
    its offset, scaled so that ``|abcd|^2 = 1``), and the same tables transposed for the backward."""
    quat_table, matrix_table, offset = forms_tables(name)[:3]
    scale = 1.0 / offset[13]  # |abcd|^2 of a unit quaternion: 1 (proper Euler) or 2 (Tait-Bryan)
    quat = [[sign * row[form] for form, sign in _LAYOUT] for row in quat_table]
    matrix = [[sign * scale * row[form] for form, sign in _LAYOUT] for row in matrix_table]
    matrix_offset = [sign * scale * offset[form] for form, sign in _LAYOUT]
    # for the backward: the tables transposed; the quaternion's times 2 (see _backward)
    transpose = ([[2.0 * v for v in column] for column in zip(*quat)], [list(column) for column in zip(*matrix)])
    return quat, matrix, matrix_offset, transpose


_TABLES = {name: _layout_tables(name) for name in EULER_CONVENTIONS}
# constant names, formatted once (an f-string costs 0.3 us a call)
_NAMES = {name: tuple(f"euler_{part}_{name}" for part in ("q_layout", "R_layout", "R_offset", "q_layout_T", "R_layout_T"))
          for name in EULER_CONVENTIONS}


def _quat_layout_and_scale(q: Tensor, conv: EulerConvention):
    """The forms of ``q`` scaled by ``1 / |abcd|^2`` (scale-invariant angles; ``q = 0`` gives NaN),
    and ``|abcd|^2``, shaped ``(..., 1, 1)``."""
    unscaled = (outer_product(q, q)
                @ constant(_NAMES[conv.name][0], _TABLES[conv.name][0], q)).unflatten(-1, (4, 2))
    scale = unscaled[..., 3:, 1:]
    return unscaled / scale, scale  # (the last pair's x is |abcd|^2 / |abcd|^2: exactly 1)


def quat_layout(q: Tensor, conv: EulerConvention) -> Tensor:
    """The forms of ``q`` scaled by ``1 / |abcd|^2`` (scale-invariant angles; ``q = 0`` gives NaN)."""
    return _quat_layout_and_scale(q, conv)[0]


def matrix_layout(R: Tensor, conv: EulerConvention) -> Tensor:
    """The forms of ``R`` (``|abcd|^2 = 1`` by the table's scale)."""
    names, tables = _NAMES[conv.name], _TABLES[conv.name]
    forms = torch.addmm(constant(names[2], tables[2], R), R.reshape(-1, 9), constant(names[1], tables[1], R))
    return forms.view(R.shape[:-2] + (4, 2))


def lock(forms: Tensor, eps: float, differentiable_twice: bool = False):
    """``2h`` (the middle angle's sine) and the gimbal-lock mask ``2h <= sin(eps)``: the test of
    both the angles and :func:`euler_gimbal_lock`. ``differentiable_twice``: ``2h`` with
    derivatives of every order 0 at ``h = 0`` (``vector_norm``'s second derivative there is NaN:
    double backward at a proper-Euler lock with middle angle 0, the identity among them, was NaN on
    small batches and 0 on large ones); the same numbers."""
    pair = forms[..., 0, :]
    if differentiable_twice:
        two_h = norm_twice_differentiable(pair)
    else:
        two_h = torch.linalg.vector_norm(pair, dim=-1)  # |t1's pair|; its gradient is 0 at h = 0
    threshold = math.sin(eps)
    # The defaults as cached tensors (a Python number costs 1 us more a call); other values are not
    # kept (one cached tensor per value grew without bound). Under compile eps may be symbolic.
    if not torch.compiler.is_compiling() and eps in _DEFAULT_EPS:
        threshold = constant(f"sin_eps_{eps!r}", threshold, forms)
    return two_h, two_h <= threshold


_FLIPS = {1: ("sign1", 1.0, "sign-1", -1.0), -1: ("sign-1", -1.0, "sign1", 1.0)}


def _angles(forms: Tensor, conv: EulerConvention, eps: float, for_autograd: bool = True):
    """The angles, and what the closed-form backward needs."""
    two_h, locked = lock(forms, eps, differentiable_twice=for_autograd)
    y, x = forms.unbind(-1)
    z = y[..., 3]
    zero = constant("zero", 0.0, forms)  # (a tensor: a Python 0 is wrapped into one on every call, 1 us)
    near_zero = z >= zero if conv.symmetric else z <= zero
    if for_autograd:  # the discarded pairs become (0, 1) before atan2 (see the module docstring);
        # the same layout as forms', so that atan2 takes the same (vectorised or scalar) loop
        discarded = torch.stack((locked, near_zero.logical_not(), near_zero, torch.zeros_like(locked)), dim=-1)
        y, x = torch.where(discarded.unsqueeze(-1), constant("unit_x", (0.0, 1.0), forms), forms).unbind(-1)
    if y.numel() > 64:  # a strided atan2 is not vectorised (15x slower): contiguous first
        y, x = y.contiguous(), x.contiguous()  # (for a few rows the copies cost more than they save)
    t1, near_zero_double, near_pi_double, _ = torch.atan2(y, x).unbind(-1)
    t1 = torch.where(locked, zero, t1)  # (for autograd already atan2(0, 1) = 0)
    double = torch.where(near_zero, near_zero_double, near_pi_double)
    middle = torch.atan2(two_h, z) if conv.symmetric else torch.atan2(z, two_h)
    # t3 = D - tb t1 (middle near 0) or D + tb t1 (near pi), in [-pi, pi]; `flip` is -step
    name, value, other_name, other_value = _FLIPS[forms_tables(conv.name)[3]]
    flip = torch.where(near_zero, constant(name, value, forms), constant(other_name, other_value, forms))
    # t3 + pi (the double angles are shifted by pi); remainder by -2 pi, in (-2 pi, 0], then + pi
    # wraps into (-pi, pi]: an exact half turn is +pi on every path (as the large batches' wrap)
    shifted = torch.addcmul(double, t1, flip, value=-1.0)
    if not conv.intrinsic:  # at lock t1 = 0 here, and SciPy's rule moves the rotation into the
        # first angle: t3 = D, and the lock pair's atan2 (2ab, a^2 - b^2) or (-2cd, c^2 - d^2) is
        # flip * D, whose shifted form is flip * shifted (mod 2 pi): wrapped by the same pass
        shifted = shifted * torch.where(locked, flip, constant("one", 1.0, forms))
    t3 = torch.remainder(shifted, constant("minus_two_pi", -2.0 * math.pi, forms)) + constant("pi", math.pi, forms)
    if conv.intrinsic:  # the letters' third angle is t1, exactly 0 at lock
        angles = torch.stack((t3, middle, t1), dim=-1)
    else:
        angles = torch.stack((torch.where(locked, t3, t1), middle, torch.where(locked, zero, t3)), dim=-1)
    return angles, (two_h, z, near_zero, locked, flip)


def angles(forms: Tensor, conv: EulerConvention, eps: float) -> Tensor:
    """Euler angles from the ``(..., 4, 2)`` forms, differentiable by autograd."""
    return _angles(forms, conv, eps)[0]


def _gradient_tables(conv: EulerConvention, like: Tensor):
    """For :func:`_forms_gradient`: the squares' mask (pairs 0-2: ``y^2 + x^2``; pair 3: exactly 1,
    its x), the signs of ``(x, -y)`` (pair 3: ``z``'s gradient, and none for its x), and 2h's."""
    name, z_sign, two_h_sign = (("euler_gradient_proper", -1.0, 1.0) if conv.symmetric
                                else ("euler_gradient_tait_bryan", 1.0, -1.0))
    return (constant("euler_square_mask", ((1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (0.0, 1.0)), like),
            constant(name + "_signs", ((1.0, -1.0), (1.0, -1.0), (1.0, -1.0), (z_sign, 0.0)), like),
            constant(name + "_two_h", ((two_h_sign,), (0.0,), (0.0,), (0.0,)), like))


def _forms_gradient(grad: Tensor, forms: Tensor, conv: EulerConvention, saved) -> Tensor:
    """The gradient with respect to the forms, from ``d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)``."""
    two_h, z, near_zero, locked, flip = saved
    g0, g_middle, g2 = grad.unbind(-1)
    if conv.intrinsic:  # angles (t3, middle, t1), t3 = D - flip t1
        g_double, g_t1 = g0, torch.addcmul(g2, flip, g0, value=-1.0)
    else:  # (t1 or flip t3 at lock, middle, t3 or 0 at lock); t1 is a constant at lock
        g_double, g_t1 = torch.where(locked, flip * g0, g2), torch.addcmul(g0, flip, g2, value=-1.0)
    zero = constant("zero", 0.0, grad)
    g_near_zero = torch.where(near_zero, g_double, zero)
    # middle = atan2(2h, z) (proper Euler) or atan2(z, 2h): d middle = (+-)(2h dz - z d2h) / (z^2 + 4h^2)
    g_middle = g_middle / torch.addcmul(z * z, two_h, two_h)
    # per pair, the gradient of its atan2 (t1's: 0 at lock; the discarded double angle's: 0),
    # and for the last pair z's, which the signs table turns into (g_z, 0)
    per_pair = torch.stack((torch.where(locked, zero, g_t1), g_near_zero, g_double - g_near_zero, g_middle * two_h), dim=-1)
    mask, signs, two_h_column = _gradient_tables(conv, grad)
    # (a zero pair, whose gradient is 0, divides by inf)
    squares = zero_to_inf((forms * (forms * mask)).sum(-1))
    g_forms = forms.flip(-1) * ((per_pair / squares).unsqueeze(-1) * signs)
    # and 2h = |t1's pair|: d 2h = (pair / 2h) . d pair (0 where 2h = 0, as vector_norm's gradient)
    g_two_h = g_middle * z / zero_to_inf(two_h)
    return torch.addcmul(g_forms, forms, g_two_h[..., None, None] * two_h_column)


def _plain(x: Tensor, conv: EulerConvention, eps: float, is_matrix: bool) -> Tensor:
    return angles(matrix_layout(x, conv) if is_matrix else quat_layout(x, conv), conv, eps)


def _forward(x: Tensor, conv: EulerConvention, eps: float, is_matrix: bool):
    forms, scale = (matrix_layout(x, conv), x) if is_matrix else _quat_layout_and_scale(x, conv)
    result, saved = _angles(forms, conv, eps, for_autograd=False)
    return result, (forms, scale, *saved)  # (a matrix's forms need no scale: x stands in)


def _backward(grad: Tensor, inputs, saved, conv: EulerConvention, eps: float, is_matrix: bool):
    (x,), (forms, scale, *saved) = inputs, saved
    # (reshape, not flatten/unflatten: autograd's is_grads_batched vmap has no rule for those)
    g_forms = _forms_gradient(grad, forms, conv, saved).reshape(forms.shape[:-2] + (8,))
    names, (quat_transpose, matrix_transpose) = _NAMES[conv.name], _TABLES[conv.name][3]
    if is_matrix:
        return ((g_forms @ constant(names[4], matrix_transpose, x)).reshape(x.shape),)
    # forms = F(q q^T) / s with s = |abcd|^2: the angles are scale-invariant, so the gradient
    # through s is 0 and d forms = dF / s; d(q q^T)/dq contracted with the symmetric G is 2 G q
    # (the table holds the 2)
    g_outer = (g_forms @ constant(names[3], quat_transpose, x)).reshape(x.shape + (4,))
    # (a broadcast product and sum: 3 dispatches where a batched matmul takes 6)
    return ((g_outer * x.unsqueeze(-2)).sum(-1) / scale.squeeze(-1),)


def _values(x: Tensor, conv: EulerConvention, eps: float, is_matrix: bool) -> Tensor:
    return _forward(x, conv, eps, is_matrix)[0]


EULER_ANGLES = Rule(_plain, _forward, _backward, _values)


def euler_angles(x: Tensor, conv: EulerConvention, eps: float, is_matrix: bool) -> Tensor:
    """Small-batch Euler angles of ``x`` (quaternions or matrices), with the closed-form backward."""
    return closed_form.apply(EULER_ANGLES, x, conv=conv, eps=eps, is_matrix=is_matrix)
