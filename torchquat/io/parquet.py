"""Parquet pose files (``.parquet``): a plain format with the CSV's column names, through pyarrow.

Columns: ``timestamp`` (float64 seconds, when the poses have times), ``x,y,z`` (when they have
positions), then the rotation columns named as in a plain CSV (:func:`~torchquat.io.plain.rotation_columns`:
``qw,qx,qy,qz``, ``ZYX_1_deg,...``, ``r00..r22``, ...), so that reading the file back recovers the
representation. Identifiers of camera poses (``image_id``, ``camera_id``, ``name``, ``file_path``,
``obj_id``: int64 or string columns) come first, as in the CSV, and read back into ``Poses.meta``.
Values are float64, or float32 with ``dtype=numpy.float32`` (times stay float64).
The file is written in row groups of about :data:`ROW_GROUP_ROWS` rows and read back one record
batch at a time, so memory stays flat in the file's size.

pyarrow is optional (``pip install 'torchquat[dask]'``) and imported on first use; without it,
reading or writing a ``.parquet`` file raises a :class:`PoseFileError` that says so.
"""

from typing import BinaryIO, Iterator, List, Optional

import numpy as np
import torch

from .cameras import ID_FIELDS
from .checks import Report
from .plain import _checked, id_columns, id_values, parse_columns, rotation_columns
from .poses import PoseFileError, Poses
from .representations import SHAPES

__all__ = ["read_parquet", "ParquetWriter", "ROW_GROUP_ROWS", "pyarrow_modules"]

ROW_GROUP_ROWS = 131_072  # rows per row group: large enough for readers, small enough to stay flat


def pyarrow_modules(path):
    """``(pyarrow, pyarrow.parquet)``, imported now; a :class:`PoseFileError` naming ``path`` and
    the ``torchquat[dask]`` extra when pyarrow is not installed."""
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise PoseFileError(path, "Parquet files need pyarrow, which is not installed: pip install "
                            "'torchquat[dask]' (or pip install pyarrow)") from None
    return pyarrow, pyarrow.parquet


def read_parquet(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield poses from a Parquet file whose columns are named as in a plain CSV.

    Args:
        path: the file's name (for messages).
        stream: the open file (binary, seekable).
        chunk_lines: rows per chunk.
        report: collects what was repaired.

    Returns:
        An iterator of :class:`Poses` in the representation the column names give.

    Raises:
        PoseFileError: not Parquet, unrecognised columns, missing or non-finite values (the
            message names the column and the 0-based row).
    """
    pyarrow, parquet = pyarrow_modules(path)
    try:
        handle = parquet.ParquetFile(stream)
    except (pyarrow.ArrowException, OSError, ValueError) as err:
        raise PoseFileError(path, f"not a readable Parquet file ({err})") from None
    names = list(handle.schema_arrow.names)
    has_time, has_position, representation, degrees = parse_columns(path, names, None)
    shape = SHAPES[representation.partition(":")[0]]
    start = int(has_time) + 3 * has_position
    ids = id_columns(names)
    row = 0
    try:
        batches = handle.iter_batches(batch_size=max(1, chunk_lines), columns=names)
        for batch in batches:
            n = batch.num_rows
            if n == 0:
                continue
            meta = {name: _id_column(path, batch.column(i), name, row) for i, name in enumerate(ids)} or None
            columns = [_column(path, batch.column(i), name, row) for i, name in enumerate(names) if i >= len(ids)]
            values = np.stack(columns, axis=1)
            rotations = np.ascontiguousarray(values[:, start:]).reshape(n, *shape)
            rows = np.arange(row, row + n)
            try:
                rotations = _checked(path, rotations, representation, rows, report)
            except PoseFileError as err:
                raise PoseFileError(path, f"rotation row {err.line}: {err.problem}") from None
            yield Poses(torch.from_numpy(rotations), representation, degrees=degrees,
                        positions=torch.from_numpy(values[:, start - 3:start].copy()) if has_position else None,
                        timestamps=values[:, 0].copy() if has_time else None, meta=meta)
            row += n
    except pyarrow.ArrowException as err:
        raise PoseFileError(path, f"not a readable Parquet file ({err})") from None


def _column(path, array, name: str, row: int) -> np.ndarray:
    """One column of a record batch as float64, refusing nulls, non-numbers and nan/inf."""
    kind = str(array.type)
    if not (kind.startswith("float") or kind.startswith("int") or kind.startswith("uint")
            or kind in ("double", "halffloat")):
        raise PoseFileError(path, f"column {name!r} has type {kind}, not numbers")
    if array.null_count:
        first = int(np.argmax(np.asarray(array.is_null())))
        raise PoseFileError(path, f"column {name!r} row {row + first} is missing (null)")
    values = np.asarray(array.to_numpy(zero_copy_only=False), dtype=np.float64)
    finite = np.isfinite(values)
    if not finite.all():
        raise PoseFileError(path, f"column {name!r} row {row + int(np.argmin(finite))} is not finite (nan or inf)")
    return values


def _id_column(path, array, name: str, row: int) -> np.ndarray:
    """An identifier column of a record batch: int64 ids or str names, refusing nulls."""
    if array.null_count:
        first = int(np.argmax(np.asarray(array.is_null())))
        raise PoseFileError(path, f"column {name!r} row {row + first} is missing (null)")
    values = array.to_pylist()
    try:
        return id_values(name, values)
    except (TypeError, ValueError):
        raise PoseFileError(path, f"column {name!r} has type {array.type}, not integer ids") from None


class ParquetWriter:
    """Parquet with the CSV's column names; the columns are decided by the first chunk.

    Args:
        stream: the binary stream to write (from :func:`~torchquat.io.files.atomic_output`).
        report: collects notes.
        dtype: ``numpy.float64`` or ``numpy.float32`` for positions and rotations.
        representation: the rotation representation written.
        degrees: Euler angles in degrees.

    Example:
        >>> import io
        >>> stream = io.BytesIO()
        >>> writer = ParquetWriter(stream, Report(), representation="euler:ZYX", degrees=True)
        >>> writer.write(Poses(torch.tensor([[1.0, 0.0, 0.0, 0.0]]), "quat"))
        >>> writer.close()
        >>> poses = list(read_parquet("mem.parquet", io.BytesIO(stream.getvalue()), 10, Report()))
        >>> poses[0].representation, poses[0].degrees, poses[0].rotations.tolist()
        ('euler:ZYX', True, [[0.0, 0.0, 0.0]])
    """

    def __init__(self, stream: BinaryIO, report: Report, dtype=np.float64, representation: str = "quat",
                 degrees: bool = False):
        self.stream, self.report, self.dtype = stream, report, np.dtype(dtype).type
        self.representation, self.degrees, self.rows = representation, degrees, 0
        self.columns: Optional[tuple] = None
        self.ids: List[str] = []  # identifier columns (ID_FIELDS found in the first chunk's meta)
        self.pending: List[Poses] = []
        self.pending_rows = 0
        self.writer = None
        name = getattr(stream, "name", None)  # (a file descriptor for atomic_output's temporary file)
        self.modules = pyarrow_modules(name if isinstance(name, str) else "the .parquet output")

    def write(self, poses: Poses) -> None:
        if self.columns is None:
            self.columns = (poses.timestamps is not None, poses.positions is not None)
            self.ids = [k for k in ID_FIELDS if k in (poses.meta or {})]
        if not len(poses):
            return
        self.pending.append(poses.to(self.representation, degrees=self.degrees))
        self.pending_rows += len(poses)
        if self.pending_rows >= ROW_GROUP_ROWS:
            self._flush()

    def _names(self) -> List[str]:
        names = self.ids + (["timestamp"] if self.columns[0] else []) + (["x", "y", "z"] if self.columns[1] else [])
        return names + rotation_columns(self.representation, self.degrees)

    def _flush(self) -> None:
        if not self.pending:
            return
        pyarrow, parquet = self.modules
        arrays = [pyarrow.array(np.concatenate([np.asarray(p.meta[k]) for p in self.pending]).tolist(),
                                type=pyarrow.int64() if k.endswith("_id") else pyarrow.string()) for k in self.ids]
        if self.columns[0]:
            arrays.append(self._seconds())
        if self.columns[1]:
            positions = torch.cat([p.positions for p in self.pending]).numpy().astype(self.dtype, copy=False)
            arrays.extend(positions[:, i] for i in range(3))
        rotations = torch.cat([p.rotations for p in self.pending]).numpy()
        rotations = rotations.reshape(len(rotations), -1).astype(self.dtype, copy=False)
        arrays.extend(rotations[:, i] for i in range(rotations.shape[1]))
        arrays[len(self.ids):] = [pyarrow.array(np.ascontiguousarray(a)) for a in arrays[len(self.ids):]]
        table = pyarrow.table(arrays, names=self._names())
        if self.writer is None:
            self.writer = parquet.ParquetWriter(self.stream, table.schema)
        self.writer.write_table(table, row_group_size=len(table))
        self.rows += self.pending_rows
        self.pending, self.pending_rows = [], 0

    def _seconds(self) -> np.ndarray:
        seconds = np.concatenate([np.asarray(p.timestamps, dtype=np.float64) for p in self.pending])
        exact = [p.timestamps_ns for p in self.pending if p.timestamps_ns is not None]
        if exact:
            ns = np.concatenate(exact)
            if len(ns) == len(seconds) and not np.array_equal(np.rint(seconds * 1e9).astype(np.int64), ns):
                self.report.note("Parquet's timestamp column holds float64 seconds: times given to the "
                                 "nanosecond are rounded to float64")
        return seconds

    def close(self) -> None:
        if self.columns is None:
            raise PoseFileError(getattr(self.stream, "name", "output"), "no poses to write")
        self._flush()
        if self.writer is None:  # (no rows at all: an empty table with the columns)
            pyarrow, parquet = self.modules
            types = {k: pyarrow.int64() if k.endswith("_id") else pyarrow.string() for k in self.ids}
            schema = pyarrow.schema([(name, types.get(name, pyarrow.float64())) for name in self._names()])
            self.writer = parquet.ParquetWriter(self.stream, schema)
        self.writer.close()
