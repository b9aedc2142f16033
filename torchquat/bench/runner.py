"""Running the benchmark: the peers' agreement check, then every (N, op, pass, implementation)
timed in rounds, stopping cleanly on Ctrl-C, SIGTERM or an error."""

import sys
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import torch

from .. import _signals
from . import ops as _ops
from . import report as _report
from . import timing as _timing
from .options import Settings

__all__ = ["check_peers", "Outcome", "time_all"]


def check_peers(selected, active, dtype: torch.dtype, device) -> Tuple[List[dict], Dict[tuple, bool], float]:
    """Check once per (op, peer), on generic rotations, that the peer computes torchquat's rotation.

    Returns:
        ``(agreement records, {(op, peer): agrees}, the tolerance used)``.
    """
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
            except Exception as exc:  # (shown as err in the table, never a traceback)
                ok, err, error = False, None, f"{type(exc).__name__}: {exc}"
            agrees[(op.name, peer.name)] = ok
            agreement.append({"op": op.name, "impl": peer.name, "agrees": ok, "max_abs_err": err,
                              "tolerance": tol, "error": error})
    return agreement, agrees, tol


def _callable(impl: _ops.Impl, inputs, backward: bool, seed: int):
    """The timed call: the forward alone, or the forward and ``torch.autograd.grad`` with a
    preallocated output gradient."""
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


@dataclass
class Outcome:
    """What a run timed: the records, how far it got and what stopped it."""

    results: List[dict] = field(default_factory=list)
    done: int = 0  # (N, op) pairs timed at least once
    total: int = 0
    stopped: Optional[str] = None  # "SIGINT", "SIGTERM", "error at ...", or None
    elapsed: float = 0.0


@dataclass
class _Round:
    """The fixed parts of one round over the ops at one N."""

    s: Settings
    inputs: dict
    active: list
    agrees: dict
    check_errors: Dict[str, Dict[str, str]]
    records: dict
    results: List[dict]


def _impls(op, rnd: _Round):
    impls = [(_report.TORCHQUAT, _ops.torchquat_impl(op), None)]
    if rnd.s.compiled:
        impls.append((_report.COMPILED, _ops.torchquat_impl(op, compiled=True), None))
    return impls + [(p.name, p.impls[op.name], rnd.agrees.get((op.name, p.name)))
                    for p in rnd.active if op.name in p.impls]


def _record(op, n, pss, name, impl, ok, rnd: _Round, first: bool) -> Optional[dict]:
    """The cell's record, made in the first round; None when it raised in an earlier one."""
    if not first:
        rec = rnd.records[(op.name, pss, name)]
        return None if rec["error"] else rec
    rec = rnd.records[(op.name, pss, name)] = {
        "op": op.name, "n": n, "pass": pss, "impl": name, "call": impl.call, "agrees": ok,
        "median_s": None, "iqr_s": None, "runs": 0, "error": None}
    if name in rnd.check_errors.get(op.name, {}):  # (its output could not be compared: shown as err)
        rec["check_error"] = rnd.check_errors[op.name][name]
    rnd.results.append(rec)
    return rec


def _time_op(op, n, rnd: _Round, first: bool) -> None:
    """One round of ``op`` at ``n``: every implementation's every pass timed once; a record keeps
    the fastest median of its rounds."""
    for pss in rnd.s.passes:
        cells = []  # (record, callable): all set up before any is timed
        for name, impl, ok in _impls(op, rnd):
            if pss == "fwd+bwd" and not impl.backward:
                continue
            rec = _record(op, n, pss, name, impl, ok, rnd, first)
            if rec is None:
                continue
            try:
                fn = _callable(impl, rnd.inputs, pss == "fwd+bwd", rnd.s.seed)
                if name == _report.COMPILED:
                    fn(), fn()  # compile in the first round, warm up in later ones (excluded from the timing)
            except Exception as exc:
                rec["error"], fn = f"{type(exc).__name__}: {exc}"[:300], None
            cells.append((rec, fn))
        for rec, fn in cells:
            if fn is not None:
                _measure_into(rec, fn, rnd.s)
        del cells


def _measure_into(rec: dict, fn, s: Settings) -> None:
    try:
        t = _timing.measure(fn, s.min_run_time, s.threads)
    except Exception as exc:
        rec["error"] = f"{type(exc).__name__}: {exc}"[:300]
        return
    if rec["median_s"] is None or t.median < rec["median_s"]:
        rec.update(median_s=t.median, iqr_s=t.iqr, runs=t.runs, calls=t.calls)


def _floor(op, n, inputs, s: Settings) -> dict:
    """The memory floor of ``op`` at ``n``: the cheapest of three fresh preallocations (a large
    copy's time varies run to run with where its pages land, and the floor is the cheapest pass)."""
    out = op.tq_fn(*(inputs[k] for k in op.args))
    in_width = sum(inputs[k][0].numel() for k in op.args)
    shape = tuple(out.shape[1:])
    del out
    t = min((_timing.measure(_timing.floor_fn(n, in_width, shape, s.dtype, s.device), s.min_run_time, s.threads)
             for _ in range(3)), key=lambda timing: timing.median)
    return {"op": op.name, "n": n, "pass": "fwd", "impl": _report.FLOOR, "agrees": None, "call": "floor",
            "median_s": t.median, "iqr_s": t.iqr, "runs": t.runs, "error": None}


def _progress(text: str, enabled: bool) -> None:
    if enabled:
        print(text, file=sys.stderr, flush=True)


def time_all(s: Settings, selected, active, agrees, agreement) -> Outcome:
    """Time every op at every N in ``s.rounds`` rounds.

    Each round times every op once: a cell's rounds are a fraction of this N's part of the run
    apart, so a slow spell of a minute or two on a shared machine costs a cell one round, not
    all of them. Ctrl-C, SIGTERM or an error (out of memory at a larger N) keeps what finished.

    Returns:
        The :class:`Outcome`.
    """
    outcome = Outcome(total=len(s.ns) * len(selected))
    check_errors: Dict[str, Dict[str, str]] = {}
    for a in agreement:
        if a["error"]:
            check_errors.setdefault(a["op"], {})[a["impl"]] = a["error"]
    n, step, current = None, 0, None  # current: the (N, op, first round?) in progress
    started = time.perf_counter()
    with _signals.sigterm_as_interrupt():
        try:
            for n in s.ns:
                rnd = _Round(s, _ops.make_inputs(n, s.dtype, s.seed, s.device), active, agrees, check_errors, {},
                             outcome.results)
                for round_index in range(s.rounds):
                    first = round_index == 0
                    for op in selected:
                        outcome.done += first
                        current, step = (n, op.name, first), step + 1
                        _progress(f"[{step}/{outcome.total * s.rounds}] N={n} {op.name}"
                                  + (f" (round {round_index + 1} of {s.rounds})" if s.rounds > 1 else ""), s.verbose)
                        _time_op(op, n, rnd, first)
                        if first:
                            outcome.results.append(_floor(op, n, rnd.inputs, s))
                        current = None
                del rnd
        except (KeyboardInterrupt, Exception) as exc:  # (an error keeps the rest too)
            outcome.stopped = _why_stopped(exc, n, current)
            if current is not None and current[2]:  # the table keeps every (N, op) timed once; one in its
                outcome.done -= 1                     # first round is dropped (a later round keeps the earlier)
                outcome.results[:] = [r for r in outcome.results if (r["n"], r["op"]) != current[:2]]
    outcome.elapsed = time.perf_counter() - started
    return outcome


def _why_stopped(exc: BaseException, n, current) -> str:
    if isinstance(exc, KeyboardInterrupt):
        return "SIGTERM" if str(exc) == "SIGTERM" else "SIGINT"
    where = f"N={n}" + (f" {current[1]}" if current is not None else "")
    return f"error at {where}: {type(exc).__name__}: {exc}".splitlines()[0][:300]
