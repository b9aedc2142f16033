"""Format detection, streaming reads, atomic writes and whole-file conversion.

Text formats are read in chunks of lines and written chunk by chunk, so memory stays flat in
the file's size; ``.npz``/``.npy`` are whole arrays by nature and are held in memory.
"""

import json
import os
import tempfile
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import BinaryIO, Callable, Iterable, Iterator, Optional, Tuple, Union

import numpy as np

from ..registry import parse_representation
from .checks import Report
from .formats import EurocWriter, KittiWriter, TumWriter, euroc_header_problem, read_euroc, read_kitti, read_tum
from .plain import CsvWriter, NpyWriter, NpzWriter, read_csv, read_npy, read_npz
from .poses import PoseFileError, Poses
from .textparse import decimal_seconds_to_ns, read_header

__all__ = ["read_poses", "iter_poses", "write_poses", "convert_file", "detect_format", "output_plan",
           "atomic_output", "output_folder_problem", "read_times", "FORMATS", "POSE_FORMATS", "PLAIN_TARGETS", "DEFAULT_CHUNK_SIZE"]

READ_AHEAD = True  # convert_file parses the next chunk in a thread while this one is converted and written
DEFAULT_CHUNK_SIZE = 10_000  # small chunks keep numpy temporaries in reused heap memory (measured: less CPU, RSS)
READERS = {"tum": read_tum, "kitti": read_kitti, "euroc": read_euroc, "csv": read_csv, "npz": read_npz,
           "npy": read_npy}
WRITERS = {"tum": TumWriter, "kitti": KittiWriter, "euroc": EurocWriter, "csv": CsvWriter, "npz": NpzWriter,
           "npy": NpyWriter}
FORMATS = tuple(READERS)
POSE_FORMATS = ("tum", "kitti", "euroc")
PLAIN_TARGETS = ("quat", "quat_xyzw", "matrix", "euler:SEQ", "axis_angle", "rot6d")
_BY_EXTENSION = {".tum": "tum", ".kitti": "kitti", ".npz": "npz", ".npy": "npy"}
_SNIFFED = (".txt", ".csv")
_NAME_IT = "--from on the command line, format= in Python"  # (the messages serve both)
# The extensions each pose format may be written under; the others named here (and in
# _BY_EXTENSION) are another format's, and a file under one would be misread: text in an .npz.
_POSE_EXTENSIONS = {"tum": (".tum", ".txt"), "kitti": (".kitti", ".txt"), "euroc": (".csv",)}
_KNOWN_EXTENSIONS = (*_BY_EXTENSION, *_SNIFFED)
PathLike = Union[str, os.PathLike]


_BOM = b"\xef\xbb\xbf"


def _skip_byte_order_mark(stream: BinaryIO) -> None:
    """Step over a UTF-8 byte order mark (spreadsheets write one before a CSV header)."""
    if stream.read(3) != _BOM:
        stream.seek(0)


def _first_lines(path: PathLike, limit: int = 50):
    with open(path, "rb") as stream:
        _skip_byte_order_mark(stream)
        for _, line in zip(range(limit), stream):
            if line.strip():
                yield line.strip()


def detect_format(path: PathLike, format: Optional[str] = None) -> str:
    """The format of an input file: ``format`` if given, else from its extension and content.

    ``.txt`` is TUM with 8 numbers a line and KITTI with 12; ``.csv`` is EuRoC when its header
    names EuRoC's columns in EuRoC's order (``timestamp``, ``p_`` x y z, ``q_`` w x y z), or a line
    has 8+ numbers and no header; else a plain CSV with named columns.

    Args:
        path: the input file.
        format: one of ``tum, kitti, euroc, csv, npz, npy`` to skip detection.

    Returns:
        The format name.
    """
    if format is not None:
        if format not in READERS:
            raise PoseFileError(path, f"unknown format {format!r}: use one of {', '.join(FORMATS)}")
        return format
    suffix = Path(path).suffix.lower()
    if suffix in _BY_EXTENSION:
        return _BY_EXTENSION[suffix]
    if suffix not in _SNIFFED:
        raise PoseFileError(path, f"cannot tell the format from the extension {suffix or '(none)'!r}: name it "
                            f"({_NAME_IT}: {', '.join(FORMATS)})")
    if suffix == ".csv":
        with open(path, "rb") as stream:
            _skip_byte_order_mark(stream)
            header, _, _ = read_header(stream)
            data = next((line for _, line in zip(range(50), stream) if line.strip()
                         and not line.lstrip().startswith(b"#")), b"")
        if header:
            return "euroc" if euroc_header_problem(header) is None else "csv"  # (EuRoC's order, whatever its units)
        if data:
            return "euroc" if _numbers(data.decode("utf-8", "replace").split(",")) >= 8 else "csv"
    else:
        for line in _first_lines(path):
            text = line.decode("utf-8", "replace")
            if text.startswith("#"):
                continue
            count = _numbers(text.split())
            if count in (8, 12):
                return "tum" if count == 8 else "kitti"
            raise PoseFileError(path, f"a .txt pose file has 8 numbers a line (TUM) or 12 (KITTI); the first data "
                                f"line has {len(text.split())} fields: name the format ({_NAME_IT})")
    raise PoseFileError(path, "the file holds no poses (empty, or comments only)")


def _numbers(fields) -> int:
    try:
        return len([float(f) for f in fields])
    except ValueError:
        return -1


def output_plan(path: PathLike, to: Optional[str] = None, degrees: bool = False) -> Tuple[str, str]:
    """Decide the output format and the rotation representation it holds.

    Args:
        path: the output file; its extension decides when ``to`` is None.
        to: ``tum``, ``kitti``, ``euroc`` or, for ``.csv``/``.npz``/``.npy`` outputs, a rotation
            representation (``quat``, ``quat_xyzw``, ``matrix``, ``euler:SEQ``, ``axis_angle``, ``rot6d``).
        degrees: Euler angles in degrees.

    Returns:
        ``(format, representation)``.
    """
    suffix = Path(path).suffix.lower()
    if to in POSE_FORMATS:
        _check_pose_extension(path, to)
        return to, {"tum": "quat_xyzw", "kitti": "matrix", "euroc": "quat"}[to]
    plain = {".csv": "csv", ".npz": "npz", ".npy": "npy"}.get(suffix)
    if to is None:
        if suffix in (".tum", ".kitti"):
            return suffix[1:], "quat_xyzw" if suffix == ".tum" else "matrix"
        if plain is None:
            raise PoseFileError(path, f"cannot tell the output format from the extension {suffix or '(none)'!r}: "
                                "use .tum, .kitti, .csv, .npz or .npy, or name a pose format "
                                "(--to or format=: tum, kitti, euroc)")
        return plain, "quat"
    try:
        rep, _ = parse_representation(to, "output rotations")
    except ValueError as err:
        raise PoseFileError(path, f"{err}; pose formats: {', '.join(POSE_FORMATS)}") from None
    if rep.name == "rot9d":
        to = "matrix"
    if plain is None:
        raise PoseFileError(path, f"rotations as {to} are written to a plain file: its name must end in .csv, "
                            ".npz or .npy")
    return plain, to


_READ_BACK_AS = {".tum": "TUM", ".kitti": "KITTI", ".txt": "TUM or KITTI text", ".csv": "a CSV",
                 ".npz": "a NumPy archive", ".npy": "a NumPy array"}


def _check_pose_extension(path: PathLike, format: str) -> None:
    """Refuse a pose format's text under another format's extension (TUM text named ``.npz``, say),
    which every reader, ours included, would take for that other format."""
    suffix = Path(path).suffix.lower()
    if suffix in _KNOWN_EXTENSIONS and suffix not in _POSE_EXTENSIONS[format]:
        raise PoseFileError(path, f"{format} output under the extension {suffix} would be read back as "
                            f"{_READ_BACK_AS[suffix]}: name it {' or '.join(_POSE_EXTENSIONS[format])}")


def read_times(path: PathLike) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Read a KITTI ``times.txt`` (one time in seconds a line): float seconds and exact ns if possible."""
    from .textparse import LineChunk, parse_table
    with open(path, "rb") as stream:
        _skip_byte_order_mark(stream)
        table = parse_table(path, LineChunk(1, stream.readlines()), (1,), "one time in seconds",
                            keep_first_text=True)
    return table.values[:, 0].copy(), decimal_seconds_to_ns(table.first_fields)


def iter_poses(path: PathLike, chunk_size: int = DEFAULT_CHUNK_SIZE, format: Optional[str] = None,
               times: Optional[PathLike] = None, report: Optional[Report] = None,
               on_chunk: Optional[Callable[[int], None]] = None) -> Iterator[Poses]:
    """Stream a pose file as :class:`Poses` chunks of at most ``chunk_size`` rows.

    Args:
        path: the file (TUM, KITTI, EuRoC, plain CSV, ``.npz`` or ``.npy``).
        chunk_size: lines per chunk.
        format: the format name, when extension and content do not tell.
        times: a KITTI ``times.txt`` giving the time of each row.
        report: collects what was assumed and repaired.
        on_chunk: called with the bytes read so far after each chunk (progress bars).

    Returns:
        An iterator of :class:`Poses` in the file's own representation.

    Raises:
        PoseFileError: a malformed line (the message names the file and the 1-based line).
    """
    if chunk_size < 1:
        raise ValueError(f"iter_poses: chunk_size must be positive, got {chunk_size}")
    report = Report() if report is None else report
    for poses, done in _chunks_and_positions(path, format, times, chunk_size, report):
        yield poses
        if on_chunk is not None:
            on_chunk(done)


def _chunks_and_positions(path, format: Optional[str], times: Optional[PathLike], chunk_size: int,
                          report: Report) -> Iterator[Tuple[Poses, int]]:
    """The reader's chunks, each with the input bytes consumed so far (for progress bars)."""
    name = detect_format(path, format)
    extra = {}
    if times is not None:
        if name != "kitti":
            raise PoseFileError(times, "a times file goes with KITTI input only")
        extra["times"], extra["times_ns"] = read_times(times)
    with open(path, "rb") as stream:
        _skip_byte_order_mark(stream)
        for poses in READERS[name](str(path), stream, chunk_size, report, **extra):
            yield poses, stream.tell()


_DONE = object()


def _read_ahead(chunks: Iterator, depth: int = 2) -> Iterator:
    """Run an iterator in a background thread, ``depth`` items ahead of the consumer.

    numpy, polars, torch and file I/O release the GIL in their loops, so parsing chunk k+1 overlaps
    converting and formatting chunk k (2 cores: see the README's speed figure). Items come in
    order; an exception in the reader (a malformed line) is raised here, in the consumer, after the
    items before it; memory holds at most ``depth + 2`` chunks.
    """
    import queue
    import threading
    items: "queue.Queue" = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                items.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for item in chunks:
                if not put((item, None)):
                    return
            put((_DONE, None))
        except BaseException as err:  # handed to the consumer, which raises it
            put((_DONE, err))
        finally:
            close = getattr(chunks, "close", None)
            if close is not None:
                close()

    thread = threading.Thread(target=work, name="torchquat-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            item, error = items.get()
            if error is not None:
                raise error
            if item is _DONE:
                return
            yield item
    finally:
        stop.set()
        thread.join()


def read_poses(path: PathLike, format: Optional[str] = None, times: Optional[PathLike] = None) -> Poses:
    """Read a whole pose file.

    Args:
        path: the file (TUM, KITTI, EuRoC, plain CSV, ``.npz`` or ``.npy``).
        format: the format name, when extension and content do not tell.
        times: a KITTI ``times.txt``.

    Returns:
        :class:`Poses` in the file's representation (``"quat_xyzw"`` for TUM, ``"matrix"`` for
        KITTI, ``"quat"`` for EuRoC, as named by the header for plain CSV).

    Example:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "one.tum")
        >>> _ = open(path, "w").write("1.5 1 2 3 0 0 0 1\\n")
        >>> read_poses(path).to("quat").rotations
        tensor([[1., 0., 0., 0.]], dtype=torch.float64)
    """
    chunks = list(iter_poses(path, format=format, times=times))
    if not chunks:
        raise PoseFileError(path, "the file holds no poses (empty, or comments only)")
    return _concatenate(chunks)


def _concatenate(chunks) -> Poses:
    import torch

    def join(items, cat):
        return None if any(i is None for i in items) else cat(items)
    first = chunks[0]
    return Poses(torch.cat([c.rotations for c in chunks]), first.representation, first.degrees,
                 join([c.positions for c in chunks], torch.cat),
                 join([c.timestamps for c in chunks], np.concatenate),
                 join([c.timestamps_ns for c in chunks], np.concatenate))


def output_folder_problem(path: PathLike) -> Optional[str]:
    """Why a file cannot be written at ``path`` (its folder is missing or read-only, or ``path`` is
    a folder), or ``None``: for commands to refuse before a long run rather than fail after it."""
    reason = _output_reason(path)
    return None if reason is None else f"{os.fspath(path)}: {reason}"


def _output_reason(path: PathLike) -> Optional[str]:
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        return f"no such folder {directory}"
    if os.path.isdir(path):
        return "is a folder"
    if not os.access(directory, os.W_OK):
        return f"the folder {directory} is not writable"
    return None


@contextmanager
def atomic_output(path: PathLike) -> Iterator[BinaryIO]:
    """Write to a temporary file beside ``path`` and rename it into place only on success.

    On any exception the temporary file is removed and ``path`` is left as it was.
    """
    path = os.fspath(path)
    reason = _output_reason(path)  # (named now: else the temporary file's name, or a failed rename at the end)
    if reason is not None:
        raise PoseFileError(path, reason)
    directory = os.path.dirname(os.path.abspath(path))
    fd, temporary = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb", buffering=1 << 20) as stream:
            yield stream
        try:
            mode = os.stat(path).st_mode & 0o777
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(temporary, mode)
        try:
            os.replace(temporary, path)
        except OSError as exc:  # (its message names the temporary file, which is about to go)
            raise PoseFileError(path, f"could not be replaced: {exc.strerror or exc}") from exc
    except BaseException:
        with suppress(OSError):
            os.unlink(temporary)
        raise


def write_json(path: PathLike, data) -> None:
    """Write ``data`` as indented JSON through :func:`atomic_output`: a failed write (a full disk,
    a file that cannot be replaced) leaves an existing file as it was."""
    with atomic_output(path) as stream:
        stream.write(json.dumps(data, indent=1, default=str).encode("utf-8") + b"\n")


def write_poses(path: PathLike, poses: Union[Poses, Iterable[Poses]], format: Optional[str] = None,
                representation: Optional[str] = None, degrees: bool = False, dtype=np.float64,
                report: Optional[Report] = None) -> int:
    """Write poses (one :class:`Poses` or an iterable of chunks) atomically.

    Args:
        path: output file.
        poses: the poses, or chunks of them.
        format: ``tum``, ``kitti``, ``euroc``, ``csv``, ``npz`` or ``npy``; default from the extension.
        representation: rotation representation of plain outputs (default ``"quat"``).
        degrees: Euler angles in degrees.
        dtype: ``numpy.float64`` (17 significant digits at most) or ``numpy.float32`` (9).
        report: collects notes.

    Returns:
        The number of poses written.
    """
    report = Report() if report is None else report
    if format is None:
        name, default_rep = output_plan(path, representation, degrees)
    elif format in WRITERS:
        if format in POSE_FORMATS:
            _check_pose_extension(path, format)
        name, default_rep = format, {"tum": "quat_xyzw", "kitti": "matrix"}.get(format, "quat")
    else:
        raise PoseFileError(path, f"unknown format {format!r}: use one of {', '.join(FORMATS)}")
    chunks = [poses] if isinstance(poses, Poses) else poses
    writer_class = WRITERS[name]
    with atomic_output(path) as stream:
        if name in POSE_FORMATS:
            writer = writer_class(stream, report, np.dtype(dtype).type)
        else:
            writer = writer_class(stream, report, np.dtype(dtype).type, representation or default_rep, degrees)
        rows = 0
        for chunk in chunks:
            writer.write(chunk)
            rows += len(chunk)
        if rows == 0:
            raise PoseFileError(path, "no poses to write")
        writer.close()
    return rows


def convert_file(src: PathLike, dst: PathLike, to: Optional[str] = None, from_format: Optional[str] = None,
                 degrees: bool = False, dtype=np.float64, times: Optional[PathLike] = None,
                 chunk_size: int = DEFAULT_CHUNK_SIZE, report: Optional[Report] = None,
                 on_chunk: Optional[Callable[[int], None]] = None) -> int:
    """Convert a pose file to another format or rotation representation, streaming.

    Args:
        src: input file.
        dst: output file (written atomically; untouched on any error).
        to: ``tum``/``kitti``/``euroc`` or a representation for plain outputs (see :func:`output_plan`).
        from_format: the input's format when its extension and content do not tell.
        degrees: Euler angles in degrees.
        dtype: values written to round-trip ``float64`` (default) or ``float32``.
        times: KITTI ``times.txt`` for the input.
        chunk_size: lines per chunk.
        report: collects what was assumed and repaired.
        on_chunk: progress callback, given the input bytes read so far.

    Returns:
        The number of poses written.
    """
    report = Report() if report is None else report
    if not os.path.isfile(src):
        raise PoseFileError(src, "no such file" if not os.path.exists(src) else "not a regular file")
    if os.path.exists(dst) and os.path.samefile(src, dst):
        raise PoseFileError(dst, "the output is the same file as the input: choose another output name")
    source = detect_format(src, from_format)
    target, representation = output_plan(dst, to, degrees)
    report.note(f"reading {src} as {source}; writing {dst} as {target}"
                + ("" if target in POSE_FORMATS else f" with rotations as {representation}"
                   + (" in degrees" if degrees and representation.startswith("euler") else "")))
    if chunk_size < 1:
        raise ValueError(f"convert_file: chunk_size must be positive, got {chunk_size}")
    pairs = _chunks_and_positions(src, source, times, chunk_size, report)
    if READ_AHEAD:
        pairs = _read_ahead(pairs)

    def chunks() -> Iterator[Poses]:
        rows = 0
        for poses, done in pairs:
            rows += len(poses)
            yield poses
            if on_chunk is not None:  # called here, in the caller's thread, once the chunk is written
                on_chunk(done)
        if rows == 0:  # (IN's fault: not write_poses' "no poses to write", which names OUT)
            raise PoseFileError(src, "the file holds no poses (empty, or comments only)")
    try:
        return write_poses(dst, chunks(), target, representation, degrees, dtype, report)
    finally:
        pairs.close()  # stops the read-ahead thread now, on success or failure
