"""Skeletal motion: a joint tree (:class:`Skeleton`) and per-frame local rotations (:class:`Motion`).

BVH and AMASS files read into a :class:`Motion` (``torchquat.io.read_bvh``, ``read_amass``);
a :class:`Motion` in any representation writes back to BVH or to ``.npz``.
"""

from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch
from torch import Tensor

import torchquat as _tq

__all__ = ["Skeleton", "Motion", "POSITION_CHANNELS", "ROTATION_CHANNELS"]

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")


@dataclass
class Skeleton:
    """A joint tree: names, parents, rest offsets and (for BVH) each joint's channels.

    Attributes:
        names: joint names, ``J`` of them.
        parents: parent index of each joint, ``-1`` for the root.
        offsets: ``(J, 3)`` translation of each joint from its parent, in the parent's frame.
        channels: each joint's BVH channel names in file order (e.g. ``("Zrotation",
            "Xrotation", "Yrotation")``); empty tuples where the source had none (AMASS).
        end_sites: per joint, the offset of its BVH ``End Site`` or None (kept on write).

    Example:
        >>> s = Skeleton(["hips", "knee"], [-1, 0], torch.tensor([[0.0, 0, 0], [0, -1, 0]]))
        >>> len(s), s.orders
        (2, [None, None])
    """

    names: List[str]
    parents: List[int]
    offsets: Tensor
    channels: List[Tuple[str, ...]] = field(default_factory=list)
    end_sites: List[Optional[Tuple[float, float, float]]] = field(default_factory=list)

    def __post_init__(self):
        self.names = [str(n) for n in self.names]
        self.parents = [int(p) for p in self.parents]
        count = len(self.names)
        if len(self.parents) != count:
            raise ValueError(f"Skeleton: expected {count} parents (one per name), got {len(self.parents)}")
        if tuple(self.offsets.shape) != (count, 3):
            raise _tq.ShapeError(f"Skeleton: expected offsets of shape ({count}, 3), got {tuple(self.offsets.shape)}")
        self.channels = [tuple(c) for c in self.channels] or [()] * count
        self.end_sites = list(self.end_sites) or [None] * count
        for name, values in (("channels", self.channels), ("end_sites", self.end_sites)):
            if len(values) != count:
                raise ValueError(f"Skeleton: expected {count} {name} (one per joint), got {len(values)}")
        from ..kinematics import tree_levels
        tree_levels(self.parents, "Skeleton")  # (a tree with one root, or a clear error now)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def orders(self) -> List[Optional[str]]:
        """Each joint's rotation channels as axis letters (``'ZXY'`` for ``Zrotation Xrotation
        Yrotation``), or None where it has none."""
        return [("".join(c[0] for c in chans if c in ROTATION_CHANNELS) or None) for chans in self.channels]

    def index(self, name: str) -> int:
        """The index of the joint called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"Skeleton.index: no joint named {name!r}; joints: {', '.join(self.names)}") from None


@dataclass
class Motion:
    """Per-frame local joint rotations on a :class:`Skeleton`, with root positions and frame time.

    Attributes:
        skeleton: the joint tree.
        rotations: ``(T, J, *shape)`` local rotations in ``representation``.
        representation: a :func:`torchquat.convert` token (``"quat"``, ``"rot6d"``, ``"matrix"``,
            ``"euler:ZXY"``, ``"axis_angle"``, ...).
        root_positions: ``(T, 3)`` root position per frame.
        frame_time: seconds between frames.
        degrees: Euler angles in degrees (Euler only).
        translations: ``(T, J, 3)`` local translation of every joint per frame when joints other
            than the root have BVH position channels (each channel replaces that component of the
            offset); None otherwise, when the offsets hold.
        extras: other arrays of the source file (AMASS ``betas``, ``gender``, ``dmpls``, ...).

    Example:
        >>> s = Skeleton(["hips", "knee"], [-1, 0], torch.tensor([[0.0, 0, 0], [0, -1, 0]]))
        >>> m = Motion(s, quat_identity((5, 2), dtype=torch.float64), "quat", torch.zeros(5, 3), 1 / 30)
        >>> m.to("rot6d").rotations.shape, m.num_frames
        (torch.Size([5, 2, 6]), 5)
    """

    skeleton: Skeleton
    rotations: Tensor
    representation: str
    root_positions: Tensor
    frame_time: float
    degrees: bool = False
    translations: Optional[Tensor] = None
    extras: Dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self):
        joints = len(self.skeleton)
        if self.rotations.dim() < 2 or self.rotations.shape[1] != joints:
            raise _tq.ShapeError(f"Motion: expected rotations of shape (T, {joints}, ...) for {joints} joints, "
                                 f"got {tuple(self.rotations.shape)}")
        frames = self.rotations.shape[0]
        if tuple(self.root_positions.shape) != (frames, 3):
            raise _tq.ShapeError(f"Motion: expected root_positions of shape ({frames}, 3), "
                                 f"got {tuple(self.root_positions.shape)}")
        if self.translations is not None and tuple(self.translations.shape) != (frames, joints, 3):
            raise _tq.ShapeError(f"Motion: expected translations of shape ({frames}, {joints}, 3), "
                                 f"got {tuple(self.translations.shape)}")
        self.frame_time = float(self.frame_time)

    @property
    def num_frames(self) -> int:
        """The number of frames ``T``."""
        return self.rotations.shape[0]

    def __len__(self) -> int:
        return self.num_frames

    def to(self, representation: str, degrees: bool = False) -> "Motion":
        """The same motion with rotations in another representation (via :func:`torchquat.convert`).

        Args:
            representation: target token, e.g. ``"rot6d"``, ``"quat"``, ``"euler:ZXY"``.
            degrees: Euler output in degrees.

        Returns:
            A new :class:`Motion`; everything but the rotations is shared.
        """
        src, dst = self.representation, representation
        if src == dst and (self.degrees == degrees or not dst.startswith("euler")):
            return replace(self, degrees=degrees if dst.startswith("euler") else False)
        x = self.rotations
        if src.startswith("euler") and dst.startswith("euler"):  # (degree flags may differ)
            x, src = _tq.convert(x, src, "quat", degrees=self.degrees), "quat"
        src_degrees = self.degrees if src.startswith("euler") else degrees
        return replace(self, rotations=_tq.convert(x, src, dst, degrees=src_degrees), representation=dst,
                       degrees=degrees if dst.startswith("euler") else False)

    def quaternions(self) -> Tensor:
        """Local rotations as ``(T, J, 4)`` quaternions."""
        return self.to("quat").rotations

    def local_translations(self) -> Tensor:
        """``(T, J, 3)`` translation of each joint from its parent (the root's is its position)."""
        frames, joints = self.num_frames, len(self.skeleton)
        local = self.translations if self.translations is not None else \
            self.skeleton.offsets.to(self.root_positions.dtype).expand(frames, joints, 3)
        root = self.skeleton.parents.index(-1)
        is_root = torch.arange(joints, device=local.device) == root
        return torch.where(is_root[:, None], self.root_positions[:, None, :], local)

    def world(self) -> Tuple[Tensor, Tensor]:
        """World positions ``(T, J, 3)`` and world quaternions ``(T, J, 4)`` of every joint
        (:func:`torchquat.kinematics.forward_kinematics`)."""
        from ..kinematics import forward_kinematics
        q = self.quaternions()
        return forward_kinematics(self.skeleton.parents, self.local_translations().to(q.dtype), q,
                                  self.root_positions.to(q.dtype))

    def __getitem__(self, index: slice) -> "Motion":
        """The frames ``index`` (a slice) of this motion."""
        if not isinstance(index, slice):
            raise TypeError(f"Motion: index with a slice of frames, got {type(index).__name__}")
        return replace(self, rotations=self.rotations[index], root_positions=self.root_positions[index],
                       translations=None if self.translations is None else self.translations[index])


def check_names(fn: str, names: Sequence[str]) -> None:
    """Joint names that a BVH file can hold: unique, one line, no braces, no space at either end."""
    seen = set()
    for name in names:
        if not name or name != name.strip() or any(c in "{}\r\n\t" for c in name):
            raise ValueError(f"{fn}: joint name {name!r} cannot be written to BVH (empty, a brace, a tab, "
                             "a line break, or a space at either end)")
        if name in seen:
            raise ValueError(f"{fn}: joint name {name!r} appears twice")
        seen.add(name)
