"""Euler angles for small batches: the Bernardes-Viollet forms as one ``(..., 5, 2)`` tensor,
and a closed-form backward.

For a few rows every dispatch counts, in the forward and (more so) in autograd's backward, which
runs one node per forward operation. So the forms (see ``torchquat._euler_forms``) come out of one
matmul already laid out for the angles as five ``(y, x)`` pairs for ``atan2``: ``t1``'s, the
double angle used near middle 0, ``t1``'s again, the double angle used near pi, and
``(Z, |abcd|^2)``. Both double angles are negated: ``atan2(-y, -x)`` is
``atan2(y, x) + pi`` modulo ``2 pi``, the shift that wrapping the third angle into ``[-pi, pi]``
needs anyway. Forms are scaled by ``1 / |abcd|^2`` (a quaternion's at run time, a matrix's in the
table), so ``2h`` is the sine of the middle angle and the gimbal-lock test is ``2h <= sin(eps)``.

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
from ._math import constant, zero_to_inf
from .conventions import EULER_CONVENTIONS, EulerConvention

# (form, sign) of each pair's y and x; forms are numbered as in _euler_forms
_LAYOUT = ((0, 1.0), (1, 1.0), (2, -1.0), (3, -1.0), (0, 1.0), (1, 1.0), (4, -1.0), (5, -1.0), (12, 1.0), (13, 1.0))


def _layout_tables(name: str):
    """The quaternion table (16 x 10, symmetric in ``q_i q_j``) and the matrix table (9 x 10, with
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


def _quat_layout_and_scale(q: Tensor, conv: EulerConvention):
    """The forms of ``q`` scaled by ``1 / |abcd|^2`` (scale-invariant angles; ``q = 0`` gives NaN),
    and ``|abcd|^2``, shaped ``(..., 1, 1)``."""
    unscaled = ((q.unsqueeze(-1) * q.unsqueeze(-2)).flatten(-2)
                @ constant("euler_q_layout_" + conv.name, _TABLES[conv.name][0], q)).unflatten(-1, (5, 2))
    scale = unscaled[..., 4:, 1:]
    return unscaled / scale, scale


def quat_layout(q: Tensor, conv: EulerConvention) -> Tensor:
    """The forms of ``q`` scaled by ``1 / |abcd|^2`` (scale-invariant angles; ``q = 0`` gives NaN)."""
    return _quat_layout_and_scale(q, conv)[0]


def matrix_layout(R: Tensor, conv: EulerConvention) -> Tensor:
    """The forms of ``R`` (``|abcd|^2 = 1`` by the table's scale)."""
    tables = _TABLES[conv.name]
    forms = torch.addmm(constant("euler_R_layout_offset_" + conv.name, tables[2], R), R.reshape(-1, 9),
                        constant("euler_R_layout_" + conv.name, tables[1], R))
    return forms.view(R.shape[:-2] + (5, 2))


def lock(forms: Tensor, eps: float):
    """``2h`` (the middle angle's sine) and the gimbal-lock mask ``2h <= sin(eps)`` (for
    :func:`euler_gimbal_lock`; the angles take the same test shaped as a mask of t1's pair)."""
    two_h = torch.linalg.vector_norm(forms[..., 0, :], dim=-1)  # its gradient is 0 at h = 0
    threshold = math.sin(eps)
    if not torch.compiler.is_compiling():  # (under compile eps may be symbolic: no cache key)
        threshold = constant(f"sin_eps_{eps!r}", threshold, forms)
    return two_h, two_h <= threshold


def _angles(forms: Tensor, conv: EulerConvention, eps: float):
    """The angles, and what the closed-form backward needs."""
    two_h = torch.linalg.vector_norm(forms[..., 0, :], dim=-1)
    # lock()'s test, shaped as a mask of t1's pair in the (t1, double angle) pairs below
    sin_eps = math.sin(eps)
    locked_t1 = two_h[..., None, None] <= constant(f"lock_thresholds_{eps!r}", ((sin_eps, sin_eps), (-1.0, -1.0)), forms)
    z = forms[..., 4, 0]
    near_zero = z >= 0 if conv.symmetric else z <= 0
    # Choose each (Y, X) pair *before* atan2, so a discarded pair (which is (0, 0) at an exact
    # lock, where atan2's gradient is NaN) never reaches it; at lock t1's pair is (0, 1).
    pairs = torch.where(near_zero[..., None, None], forms[..., 0:2, :], forms[..., 2:4, :])
    pairs = torch.where(locked_t1, constant("lock_pair", ((0.0, 1.0), (0.0, 0.0)), forms), pairs)
    if pairs.numel() > 64:  # a strided atan2 is not vectorised (15x slower): y and x contiguous first
        y, x = pairs.movedim(-1, 0).contiguous()
    else:  # (for a few rows the copy costs more than it saves)
        y, x = pairs.unbind(-1)
    t1, shifted = torch.atan2(y, x).unbind(-1)
    middle = torch.atan2(two_h, z) if conv.symmetric else torch.atan2(z, two_h)
    # t3 = D - tb t1 (middle near 0) or D + tb t1 (near pi), in [-pi, pi]; `flip` is -step
    tb = forms_tables(conv.name)[3]
    flip = torch.where(near_zero, constant(f"sign{tb}", float(tb), forms), constant(f"sign{-tb}", float(-tb), forms))
    t3 = torch.remainder(torch.addcmul(shifted, t1, flip, value=-1.0), constant("two_pi", 2.0 * math.pi, forms)) - constant("pi", math.pi, forms)
    if conv.intrinsic:  # the letters' third angle is t1, exactly atan2(0, 1) = 0 at lock
        angles = torch.stack((t3, middle, t1), dim=-1)
    else:  # at lock t1 = 0 here, and SciPy's rule moves the rotation into the first angle:
        # t3 = D, and the lock pair's atan2 (2ab, a^2 - b^2) or (-2cd, c^2 - d^2) is flip * D
        locked = locked_t1[..., 0, 0]
        angles = torch.stack((torch.where(locked, flip * t3, t1), middle, torch.where(locked, constant("zero", 0.0, forms), t3)), dim=-1)
    return angles, (pairs, two_h, z, near_zero, locked_t1, flip)


def angles(forms: Tensor, conv: EulerConvention, eps: float) -> Tensor:
    """Euler angles from the ``(..., 5, 2)`` forms, differentiable by autograd."""
    return _angles(forms, conv, eps)[0]


def _forms_gradient(grad: Tensor, forms: Tensor, conv: EulerConvention, saved) -> Tensor:
    """The gradient with respect to the forms, from ``d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)``."""
    pairs, two_h, z, near_zero, locked_t1, flip = saved
    g0, g_middle, g2 = grad.unbind(-1)
    if conv.intrinsic:  # angles (t3, middle, t1), t3 = shifted - flip t1
        g_shifted, g_t1 = g0, torch.addcmul(g2, flip, g0, value=-1.0)
    else:  # (t1 or flip t3 at lock, middle, t3 or 0 at lock); t1's lock pair is a constant
        g_shifted, g_t1 = torch.where(locked_t1[..., 0, 0], flip * g0, g2), torch.addcmul(g0, flip, g2, value=-1.0)
    g_angle = torch.stack((g_t1, g_shifted), dim=-1).unsqueeze(-1)
    scale = g_angle / (pairs * pairs).sum(-1, keepdim=True)
    g_pairs = pairs.flip(-1) * scale * constant("dy_dx", (1.0, -1.0), pairs)
    zero = constant("zero", 0.0, pairs)
    g_pairs = torch.where(locked_t1, zero, g_pairs)
    g_near_zero = torch.where(near_zero[..., None, None], g_pairs, zero)
    # middle = atan2(2h, z) (proper Euler) or atan2(z, 2h), and 2h = |forms[..., 0, :]|
    g_middle = g_middle / torch.addcmul(z * z, two_h, two_h)
    g_two_h, g_z = g_middle * z, g_middle * two_h
    if conv.symmetric:
        g_z = -g_z
    else:
        g_two_h = -g_two_h
    # d 2h = (pair / 2h) . d pair (0 where 2h = 0, as vector_norm's gradient)
    g_t1_pair = forms[..., 0, :] * (g_two_h / zero_to_inf(two_h)).unsqueeze(-1)
    # rows: t1's pair (near 0: the choice, plus 2h's share), the double angle near 0, t1's pair and
    # the double angle near pi, (z, |abcd|^2)
    g_near_pi = g_pairs - g_near_zero
    return torch.stack((g_near_zero[..., 0, :] + g_t1_pair, g_near_zero[..., 1, :], *g_near_pi.unbind(-2),
                        torch.stack((g_z, torch.zeros_like(g_z)), dim=-1)), dim=-2)


def _plain(x: Tensor, conv: EulerConvention, eps: float, is_matrix: bool) -> Tensor:
    return angles(matrix_layout(x, conv) if is_matrix else quat_layout(x, conv), conv, eps)


def _forward(x: Tensor, conv: EulerConvention, eps: float, is_matrix: bool):
    forms, scale = (matrix_layout(x, conv), x) if is_matrix else _quat_layout_and_scale(x, conv)
    result, saved = _angles(forms, conv, eps)
    return result, (forms, scale, *saved)  # (a matrix's forms need no scale: x stands in)


def _backward(grad: Tensor, inputs, saved, conv: EulerConvention, eps: float, is_matrix: bool):
    (x,), (forms, scale, *saved) = inputs, saved
    # (reshape, not flatten/unflatten: autograd's is_grads_batched vmap has no rule for those)
    g_forms = _forms_gradient(grad, forms, conv, saved).reshape(forms.shape[:-2] + (10,))
    quat_transpose, matrix_transpose = _TABLES[conv.name][3]
    if is_matrix:
        return ((g_forms @ constant("euler_R_layout_T_" + conv.name, matrix_transpose, x)).reshape(x.shape),)
    # forms = F(q q^T) / s with s = |abcd|^2: the angles are scale-invariant, so the gradient
    # through s is 0 and d forms = dF / s; d(q q^T)/dq contracted with the symmetric G is 2 G q
    # (the table holds the 2)
    g_outer = (g_forms @ constant("euler_q_layout_T_" + conv.name, quat_transpose, x)).reshape(x.shape + (4,))
    # (a broadcast product and sum: 3 dispatches where a batched matmul takes 6)
    return ((g_outer * x.unsqueeze(-2)).sum(-1) / scale.squeeze(-1),)


EULER_ANGLES = Rule(_plain, _forward, _backward)


def euler_angles(x: Tensor, conv: EulerConvention, eps: float, is_matrix: bool) -> Tensor:
    """Small-batch Euler angles of ``x`` (quaternions or matrices), with the closed-form backward."""
    return closed_form.apply(EULER_ANGLES, x, conv=conv, eps=eps, is_matrix=is_matrix)
