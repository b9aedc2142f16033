"""Write a :class:`~torchquat.io.motion.Motion` (any representation) as a BVH file.

Each joint keeps its own channels and rotation order unless ``order=`` names one for all; angles
are the quaternions decomposed in that order (:func:`torchquat.convert` to ``euler:ORDER`` in
degrees) and written with the shortest digits that read back to the same float64, so a write
and a read give back the same motion to rounding.
"""

from typing import Dict, List, Optional, Tuple

import numpy as np
import torch

import torchquat as _tq
from .bvh import _DEFAULT_ORDER, _is_convention
from .motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, check_names

__all__ = ["write_bvh", "bvh_text"]


def _check_order(fn: str, order: Optional[str]) -> None:
    if order is not None and not (isinstance(order, str) and set(order) <= set("XYZ") and _is_convention(order)):
        raise _tq.ConventionError(f"{fn}: invalid order {order!r}: BVH rotation channels are intrinsic, so use 3 "
                                  "letters from 'XYZ', adjacent letters different, e.g. 'ZXY' or 'ZYX'")


def _channels(own: Tuple[str, ...], order: Optional[str], moves: bool, turns: bool) -> Tuple[str, ...]:
    """The channels a joint is written with: its own, with ``order`` swapped in when given, and
    the position or rotation channels added that its motion needs (AMASS joints have none)."""
    positions = tuple(c for c in own if c in POSITION_CHANNELS)
    letters = "".join(c[0] for c in own if c in ROTATION_CHANNELS)
    if order is None and _is_convention(letters) and (positions or not moves):
        return own  # exactly as read, interleaving included
    if moves and not positions:
        positions = POSITION_CHANNELS
    if order is not None and (letters or turns):
        rotation = order
    elif _is_convention(letters) or not (letters or turns):
        rotation = letters
    else:  # one or two axes (or none, for a joint that now turns): padded to a full order
        rotation = letters + "".join(a for a in _DEFAULT_ORDER if a not in letters)
    return positions + tuple(f"{a}rotation" for a in rotation)


def _depth_first(parents: List[int]) -> List[int]:
    children: Dict[int, List[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(p, []).append(j)
    order, stack = [], list(reversed(children[-1]))
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children.get(j, [])))
    return order


def _number(x: float) -> str:
    return repr(float(x))


def _hierarchy(motion: Motion, channels: List[Tuple[str, ...]]) -> List[str]:
    s = motion.skeleton
    children: Dict[int, List[int]] = {}
    for j, p in enumerate(s.parents):
        children.setdefault(p, []).append(j)
    offsets = s.offsets.detach().to(torch.float64).cpu().numpy()
    lines = ["HIERARCHY"]

    def joint(j: int, depth: int) -> None:
        pad = "\t" * depth
        lines.append(f"{pad}{'ROOT' if s.parents[j] == -1 else 'JOINT'} {s.names[j]}")
        lines.append(pad + "{")
        lines.append(f"{pad}\tOFFSET {' '.join(map(_number, offsets[j]))}")
        if channels[j] or s.parents[j] == -1:
            lines.append(f"{pad}\tCHANNELS {len(channels[j])} {' '.join(channels[j])}".rstrip())
        for child in children.get(j, []):
            joint(child, depth + 1)
        if s.end_sites[j] is not None:
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{",
                          f"{pad}\t\tOFFSET {' '.join(map(_number, s.end_sites[j]))}", f"{pad}\t}}"])
        lines.append(pad + "}")
    joint(children[-1][0], 0)
    return lines


def bvh_text(motion: Motion, order: Optional[str] = None, dtype=np.float64) -> bytes:
    """The BVH file of ``motion`` as bytes (see :func:`write_bvh`)."""
    fn = "write_bvh"
    _check_order(fn, order)
    s = motion.skeleton
    check_names(fn, s.names)
    q = motion.quaternions().detach().to(torch.float64).cpu()
    local = motion.local_translations().detach().to(torch.float64).cpu().numpy()
    offsets = s.offsets.detach().to(torch.float64).cpu().numpy()
    turned = (q[..., 1:].abs().amax(dim=(0, 2)) > 0).tolist() if len(q) else [False] * len(s)
    channels = [_channels(s.channels[j], order, bool(np.any(local[:, j] != offsets[j]))
                          or (s.parents[j] == -1 and not s.channels[j]), turned[j]) for j in range(len(s))]
    groups: Dict[str, List[int]] = {}
    for j, chans in enumerate(channels):
        letters = "".join(c[0] for c in chans if c in ROTATION_CHANNELS)
        if letters:
            groups.setdefault(letters, []).append(j)
    angles: Dict[int, np.ndarray] = {}
    for letters, joints in groups.items():
        euler = _tq.convert(q[:, joints], "quat", f"euler:{letters}", degrees=True).numpy()
        angles.update({j: euler[:, k] for k, j in enumerate(joints)})
    columns = []
    for j in _depth_first(s.parents):
        letters = "".join(c[0] for c in channels[j] if c in ROTATION_CHANNELS)
        for c in channels[j]:
            columns.append(local[:, j, POSITION_CHANNELS.index(c)] if c in POSITION_CHANNELS
                           else angles[j][:, letters.index(c[0])])
    values = np.stack(columns, axis=1) if columns else np.zeros((motion.num_frames, 0))
    lines = _hierarchy(motion, channels) + ["MOTION", f"Frames: {motion.num_frames}",
                                            f"Frame Time: {_number(motion.frame_time)}"]
    if np.dtype(dtype) == np.float32:  # 9 significant digits read back to the same float32
        row = " ".join(["%.9g"] * values.shape[1])
        body = [row % tuple(r) for r in values.astype(np.float32).tolist()]
    else:
        body = [" ".join(map(repr, r)) for r in values.tolist()]
    return ("\n".join(lines + body) + "\n").encode("utf-8")


def write_bvh(path, motion: Motion, order: Optional[str] = None, dtype=np.float64) -> int:
    """Write a motion as a BVH file, atomically.

    Args:
        path: the output file (untouched if anything fails).
        motion: a :class:`Motion` in any representation.
        order: an intrinsic order such as ``'ZXY'`` for every joint's rotation channels; by
            default each joint keeps its own (joints without BVH channels, as from AMASS, get
            ``'ZXY'``, and the root gets position channels).
        dtype: ``numpy.float64`` (shortest digits that read back exactly) or ``numpy.float32``.

    Returns:
        The number of frames written.

    Example:
        >>> import os, tempfile
        >>> from torchquat.io import Motion, Skeleton, read_bvh
        >>> s = Skeleton(["hips", "knee"], [-1, 0], torch.tensor([[0.0, 0, 0], [0, -1, 0]]))
        >>> q = euler_to_quat(torch.tensor([[[30.0, 0, 0], [0, 45, 0]]]), "ZXY", degrees=True)
        >>> path = os.path.join(tempfile.mkdtemp(), "two.bvh")
        >>> write_bvh(path, Motion(s, q, "quat", torch.zeros(1, 3), 1 / 30))
        1
        >>> torch.allclose(read_bvh(path).rotations, q.double())
        True
    """
    from .files import atomic_output
    text = bvh_text(motion, order, dtype)
    with atomic_output(path) as stream:
        stream.write(text)
    return motion.num_frames
