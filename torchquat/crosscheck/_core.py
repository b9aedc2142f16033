"""Rows, error metrics and the report table of the cross-check."""

import math
from dataclasses import asdict, dataclass
from typing import Callable, List, Sequence, Tuple

import torch
from torch import Tensor

F64 = torch.float64
HALF_TURN_BAND = 1e-6  # rotation vectors this close to pi may be negated (v and -v agree)


@dataclass
class Row:
    """One line of the report: the worst error of one function on one case against one oracle."""

    function: str
    case: str
    oracle: str
    metric: str
    error: float
    tolerance: float
    note: str = ""

    @property
    def passed(self) -> bool:
        """Within tolerance (NaN and inf never are)."""
        return math.isfinite(self.error) and self.error <= self.tolerance

    def as_dict(self) -> dict:
        """The row as JSON-ready data, with its status."""
        return dict(asdict(self), error=self.error if math.isfinite(self.error) else str(self.error),
                    status="PASS" if self.passed else "FAIL")


class Context:
    """Where the checks run: the dtype torchquat computes in, and the rows collected so far.

    torchquat gets inputs rounded to ``dtype``; the oracles always get the same rounded
    values in float64, so an error measures torchquat's accuracy in ``dtype``.
    """

    def __init__(self, dtype: torch.dtype):
        self.dtype = dtype
        self.rows: List[Row] = []

    def split(self, x: Tensor) -> Tuple[Tensor, Tensor]:
        """``(x in dtype for torchquat, the same values in float64 for the oracle)``."""
        ours = x.to(self.dtype)
        return ours, ours.to(F64)

    def tol(self, tolerances: Tuple[float, float]) -> float:
        """Pick the float64 or the float32 tolerance of a ``(tol64, tol32)`` pair."""
        return tolerances[0] if self.dtype == F64 else tolerances[1]

    def check(self, function: str, case: str, oracle: str, metric: str,
              tolerances: Tuple[float, float], compute: Callable[[], float], note: str = "") -> None:
        """Run ``compute`` (which returns the max error) and record the row; an exception is
        recorded as a failure with its message rather than stopping the run."""
        try:
            error = float(compute())
        except Exception as exc:  # noqa: BLE001 - reported in the table, never swallowed
            error, note = math.inf, f"{type(exc).__name__}: {exc}".splitlines()[0][:120]
        self.rows.append(Row(function, case, oracle, metric, error, self.tol(tolerances), note))


def _max(err: Tensor) -> float:
    err = torch.nan_to_num(err.to(F64), nan=math.inf)
    return float(err.max()) if err.numel() else 0.0


def _same_shape(a: Tensor, b: Tensor) -> None:
    if a.shape != b.shape:
        raise ValueError(f"shape {tuple(a.shape)} != oracle's {tuple(b.shape)}")


def err_abs(ours: Tensor, ref: Tensor) -> float:
    """Largest absolute difference of any entry."""
    _same_shape(ours, ref)
    return _max((ours.to(F64) - ref.to(F64)).abs())


def err_quat(ours: Tensor, ref: Tensor) -> float:
    """Largest entry difference between quaternions up to sign (q and -q are one rotation)."""
    _same_shape(ours, ref)
    ours, ref = ours.to(F64), ref.to(F64)
    plus = (ours - ref).abs().amax(-1)
    minus = (ours + ref).abs().amax(-1)
    return _max(torch.minimum(plus, torch.nan_to_num(minus, nan=math.inf)))


def err_angles(ours: Tensor, ref: Tensor) -> float:
    """Largest angle difference, wrapped to [-pi, pi] (so -pi and pi agree)."""
    _same_shape(ours, ref)
    d = ours.to(F64) - ref.to(F64)
    return _max(torch.remainder(d + math.pi, 2 * math.pi).sub(math.pi).abs())


def err_rotvec(ours: Tensor, ref: Tensor) -> float:
    """Largest entry difference of rotation vectors; at a half turn ``v`` and ``-v`` are the same
    rotation, so there the smaller of the two differences counts."""
    _same_shape(ours, ref)
    ours, ref = ours.to(F64), ref.to(F64)
    plus = (ours - ref).abs().amax(-1)
    minus = (ours + ref).abs().amax(-1)
    at_pi = ref.norm(dim=-1) > math.pi - HALF_TURN_BAND
    return _max(torch.where(at_pi, torch.minimum(plus, minus), plus))


def _fmt(x: float) -> str:
    return f"{x:.1e}" if math.isfinite(x) else str(x)


def format_table(rows: Sequence[Row], failures_only: bool = False) -> str:
    """The markdown table: function, case, oracle, metric, max error, tolerance, status."""
    header = ("function", "case", "oracle", "metric", "max error", "tolerance", "status")
    body = [(r.function, r.case, r.oracle, r.metric, _fmt(r.error), _fmt(r.tolerance),
             ("PASS" if r.passed else "FAIL") + (f" ({r.note})" if r.note else ""))
            for r in rows if not (failures_only and r.passed)]
    widths = [max(len(line[i]) for line in [header] + body) for i in range(len(header))]

    def line(cells) -> str:
        return "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths)) + " |"

    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(header), rule] + [line(b) for b in body])


def family_summary(rows: Sequence[Row]) -> str:
    """One line per (function, oracle, metric): the worst error over all its cases."""
    worst = {}
    for r in rows:
        key = (r.function, r.oracle, r.metric)
        if key not in worst or not r.error <= worst[key].error:
            worst[key] = r
    return format_table(
        [Row(r.function, f"worst of {sum(1 for x in rows if (x.function, x.oracle, x.metric) == k)}"
             f": {r.case}", r.oracle, r.metric, r.error, r.tolerance, r.note)
         for k, r in worst.items()])


class Once:
    """Compute on first call and keep the value, so that two rows share one call to torchquat
    and each still records an exception as its own failure."""

    def __init__(self, compute: Callable[[], Tensor]):
        self.compute, self.done, self.value = compute, False, None

    def __call__(self) -> Tensor:
        if not self.done:
            self.value, self.done = self.compute(), True
        return self.value
