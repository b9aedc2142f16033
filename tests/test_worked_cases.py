"""The worked cases of SPEC section 1, from the aerospace and graphics literature, held exactly."""

import math

import torch

import torchquat as tq


def _angles(n=200, seed=0):
    g = torch.Generator().manual_seed(seed)
    a = (torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
    a[:, 1] = a[:, 1] / 2.2  # keep the middle angle away from gimbal lock
    return a


def same_rotation(q, p, tol=1e-14):
    return torch.minimum((q - p).abs().amax(-1), (q + p).abs().amax(-1)).max() <= tol


def test_zyx_is_the_aerospace_body_321_sequence():
    yaw, pitch, roll = _angles().unbind(-1)
    cy, sy = torch.cos(yaw / 2), torch.sin(yaw / 2)
    cp, sp = torch.cos(pitch / 2), torch.sin(pitch / 2)
    cr, sr = torch.cos(roll / 2), torch.sin(roll / 2)
    expected = torch.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], -1)
    assert same_rotation(tq.euler_to_quat(torch.stack([yaw, pitch, roll], -1), "ZYX"), expected)


def test_intrinsic_zyx_equals_extrinsic_xyz_with_reversed_angles():
    a = _angles()
    assert same_rotation(tq.euler_to_quat(a, "ZYX"), tq.euler_to_quat(a.flip(-1), "xyz"))
    assert (tq.euler_to_matrix(a, "ZYX") - tq.euler_to_matrix(a.flip(-1), "xyz")).abs().max() <= 1e-15


def test_quat_to_zyx_matches_the_textbook_formulas():
    q = tq.euler_to_quat(_angles(seed=1), "ZYX")
    w, x, y, z = q.unbind(-1)
    roll = torch.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = torch.asin(2 * (w * y - z * x))
    yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    assert (tq.quat_to_euler(q, "ZYX") - torch.stack([yaw, pitch, roll], -1)).abs().max() <= 1e-12


def test_heading_attitude_bank_is_intrinsic_yzx():
    heading, attitude, bank = _angles(seed=2).unbind(-1)
    c1, s1 = torch.cos(heading / 2), torch.sin(heading / 2)
    c2, s2 = torch.cos(attitude / 2), torch.sin(attitude / 2)
    c3, s3 = torch.cos(bank / 2), torch.sin(bank / 2)
    expected = torch.stack([c1 * c2 * c3 - s1 * s2 * s3, s1 * s2 * c3 + c1 * c2 * s3,
                            s1 * c2 * c3 + c1 * s2 * s3, c1 * s2 * c3 - s1 * c2 * s3], -1)
    assert same_rotation(tq.euler_to_quat(torch.stack([heading, attitude, bank], -1), "YZX"), expected)


def test_bank_of_90_degrees_alone():
    q = tq.euler_to_quat(torch.tensor([0.0, 0.0, 90.0], dtype=torch.float64), "YZX", degrees=True)
    h = math.sqrt(0.5)
    assert (q - torch.tensor([h, h, 0.0, 0.0], dtype=torch.float64)).abs().max() <= 1e-15


def test_vector_rotation_is_the_sandwich_product_and_the_matrix():
    g = torch.Generator().manual_seed(3)
    q = tq.random_quat(100, generator=g, dtype=torch.float64)
    v = torch.randn(100, 3, generator=g, dtype=torch.float64)
    pure = torch.cat([torch.zeros(100, 1, dtype=torch.float64), v], -1)
    sandwich = tq.quat_multiply(tq.quat_multiply(q, pure), tq.quat_conjugate(q))
    rotated = tq.quat_rotate(q, v)
    assert sandwich[:, 0].abs().max() <= 1e-14
    assert (rotated - sandwich[:, 1:]).abs().max() <= 1e-14
    assert (rotated - (tq.quat_to_matrix(q) @ v.unsqueeze(-1)).squeeze(-1)).abs().max() <= 1e-14
    # the formula of the spec, written out: t = 2 q_vec x v; v' = v + w t + q_vec x t
    t = 2 * torch.linalg.cross(q[:, 1:], v)
    assert (rotated - (v + q[:, :1] * t + torch.linalg.cross(q[:, 1:], t))).abs().max() <= 1e-14


def test_jpl_quaternion_follows_trawny_and_roumeliotis():
    g = torch.Generator().manual_seed(4)
    jpl = tq.random_quat(50, generator=g, dtype=torch.float64)  # read as (x, y, z, w)
    x, y, z, w = jpl.unbind(-1)
    qv = torch.stack([x, y, z], -1)
    skew = torch.zeros(50, 3, 3, dtype=torch.float64)
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -z, y, -x
    skew = skew - skew.mT
    C = (2 * w * w - 1)[:, None, None] * torch.eye(3, dtype=torch.float64) - 2 * w[:, None, None] * skew \
        + 2 * qv.unsqueeze(-1) * qv.unsqueeze(-2)
    assert (tq.quat_to_matrix(tq.quat_from_jpl(jpl)) - C).abs().max() <= 1e-14
    assert (tq.quat_to_jpl(tq.quat_from_jpl(jpl)) - jpl).abs().max() == 0


def test_matrices_act_on_column_vectors():
    R = tq.euler_to_matrix(torch.tensor([90.0, 0.0, 0.0], dtype=torch.float64), "ZYX", degrees=True)
    x_axis = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    assert (R @ x_axis - torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)).abs().max() <= 1e-15


def test_rot6d_holds_the_first_two_columns():
    R = tq.quat_to_matrix(tq.random_quat(10, generator=torch.Generator().manual_seed(5), dtype=torch.float64))
    x = tq.matrix_to_rot6d(R)
    assert torch.equal(x[:, :3], R[:, :, 0]) and torch.equal(x[:, 3:], R[:, :, 1])
