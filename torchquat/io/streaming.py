"""Reading, writing and converting whole pose files, streaming.

Text formats are read in chunks of lines and written chunk by chunk, so memory stays flat in
the file's size; ``.npz``/``.npy`` are whole arrays by nature and are held in memory.
"""

import os
from typing import Callable, Iterable, Iterator, Optional, Tuple, Union

import numpy as np

from .bop import BopWriter, read_bop
from .cameras import CAMERA_FORMATS, IdColumns, camera_extension_problem, in_convention
from .checks import Report
from .colmap import ColmapWriter, read_colmap
from .detect import POSE_FORMATS, POSE_REPRESENTATIONS, check_pose_extension, detect_format, output_plan, skip_byte_order_mark
from .files import atomic_output
from .formats import EurocWriter, KittiWriter, TumWriter, read_euroc, read_kitti, read_tum
from .nerf import NerfWriter, read_nerf
from .parquet import ParquetWriter, read_parquet
from .plain import CsvWriter, NpyWriter, NpzWriter, read_csv, read_npy, read_npz
from .poses import PoseFileError, Poses
from .textparse import LineChunk, decimal_seconds_to_ns, parse_table

__all__ = ["read_poses", "iter_poses", "write_poses", "convert_file", "read_times", "DEFAULT_CHUNK_SIZE"]

READ_AHEAD = True  # convert_file parses the next chunk in a thread while this one is converted and written
DEFAULT_CHUNK_SIZE = 10_000  # small chunks keep numpy temporaries in reused heap memory (measured: less CPU, RSS)
READERS = {"tum": read_tum, "kitti": read_kitti, "euroc": read_euroc, "csv": read_csv, "npz": read_npz,
           "npy": read_npy, "parquet": read_parquet, "colmap": read_colmap, "nerf": read_nerf, "bop": read_bop}
WRITERS = {"tum": TumWriter, "kitti": KittiWriter, "euroc": EurocWriter, "csv": CsvWriter, "npz": NpzWriter,
           "npy": NpyWriter, "parquet": ParquetWriter, "colmap": ColmapWriter, "nerf": NerfWriter, "bop": BopWriter}
PathLike = Union[str, os.PathLike]


def read_times(path: PathLike) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Read a KITTI ``times.txt`` (one time in seconds a line): float seconds and exact ns if possible."""
    with open(path, "rb") as stream:
        skip_byte_order_mark(stream)
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
        skip_byte_order_mark(stream)
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
    meta = None if first.meta is None else {k: np.concatenate([c.meta[k] for c in chunks]) for k in first.meta}
    return Poses(torch.cat([c.rotations for c in chunks]), first.representation, first.degrees,
                 join([c.positions for c in chunks], torch.cat),
                 join([c.timestamps for c in chunks], np.concatenate),
                 join([c.timestamps_ns for c in chunks], np.concatenate),
                 meta=meta, maps=first.maps, document=first.document)


def write_poses(path: PathLike, poses: Union[Poses, Iterable[Poses]], format: Optional[str] = None,
                representation: Optional[str] = None, degrees: bool = False, dtype=np.float64,
                report: Optional[Report] = None) -> int:
    """Write poses (one :class:`Poses` or an iterable of chunks) atomically.

    Args:
        path: output file.
        poses: the poses, or chunks of them.
        format: ``tum``, ``kitti``, ``euroc``, ``csv``, ``npz``, ``npy``, ``parquet``, ``colmap``,
            ``nerf`` or ``bop``; default from the extension (and the names ``images.txt``,
            ``images.bin``, ``transforms.json``, ``scene_gt.json``). Poses read from a camera format
            are changed to the target's convention first, as ``torchquat convert`` does (see
            :func:`torchquat.io.cameras.to_convention`); plain outputs keep their identifiers.
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
            check_pose_extension(path, format)
        elif format in CAMERA_FORMATS and camera_extension_problem(path, format):
            raise PoseFileError(path, camera_extension_problem(path, format))
        name, default_rep = format, POSE_REPRESENTATIONS.get(format, "quat")
    else:
        raise PoseFileError(path, f"unknown format {format!r}: use one of {', '.join(WRITERS)}")
    chunks = in_convention([poses] if isinstance(poses, Poses) else poses, name, report)  # (cameras.py)
    writer_class = WRITERS[name]
    with atomic_output(path) as stream:
        if name in POSE_FORMATS:
            writer = writer_class(stream, report, np.dtype(dtype).type)
        elif name in CAMERA_FORMATS:
            writer = writer_class(stream, report, np.dtype(dtype).type, path)
        else:
            writer = writer_class(stream, report, np.dtype(dtype).type, representation or default_rep, degrees)
            if name in ("csv", "npz"):  # (identifiers of camera poses as columns)
                writer = IdColumns(writer, name)
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
                 on_chunk: Optional[Callable[[int], None]] = None, read_ahead: Optional[bool] = None) -> int:
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
        read_ahead: parse the next chunk in a thread meanwhile; None: ``READ_AHEAD``. False where
            other processes already keep every core busy (a worker of a local cluster): the
            thread then only adds its cost. The output is the same either way.

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
                + ("" if target in POSE_FORMATS + CAMERA_FORMATS else f" with rotations as {representation}"
                   + (" in degrees" if degrees and representation.startswith("euler") else "")))
    if chunk_size < 1:
        raise ValueError(f"convert_file: chunk_size must be positive, got {chunk_size}")
    pairs = _chunks_and_positions(src, source, times, chunk_size, report)
    if READ_AHEAD if read_ahead is None else read_ahead:
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
