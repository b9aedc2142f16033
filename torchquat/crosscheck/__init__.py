"""``torchquat crosscheck``: every conversion against SciPy and pytorch-kinematics.

Runs torchquat's conversions, quaternion algebra and distances against
``scipy.spatial.transform`` and ``pytorch_kinematics.transforms`` on uniform random rotations
and on singular sets (the identity and 1e-9..1e-3 rad from it; half turns about x, y, z and
random axes and 1e-9..1e-3 rad short of them; Euler angles exactly at gimbal lock for each of
the 24 conventions and 1e-9..1e-3 rad from it), prints a table of max errors per function and
case with each row's tolerance, and exits 1 if any row exceeds its tolerance.

How errors are measured: quaternions up to sign; rotation vectors up to ``v ~ -v`` at a half
turn; Euler angles wrapped to ``[-pi, pi]`` (metric ``angles``, on random rotations and, in
float64, exactly at lock where SciPy's rule makes them unique) and as rotations (metric
``rotation``: both sets of angles turned back into matrices by the oracle, on every input,
near lock included, where the angles are ill-conditioned but the rotation is not). torchquat
computes in ``--dtype``; the oracles always compute in float64 on the same rounded inputs.
The ``convention mapping`` rows check each oracle's Euler conventions against their definition
(products of elementary rotations), so the mapping between conventions is verified, not assumed.

Example:
    >>> import argparse
    >>> parser = argparse.ArgumentParser()
    >>> add_arguments(parser)
    >>> parser.parse_args(["--n", "50", "--oracle", "scipy"]).n
    50
"""

import argparse
import importlib
import sys
import time
from typing import List, Optional, Sequence

import torch

from ..io import PoseFileError, output_folder_problem, write_json
from ._core import Context, Row, family_summary, format_table

__all__ = ["add_arguments", "run", "main", "crosscheck"]

PK_MISSING = 'pytorch-kinematics is not installed: pip install pytorch-kinematics (or pip install "torchquat[test]")'
SCIPY_MISSING = 'SciPy is not installed: pip install scipy (or pip install "torchquat[test]")'
MAX_N = 1_000_000  # random samples per set: far beyond a useful check, short of exhausting memory
ORACLES = {"scipy": ("scipy.spatial.transform", "scipy", SCIPY_MISSING),
           "pk": ("pytorch_kinematics.transforms", "pytorch-kinematics", PK_MISSING)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the cross-check's options to ``parser`` (used by ``torchquat crosscheck``)."""
    parser.add_argument("--n", type=int, default=2000, metavar="N",
                        help=f"random samples per set, 1 to {MAX_N:,} (default 2000); singular sets are fixed")
    parser.add_argument("--dtype", choices=("float64", "float32"), default="float64",
                        help="dtype torchquat computes in (default float64); tolerances follow it")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random inputs (default 0)")
    parser.add_argument("--json", metavar="FILE", help="also write every row to FILE as JSON")
    parser.add_argument("--oracle", choices=("all", "scipy", "pk"), default="all",
                        help="compare against SciPy, pytorch-kinematics or both (default all)")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="print only failing rows, the per-family summary and the totals")


def _version(dist: str) -> str:
    try:
        from importlib.metadata import version
        return version(dist)
    except Exception:  # noqa: BLE001 - a version is only informative
        return "unknown"


def _load(oracle: str):
    """The oracle's module, or None (after saying how to install it) when it is missing."""
    module, _, missing = ORACLES[oracle]
    try:
        return importlib.import_module(module)
    except ImportError:
        print(missing, file=sys.stderr)
        return None


def crosscheck(n: int = 2000, dtype: torch.dtype = torch.float64, seed: int = 0,
               oracles: Sequence[str] = ("scipy", "pk")) -> List[Row]:
    """Run the checks against the named oracles that are installed; return the rows.

    Args:
        n: random samples per set.
        dtype: the dtype torchquat computes in (``torch.float64`` or ``torch.float32``).
        seed: seed of the random inputs.
        oracles: any of ``"scipy"`` and ``"pk"``; missing ones are skipped with a message.

    Returns:
        The rows of the report (an empty list when no named oracle is installed).
    """
    from . import _pk, _scipy

    ctx = Context(dtype)
    for oracle in oracles:
        module = _load(oracle)
        if module is None:
            continue
        runner = _scipy.run_checks if oracle == "scipy" else _pk.run_checks
        try:
            runner(ctx, module, n, torch.Generator().manual_seed(seed))
        except Exception as exc:  # noqa: BLE001 - an oracle that crashes is a failed row, not a traceback
            ctx.check("(oracle crashed)", oracle, oracle, "-", (0.0, 0.0),
                      lambda: float("inf"), note=f"{type(exc).__name__}: {exc}".splitlines()[0][:120])
    return ctx.rows


def _usage_problem(args: argparse.Namespace) -> Optional[str]:
    """What is out of range in the options (named, with the range and the value), or None."""
    if not 1 <= args.n <= MAX_N:
        return f"--n must be from 1 to {MAX_N}, got {args.n}"
    if not 0 <= args.seed < 2 ** 63:
        return f"--seed must be from 0 to {2 ** 63 - 1}, got {args.seed}"
    if args.json is not None and not args.json.strip():
        return "--json needs a file name"
    problem = args.json and output_folder_problem(args.json)  # (before the run, not after it)
    return f"--json {problem}" if problem else None


def run(args: argparse.Namespace) -> int:
    """Run the cross-check for parsed ``args``; print the report.

    Returns:
        0 when every row is within its tolerance, 1 when some row is not, 2 for a usage error
        or when none of the requested oracles is installed.
    """
    problem = _usage_problem(args)
    if problem:
        print(f"torchquat crosscheck: {problem}", file=sys.stderr)
        return 2
    names = ("scipy", "pk") if args.oracle == "all" else (args.oracle,)
    dtype = torch.float64 if args.dtype == "float64" else torch.float32
    start, threads = time.perf_counter(), torch.get_num_threads()
    torch.set_num_threads(1)  # thousands of rows per call: threads cost more than they give
    try:
        rows = crosscheck(args.n, dtype, args.seed, names)
    finally:
        torch.set_num_threads(threads)
    seconds = time.perf_counter() - start
    if not rows:
        print("torchquat crosscheck: no oracle to compare against", file=sys.stderr)
        return 2
    failed = [r for r in rows if not r.passed]
    used = sorted({r.oracle for r in rows})
    versions = {ORACLES[o][1]: _version(ORACLES[o][1]) for o in used}
    print(f"torchquat crosscheck: dtype {args.dtype}, n {args.n}, seed {args.seed}; "
          + ", ".join(f"{k} {v}" for k, v in versions.items()))
    print()
    print(format_table(rows, failures_only=args.quiet) if failed or not args.quiet else "(every row passed)")
    print()
    print("Worst case per function, oracle and metric:")
    print(family_summary(rows))
    print()
    print(f"{len(rows)} checks, {len(failed)} failed ({seconds:.1f} s)")
    if args.json:
        from .. import __version__
        report = {"torchquat": __version__, "dtype": args.dtype, "n": args.n, "seed": args.seed,
                  "oracles": versions, "checks": len(rows), "failed": len(failed),
                  "rows": [r.as_dict() for r in rows]}
        try:
            write_json(args.json, report)
        except (OSError, PoseFileError) as exc:  # (exit 1 means a check failed: this is not that)
            print(f"torchquat crosscheck: --json {args.json}: {exc}", file=sys.stderr)
            return 2
    return 1 if failed else 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m torchquat.crosscheck [options]``: parse ``argv`` and :func:`run`."""
    parser = argparse.ArgumentParser(prog="torchquat crosscheck", description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))
