"""The markdown table, its header and footer, and the JSON file."""

import os
import platform
from typing import Dict, List, Optional, Sequence

import torch

import torchquat

from ..io import write_json as atomic_json
from .timing import FLOOR_DEFINITION

TORCHQUAT = "torchquat"
COMPILED = "torchquat compiled"
FLOOR = "floor"
PASSES = ("fwd", "fwd+bwd")


def fmt_time(seconds: Optional[float]) -> str:
    if seconds is None:
        return "—"
    if seconds < 1e-3:
        return f"{seconds * 1e6:.1f} us"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"


def fmt_ratio(x: Optional[float]) -> str:
    if x is None:
        return "—"
    return f"{x:.1f}x" if x >= 0.95 else f"{x:.2f}x"


def index(results: List[dict]) -> Dict[tuple, dict]:
    return {(r["op"], r["n"], r["pass"], r["impl"]): r for r in results}


def fastest_peer(idx, op, n, pss, torch_peers) -> Optional[dict]:
    """The fastest torch peer cell that ran and agreed with torchquat."""
    best = None
    for peer in torch_peers:
        r = idx.get((op, n, pss, peer))
        if r is None or r.get("median_s") is None or r.get("agrees") is False:
            continue
        if best is None or r["median_s"] < best["median_s"]:
            best = r
    return best


def summarize(results: List[dict], torch_peers: Sequence[str]) -> List[dict]:
    """One row per (op, N, pass): torchquat, the fastest agreeing peer, the speed-up, the floor."""
    idx = index(results)
    keys = []
    for r in results:
        key = (r["op"], r["n"], r["pass"])
        if key not in keys:
            keys.append(key)
    rows = []
    for op, n, pss in keys:
        mine = idx.get((op, n, pss, TORCHQUAT))
        best = fastest_peer(idx, op, n, pss, torch_peers)
        floor = idx.get((op, n, "fwd", FLOOR)) if pss == "fwd" else None
        t = mine.get("median_s") if mine else None
        compiled = idx.get((op, n, pss, COMPILED))
        c = compiled.get("median_s") if compiled else None
        rows.append({
            "op": op, "n": n, "pass": pss, "torchquat_s": t,
            "fastest_peer": best["impl"] if best else None,
            "fastest_peer_s": best["median_s"] if best else None,
            "speedup": best["median_s"] / t if best and t else None,
            "floor_s": floor["median_s"] if floor else None,
            "over_floor": t / floor["median_s"] if floor and t and floor.get("median_s") else None,
            "compiled_s": c,
            "compiled_speedup": best["median_s"] / c if best and c else None,
            "compiled_over_floor": c / floor["median_s"] if floor and c and floor.get("median_s") else None,
        })
    return rows


def _cell(r: Optional[dict]) -> str:
    if r is None:
        return "—"
    if r.get("error") or r.get("check_error"):  # (it raised, or its agreement check did)
        return "err"
    text = fmt_time(r.get("median_s"))
    if r.get("agrees") is False:
        return "≠ " + text
    return text


def markdown(results: List[dict], labels: Dict[str, str], ns: Sequence[int], peers: Sequence[str],
             torch_peers: Sequence[str], header: Sequence[str], footer: Sequence[str]) -> str:
    idx = index(results)
    summary = {(s["op"], s["n"], s["pass"]): s for s in summarize(results, torch_peers)}
    ops = []
    for r in results:
        if r["op"] not in ops:
            ops.append(r["op"])
    with_compiled = any(r["impl"] == COMPILED for r in results)
    cols = ["op", "pass", TORCHQUAT] + list(peers) + ["fastest peer", "speed-up", "floor", "torchquat / floor"]
    if with_compiled:
        cols += ["compiled speed-up", "compiled / floor"]
    lines = list(header)
    for n in ns:
        lines += ["", f"### N = {n:,}", "", "| " + " | ".join(cols) + " |",
                  "|" + "|".join(["---"] * 2 + ["---:"] * (len(cols) - 2)) + "|"]
        for op in ops:
            for pss in PASSES:
                s = summary.get((op, n, pss))
                if s is None:
                    continue
                cells = [labels.get(op, op), pss, _cell(idx.get((op, n, pss, TORCHQUAT)))]
                cells += [_cell(idx.get((op, n, pss, p))) for p in peers]
                cells += [s["fastest_peer"] or "—", fmt_ratio(s["speedup"]),
                          fmt_time(s["floor_s"]), fmt_ratio(s["over_floor"])]
                if with_compiled:
                    cells += [fmt_ratio(s["compiled_speedup"]), fmt_ratio(s["compiled_over_floor"])]
                lines.append("| " + " | ".join(cells) + " |")
    lines += [""] + list(footer)
    return "\n".join(lines) + "\n"


def write_json(path: str, meta: dict, results: List[dict], torch_peers: Sequence[str], legend: dict,
               agreement: List[dict]) -> None:
    """Write every number of the run to ``path`` (atomically: a failed write keeps an old file)."""
    data = {"meta": meta, "results": results, "summary": summarize(results, torch_peers),
            "agreement": agreement, "legend": legend}
    atomic_json(path, data)


def cpu_model() -> str:
    """The CPU's model name (Linux: /proc/cpuinfo; elsewhere ``platform.processor()``), or ``""``."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as stream:
            for line in stream:
                if line.lower().startswith("model name"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or ""


def where(s) -> str:
    """The machine the run timed (threads and CPU, or the device)."""
    if s.device.type == "cpu":
        return f"{s.threads} thread(s), {platform.machine()} {cpu_model()} ({os.cpu_count()} CPUs)"
    name = torch.cuda.get_device_name(s.device) if s.device.type == "cuda" else s.device
    return f"{s.device.type} device {name}"


def header(s, allocator: str, peers, active, outcome, tol: float, install_hint: str) -> List[str]:
    """The lines above the tables: versions, machine, method, peers, and how the run ended."""
    lines = [
        "## torchquat bench",
        "",
        f"torchquat {torchquat.__version__}, torch {torch.__version__}, {str(s.dtype).replace('torch.', '')}, "
        f"{where(s)}, Python {platform.python_version()}",
        f"Medians of torch.utils.benchmark blocked_autorange(min_run_time={s.min_run_time}) (at least 3 "
        f"measurements); the fastest such median of {s.rounds} round(s), each of which times every op and "
        "implementation at one N in turn; fwd+bwd = the call plus torch.autograd.grad with a preallocated output gradient.",
        allocator,
        "Peers: " + (", ".join(f"{p.name} {p.version} (import {p.import_s:.2f} s)" for p in active) or "none"),
    ]
    if outcome.stopped:
        lines.append(f"Stopped by {outcome.stopped} after {outcome.done} of {outcome.total} (N, op) measurements: "
                     "the table holds the finished ones (with the rounds that finished).")
    lines += [f"Skipped {p.name}: {p.error.splitlines()[0]} -- install the peers with: {install_hint}"
              for p in peers if p.error is not None]
    if s.compiled:
        lines.append(f"{COMPILED}: torchquat with use_compiled_kernels(True); compile time is "
                     "excluded (warm-up calls). speed-up compares eager torchquat; compiled speed-up and "
                     "compiled / floor the compiled kernels.")
    lines.append("speed-up = fastest agreeing torch peer / torchquat (SciPy, on NumPy, is not counted); "
                 "≠ = the peer's output differs from torchquat's beyond "
                 f"{tol:g} (compared as matrices on generic rotations): not counted; err = it raised.")
    return lines


def footer(legend: Dict[str, Dict[str, str]], labels: Dict[str, str], agreement: List[dict], results: List[dict],
           elapsed: float) -> List[str]:
    """The lines below the tables: the floor, every call timed, disagreements and errors."""
    lines = ["Floor: " + FLOOR_DEFINITION + ".", "", "Calls timed:"]
    lines += [f"- {labels[op]}: " + "; ".join(f"{k}: `{v}`" for k, v in calls.items()) for op, calls in legend.items()]
    for a in agreement:
        if not a["agrees"]:
            lines.append(f"- err {a['impl']} on {a['op']}: the agreement check raised {a['error']}" if a["error"]
                         else f"- ≠ {a['impl']} on {a['op']}: max abs error {a['max_abs_err']}")
    errors: Dict[tuple, List[str]] = {}
    for r in results:
        if r.get("error"):
            errors.setdefault((r["impl"], r["op"], r["pass"], r["error"]), []).append(f"{r['n']:,}")
    for (impl_name, op_name, pss, error), sizes in errors.items():
        lines.append(f"- err {impl_name} on {op_name} {pss} (N = {', '.join(sizes)}): {error}")
    lines.append(f"Total bench time {elapsed:.0f} s.")
    return lines
