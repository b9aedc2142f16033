"""What the benchmark times: the operations, their inputs, torchquat's call for each, and the
check that a peer's call computes the same rotation.

Every implementation gets the *same* rotations (:func:`make_inputs`); the peers' calls, laid out
the way each library expects, are in :mod:`torchquat.bench.peers`.
"""

import math
from dataclasses import dataclass
from typing import Callable, Dict, List, Tuple

import torch

import torchquat as tq

# --------------------------------------------------------------------------------------------
# inputs


def make_inputs(n: int, dtype: torch.dtype, seed: int = 0, device="cpu") -> Dict[str, torch.Tensor]:
    """Random rotations (uniform on SO(3)) and everything derived from them, shape ``(n, ...)``,
    drawn on the CPU (the same rotations on every device) and moved to ``device``."""
    g = torch.Generator().manual_seed(seed)
    q = tq.random_quat(n, generator=g, dtype=torch.float64)
    q2 = tq.random_quat(n, generator=g, dtype=torch.float64)
    data = {
        "q": q,
        "q2": q2,
        "R": tq.quat_to_matrix(q),
        "R2": tq.quat_to_matrix(q2),
        "e_ZYX": tq.quat_to_euler(q, "ZYX"),
        "e_ZXZ": tq.quat_to_euler(q, "ZXZ"),
        "aa": tq.quat_to_axis_angle(q),
        "v": torch.randn(n, 3, generator=g, dtype=torch.float64),
        "x6": torch.randn(n, 6, generator=g, dtype=torch.float64),  # any 6 numbers, not orthonormal
    }
    return {k: t.to(device, dtype).contiguous() for k, t in data.items()}


# --------------------------------------------------------------------------------------------
# operations


@dataclass
class Impl:
    """One library's implementation of one operation."""

    fn: Callable                      # fn(*inputs) -> output (a tensor, LieTensor, tuple, ndarray)
    prep: Callable                    # prep(inputs: dict) -> tuple of this library's inputs
    call: str                         # the call, as written in the legend
    to_tq: Callable = lambda out: out  # output -> torchquat's layout (sanity check only)
    note: str = ""                    # anything the timed region does beyond the call
    backward: bool = True             # False: forward only (SciPy)


@dataclass
class Op:
    name: str          # the --ops identifier
    label: str         # the table's label
    args: Tuple[str, ...]  # keys of make_inputs, in torchquat's argument order
    kind: str          # how outputs are compared: quat, matrix, euler:SEQ, axis_angle, vector, scalar
    tq_fn: Callable
    tq_call: str


def _op(name, label, args, kind, fn, call):
    return Op(name, label, tuple(args), kind, fn, call)


OPS: List[Op] = [
    _op("quat_to_matrix", "quat -> matrix", ["q"], "matrix", tq.quat_to_matrix, "quat_to_matrix(q)"),
    _op("matrix_to_quat", "matrix -> quat", ["R"], "quat", tq.matrix_to_quat, "matrix_to_quat(R)"),
    _op("euler_to_quat_ZYX", "Euler ZYX -> quat", ["e_ZYX"], "quat",
        lambda e: tq.euler_to_quat(e, "ZYX"), 'euler_to_quat(e, "ZYX")'),
    _op("quat_to_euler_ZYX", "quat -> Euler ZYX", ["q"], "euler:ZYX",
        lambda q: tq.quat_to_euler(q, "ZYX"), 'quat_to_euler(q, "ZYX")'),
    _op("euler_to_matrix_ZYX", "Euler ZYX -> matrix", ["e_ZYX"], "matrix",
        lambda e: tq.euler_to_matrix(e, "ZYX"), 'euler_to_matrix(e, "ZYX")'),
    _op("matrix_to_euler_ZYX", "matrix -> Euler ZYX", ["R"], "euler:ZYX",
        lambda R: tq.matrix_to_euler(R, "ZYX"), 'matrix_to_euler(R, "ZYX")'),
    _op("euler_to_quat_ZXZ", "Euler ZXZ -> quat", ["e_ZXZ"], "quat",
        lambda e: tq.euler_to_quat(e, "ZXZ"), 'euler_to_quat(e, "ZXZ")'),
    _op("quat_to_euler_ZXZ", "quat -> Euler ZXZ", ["q"], "euler:ZXZ",
        lambda q: tq.quat_to_euler(q, "ZXZ"), 'quat_to_euler(q, "ZXZ")'),
    _op("euler_to_matrix_ZXZ", "Euler ZXZ -> matrix", ["e_ZXZ"], "matrix",
        lambda e: tq.euler_to_matrix(e, "ZXZ"), 'euler_to_matrix(e, "ZXZ")'),
    _op("matrix_to_euler_ZXZ", "matrix -> Euler ZXZ", ["R"], "euler:ZXZ",
        lambda R: tq.matrix_to_euler(R, "ZXZ"), 'matrix_to_euler(R, "ZXZ")'),
    _op("quat_rotate", "rotate vectors", ["q", "v"], "vector", tq.quat_rotate, "quat_rotate(q, v)"),
    _op("axis_angle_to_quat", "axis-angle -> quat", ["aa"], "quat", tq.axis_angle_to_quat,
        "axis_angle_to_quat(v)"),
    _op("quat_to_axis_angle", "quat -> axis-angle", ["q"], "axis_angle", tq.quat_to_axis_angle,
        "quat_to_axis_angle(q)"),
    _op("axis_angle_to_matrix", "axis-angle -> matrix", ["aa"], "matrix", tq.axis_angle_to_matrix,
        "axis_angle_to_matrix(v)"),
    _op("matrix_to_axis_angle", "matrix -> axis-angle", ["R"], "axis_angle", tq.matrix_to_axis_angle,
        "matrix_to_axis_angle(R)"),
    _op("quat_multiply", "quat product", ["q", "q2"], "quat", tq.quat_multiply, "quat_multiply(p, q)"),
    _op("rot6d_to_matrix", "6D -> matrix", ["x6"], "matrix", tq.rot6d_to_matrix, "rot6d_to_matrix(x)"),
    _op("quat_geodesic_distance", "geodesic distance (quat)", ["q", "q2"], "scalar",
        tq.quat_geodesic_distance, "quat_geodesic_distance(q1, q2)"),
    _op("matrix_geodesic_distance", "geodesic distance (matrix)", ["R", "R2"], "scalar",
        tq.matrix_geodesic_distance, "matrix_geodesic_distance(R1, R2)"),
]
OPS_BY_NAME: Dict[str, Op] = {op.name: op for op in OPS}


def torchquat_impl(op: Op, compiled: bool = False) -> Impl:
    """torchquat's call; ``compiled``: with ``torchquat.use_compiled_kernels(True)`` around it."""
    prep = lambda d: tuple(d[k] for k in op.args)  # noqa: E731
    if not compiled:
        return Impl(op.tq_fn, prep, "torchquat." + op.tq_call)

    def fn(*args):
        previous = tq.compiled_kernels_enabled()
        tq.use_compiled_kernels(True)
        try:
            return op.tq_fn(*args)
        finally:
            tq.use_compiled_kernels(previous)

    return Impl(fn, prep, "torchquat." + op.tq_call + " with use_compiled_kernels(True)",
                note="torch.compile'd kernels; compile time excluded (warm-up calls)")


def has_compiled_kernels() -> bool:
    """Whether this torchquat has the compiled-kernels switch."""
    return hasattr(tq, "use_compiled_kernels") and hasattr(tq, "compiled_kernels_enabled")


# --------------------------------------------------------------------------------------------
# sanity check: does a peer compute the same rotation?


def as_matrix(x: torch.Tensor, kind: str) -> torch.Tensor:
    """Map an output of the given kind to something comparable entry by entry."""
    x = x.to(torch.float64)
    if kind == "quat":
        return tq.quat_to_matrix(x)
    if kind.startswith("euler:"):
        return tq.euler_to_matrix(x, kind.split(":", 1)[1])
    if kind == "axis_angle":
        return tq.axis_angle_to_matrix(x)
    return x


def check_agreement(op: Op, impl: Impl, inputs: Dict[str, torch.Tensor], tol: float) -> Tuple[bool, float]:
    """Max abs difference, compared as matrices (or vectors/angles), against torchquat's output."""
    ref = as_matrix(op.tq_fn(*(inputs[k] for k in op.args)), op.kind)
    with torch.no_grad():
        out = impl.to_tq(impl.fn(*impl.prep(inputs)))
    if hasattr(out, "tensor") and not isinstance(out, torch.Tensor):
        out = out.tensor()
    out = torch.as_tensor(out)
    if hasattr(out, "tensor"):  # a LieTensor that to_tq left alone
        out = out.tensor()
    out = as_matrix(torch.Tensor.as_subclass(out, torch.Tensor), op.kind)
    if out.shape != ref.shape:
        return False, math.inf
    err = float((out - ref).abs().max())
    return err <= tol, err


def make_check_inputs(dtype: torch.dtype, n: int = 256, seed: int = 12345, device="cpu") -> Dict[str, torch.Tensor]:
    """Inputs for the sanity check: generic rotations, at least 10 degrees from gimbal lock in
    both Euler conventions, because libraries snap to the lock at different distances
    (PyPose within about 1.1 degrees, kornia within 0.04 degrees in float32) by design, and
    pairs 10 to 170 degrees apart, because acos-based distances (pytorch-kinematics clamps the
    cosine to 1 - 1e-4) lose up to 0.014 rad next to 0 and pi by design."""
    data = make_inputs(4 * n, torch.float64, seed)
    distance = tq.quat_geodesic_distance(data["q"], data["q2"])
    keep = (data["e_ZYX"][:, 1].abs() < math.radians(80.0)) & (
        (data["e_ZXZ"][:, 1] - math.pi / 2).abs() < math.radians(80.0)) & (
        (distance - math.pi / 2).abs() < math.radians(80.0))
    rows = keep.nonzero().squeeze(-1)[:n]
    return {k: t[rows].to(device, dtype).contiguous() for k, t in data.items()}
