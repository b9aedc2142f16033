"""The 6D (Zhou et al. 2019) and 9D (Levinson et al. 2020) representations."""

import torch
from torch import Tensor

from . import _formulas as F
from ._dispatch import run
from ._validation import prepare, restore, tensor_or_as_is
from .errors import ShapeError

__all__ = ["rot6d_to_matrix", "matrix_to_rot6d", "rot9d_to_matrix"]


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
    x, dtype = prepare(x, "rot6d_to_matrix", "x", (6,))
    return restore(run(F.rot6d_to_matrix, (x,), (3, 3), noise=rot6d_noise(x.dtype)), dtype)


def rot6d_noise(dtype: torch.dtype) -> float:
    """The relative size below which 6D columns count as collinear: rounding noise of ``dtype``."""
    return 16.0 * torch.finfo(dtype).eps


def matrix_to_rot6d(R: Tensor) -> Tensor:
    """The 6D representation: the first two columns of R, ``cat(R[..., :, 0], R[..., :, 1])``.

    Shape:
        ``(..., 3, 3)`` -> ``(..., 6)``.

    Example:
        >>> matrix_to_rot6d(torch.eye(3))
        tensor([1., 0., 0., 0., 1., 0.])
    """
    R, dtype = prepare(R, "matrix_to_rot6d", "R", (3, 3))
    return restore(torch.cat((R[..., :, 0], R[..., :, 1]), -1), dtype)


class _SpecialProcrustes(torch.autograd.Function):
    """``R = U diag(1, 1, det(U V^T)) V^T`` with a backward that stays finite when singular values
    coincide (autograd through ``torch.linalg.svd`` divides by their differences).

    With ``M = R P`` (``P = R^T M`` symmetric), the gradient ``grad_M = R [x]_x`` where ``x`` solves
    ``(tr(P) I - P) x = vee(R^T G - G^T R)``: a 3 x 3 system whose eigenvalues are the sums of
    pairs of signed singular values (never negative). It is written with differentiable torch
    operations and this Function again, so it can itself be differentiated to any order.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(M):
        U, _, Vh = torch.linalg.svd(M)
        d = torch.where(torch.linalg.det(U) * torch.linalg.det(Vh) < 0, -1.0, 1.0).to(M.dtype)
        flip = torch.stack((torch.ones_like(d), torch.ones_like(d), d), dim=-1)
        return (U * flip.unsqueeze(-2)) @ Vh

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(inputs[0])
        ctx.save_for_forward(inputs[0])

    @staticmethod
    def backward(ctx, grad):
        return _gradient(ctx.saved_tensors[0], grad)



class _SpecialProcrustesForwardMode(_SpecialProcrustes):
    """The same with forward mode (``torch.func.jvp``, ``jacfwd``): the projection's Jacobian is
    symmetric, so its ``jvp`` is the backward's map. Not under ``torch.compile``, whose tracer
    refuses Functions that define ``jvp``."""

    @staticmethod
    def jvp(ctx, tangent):
        return _gradient(ctx.saved_tensors[0], tangent)


def _projection():
    return _SpecialProcrustes if torch.compiler.is_compiling() else _SpecialProcrustesForwardMode


def _gradient(M: Tensor, G: Tensor) -> Tensor:
    """``grad_M`` of the projection for ``grad_R = G`` (see :class:`_SpecialProcrustes`). The system
    is divided by ``tr(P)``, so the floor ``eps`` added to its eigenvalues (finite at rank 1 and
    below) is relative at any scale."""
    with torch.autocast(M.device.type, enabled=False):
        return _gradient_in_full_precision(M, G)


def _gradient_in_full_precision(M: Tensor, G: Tensor) -> Tensor:
    R = _projection().apply(M)
    P = R.mT @ M
    P = (P + P.mT) * 0.5
    eye = torch.eye(3, dtype=M.dtype, device=M.device)
    trace = P.diagonal(dim1=-2, dim2=-1).sum(-1)[..., None, None]
    positive = trace.detach() > 0
    unit = torch.where(positive, trace.detach(), 1.0)
    floor = torch.where(positive, torch.finfo(M.dtype).eps, 1.0)
    B = R.mT @ G
    B = B - B.mT
    b = torch.stack((B[..., 2, 1], B[..., 0, 2], B[..., 1, 0]), dim=-1)
    x = (torch.linalg.inv((trace * eye - P) / unit + floor * eye) * b.unsqueeze(-2)).sum(-1) / unit.squeeze(-1)
    x0, x1, x2 = x.unbind(-1)
    zero = torch.zeros_like(x0)
    X = torch.stack((torch.stack((zero, -x2, x1), -1), torch.stack((x2, zero, -x0), -1),
                     torch.stack((-x1, x0, zero), -1)), -2)
    return R @ X


def rot9d_to_matrix(x: Tensor) -> Tensor:
    """The rotation nearest to any 3x3 matrix (special orthogonal Procrustes, Levinson et al. 2020).

    ``R = U diag(1, 1, det(U V^T)) V^T`` from the SVD ``x = U S V^T``: the closest rotation in
    Frobenius norm, always det +1. A matrix of rank 1 or 0 to rounding (second singular value at
    most ``16 eps`` times the first; the zero matrix among them) has no single nearest rotation
    and gives NaN. The backward pass is closed-form and stays finite when
    singular values coincide (autograd through ``svd`` does not); it is itself differentiable, so
    second derivatives are exact (double backward, ``torch.func.hessian``, ``jacrev(jacfwd(...))``).
    Forward mode over forward mode (``jacfwd(jacfwd(...))``) is not supported: PyTorch runs a
    Function's ``jvp`` without the outer forward mode, so its second-order terms would be missing.

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
    x = tensor_or_as_is(x)  # (lists and NumPy arrays: read before the shape decides)
    if isinstance(x, Tensor) and x.dim() >= 1 and x.shape[-1] == 9:
        x, dtype = prepare(x, "rot9d_to_matrix", "x", (9,))
        x = x.unflatten(-1, (3, 3))
    else:
        try:
            x, dtype = prepare(x, "rot9d_to_matrix", "x", (3, 3))
        except ShapeError:
            raise ShapeError(f"rot9d_to_matrix: expected x of shape (..., 9) or (..., 3, 3), "
                             f"got {tuple(torch.as_tensor(x).shape)}") from None
    return restore(project(x), dtype)


def project(M: Tensor) -> Tensor:
    """Unchecked :func:`rot9d_to_matrix` of ``(..., 3, 3)`` matrices. LAPACK's SVD raises on NaN or
    inf, so such rows get the identity and then NaN; so do rank-1 and rank-0 matrices (second
    singular value at most ``16 eps`` times the first), which have no single nearest rotation."""
    with torch.autocast(M.device.type, enabled=False):  # (an SVD in bfloat16 would keep 2 digits)
        finite = torch.isfinite(M).all(-1, keepdim=True).all(-2, keepdim=True)
        M = torch.where(finite, M, torch.eye(3, dtype=M.dtype, device=M.device))
        S = torch.linalg.svdvals(M.detach())
        independent = S[..., 1] > 16.0 * torch.finfo(M.dtype).eps * S[..., 0]
        return torch.where(finite & independent[..., None, None], _projection().apply(M), torch.nan)
