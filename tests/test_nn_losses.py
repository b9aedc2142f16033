"""Losses: match their formulas (computed independently) and reductions; finite gradients at 0 and pi."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torchquat
from torchquat.nn import ChordalLoss, GeodesicLoss, QuatDistanceLoss

REDUCTIONS = ["none", "mean", "sum"]


def _rotations(n, seed):
    """Uniform rotations plus the singular cases: identity pairs and half turns."""
    rng = np.random.default_rng(seed)
    return Rotation.random(n, random_state=rng)


def _wxyz(rot: Rotation) -> torch.Tensor:
    return torch.from_numpy(rot.as_quat()[:, [3, 0, 1, 2]])


def _reduced(per_item: np.ndarray, reduction: str) -> np.ndarray:
    return {"none": per_item, "mean": per_item.mean(), "sum": per_item.sum()}[reduction]


@pytest.mark.parametrize("reduction", REDUCTIONS)
def test_geodesic_matrix_matches_scipy_angle(reduction):
    a, b = _rotations(50, 0), _rotations(50, 1)
    expected = (a.inv() * b).magnitude()
    got = GeodesicLoss("matrix", reduction)(torch.from_numpy(a.as_matrix()), torch.from_numpy(b.as_matrix()))
    np.testing.assert_allclose(got.numpy(), _reduced(expected, reduction), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("reduction", REDUCTIONS)
def test_geodesic_quat_matches_scipy_angle_and_ignores_sign(reduction):
    a, b = _rotations(50, 2), _rotations(50, 3)
    expected = (a.inv() * b).magnitude()
    signs = torch.from_numpy(np.random.default_rng(4).choice([-1.0, 1.0], size=(50, 1)))
    got = GeodesicLoss("quat", reduction)(_wxyz(a) * signs, 3.0 * _wxyz(b))  # non-unit, either sign
    np.testing.assert_allclose(got.numpy(), _reduced(expected, reduction), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("reduction", REDUCTIONS)
def test_quat_distance_is_one_minus_abs_dot_of_unit_quats(reduction):
    rng = np.random.default_rng(5)
    p, q = rng.normal(size=(40, 4)), rng.normal(size=(40, 4))
    unit = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)  # noqa: E731
    expected = 1.0 - np.abs((unit(p) * unit(q)).sum(-1))
    got = QuatDistanceLoss(reduction)(torch.from_numpy(p), torch.from_numpy(q))
    np.testing.assert_allclose(got.numpy(), _reduced(expected, reduction), rtol=1e-12, atol=1e-14)


def test_quat_distance_is_one_minus_cos_half_angle():
    a, b = _rotations(30, 6), _rotations(30, 7)
    angle = (a.inv() * b).magnitude()
    got = QuatDistanceLoss("none")(_wxyz(a), -_wxyz(b))
    np.testing.assert_allclose(got.numpy(), 1.0 - np.cos(angle / 2), atol=1e-12)


@pytest.mark.parametrize("reduction", REDUCTIONS)
def test_chordal_is_squared_frobenius_norm(reduction):
    rng = np.random.default_rng(8)
    A, B = rng.normal(size=(20, 3, 3)), rng.normal(size=(20, 3, 3))  # any matrices: no projection
    expected = ((A - B) ** 2).sum(axis=(-2, -1))
    got = ChordalLoss(reduction)(torch.from_numpy(A), torch.from_numpy(B))
    np.testing.assert_allclose(got.numpy(), _reduced(expected, reduction), rtol=1e-12)


def test_chordal_of_rotations_is_eight_sin_squared_half_angle():
    a, b = _rotations(30, 9), _rotations(30, 10)
    angle = (a.inv() * b).magnitude()
    got = ChordalLoss("none")(torch.from_numpy(a.as_matrix()), torch.from_numpy(b.as_matrix()))
    np.testing.assert_allclose(got.numpy(), 8.0 * np.sin(angle / 2) ** 2, atol=1e-12)


def test_losses_broadcast_batch_shapes():
    q = torchquat.random_quat((2, 1, 5), dtype=torch.float64)
    t = torchquat.random_quat((3, 1), dtype=torch.float64)
    R, T = torchquat.quat_to_matrix(q), torchquat.quat_to_matrix(t)
    g = GeodesicLoss("quat", "none")(q, t)
    assert g.shape == (2, 3, 5)
    torch.testing.assert_close(GeodesicLoss("matrix", "none")(R, T), g)
    assert QuatDistanceLoss("none")(q, t).shape == (2, 3, 5)
    assert ChordalLoss("none")(R, T).shape == (2, 3, 5)
    assert GeodesicLoss()(torch.eye(3), torch.eye(3)).shape == ()  # no batch dims at all


# Singular pairs: equal rotations (zero loss) and half turns about x, y, z and a generic axis.
_AXES = {"x": [1.0, 0, 0], "y": [0, 1.0, 0], "z": [0, 0, 1.0], "generic": [1.0, -2.0, 0.5]}
CASES = ["zero"] + [f"pi-{name}" for name in _AXES]


def _pair(case):
    base = torchquat.random_quat(3, generator=torch.Generator().manual_seed(11), dtype=torch.float64)
    base = torch.cat((torchquat.quat_identity(1, dtype=torch.float64), base))  # identity among them
    if case == "zero":
        return base, base.clone()
    axis = torch.tensor(_AXES[case[3:]], dtype=torch.float64)
    half_turn = torchquat.axis_angle_to_quat(math.pi * axis / axis.norm())
    return base, torchquat.quat_multiply(base, half_turn)


LOSSES = {
    "geodesic-matrix": (lambda r: GeodesicLoss("matrix", r), True),
    "geodesic-quat": (lambda r: GeodesicLoss("quat", r), False),
    "quat-distance": (QuatDistanceLoss, False),
    "chordal": (ChordalLoss, True),
}


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("reduction", REDUCTIONS)
@pytest.mark.parametrize("name", list(LOSSES))
def test_gradients_finite_at_zero_loss_and_at_pi(name, reduction, case):
    make, on_matrices = LOSSES[name]
    q1, q2 = _pair(case)
    if on_matrices:
        q1, q2 = torchquat.quat_to_matrix(q1), torchquat.quat_to_matrix(q2)
    q1.requires_grad_(True)
    q2.requires_grad_(True)
    loss = make(reduction)(q1, q2)
    expected = {"zero": 0.0}.get(case, {"geodesic-matrix": math.pi, "geodesic-quat": math.pi,
                                        "quat-distance": 1.0, "chordal": 8.0}[name])
    torch.testing.assert_close(loss.detach(), _reduced_t(torch.full((4,), expected, dtype=torch.float64), reduction),
                               atol=1e-6, rtol=0)
    loss.sum().backward()
    assert torch.isfinite(q1.grad).all() and torch.isfinite(q2.grad).all()
    if case == "zero":  # the minimum: a zero (sub)gradient, not a push in a random direction
        torch.testing.assert_close(q1.grad, torch.zeros_like(q1), atol=1e-7, rtol=0)


def _reduced_t(x, reduction):
    return {"none": x, "mean": x.mean(), "sum": x.sum()}[reduction]


@pytest.mark.parametrize("name", list(LOSSES))
def test_half_precision_inputs_are_computed_in_float32(name):
    make, on_matrices = LOSSES[name]
    q1 = torchquat.random_quat(16, generator=torch.Generator().manual_seed(12))
    q2 = torchquat.random_quat(16, generator=torch.Generator().manual_seed(13))
    if on_matrices:
        q1, q2 = torchquat.quat_to_matrix(q1), torchquat.quat_to_matrix(q2)
    loss = make("none")
    for dtype in (torch.float16, torch.bfloat16):
        got = loss(q1.to(dtype), q2.to(dtype))
        assert got.dtype == dtype
        reference = loss(q1.to(dtype).float(), q2.to(dtype).float()).to(dtype)  # rounded once at the end
        torch.testing.assert_close(got, reference, rtol=0, atol=0)


def test_autocast_does_not_round_the_geodesic_matmul():
    R1 = torchquat.quat_to_matrix(torchquat.random_quat(64, generator=torch.Generator().manual_seed(14)))
    R2 = R1 @ torchquat.axis_angle_to_matrix(torch.tensor([1e-3, 0.0, 0.0]))  # 1 mrad apart
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = GeodesicLoss("matrix", "none")(R1, R2)
    assert got.dtype == torch.float32
    torch.testing.assert_close(got, torch.full((64,), 1e-3), rtol=1e-3, atol=0)


BAD_LOSSES = [
    (lambda: GeodesicLoss("rot6d"), ValueError,
     "GeodesicLoss: expected representation 'matrix' or 'quat', got 'rot6d'"),
    (lambda: GeodesicLoss(reduction="avg"), ValueError,
     "GeodesicLoss: expected reduction 'none', 'mean' or 'sum', got 'avg'"),
    (lambda: QuatDistanceLoss("batchmean"), ValueError, "QuatDistanceLoss: expected reduction"),
    (lambda: ChordalLoss(None), ValueError, "ChordalLoss: expected reduction 'none', 'mean' or 'sum', got None"),
    (lambda: GeodesicLoss()(torch.zeros(5, 4), torch.zeros(5, 4)), torchquat.ShapeError,
     r"GeodesicLoss: expected input of shape \(\.\.\., 3, 3\), got \(5, 4\)"),
    (lambda: GeodesicLoss("quat")(torch.zeros(5, 4), torch.eye(3)), torchquat.ShapeError,
     r"GeodesicLoss: expected target of shape \(\.\.\., 4\), got \(3, 3\)"),
    (lambda: QuatDistanceLoss()(torch.zeros(2, 4), torch.zeros(3, 4)), torchquat.ShapeError,
     r"QuatDistanceLoss: expected input and target with broadcastable batch shapes, got \(2,\) and \(3,\)"),
    (lambda: ChordalLoss()(torch.zeros(3, 3, dtype=torch.int64), torch.eye(3)), TypeError,
     "ChordalLoss: expected input to be a floating-point tensor"),
    (lambda: ChordalLoss()([[1.0]], torch.eye(3)), TypeError, "ChordalLoss: expected input to be a tensor"),
]


@pytest.mark.parametrize("call,error,message", BAD_LOSSES, ids=[m[:60] for _, _, m in BAD_LOSSES])
def test_bad_input_messages_name_the_loss(call, error, message):
    with pytest.raises(error, match=message):
        call()


def test_zero_quaternion_gives_nan_loss_not_a_crash():
    q = torch.zeros(2, 4)
    q[1, 0] = 1.0
    got = QuatDistanceLoss("none")(q, torch.tensor([1.0, 0.0, 0.0, 0.0]))
    assert torch.isnan(got[0]) and got[1] == 0
    assert torch.isnan(GeodesicLoss("quat", "none")(q, q)[0])


def test_quat_distance_loss_is_never_negative_and_keeps_small_losses():
    # 1 - |<p, q>| was -2.4e-7 for equal float32 inputs, and rounded small losses to multiples of 6e-8
    q = torchquat.random_quat(1000, generator=torch.Generator().manual_seed(7))
    assert QuatDistanceLoss("none")(q, q).min() >= 0.0
    assert QuatDistanceLoss("none")(q, -q).min() >= 0.0
    angles = torch.logspace(-4, -2, 50, dtype=torch.float64)
    axis_angle = angles[:, None] * torch.tensor([0.6, 0.0, 0.8], dtype=torch.float64)
    q1 = torchquat.random_quat(50, generator=torch.Generator().manual_seed(8), dtype=torch.float64)
    q2 = torchquat.quat_multiply(q1, torchquat.axis_angle_to_quat(axis_angle))
    a, b = q1.float(), q2.float()
    # 1 - cos(angle / 2) of the float32 inputs' own angle (their rounding moves it), in float64
    expected = 2.0 * torch.sin(torchquat.quat_geodesic_distance(a.double(), b.double()) / 4) ** 2
    got = QuatDistanceLoss("none")(a, b).double()
    # (normalising each float32 input rounds its components by ~6e-8: a 1e-4 rad loss keeps 2 digits)
    assert ((got - expected).abs() / expected).max() < 2e-2
