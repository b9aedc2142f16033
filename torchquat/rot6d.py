"""6D (two columns, Zhou et al. 2019) and 9D (SVD projection, Levinson et al. 2020) rotations."""

import math

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule, _transformed, autocast_device
from ._dispatch import kernel
from ._one_row import OneRow
from ._math import constant, is_small, matmul3, sum_of_squares
from ._planes import columns, plane_buffer, rows, slot
from ._validation import prepare, restore, tensor_or_as_is
from .errors import ShapeError

__all__ = ["rot6d_to_matrix", "matrix_to_rot6d", "rot9d_to_matrix"]
_PLANAR_SHARE = 0.25  # contiguous columns from 8,192 rows (measured crossover)


def _rot6d_parts(x: Tensor):
    """The matrix, and what the closed-form backward needs."""
    a1, a2 = x.narrow(-1, 0, 3), x.narrow(-1, 3, 3)
    r1 = torch.linalg.vector_norm(a1, dim=-1, keepdim=True)
    b1 = a1 / r1  # NaN for a zero first column
    d = (b1 * a2).sum(-1, keepdim=True)
    b2 = torch.addcmul(a2, b1, d, value=-1.0)
    n = torch.linalg.vector_norm(b2, dim=-1, keepdim=True)
    # Collinear to rounding: what is left of a2 is rounding noise, whose direction would be a
    # plausible but arbitrary rotation. Give NaN instead (the whole matrix).
    noise = torch.linalg.vector_norm(a2, dim=-1, keepdim=True) * constant("rot6d_noise", 16.0 * torch.finfo(x.dtype).eps, x)
    valid = torch.where(n > noise, constant("one", 1.0, x), constant("nan", math.nan, x))
    b1 = b1 * valid
    b2 = b2 * (valid / n)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    R = torch.stack((b1, b2, b3), dim=-1)
    return R, (R, b1, b3, r1, d, n)


def _rot6d_small(x: Tensor) -> Tensor:
    return _rot6d_parts(x)[0]


def _rot6d_backward(grad: Tensor, inputs, saved):
    R, b1, b3, r1, d, n = saved
    # Gram-Schmidt's vector-Jacobian product (b1 = a1 / r1, a2 = d b1 + n b2, b3 = b1 x b2) only
    # sees the skew part of R^T G (G = grad), whose axial vector is R^T w, w = sum_k b_k x G_k:
    # a2's gradient is (b1 . w / n) b3 and a1's is (w x b1 - d (b1 . w / n) b3) / r1. (Two
    # cross products instead of autograd's thirteen nodes.)
    w = torch.linalg.cross(R, grad, dim=-2).sum(-1)
    g2 = b3 * ((b1 * w).sum(-1, keepdim=True) / n)
    g1 = torch.addcmul(torch.linalg.cross(w, b1, dim=-1), d, g2, value=-1.0) / r1
    return (torch.cat((g1, g2), dim=-1),)


_ROT6D = Rule(_rot6d_small, _rot6d_parts, _rot6d_backward)


@kernel(blocked_row_dims=(1,), compiled_from_rows=512, one_row=OneRow("rot6d_to_matrix", (6,), (3, 3)), vector_bits=256)
def rot6d_to_matrix_unchecked(x: Tensor) -> Tensor:
    if not is_small(x, 6, share=0.4375, gpu_share=4):  # the columns from 1,793 rows: 0.73-0.78x the table's time at 4,096
        if torch.compiler.is_compiling():
            return _ROT6D_TRACED(x)
        return closed_form.apply(_ROT6D_COLUMNWISE, x)
    return closed_form.apply(_ROT6D, x)


def _rot6d_columnwise_parts(x: Tensor, for_autograd: bool = False, values: bool = False):
    """The same, column by column: fewer passes for large batches, and one fused vectorised loop
    under ``torch.compile``. Returns the matrix and what the closed-form backward needs; where
    nothing records a graph R's columns are written into one buffer (no stack before the transpose).
    ``for_autograd``: keep ``rsqrt`` away from 0 in the rows ``where`` drops (its gradient there
    would be NaN times 0). ``values``: nothing keeps the saved parts (R's columns among them)."""
    a = columns(x, share=_PLANAR_SHARE)
    a1, a2 = a[:3], a[3:]
    r2 = sum_of_squares(a1)
    dot = a1[0] * a2[0]
    for u, v in zip(a1[1:], a2[1:]):
        dot = torch.addcmul(dot, u, v)
    coefficient = dot / r2  # a2 less its part along a1, before normalising either (fewer passes)
    b2 = [torch.addcmul(v, u, coefficient, value=-1.0) for u, v in zip(a1, a2)]
    n2 = sum_of_squares(b2)
    # |a2|^2 = n2 + <a1, a2>^2 / |a1|^2 (two non-negative terms: no cancellation)
    noise = (16.0 * torch.finfo(x.dtype).eps) ** 2 * torch.addcmul(n2, dot, coefficient)
    valid = n2 > noise
    inv2 = torch.where(valid, torch.rsqrt(torch.where(valid, n2, 1.0) if for_autograd else n2), torch.nan)
    inv1 = torch.where(valid, torch.rsqrt(r2), torch.nan)
    # R row-major: b_k's entry i at 3 i + k (in R's own memory only where no backward keeps the b_k)
    buffer = plane_buffer(9, a, _PLANAR_SHARE, output=values)
    b1 = [torch.mul(c, inv1, out=slot(buffer, 3 * i)) for i, c in enumerate(a1)]
    b2 = [torch.mul(c, inv2, out=slot(buffer, 3 * i + 1)) for i, c in enumerate(b2)]
    b3 = [torch.addcmul(b1[i] * b2[j], b1[j], b2[i], value=-1.0, out=slot(buffer, 3 * k + 2))
          for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1)))]
    R = rows([c for row in zip(b1, b2, b3) for c in row] if buffer is None else buffer, share=_PLANAR_SHARE)
    return R.unflatten(-1, (3, 3)), (*b1, *b2, *b3, inv1, inv2, dot)


def _rot6d_columnwise(x: Tensor) -> Tensor:
    return _rot6d_columnwise_parts(x, for_autograd=True)[0]


_CROSS = ((1, 2), (2, 0), (0, 1))  # (u x v)_k = u_i v_j - u_j v_i


def _rot6d_columnwise_backward(grad: Tensor, inputs, saved):
    # _rot6d_backward column by column: w = sum_k b_k x G_k, t = (b1 . w) / n; a2's gradient is
    # t b3 and a1's is (w x b1 - d t b3) / r1, with d = <a1, a2> / r1, 1 / r1 and 1 / n saved
    b, (inv1, inv2, dot) = saved[:9], saved[9:]
    b1, b2, b3 = b[:3], b[3:6], b[6:]
    G = columns(grad.flatten(-2), share=_PLANAR_SHARE)  # G[3 i + k]: column k's entry i
    w = []
    for i, j in _CROSS:  # sum over the columns k of (b_k x G_k)_(i, j component)
        total = None
        for k, column in enumerate((b1, b2, b3)):
            total = column[i] * G[3 * j + k] if total is None else torch.addcmul(total, column[i], G[3 * j + k])
            total = torch.addcmul(total, column[j], G[3 * i + k], value=-1.0)
        w.append(total)
    t = b1[0] * w[0]
    for u, v in zip(b1[1:], w[1:]):
        t = torch.addcmul(t, u, v)
    t = t * inv2
    e = dot * t * (inv1 * inv1)  # d t / r1
    buffer = plane_buffer(6, b1, _PLANAR_SHARE)
    g1 = [torch.addcmul(torch.addcmul(w[i] * b1[j], w[j], b1[i], value=-1.0) * inv1, e, b3[k], value=-1.0,
                        out=slot(buffer, k)) for k, (i, j) in enumerate(_CROSS)]
    g2 = [torch.mul(c, t, out=slot(buffer, 3 + k)) for k, c in enumerate(b3)]
    return (rows(g1 + g2 if buffer is None else buffer, share=_PLANAR_SHARE),)


_ROT6D_COLUMNWISE = Rule(_rot6d_columnwise, _rot6d_columnwise_parts, _rot6d_columnwise_backward,
                         lambda x: _rot6d_columnwise_parts(x, values=True)[0])
_ROT6D_TRACED = closed_form.traced_rule(_ROT6D_COLUMNWISE)


def rot6d_to_matrix(x: Tensor) -> Tensor:
    """Rotation matrix from the 6D representation by Gram-Schmidt (Zhou et al. 2019).

    The 6 numbers are the first two **columns** of R, ``cat(R[..., :, 0], R[..., :, 1])``, as
    in the paper. PyTorch3D and pytorch-kinematics use the first two *rows* instead: their 6D
    of ``R`` is torchquat's 6D of ``R.mT``. Any pair of non-collinear vectors is accepted whose
    squared norms are normal floats (norms from about 1e-18 to 1e18 in float32, 1e-153 to 1e153 in
    float64; :class:`torchquat.nn.RotationHead` scales its outputs into that range); collinear ones
    (to rounding) give NaN.

    Args:
        x: two 3-vectors, concatenated.

    Returns:
        Rotation matrices (orthonormal, det +1): column 1 is ``x[:3]`` normalised, column 2 is
        ``x[3:]`` made orthogonal to it, column 3 their cross product.

    Shape:
        ``(..., 6)`` -> ``(..., 3, 3)``.

    Example:
        >>> rot6d_to_matrix(torch.tensor([2., 0., 0., 1., 3., 0.]))
        tensor([[1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.]])
    """
    if (out := rot6d_to_matrix_unchecked.at_one_row(x)) is not None:
        return out
    x, dtype = prepare(x, "rot6d_to_matrix", "x", (6,))
    return restore(rot6d_to_matrix_unchecked(x), dtype)


def matrix_to_rot6d_unchecked(R: Tensor) -> Tensor:
    return torch.cat((R[..., :, 0], R[..., :, 1]), dim=-1)


def matrix_to_rot6d(R: Tensor) -> Tensor:
    """The 6D representation: the first two columns of R, ``cat(R[..., :, 0], R[..., :, 1])``.

    Shape:
        ``(..., 3, 3)`` -> ``(..., 6)``.

    Example:
        >>> matrix_to_rot6d(torch.eye(3))
        tensor([1., 0., 0., 0., 1., 0.])
    """
    R, dtype = prepare(R, "matrix_to_rot6d", "R", (3, 3))
    return restore(matrix_to_rot6d_unchecked(R), dtype)


class _SpecialProcrustes(torch.autograd.Function):
    """``R = U diag(1, 1, det(U V^T)) V^T`` with a closed-form backward.

    Autograd through ``torch.linalg.svd`` divides by ``s_i - s_j`` and is inf/NaN when singular
    values coincide, which is exactly the case for an input that is already a rotation. The
    projection itself only depends on ``s_i + s_j``: with ``M = U' S' V^T`` (``U' = U D``,
    ``S' = D S``), ``dR = R Omega`` where ``(V^T Omega V)_ij (s'_i + s'_j) = (X - X^T)_ij`` and
    ``X = U'^T dM V``. Its adjoint is ``grad_M = U' Z V^T`` with
    ``Z_ij = (Y_ij - Y_ji) / (s'_i + s'_j)``, ``Y = U'^T grad_R V``. Forward mode (``jvp``) is
    ``dR = U' W V^T``, ``W_ij = (X_ij - X_ji) / (s'_i + s'_j)``. Where the result of the backward
    (or of ``jvp``) may be differentiated again, it is :func:`_rotation_times_skew_solution`
    instead: the same numbers, differentiable.
    """

    @staticmethod
    def vmap(info, in_dims, M):
        # A vmapped dimension is one more row dimension. (Not generate_vmap_rule: its vmapped
        # backward fails, in torch.func.jacrev(jacrev(...)), once the backward applies this
        # Function again.) The rule runs only for a batched M.
        return _projection().apply(M.movedim(in_dims[0], 0)), (0, 0, 0, 0)

    @staticmethod
    def forward(M):
        U, S, Vh = torch.linalg.svd(M)
        d = torch.where(torch.linalg.det(U) * torch.linalg.det(Vh) < 0, -1.0, 1.0).to(M.dtype)
        flip = torch.stack((torch.ones_like(d), torch.ones_like(d), d), dim=-1)
        U_signed = U * flip.unsqueeze(-2)
        return matmul3(U_signed, Vh), U_signed, S * flip, Vh

    @staticmethod
    def setup_context(ctx, inputs, output):
        _, U_signed, S_signed, Vh = output
        ctx.save_for_backward(U_signed, S_signed, Vh, inputs[0])
        ctx.save_for_forward(U_signed, S_signed, Vh, inputs[0])
        ctx.mark_non_differentiable(U_signed, S_signed, Vh)

    @staticmethod
    def backward(ctx, grad_R, _gu, _gs, _gv):
        if (device := autocast_device(grad_R)) is not None:  # (a backward inside an autocast region: in M's precision)
            with torch.autocast(device, enabled=False):
                return _SpecialProcrustes.backward(ctx, grad_R, _gu, _gs, _gv)
        U, S, Vh, M = ctx.saved_tensors
        if _differentiated_again():
            return _rotation_times_skew_solution(M, grad_R)
        return matmul3(matmul3(U, _skew_over_sums(matmul3(matmul3(U.mT, grad_R), Vh.mT), S)), Vh)


def _differentiated_again() -> bool:
    """Whether the backward's result may be differentiated: autograd's ``create_graph`` (grad mode
    on in a backward), dual tensors (forward over reverse), or any ``torch.func`` transform. (From a
    Function's backward the transforms outside its own level cannot be seen, so a single
    ``torch.func.grad`` takes the differentiable form too: 1.9x the closed form's time.)"""
    return torch.is_grad_enabled() or _transformed()


try:  # (private: where it is missing, the answer is the safe one)
    from torch._C._functorch import TransformType as _TransformType
    from torch._functorch.pyfunctorch import retrieve_all_functorch_interpreters as _interpreters
    _LEVEL_NAMES = {_TransformType.Grad: "grad", _TransformType.Jvp: "jvp"}
except ImportError:  # pragma: no cover
    _interpreters = None


def _functorch_derivative_levels():
    """The differentiating ``torch.func`` transforms active (``"grad"``, ``"jvp"``), as a Function's
    ``jvp`` sees them: all levels (a backward sees only its own)."""
    if _interpreters is None:  # (a torch without the interpreter stack: assume two, the safe answer)
        return ["grad", "grad"]
    return [_LEVEL_NAMES[i.key()] for i in _interpreters() if i.key() in _LEVEL_NAMES]


_FORWARD_OVER_FORWARD = ("rot9d_to_matrix: forward mode over forward mode (jacfwd(jacfwd(...)), jvp of a jvp) is not "
                         "supported: PyTorch runs a Function's jvp without forward mode. Use jacfwd(jacrev(...)) "
                         "(torch.func.hessian) or jacrev(jacrev(...))")


class _SpecialProcrustesForwardMode(_SpecialProcrustes):
    """The same, with forward mode (``torch.func.jvp``, ``jacfwd``, dual tensors): used only under
    those transforms, since dynamo cannot trace a Function that defines ``jvp``."""

    @staticmethod
    def jvp(ctx, tangent_M):
        U, S, Vh, M = ctx.saved_tensors
        levels = _functorch_derivative_levels() if torch._C._are_functorch_transforms_active() else []
        if levels.count("jvp") >= 2 or getattr(torch.autograd.forward_ad, "_current_level", -1) >= 1:
            raise RuntimeError(_FORWARD_OVER_FORWARD)
        if len(levels) >= 2 or (torch.is_grad_enabled() and (M.requires_grad or tangent_M.requires_grad)):
            # reverse over forward (jacrev(jacfwd(...)), or dual tensors with a graph): differentiable
            return _rotation_times_skew_solution(M, tangent_M), None, None, None
        W = _skew_over_sums(matmul3(matmul3(U.mT, tangent_M), Vh.mT), S)
        return matmul3(matmul3(U, W), Vh), None, None, None


def _projection():
    """The Function to apply: with forward mode only under the transforms that need it."""
    return _SpecialProcrustesForwardMode if _transformed() else _SpecialProcrustes


def _rotation_times_skew_solution(M: Tensor, T: Tensor) -> Tensor:
    """``R [x]_x`` with ``(tr(P) I - P) x = vee(R^T T - T^T R)``, ``R`` the projection of ``M`` applied
    again and ``P = R^T M``, as a function of ``M`` and ``T`` that autograd and ``torch.func`` can
    differentiate (without the SVD's derivative). It is the backward's ``grad_M`` for ``T = grad_R``
    and the forward mode's ``dR`` for ``T = dM``: with ``M = R P`` (P symmetric) the skew ``X`` of
    ``grad_M = R X`` or ``dR = R X`` solves ``P X + X P = R^T T - T^T R``, and for a symmetric P,
    ``P [x]_x + [x]_x P = [(tr(P) I - P) x]_x``: a 3 x 3 system whose eigenvalues are the
    ``s'_i + s'_j`` (never negative). Its own derivative needs only R's first derivative (this
    Function again), so any order works. The same numbers as the closed forms to rounding, for a
    second SVD and a 3 x 3 inverse.

    The system is divided by ``tr(P)`` (at least ``s_1``), so the floor, ``eps`` added to its
    eigenvalues (finite at rank 1 and below), is relative at any scale, as the closed forms'.
    ``linalg.inv``, not ``linalg.solve``: torch 2.13's ``solve`` has wrong forward-mode derivatives
    under a nested vmap (``vmap(torch.func.hessian(...))``). Autocast is off: a bfloat16 system would
    lose the gradient's digits (and ``inv`` would mix dtypes)."""
    with torch.autocast(M.device.type, enabled=False):
        R = _projection().apply(M)[0]
        P = matmul3(R.mT, M)
        P = (P + P.mT) * 0.5  # (symmetric to rounding; exactly so, as its derivative is)
        eye = torch.eye(3, dtype=M.dtype, device=M.device)
        trace = P.diagonal(dim1=-2, dim2=-1).sum(-1)[..., None, None]
        positive = trace.detach() > 0  # (0 only for a zero matrix: the unit-scale system, floor 1)
        unit = torch.where(positive, trace.detach(), 1.0)
        floor = torch.where(positive, torch.finfo(M.dtype).eps, 1.0)
        B = matmul3(R.mT, T)
        B = B - B.mT
        b = torch.stack((B[..., 2, 1], B[..., 0, 2], B[..., 1, 0]), dim=-1)
        x = (torch.linalg.inv((trace * eye - P) / unit + floor * eye) * b.unsqueeze(-2)).sum(-1) / unit.squeeze(-1)
        zero = torch.zeros_like(x[..., 0])
        x0, x1, x2 = x.unbind(-1)
        X = torch.stack((torch.stack((zero, -x2, x1), -1), torch.stack((x2, zero, -x0), -1),
                         torch.stack((-x1, x0, zero), -1)), -2)
        return matmul3(R, X)


def _skew_over_sums(Y: Tensor, S: Tensor) -> Tensor:
    """``(Y_ij - Y_ji) / (s_i + s_j)``: the backward's ``Z`` and the forward mode's ``W``."""
    denom = S.unsqueeze(-1) + S.unsqueeze(-2)
    # rank <= 1: any finite value. Relative to the largest singular value: the projection is
    # scale-invariant, and an absolute eps shrank every gradient of a matrix whose singular values
    # are all below it (1e-8 in float32 already) by s / eps
    # (at least the smallest normal number; for a zero matrix 1, the floor of a unit-scale matrix:
    # 0 / 0 was NaN, and a floor of the smallest normal number overflowed to inf for gradients
    # of order 1, at random)
    scale = S.abs().amax(-1, keepdim=True)
    floor = torch.where(scale > 0, (scale * torch.finfo(S.dtype).eps).clamp_min(torch.finfo(S.dtype).tiny), 1.0).unsqueeze(-1)
    denom = torch.where(denom.abs() < floor, floor, denom)
    return (Y - Y.mT) / denom


@kernel
def rot9d_to_matrix_unchecked(M: Tensor) -> Tensor:
    # LAPACK's SVD raises on NaN/inf: give such rows the identity, then NaN, never a crash.
    finite = torch.isfinite(M).all(-1, keepdim=True).all(-2, keepdim=True)
    eye = torch.eye(3, dtype=M.dtype, device=M.device)
    R, _, S, _ = _projection().apply(torch.where(finite, M, eye))
    # Rank 1 or 0 to rounding (the zero matrix among them): every rotation that maps M's one
    # direction onto itself is as near, so none is the answer: NaN, as for a zero quaternion or
    # collinear 6D vectors (a rank-2 matrix still has one nearest rotation). The bound is the SVD's
    # rounding noise, as 6D's collinearity test.
    independent = S[..., 1] > 16.0 * torch.finfo(M.dtype).eps * S[..., 0]
    return torch.where(finite & independent[..., None, None], R, torch.nan)


def rot9d_to_matrix(x: Tensor) -> Tensor:
    """The rotation nearest to any 3x3 matrix (special orthogonal Procrustes, Levinson et al. 2020).

    ``R = U diag(1, 1, det(U V^T)) V^T`` from the SVD ``x = U S V^T``: the closest rotation in
    Frobenius norm, always det +1. A matrix of rank 1 or 0 to rounding (second singular value at
    most ``16 eps`` times the first; the zero matrix among them) has no single nearest rotation
    and gives NaN. The backward pass is closed-form and stays finite when
    singular values coincide (autograd through ``svd`` does not). Second and higher derivatives
    are exact (double backward, ``torch.func.hessian``, ``jacrev(jacrev(...))``,
    ``jacrev(jacfwd(...))``); forward mode over forward mode raises.

    Args:
        x: 9 numbers read row-major, or a ``(..., 3, 3)`` matrix.

    Returns:
        Rotation matrices.

    Shape:
        ``(..., 9)`` or ``(..., 3, 3)`` -> ``(..., 3, 3)``.

    Example:
        >>> rot9d_to_matrix(torch.tensor([0., -2., 0., 3., 0., 0., 0., 0., 0.5]))  # 90 deg about z, scaled
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    x = tensor_or_as_is(x)  # (lists and NumPy arrays, as everywhere: read before the shape decides)
    if isinstance(x, Tensor) and x.dim() >= 1 and x.shape[-1] == 9:
        x, dtype = prepare(x, "rot9d_to_matrix", "x", (9,))
        x = x.unflatten(-1, (3, 3))
    else:
        try:
            x, dtype = prepare(x, "rot9d_to_matrix", "x", (3, 3))
        except ShapeError:
            raise ShapeError(
                f"rot9d_to_matrix: expected x of shape (..., 9) or (..., 3, 3), got {tuple(torch.as_tensor(x).shape)}"
            ) from None
    return restore(rot9d_to_matrix_unchecked(x), dtype)
