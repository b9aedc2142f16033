"""Timing: a steady allocator, medians from ``torch.utils.benchmark``, and the memory floor."""

import ctypes
import ctypes.util
import math
import os
import statistics
import sys
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence

import torch
from torch.utils.benchmark import Timer

TUNABLES = "glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=68719476736"
_GUARD = "TORCHQUAT_BENCH_REEXEC"
# mallopt parameters (glibc malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4

FLOOR_DEFINITION = (
    "memory floor: the cheapest single eager pass over the same bytes, into a preallocated output "
    "of the op's output shape: when the inputs are no larger than the output, `out.copy_(src)` with "
    "`src` a preallocated tensor of the output's shape (reads and writes the output's size); when "
    "they are larger, `torch.sum(P, dim=0, out=out)` with `P` of shape (k, N, output width), "
    "k = ceil(input width / output width) (reads at least the inputs' size, writes the output); "
    "the fastest of three fresh preallocations"
)


def _tunables_set() -> bool:
    value = os.environ.get("GLIBC_TUNABLES", "")
    return "glibc.malloc.mmap_max=0" in value and "glibc.malloc.trim_threshold=" in value


def relaunch_argv() -> Optional[List[str]]:
    """The command line that started this process, if it is a bench invocation we may re-run.

    Only ``torchquat bench ...``, ``python -m torchquat bench ...`` and
    ``python -m torchquat.bench ...`` qualify: a bench run in-process by some other program
    (a test runner, a notebook) is never replaced.
    """
    argv = list(sys.argv)
    orig = list(getattr(sys, "orig_argv", []) or [])
    if len(orig) >= 3 and orig[1] == "-m" and orig[2] in ("torchquat", "torchquat.bench", "torchquat.cli"):
        if orig[2] == "torchquat.bench" or "bench" in orig[3:]:
            return [sys.executable] + orig[1:]
        return None
    script = argv[0] if argv else ""
    base = os.path.basename(script)
    norm = script.replace("\\", "/")
    if norm.endswith("torchquat/bench/__main__.py"):
        return [sys.executable, "-m", "torchquat.bench"] + argv[1:]
    if norm.endswith("torchquat/__main__.py") and "bench" in argv[1:]:
        return [sys.executable, "-m", "torchquat"] + argv[1:]
    if base in ("torchquat", "torchquat.exe", "torchquat-script.py") and "bench" in argv[1:]:
        return [sys.executable, script] + argv[1:]
    return None


def _mallopt() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        ok1 = libc.mallopt(_M_MMAP_MAX, 0)
        ok2 = libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
        return bool(ok1) and bool(ok2)
    except (OSError, AttributeError):
        return False


def steady_allocator(mode: str) -> str:
    """Make freed memory reusable so N = 1e6 times do not include page faults; say how.

    ``mode``: ``auto`` (re-exec with GLIBC_TUNABLES when this process is a bench command line,
    else glibc ``mallopt`` in-process), ``reexec``, ``mallopt``, or ``none``. Returns the line
    the report prints. May not return (``os.execv``).
    """
    if _tunables_set():
        how = "set by re-exec of this command" if os.environ.get(_GUARD) else "set by the caller"
        return f"allocator: GLIBC_TUNABLES={os.environ['GLIBC_TUNABLES']} ({how})"
    if mode == "none":
        return "allocator: glibc defaults (large outputs may be page-faulted on every call at N = 1e6)"
    if mode in ("auto", "reexec") and not os.environ.get(_GUARD):
        argv = relaunch_argv()
        if argv is not None:
            print(f"torchquat bench: re-executing with GLIBC_TUNABLES={TUNABLES} "
                  "(a steady allocator)", file=sys.stderr, flush=True)
            sys.stdout.flush()
            env = dict(os.environ)
            existing = env.get("GLIBC_TUNABLES")
            env["GLIBC_TUNABLES"] = f"{existing}:{TUNABLES}" if existing else TUNABLES
            env[_GUARD] = "1"
            os.execve(sys.executable, argv, env)
    if mode in ("auto", "mallopt", "reexec") and _mallopt():
        return ("allocator: glibc mallopt(M_MMAP_MAX=0, M_TRIM_THRESHOLD=2^31-1) in-process (as "
                f"GLIBC_TUNABLES={TUNABLES}, with mallopt's largest trim threshold, 2 GiB, for the tunable's 64 GiB)")
    return "allocator: glibc defaults (could not make it steady; N = 1e6 times include page faults)"


@dataclass
class Timing:
    median: float   # seconds per call
    iqr: float
    runs: int       # measurements the median is taken over
    calls: int      # calls timed in all


def measure(fn: Callable[[], object], min_run_time: float, threads: int, min_runs: int = 3) -> Timing:
    """Median seconds per call of ``fn()`` with ``Timer.blocked_autorange``, topped up to at
    least ``min_runs`` measurements (a slow call fills ``min_run_time`` in one block)."""
    timer = Timer(stmt="fn()", globals={"fn": fn}, num_threads=threads)
    first = timer.timeit(1).times[0]  # warm-up, and a probe of the cost of one call
    if first * min_runs >= min_run_time:
        # One call fills the budget (N = 1e6, or SciPy): median of min_runs single calls.
        times, number = [first] + [timer.timeit(1).times[0] for _ in range(min_runs - 1)], 1
        times = times[1:] + [timer.timeit(1).times[0]] if first > 2 * min(times[1:]) else times
    else:
        m = timer.blocked_autorange(min_run_time=min_run_time)
        times, number = list(m.times), m.number_per_run
    while len(times) < min_runs:
        times.extend(timer.timeit(number).times)
    q = statistics.quantiles(times, n=4) if len(times) >= 2 else [times[0]] * 3
    return Timing(statistics.median(times), q[2] - q[0], len(times), len(times) * number)


def floor_fn(n: int, in_width: int, out_shape: Sequence[int], dtype: torch.dtype,
             device="cpu") -> Callable[[], object]:
    """The memory-floor kernel for one op (see FLOOR_DEFINITION), preallocated."""
    out = torch.empty((n,) + tuple(out_shape), dtype=dtype, device=device)
    out_width = max(1, math.prod(out_shape))
    k = max(1, math.ceil(in_width / out_width))
    if k == 1:
        src = torch.rand_like(out)
        return lambda: out.copy_(src)
    planes = torch.rand((k,) + tuple(out.shape), dtype=dtype, device=device)
    return lambda: torch.sum(planes, dim=0, out=out)
