"""In-process A/B of torchquat's compiled kernels: two variants of the code, timed in turns.

On a noisy machine a full ``torchquat bench`` cannot see a change under about 10%, and two
processes (one per variant) drift apart by as much. This compiles each variant's kernels once,
keeps each variant's compiled functions in a dictionary of its own, and then times the variants
in alternating order, round after round, swapping that dictionary into the dispatcher
(``torchquat._dispatch._compiled``) before each measurement. Use 20 rounds or more, and repeat a
large first result before believing it (``docs/bench_profile.md``, "Tried in session 24").

A variants file is Python that defines ``VARIANTS``, a dict of name -> callable. Each callable
puts torchquat into that variant's state (patch a module attribute, set a flag); it runs before
the variant is compiled and again before each of its measurements, so each must set every
attribute any variant changes. For example, session 25's half-angle polynomials on and off::

    import torchquat._dispatch as D

    ORIGINAL = D._sincos_mode

    def reduced():
        D._sincos_mode = lambda largest, bound: ORIGINAL(largest, -1.0)

    def direct():
        D._sincos_mode = ORIGINAL

    VARIANTS = {"reduced": reduced, "direct": direct}

Run (steady allocator, as the bench does)::

    GLIBC_TUNABLES=glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=68719476736 \\
        python tools/ab_compiled.py variants.py --ops euler_to_quat_ZYX,axis_angle_to_quat --rounds 20

Forward only with no gradient recorded (the graphs inference takes), or with ``--backward`` the
forward and ``torch.autograd.grad`` with a fixed output gradient (the training graphs, as the bench's
fwd+bwd cells); float32, one thread, inputs of ``torchquat.bench``. Prints the median and fastest time
of each variant per op, and the ratio of the medians (second / first).
"""

import argparse
import runpy
import statistics
import sys

import torch
from torch.utils import benchmark

import torchquat as tq
from torchquat import _dispatch
from torchquat.bench import ops as bench_ops


def _call(fn, inputs, backward: bool):
    """``(fn, inputs)`` to time: ``fn`` itself, or with ``backward`` a step that calls ``fn`` on leaves
    that require a gradient and returns ``torch.autograd.grad`` of its output (a fixed random gradient)."""
    if not backward:
        return fn, inputs
    leaves = tuple(t.detach().clone().requires_grad_() for t in inputs)
    with torch.no_grad():  # (the output's shape, without compiling a graph for it)
        shape = fn(*leaves).shape
    grad = torch.randn(shape, generator=torch.Generator().manual_seed(0))

    def step(*tensors):
        return torch.autograd.grad(fn(*tensors), tensors, grad)

    return step, leaves


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("variants", help="a Python file that defines VARIANTS = {name: setup callable}")
    parser.add_argument("--ops", default="euler_to_quat_ZYX,axis_angle_to_quat",
                        help="comma-separated op names of torchquat bench (default: %(default)s)")
    parser.add_argument("--n", type=int, default=1_000_000, help="rows (default: %(default)s)")
    parser.add_argument("--rounds", type=int, default=20, help="alternating rounds (default: %(default)s)")
    parser.add_argument("--min-run-time", type=float, default=0.3,
                        help="seconds of blocked_autorange per measurement (default: %(default)s)")
    parser.add_argument("--backward", action="store_true",
                        help="time the forward and its backward (torch.autograd.grad), not the forward alone")
    args = parser.parse_args(argv)
    variants = runpy.run_path(args.variants)["VARIANTS"]
    names = [name for name in args.ops.split(",") if name]
    unknown = [name for name in names if name not in bench_ops.OPS_BY_NAME]
    if len(variants) != 2 or unknown or args.rounds < 1 or args.n < 1:
        parser.error(f"VARIANTS needs two entries (has {len(variants)}); unknown ops: {unknown}; "
                     "--rounds and --n at least 1")
    torch.set_num_threads(1)
    inputs = bench_ops.make_inputs(args.n, torch.float32)
    calls = {name: _call(bench_ops.OPS_BY_NAME[name].tq_fn, tuple(inputs[k] for k in bench_ops.OPS_BY_NAME[name].args),
                         args.backward)
             for name in names}
    previous = (tq.compiled_kernels_enabled(), _dispatch._compiled)
    compiled = {}
    try:
        tq.use_compiled_kernels(True)
        with torch.set_grad_enabled(args.backward):
            for variant, setup in variants.items():
                setup()
                _dispatch._compiled = {}
                for fn, call_inputs in calls.values():
                    fn(*call_inputs)  # (compiles this variant's graph; excluded from the timing)
                compiled[variant] = _dispatch._compiled
            times = {name: {variant: [] for variant in variants} for name in names}
            order = list(variants)
            for round_ in range(args.rounds):
                for name, (fn, call_inputs) in calls.items():
                    for variant in (order if round_ % 2 == 0 else order[::-1]):
                        variants[variant]()
                        _dispatch._compiled = compiled[variant]
                        timer = benchmark.Timer("fn(*x)", globals={"fn": fn, "x": call_inputs})
                        times[name][variant].append(timer.blocked_autorange(min_run_time=args.min_run_time).median)
    finally:
        tq.use_compiled_kernels(previous[0])
        _dispatch._compiled = previous[1]
    first, second = order
    print(f"{args.n:,} float32 rows, {'forward+backward' if args.backward else 'forward'}, {args.rounds} rounds, "
          "medians over rounds (fastest round), ms")
    print(f"| op | {first} | {second} | {second} / {first} |")
    print("|---|---:|---:|---:|")
    for name in names:
        a, b = times[name][first], times[name][second]
        print(f"| {name} | {statistics.median(a) * 1e3:.2f} ({min(a) * 1e3:.2f}) | "
              f"{statistics.median(b) * 1e3:.2f} ({min(b) * 1e3:.2f}) | "
              f"{statistics.median(b) / statistics.median(a):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
