"""The pose container shared by every reader and writer, and the error they raise."""

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from .. import convert
from .cameras import FORMAT_MAPS, PoseMap, change_camera_axes, invert_transform
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
        meta: per-pose identifiers, ``{field: (n,) numpy array}`` under the source's own names
            (COLMAP ``image_id``, ``camera_id``, ``name``; NeRF ``file_path`` and per-frame
            extras; BOP ``image_id``, ``obj_id``), or None.
        maps: what each pose maps (:class:`~torchquat.io.cameras.PoseMap`: from which frame to
            which, camera axes); None for the body's pose in the world (TUM, KITTI, EuRoC).
            For a world -> camera map, ``positions`` holds the transform's translation
            (COLMAP's ``TX TY TZ``), not the camera centre (that is ``inverse().positions``).
        document: the source file's fields that are not per pose (``transforms.json``'s
            intrinsics), kept to write it back; or None.

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
    meta: Optional[dict] = None
    maps: Optional[PoseMap] = None
    document: Optional[dict] = None

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
                       timestamps=cut(self.timestamps), timestamps_ns=cut(self.timestamps_ns),
                       meta=None if self.meta is None else {k: v[index] for k, v in self.meta.items()})

    def inverse(self) -> "Poses":
        """The inverse transforms ``(R^T, -R^T t)``, their ``maps`` turned round (world -> camera
        becomes camera -> world). Rotations invert exactly; see
        :func:`~torchquat.io.cameras.invert_transform`.

        Returns:
            A new :class:`Poses` in the same representation; times and ``meta`` are shared.

        Example:
            >>> p = Poses(torch.tensor([[0.0, 1.0, 0.0, 0.0]]), "quat", positions=torch.tensor([[1.0, 2.0, 3.0]]),
            ...           maps=FORMAT_MAPS["colmap"])
            >>> q = p.inverse()
            >>> q.positions, str(q.maps)
            (tensor([[-1.,  2.,  3.]]), 'camera -> world, OpenCV camera axes (x right, y down, z forward)')
        """
        rotations, positions = invert_transform(self.rotations, self.representation, self.positions)
        maps = PoseMap("world", "body") if self.maps is None else self.maps.inverse()
        return replace(self, rotations=rotations, positions=positions, maps=maps)

    def to_camera_axes(self, axes: str) -> "Poses":
        """The same poses with ``"opencv"`` or ``"opengl"`` camera axes (``D = diag(1, -1, -1)`` on
        the camera's side); exact, and exactly undone by the way back.

        Args:
            axes: ``"opencv"`` (x right, y down, z forward) or ``"opengl"`` (x right, y up, z backward).

        Returns:
            A new :class:`Poses` (itself when the axes are already ``axes``).

        Shape:
            rotations and positions keep theirs.

        Example:
            >>> p = Poses(torch.tensor([[0.5, 0.5, 0.5, 0.5]]), "quat", maps=FORMAT_MAPS["nerf"])
            >>> p.to_camera_axes("opencv").to_camera_axes("opengl").rotations
            tensor([[0.5000, 0.5000, 0.5000, 0.5000]])
        """
        if axes not in ("opencv", "opengl"):
            raise ValueError(f"Poses.to_camera_axes: axes must be 'opencv' or 'opengl', got {axes!r}")
        if self.maps is None or "camera" not in (self.maps.source, self.maps.target) or self.maps.camera_axes is None:
            raise ValueError(f"Poses.to_camera_axes: expected poses whose maps name a camera frame and its axes "
                             f"(read from colmap, nerf or bop), got maps={self.maps}")
        if self.maps.camera_axes == axes:
            return self
        rotations, positions = change_camera_axes(self.rotations, self.representation, self.positions,
                                                  camera_is_target=self.maps.target == "camera",
                                                  to_opengl=axes == "opengl")
        return replace(self, rotations=rotations, positions=positions, maps=self.maps._replace(camera_axes=axes))


def convert_degrees(x: Tensor, src: str, src_degrees: bool, dst: str, dst_degrees: bool) -> Tensor:
    """:func:`torchquat.convert` where source and target may differ in their ``degrees`` flag."""
    if src.startswith("euler") and dst.startswith("euler") and src_degrees != dst_degrees:
        x = convert(x, src, "quat", degrees=src_degrees)
        return convert(x, "quat", dst, degrees=dst_degrees)
    degrees = src_degrees if src.startswith("euler") else dst_degrees
    return convert(x, src, dst, degrees=degrees)
