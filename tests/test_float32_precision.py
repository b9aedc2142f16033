"""float32 accuracy where other libraries lose it: round trips within 1e-6 everywhere, gimbal
lock and its neighbourhood included (PyTorch3D's asin path reaches 1e-4 there), and a rotation
exactly at lock is detected in float32 as in float64."""

import math

import pytest
import torch

import torchquat as tq
from rotation_samples import CONVENTIONS, cube_rotations, lock_angles, singular_and_uniform

F32 = torch.float32


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_matrix_euler_round_trip_within_1e6_near_lock(convention):
    angles, _ = lock_angles(convention, n=20)
    R64 = torch.cat([tq.euler_to_matrix(angles, convention), tq.quat_to_matrix(singular_and_uniform())])
    R = R64.to(F32)
    back = tq.euler_to_matrix(tq.matrix_to_euler(R, convention), convention)
    err = (back.double() - R.double()).abs().amax((-2, -1))
    locked = tq.euler_gimbal_lock(R, convention)  # the matrix's own lock test
    # Outside the lock band (exactly at lock, and 1e-5 rad away and beyond) within 1e-6 ...
    assert err[~locked].max() <= 1e-6
    # ... inside it (eps = 1e-6) SciPy's rule drops up to ~2 eps of the rotation, no more.
    assert torch.cat([err[locked], err.new_zeros(1)]).max() <= 2.5e-6
    exactly, _ = lock_angles(convention, n=20)
    assert locked[: len(exactly)].any()


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_lock_detected_exactly_at_lock_in_both_dtypes(convention):
    angles, offset = lock_angles(convention, n=5)
    at_lock = angles[offset == 0]
    for dtype in (torch.float64, F32):
        q = tq.euler_to_quat(at_lock.to(dtype), convention)
        assert tq.euler_gimbal_lock(q, convention).all()
        out = tq.quat_to_euler(q, convention)
        assert (out[:, 2] == 0).all()
    q = tq.matrix_to_quat(cube_rotations().to(F32))
    for dtype in (torch.float64, F32):
        assert torch.equal(tq.euler_gimbal_lock(q.to(dtype), convention),
                           tq.euler_gimbal_lock(tq.matrix_to_quat(cube_rotations()), convention))


def test_away_from_lock_is_not_flagged():
    angles, offset = lock_angles("ZYX", n=20)
    q = tq.euler_to_quat(angles[offset >= 1e-5].to(F32), "ZYX")
    assert not tq.euler_gimbal_lock(q, "ZYX").any()


def test_quaternion_matrix_round_trip_float32():
    q = singular_and_uniform().to(F32)
    back = tq.matrix_to_quat(tq.quat_to_matrix(q))
    err = torch.minimum((back - q).abs().amax(-1), (back + q).abs().amax(-1))
    assert err.max() <= 3e-7


def test_axis_angle_float32_at_tiny_and_half_turn_angles():
    q = singular_and_uniform().to(F32)
    v = tq.quat_to_axis_angle(q)
    assert (tq.axis_angle_to_matrix(v) - tq.quat_to_matrix(q)).abs().max() <= 1e-6
    tiny = torch.tensor([1e-30, 1e-20, 1e-8, 1e-4], dtype=F32)
    v = torch.stack([tiny, torch.zeros_like(tiny), torch.zeros_like(tiny)], -1)
    assert torch.equal(tq.quat_to_axis_angle(tq.axis_angle_to_quat(v)), v)
    assert math.isclose(tq.axis_angle_to_quat(v)[-1, 1].item(), 5e-5, rel_tol=1e-6)


_MKLDNN_MATMUL = getattr(getattr(torch.backends, "mkldnn", None), "matmul", None)


@pytest.mark.skipif(not hasattr(_MKLDNN_MATMUL, "fp32_precision"), reason="this torch has no CPU fp32 matmul precision switch")
@pytest.mark.parametrize("precision", ["bf16", "tf32"])
def test_float32_accuracy_holds_when_the_user_allows_reduced_precision_matmuls(precision):
    # A user who lets float32 matmuls run in bf16 or tf32 for a network must not get rotations
    # good to 1e-3 (the formulas use no matmul; rot9d's SVD and products run with autocast off).
    previous = _MKLDNN_MATMUL.fp32_precision
    g = torch.Generator().manual_seed(5)
    try:
        _MKLDNN_MATMUL.fp32_precision = precision
        for n in (1, 300, 40_007):
            q = tq.random_quat(n, generator=g, dtype=torch.float64)
            q2, R = tq.random_quat(n, generator=g, dtype=torch.float64), tq.quat_to_matrix(q)
            for fn, args in ((tq.quat_to_matrix, (q,)), (tq.matrix_to_quat, (R,)), (tq.quat_multiply, (q, q2)),
                             (lambda x: tq.quat_to_euler(x, "ZYX"), (q,)), (lambda x: tq.matrix_to_euler(x, "zxz"), (R,)),
                             (tq.quat_rotate, (q, R[..., 0])), (tq.matrix_geodesic_distance, (R, tq.quat_to_matrix(q2)))):
                expected = fn(*args)
                got = fn(*(a.to(F32) for a in args)).double()
                difference = got - expected
                if difference.dim() == 2 and difference.shape[-1] == 3 and fn is not tq.quat_rotate:  # angles
                    difference = torch.remainder(difference + math.pi, 2 * math.pi) - math.pi
                assert difference.abs().max() < 2e-5, (precision, n)
    finally:
        _MKLDNN_MATMUL.fp32_precision = previous


@pytest.mark.parametrize("angle", [1e3, 1e6, 1e9, -7.3e5 - 0.25])
def test_large_angles_in_degrees_keep_their_rotation(angle):
    # degrees were multiplied by pi / 180 first: 1e6 degrees in float32 came out 1e-3 rad off (the
    # fraction of a turn rounded away); fmod by 360 first is exact
    from scipy.spatial.transform import Rotation
    e = torch.tensor([angle, 10.0, 20.0])
    expected = torch.from_numpy(Rotation.from_euler("ZYX", e.double().numpy() % 360, degrees=True).as_matrix())
    for R in (tq.euler_to_matrix(e, "ZYX", degrees=True), tq.quat_to_matrix(tq.euler_to_quat(e, "ZYX", degrees=True)),
              tq.convert(e, "euler:ZYX", "matrix", degrees=True)):
        torch.testing.assert_close(R.double(), expected, rtol=0, atol=5e-7)


def test_angles_within_a_turn_in_degrees_are_converted_as_before():
    e = torch.tensor([[359.9, -0.001, 45.0], [-359.9, 89.9, -180.0]])
    expected = tq.euler_to_quat(e * (torch.pi / 180), "ZYX")
    assert torch.equal(tq.euler_to_quat(e, "ZYX", degrees=True), expected)
