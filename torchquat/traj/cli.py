"""``torchquat eval REFERENCE ESTIMATE``: APE or RPE of two pose files, with evo's numbers."""

import argparse
import json
import sys
from typing import Optional

__all__ = ["add_arguments", "run"]

# evo's command-line names of the relations (evo_ape -r ...), accepted beside the full ones
_ALIASES = {"trans_part": "translation_part", "rot_part": "rotation_part", "full": "full_transformation",
            "angle_rad": "rotation_angle_rad", "angle_deg": "rotation_angle_deg"}
_UNITS = {"translation_part": "m", "point_distance": "m", "rotation_angle_rad": "rad", "rotation_angle_deg": "deg",
          "rotation_part": "unitless", "full_transformation": "unitless"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``torchquat eval``."""
    from .metrics import RELATIONS
    parser.add_argument("reference", metavar="REFERENCE", help="ground-truth pose file (TUM, KITTI, EuRoC, CSV, NPZ, "
                        "COLMAP, NeRF, BOP: camera poses are taken as the camera's pose in the world)")
    parser.add_argument("estimate", metavar="ESTIMATE", help="estimated pose file, any format the readers know")
    parser.add_argument("--metric", choices=("ape", "rpe"), default="ape", help="absolute or relative pose error "
                        "(default ape)")
    parser.add_argument("-r", "--relation", default="translation_part", metavar="NAME",
                        help=f"evo's pose relation: {', '.join(RELATIONS)} (or evo's short names "
                        f"{', '.join(_ALIASES)}); default translation_part")
    parser.add_argument("--align", action="store_true", help="Umeyama SE(3) alignment of the estimate first")
    parser.add_argument("--scale", action="store_true", help="correct the scale (Sim(3) with --align, alone without)")
    parser.add_argument("--delta", type=float, default=1.0, help="RPE pair distance (default 1)")
    parser.add_argument("--delta-unit", choices=("frames", "meters", "seconds"), default="frames",
                        help="unit of --delta (default frames)")
    parser.add_argument("--max-difference", type=float, default=0.01, metavar="S",
                        help="largest time difference of an associated pair, seconds (default 0.01, as evo_ape)")
    parser.add_argument("--offset", type=float, default=0.0, metavar="S",
                        help="seconds added to ESTIMATE's times before association (default 0)")
    parser.add_argument("--json", metavar="FILE", help="write the statistics as JSON with evo's keys "
                        "(rmse, mean, median, std, min, max, sse)")
    parser.add_argument("--plot", metavar="FILE.png", help="draw both trajectories (top view, coloured by error) "
                        "and the error along the way (needs matplotlib: pip install torchquat[plot])")


def _fail(message: str) -> int:
    print(f"torchquat eval: error: {message}", file=sys.stderr)
    return 2


def _float64(poses):
    """The poses in float64, in their own representation (no conversion)."""
    import torch
    return poses.to(poses.representation, degrees=poses.degrees, dtype=torch.float64)


def _in_world(path: str, poses):
    """The poses as the camera's (or body's) pose in the world, as ``convert`` writes them to TUM:
    COLMAP's world -> camera and BOP's model -> camera poses are inverted (the world frame is
    neither moved nor rescaled), and what was changed is said on stderr."""
    from ..io import Report, to_convention
    report = Report()
    poses = to_convention(poses, "tum", report)
    prefix = "tum output: "
    for note in report.notes:
        note = note[len(prefix):] if note.startswith(prefix) else note
        note = note.replace("tum's world frame", "the evaluation's world frame").replace("are written in", "stay in")
        print(f"torchquat eval: {path}: {note}", file=sys.stderr)
    return poses


def _has_times(path: str, poses) -> bool:
    """KITTI files get the row index as their time: those, and files without times, go by index."""
    from ..io import detect_format
    return poses.timestamps is not None and detect_format(path) != "kitti"


def run(args: argparse.Namespace) -> int:
    """Run ``torchquat eval``; user errors print one line on stderr and return 2."""
    import torch

    from ..errors import ShapeError
    from ..io import read_poses
    from . import ape, associate, error_statistics, rpe
    from .metrics import RELATIONS
    relation = _ALIASES.get(args.relation, args.relation)
    if relation not in RELATIONS:
        return _fail(f"--relation: expected one of {', '.join(RELATIONS)}, got {args.relation!r}")
    if args.plot is not None:
        try:
            import matplotlib  # noqa: F401  (checked before the work, imported for drawing below)
        except ImportError:
            return _fail("--plot needs matplotlib: pip install 'torchquat[plot]'")
    try:
        reference, estimate = (_float64(_in_world(path, read_poses(path))) for path in (args.reference, args.estimate))
        if reference.positions is None or estimate.positions is None:
            missing = args.reference if reference.positions is None else args.estimate
            return _fail(f"{missing}: the file holds rotations only, no positions to evaluate")
        timed = _has_times(args.reference, reference) and _has_times(args.estimate, estimate)
    except (ValueError, OSError) as err:
        return _fail(_describe(err))
    how = "by index"
    if timed:
        index_ref, index_est = associate(reference.timestamps, estimate.timestamps, args.max_difference, args.offset)
        if len(index_ref) == 0:
            return _fail(f"no pair of poses within {args.max_difference} s of each other (estimate times "
                         f"shifted by {args.offset} s): try a larger --max-difference or an --offset")
        how = f"by time: {len(index_ref)} pairs within {args.max_difference} s"
        reference, estimate = reference[index_ref.numpy()], estimate[index_est.numpy()]
    elif len(reference) != len(estimate):
        return _fail(f"{args.reference} has {len(reference)} poses and {args.estimate} {len(estimate)}: files "
                     f"without times (both need them to associate by time) are compared by index and need as "
                     f"many poses")
    print(f"torchquat eval: {len(reference)} poses of {args.reference} against {args.estimate}, associated {how}",
          file=sys.stderr)
    ref, est = reference, estimate  # (rotations are turned into matrices only for the relations that use them)
    try:
        if args.metric == "ape":
            errors = ape(ref, est, relation, align=args.align, scale=args.scale)
        else:
            times = None if estimate.timestamps is None else torch.as_tensor(estimate.timestamps)
            if args.delta_unit == "seconds" and not timed:
                return _fail("--delta-unit seconds needs times in both files")
            errors = rpe(ref, est, args.delta, args.delta_unit, relation, align=args.align, scale=args.scale,
                         times=times)
    except (ShapeError, ValueError) as err:
        return _fail(str(err).replace("ape: ", "").replace("rpe: ", ""))
    bad = int(torch.isnan(errors).sum())
    if bad:
        print(f"torchquat eval: {bad} of {errors.numel()} errors are NaN (poses with NaN values); the statistics "
              f"leave them out", file=sys.stderr)
    stats = {k: float(v) for k, v in error_statistics(errors, ignore_nan=True).items()}
    _print_table(args, relation, stats, errors.numel() - bad)
    if args.json is not None:
        try:
            _write_json(args.json, stats)
        except OSError as err:
            return _fail(_describe(err))
    if args.plot is not None:
        from .plot import plot_evaluation
        try:
            plot_evaluation(args, (None, reference.positions), (None, estimate.positions), errors, estimate.timestamps if timed else None, relation)
        except (OSError, ValueError) as err:
            return _fail(_describe(err))
        print(f"torchquat eval: plot written to {args.plot}", file=sys.stderr)
    return 0


def _print_table(args, relation: str, stats: dict, count: int) -> None:
    title = f"{args.metric.upper()} w.r.t. {relation.replace('_', ' ')} ({_UNITS[relation]})"
    if args.metric == "rpe":
        title += f", delta {args.delta:g} {args.delta_unit}"
    title += {(False, False): ", not aligned", (True, False): ", SE(3) Umeyama alignment",
              (True, True): ", Sim(3) Umeyama alignment", (False, True): ", scale corrected"}[(args.align, args.scale)]
    print(title)
    print(f"{'pairs' if args.metric == 'rpe' else 'poses':>8}  {count}")
    for key, value in stats.items():
        print(f"{key:>8}  {value:.9g}")


def _write_json(path: str, stats: dict) -> None:
    from ..io import atomic_output
    with atomic_output(path) as stream:  # (a failed write leaves an existing FILE as it was)
        stream.write(json.dumps(stats, indent=2).encode("utf-8") + b"\n")


def _describe(err: Exception) -> str:
    if isinstance(err, OSError) and err.filename is not None:
        return f"{err.filename}: {err.strerror or err}"
    return str(err)


def main(argv: Optional[list] = None) -> int:  # pragma: no cover  (torchquat.cli is the entry point)
    parser = argparse.ArgumentParser(prog="torchquat eval")
    add_arguments(parser)
    return run(parser.parse_args(argv))

