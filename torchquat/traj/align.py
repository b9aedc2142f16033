"""Least-squares similarity between point sets (Umeyama 1991), batched and differentiable."""

from typing import Optional, Tuple

import torch
from torch import Tensor

from .. import ShapeError

__all__ = ["align"]


def _check_points(name: str, x: Tensor) -> None:
    if not isinstance(x, Tensor) or x.dim() < 2 or x.shape[-1] != 3:
        shape = tuple(x.shape) if isinstance(x, Tensor) else type(x).__name__
        raise ShapeError(f"align: expected {name} of shape (..., N, 3), got {shape}")
    if not x.is_floating_point():
        raise TypeError(f"align: expected {name} of a floating dtype, got {x.dtype}")


def align(source: Tensor, target: Tensor, weights: Optional[Tensor] = None,
          scale: bool = False) -> Tuple[Tensor, Tensor, Tensor]:
    """The rotation, translation and scale that best map ``source`` onto ``target``.

    Minimises ``sum_i w_i |target_i - (s R source_i + t)|^2`` in closed form (Umeyama, "Least-squares
    estimation of transformation parameters between two point patterns", IEEE PAMI 13(4), 1991,
    eqs. 34-43), the method of ``evo.core.geometry.umeyama_alignment``: the SVD of the
    cross-covariance, with the last singular direction flipped when needed so that ``det(R) = +1``
    (never a reflection). Where the points do not determine the transform (fewer than 3 points,
    all points collinear or coincident: the second singular value of the covariance is at most
    ``N * eps`` of the first, Umeyama's rank condition ``rank >= m - 1`` with a relative rather than
    evo's absolute tolerance), ``R``, ``t`` and ``s`` are NaN: never a plausible wrong transform.

    Args:
        source: points ``(..., N, 3)`` (the estimate).
        target: points ``(..., N, 3)`` (the reference); batch dims broadcast with ``source``'s.
        weights: optional non-negative ``(..., N)`` weights (default: all 1).
        scale: also estimate the scale ``s`` (Sim(3)); otherwise ``s = 1`` (SE(3)).

    Returns:
        ``(R, t, s)``: rotations ``(..., 3, 3)``, translations ``(..., 3)`` and scales ``(...)``
        with ``s R source + t ~ target``.

    Shape:
        ``(..., N, 3)``, ``(..., N, 3)`` -> ``(..., 3, 3)``, ``(..., 3)``, ``(...)``.

    Example:
        >>> x = torch.tensor([[0., 0., 0.], [1., 0., 0.], [0., 2., 0.], [0., 0., 3.]])
        >>> R = quat_to_matrix(torch.tensor([0.6, 0.8, 0., 0.]))
        >>> r, t, s = torchquat.traj.align(x, 2 * x @ R.T + 1, scale=True)
        >>> torch.allclose(r, R, atol=1e-6), torch.allclose(t, torch.ones(3), atol=1e-5), s
        (True, True, tensor(2.0000))
    """
    _check_points("source", source)
    _check_points("target", target)
    if source.shape[-2] != target.shape[-2]:
        raise ShapeError(f"align: expected source and target with the same number of points N, got "
                         f"{tuple(source.shape)} and {tuple(target.shape)}")
    try:
        batch = torch.broadcast_shapes(source.shape[:-2], target.shape[:-2])
    except RuntimeError:
        raise ShapeError(f"align: batch shapes of source {tuple(source.shape)} and target "
                         f"{tuple(target.shape)} do not broadcast") from None
    n = source.shape[-2]
    dtype = torch.promote_types(source.dtype, target.dtype)
    compute = torch.float32 if dtype in (torch.float16, torch.bfloat16) else dtype
    x, y = source.to(compute), target.to(compute)
    if weights is None:
        w = torch.ones((n,), dtype=compute, device=x.device)
    else:
        if weights.shape[-1:] != (n,):
            raise ShapeError(f"align: expected weights of shape (..., {n}), got {tuple(weights.shape)}")
        w = weights.to(compute)
    w = (w / w.sum(-1, keepdim=True)).unsqueeze(-2)  # (..., 1, N); all-zero weights: NaN
    mean_x = (w @ x).squeeze(-2)  # eq. 34 (as matrix products: one pass over the points each)
    mean_y = (w @ y).squeeze(-2)  # eq. 35
    xc = x - mean_x.unsqueeze(-2)
    yc = y - mean_y.unsqueeze(-2)
    weighted = xc * w.transpose(-1, -2)
    sigma_x = torch.diagonal(xc.transpose(-1, -2) @ weighted, dim1=-2, dim2=-1).sum(-1)  # eq. 36
    cov = yc.transpose(-1, -2) @ weighted  # eq. 38: sum_i w_i (y_i - mu_y)(x_i - mu_x)^T
    u, d, vh = torch.linalg.svd(cov)
    # eq. 43: S = diag(1, 1, -1) when det(U) det(V) < 0 (a reflection otherwise)
    flip = torch.where(torch.linalg.det(u) * torch.linalg.det(vh) < 0, -1.0, 1.0).to(compute)
    ones = torch.ones_like(flip)
    signs = torch.stack((ones, ones, flip), -1)
    r = (u * signs.unsqueeze(-2)) @ vh  # eq. 40: R = U S V^T
    if scale:
        s = (d * signs).sum(-1) / sigma_x  # eq. 42: tr(D S) / sigma_x^2
    else:
        s = torch.ones_like(sigma_x)
    t = mean_y - s.unsqueeze(-1) * (r @ mean_x.unsqueeze(-1)).squeeze(-1)  # eq. 41
    # rank condition (text after eq. 39): undetermined when rank(cov) < 2
    tolerance = max(n, 3) * torch.finfo(compute).eps
    undetermined = (d[..., 1] <= tolerance * d[..., 0]) | (n < 3)
    nan = torch.full((), float("nan"), dtype=compute, device=x.device)
    r = torch.where(undetermined[..., None, None], nan, r)
    t = torch.where(undetermined[..., None], nan, t)
    s = torch.where(undetermined, nan, s)
    r, t, s = r.expand(*batch, 3, 3), t.expand(*batch, 3), s.expand(batch)
    return r.to(dtype), t.to(dtype), s.to(dtype)
