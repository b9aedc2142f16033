"""The ``torchquat`` command line: ``convert``, ``crosscheck`` and ``bench``.

``crosscheck`` and ``bench`` live in their own modules (``torchquat.crosscheck``,
``torchquat.bench``), each exposing ``add_arguments(parser)`` and ``run(args) -> int``; they are
imported only when chosen, so ``torchquat convert`` starts without loading them.
"""

import argparse
import importlib
import sys
from typing import List, Optional

__all__ = ["main", "build_parser", "ArgumentParser", "MAX_CHUNK_SIZE"]

MAX_CHUNK_SIZE = 10_000_000  # lines: a chunk this large already takes gigabytes; beyond, allocation fails


_LAZY = {
    "crosscheck": ("torchquat.crosscheck", "every conversion against pytorch-kinematics and SciPy: a table of "
                   "max errors, exit 1 on failure"),
    "bench": ("torchquat.bench", "the benchmark table against whichever peers are installed"),
    "eval": ("torchquat.traj.cli", "trajectory error of ESTIMATE against REFERENCE (APE or RPE, evo's numbers)"),
}

_MAIN_EPILOG = """examples:
  torchquat convert KITTI_00_gt.txt kitti00.tum
  torchquat convert trajectory.tum angles.csv --to euler:ZYX --degrees
  torchquat crosscheck
  torchquat bench
  torchquat eval groundtruth.txt estimate.txt --align --json ape.json
"""

_CONVERT_EPILOG = """formats (from the extension, or --from / --to):
  tum    .tum   timestamp tx ty tz qx qy qz qw   (.txt with 8 numbers a line)
  kitti  .kitti 12 numbers a line, row-major 3x4 [R | t]   (.txt with 12 numbers a line)
  euroc  .csv   #timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...  (recognised by its header)
  csv    .csv   plain, header [timestamp,][x,y,z,] rotation columns (qw,qx,qy,qz | ZYX_1,... | r00..r22 ...)
  npz    .npz   arrays timestamp, position, rotation and a string representation
  npy    .npy   the rotation array alone
  bvh    .bvh   motion capture (HIERARCHY + MOTION): in, and out from any motion (--to bvh)
  amass  .npz   AMASS poses (T, 3J) axis-angle, trans, mocap_frame[_]rate; a motion in .npz/.parquet/.npy
                holds (T, J, k) rotations (--to rot6d ...) with joint names, parents, offsets
  colmap images.txt, images.bin  COLMAP model: world -> camera, QW QX QY QZ TX TY TZ, OpenCV axes
  nerf   transforms.json  frames[].transform_matrix: camera -> world, OpenGL axes (other fields kept)
  bop    scene_gt.json    cam_R_m2c, cam_t_m2c (mm): model -> camera, OpenCV axes

camera conventions: between colmap, nerf and bop each pose is inverted and its camera axes turned
as needed (colmap -> nerf: c2w = inv(w2c) @ diag(1, -1, -1, 1)); to tum, kitti, euroc and plain
files a pose becomes the camera's pose in the world; stderr says what was done. The world frame is
never moved, recentred or rescaled; plain .csv/.npz outputs keep image_id, name ... as columns.

checks: a malformed line stops the conversion (file:line on stderr, exit 2, OUT untouched);
quaternions with |norm - 1| < 1e-3 are normalised, matrices with 1e-5 <= max|R^T R - I| < 1e-2 are
projected onto the nearest rotation (counts on stderr; below 1e-5 taken as written); worse is an error.

examples:
  torchquat convert KITTI_00_gt.txt kitti00.tum
  torchquat convert KITTI_00_gt.txt kitti00.tum --times times.txt
  torchquat convert V102_groundtruth.csv v102.tum
  torchquat convert v102.tum v102_euroc.csv --to euroc
  torchquat convert freiburg1_xyz-groundtruth.txt angles.csv --to euler:ZYX --degrees
  torchquat convert trajectory.tum rot6d.npz --to rot6d --dtype float32
  torchquat convert walk.bvh walk.npz --to rot6d
  torchquat convert walk.npz walk.bvh
  torchquat convert sequences/ out/ --to tum --workers 4
  torchquat convert 'shards/*.txt' out/ --to rot6d --ext .parquet --scheduler tcp://10.0.0.1:8786
  torchquat convert sparse/0/images.bin transforms.json
  torchquat convert sparse/0/images.bin cameras.tum
"""


def _formatter(prog):
    return argparse.RawDescriptionHelpFormatter(prog, max_help_position=32)


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, but a usage error is one line on stderr (and exit status 2).

    argparse prints the whole usage before its message; on a long command line the message
    is lost under it. Subcommand parsers are made of the same class.
    """

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def add_convert_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``torchquat convert``."""
    parser.add_argument("input", metavar="IN", nargs="+", help="pose file to read; several files, a folder or a glob "
                        "pattern convert into the folder OUT, in parallel (see 'many files' below)")
    parser.add_argument("output", metavar="OUT", help="file to write (atomically: untouched on any error)")
    parser.add_argument("--to", metavar="TARGET",
                        help="tum, kitti, euroc, colmap, nerf, bop, or for .csv/.npz/.npy outputs a rotation "
                        "representation: quat, "
                        "quat_xyzw, matrix, euler:SEQ (e.g. euler:ZYX), axis_angle, rot6d "
                        "(default: from OUT's extension; plain outputs hold quat)")
    parser.add_argument("--from", dest="from_format", metavar="FORMAT",
                        help="IN's format when its extension and content do not tell: tum, kitti, euroc, csv, "
                        "npz, npy, parquet, colmap, nerf, bop, bvh, amass")
    parser.add_argument("--degrees", action="store_true", help="Euler angles in degrees")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float64",
                        help="precision of the values written, with enough digits to round-trip it "
                        "(default float64: at most 17 significant digits; float32: 9)")
    parser.add_argument("--times", metavar="FILE", help="KITTI times.txt: the time of each row of a KITTI IN")
    parser.add_argument("--chunk-size", type=int, default=None, metavar="N",
                        help=f"lines read and written at a time, 1 to {MAX_CHUNK_SIZE:,} (default 10000); memory is "
                        "flat in the file size")
    many = parser.add_argument_group("many files (IN... OUT/: torchquat.io.shards, on Dask)")
    many.add_argument("--workers", type=int, metavar="N", help="processes of a local Dask cluster (default: the "
                      "cores; 1 converts in this process)")
    many.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler (tcp://host:8786) whose "
                      "workers see the files at the same paths")
    many.add_argument("--ext", metavar="EXT", help="extension of plain outputs: .npz (default), .csv or .parquet")
    many.add_argument("--overwrite", action="store_true", help="convert again files whose output is complete "
                      "(default: skip them, so a second run resumes)")


def run_convert(args: argparse.Namespace) -> int:
    """Run ``torchquat convert``; user errors print one line on stderr and return 2."""
    from .io.shards import is_many_files
    if args.chunk_size is not None and not 1 <= args.chunk_size <= MAX_CHUNK_SIZE:
        return _fail(f"--chunk-size must be from 1 to {MAX_CHUNK_SIZE} lines, got {args.chunk_size}")
    if is_many_files(args.input, args.output):  # IN... OUT/ (SPEC section 9)
        from .io.shards_cli import run_many
        return run_many(args)
    args.input = args.input[0]
    if (args.workers, args.scheduler, args.ext) != (None, None, None):
        return _fail("--workers, --scheduler and --ext apply to many files (IN... OUT/), not to one IN and OUT")
    import numpy as np

    import torch

    from .io import DEFAULT_CHUNK_SIZE, Report, convert_file
    from .io.mocap import convert_motion, is_motion_conversion
    # Chunks of ~10k rows are too small for torch's intra-op threads to pay, and on a busy machine
    # their spin-waiting is ruinous (measured, 2 cores, load 4: matrix_to_quat on 1M rows in 10k
    # chunks 12 s with 2 threads, 0.24 s with 1). The second core parses ahead instead (io.streaming).
    torch.set_num_threads(1)
    report = Report()
    chunk_size = DEFAULT_CHUNK_SIZE if args.chunk_size is None else args.chunk_size
    problem = _convert_usage_problem(args)
    if problem:
        return _fail(problem)
    progress = _progress_bar(args.input)
    try:
        motion = is_motion_conversion(args.input, args.output, args.to, args.from_format)  # BVH, AMASS (io.mocap)
        if motion:
            rows = convert_motion(args.input, args.output, to=args.to, from_format=args.from_format,
                                  degrees=args.degrees, dtype=np.float32 if args.dtype == "float32" else np.float64,
                                  report=report)
        else:
            rows = convert_file(args.input, args.output, to=args.to, from_format=args.from_format, degrees=args.degrees,
                                dtype=np.float32 if args.dtype == "float32" else np.float64, times=args.times,
                                chunk_size=chunk_size, report=report,
                                on_chunk=None if progress is None else progress.update_to)
    except (ValueError, OSError) as err:
        return _fail(_describe(err))
    finally:
        if progress is not None:
            progress.close()
    for line in report.lines():
        print(f"torchquat convert: {line}", file=sys.stderr)
    print(f"torchquat convert: wrote {rows} {'frames' if motion else 'poses'} to {args.output} ({args.dtype})",
          file=sys.stderr)
    return 0


def _convert_usage_problem(args: argparse.Namespace) -> Optional[str]:
    """What is wrong with ``convert``'s options (named, with what is expected and the value), or None."""
    for name, value, expected in (("IN", args.input, "an input file"), ("OUT", args.output, "an output file"),
                                  ("--to", args.to, "a format or a rotation representation"),
                                  ("--from", args.from_format, "a format"), ("--times", args.times, "a times file")):
        if value is not None and not value.strip():
            return f"{name} is empty: name {expected}"
    if args.degrees and not (args.to or "").lower().startswith("euler"):
        return "--degrees applies to Euler angles only: use it with --to euler:SEQ"
    return None


def _describe(err: Exception) -> str:
    if isinstance(err, OSError) and err.filename is not None:
        return f"{err.filename}: {err.strerror or err}"
    return str(err)


def _fail(message: str) -> int:
    print(f"torchquat convert: error: {message}", file=sys.stderr)
    return 2


def _progress_bar(path: str):
    """A tqdm bar over the input's bytes, only when stderr is a terminal."""
    import os
    if not sys.stderr.isatty():
        return None
    try:
        total = os.path.getsize(path)
        from tqdm import tqdm
    except (OSError, ImportError):
        return None

    class Bar(tqdm):
        def update_to(self, done: int) -> None:
            self.update(done - self.n)
    return Bar(total=total, unit="B", unit_scale=True, desc="convert", file=sys.stderr, leave=False)


def build_parser(lazy: Optional[str] = None) -> argparse.ArgumentParser:
    """The argument parser; the ``lazy`` subcommand's module is imported to add its arguments."""
    parser = ArgumentParser(prog="torchquat", description="Batched, differentiable 3D rotations: "
                                     "pose-file conversion, cross-checks and benchmarks.",
                                     epilog=_MAIN_EPILOG, formatter_class=_formatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    convert = sub.add_parser("convert", help="convert pose files between TUM, KITTI, EuRoC, CSV, NPZ, NPY and "
                             "rotation representations", description="Convert a pose file, streaming.",
                             epilog=_CONVERT_EPILOG, formatter_class=_formatter)
    add_convert_arguments(convert)
    convert.set_defaults(run=run_convert)
    for name, (module_name, help_text) in _LAZY.items():
        command = sub.add_parser(name, help=help_text, description=help_text, formatter_class=_formatter,
                                 epilog=f"examples:\n  torchquat {name}\n  torchquat {name} --help\n")
        if name == lazy:
            module = importlib.import_module(module_name)
            module.add_arguments(command)
            command.set_defaults(run=module.run)
    return parser


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("torchquat")
    except Exception:  # not installed: a source checkout
        return "unknown"


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``torchquat`` and ``python -m torchquat``; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    lazy = chosen if chosen in _LAZY else None
    if lazy is not None:
        try:
            importlib.import_module(_LAZY[lazy][0])
        except ModuleNotFoundError as err:
            if err.name != _LAZY[lazy][0]:
                raise
            print(f"torchquat {lazy}: not available in this installation ({_LAZY[lazy][0]} is missing)",
                  file=sys.stderr)
            return 2
    parser = build_parser(lazy)
    args = parser.parse_args(argv)
    if getattr(args, "run", None) is None:
        parser.print_help(sys.stderr)
        return 2
    from ._signals import sigterm_as_interrupt
    try:
        with sigterm_as_interrupt():
            return int(args.run(args) or 0)
    except KeyboardInterrupt:
        print("torchquat: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
