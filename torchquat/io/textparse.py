"""Parsing blocks of text lines into number tables, with exact line numbers on any failure.

Measured on the 2-core reference machine, 1M KITTI lines (12 numbers each, 160 MB):
``numpy.loadtxt`` over 1 MB blocks 0.68-0.81 s, ``numpy.fromstring(sep=' ')`` 1.06 s,
``bytes.split`` + ``numpy.array`` 1.30 s, ``numpy.loadtxt`` on the whole file 0.63 s (but memory
grows with the file). So each chunk of lines goes through ``numpy.loadtxt`` (its C parser), and
only when that fails is the chunk walked line by line in Python to name the first bad line.

Chunks are read as byte blocks cut at the ``chunk_lines``-th newline (no Python object per
line). A block without ``#`` is first parsed whole, and the result kept only when it has exactly
one full row per line (so no line was blank or a comment): then it is what the line-by-line way
gives. Any other block is split into lines and goes the way above. When polars is installed
(``pip install torchquat[fast]``) the whole-block parse is polars ``read_csv`` (0.4 s for 1M
KITTI lines; see :mod:`torchquat.io.fastpath`), falling back to ``loadtxt`` when polars refuses
the block, so errors and their line numbers are the same with and without polars.
"""

import io
from typing import BinaryIO, Iterator, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .fastpath import parse_block
from .poses import PoseFileError

__all__ = ["LineChunk", "Table", "iter_line_chunks", "parse_table", "decimal_seconds_to_ns"]


class LineChunk:
    """A block of whole lines and the 1-based number of its first line.

    Built either from a list of lines (``LineChunk(first_line, lines)``) or from the raw bytes
    (``LineChunk(first_line, block=b"...")``); the other form is made on first use.
    """

    __slots__ = ("first_line", "_lines", "_block", "_count")

    def __init__(self, first_line: int, lines: Optional[List[bytes]] = None, block: Optional[bytes] = None,
                 count: Optional[int] = None):
        if (lines is None) == (block is None):
            raise ValueError("LineChunk: give lines or block")
        self.first_line, self._lines, self._block = first_line, lines, block
        self._count = len(lines) if lines is not None else count

    @property
    def lines(self) -> List[bytes]:
        if self._lines is None:
            self._lines = io.BytesIO(self._block).readlines()  # split at b"\n" only, as file iteration does
        return self._lines

    @property
    def block(self) -> bytes:
        if self._block is None:
            self._block = b"".join(self._lines)
        return self._block

    @property
    def count(self) -> int:
        """The number of lines (the last may lack its newline)."""
        if self._count is None:
            self._count = _newlines(self._block) + (len(self._block) > 0 and not self._block.endswith(b"\n"))
        return self._count

    def __iter__(self):  # ``first_line, lines = chunk`` as with the former named tuple
        return iter((self.first_line, self.lines))


class Table(NamedTuple):
    values: np.ndarray  # (n, k) float64
    line_numbers: np.ndarray  # (n,) 1-based line of each row
    first_fields: Optional[List[bytes]]  # text of column 0 when asked for (exact timestamps)


def _newlines(data: bytes) -> int:
    return int(np.count_nonzero(np.frombuffer(data, dtype=np.uint8) == 10))  # 2x faster than bytes.count


def iter_line_chunks(stream: BinaryIO, chunk_lines: int, first_line: int = 1) -> Iterator[LineChunk]:
    """Yield successive blocks of at most ``chunk_lines`` raw lines from a binary stream.

    Lines end at ``b"\\n"`` (the last may lack it), as when iterating over the stream; the
    blocks are cut from large reads, so no Python object is made per line.
    """
    pending, newlines = b"", 0  # bytes read but not yet yielded, and the newlines among them
    guess = 128  # bytes per line, refined from what was read
    eof = False
    while True:
        while not eof and newlines < chunk_lines:
            more = stream.read(max(1 << 16, int(guess * (chunk_lines - newlines) * 1.02)))
            eof = not more
            pending += more
            newlines += _newlines(more)
        if not pending:
            return
        extra = newlines - chunk_lines  # newlines beyond this chunk's last
        if extra < 0 or extra == 0 and pending.endswith(b"\n"):  # all that is left
            block, pending, count, newlines = pending, b"", newlines + (not pending.endswith(b"\n")), 0
        else:
            if extra < 1000:  # the usual case: a few lines too many were read; step back over them
                cut = len(pending)
                for _ in range(extra + 1):
                    cut = pending.rfind(b"\n", 0, cut)
            else:
                cut = int(np.flatnonzero(np.frombuffer(pending, dtype=np.uint8) == 10)[chunk_lines - 1])
            block, pending, count, newlines = pending[:cut + 1], pending[cut + 1:], chunk_lines, extra
        guess = max(16, len(block) // max(count, 1))
        yield LineChunk(first_line, block=block, count=count)
        first_line += count


def _maybe_clean(block: bytes) -> bool:
    """False when the block surely holds comments (then it is split into lines at once)."""
    return b"#" not in block  # memchr-fast; blank lines are caught by the row count after parsing


def _is_data(line: bytes) -> bool:
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith(b"#")


def _split(line: bytes, delimiter: Optional[bytes]) -> List[bytes]:
    return [f.strip() for f in line.split(delimiter)] if delimiter else line.split()


def parse_table(path, chunk: LineChunk, columns: Sequence[int], describe: str,
                delimiter: Optional[bytes] = None, keep_first_text: bool = False) -> Table:
    """Parse the data lines of a chunk (``#`` comments and blank lines skipped) into floats.

    Args:
        path: file name, for messages.
        chunk: the raw lines and the number of the first.
        columns: accepted column counts; extra columns beyond the largest are an error.
        describe: what a line holds, for messages (``"TUM: timestamp tx ty tz qx qy qz qw"``).
        delimiter: ``b","`` for CSV, None for any whitespace.
        keep_first_text: also return the text of column 0 (for exact timestamps).

    Returns:
        A :class:`Table`; raises :class:`PoseFileError` naming the first bad line.
    """
    block = chunk.block
    if _maybe_clean(block):  # the common case: every line is data, parsed as one block
        count = chunk.count
        values = parse_block(block, count, columns, delimiter)
        if values is None:
            values = _loadtxt(block, delimiter)
        if values is not None and values.shape[0] == count and values.shape[1] in columns:
            # one row per line: no line was blank or a comment, so this is what the line-by-line way gives
            numbers = chunk.first_line + np.arange(count, dtype=np.int64)
            return _checked_table(path, values, numbers, lambda: chunk.lines, delimiter, keep_first_text)
    lines = chunk.lines
    if b"#" in block or any(not line or line.isspace() for line in lines):  # (isspace: no copy)
        kept = [i for i, line in enumerate(lines) if _is_data(line)]
        data = [lines[i] for i in kept]
        numbers = chunk.first_line + np.asarray(kept, dtype=np.int64)
        block = b"".join(data)
    else:
        data = lines
        numbers = chunk.first_line + np.arange(len(lines), dtype=np.int64)
    if not data:
        return Table(np.zeros((0, max(columns))), numbers, [] if keep_first_text else None)
    values = _loadtxt(block, delimiter)
    if values is None:
        _diagnose(path, data, numbers, columns, describe, delimiter)
        raise PoseFileError(path, f"cannot parse lines {numbers[0]}-{numbers[-1]} as {describe}") from None
    if values.shape[0] != len(data) or values.shape[1] not in columns:
        _diagnose(path, data, numbers, columns, describe, delimiter)
        raise PoseFileError(path, f"cannot parse lines {numbers[0]}-{numbers[-1]} as {describe}")
    return _checked_table(path, values, numbers, lambda: data, delimiter, keep_first_text)


def _checked_table(path, values: np.ndarray, numbers: np.ndarray, data, delimiter: Optional[bytes],
                   keep_first_text: bool) -> Table:
    """Reject non-finite values (naming the line) and collect the first fields if asked."""
    finite = np.isfinite(values).all(axis=1)
    if not finite.all():
        row = int(np.argmin(finite))
        raise PoseFileError(path, f"value is not finite (nan or inf) in {lines_text(data()[row])!r}",
                            int(numbers[row]))
    first = [_split(line, delimiter)[0] for line in data()] if keep_first_text else None
    return Table(values, numbers, first)


def _loadtxt(block: bytes, delimiter: Optional[bytes]) -> Optional[np.ndarray]:
    """``numpy.loadtxt`` of a block of data lines; None when it cannot parse them."""
    if not block or block.isspace():  # (blank lines only: numpy warns "input contained no data")
        return None
    try:
        return np.loadtxt(io.BytesIO(block), delimiter=None if delimiter is None else delimiter.decode(),
                          comments=None, ndmin=2, dtype=np.float64, quotechar=None)
    except ValueError:
        return None


def lines_text(line: bytes, limit: int = 80) -> str:
    text = line.decode("utf-8", "replace").strip()
    return text if len(text) <= limit else text[:limit] + "..."


def _diagnose(path, data: List[bytes], numbers: np.ndarray, columns: Sequence[int], describe: str,
              delimiter: Optional[bytes]) -> None:
    """Find the first line that does not parse and raise a :class:`PoseFileError` for it."""
    expected = " or ".join(str(c) for c in sorted(columns)) if len(columns) < 4 else f"{min(columns)} or more"
    width = None
    for line, number in zip(data, numbers):
        fields = _split(line, delimiter)
        if len(fields) not in columns:
            raise PoseFileError(path, f"expected {expected} numbers ({describe}), found {len(fields)}: "
                                f"{lines_text(line)!r}", int(number))
        if width is None:
            width, first = len(fields), int(number)
        elif len(fields) != width:  # (each count allowed, but a table has one width)
            raise PoseFileError(path, f"expected {width} numbers as on line {first}, found {len(fields)}: "
                                f"{lines_text(line)!r}", int(number))
        for field in fields:
            try:  # (as loadtxt reads it: Python's float also takes 1_000 and non-ASCII digits)
                if b"_" in field or not field.isascii():
                    raise ValueError
                float(field)
            except ValueError:
                raise PoseFileError(path, f"not a number: {field.decode('utf-8', 'replace')!r} in "
                                    f"{lines_text(line)!r}", int(number)) from None


_MAX_WHOLE_SECONDS = (2 ** 63 - 1) // 1_000_000_000 - 1  # (int64 nanoseconds hold up to 9223372036.85 s)


def decimal_seconds_to_ns(fields: Sequence[bytes]) -> Optional[np.ndarray]:
    """Int64 nanoseconds from decimal texts like ``b"1403715524.907143168"``: exact up to 9
    decimals, and rounded to the nearest nanosecond (halves away from zero) beyond, which is
    still far finer than a float64 of seconds.

    Returns None unless every text is ``[+-]digits[.digits]`` with at most 10 integer digits and
    a magnitude below 9223372035 s (int64 nanoseconds); the caller then keeps float seconds.

    Example:
        >>> decimal_seconds_to_ns([b"1305031098.6659", b"-2", b"0.000000001", b"1.0000000015"]).tolist()
        [1305031098665900000, -2000000000, 1, 1000000002]
        >>> decimal_seconds_to_ns([b"1.5e3"]) is None
        True
    """
    if len(fields) == 0:
        return np.zeros(0, dtype=np.int64)
    texts = np.array(fields, dtype="S")
    width = texts.dtype.itemsize
    chars = texts.view(np.uint8).reshape(-1, width)
    sign = (chars[:, 0] == ord("-")) | (chars[:, 0] == ord("+"))
    digit = (chars >= ord("0")) & (chars <= ord("9"))
    dot = chars == ord(".")
    pad = chars == 0
    allowed = digit | dot | pad
    allowed[:, 0] |= sign
    if not allowed.all() or (dot.sum(axis=1) > 1).any():
        return None
    length = width - pad.sum(axis=1)
    dot_at = np.where(dot.any(axis=1), np.argmax(dot, axis=1), length)
    start = sign.astype(np.int64)
    if ((dot_at - start) > 10).any() or ((dot_at - start) < 1).any():
        return None
    whole = np.zeros(len(texts), dtype=np.int64)
    fraction = np.zeros(len(texts), dtype=np.int64)
    decimals = np.zeros(len(texts), dtype=np.int64)
    round_up = np.zeros(len(texts), dtype=bool)
    for j in range(width):
        value = chars[:, j].astype(np.int64) - ord("0")
        place = j - dot_at  # 1 for the first decimal
        in_whole = digit[:, j] & (place < 0)
        in_fraction = digit[:, j] & (place > 0) & (place <= 9)
        whole = np.where(in_whole, whole * 10 + value, whole)
        fraction = np.where(in_fraction, fraction * 10 + value, fraction)
        decimals += in_fraction
        round_up |= digit[:, j] & (place == 10) & (value >= 5)
    if (whole > _MAX_WHOLE_SECONDS).any():
        return None
    ns = whole * 1_000_000_000 + fraction * 10 ** (9 - decimals) + round_up
    return np.where(chars[:, 0] == ord("-"), -ns, ns)


def is_data_line(line: bytes) -> bool:
    """Whether a CSV line holds numbers (its first field reads as a float), not column names."""
    try:
        float(line.split(b",", 1)[0])
    except ValueError:
        return False
    return True


def read_header(stream: BinaryIO) -> Tuple[bytes, int, int]:
    """Find a CSV's header: its first non-blank line that is not a ``#`` comment or, when that
    line is already data, the last ``#`` line before it (``#timestamp,...``, as EuRoC writes it);
    ``b""`` when there is neither. So a preamble of ``#`` comments before a header is skipped, and
    a header written as a comment is still one. (A stream that cannot seek takes its first
    non-blank line.)

    Returns:
        ``(header, its line number (0 for none), the number of the line the stream is left at)``:
        the line after the header, or the first data line.
    """
    count, comment, comment_number = 0, b"", 0
    seekable = stream.seekable()
    while True:
        start = stream.tell() if seekable else None
        line = stream.readline()
        if not line:
            return comment, comment_number, count + 1
        count += 1
        stripped = line.strip()
        if not stripped:
            continue
        if not seekable or not (stripped.startswith(b"#") or is_data_line(stripped)):
            return line, count, count + 1
        if stripped.startswith(b"#"):
            comment, comment_number = line, count
            continue
        stream.seek(start)  # (the first data line: it is read again with the others)
        return comment, comment_number, count
