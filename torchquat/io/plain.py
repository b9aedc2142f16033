"""Plain pose files: ``.csv`` with a header naming the representation, ``.npz`` and ``.npy``.

CSV columns: ``timestamp`` (when there are times), ``x,y,z`` (when there are positions), then
the rotation columns, named so that reading the file back recovers the representation:

==============  ==============================================
``quat``        ``qw,qx,qy,qz``
``quat_xyzw``   ``qx,qy,qz,qw``
``matrix``      ``r00,r01,...,r22`` (row-major; also ``rot9d``)
``euler:SEQ``   ``SEQ_1,SEQ_2,SEQ_3``, ``SEQ_1_deg,...`` in degrees
``axis_angle``  ``ax,ay,az``
``rot6d``       ``r6_1,...,r6_6``
==============  ==============================================

Camera poses keep their identifiers (:data:`~torchquat.io.cameras.ID_FIELDS`: ``image_id``,
``camera_id``, ``name``, ``file_path``, ``obj_id``) as leading columns (CSV quoting where a name
needs it) or ``.npz`` arrays; reading the file back puts them in ``Poses.meta`` under those names.
"""

import re
import zipfile
from typing import BinaryIO, Iterator, List, Optional, Tuple

import numpy as np
import torch

from .cameras import ID_FIELDS
from .checks import Report, check_matrices, check_rot6d, normalize_quaternions
from .numtext import Floats
from .poses import PoseFileError, Poses
from .representations import SHAPES, parse_token
from .textparse import LineChunk, decimal_seconds_to_ns, iter_line_chunks, lines_text, parse_table, read_header
from .textwrite import format_table, positions_of, time_column

__all__ = ["rotation_columns", "parse_columns", "id_columns", "id_values", "read_csv", "read_npz", "read_npy",
           "CsvWriter", "NpzWriter", "NpyWriter", "representation_of_shape"]

_FIXED = {
    "quat": ["qw", "qx", "qy", "qz"],
    "quat_xyzw": ["qx", "qy", "qz", "qw"],
    "matrix": [f"r{i}{j}" for i in range(3) for j in range(3)],
    "axis_angle": ["ax", "ay", "az"],
    "rot6d": [f"r6_{i}" for i in range(1, 7)],
}
_EULER = re.compile(r"^([xyzXYZ]{3})_([123])(_deg)?$")


def rotation_columns(representation: str, degrees: bool = False) -> List[str]:
    """Column names of a rotation representation in a plain CSV file.

    Example:
        >>> rotation_columns("euler:ZYX", degrees=True)
        ['ZYX_1_deg', 'ZYX_2_deg', 'ZYX_3_deg']
    """
    name, _, convention = representation.partition(":")
    if name == "euler":
        return [f"{convention}_{i}{'_deg' if degrees else ''}" for i in (1, 2, 3)]
    return _FIXED["matrix" if name == "rot9d" else name]


def id_columns(names: List[str]) -> List[str]:
    """The leading identifier columns of a header (:data:`~torchquat.io.cameras.ID_FIELDS`, each once).

    Example:
        >>> id_columns(["image_id", "camera_id", "name", "x", "y", "z", "qw", "qx", "qy", "qz"])
        ['image_id', 'camera_id', 'name']
    """
    found: List[str] = []
    for name in names:
        if name not in ID_FIELDS or name in found:
            break
        found.append(name)
    return found


_INTEGER_IDS = ("image_id", "camera_id", "obj_id")


def id_values(name: str, values: list) -> np.ndarray:
    """An identifier column as ``Poses.meta`` holds it: int64 ids, str names (ValueError if not ints)."""
    return np.array([int(v) for v in values], dtype=np.int64) if name in _INTEGER_IDS else np.array(values, dtype=str)


def parse_columns(path, names: List[str], line: int = 1) -> Tuple[bool, bool, str, bool]:
    """From a header (at ``line``, for errors): (has timestamp, has positions, representation, degrees).
    Leading identifier columns (:func:`id_columns`) are allowed and skipped."""
    rest = list(names)[len(id_columns(names)):]
    has_time = bool(rest) and rest[0] == "timestamp"
    rest = rest[1:] if has_time else rest
    has_position = rest[:3] == ["x", "y", "z"]
    rest = rest[3:] if has_position else rest
    for name, columns in _FIXED.items():
        if rest == columns:
            return has_time, has_position, name, False
    found = [_EULER.match(c) for c in rest]
    if len(rest) == 3 and all(found) and len({m.group(1) for m in found}) == 1 \
            and [m.group(2) for m in found] == ["1", "2", "3"] and len({m.group(3) for m in found}) == 1:
        return has_time, has_position, f"euler:{found[0].group(1)}", found[0].group(3) is not None
    raise PoseFileError(path, f"unrecognised CSV header {','.join(names)!r}: expected [ids,][timestamp,][x,y,z,] then "
                        "qw,qx,qy,qz | qx,qy,qz,qw | r00..r22 | SEQ_1,SEQ_2,SEQ_3[_deg] | ax,ay,az | r6_1..r6_6", line)


def _checked(path, rotations: np.ndarray, representation: str, lines: np.ndarray, report: Report) -> np.ndarray:
    if representation.startswith("quat"):
        return normalize_quaternions(path, rotations, lines, report)
    if representation == "matrix":
        return check_matrices(path, rotations, lines, report)[0]
    if representation == "rot6d":
        return check_rot6d(path, rotations, lines)
    return rotations


def read_csv(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield poses from a plain CSV file whose header names the columns."""
    header, header_line, next_line = read_header(stream)
    if not header:
        raise PoseFileError(path, "a plain CSV needs a header naming its columns (e.g. timestamp,x,y,z,qw,qx,qy,qz), "
                            "on its first line or as the # line before the data", next_line)
    names = [n.strip() for n in header.decode("utf-8", "replace").strip().lstrip("#").strip().split(",")]
    has_time, has_position, representation, degrees = parse_columns(path, names, header_line)
    shape = SHAPES[representation.partition(":")[0]]
    start = int(has_time) + 3 * has_position
    ids = id_columns(names)
    numbers = names[len(ids):]
    for chunk in iter_line_chunks(stream, chunk_lines, first_line=next_line):
        fields = None
        if ids:
            chunk, fields = _split_ids(path, chunk, names)
        table = parse_table(path, chunk, (len(numbers),), f"CSV columns {','.join(numbers)}", delimiter=b",",
                            keep_first_text=has_time)
        if len(table.values) == 0:
            continue
        values = table.values
        meta = None
        if ids:
            rows = [fields[i] for i in table.line_numbers - chunk.first_line]
            meta = {}
            for k, name in enumerate(ids):
                try:
                    meta[name] = id_values(name, [row[k] for row in rows])
                except ValueError:
                    bad = next(i for i, row in enumerate(rows) if not _is_integer(row[k]))
                    raise PoseFileError(path, f"column {name!r} holds {rows[bad][k]!r}, not an integer id",
                                        int(table.line_numbers[bad])) from None
        rotations = np.ascontiguousarray(values[:, start:]).reshape(len(values), *shape)
        rotations = _checked(path, rotations, representation, table.line_numbers, report)
        yield Poses(torch.from_numpy(rotations), representation, degrees=degrees,
                    positions=torch.from_numpy(values[:, start - 3:start].copy()) if has_position else None,
                    timestamps=values[:, 0].copy() if has_time else None,
                    timestamps_ns=decimal_seconds_to_ns(table.first_fields) if has_time else None, meta=meta)


def _is_integer(text: str) -> bool:
    try:
        int(text)
    except ValueError:
        return False
    return True


def _split_ids(path, chunk: LineChunk, names: List[str]) -> Tuple[LineChunk, List[Optional[List[str]]]]:
    """Cut the leading identifier fields off each data line (read as Python's ``csv`` writes them,
    quoted where a name holds a comma): the numbers that are left, as a chunk with the same line
    numbers, and each line's identifier fields (None for blank and comment lines)."""
    import csv
    count = len(id_columns(names))
    lines, fields = [], []
    for number, line in enumerate(chunk.lines, chunk.first_line):
        stripped = line.strip()
        if not stripped or stripped.startswith(b"#"):
            lines.append(line)
            fields.append(None)
            continue
        try:
            row = next(csv.reader([line.decode("utf-8").rstrip("\r\n")]))
        except (UnicodeDecodeError, csv.Error) as err:
            raise PoseFileError(path, f"cannot read {lines_text(line)!r} as CSV ({err})", number) from None
        if len(row) != len(names):
            raise PoseFileError(path, f"expected {len(names)} columns ({','.join(names)}), found {len(row)}: "
                                f"{lines_text(line)!r}", number)
        lines.append(",".join(row[count:]).encode() + b"\n")
        fields.append(row[:count])
    return LineChunk(chunk.first_line, lines), fields


def representation_of_shape(path, shape: Tuple[int, ...]) -> str:
    """Guess the representation of a bare rotation array from its trailing shape."""
    guesses = {(4,): "quat", (3, 3): "matrix", (9,): "rot9d", (6,): "rot6d", (3,): "axis_angle"}
    found = guesses.get(tuple(shape[1:]))
    if found is None or len(shape) < 2:
        raise PoseFileError(path, f"cannot tell the rotation representation of an array of shape {shape}: "
                            "expected (n, 4), (n, 3, 3), (n, 9), (n, 6) or (n, 3)")
    return found


def _array_chunks(poses: Poses, chunk_lines: int) -> Iterator[Poses]:
    for start in range(0, len(poses), chunk_lines):
        yield poses[start:start + chunk_lines]


def _float_array(path, array: np.ndarray, what: str) -> np.ndarray:
    if not np.issubdtype(array.dtype, np.floating):
        raise PoseFileError(path, f"{what} must be a floating-point array, got dtype {array.dtype}")
    finite = np.isfinite(array.reshape(len(array), -1)).all(axis=1) if array.size else np.ones(0, bool)
    if not finite.all():
        raise PoseFileError(path, f"{what} row {int(np.argmin(finite))} is not finite (nan or inf)")
    return array


def _checked_array(path, rotations: np.ndarray, representation: str, report: Report) -> np.ndarray:
    rows = np.arange(len(rotations))  # reported as rows, not lines
    try:
        return _checked(path, rotations.astype(np.float64), representation, rows, report)
    except PoseFileError as err:
        raise PoseFileError(path, f"rotation row {err.line}: {err.problem}") from None


def _load(path, stream: BinaryIO, kind: str):
    """``numpy.load`` of a whole ``.npz``/``.npy``, its failures (empty, truncated, pickled or not
    numpy at all) as one :class:`PoseFileError`."""
    try:
        return np.load(stream, allow_pickle=False)
    except (EOFError, ValueError, zipfile.BadZipFile, OSError) as err:
        raise PoseFileError(path, f"not a readable {kind} file ({err})") from None


def _array_of(path, data, name: str, kinds: str, rows: int) -> np.ndarray:
    array = data[name]
    if array.dtype.kind not in kinds:
        raise PoseFileError(path, f"array {name!r} has dtype {array.dtype}, not numbers")
    if array.ndim != 1 or len(array) != rows:
        raise PoseFileError(path, f"array {name!r} has shape {array.shape}; {rows} rotations need ({rows},)")
    return array


def read_npz(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield poses from an ``.npz`` holding ``rotation``, ``representation`` and optional times and positions."""
    with _load(path, stream, ".npz") as data:
        if "rotation" not in data or "representation" not in data:
            raise PoseFileError(path, "an .npz pose file needs arrays 'rotation' and 'representation'")
        representation = str(data["representation"])
        try:
            parse_token(representation, "array 'representation'")
        except ValueError as err:  # (ConventionError too: a malformed Euler convention)
            raise PoseFileError(path, str(err)) from None
        degrees = bool(data["degrees"]) if "degrees" in data else False
        rotations = _checked_array(path, _float_array(path, data["rotation"], "rotation"), representation, report)
        rows = len(rotations)
        position = _float_array(path, data["position"], "position") if "position" in data else None
        if position is not None and position.shape != (rows, 3):
            raise PoseFileError(path, f"array 'position' has shape {position.shape}; {rows} rotations need ({rows}, 3)")
        seconds = _array_of(path, data, "timestamp", "fiu", rows) if "timestamp" in data else None
        ns = _array_of(path, data, "timestamp_ns", "iu", rows) if "timestamp_ns" in data else None
        meta = {k: _array_of(path, data, k, "iuU", rows) for k in ID_FIELDS if k in data} or None
    poses = Poses(torch.from_numpy(rotations), representation, degrees=degrees,
                  positions=None if position is None else torch.from_numpy(position.astype(np.float64)),
                  timestamps=seconds, timestamps_ns=ns, meta=meta)
    yield from _array_chunks(poses, chunk_lines)


def read_npy(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield rotations from an ``.npy`` array; the representation is guessed from its shape."""
    rotations = _load(path, stream, ".npy")
    if not isinstance(rotations, np.ndarray):
        raise PoseFileError(path, "an .npz archive, not one .npy array: name the file .npz")
    rotations = _float_array(path, rotations, "rotation")
    representation = representation_of_shape(path, rotations.shape)
    report.note(f"{path}: an array of shape {rotations.shape} read as {representation!r}")
    rotations = _checked_array(path, rotations, representation, report)
    yield from _array_chunks(Poses(torch.from_numpy(rotations), representation), chunk_lines)


class CsvWriter:
    """Plain CSV with a header; the columns are decided by the first chunk."""

    def __init__(self, stream: BinaryIO, report: Report, dtype=np.float64, representation: str = "quat",
                 degrees: bool = False):
        self.stream, self.report, self.dtype = stream, report, dtype
        self.representation, self.degrees, self.rows = representation, degrees, 0
        self.columns: Optional[Tuple[bool, bool]] = None

    def write(self, poses: Poses) -> None:
        if self.columns is None:
            self.columns = (poses.timestamps is not None, poses.positions is not None)
            names = (["timestamp"] if self.columns[0] else []) + (["x", "y", "z"] if self.columns[1] else [])
            names += rotation_columns(self.representation, self.degrees)
            self.stream.write((",".join(names) + "\n").encode())
        if not len(poses):
            return
        poses = poses.to(self.representation, degrees=self.degrees)
        fields = [time_column(poses, self.report, self.rows)] if self.columns[0] else []
        values = [positions_of(poses, self.dtype, self.report)] if self.columns[1] else []
        values.append(poses.rotations.numpy().reshape(len(poses), -1).astype(self.dtype, copy=False))
        fields.append(Floats(np.concatenate(values, axis=1)))
        self.stream.write(format_table(fields, ","))
        self.rows += len(poses)

    def close(self) -> None:
        if self.columns is None:
            raise PoseFileError(getattr(self.stream, "name", "output"), "no poses to write")


class NpyWriter:
    """``.npy``: the rotation array alone (kept in memory until closed)."""

    def __init__(self, stream: BinaryIO, report: Report, dtype=np.float64, representation: str = "quat",
                 degrees: bool = False):
        self.stream, self.report, self.dtype = stream, report, dtype
        self.representation, self.degrees = representation, degrees
        self.parts: List[Poses] = []

    def write(self, poses: Poses) -> None:
        self.parts.append(poses.to(self.representation, degrees=self.degrees))

    def _rotations(self) -> np.ndarray:
        return np.concatenate([p.rotations.numpy() for p in self.parts]).astype(self.dtype, copy=False)

    def close(self) -> None:
        if self.representation.startswith("euler") or self.representation == "quat_xyzw":
            self.report.note(f"an .npy file holds no representation name: it will read back by shape, "
                             f"not as {self.representation!r}")
        np.save(self.stream, self._rotations())


class NpzWriter(NpyWriter):
    """``.npz``: arrays ``timestamp``, ``timestamp_ns``, ``position``, ``rotation``, ``representation``, ``degrees``."""

    def close(self) -> None:
        arrays = {"rotation": self._rotations(), "representation": np.array(self.representation),
                  "degrees": np.array(self.degrees)}
        if all(p.positions is not None for p in self.parts):
            arrays["position"] = np.concatenate([p.positions.numpy() for p in self.parts]).astype(self.dtype)
        if all(p.timestamps is not None for p in self.parts):
            arrays["timestamp"] = np.concatenate([p.timestamps for p in self.parts]).astype(np.float64)
        if all(p.timestamps_ns is not None for p in self.parts):
            arrays["timestamp_ns"] = np.concatenate([p.timestamps_ns for p in self.parts])
        np.savez(self.stream, **arrays)
