"""The pose container shared by every reader and writer, and the error they raise."""

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from .. import convert
from .representations import parse_token

__all__ = ["Poses", "PoseFileError"]


class PoseFileError(ValueError):
    """A pose file cannot be read or written; ``str()`` names the file and, if known, the line.

    Attributes:
        path: the file concerned.
        line: 1-based line number (every line counted, comments and header too), or None.
    """

    def __init__(self, path, problem: str, line: Optional[int] = None):
        self.path, self.line, self.problem = str(path), line, problem
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {problem}")


@dataclass
class Poses:
    """A batch of poses: optional times and positions, and rotations in a named representation.

    Attributes:
        rotations: ``(n, *shape)`` tensor in ``representation`` (``(n, 4)`` for ``"quat"``).
        representation: a :func:`torchquat.convert` token: ``"quat"``, ``"quat_xyzw"``,
            ``"matrix"``, ``"euler:ZYX"`` (convention in the token), ``"axis_angle"``,
            ``"rot6d"`` or ``"rot9d"``.
        degrees: Euler angles in degrees (Euler only).
        positions: ``(n, 3)`` tensor, or None.
        timestamps: ``(n,)`` float64 array of seconds, or None.
        timestamps_ns: ``(n,)`` int64 array of exact nanoseconds where the source gave them to
            the nanosecond (EuRoC, and decimal seconds with at most 9 decimals), else None.

    Example:
        >>> p = Poses(torch.tensor([[1.0, 0.0, 0.0, 0.0]]), "quat")
        >>> p.to("euler:ZYX", degrees=True).rotations
        tensor([[0., 0., 0.]])
    """

    rotations: Tensor
    representation: str
    degrees: bool = False
    positions: Optional[Tensor] = None
    timestamps: Optional[np.ndarray] = None
    timestamps_ns: Optional[np.ndarray] = None

    def __post_init__(self):
        token = parse_token(self.representation, "Poses")
        if tuple(self.rotations.shape[1:]) != token.shape and not (
                token.name == "rot9d" and tuple(self.rotations.shape[1:]) == (3, 3)):
            raise ValueError(f"Poses: expected rotations of shape (n, {', '.join(map(str, token.shape))}) "
                             f"for {self.representation!r}, got {tuple(self.rotations.shape)}")
        if self.timestamps_ns is not None and self.timestamps is None:
            self.timestamps = self.timestamps_ns / 1e9

    def __len__(self) -> int:
        return self.rotations.shape[0]

    def to(self, representation: str, degrees: bool = False, dtype: Optional[torch.dtype] = None) -> "Poses":
        """The same poses with rotations in another representation (via :func:`torchquat.convert`).

        Args:
            representation: target token, e.g. ``"quat"`` or ``"euler:ZYX"``.
            degrees: Euler output in degrees.
            dtype: optional floating dtype for rotations and positions.

        Returns:
            A new :class:`Poses`; times and positions are shared, not copied.
        """
        rotations = self.rotations if dtype is None else self.rotations.to(dtype)
        positions = self.positions if dtype is None or self.positions is None else self.positions.to(dtype)
        same = representation == self.representation and (degrees == self.degrees or "euler" not in representation)
        if not same:
            rotations = convert_degrees(rotations, self.representation, self.degrees, representation, degrees)
        return replace(self, rotations=rotations, representation=representation, degrees=degrees,
                       positions=positions)

    def __getitem__(self, index: slice) -> "Poses":
        def cut(a):
            return None if a is None else a[index]
        return replace(self, rotations=self.rotations[index], positions=cut(self.positions),
                       timestamps=cut(self.timestamps), timestamps_ns=cut(self.timestamps_ns))


def convert_degrees(x: Tensor, src: str, src_degrees: bool, dst: str, dst_degrees: bool) -> Tensor:
    """:func:`torchquat.convert` where source and target may differ in their ``degrees`` flag."""
    if src.startswith("euler") and dst.startswith("euler") and src_degrees != dst_degrees:
        x = convert(x, src, "quat", degrees=src_degrees)
        return convert(x, "quat", dst, degrees=dst_degrees)
    degrees = src_degrees if src.startswith("euler") else dst_degrees
    return convert(x, src, dst, degrees=degrees)
