"""The markdown table and the JSON file."""

from typing import Dict, List, Optional, Sequence

from ..io.streaming import write_json as atomic_json

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
    data = {"meta": meta, "results": results, "summary": summarize(results, torch_peers),
            "agreement": agreement, "legend": legend}
    atomic_json(path, data)
