"""Rows against planes: what a compiled Euler -> quaternion loop pays for its layout, in torch code.

A developer's tool (not installed). ``tools/layout_model.py`` answers the question in C++ with AVX2
intrinsics; this one asks inductor itself, on whatever vectors it picks for this CPU. It compiles
Euler ZYX -> quat's arithmetic (the shipped half-angle cosine and sinc polynomials of
``torchquat._polynomials`` by Estrin's scheme, the ZYX product, ``w >= 0``) and a trivial one (a
multiply-add per component) into three layouts each, and times them in one process, in turns, beside
the bench's ``(N, 4)`` copy floor and torchquat's own compiled kernel:

- ``rows -> rows``: reads rows of 3, writes rows of 4 (``stack(cols, -1)``), as the kernel does:
  inductor gathers each input column with scalar loads and scatters each output column with
  scalar stores;
- ``rows -> planes``: writes the four components as contiguous planes (``stack(cols, 0)``), so each
  is one vector store;
- ``planes -> planes``: reads contiguous planes too (no layout at all).

Every variant's output is checked against ``torchquat.euler_to_quat`` in float64 first. Run::

    GLIBC_TUNABLES=glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=68719476736 \\
        python tools/rows_or_planes.py [--n 1000000] [--rounds 16] [--min-run-time 0.3]

``docs/bench_profile.md`` ("Rows against planes on Zen 4 (session 33)") has the figures.
"""

import argparse
import statistics
import sys
from typing import Callable, Dict, List

import torch
from torch.utils import benchmark

import torchquat as tq
from torchquat import _polynomials
from torchquat.bench import timing


def _half_cos_sin(h):
    """``(cos h, sin h)`` for ``|h| <= pi / 2`` by the shipped polynomials (as the kernels' direct mode)."""
    c, sinc = _polynomials.half_cos_sinc(h * h)
    return c, h * sinc


def euler_zyx_quat_columns(angles) -> List:
    """The four components ``(w, x, y, z)`` of Euler ZYX -> quat, ``w >= 0``, from ``(..., 3)`` angles
    (yaw, pitch, roll) within pi."""
    a, b, c = (angles * 0.5).unbind(-1)
    ca, sa = _half_cos_sin(a)
    cb, sb = _half_cos_sin(b)
    cc, sc = _half_cos_sin(c)
    cacb, sasb, casb, sacb = ca * cb, sa * sb, ca * sb, sa * cb
    w = cacb * cc + sasb * sc
    sign = torch.where(w < 0, -1.0, 1.0)
    return [w * sign, (cacb * sc - sasb * cc) * sign, (casb * cc + sacb * sc) * sign, (sacb * cc - casb * sc) * sign]


def trivial_columns(x) -> List:
    """Four columns from rows of 3 with a multiply-add each: the layouts' cost with no arithmetic."""
    a, b, c = x.unbind(-1)
    return [a * b + c, b * c + a, c * a + b, a + b + c]


def _rows(columns: Callable) -> Callable:
    return lambda x: torch.stack(columns(x), -1)


def _planes_out(columns: Callable) -> Callable:
    return lambda x: torch.stack(columns(x), 0)


def _planes_in_out(columns: Callable) -> Callable:
    return lambda planes: torch.stack(columns(planes.t()), 0)


# name -> (columns, layout, input is planes); the output is rows for "rows -> rows", else planes
VARIANTS = {
    "trivial, rows -> rows": (trivial_columns, _rows, False),
    "trivial, rows -> planes": (trivial_columns, _planes_out, False),
    "E->q arithmetic, rows -> rows": (euler_zyx_quat_columns, _rows, False),
    "E->q arithmetic, rows -> planes": (euler_zyx_quat_columns, _planes_out, False),
    "E->q arithmetic, planes -> planes": (euler_zyx_quat_columns, _planes_in_out, True),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--rounds", type=int, default=16)
    parser.add_argument("--min-run-time", type=float, default=0.3)
    parser.add_argument("--backend", default="inductor", help="torch.compile's backend (tests: eager)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    generator = torch.Generator().manual_seed(0)
    angles = (torch.rand(args.n, 3, generator=generator) * 2 - 1) * 3.0
    planes = angles.t().contiguous()
    options = {"cpp.enable_tiling_heuristics": False, "cpp.enable_floating_point_contract_flag": "fast"}
    compile_options = {"options": options} if args.backend == "inductor" else {}
    calls: Dict[str, Callable] = {"floor: (N, 4) copy": timing.floor_fn(args.n, 3, (4,), torch.float32)}
    reference = tq.euler_to_quat(angles.double(), "ZYX")
    errors = {}
    with torch.no_grad():
        for name, (columns, layout, planes_in) in VARIANTS.items():
            fn = torch.compile(layout(columns), dynamic=True, backend=args.backend, **compile_options)
            x = planes if planes_in else angles
            calls[name] = (lambda fn=fn, x=x: fn(x))
            if columns is euler_zyx_quat_columns:
                out = fn(x)
                errors[name] = float(((out if layout is _rows else out.t()).double() - reference).abs().max())
        was_enabled = tq.compiled_kernels_enabled()
        tq.use_compiled_kernels(True)
        try:
            calls["torchquat euler_to_quat ZYX (compiled)"] = lambda: tq.euler_to_quat(angles, "ZYX")
            errors["torchquat euler_to_quat ZYX (compiled)"] = float((calls["torchquat euler_to_quat ZYX (compiled)"]().double() - reference).abs().max())
            for call in calls.values():  # (compiles and warms up)
                call()
            medians: Dict[str, List[float]] = {name: [] for name in calls}
            for r in range(args.rounds):
                order = list(calls.items()) if r % 2 == 0 else list(reversed(calls.items()))
                for name, call in order:
                    t = benchmark.Timer("f()", globals={"f": call}, num_threads=1).blocked_autorange(min_run_time=args.min_run_time)
                    medians[name].append(t.median * 1e3)
        finally:
            tq.use_compiled_kernels(was_enabled)
    print(f"{args.n} float32 rows, one thread, {args.rounds} rounds in turns; medians of each round (ms)\n")
    print("| variant | median ms | fastest ms | max error against float64 |")
    print("|---|---:|---:|---:|")
    for name, times in medians.items():
        error = f"{errors[name]:.1e}" if name in errors else ""
        print(f"| {name} | {statistics.median(times):.3f} | {min(times):.3f} | {error} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
