"""The bench's options: checked all at once, before anything is timed.

Each option out of range is a :class:`UsageError` whose message names the option, the range
and the value given; the command prints it as one line and exits with status 2.
"""

import sys
from dataclasses import dataclass
from typing import List, Optional

import torch

from ..io import output_folder_problem
from .ops import OPS, OPS_BY_NAME, has_compiled_kernels
from .peers import PEER_NAMES

__all__ = ["UsageError", "Settings", "settings", "LIMITS", "DTYPES"]

DTYPES = {"float32": torch.float32, "float64": torch.float64}
# Sane ranges: far beyond any useful run, short of an allocation or a loop that never ends.
LIMITS = {"n": (1, 10_000_000), "threads": (1, 1024), "rounds": (1, 1000), "min_run_time": (0.0, 3600.0),
          "seed": (0, 2 ** 63 - 1)}


class UsageError(ValueError):
    """An option out of range; ``str()`` is the one line the command prints."""


@dataclass
class Settings:
    """Everything a run needs, checked."""

    ns: List[int]
    op_names: List[str]
    peer_names: List[str]
    device: torch.device
    dtype: torch.dtype
    threads: int
    min_run_time: float
    rounds: int
    passes: List[str]
    seed: int
    compiled: bool
    verbose: bool
    json_path: Optional[str]
    allocator: str


def unique(values) -> list:
    """``values`` in order, each once (a repeated N or op would be timed twice)."""
    return list(dict.fromkeys(values))


def check_range(option: str, value, low, high) -> None:
    """Raise :class:`UsageError` unless ``low <= value <= high`` (NaN is out of range)."""
    if not low <= value <= high:
        raise UsageError(f"{option} must be from {low:g} to {high:g}, got {value!r}" if isinstance(value, float)
                         else f"{option} must be from {low} to {high}, got {value}")


def settings(args) -> Settings:
    """Check the parsed options (see :func:`torchquat.bench.add_arguments`).

    Args:
        args: an ``argparse.Namespace``; missing options take their defaults.

    Returns:
        The :class:`Settings`.

    Raises:
        UsageError: an option out of range, named in the message.
    """
    json_path = _json_path(getattr(args, "json", None))
    ns = unique(getattr(args, "n", None) or [1, 1000, 1_000_000])
    for n in ns:
        check_range("--n", n, *LIMITS["n"])
    threads, rounds = int(getattr(args, "threads", 1)), int(getattr(args, "rounds", 3))
    min_run_time, seed = float(getattr(args, "min_run_time", 0.2)), int(getattr(args, "seed", 0))
    check_range("--threads", threads, *LIMITS["threads"])
    check_range("--rounds", rounds, *LIMITS["rounds"])
    check_range("--min-run-time", min_run_time, *LIMITS["min_run_time"])
    check_range("--seed", seed, *LIMITS["seed"])
    device = _device(getattr(args, "device", "cpu"))
    verbose = getattr(args, "progress", None)
    return Settings(
        ns=ns, op_names=_op_names(getattr(args, "ops", None)),
        peer_names=_peer_names(getattr(args, "peers", None), device), device=device,
        dtype=DTYPES[getattr(args, "dtype", "float32")], threads=threads, min_run_time=min_run_time, rounds=rounds,
        passes=["fwd", "fwd+bwd"] if getattr(args, "backward", True) else ["fwd"], seed=seed,
        compiled=bool(getattr(args, "compiled", False)) and has_compiled_kernels(),
        verbose=sys.stderr.isatty() if verbose is None else bool(verbose),
        json_path=json_path, allocator=getattr(args, "allocator", "auto"))


def _json_path(path: Optional[str]) -> Optional[str]:
    if path is None:
        return None
    if not path.strip():
        raise UsageError("--json needs a file name")
    problem = output_folder_problem(path)  # (before the run, not after it)
    if problem:
        raise UsageError(f"--json {problem}")
    return path


def _op_names(names: Optional[List[str]]) -> List[str]:
    names = unique(names or [op.name for op in OPS])
    unknown = [name for name in names if name not in OPS_BY_NAME]
    if unknown:
        raise UsageError(f"unknown op(s) {' '.join(map(repr, unknown))} for --ops; choose from "
                         + " ".join(op.name for op in OPS))
    return names


def _peer_names(names: Optional[List[str]], device: torch.device) -> List[str]:
    if names is not None and "none" in names and len(set(names)) > 1:
        raise UsageError("--peers none means torchquat alone: name peers or none, not both")
    names = list(PEER_NAMES) if names is None else unique(p for p in names if p != "none")
    bad = [p for p in names if p not in PEER_NAMES]
    if bad:
        raise UsageError(f"unknown peer(s) {' '.join(map(repr, bad))} for --peers; choose from {' '.join(PEER_NAMES)}")
    if device.type != "cpu":
        names = [p for p in names if p != "scipy"]  # NumPy: its timing would be copies
    return names


def _device(name: str) -> torch.device:
    """The device, after allocating on it: a misspelt name, or CUDA absent, is a usage error."""
    try:
        device = torch.device(name)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError, ValueError, TypeError) as exc:
        why = str(exc).splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UsageError(f"--device {name or repr(name)}: {why}") from None
    return device
