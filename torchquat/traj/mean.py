"""The rotation mean of quaternions (Markley et al. 2007), batched and sign-invariant."""

from typing import Optional

import torch
from torch import Tensor

from .. import ShapeError

__all__ = ["quat_mean"]


def quat_mean(q: Tensor, weights: Optional[Tensor] = None) -> Tensor:
    """The chordal L2 mean of rotations given as quaternions.

    The quaternion maximising ``sum_i w_i <q_i, m>^2``: the eigenvector of the largest eigenvalue of
    ``M = sum_i w_i q_i q_i^T`` over the normalised inputs (Markley, Cheng, Crassidis and
    Oshman, "Averaging Quaternions", J. Guidance, Control, and Dynamics 30(4), 2007, eq. 12-13),
    the rotation minimising the weighted sum of squared chordal distances ``|R_i - R|_F^2``
    (Hartley et al. 2013), as SciPy's ``Rotation.mean``. ``q`` and ``-q`` give the same ``M``, so
    the mean is sign-invariant; it is returned with ``w >= 0``. Differentiable where the largest
    eigenvalue is simple.

    Args:
        q: quaternions ``(w, x, y, z)``, ``(..., N, 4)``, any non-zero norms.
        weights: optional non-negative ``(..., N)`` weights; batch dims broadcast with ``q``'s.

    Returns:
        Unit quaternions ``(..., 4)`` with ``w >= 0``.

    Shape:
        ``(..., N, 4)`` -> ``(..., 4)``.

    Example:
        >>> q = torch.tensor([[1., 0., 0., 0.], [0., 0., 0., -1.], [0.6, 0., 0., 0.8]])
        >>> torchquat.traj.quat_mean(q[:1].expand(3, 4) * torch.tensor([[1.], [-1.], [2.]]))
        tensor([1., 0., 0., 0.])
    """
    if not isinstance(q, Tensor) or q.dim() < 2 or q.shape[-1] != 4:
        raise ShapeError(f"quat_mean: expected q of shape (..., N, 4), got "
                         f"{tuple(q.shape) if isinstance(q, Tensor) else type(q).__name__}")
    if not q.is_floating_point():
        raise TypeError(f"quat_mean: expected q of a floating dtype, got {q.dtype}")
    dtype = q.dtype
    x = q.float() if dtype in (torch.float16, torch.bfloat16) else q
    x = x / torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    if weights is not None:
        if weights.shape[-1:] != q.shape[-2:-1]:
            raise ShapeError(f"quat_mean: expected weights of shape (..., {q.shape[-2]}), got {tuple(weights.shape)}")
        xw = x * weights.to(x.dtype).unsqueeze(-1)
    else:
        xw = x
    m = xw.transpose(-1, -2) @ x  # sum_i w_i q_i q_i^T
    _, vectors = torch.linalg.eigh(m)  # eigenvalues ascending
    mean = vectors[..., :, -1]
    sign = torch.where(mean[..., :1] < 0, -1.0, 1.0).to(mean.dtype)
    return (mean * sign).to(dtype)
