"""Optional polars fast path for parsing and formatting text pose files.

Used only when ``import polars`` works (``pip install torchquat[fast]``) and the environment
variable ``TORCHQUAT_POLARS`` is not ``0``; everything here has a numpy twin that gives the same
values, so polars changes speed, never results:

* :func:`parse_block` parses a block of data lines with polars ``read_csv`` and returns None
  (the caller then uses ``numpy.loadtxt`` and, on failure, names the bad line) unless every line
  gave exactly one full row of finite-or-not floats. Measured: 1M KITTI lines 0.4 s against
  0.7-1.5 s for ``loadtxt``. Every token polars accepts parses to the same float as with
  ``loadtxt`` (tested in ``tests/test_io_fastpath.py``).
* :func:`write_table` formats columns with polars ``write_csv`` (shortest round-trip floats, by
  the Ryu algorithm): about 1 s for 1M rows of 8 columns against 3.7-7 s for the vectorised
  numpy formatter of :mod:`torchquat.io.numtext`. The text can differ in layout (``1.0`` for
  ``1``, ``0.00001`` for ``1e-05``, ``-0.0`` for ``0``), never in the value read back.
"""

import io
import os
import threading
from typing import Optional, Sequence

import numpy as np

from .numtext import Floats, Integers, Nanoseconds

__all__ = ["polars", "use_polars", "parse_block", "write_table"]

_IMPORT_LOCK = threading.Lock()
_STATE = {"module": None, "tried": False, "enabled": os.environ.get("TORCHQUAT_POLARS", "1") != "0"}


def polars():
    """The polars module when installed and enabled, else None (imported on first use)."""
    if not _STATE["enabled"]:
        return None
    if not _STATE["tried"]:
        # (the parsing thread and the writer ask at once: the second waits for the first's import,
        # rather than reading "tried, no module" and taking the numpy path for its first chunk)
        with _IMPORT_LOCK:
            if not _STATE["tried"]:
                try:
                    import polars as module
                    _STATE["module"] = module
                except Exception:  # not installed, or a broken install: the numpy path is always there
                    _STATE["module"] = None
                _STATE["tried"] = True
    return _STATE["module"]


def use_polars(enabled: bool) -> bool:
    """Turn the polars fast path on or off for this process; returns the previous setting."""
    previous = _STATE["enabled"]
    _STATE["enabled"] = bool(enabled)
    return previous


def parse_block(block: bytes, count: int, columns: Sequence[int], delimiter: Optional[bytes]) -> Optional[np.ndarray]:
    """Parse ``count`` data lines (no comments, no blank lines) into a C-ordered ``(count, k)`` float64 array.

    Returns None when polars is not used, or when it cannot give exactly ``count`` full rows of
    one of the accepted column counts (the caller then parses with numpy and names the bad line).
    """
    pl = polars()
    if pl is None or count == 0:
        return None
    separator = (delimiter or b" ").decode()
    end = block.find(b"\n")
    k = (block[:end] if end >= 0 else block).count(separator.encode()) + 1
    if k not in columns:
        return None
    try:
        frame = pl.read_csv(block, has_header=False, separator=separator, quote_char=None, comment_prefix=None,
                            schema={f"c{i}": pl.Float64 for i in range(k)}, truncate_ragged_lines=False,
                            eol_char="\n")
        if frame.height != count or frame.null_count().sum_horizontal().item() != 0:
            return None
        return np.ascontiguousarray(frame.to_numpy(), dtype=np.float64)
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException:  # any polars error (a pyo3 panic is a BaseException): numpy decides
        return None


def write_table(columns: Sequence, separator: str = " ") -> Optional[bytes]:
    """Format columns (see :func:`torchquat.io.numtext.format_columns`) as text lines, or None without polars."""
    pl = polars()
    if pl is None:
        return None
    series = []
    for column in columns:
        values = column.values
        if isinstance(column, Floats):
            dtype = pl.Float32 if values.dtype == np.float32 else pl.Float64
            series += [pl.Series(f"c{len(series) + j}", values[:, j], dtype=dtype) for j in range(values.shape[1])]
        elif isinstance(column, Integers):
            series.append(pl.Series(f"c{len(series)}", np.asarray(values, dtype=np.int64)))
        elif isinstance(column, Nanoseconds):
            series.append(_seconds_text(pl, np.asarray(values, dtype=np.int64)).alias(f"c{len(series)}"))
        else:
            raise TypeError(f"write_table: unknown column {type(column).__name__}")
    out = io.BytesIO()
    pl.DataFrame(series).write_csv(out, include_header=False, separator=separator, float_precision=None,
                                   quote_style="never", line_terminator="\n")
    return out.getvalue()


def _seconds_text(pl, ns: np.ndarray):
    """Exact seconds ``[-]s.fffffffff`` (trailing zeros dropped, at least one decimal), like ``format_nanoseconds``."""
    frame = pl.DataFrame({"ns": ns})
    magnitude = pl.col("ns").abs()
    fraction = (magnitude % 1_000_000_000).cast(pl.String).str.zfill(9).str.strip_chars_end("0")
    text = pl.concat_str([
        pl.when(pl.col("ns") < 0).then(pl.lit("-")).otherwise(pl.lit("")),
        (magnitude // 1_000_000_000).cast(pl.String),
        pl.lit("."),
        pl.when(fraction == "").then(pl.lit("0")).otherwise(fraction),
    ])
    return frame.select(text.alias("t")).to_series()
