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
import time
from typing import List, Optional

import torch

from . import ops as _ops
from . import report as _report
from . import timing as _timing
from .._signals import sigterm_as_interrupt
from ..io.poses import PoseFileError
from ..io.streaming import output_folder_problem

__all__ = ["add_arguments", "run", "main"]

_DTYPES = {"float32": torch.float32, "float64": torch.float64}
INSTALL_HINT = 'pip install "torchquat[bench]"'


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the bench options to ``parser`` (the ``torchquat bench`` subcommand uses this)."""
    parser.add_argument("--n", type=int, nargs="+", default=[1, 1000, 1_000_000], metavar="N",
                        help="batch sizes (default: 1 1000 1000000)")
    parser.add_argument("--ops", nargs="+", default=None, metavar="OP",
                        help="operations to time (default: all): " + " ".join(op.name for op in _ops.OPS))
    parser.add_argument("--peers", nargs="+", default=None, metavar="PEER",
                        help="peers to time, if installed (default: all): " + " ".join(_ops.PEER_NAMES)
                        + "; 'none' for torchquat alone")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default: 1)")
    parser.add_argument("--device", default="cpu",
                        help="where the tensors live: cpu (default) or cuda; on a GPU the timer "
                        "synchronizes the device around each measurement, and SciPy (NumPy, host "
                        "memory) is left out")
    parser.add_argument("--dtype", choices=sorted(_DTYPES), default="float32", help="default: float32")
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


def _callable(impl: _ops.Impl, inputs, backward: bool, seed: int):
    args = impl.prep(inputs)
    if not backward:
        return lambda: impl.fn(*args)
    leaves = tuple(a.detach().clone().requires_grad_() if isinstance(a, torch.Tensor) and a.is_floating_point()
                   else a for a in args)
    diff = tuple(a for a in leaves if isinstance(a, torch.Tensor) and a.requires_grad)
    out = impl.fn(*leaves)
    outs = tuple(out) if isinstance(out, (tuple, list)) else (out,)
    g = torch.Generator().manual_seed(seed)
    grads = tuple(torch.randn(tuple(o.shape), generator=g, dtype=o.dtype).to(o.device) for o in outs)
    del out, outs

    def step():
        out = impl.fn(*leaves)
        outs = tuple(out) if isinstance(out, (tuple, list)) else (out,)
        return torch.autograd.grad(outs, diff, grads, allow_unused=True)

    return step


def _time_op(op, n, inputs, passes, compiled, active, agrees, agreement, records, results, first, seed,
             min_run_time, threads) -> None:
    """One round of ``op`` at ``n``: every implementation's every pass timed once; a record's median
    is the fastest of its rounds. The first round creates the records (in ``records`` and ``results``)."""
    tq_impl = _ops.torchquat_impl(op)
    impls = [(_report.TORCHQUAT, tq_impl, None)]
    if compiled:
        impls.append((_report.COMPILED, _ops.torchquat_impl(op, compiled=True), None))
    impls += [(p.name, p.impls[op.name], agrees.get((op.name, p.name))) for p in active if op.name in p.impls]
    check_errors = {a["impl"]: a["error"] for a in agreement if a["op"] == op.name and a["error"]}
    for pss in passes:
        cells = []  # (record, callable)
        for name, impl, ok in impls:
            if pss == "fwd+bwd" and not impl.backward:
                continue
            if first:
                rec = records[(op.name, pss, name)] = {
                    "op": op.name, "n": n, "pass": pss, "impl": name, "call": impl.call, "agrees": ok,
                    "median_s": None, "iqr_s": None, "runs": 0, "error": None}
                if name in check_errors:  # (its output could not be compared: shown as err)
                    rec["check_error"] = check_errors[name]
                results.append(rec)
            else:
                rec = records[(op.name, pss, name)]
                if rec["error"]:  # (it raised in an earlier round: not again)
                    continue
            try:
                fn = _callable(impl, inputs, pss == "fwd+bwd", seed)
                if name == _report.COMPILED:
                    fn(), fn()  # compile in the first round, warm up in later ones (excluded from the timing)
            except Exception as exc:
                rec["error"], fn = f"{type(exc).__name__}: {exc}"[:300], None
            cells.append((rec, fn))
        for rec, fn in cells:
            if fn is None:
                continue
            try:
                t = _timing.measure(fn, min_run_time, threads)
            except Exception as exc:
                rec["error"] = f"{type(exc).__name__}: {exc}"[:300]
                continue
            if rec["median_s"] is None or t.median < rec["median_s"]:
                rec.update(median_s=t.median, iqr_s=t.iqr, runs=t.runs, calls=t.calls)
        del cells


def _cpu_model() -> str:
    """The CPU's model name (Linux: /proc/cpuinfo; elsewhere ``platform.processor()``), or ``""``."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as stream:
            for line in stream:
                if line.lower().startswith("model name"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or ""


def _transposes() -> str:
    """How the large eager batches were transposed in this run (``torchquat._planes.by_matmul``)."""
    from .._planes import TRANSPOSES_VARIABLE, _BY_MATMUL

    made = ", ".join(f"{direction} of {k}: {'matmul' if by_matmul else 'copy'}"
                     for (direction, k), by_matmul in sorted(_BY_MATMUL.items()))
    setting = os.environ.get(TRANSPOSES_VARIABLE, "auto") or "auto"
    return f"transposes of large eager batches ({TRANSPOSES_VARIABLE}={setting}): {made or 'none made'}"


def _unique(values) -> list:
    """``values`` in order, each once."""
    return list(dict.fromkeys(values))


def _progress(text: str, enabled: bool) -> None:
    if enabled:
        print(text, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark described by ``args`` (from :func:`add_arguments`); return the exit status."""
    ns: List[int] = _unique(getattr(args, "n", None) or [1, 1000, 1_000_000])  # (a repeat would be timed twice)
    json_path = getattr(args, "json", None)
    if json_path is not None and not json_path.strip():
        print("torchquat bench: --json needs a file name", file=sys.stderr)
        return 2
    problem = json_path and output_folder_problem(json_path)  # (before the run, not after it)
    if problem:
        print(f"torchquat bench: --json {problem}", file=sys.stderr)
        return 2
    op_names = _unique(getattr(args, "ops", None) or [op.name for op in _ops.OPS])
    unknown = [name for name in op_names if name not in _ops.OPS_BY_NAME]
    if unknown:
        print(f"torchquat bench: unknown op(s) {' '.join(unknown)}; choose from "
              + " ".join(op.name for op in _ops.OPS), file=sys.stderr)
        return 2
    peer_names = getattr(args, "peers", None)
    if peer_names is not None and "none" in peer_names and len(set(peer_names)) > 1:
        print("torchquat bench: --peers none means torchquat alone: name peers or none, not both", file=sys.stderr)
        return 2
    peer_names = _ops.PEER_NAMES if peer_names is None else _unique(p for p in peer_names if p != "none")
    bad = [p for p in peer_names if p not in _ops.PEER_NAMES]
    if bad:
        print(f"torchquat bench: unknown peer(s) {' '.join(bad)}; choose from "
              + " ".join(_ops.PEER_NAMES), file=sys.stderr)
        return 2
    if any(n < 1 for n in ns):
        print("torchquat bench: --n values must be >= 1", file=sys.stderr)
        return 2
    if int(getattr(args, "threads", 1)) < 1:
        print("torchquat bench: --threads must be >= 1", file=sys.stderr)
        return 2
    if int(getattr(args, "rounds", 3)) < 1:
        print("torchquat bench: --rounds must be >= 1", file=sys.stderr)
        return 2
    if not float(getattr(args, "min_run_time", 0.2)) >= 0:  # (NaN too; 0 still takes 3 measurements)
        print("torchquat bench: --min-run-time must be >= 0 seconds", file=sys.stderr)
        return 2
    if not 0 <= int(getattr(args, "seed", 0)) < 2 ** 63:
        print("torchquat bench: --seed must be between 0 and 2**63 - 1", file=sys.stderr)
        return 2
    try:
        device = torch.device(getattr(args, "device", "cpu"))
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as exc:  # a misspelt device, or CUDA absent
        print(f"torchquat bench: --device {getattr(args, 'device', 'cpu')}: {exc}".splitlines()[0], file=sys.stderr)
        return 2
    on_host = device.type == "cpu"
    if not on_host:
        peer_names = [p for p in peer_names if p != "scipy"]  # NumPy: its timing would be copies
    dtype = _DTYPES[getattr(args, "dtype", "float32")]
    threads = int(getattr(args, "threads", 1))
    min_run_time = float(getattr(args, "min_run_time", 0.2))
    rounds = int(getattr(args, "rounds", 3))
    passes = ["fwd", "fwd+bwd"] if getattr(args, "backward", True) else ["fwd"]
    seed = int(getattr(args, "seed", 0))
    compiled = bool(getattr(args, "compiled", False)) and _ops.has_compiled_kernels()
    verbose = getattr(args, "progress", None)
    verbose = sys.stderr.isatty() if verbose is None else bool(verbose)

    allocator = (_timing.steady_allocator(getattr(args, "allocator", "auto")) if on_host  # may re-exec
                 else f"allocator: PyTorch's {device.type} caching allocator (freed outputs are reused, never returned)")
    torch.set_num_threads(threads)

    peers = _ops.load_peers(peer_names)
    active = [p for p in peers if p.error is None]
    torch_peers = [p.name for p in active if p.torch_peer]
    columns = ([_report.COMPILED] if compiled else []) + [p.name for p in active]
    selected = [_ops.OPS_BY_NAME[name] for name in op_names]

    # Sanity check, once per (op, peer), on generic rotations away from gimbal lock.
    check_inputs = _ops.make_check_inputs(dtype, device=device)
    tol = 1e-3 if dtype == torch.float32 else 1e-6
    agreement, agrees = [], {}
    for op in selected:
        for peer in active:
            impl = peer.impls.get(op.name)
            if impl is None:
                continue
            try:
                ok, err = _ops.check_agreement(op, impl, check_inputs, tol)
                error = None
            except Exception as exc:
                ok, err, error = False, None, f"{type(exc).__name__}: {exc}"
            agrees[(op.name, peer.name)] = ok
            agreement.append({"op": op.name, "impl": peer.name, "agrees": ok, "max_abs_err": err,
                              "tolerance": tol, "error": error})

    results = []
    total = len(ns) * len(selected)
    n, done, step, current, stopped = None, 0, 0, None, None  # stopped: the signal, or the error, that ended the run early
    started = time.perf_counter()
    with sigterm_as_interrupt():
        try:
            for n in ns:
                inputs = _ops.make_inputs(n, dtype, seed, device)
                records = {}  # (op, pass, impl) -> its record, from the first round on
                # Each round times every op once: a cell's rounds are a third of this N's part of the
                # run apart (minutes at 1e6), so a slow spell of a minute or two on a shared machine
                # costs a cell one round, not all of them.
                for round_index in range(rounds):
                    first = round_index == 0
                    for op in selected:
                        if first:
                            done += 1
                        current = (n, op.name, first)
                        step += 1
                        _progress(f"[{step}/{total * rounds}] N={n} {op.name}"
                                  + (f" (round {round_index + 1} of {rounds})" if rounds > 1 else ""), verbose)
                        _time_op(op, n, inputs, passes, compiled, active, agrees, agreement, records, results,
                                 first, seed, min_run_time, threads)
                        if first:
                            out = op.tq_fn(*(inputs[k] for k in op.args))
                            in_width = sum(inputs[k][0].numel() for k in op.args)
                            # the cheapest of three fresh preallocations: a large copy's time varies run to run
                            # (where its pages land), and the floor is the cheapest pass
                            t = min((_timing.measure(_timing.floor_fn(n, in_width, tuple(out.shape[1:]), dtype, device), min_run_time, threads)
                                     for _ in range(3)), key=lambda timing: timing.median)
                            results.append({"op": op.name, "n": n, "pass": "fwd", "impl": _report.FLOOR, "agrees": None,
                                            "call": "floor", "median_s": t.median, "iqr_s": t.iqr, "runs": t.runs, "error": None})
                            del out
                        current = None  # (finished)
                del inputs, records
        except (KeyboardInterrupt, Exception) as exc:  # (an error, e.g. out of memory at a larger N, keeps the rest too)
            if isinstance(exc, KeyboardInterrupt):
                stopped = "SIGTERM" if str(exc) == "SIGTERM" else "SIGINT"
            else:
                where = f"N={n}" + (f" {current[1]}" if current is not None else "")
                stopped = f"error at {where}: {type(exc).__name__}: {exc}".splitlines()[0][:300]
            if current is not None and current[2]:  # the table keeps every (N, op) timed once; one in its
                done -= 1                             # first round is dropped (a later round keeps the earlier)
                results[:] = [r for r in results if (r["n"], r["op"]) != current[:2]]
    elapsed = time.perf_counter() - started

    import torchquat
    where = (f"{threads} thread(s), {platform.machine()} {_cpu_model()} ({os.cpu_count()} CPUs)" if on_host
             else f"{device.type} device {torch.cuda.get_device_name(device) if device.type == 'cuda' else device}")
    header = [
        "## torchquat bench",
        "",
        f"torchquat {torchquat.__version__}, torch {torch.__version__}, {str(dtype).replace('torch.', '')}, {where}, "
        f"Python {platform.python_version()}",
        f"Medians of torch.utils.benchmark blocked_autorange(min_run_time={min_run_time}) (at least 3 "
        f"measurements); the fastest such median of {rounds} round(s), each of which times every op and "
        "implementation at one N in turn; fwd+bwd = the call plus torch.autograd.grad with a preallocated output gradient.",
        allocator,
        _transposes(),
        "Peers: " + (", ".join(f"{p.name} {p.version} (import {p.import_s:.2f} s)" for p in active) or "none"),
    ]
    if stopped:
        header.append(f"Stopped by {stopped} after {done} of {total} (N, op) measurements: the table holds "
                      "the finished ones (with the rounds that finished).")
    for p in peers:
        if p.error is not None:
            header.append(f"Skipped {p.name}: {p.error.splitlines()[0]} -- install the peers with: {INSTALL_HINT}")
    if compiled:
        header.append(f"{_report.COMPILED}: torchquat with use_compiled_kernels(True); compile time is "
                      "excluded (warm-up calls). speed-up compares eager torchquat; compiled speed-up and "
                      "compiled / floor the compiled kernels.")
    header.append("speed-up = fastest agreeing torch peer / torchquat (SciPy, on NumPy, is not counted); "
                  "≠ = the peer's output differs from torchquat's beyond "
                  f"{tol:g} (compared as matrices on generic rotations): not counted; err = it raised.")
    footer = ["Floor: " + _timing.FLOOR_DEFINITION + ".", "", "Calls timed:"]
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
        footer.append(f"- {op.label}: " + "; ".join(f"{k}: `{v}`" for k, v in calls.items()))
    failures = [a for a in agreement if not a["agrees"]]
    for a in failures:
        footer.append(f"- err {a['impl']} on {a['op']}: the agreement check raised {a['error']}" if a["error"]
                      else f"- ≠ {a['impl']} on {a['op']}: max abs error {a['max_abs_err']}")
    errors = {}
    for r in results:
        if r.get("error"):
            errors.setdefault((r["impl"], r["op"], r["pass"], r["error"]), []).append(f"{r['n']:,}")
    for (impl_name, op_name, pss, error), sizes in errors.items():
        footer.append(f"- err {impl_name} on {op_name} {pss} (N = {', '.join(sizes)}): {error}")
    footer.append(f"Total bench time {elapsed:.0f} s.")

    labels = {op.name: op.label for op in selected}
    print(_report.markdown(results, labels, ns, columns, torch_peers, header, footer), end="")
    if json_path:
        meta = {"torchquat": torchquat.__version__, "torch": torch.__version__, "dtype": str(dtype),
                "threads": threads, "device": str(device), "ns": ns, "compiled": compiled, "min_run_time": min_run_time, "allocator": allocator,
                "floor_definition": _timing.FLOOR_DEFINITION, "machine": platform.platform(),
                "cpus": os.cpu_count(), "cpu": _cpu_model(), "transposes": _transposes(),
                "python": platform.python_version(), "elapsed_s": elapsed,
                "peers": {p.name: {"version": p.version, "import_s": p.import_s, "error": p.error} for p in peers},
                "stopped_by": stopped, "finished": done, "planned": total}
        try:
            _report.write_json(json_path, meta, results, torch_peers, legend, agreement)
        except (OSError, PoseFileError) as exc:
            print(f"torchquat bench: --json {json_path}: {exc}", file=sys.stderr)
            return 2
    if stopped is not None and stopped.startswith("error"):
        print(f"torchquat bench: stopped by an {stopped} (the table has what finished before)", file=sys.stderr)
        return 1
    return {None: 0, "SIGINT": 130, "SIGTERM": 143}[stopped]


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m torchquat.bench",
                                     description="Time torchquat against the installed peer libraries.")
    add_arguments(parser)
    return run(parser.parse_args(argv))
