"""Many pose files at once: a folder, a glob or a list of files converted into an output folder.

Each input becomes one output at the same relative path under ``out_dir``, with the extension of
the format ``to`` names (``tum`` -> ``.tum``, ``kitti`` -> ``.kitti``, ``euroc`` -> ``.csv``,
``bvh`` -> ``.bvh``; a camera format gets its own file name, ``colmap`` -> ``images.txt``, ``nerf`` ->
``transforms.json``, ``bop`` -> ``scene_gt.json``, in the input's sub-folder, or in a sub-folder named
after the input where its name is not that format's own) or, where ``to`` names a rotation
representation (or is None), of ``ext`` (``.npz`` by default, ``.csv`` or ``.parquet``). Every
file goes through the one-file conversion (:func:`~torchquat.io.convert_file`, or
:func:`~torchquat.io.convert_motion` for motion capture), so each output equals the one-file
conversion of its input; outputs are written atomically, and an output already there and newer
than its input is skipped unless ``overwrite``, so a second run resumes an interrupted one. The
files are converted in parallel on Dask's distributed scheduler (:mod:`torchquat.dask`): a local
cluster of ``workers`` processes, or the cluster at ``scheduler``.
"""

import glob
import os
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from .cameras import camera_format_of
from .checks import Report
from .poses import PoseFileError
from .streaming import DEFAULT_CHUNK_SIZE

__all__ = ["convert_files", "convert_one", "plan_files", "FileResult", "ConvertSummary", "FORMAT_EXTENSIONS",
           "CAMERA_FILE_NAMES", "PLAIN_EXTENSIONS", "INPUT_EXTENSIONS", "is_many_files"]

PathLike = Union[str, os.PathLike]
FORMAT_EXTENSIONS = {"tum": ".tum", "kitti": ".kitti", "euroc": ".csv", "bvh": ".bvh"}
PLAIN_EXTENSIONS = (".npz", ".csv", ".parquet")
CAMERA_FILE_NAMES = {"colmap": "images.txt", "nerf": "transforms.json", "bop": "scene_gt.json"}
# what a folder given as input contributes (files named on their own or by a glob are all taken), and
# its .json/.bin files whose name gives a camera format (images.bin, transforms*.json, scene_gt*.json)
INPUT_EXTENSIONS = (".txt", ".tum", ".kitti", ".csv", ".npz", ".npy", ".parquet", ".bvh")
_COLMAP_OTHERS = ("cameras.txt", "points3d.txt", "frames.txt", "rigs.txt")  # (beside images.txt: not poses)
_GLOB_MAGIC = ("*", "?", "[")


@dataclass
class FileResult:
    """What became of one input.

    Attributes:
        src: the input file.
        dst: its output file.
        status: ``"written"``, ``"skipped"`` (the output was complete) or ``"failed"``.
        rows: poses (or frames) written; 0 unless written.
        message: the problem (``file:line: problem``) when failed, else ``""``.
        notes: what was assumed and repaired (the one-file conversion's notes).
    """

    src: str
    dst: str
    status: str
    rows: int = 0
    message: str = ""
    notes: List[str] = field(default_factory=list)


@dataclass
class ConvertSummary:
    """The results of :func:`convert_files`, in input order.

    Attributes:
        results: one :class:`FileResult` per input.
    """

    results: List[FileResult]

    def _having(self, status: str) -> List[FileResult]:
        return [r for r in self.results if r.status == status]

    @property
    def written(self) -> List[FileResult]:
        """The files converted this time."""
        return self._having("written")

    @property
    def skipped(self) -> List[FileResult]:
        """The files whose output was complete already."""
        return self._having("skipped")

    @property
    def failed(self) -> List[FileResult]:
        """The files that could not be converted (each with its message)."""
        return self._having("failed")

    def __str__(self) -> str:
        return f"{len(self.written)} written, {len(self.skipped)} skipped, {len(self.failed)} failed"


def _has_magic(text: str) -> bool:
    return any(c in text for c in _GLOB_MAGIC)


def is_many_files(inputs: Sequence[PathLike], output: PathLike) -> bool:
    """Whether a conversion of ``inputs`` into ``output`` is the many-files kind.

    It is when there are several inputs, an input is a folder or a glob pattern (not an existing
    file), or ``output`` is an existing folder or ends with a path separator.

    Example:
        >>> is_many_files(["a.tum"], "a.csv"), is_many_files(["a.tum", "b.tum"], "out"), is_many_files(["*.tum"], "o")
        (False, True, True)
    """
    names = [os.fspath(i) for i in inputs]
    out = os.fspath(output)
    if len(names) != 1 or out.endswith(os.sep) or out.endswith("/") or os.path.isdir(out):
        return True
    return os.path.isdir(names[0]) or (_has_magic(names[0]) and not os.path.exists(names[0]))


def _output_extension(to: Optional[str], ext: str) -> str:
    if to in CAMERA_FILE_NAMES:
        return CAMERA_FILE_NAMES[to]
    if to in FORMAT_EXTENSIONS:
        return FORMAT_EXTENSIONS[to]
    if to is not None:
        from .representations import parse_token
        try:
            parse_token(to, "convert_files: to")
        except ValueError as err:
            raise ValueError(f"{err}; or a format: {', '.join([*FORMAT_EXTENSIONS, *CAMERA_FILE_NAMES])}") from None
    chosen = ext if ext.startswith(".") else f".{ext}"
    if chosen.lower() not in PLAIN_EXTENSIONS:
        raise ValueError(f"convert_files: ext must be one of {', '.join(PLAIN_EXTENSIONS)} for plain outputs, "
                         f"got {ext!r}")
    return chosen.lower()


def _walk(folder: str, out_dir: str) -> List[str]:
    found = []
    skip = os.path.abspath(out_dir)
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and os.path.abspath(os.path.join(root, d)) != skip)
        model = any(f.lower() in ("images.txt", "images.bin") for f in files)  # (a COLMAP model's folder)
        found.extend(os.path.join(root, f) for f in sorted(files)
                     if not f.startswith(".") and not (model and f.lower() in _COLMAP_OTHERS)
                     and (os.path.splitext(f)[1].lower() in INPUT_EXTENSIONS or camera_format_of(f) is not None))
    return found


def _output_path(rel: str, suffix: str) -> str:
    """Where the input at ``rel`` goes: its extension changed to ``suffix``, or for a camera format's
    file name (``images.txt``), that name in the input's folder when the input's own name is a
    camera format's (``scene_gt.json``), else in a folder named after the input."""
    if suffix.startswith("."):
        return os.path.splitext(rel)[0] + suffix
    own = os.path.basename(rel).lower() in ("images.txt", "images.bin", *CAMERA_FILE_NAMES.values())
    return os.path.join(os.path.dirname(rel) if own else os.path.splitext(rel)[0], suffix)


def plan_files(inputs: Sequence[PathLike], out_dir: PathLike, to: Optional[str] = None,
               ext: str = ".npz") -> List[Tuple[str, str]]:
    """The ``(input, output)`` pairs of a many-files conversion, in a stable order.

    Args:
        inputs: files, folders (their pose files, recursively; hidden ones skipped) and glob
            patterns (``**`` recursive).
        out_dir: the output folder.
        to: a format (``tum``, ``kitti``, ``euroc``, ``bvh``, ``colmap``, ``nerf``, ``bop``) or a
            rotation representation.
        ext: the extension of plain outputs: ``.npz``, ``.csv`` or ``.parquet``.

    Returns:
        Absolute paths: a folder's files keep their path relative to the folder; the files named
        on their own or by a glob keep theirs relative to the folder they all share.

    Raises:
        ValueError: ``inputs`` empty, a glob that matches nothing, a bad ``to``/``ext``, or two
            inputs that would be written to the same output.

    Example:
        >>> import os, tempfile
        >>> root = tempfile.mkdtemp()
        >>> for name in ("a/00.txt", "b/01.txt"):
        ...     os.makedirs(os.path.dirname(os.path.join(root, name)), exist_ok=True)
        ...     _ = open(os.path.join(root, name), "w").write("0 0 0 0 0 0 0 1\\n")
        >>> [os.path.relpath(d, root) for _, d in plan_files([os.path.join(root, "*", "*.txt")], os.path.join(root, "out"), to="tum")]
        ['out/a/00.tum', 'out/b/01.tum']
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if not inputs:
        raise ValueError("convert_files: inputs is empty: give files, folders or glob patterns")
    suffix = _output_extension(to, ext)
    out_dir = os.path.abspath(os.fspath(out_dir))
    pairs: List[Tuple[str, str]] = []  # (input, relative path)
    loose: List[str] = []
    for item in map(os.fspath, inputs):
        if os.path.isdir(item):
            folder = os.path.abspath(item)
            pairs.extend((f, os.path.relpath(f, folder)) for f in map(os.path.abspath, _walk(folder, out_dir)))
        elif _has_magic(item) and not os.path.exists(item):
            matches = sorted(m for m in glob.glob(item, recursive=True) if os.path.isfile(m))
            if not matches:
                raise ValueError(f"convert_files: the pattern {item!r} matches no file")
            loose.extend(map(os.path.abspath, matches))
        else:
            loose.append(os.path.abspath(item))
    if loose:
        base = os.path.commonpath([os.path.dirname(f) for f in loose])
        pairs.extend((f, os.path.relpath(f, base)) for f in loose)
    planned: List[Tuple[str, str]] = []
    taken: Dict[str, str] = {}
    for src, rel in pairs:
        dst = os.path.join(out_dir, _output_path(rel, suffix))
        if dst in taken and taken[dst] != src:
            raise ValueError(f"convert_files: {taken[dst]} and {src} would both be written to {dst}: "
                             "convert them in separate runs")
        if dst not in taken:
            taken[dst] = src
            planned.append((src, dst))
    return planned


def _complete(src: str, dst: str) -> bool:
    """An output written (atomically) after its input was last changed."""
    try:
        return os.path.getmtime(dst) >= os.path.getmtime(src) and os.path.isfile(dst)
    except OSError:
        return False


def convert_one(src: str, dst: str, options: Dict) -> FileResult:
    """Convert one file as ``torchquat convert SRC DST`` would; runs on a Dask worker.

    Args:
        src: input file.
        dst: output file; its folder is made if missing.
        options: ``to``, ``from_format``, ``degrees``, ``dtype`` (a name), ``chunk_size``;
            ``one_thread`` (on a worker): torch on one thread and no read-ahead thread, since the
            other workers keep the other cores busy (the thread would only add its cost).

    Returns:
        A :class:`FileResult`: written, or failed with the one-line problem (a user's error:
        malformed line, unreadable file). Other exceptions propagate (Dask retries them).
    """
    import torch

    from .mocap import convert_motion, is_motion_conversion
    from .streaming import convert_file
    one_thread = bool(options.get("one_thread"))  # (a worker: one per core, so each file on one thread)
    if one_thread and torch.get_num_threads() != 1:
        torch.set_num_threads(1)  # (10k-row chunks do not pay for intra-op threads; see cli.run_convert)
    report = Report()
    dtype = np.dtype(options.get("dtype", "float64")).type
    to, from_format, degrees = options.get("to"), options.get("from_format"), options.get("degrees", False)
    try:
        if os.path.exists(dst) and os.path.exists(src) and os.path.samefile(src, dst):
            raise PoseFileError(dst, "the output is the same file as the input: choose another output folder")
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        _remove_stale_temporaries(dst, options.get("started"))
        if is_motion_conversion(src, dst, to, from_format):
            rows = convert_motion(src, dst, to=to, from_format=from_format, degrees=degrees, dtype=dtype,
                                  report=report)
        else:
            rows = convert_file(src, dst, to=to, from_format=from_format, degrees=degrees, dtype=dtype,
                                chunk_size=options.get("chunk_size", DEFAULT_CHUNK_SIZE), report=report,
                                read_ahead=False if one_thread else None)
    except (ValueError, OSError) as err:
        message = f"{err.filename}: {err.strerror or err}" if isinstance(err, OSError) and err.filename else str(err)
        return FileResult(src, dst, "failed", message=message, notes=report.lines())
    return FileResult(src, dst, "written", rows=int(rows), notes=report.lines())


def _remove_stale_temporaries(dst: str, started: Optional[float]) -> None:
    """Remove the temporary files of ``dst`` that a conversion killed before this run began left
    (:func:`~torchquat.io.atomic_output` names them ``.NAME.*.tmp``)."""
    if started is None:
        return
    for stale in glob.glob(os.path.join(glob.escape(os.path.dirname(dst)), f".{glob.escape(os.path.basename(dst))}.*.tmp")):
        try:
            if os.path.getmtime(stale) < started:
                os.unlink(stale)
        except OSError:
            pass


def _convert_here(pairs: List[Tuple[str, str]], options: Dict, on_result: Callable) -> None:
    """Convert one file after the other in this process, torch on one thread meanwhile."""
    import torch
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for k, (src, dst) in enumerate(pairs):
            on_result(k, convert_one(src, dst, options))
    finally:
        torch.set_num_threads(threads)


def _check_workers(workers, scheduler) -> None:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"convert_files: workers must be a positive integer or None, got {workers!r}")
    if workers is not None and scheduler is not None:
        raise ValueError("convert_files: give workers (a local cluster) or scheduler (an existing one), not both")


def convert_files(inputs: Sequence[PathLike], out_dir: PathLike, to: Optional[str] = None, workers: Optional[int] = None,
                  scheduler: Optional[str] = None, *, ext: str = ".npz", from_format: Optional[str] = None,
                  degrees: bool = False, dtype=np.float64, overwrite: bool = False,
                  chunk_size: int = DEFAULT_CHUNK_SIZE, retries: int = 2,
                  on_file: Optional[Callable[[FileResult], None]] = None) -> ConvertSummary:
    """Convert many pose files into ``out_dir``, in parallel on Dask's distributed scheduler.

    Args:
        inputs: files, folders and glob patterns (see :func:`plan_files`).
        out_dir: the output folder (made if missing).
        to: a format (``tum``, ``kitti``, ``euroc``, ``bvh``, ``colmap``, ``nerf``, ``bop``) or a rotation
            representation for plain outputs (``quat``, ``euler:ZYX``, ...); None: plain outputs
            holding quaternions.
        workers: processes of a local cluster; None: the cores, but no cluster at all when there
            is one file to convert or one core. ``1`` converts here, in this process.
        scheduler: the address of an existing Dask scheduler (``tcp://host:8786``); its workers
            must see the files at the same paths.
        ext: the extension of plain outputs: ``.npz``, ``.csv`` or ``.parquet``.
        from_format: the inputs' format when extension and content do not tell.
        degrees: Euler angles in degrees.
        dtype: ``numpy.float64`` or ``numpy.float32`` values written.
        overwrite: convert again the files whose output is complete.
        chunk_size: lines per chunk in each conversion.
        retries: how often a file whose conversion raised an unexpected exception (not a user
            error) is retried; files on a worker lost mid-run are rescheduled by Dask anyway.
        on_file: called in this process with each :class:`FileResult` as it comes (progress).

    Returns:
        A :class:`ConvertSummary`: what was written, skipped and failed.

    Raises:
        ValueError: bad arguments (see :func:`plan_files`); a file's own problem is a failed
            result, not an exception.

    Example:
        >>> import os, tempfile
        >>> root = tempfile.mkdtemp()
        >>> for name in ("00.txt", "01.txt"):
        ...     _ = open(os.path.join(root, name), "w").write("0.5 1 2 3 0 0 0 1\\n")
        >>> summary = convert_files([root], os.path.join(root, "out"), to="tum", workers=1)
        >>> str(summary), sorted(os.listdir(os.path.join(root, "out")))
        ('2 written, 0 skipped, 0 failed', ['00.tum', '01.tum'])
        >>> str(convert_files([root], os.path.join(root, "out"), to="tum", workers=1))
        '0 written, 2 skipped, 0 failed'
    """
    _check_workers(workers, scheduler)
    if chunk_size < 1:
        raise ValueError(f"convert_files: chunk_size must be positive, got {chunk_size}")
    plan = plan_files(inputs, out_dir, to, ext)
    os.makedirs(os.fspath(out_dir), exist_ok=True)
    options = {"to": to, "from_format": from_format, "degrees": bool(degrees), "dtype": np.dtype(dtype).name,
               "chunk_size": int(chunk_size), "started": time.time()}
    results: Dict[int, FileResult] = {}

    def done(index: int, result: FileResult) -> None:
        results[index] = result
        if on_file is not None:
            on_file(result)
    pending = []
    for index, (src, dst) in enumerate(plan):
        if not overwrite and os.path.isfile(src) and _complete(src, dst) and not os.path.samefile(src, dst):
            done(index, FileResult(src, dst, "skipped"))
        else:
            pending.append(index)
    if scheduler is None and workers is None:
        workers = max(1, min(os.cpu_count() or 1, len(pending)))
    if pending and scheduler is None and workers == 1:
        _convert_here([plan[i] for i in pending], options, lambda k, result: done(pending[k], result))
    elif pending:
        from .cluster import run_files
        run_files(convert_one, [plan[i] for i in pending], {**options, "one_thread": True},
                  lambda src, dst, message: FileResult(src, dst, "failed", message=message), workers=workers,
                  scheduler=scheduler, retries=retries, on_result=lambda k, result: done(pending[k], result))
    return ConvertSummary([results[i] for i in range(len(plan))])
