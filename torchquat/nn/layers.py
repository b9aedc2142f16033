"""Stateless layers: :class:`Convert` and :class:`RotateVectors`."""

from typing import Optional

from torch import Tensor, nn

from .._validation import check_broadcast
from ..conventions import check_degrees
from ..quaternion import quat_rotate
from ..registry import convert, parse_conversion
from ._common import check_tensor

__all__ = ["Convert", "RotateVectors"]


class Convert(nn.Module):
    """Convert rotations between two representations: :func:`torchquat.convert` as a layer.

    Tokens are those of :func:`torchquat.convert` (``"quat"``, ``"quat_xyzw"``, ``"matrix"``,
    ``"euler"``, ``"axis_angle"``, ``"rot6d"``, ``"rot9d"``; ``"euler:ZYX"`` carries its
    convention). They are checked when the layer is built, so a typo fails before training
    starts. The layer has no parameters and no buffers.

    Args:
        src: input representation token.
        dst: output representation token.
        convention: Euler convention, required when ``src`` or ``dst`` is ``"euler"`` (no
            default: ``'ZYX'`` and ``'xyz'`` are different rotations) and refused otherwise.
        degrees: Euler angles in degrees (only with ``"euler"``).

    Raises:
        ValueError: unknown token, missing or invalid convention, or ``convention``/``degrees``
            given where no Euler angles are involved. The message starts with ``Convert:``.

    Shape:
        ``(..., *src_shape)`` -> ``(..., *dst_shape)``, e.g. ``(..., 3)`` -> ``(..., 4)`` for
        ``"euler"`` -> ``"quat"``.

    Example:
        >>> layer = Convert("euler", "quat", convention="ZYX", degrees=True)
        >>> layer
        Convert(src='euler', dst='quat', convention='ZYX', degrees=True)
        >>> layer(torch.tensor([90., 0., 0.]))  # 90 degrees of yaw
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """

    def __init__(self, src: str, dst: str, convention: Optional[str] = None, degrees: bool = False):
        super().__init__()
        src_rep, src_conv, dst_rep, dst_conv = parse_conversion(src, dst, "Convert", convention, degrees)
        self.src, self.dst, self.convention = src_rep.name, dst_rep.name, None
        if src_conv is not None and dst_conv is not None and src_conv.name != dst_conv.name:
            # "euler:ZYX" -> "euler:xyz": two conventions, kept in the tokens
            self.src, self.dst = f"euler:{src_conv.name}", f"euler:{dst_conv.name}"
        elif src_conv is not None or dst_conv is not None:
            self.convention = (src_conv or dst_conv).name
        self.degrees = check_degrees("Convert", degrees)  # ("no" would be true)
        self._src_shape = src_rep.shape

    def forward(self, x: Tensor) -> Tensor:
        """Convert ``x`` from ``src`` to ``dst``."""
        # (checked here, so that errors name the layer; rot9d also takes 3 x 3 matrices: the last
        # dimension compared first, as a symbolic batch size compared with 3 would guard it under export)
        if not (self.src == "rot9d" and isinstance(x, Tensor) and x.dim() >= 2 and x.shape[-1] == 3 and x.shape[-2] == 3):
            check_tensor("Convert", "x", x, self._src_shape)
        return convert(x, self.src, self.dst, convention=self.convention, degrees=self.degrees)

    def extra_repr(self) -> str:
        text = f"src={self.src!r}, dst={self.dst!r}"
        if self.convention is not None:
            text += f", convention={self.convention!r}"
        if self.src.startswith("euler") or self.dst.startswith("euler"):
            text += f", degrees={self.degrees}"
        return text


class RotateVectors(nn.Module):
    """Rotate 3-vectors by quaternions: :func:`torchquat.quat_rotate` as a layer.

    Batch dims broadcast, so one rotation can move a whole point cloud (``q`` of shape
    ``(B, 1, 4)`` with ``v`` of shape ``(B, N, 3)``). Non-unit quaternions rotate by ``q / |q|``,
    for norms where ``|q|^2`` neither overflows nor underflows (see :func:`torchquat.quat_rotate`).

    Shape:
        ``q``: ``(..., 4)`` ``(w, x, y, z)``; ``v``: ``(..., 3)``; output: ``(..., 3)`` with the
        broadcast batch shape.

    Example:
        >>> q = torch.tensor([[0., 0., 0., 1.]])  # 180 degrees about z
        >>> RotateVectors()(q, torch.tensor([[1., 2., 3.], [0., 1., 0.]]))
        tensor([[-1., -2.,  3.],
                [ 0., -1.,  0.]])
    """

    def forward(self, q: Tensor, v: Tensor) -> Tensor:
        """Rotate ``v`` by ``q``."""
        check_tensor("RotateVectors", "q", q, (4,))  # (here, so that errors name the layer)
        check_tensor("RotateVectors", "v", v, (3,))
        check_broadcast("RotateVectors", ("q", "v"), (q, v), (1, 1))
        return quat_rotate(q, v)
