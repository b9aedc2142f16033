"""Network heads that map unconstrained features to valid rotations."""

import operator
from typing import Optional

import torch
from torch import Tensor, nn

from ..errors import ShapeError
from ..quaternion import quat_normalize
from ..registry import convert, parse_representation

__all__ = ["RotationHead"]

HEAD_REPRESENTATIONS = ("quat", "rot6d", "rot9d", "axis_angle", "euler")
HEAD_OUTPUTS = ("matrix", "quat")


class RotationHead(nn.Module):
    """A linear layer and the map from its unconstrained output to a valid rotation.

    ``features -> nn.Linear(in_features, size) -> rotation``, where ``size`` and the map depend
    on ``representation``:

    ================  ====  ==================================================================
    representation    size  map to a rotation
    ================  ====  ==================================================================
    ``"rot6d"``       6     Gram-Schmidt on two columns (Zhou et al. 2019); continuous
    ``"rot9d"``       9     SVD special orthogonalisation, the nearest rotation (Levinson et
                            al. 2020); continuous
    ``"quat"``        4     normalisation; discontinuous: Zhou et al. 2019 show that SO(3)
                            has no continuous representation in 4 or fewer real numbers
                            (``q`` and ``-q`` are one rotation, and the map from rotations to
                            the 4 numbers a net must fit jumps somewhere)
    ``"axis_angle"``  3     exponential map of the rotation vector; discontinuous (Zhou et al.)
    ``"euler"``       3     Euler angles in radians with ``convention`` (required);
                            discontinuous, and singular at gimbal lock
    ================  ====  ==================================================================

    Parameters keep ``nn.Linear``'s default initialisation (no bias towards the identity), so an
    untrained head outputs scattered rotations. Linear outputs of any finite non-zero magnitude
    give orthonormal matrices with det +1 (``"axis_angle"``: while the rotation angle, the
    output's norm, stays below about 1e19, where its square overflows in float32); NaN or inf
    outputs (from NaN features, or features so large that the linear layer overflows, near 3e38
    in float32) give NaN rotations (never an exception). An output that is exactly zero is no
    rotation for ``"quat"``, ``"rot6d"`` and ``"rot9d"`` (a zero quaternion, collinear columns, a
    matrix of rank 0): NaN, as is a ``"rot6d"`` output whose two halves are collinear or whose
    second half is zero, and a ``"rot9d"`` output of rank 1; so do not initialise such a head's
    weight and bias to zero (``"axis_angle"`` and ``"euler"`` give the identity there).

    Args:
        in_features: size of the last dimension of the input features.
        representation: ``"rot6d"`` (default), ``"rot9d"``, ``"quat"``, ``"axis_angle"`` or
            ``"euler"`` (``"euler:ZYX"`` also names the convention).
        output: ``"matrix"`` (default) or ``"quat"`` (unit, ``w >= 0``).
        convention: Euler convention for ``representation="euler"``, e.g. ``'ZYX'``.
        bias: whether the linear layer has a bias.
        device: passed to ``nn.Linear``.
        dtype: passed to ``nn.Linear``.

    Raises:
        ValueError: unknown representation or output, missing/invalid convention (at
            construction); features whose last dimension is not ``in_features`` (``ShapeError``,
            in ``forward``). Messages start with ``RotationHead:``.

    Shape:
        ``(..., in_features)`` -> ``(..., 3, 3)`` for ``output="matrix"``, ``(..., 4)`` for
        ``output="quat"``. Under autocast the linear layer runs in the autocast dtype and the
        map to a rotation in float32 (the core turns autocast off); the result has the linear output's dtype.

    Example:
        >>> head = RotationHead(16, "rot6d")
        >>> head
        RotationHead(
          in_features=16, representation='rot6d', output='matrix'
          (linear): Linear(in_features=16, out_features=6, bias=True)
        )
        >>> R = head(torch.randn(5, 16))
        >>> R.shape, bool(torch.allclose(R @ R.mT, torch.eye(3).expand(5, 3, 3), atol=1e-6))
        (torch.Size([5, 3, 3]), True)
        >>> RotationHead(16, "euler", output="quat", convention="ZYX")(torch.randn(16)).shape
        torch.Size([4])
    """

    def __init__(self, in_features: int, representation: str = "rot6d", output: str = "matrix",
                 convention: Optional[str] = None, bias: bool = True, device=None, dtype=None):
        super().__init__()
        try:  # (an integer of any kind, numpy's included, as nn.Linear takes; not a bool)
            size = None if isinstance(in_features, bool) else operator.index(in_features)
        except TypeError:
            size = None
        if size is None or size < 1:
            raise ValueError(f"RotationHead: expected in_features to be a positive int, got {in_features!r}")
        in_features = size
        name = representation.partition(":")[0] if isinstance(representation, str) else representation
        if name not in HEAD_REPRESENTATIONS:
            raise ValueError(f"RotationHead: unknown representation {representation!r}: use one of "
                             f"{', '.join(repr(r) for r in HEAD_REPRESENTATIONS)}")
        if output not in HEAD_OUTPUTS:
            raise ValueError(f"RotationHead: unknown output {output!r}: use 'matrix' or 'quat'")
        rep, conv = parse_representation(representation, "RotationHead", convention)
        if conv is None and convention is not None:
            raise ValueError(f"RotationHead: convention={convention!r} only applies to representation='euler', "
                             f"got representation={representation!r}")
        self.in_features = in_features
        self.representation = rep.name
        self.output = output
        self.convention = None if conv is None else conv.name
        self.linear = nn.Linear(in_features, rep.size, bias=bias, device=device, dtype=dtype)

    def forward(self, features: Tensor) -> Tensor:
        """Map features to rotations."""
        if not isinstance(features, Tensor) or features.dim() < 1 or features.shape[-1] != self.in_features:
            got = tuple(features.shape) if isinstance(features, Tensor) else type(features).__name__
            raise ShapeError(f"RotationHead: expected features of shape (..., {self.in_features}), got {got}")
        if not features.dtype.is_floating_point:  # (as every function: not PyTorch's "mat1 and mat2" dtype error)
            raise TypeError(f"RotationHead: expected features to be a floating-point tensor, got dtype {features.dtype}")
        weight = self.linear.weight
        if features.dtype != weight.dtype and not torch.is_autocast_enabled(features.device.type):
            raise TypeError(f"RotationHead: features are {features.dtype} but the head's parameters are "
                            f"{weight.dtype}: convert one (head.to({features.dtype}) or features.to({weight.dtype}))")
        y = self.linear(features)
        return self._to_rotation(y)

    def _to_rotation(self, y: Tensor) -> Tensor:
        dtype = y.dtype
        if self.representation in ("rot6d", "quat"):  # scale-invariant: scaled by a power of 2
            # (exact: the same rotation bits) to a largest |entry| in [0.5, 1), no square overflows;
            # a constant for autograd, whose gradient through the scale is 0 anyway. In float32 at
            # least (float16's 2^e overflows from outputs of 3e-5 on, as float32's does for
            # subnormal ones: inf times y gave NaN), in two factors (2^148 is not a float32)
            if dtype in (torch.float16, torch.bfloat16):
                y = y.float()
            exponent = torch.frexp(y.detach().abs().amax(-1, keepdim=True)).exponent
            half = torch.div(exponent, 2, rounding_mode="floor")
            # (not torch.ldexp: its gradient to y is 0 in torch 2.13)
            y = y * torch.exp2(half.neg().to(y.dtype)) * torch.exp2((half - exponent).to(y.dtype))
        if self.representation == "quat" and self.output == "quat":
            y = quat_normalize(y)  # quat -> matrix accepts any non-zero quaternion as it is
        return convert(y, self.representation, self.output, convention=self.convention).to(dtype)

    def extra_repr(self) -> str:
        text = f"in_features={self.in_features}, representation={self.representation!r}, output={self.output!r}"
        if self.convention is not None:
            text += f", convention={self.convention!r}"
        return text
