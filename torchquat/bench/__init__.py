"""``torchquat bench``: time torchquat against every installed peer, on the same rotations.

Peers: RoMa, kornia, pytorch-kinematics, PyPose (torch) and SciPy (NumPy, forward only, its own
column), installed by ``pip install "torchquat[bench]"``. One process, ``torch.utils.benchmark``
medians, 1 thread by default, float32 by default, N = 1, 1,000 and 1,000,000, forward and
forward+backward (``torch.autograd.grad`` with a preallocated output gradient). Every peer
cell is first checked to compute the same rotation as torchquat; one that does not is shown
with "≠" and is never counted as the fastest peer.

Usage::

    torchquat bench [--n 1 1000 1000000] [--ops ...] [--peers ...] [--device cuda] [--json FILE]
    python -m torchquat.bench ...
"""

import argparse
import os
import platform
import sys
from typing import List, Optional

import torch

import torchquat

from ..io import PoseFileError
from . import ops as _ops
from . import report as _report
from . import timing as _timing
from .options import DTYPES, LIMITS, UsageError, settings
from .peers import PEER_NAMES, load_peers
from .runner import check_peers, time_all

__all__ = ["add_arguments", "run", "main"]

INSTALL_HINT = 'pip install "torchquat[bench]"'


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the bench options to ``parser`` (the ``torchquat bench`` subcommand uses this)."""
    parser.add_argument("--n", type=int, nargs="+", default=[1, 1000, 1_000_000], metavar="N",
                        help=f"batch sizes, {LIMITS['n'][0]} to {LIMITS['n'][1]:,} (default: 1 1000 1000000)")
    parser.add_argument("--ops", nargs="+", default=None, metavar="OP",
                        help="operations to time (default: all): " + " ".join(op.name for op in _ops.OPS))
    parser.add_argument("--peers", nargs="+", default=None, metavar="PEER",
                        help="peers to time, if installed (default: all): " + " ".join(PEER_NAMES)
                        + "; 'none' for torchquat alone")
    parser.add_argument("--threads", type=int, default=1,
                        help=f"torch intra-op threads, {LIMITS['threads'][0]} to {LIMITS['threads'][1]} (default: 1)")
    parser.add_argument("--device", default="cpu",
                        help="where the tensors live: cpu (default) or cuda; on a GPU the timer "
                        "synchronizes the device around each measurement, and SciPy (NumPy, host "
                        "memory) is left out")
    parser.add_argument("--dtype", choices=sorted(DTYPES), default="float32", help="default: float32")
    parser.add_argument("--backward", action=argparse.BooleanOptionalAction, default=True,
                        help="also time forward+backward (default: on)")
    parser.add_argument("--min-run-time", type=float, default=0.2, metavar="SECONDS",
                        help="blocked_autorange min_run_time per cell (default: 0.2); at least 3 "
                        "measurements are taken whatever it is")
    parser.add_argument("--rounds", type=int, default=3, metavar="R",
                        help="time every op and implementation in R rounds (each round goes over all "
                        "the ops at one N) and keep each one's fastest median (default: 3): a shared "
                        "machine's speed drifts over minutes and has slow spells of a minute or two, "
                        "which would skew a cell timed in one go")
    parser.add_argument("--json", metavar="FILE", default=None, help="also write every number to FILE")
    parser.add_argument("--allocator", choices=["auto", "reexec", "mallopt", "none"], default="auto",
                        help="how to keep glibc from page-faulting fresh outputs at large N: re-exec "
                        "with GLIBC_TUNABLES set (auto, when run from the command line), glibc "
                        "mallopt in-process (auto otherwise), or leave it (none)")
    parser.add_argument("--compiled", action=argparse.BooleanOptionalAction, default=False,
                        help="also time torchquat with use_compiled_kernels(True) (torch.compile, "
                        "inductor; needs a C++ compiler; compile time excluded) in its own column")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random rotations")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="progress lines on stderr (default: when stderr is a terminal)")
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the benchmark described by ``args`` (from :func:`add_arguments`).

    Args:
        args: the parsed options.

    Returns:
        The exit status: 0 done, 1 stopped by an error (the table keeps what finished), 2 an
        option out of range or a JSON file that cannot be written, 130/143 stopped by SIGINT/SIGTERM.
    """
    try:
        s = settings(args)
    except UsageError as err:
        print(f"torchquat bench: {err}", file=sys.stderr)
        return 2
    allocator = (_timing.steady_allocator(s.allocator) if s.device.type == "cpu"  # may re-exec
                 else f"allocator: PyTorch's {s.device.type} caching allocator (freed outputs are reused, never returned)")
    torch.set_num_threads(s.threads)
    peers = load_peers(s.peer_names)
    active = [p for p in peers if p.error is None]
    torch_peers = [p.name for p in active if p.torch_peer]
    selected = [_ops.OPS_BY_NAME[name] for name in s.op_names]
    agreement, agrees, tol = check_peers(selected, active, s.dtype, s.device)
    outcome = time_all(s, selected, active, agrees, agreement)
    legend = _legend(selected, active, s.compiled)
    labels = {op.name: op.label for op in selected}
    columns = ([_report.COMPILED] if s.compiled else []) + [p.name for p in active]
    print(_report.markdown(outcome.results, labels, s.ns, columns, torch_peers,
                           _report.header(s, allocator, peers, active, outcome, tol, INSTALL_HINT),
                           _report.footer(legend, labels, agreement, outcome.results, outcome.elapsed)), end="")
    if s.json_path and not _write_json(s, allocator, peers, outcome, torch_peers, legend, agreement):
        return 2
    if outcome.stopped is not None and outcome.stopped.startswith("error"):
        print(f"torchquat bench: stopped by an {outcome.stopped} (the table has what finished before)", file=sys.stderr)
        return 1
    return {None: 0, "SIGINT": 130, "SIGTERM": 143}[outcome.stopped]


def _legend(selected, active, compiled: bool):
    """Each op's call in each implementation, as the footer and the JSON name them."""
    legend = {}
    for op in selected:
        calls = {_report.TORCHQUAT: "torchquat." + op.tq_call}
        if compiled:
            calls[_report.COMPILED] = _ops.torchquat_impl(op, compiled=True).call
        for p in active:
            if op.name in p.impls:
                impl = p.impls[op.name]
                calls[p.name] = impl.call + (f" [{impl.note}]" if impl.note else "")
        legend[op.name] = calls
    return legend


def _write_json(s, allocator, peers, outcome, torch_peers, legend, agreement) -> bool:
    """Write the JSON file; False (after a one-line message) when it cannot be written."""
    meta = {"torchquat": torchquat.__version__, "torch": torch.__version__, "dtype": str(s.dtype),
            "threads": s.threads, "device": str(s.device), "ns": s.ns, "compiled": s.compiled,
            "min_run_time": s.min_run_time, "allocator": allocator, "floor_definition": _timing.FLOOR_DEFINITION,
            "machine": platform.platform(), "cpus": os.cpu_count(), "cpu": _report.cpu_model(),
            "python": platform.python_version(), "elapsed_s": outcome.elapsed,
            "peers": {p.name: {"version": p.version, "import_s": p.import_s, "error": p.error} for p in peers},
            "stopped_by": outcome.stopped, "finished": outcome.done, "planned": outcome.total}
    try:
        _report.write_json(s.json_path, meta, outcome.results, torch_peers, legend, agreement)
    except (OSError, PoseFileError) as exc:
        print(f"torchquat bench: --json {s.json_path}: {exc}", file=sys.stderr)
        return False
    return True


def main(argv: Optional[List[str]] = None) -> int:
    """``python -m torchquat.bench [options]``: parse ``argv`` and :func:`run`."""
    parser = argparse.ArgumentParser(prog="python -m torchquat.bench",
                                     description="Time torchquat against the installed peer libraries.")
    add_arguments(parser)
    return run(parser.parse_args(argv))
