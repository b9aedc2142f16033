"""The benchmark text formats: TUM, KITTI odometry and EuRoC ground truth, read and written.

* TUM RGB-D: ``timestamp tx ty tz qx qy qz qw`` separated by spaces, ``#`` comments.
* KITTI odometry: 12 numbers a line, the row-major 3x4 ``[R | t]``; no times in the file
  (its ``times.txt`` can be given separately, else the row index is the time).
* EuRoC MAV ground truth: CSV ``#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...``
  (velocity and bias columns are ignored on read), times in integer nanoseconds.
"""

from typing import BinaryIO, Iterator, Optional

import numpy as np
import torch

from .checks import Report, check_matrices, normalize_quaternions
from .numtext import Floats, Integers
from .poses import PoseFileError, Poses
from .textparse import decimal_seconds_to_ns, iter_line_chunks, parse_table, read_header
from .textwrite import format_table, positions_of, time_column

__all__ = ["read_tum", "read_kitti", "read_euroc", "TumWriter", "KittiWriter", "EurocWriter", "EUROC_HEADER",
           "euroc_header_problem"]

EUROC_HEADER = (b"#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],"
                b"q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n")


def euroc_header_problem(line: bytes) -> Optional[str]:
    """What keeps a header line from naming EuRoC's columns (``timestamp``, then ``p_*`` x, y, z,
    then ``q_*`` w, x, y, z, units in brackets allowed), or ``None`` if it names them. A header
    with another order (a scalar-last quaternion, say) must not be read as EuRoC: its numbers
    would be taken as w-first without a word."""
    names = [field.split(b"[")[0].strip().lower() for field in line.strip().lstrip(b"#").split(b",")]
    expected = "timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z"
    if len(names) < 8 or not names[0].startswith(b"timestamp"):
        return f"its header does not start with EuRoC's columns ({expected})"
    for column, name, (kind, axis) in zip(range(2, 9), names[1:8], (b"px", b"py", b"pz", b"qw", b"qx", b"qy", b"qz")):
        if not (name.startswith(bytes((kind,))) and name.endswith(bytes((axis,)))):
            return (f"its header names column {column} {name.decode('utf-8', 'replace')!r} where EuRoC "
                    f"has {kind:c}_{axis:c} ({expected})")
    return None


def _skip_euroc_header(path, stream: BinaryIO) -> int:
    """Raise if the file has a header (see :func:`textparse.read_header`) that does not name EuRoC's
    columns; else step over it (``#`` or not) and return the number of the line the stream is at."""
    if not stream.seekable():
        return 1
    line, number, next_line = read_header(stream)
    if line:  # (a header: named columns)
        problem = euroc_header_problem(line)
        if problem is not None:
            raise PoseFileError(path, f"not EuRoC ground truth: {problem}; for other columns use a plain CSV "
                                "(--from csv on the command line, format=\"csv\" in Python) with the names "
                                "it documents", number)
    return next_line


def read_tum(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield TUM poses chunk by chunk (rotations as ``"quat_xyzw"``, exact ns times when possible)."""
    for chunk in iter_line_chunks(stream, chunk_lines):
        table = parse_table(path, chunk, (8,), "TUM: timestamp tx ty tz qx qy qz qw", keep_first_text=True)
        if len(table.values) == 0:
            continue
        values = table.values
        q = normalize_quaternions(path, values[:, 4:8], table.line_numbers, report)
        ns = decimal_seconds_to_ns(table.first_fields)
        yield Poses(torch.from_numpy(q), "quat_xyzw", positions=torch.from_numpy(values[:, 1:4].copy()),
                    timestamps=values[:, 0].copy(), timestamps_ns=ns)


def read_kitti(path, stream: BinaryIO, chunk_lines: int, report: Report,
               times: Optional[np.ndarray] = None, times_ns: Optional[np.ndarray] = None,
               **_) -> Iterator[Poses]:
    """Yield KITTI poses (rotations as ``"matrix"``); times from ``times`` or the row index."""
    row = 0
    for chunk in iter_line_chunks(stream, chunk_lines):
        table = parse_table(path, chunk, (12,), "KITTI: row-major 3x4 [R | t]")
        n = len(table.values)
        if n == 0:
            continue
        pose = table.values.reshape(n, 3, 4)
        R, _ = check_matrices(path, np.ascontiguousarray(pose[:, :, :3]), table.line_numbers, report)
        if times is None:
            seconds, ns = np.arange(row, row + n, dtype=np.float64), None
        else:
            if row + n > len(times):
                raise PoseFileError(path, f"more poses than the {len(times)} lines of the times file",
                                    int(table.line_numbers[len(times) - row]) if len(times) > row else None)
            seconds = times[row:row + n]
            ns = None if times_ns is None else times_ns[row:row + n]
        row += n
        yield Poses(torch.from_numpy(R), "matrix", positions=torch.from_numpy(pose[:, :, 3].copy()),
                    timestamps=seconds, timestamps_ns=ns)
    if times is not None and row != len(times):
        raise PoseFileError(path, f"{row} poses but the times file has {len(times)} lines")


def read_euroc(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield EuRoC ground-truth poses (rotations as ``"quat"``, times exact in nanoseconds)."""
    first_line = _skip_euroc_header(path, stream)
    for chunk in iter_line_chunks(stream, chunk_lines, first_line=first_line):
        table = parse_table(path, chunk, range(8, 64), "EuRoC: timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...",
                            delimiter=b",", keep_first_text=True)
        if len(table.values) == 0:
            continue
        values = table.values
        ns = _integer_ns(path, table)
        q = normalize_quaternions(path, values[:, 4:8], table.line_numbers, report)
        yield Poses(torch.from_numpy(q), "quat", positions=torch.from_numpy(values[:, 1:4].copy()),
                    timestamps_ns=ns)


def _integer_ns(path, table) -> np.ndarray:
    texts = table.first_fields
    try:
        return np.array([int(t) for t in texts], dtype=np.int64)
    except (ValueError, OverflowError):
        for text, line in zip(texts, table.line_numbers):
            try:
                value = int(text)
            except ValueError:
                raise PoseFileError(path, f"EuRoC timestamp must be integer nanoseconds, got "
                                    f"{text.decode('utf-8', 'replace')!r}", int(line)) from None
            if not -2 ** 63 <= value < 2 ** 63:
                raise PoseFileError(path, f"EuRoC timestamp {value} does not fit int64 nanoseconds", int(line))
        raise  # (unreachable: one of the texts failed)


class _TextWriter:
    """Shared shape of the text writers: a header once, then one block of lines per chunk."""

    representation = "quat"
    separator = " "

    def __init__(self, stream: BinaryIO, report: Report, dtype=np.float64):
        self.stream, self.report, self.dtype, self.rows = stream, report, dtype, 0
        self.started = False

    def header(self) -> bytes:
        return b""

    def fields(self, poses: Poses) -> list:
        raise NotImplementedError

    def write(self, poses: Poses) -> None:
        if not self.started:
            self.stream.write(self.header())
            self.started = True
        if len(poses):
            poses = poses.to(self.representation)
            self.stream.write(format_table(self.fields(poses), self.separator))
            self.rows += len(poses)

    def close(self) -> None:
        if not self.started:
            self.stream.write(self.header())

    def rotations(self, poses: Poses) -> np.ndarray:
        return poses.rotations.numpy().astype(self.dtype, copy=False)


class TumWriter(_TextWriter):
    """TUM lines ``timestamp tx ty tz qx qy qz qw``."""

    representation = "quat_xyzw"

    def header(self) -> bytes:
        return b"# timestamp tx ty tz qx qy qz qw\n"

    def fields(self, poses):
        values = np.concatenate([positions_of(poses, self.dtype, self.report), self.rotations(poses)], axis=1)
        return [time_column(poses, self.report, self.rows), Floats(values)]


class KittiWriter(_TextWriter):
    """KITTI lines: the row-major 3x4 ``[R | t]``; times are not kept (KITTI has none)."""

    representation = "matrix"

    def fields(self, poses):
        if poses.timestamps is not None and not np.array_equal(  # (times that are the row index lose nothing:
                poses.timestamps, np.arange(self.rows, self.rows + len(poses))):  # KITTI input without --times)
            self.report.note("KITTI files hold no timestamps: the input's timestamps are not written")
        pose = np.concatenate([self.rotations(poses), positions_of(poses, self.dtype, self.report)[:, :, None]],
                              axis=2)
        return [Floats(pose.reshape(len(poses), 12))]


class EurocWriter(_TextWriter):
    """EuRoC ground-truth CSV: integer nanoseconds, position, quaternion ``(w, x, y, z)``."""

    representation = "quat"
    separator = ","

    def header(self) -> bytes:
        return EUROC_HEADER

    def fields(self, poses):
        if poses.timestamps_ns is not None:
            ns = poses.timestamps_ns
        elif poses.timestamps is not None:
            self.report.note("EuRoC times are integer nanoseconds: seconds * 1e9 rounded to the nearest ns")
            scaled = np.rint(np.asarray(poses.timestamps, dtype=np.float64) * 1e9)
            outside = ~(np.abs(scaled) < 2.0 ** 63)  # (int64's range; NaN is outside too)
            if outside.any():
                raise ValueError(f"EuRoC output: the time {float(poses.timestamps[int(np.argmax(outside))])!r} s does not fit "
                                 "its int64 nanoseconds (about +-9.2e9 s)")
            ns = scaled.astype(np.int64)
        else:
            self.report.note("input has no timestamps: the row index is written as the time (ns)")
            ns = np.arange(self.rows, self.rows + len(poses), dtype=np.int64)
        values = np.concatenate([positions_of(poses, self.dtype, self.report), self.rotations(poses)], axis=1)
        return [Integers(ns), Floats(values)]
