"""BVH files read into a :class:`~torchquat.io.motion.Motion` (the writer: ``bvh_write``).

Semantics (the Wisconsin spec, as bvhio and Blender read it): each joint's rotation channels are
intrinsic rotations in the order listed, in degrees, so ``Zrotation Xrotation Yrotation`` is the
convention ``'ZXY'`` with ``R = Rz Rx Ry``; orders may differ per joint. Position channels may sit
on any joint and replace that component of its ``OFFSET`` (the root's give ``root_positions``).

The hierarchy is parsed line by line (it is small); the MOTION block, nearly all of the file, is
parsed in one call to NumPy's C reader, and a slow line-by-line pass runs only to name the line
of an error.
"""

import io
import os
import re
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch

import torchquat as _tq
from .motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton
from .poses import PoseFileError

__all__ = ["read_bvh", "parse_bvh", "channel_rotations"]

_KNOWN_CHANNELS = POSITION_CHANNELS + ROTATION_CHANNELS
_MOTION = re.compile(rb"^[ \t]*MOTION[ \t]*\r?$", re.M)
_DEFAULT_ORDER = "ZXY"  # for joints that carry no BVH order of their own (AMASS): the common CMU order


class _Hierarchy:
    """What the HIERARCHY section declares, in file (depth-first) order."""

    def __init__(self):
        self.names: List[str] = []
        self.parents: List[int] = []
        self.offsets: List[Tuple[float, float, float]] = []
        self.channels: List[Tuple[str, ...]] = []
        self.end_sites: List[Optional[Tuple[float, float, float]]] = []


def _tokens(text: str, first_line: int = 1):
    """(token, 1-based line) pairs of the hierarchy text."""
    for number, line in enumerate(text.splitlines(), first_line):
        for token in line.split():
            yield token, number


def _numbers(path, values: List[str], count: int, what: str, line: int) -> Tuple[float, ...]:
    try:
        numbers = tuple(float(v) for v in values)
    except ValueError:
        numbers = ()
    if len(numbers) != count:
        raise PoseFileError(path, f"{what} needs {count} number{'s' if count > 1 else ''}, got "
                            f"{' '.join(values) or 'none'}", line)
    return numbers


def _parse_hierarchy(path, text: str) -> _Hierarchy:
    """Parse the HIERARCHY section with a stack of open braces (no recursion limit)."""
    tokens = list(_tokens(text))
    lines: Dict[int, List[str]] = {}
    for token, line in tokens:
        lines.setdefault(line, []).append(token)
    h = _Hierarchy()
    if not tokens or tokens[0][0] != "HIERARCHY":
        raise PoseFileError(path, "a BVH file starts with HIERARCHY", tokens[0][1] if tokens else 1)
    stack: List[Tuple[Optional[int], int]] = []  # (joint index, or None in an End Site; line of its '{')
    declared: Optional[Tuple[str, int]] = None  # a ROOT/JOINT/End Site waiting for its '{'
    closed = False
    i = 1
    while i < len(tokens):
        token, line = tokens[i]
        rest = lines[line][lines[line].index(token) + 1:] if token in ("OFFSET", "CHANNELS") else []
        if declared is not None and token != "{":
            raise PoseFileError(path, f"expected '{{' after {declared[0]}, got {token!r}", line)
        if token in ("ROOT", "JOINT"):
            if (token == "ROOT") != (not stack) or closed or (stack and stack[-1][0] is None):
                where = "inside an End Site" if stack and stack[-1][0] is None else \
                    "a second ROOT" if token == "ROOT" else "outside the ROOT's braces"
                raise PoseFileError(path, f"{token} {where}: one ROOT holds every JOINT", line)
            words = lines[line][lines[line].index(token) + 1:]
            words = words[:-1] if words and words[-1] == "{" else words  # ('JOINT name {' on one line)
            if not words:
                raise PoseFileError(path, f"{token} needs a joint name on its line", line)
            name = " ".join(words)  # (names with spaces exist in the wild; bvhio keeps the first word)
            h.names.append(name)
            h.parents.append(stack[-1][0] if stack else -1)
            h.offsets.append((0.0, 0.0, 0.0))
            h.channels.append(())
            h.end_sites.append(None)
            declared, i = (f"{token} {name}", line), i + 1 + len(words)
            continue
        if token == "End":
            if not stack or stack[-1][0] is None or i + 1 >= len(tokens) or tokens[i + 1][0] != "Site":
                raise PoseFileError(path, "'End' must be 'End Site' inside a joint", line)
            declared, i = ("End Site", line), i + 2
            continue
        if token == "{":
            if declared is None:
                raise PoseFileError(path, "'{' without a ROOT, JOINT or End Site before it", line)
            stack.append((None if declared[0] == "End Site" else len(h.names) - 1, line))
            if declared[0] == "End Site":
                h.end_sites[stack[-2][0]] = (0.0, 0.0, 0.0)
            declared = None
        elif token == "}":
            if not stack:
                raise PoseFileError(path, "'}' closes nothing", line)
            stack.pop()
            closed = not stack
        elif token == "OFFSET" and stack:
            offset = _numbers(path, rest, 3, "OFFSET", line)
            if stack[-1][0] is None:
                h.end_sites[stack[-2][0]] = offset
            else:
                h.offsets[stack[-1][0]] = offset
            i += 1 + len(rest)
            continue
        elif token == "CHANNELS" and stack and stack[-1][0] is not None:
            count = _numbers(path, rest[:1], 1, "CHANNELS", line)[0]
            unknown = [c for c in rest[1:] if c not in _KNOWN_CHANNELS]
            if unknown:
                raise PoseFileError(path, f"unknown channel {unknown[0]!r}: BVH channels are "
                                    f"{', '.join(_KNOWN_CHANNELS)}", line)
            if count != len(rest) - 1:
                raise PoseFileError(path, f"CHANNELS {rest[0]} is followed by {len(rest) - 1} channel names", line)
            if len(set(rest[1:])) != len(rest) - 1:
                raise PoseFileError(path, "a channel is listed twice", line)
            h.channels[stack[-1][0]] = tuple(rest[1:])
            i += 1 + len(rest)
            continue
        else:
            raise PoseFileError(path, f"unexpected {token!r} in the hierarchy", line)
        i += 1
    if declared is not None:
        raise PoseFileError(path, f"{declared[0]} has no '{{' before MOTION", declared[1])
    if stack:
        joint, line = stack[-1]
        what = "an End Site" if joint is None else f"joint {h.names[joint]!r}"
        raise PoseFileError(path, f"unclosed brace: the '{{' of {what} is never closed before MOTION", line)
    if not h.names:
        raise PoseFileError(path, "the hierarchy declares no ROOT", tokens[-1][1])
    return h


def _frame_header(path, data: bytes, start: int, first_line: int) -> Tuple[int, float, int, int]:
    """Parse ``Frames: N`` and ``Frame Time: t`` after MOTION: (frames, frame time, line of
    Frames:, byte offset of the first frame line)."""
    found: List[Tuple[bytes, int]] = []
    line, pos = first_line, start
    while len(found) < 2 and pos < len(data):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end + 1
        if data[pos:end].strip():
            found.append((data[pos:end].strip(), line))
        line, pos = line + 1, end
    patterns = ((rb"Frames:\s*(\d+)", "Frames: N"), (rb"Frame Time:\s*(\S+)", "Frame Time: SECONDS"))
    values = []
    for (pattern, form), (text, number) in zip(patterns, found + [(b"", line)] * 2):
        match = re.fullmatch(pattern, text)
        try:
            values.append(float(match.group(1)) if match else None)
        except ValueError:
            values.append(None)
        if values[-1] is None:
            raise PoseFileError(path, f"expected '{form}' after MOTION, got {text.decode('utf-8', 'replace')!r}",
                                number)
    return int(values[0]), values[1], found[0][1], pos


def _frame_values(path, body: bytes, width: int, first_line: int) -> np.ndarray:
    """The frame lines as a ``(frames, width)`` float64 array: NumPy's C reader in one call; on any
    problem a line-by-line pass names the first bad line."""
    if not body.strip():
        return np.zeros((0, width))
    if width:
        try:
            values = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments=None)
            if values.shape[1] == width and np.isfinite(values).all():
                return values
        except ValueError:
            pass
    for number, line in enumerate(body.split(b"\n"), first_line):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != width:
            raise PoseFileError(path, f"a frame line has {len(fields)} numbers; the hierarchy's channels need "
                                f"{width}", number)
        for field in fields:
            try:
                finite = np.isfinite(float(field))
            except ValueError:
                raise PoseFileError(path, f"{field.decode('utf-8', 'replace')!r} is not a number", number) from None
            if not finite:
                raise PoseFileError(path, f"{field.decode('utf-8', 'replace')!r} is not finite", number)
    raise PoseFileError(path, "the MOTION block could not be read")  # (not reached: loadtxt agrees)


def channel_rotations(orders: List[Optional[str]], angles: List[np.ndarray], dtype=torch.float64) -> torch.Tensor:
    """Local quaternions ``(T, J, 4)`` from each joint's rotation channels (degrees).

    Joints sharing a valid 3-letter order are converted in one :func:`torchquat.euler_to_quat`
    call; any other channel set (one or two axes) is the product of its axis rotations in order.

    Args:
        orders: per joint, its rotation letters (``'ZXY'``) or None (identity).
        angles: per joint, ``(T, len(order))`` angles in degrees (``(T, 0)`` for None).
        dtype: the quaternions' dtype.

    Returns:
        ``(T, J, 4)`` quaternions, ``w >= 0`` for the 3-letter orders.

    Example:
        >>> channel_rotations(["ZXY"], [np.array([[90.0, 0.0, 0.0]])])
        tensor([[[0.7071, 0.0000, 0.0000, 0.7071]]], dtype=torch.float64)
    """
    frames = angles[0].shape[0] if angles else 0
    groups: Dict[str, List[int]] = {}
    for j, order in enumerate(orders):
        groups.setdefault(order if order is not None and _is_convention(order) else f"#{j}", []).append(j)
    parts, index = [], []
    for order, joints in groups.items():
        if not order.startswith("#"):
            a = torch.from_numpy(np.stack([angles[j] for j in joints], axis=1)).to(dtype)
            parts.append(_tq.euler_to_quat(a, order, degrees=True))
        else:
            letters, a = orders[joints[0]] or "", torch.from_numpy(angles[joints[0]]).to(dtype)
            q = _tq.quat_identity((frames,), dtype=dtype)
            for k, letter in enumerate(letters):
                axis = torch.zeros(3, dtype=dtype)
                axis[_AXES.index(letter)] = 1.0
                q = _tq.quat_multiply(q, _tq.axis_angle_to_quat(torch.deg2rad(a[:, k:k + 1]) * axis))
            parts.append(q[:, None, :])
        index += joints
    back = torch.argsort(torch.tensor(index))
    return torch.cat(parts, dim=1).index_select(1, back) if parts else torch.zeros(frames, 0, 4, dtype=dtype)


_AXES = "XYZ"


def _is_convention(order: str) -> bool:
    return len(order) == 3 and all(a != b for a, b in zip(order, order[1:]))


def parse_bvh(path, data: bytes) -> Motion:
    """Parse the bytes of a BVH file (see :func:`read_bvh`); ``path`` names it in errors."""
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    found = _MOTION.search(data)
    if found is None:
        raise PoseFileError(path, "no MOTION line: a BVH file has HIERARCHY, then MOTION with the frames")
    h = _parse_hierarchy(path, data[:found.start()].decode("utf-8", "replace"))
    motion_line = data.count(b"\n", 0, found.start()) + 1
    frames, frame_time, frames_line, body = _frame_header(path, data, found.end() + 1, motion_line + 1)
    width = sum(len(c) for c in h.channels)
    first = data.count(b"\n", 0, body) + 1
    values = _frame_values(path, data[body:], width, first)
    if len(values) != frames:
        raise PoseFileError(path, f"'Frames: {frames}' disagrees with the MOTION block, which has {len(values)} "
                            "frame lines: fix the count or the lines", frames_line)
    return _motion_of(h, values, frame_time)


def _motion_of(h: _Hierarchy, values: np.ndarray, frame_time: float) -> Motion:
    offsets = np.array(h.offsets, dtype=np.float64)
    frames, joints = values.shape[0], len(h.names)
    moved = [j for j, chans in enumerate(h.channels) if h.parents[j] != -1 and set(chans) & set(POSITION_CHANNELS)]
    root = h.parents.index(-1)
    # (T, J, 3) translations only when joints other than the root move: else the offsets hold
    translations = np.broadcast_to(offsets, (frames, joints, 3)).copy() if moved else None
    root_positions = np.broadcast_to(offsets[root], (frames, 3)).copy()
    angles, orders, column = [], [], 0
    for j, chans in enumerate(h.channels):
        rotation_columns = []
        for c in chans:
            if c in POSITION_CHANNELS:
                target = root_positions if j == root else translations[:, j]
                target[:, POSITION_CHANNELS.index(c)] = values[:, column]
            else:
                rotation_columns.append(column)
            column += 1
        angles.append(values[:, rotation_columns])
        orders.append("".join(c[0] for c in chans if c in ROTATION_CHANNELS) or None)
    if translations is not None:
        translations[:, root] = root_positions
    skeleton = Skeleton(h.names, h.parents, torch.from_numpy(offsets), h.channels, h.end_sites)
    return Motion(skeleton, channel_rotations(orders, angles), "quat", torch.from_numpy(root_positions),
                  frame_time, translations=None if translations is None else torch.from_numpy(translations))


def read_bvh(path) -> Motion:
    """Read a BVH file into a :class:`Motion` of local quaternions.

    Args:
        path: the ``.bvh`` file.

    Returns:
        A :class:`Motion` with ``representation="quat"`` (float64), the skeleton in file order
        with each joint's channels and End Sites, ``root_positions`` from the root's position
        channels (its offset where it has none) and ``frame_time`` from ``Frame Time:``.

    Raises:
        PoseFileError: a malformed file; the message names the file and the line (a frame line
            with too few or too many numbers, an unclosed brace, an unknown channel), or says how
            ``Frames:`` disagrees with the frame lines.

    Shape:
        ``rotations`` ``(T, J, 4)``, ``root_positions`` ``(T, 3)``, ``skeleton.offsets`` ``(J, 3)``.

    Example:
        >>> import tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "one.bvh")
        >>> _ = open(path, "w").write("HIERARCHY\\nROOT hips\\n{\\n OFFSET 0 0 0\\n CHANNELS 3 Zrotation "
        ...     "Xrotation Yrotation\\n}\\nMOTION\\nFrames: 1\\nFrame Time: 0.5\\n90 0 0\\n")
        >>> read_bvh(path).rotations
        tensor([[[0.7071, 0.0000, 0.0000, 0.7071]]], dtype=torch.float64)
    """
    with open(path, "rb") as stream:
        return parse_bvh(os.fspath(path), stream.read())

