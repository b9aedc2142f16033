"""COLMAP sparse models: the poses of ``images.txt`` and ``images.bin``, read and written, streaming.

A pose is COLMAP's ``cam_from_world``: world -> camera, OpenCV camera axes, quaternion
``QW QX QY QZ`` (scalar first, Hamilton) and translation ``TX TY TZ``; the camera centre is
``-R^T t`` (``Poses.inverse().positions``). pycolmap's ``Rotation3d.quat`` is ``(x, y, z, w)``.

* ``images.txt``: ``#`` comments, then two lines per image: ``IMAGE_ID QW QX QY QZ TX TY TZ
  CAMERA_ID NAME`` and the 2D points (skipped on read, written empty: poses only). NAME is the
  rest of the line (COLMAP itself stops at the first space).
* ``images.bin`` (little-endian): ``uint64`` image count, then per image ``uint32`` id, 7
  ``float64`` (q, t), ``uint32`` camera id, the name ending in a NUL byte, ``uint64`` point count
  and 24 bytes a point (``float64 x, y``, ``uint64`` point id), which are skipped.

The other files of a model (cameras, rigs, frames, points) are left alone.
"""

import os
import struct
from typing import BinaryIO, Iterator, List

import numpy as np
import torch

from .cameras import FORMAT_MAPS
from .checks import Report, normalize_quaternions
from .numtext import Floats, Integers
from .poses import PoseFileError, Poses
from .textparse import lines_text
from .textwrite import format_table, positions_of

__all__ = ["read_colmap", "ColmapWriter", "TEXT_HEADER"]

TEXT_HEADER = (b"# Image list with two lines of data per image:\n"
               b"#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
               b"#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
               b"# Written by torchquat: poses only, the POINTS2D lines are empty\n")
_FIXED = struct.Struct("<I7dI")  # image id, qw qx qy qz tx ty tz, camera id: 64 bytes
_COUNT = struct.Struct("<Q")
_POINT_BYTES = 24
_BLOCK = 1 << 20


def is_binary(path) -> bool:
    """``images.bin`` and other ``.bin`` names are the binary layout; anything else is text."""
    return os.fspath(path).lower().endswith(".bin")


def read_colmap(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield the poses of a COLMAP ``images.txt`` or ``images.bin`` in chunks of ``chunk_lines`` images.

    Args:
        path: the file (``.bin``: binary layout, else text).
        stream: it, open in binary mode.
        chunk_lines: images per chunk.
        report: counts quaternions normalised.

    Returns:
        :class:`Poses` in ``"quat"``, ``positions`` the translation ``t`` of ``cam_from_world``,
        ``meta`` ``image_id``, ``camera_id`` (int64) and ``name``, ``maps`` world -> camera (OpenCV).
    """
    rows = _binary_rows(path, stream, chunk_lines) if is_binary(path) else _text_rows(path, stream, chunk_lines)
    for ids, values, cameras, names, lines in rows:
        values = np.asarray(values, dtype=np.float64).reshape(len(ids), 7)
        q = normalize_quaternions(path, values[:, :4], np.asarray(lines), report)
        meta = {"image_id": np.asarray(ids, dtype=np.int64), "camera_id": np.asarray(cameras, dtype=np.int64),
                "name": np.array(names, dtype=str)}
        yield Poses(torch.from_numpy(q), "quat", positions=torch.from_numpy(values[:, 4:].copy()), meta=meta,
                    maps=FORMAT_MAPS["colmap"])


def _text_rows(path, stream: BinaryIO, chunk_lines: int):
    """Lists (ids, 7 numbers each, camera ids, names, line numbers) of up to ``chunk_lines`` images.

    Lines are read one at a time: a 2D-points line can be megabytes, and only its end is needed.
    """
    ids: List[int] = []
    values: List[float] = []
    cameras: List[int] = []
    names: List[str] = []
    lines: List[int] = []
    points_next = False
    for number, line in enumerate(stream, 1):
        if points_next:  # (COLMAP's rule: the line after an image line is its points, whatever it holds)
            points_next = False
            continue
        text = line.strip()
        if not text or text.startswith(b"#"):
            continue
        fields = text.split(None, 9)
        try:
            if len(fields) < 10:
                raise ValueError(f"{len(fields)} fields")
            image_id, camera_id = int(fields[0]), int(fields[8])
            numbers = [float(f) for f in fields[1:8]]
            name = fields[9].decode("utf-8")
        except ValueError as err:
            raise PoseFileError(path, f"expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME (integer ids, "
                                f"7 numbers), got {lines_text(line)!r} ({err})", number) from None
        if not all(np.isfinite(numbers)):
            raise PoseFileError(path, f"value is not finite (nan or inf) in {lines_text(line)!r}", number)
        ids.append(image_id)
        values.extend(numbers)
        cameras.append(camera_id)
        names.append(name)
        lines.append(number)
        points_next = True
        if len(ids) == chunk_lines:
            yield ids, values, cameras, names, lines
            ids, values, cameras, names, lines = [], [], [], [], []
    if ids:
        yield ids, values, cameras, names, lines


class _Buffer:
    """Bytes of a binary stream read in large blocks, with the file offset of each position."""

    def __init__(self, path, stream: BinaryIO):
        self.path, self.stream = path, stream
        self.start = stream.tell()
        self.size = stream.seek(0, os.SEEK_END)
        stream.seek(self.start)
        self.data, self.offset, self.base = b"", 0, self.start  # base: file offset of data[0]

    def where(self) -> int:
        return self.base + self.offset

    def need(self, count: int, what: str) -> None:
        """Make ``count`` bytes from the current position available, or name where the file ends."""
        if len(self.data) - self.offset >= count:
            return
        more = self.stream.read(max(_BLOCK, count))
        self.base += self.offset
        self.data, self.offset = self.data[self.offset:] + more, 0
        if len(self.data) < count:
            raise PoseFileError(self.path, f"truncated: the file ends at byte {self.size} in {what}, which needs "
                                f"bytes {self.where()} to {self.where() + count}")

    def skip(self, count: int, what: str) -> None:
        if self.where() + count > self.size:
            raise PoseFileError(self.path, f"truncated: the file ends at byte {self.size} in {what}, which needs "
                                f"bytes {self.where()} to {self.where() + count}")
        if len(self.data) - self.offset >= count:
            self.offset += count
        else:  # (beyond the block: seek past the points instead of reading them)
            self.base = self.where() + count
            self.stream.seek(self.base)
            self.data, self.offset = b"", 0

    def name(self, what: str) -> bytes:
        """The bytes up to the next NUL, which is stepped over."""
        while True:
            end = self.data.find(b"\0", self.offset)
            if end >= 0:
                text = self.data[self.offset:end]
                self.offset = end + 1
                return text
            self.need(len(self.data) - self.offset + 1, what)


def _binary_rows(path, stream: BinaryIO, chunk_lines: int):
    """As :func:`_text_rows`, from the binary layout; the "line" of an image is its 1-based index."""
    buffer = _Buffer(path, stream)
    buffer.need(8, "the image count")
    (count,) = _COUNT.unpack_from(buffer.data, buffer.offset)
    buffer.offset += 8
    rows: List[tuple] = []
    names: List[str] = []
    first = 1
    for index in range(1, count + 1):
        what = f"image {index} of {count} (starting at byte {buffer.where()})"
        buffer.need(_FIXED.size, what)
        rows.append(_FIXED.unpack_from(buffer.data, buffer.offset))
        buffer.offset += _FIXED.size
        try:
            names.append(buffer.name(what).decode("utf-8"))
        except UnicodeDecodeError as err:
            raise PoseFileError(path, f"image {index}: its name is not UTF-8 ({err})") from None
        buffer.need(8, what)
        (points,) = _COUNT.unpack_from(buffer.data, buffer.offset)
        buffer.offset += 8
        buffer.skip(points * _POINT_BYTES, what)
        if len(rows) == chunk_lines or index == count:
            table = np.array(rows, dtype=np.float64)
            yield (table[:, 0].astype(np.int64), table[:, 1:8], table[:, 8].astype(np.int64), names,
                   np.arange(first, index + 1))
            rows, names, first = [], [], index + 1
    if buffer.where() != buffer.size:
        raise PoseFileError(path, f"{buffer.size - buffer.where()} bytes after the last of its {count} images "
                            f"(from byte {buffer.where()}): not an images.bin, or a corrupt one")


def _identifiers(poses: Poses, row: int, report: Report):
    """(image ids, camera ids, names) of a chunk, from ``meta`` or defaults that are noted."""
    meta = poses.meta or {}
    n = len(poses)
    if "image_id" in meta and "name" in meta:  # (BOP's image_id alone repeats: one image, many objects)
        ids = np.asarray(meta["image_id"], dtype=np.int64)
    elif "colmap_im_id" in meta and meta["colmap_im_id"].dtype.kind == "i":  # (nerfstudio's transforms.json)
        ids = np.asarray(meta["colmap_im_id"], dtype=np.int64)
    else:
        report.note("COLMAP output: IMAGE_ID is the pose's 1-based index")
        ids = np.arange(row + 1, row + n + 1, dtype=np.int64)
    if "camera_id" in meta:
        cameras = np.asarray(meta["camera_id"], dtype=np.int64)
    else:
        report.note("COLMAP output: CAMERA_ID 1 for every image (the model's cameras.txt is not written)")
        cameras = np.ones(n, dtype=np.int64)
    if "name" in meta or "file_path" in meta:
        key = "name" if "name" in meta else "file_path"
        if key == "file_path":
            report.note("COLMAP output: NAME is NeRF's file_path, unchanged")
        names = [str(v) for v in meta[key]]
    else:
        report.note("COLMAP output: NAME is the pose's 1-based index")
        names = [str(i) for i in ids]
    if ((ids < 0) | (ids >= 2 ** 32)).any() or ((cameras < 0) | (cameras >= 2 ** 32)).any():
        raise ValueError("COLMAP output: image and camera ids must fit uint32 (0 to 4294967295)")
    return ids, cameras, names


class ColmapWriter:
    """Writes ``images.txt`` (text) or ``images.bin`` (binary, by the name's ``.bin``), chunk by chunk.

    Args:
        stream: the output, binary and seekable (the binary image count is filled in at the end).
        report: collects notes (defaults for missing identifiers).
        dtype: ``numpy.float64`` or ``numpy.float32`` (values rounded to it; binary stores float64).
        path: the output's name, which decides text or binary.
    """

    def __init__(self, stream: BinaryIO, report: Report, dtype=np.float64, path="images.txt"):
        self.stream, self.report, self.dtype, self.binary = stream, report, dtype, is_binary(path)
        self.rows = 0
        self.stream.write(_COUNT.pack(0) if self.binary else TEXT_HEADER)

    def write(self, poses: Poses) -> None:
        if not len(poses):
            return
        poses = poses.to("quat")
        ids, cameras, names = _identifiers(poses, self.rows, self.report)
        values = np.concatenate([poses.rotations.numpy(), positions_of(poses, np.float64, self.report)], axis=1)
        values = values.astype(self.dtype).astype(np.float64)
        if any("\n" in name or "\0" in name or (not self.binary and (not name.strip() or name != name.strip()))
               for name in names):
            raise ValueError("COLMAP output: an image name is empty, has a line break or NUL, or (in images.txt) "
                             "leading or trailing spaces, which would not read back")
        if self.binary:
            end = _COUNT.pack(0)
            self.stream.write(b"".join(_FIXED.pack(int(i), *v, int(c)) + n.encode("utf-8") + b"\0" + end
                                       for i, v, c, n in zip(ids, values.tolist(), cameras, names)))
        else:
            text = format_table([Integers(ids), Floats(values), Integers(cameras)], " ")
            self.stream.write(b"".join(line + b" " + n.encode("utf-8") + b"\n\n"
                                       for line, n in zip(text.splitlines(), names)))
        self.rows += len(poses)

    def close(self) -> None:
        if self.binary:
            self.stream.seek(0)
            self.stream.write(_COUNT.pack(self.rows))
            self.stream.seek(0, os.SEEK_END)
