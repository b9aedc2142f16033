"""Numbers to text lines for the text writers: polars when it is there, else numpy.

The twin of :mod:`torchquat.io.textparse`: :func:`format_table` tries the polars fast path
(:mod:`torchquat.io.fastpath`) and falls back to the numpy formatter
(:mod:`torchquat.io.numtext`); both give text that reads back to the same values. The column
helpers here are shared by the pose-format writers and the plain CSV writer.
"""

from typing import Sequence

import numpy as np

from .checks import Report
from .fastpath import write_table
from .numtext import Floats, Integers, Nanoseconds, format_columns
from .poses import Poses

__all__ = ["format_table", "time_column", "positions_of"]


def format_table(columns: Sequence, separator: str = " ") -> bytes:
    """Format columns into text lines, with polars when available.

    Args:
        columns: :class:`~torchquat.io.numtext.Floats`, ``Integers`` and ``Nanoseconds``, in
            column order.
        separator: the byte put between fields; each row ends with a newline.

    Returns:
        The encoded lines; every value reads back to the same float (or integer).

    Example:
        >>> text = format_table([Integers(np.array([7])), Floats(np.array([[0.5, -2.0]]))])
        >>> [float(v) for v in text.split()]
        [7.0, 0.5, -2.0]
    """
    text = write_table(columns, separator)
    return format_columns(columns, separator) if text is None else text


def time_column(poses: Poses, report: Report, row: int):
    """The time column of a chunk whose first row is ``row``.

    Exact ns as ``%d.%09d`` when known; whole seconds (KITTI's row index) as integers, which
    read back to the same float and are much cheaper to write; else float seconds.
    """
    if poses.timestamps_ns is not None:
        return Nanoseconds(poses.timestamps_ns)
    if poses.timestamps is None:
        report.note("input has no timestamps: the row index is written as the time")
        return Integers(np.arange(row, row + len(poses), dtype=np.int64))
    seconds = np.asarray(poses.timestamps, dtype=np.float64)
    if len(seconds) and np.all(np.abs(seconds) < 2.0 ** 53) and np.array_equal(seconds, np.floor(seconds)):
        return Integers(seconds.astype(np.int64))  # np.floor keeps -0.0 and nan/inf fail the test above
    return Floats(seconds[:, None])


def positions_of(poses: Poses, dtype, report: Report) -> np.ndarray:
    """The ``(n, 3)`` positions in ``dtype``; zeros (and a note) when the input has none."""
    if poses.positions is None:
        report.note("input has no positions: zeros written")
        return np.zeros((len(poses), 3), dtype=dtype)
    return poses.positions.numpy().astype(dtype, copy=False)
