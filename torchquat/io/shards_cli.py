"""``torchquat convert IN... OUT/``: many files into a folder, on Dask (see :mod:`torchquat.io.shards`).

Prints each failed file as ``torchquat convert: error: file:line: problem`` as it comes, a
progress bar counting files when stderr is a terminal, what the first file converted assumed,
and a summary line ``N written, N skipped, N failed``; the exit status is 2 if any file failed.
"""

import argparse
import os
import sys
from typing import Optional

__all__ = ["run_many", "usage_problem"]

_PREFIX = "torchquat convert"
_FILE_EXTENSIONS = (".tum", ".kitti", ".txt", ".csv", ".npz", ".npy", ".parquet", ".bvh", ".json", ".bin")


def usage_problem(args: argparse.Namespace) -> Optional[str]:
    """What is wrong with the options of a many-files ``convert`` (named, with what was given), or None."""
    out = args.output
    if not os.path.isdir(out) and os.path.splitext(out.rstrip("/" + os.sep))[1].lower() in _FILE_EXTENSIONS:
        return (f"OUT must be a folder when IN is several files, a folder or a glob pattern, got the file name "
                f"{out!r}: name a folder (e.g. out/)")
    if args.times is not None:
        return "--times gives the times of one KITTI IN: convert that file on its own"
    if args.workers is not None and args.workers < 1:
        return f"--workers must be a positive number of processes, got {args.workers}"
    if args.workers is not None and args.scheduler is not None:
        return "give --workers (a local cluster) or --scheduler (an existing one), not both"
    if args.scheduler is not None and not args.scheduler.strip():
        return "--scheduler is empty: name a scheduler's address, e.g. tcp://10.0.0.1:8786"
    if args.degrees and not (args.to or "").lower().startswith("euler"):
        return "--degrees applies to Euler angles only: use it with --to euler:SEQ"
    return None


def _bar(total: int):
    """A tqdm bar counting files, only when stderr is a terminal."""
    if not sys.stderr.isatty():
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, unit="file", desc="convert", file=sys.stderr, leave=False)


def run_many(args: argparse.Namespace) -> int:
    """Convert ``args.input`` (files, folders, globs) into the folder ``args.output``.

    Args:
        args: ``torchquat convert``'s parsed arguments (``input`` a list).

    Returns:
        0, or 2 when an option is wrong or any file failed.
    """
    import numpy as np

    from .shards import INPUT_EXTENSIONS, convert_files, plan_files
    from .streaming import DEFAULT_CHUNK_SIZE
    problem = usage_problem(args)
    if problem is not None:
        return _fail(problem)
    ext = args.ext or ".npz"
    try:
        total = len(plan_files(args.input, args.output, args.to, ext))
    except ValueError as err:
        return _fail(str(err))
    if total == 0:
        return _fail(f"no pose files in {', '.join(args.input)} (a folder contributes its {', '.join(INPUT_EXTENSIONS)} "
                     "files and its images.bin, transforms*.json, scene_gt*.json; name other files one by one or "
                     "by a glob pattern)")
    bar = _bar(total)
    first_notes = []

    def on_file(result) -> None:
        if result.status == "failed":
            line = f"{_PREFIX}: error: {result.message}"
            if bar is not None:
                bar.write(line, file=sys.stderr)
            else:
                print(line, file=sys.stderr)
        elif result.status == "written" and not first_notes:
            first_notes.append(result.notes)
        if bar is not None:
            bar.update(1)
    try:
        summary = convert_files(args.input, args.output, to=args.to, workers=args.workers, scheduler=args.scheduler,
                                ext=ext, from_format=args.from_format, degrees=args.degrees,
                                dtype=np.float32 if args.dtype == "float32" else np.float64,
                                overwrite=args.overwrite,
                                chunk_size=DEFAULT_CHUNK_SIZE if args.chunk_size is None else args.chunk_size,
                                on_file=on_file)
    except (ValueError, OSError) as err:
        return _fail(str(err))
    finally:
        if bar is not None:
            bar.close()
    for note in first_notes[0] if first_notes else []:
        print(f"{_PREFIX}: {note}", file=sys.stderr)
    rows = sum(r.rows for r in summary.written)
    print(f"{_PREFIX}: {summary} ({rows} poses written to {args.output}, {args.dtype})", file=sys.stderr)
    return 2 if summary.failed else 0


def _fail(message: str) -> int:
    print(f"{_PREFIX}: error: {message}", file=sys.stderr)
    return 2
