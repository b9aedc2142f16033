"""Rotation losses with ``reduction='none' | 'mean' | 'sum'``, as in ``torch.nn``.

Each loss is a thin ``forward`` over a core function, computed in float32 for half-precision
inputs (the core kernels turn autocast off, so no matmul inside is rounded to bfloat16) and returned in the
input dtype. Gradients are finite everywhere, including at zero
loss and at rotations 180 degrees apart.
"""

import torch
from torch import Tensor, nn

from .. import _formulas as F
from .._dispatch import run
from .._validation import prepare_pair, restore
from ._common import check_reduction, check_tensor, reduce

__all__ = ["GeodesicLoss", "QuatDistanceLoss", "ChordalLoss"]


def _prepare_pair(module: str, input: Tensor, target: Tensor, trailing):
    check_tensor(module, "input", input, trailing)
    check_tensor(module, "target", target, trailing)
    return prepare_pair(module, ("input", "target"), input, target, trailing, trailing)


class GeodesicLoss(nn.Module):
    """The rotation angle between prediction and target, in radians (``[0, pi]``).

    ``"matrix"``: :func:`torchquat.matrix_geodesic_distance`, the angle of ``R1^T R2``;
    ``"quat"``: :func:`torchquat.quat_geodesic_distance`, sign-invariant (``q`` and ``-q`` are
    the same rotation). Both are computed with ``atan2`` rather than ``acos``, so the value is
    accurate near 0 and pi and the gradient is finite there (0 at zero loss). Quaternions need not
    be unit, within the norms :func:`torchquat.quat_geodesic_distance` states.

    Args:
        representation: ``"matrix"`` (default) or ``"quat"``.
        reduction: ``'none' | 'mean' | 'sum'`` (default ``'mean'``).

    Shape:
        ``input`` and ``target``: ``(..., 3, 3)`` (matrix) or ``(..., 4)`` (quat), batch shapes
        broadcasting; output: scalar, or the broadcast batch shape ``(...)`` for ``'none'``.

    Example:
        >>> loss = GeodesicLoss()
        >>> loss
        GeodesicLoss(representation='matrix', reduction='mean')
        >>> Rz = torch.tensor([[0., -1., 0.], [1., 0., 0.], [0., 0., 1.]])  # 90 degrees about z
        >>> loss(torch.stack((torch.eye(3), Rz)), torch.eye(3))
        tensor(0.7854)
    """

    def __init__(self, representation: str = "matrix", reduction: str = "mean"):
        super().__init__()
        if representation not in ("matrix", "quat"):
            raise ValueError(f"GeodesicLoss: expected representation 'matrix' or 'quat', got {representation!r}")
        self.representation = representation
        self.reduction = check_reduction("GeodesicLoss", reduction)

    def forward(self, input: Tensor, target: Tensor) -> Tensor:
        """Angles between ``input`` and ``target``, reduced."""
        return self._loss(input, target)

    def _loss(self, input: Tensor, target: Tensor) -> Tensor:
        if self.representation == "matrix":
            a, b, dtype = _prepare_pair("GeodesicLoss", input, target, (3, 3))
            loss = run(F.matrix_distance, (a, b), (), 2)
        else:
            a, b, dtype = _prepare_pair("GeodesicLoss", input, target, (4,))
            loss = run(F.quat_distance, (a, b), ())
        return restore(reduce(loss, self.reduction), dtype)

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}, reduction={self.reduction!r}"


class QuatDistanceLoss(nn.Module):
    """``1 - |<q1, q2>|`` of the normalised quaternions (Huynh 2009, metric 4), in ``[0, 1]``.

    Sign-invariant, cheap (no trigonometry) and equal to ``1 - cos(angle / 2)``, a monotone
    function of the geodesic angle. Computed as ``min(|p - q|^2, |p + q|^2) / 2`` of the unit
    ``p``, ``q`` (the same number for unit quaternions): never below 0, and small losses keep
    their digits where ``1 - |<p, q>|`` cancels. Quaternions need not be unit (norms from about
    1e-19 to 1e19 in float32, where ``|q|^2`` neither overflows nor underflows; normalise others
    first); zero quaternions give NaN.

    Args:
        reduction: ``'none' | 'mean' | 'sum'`` (default ``'mean'``).

    Shape:
        ``input`` and ``target``: ``(..., 4)`` ``(w, x, y, z)``, batch shapes broadcasting;
        output: scalar, or the broadcast batch shape ``(...)`` for ``'none'``.

    Example:
        >>> loss = QuatDistanceLoss(reduction="none")
        >>> loss(torch.tensor([[1., 0., 0., 0.], [0., 0., 0., 2.]]), torch.tensor([-1., 0., 0., 0.]))
        tensor([0., 1.])
    """

    def __init__(self, reduction: str = "mean"):
        super().__init__()
        self.reduction = check_reduction("QuatDistanceLoss", reduction)

    def forward(self, input: Tensor, target: Tensor) -> Tensor:
        """``1 - |<q1, q2>|`` of ``input`` and ``target``, reduced."""
        return self._loss(input, target)

    def _loss(self, input: Tensor, target: Tensor) -> Tensor:
        a, b, dtype = _prepare_pair("QuatDistanceLoss", input, target, (4,))
        p, q = a * torch.rsqrt((a * a).sum(-1, keepdim=True)), b * torch.rsqrt((b * b).sum(-1, keepdim=True))
        # 1 - |<p, q>| = min(|p - q|^2, |p + q|^2) / 2 for unit p, q: never below 0 (1 - |dot| was
        # -2e-7 for equal float32 inputs), and small losses keep their digits (1 - |dot| rounds
        # them to multiples of 6e-8 in float32)
        chords = torch.stack((p - q, p + q), dim=-2)
        loss = (chords * chords).sum(-1).amin(-1) * 0.5
        return restore(reduce(loss, self.reduction), dtype)

    def extra_repr(self) -> str:
        return f"reduction={self.reduction!r}"


class ChordalLoss(nn.Module):
    """Squared chordal distance ``||R1 - R2||_F^2`` between matrices (Hartley et al. 2013).

    For rotations it equals ``8 sin^2(angle / 2) = 4 (1 - cos(angle))``, in ``[0, 8]``; it is
    smooth everywhere (the plain L2 loss on matrix entries). Inputs are not projected.

    Args:
        reduction: ``'none' | 'mean' | 'sum'`` (default ``'mean'``).

    Shape:
        ``input`` and ``target``: ``(..., 3, 3)``, batch shapes broadcasting; output: scalar,
        or the broadcast batch shape ``(...)`` for ``'none'``.

    Example:
        >>> Rz = torch.tensor([[-1., 0., 0.], [0., -1., 0.], [0., 0., 1.]])  # 180 degrees about z
        >>> ChordalLoss()(Rz, torch.eye(3))
        tensor(8.)
    """

    def __init__(self, reduction: str = "mean"):
        super().__init__()
        self.reduction = check_reduction("ChordalLoss", reduction)

    def forward(self, input: Tensor, target: Tensor) -> Tensor:
        """``||input - target||_F^2``, reduced."""
        return self._loss(input, target)

    def _loss(self, input: Tensor, target: Tensor) -> Tensor:
        a, b, dtype = _prepare_pair("ChordalLoss", input, target, (3, 3))
        difference = a - b
        loss = (difference * difference).sum((-2, -1))
        return restore(reduce(loss, self.reduction), dtype)

    def extra_repr(self) -> str:
        return f"reduction={self.reduction!r}"
