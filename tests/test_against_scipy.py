"""Every conversion against SciPy's ``Rotation`` in float64, on uniform and singular rotations.

Target: max difference <= 1e-12, singular sets included. Quaternions are compared up to sign;
Euler angles as raw angles where they are unique and well conditioned, and as rotations
everywhere (gimbal lock, proper-Euler middle angle at 0 or pi).
"""

import math
import warnings

import numpy as np
import pytest
import torch

import torchquat as tq
from rotation_samples import CONVENTIONS, cube_rotations, lock_angles, singular_and_uniform, uniform

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation
Slerp = pytest.importorskip("scipy.spatial.transform").Slerp

TOL = 1e-12


def sp(q):
    """SciPy rotation of (w, x, y, z) quaternions."""
    return Rotation.from_quat(tq.quat_wxyz_to_xyzw(q).numpy())


def sign_free_error(q, ref):
    ref = torch.as_tensor(ref)
    return torch.minimum((q - ref).abs().amax(-1), (q + ref).abs().amax(-1)).max().item()


def wrapped(a):
    return torch.remainder(a + math.pi, 2 * math.pi) - math.pi


def scipy_euler(rot, convention):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SciPy warns at gimbal lock; we compare its output anyway
        return torch.as_tensor(rot.as_euler(convention))


def test_quat_to_matrix_matches_scipy():
    q = singular_and_uniform()
    assert (tq.quat_to_matrix(q) - torch.as_tensor(sp(q).as_matrix())).abs().max() <= TOL


def test_matrix_to_quat_matches_scipy_with_w_nonnegative():
    R = torch.cat([torch.as_tensor(sp(singular_and_uniform()).as_matrix()), cube_rotations()])
    q = tq.matrix_to_quat(R)
    assert sign_free_error(q, tq.quat_xyzw_to_wxyz(torch.as_tensor(Rotation.from_matrix(R.numpy()).as_quat()))) <= TOL
    assert (q[..., 0] >= 0).all()


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_euler_to_quat_and_matrix_match_scipy(convention):
    g = torch.Generator().manual_seed(0)
    angles = torch.cat([(torch.rand(300, 3, generator=g, dtype=torch.float64) * 2 - 1) * math.pi,
                        lock_angles(convention)[0]])
    ref = Rotation.from_euler(convention, angles.numpy())
    q = tq.euler_to_quat(angles, convention)
    assert sign_free_error(q, tq.quat_xyzw_to_wxyz(torch.as_tensor(ref.as_quat()))) <= TOL
    assert (q[..., 0] >= 0).all()
    assert (tq.euler_to_matrix(angles, convention) - torch.as_tensor(ref.as_matrix())).abs().max() <= TOL


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_euler_degrees_match_scipy(convention):
    angles = torch.tensor([[10.0, 20.0, 30.0], [-170.0, 45.0, 179.0]], dtype=torch.float64)
    ref = Rotation.from_euler(convention, angles.numpy(), degrees=True)
    assert (tq.euler_to_matrix(angles, convention, degrees=True) - torch.as_tensor(ref.as_matrix())).abs().max() <= TOL
    back = tq.quat_to_euler(tq.euler_to_quat(angles, convention, degrees=True), convention, degrees=True)
    assert (wrapped(back * math.pi / 180) - wrapped(torch.as_tensor(ref.as_euler(convention)))).abs().max() <= TOL


def _euler_inputs(convention):
    """Quaternions: uniform, singular, cube rotations, and at/near this convention's lock."""
    locked = tq.quat_xyzw_to_wxyz(torch.as_tensor(Rotation.from_euler(convention, lock_angles(convention)[0].numpy()).as_quat()))
    return torch.cat([singular_and_uniform(), tq.matrix_to_quat(cube_rotations()), locked])


@pytest.mark.parametrize("convention", CONVENTIONS)
@pytest.mark.parametrize("source", ["quat", "matrix"])
def test_to_euler_matches_scipy(convention, source):
    q = _euler_inputs(convention)
    R = tq.quat_to_matrix(q)
    ours = tq.quat_to_euler(q, convention) if source == "quat" else tq.matrix_to_euler(R, convention)
    theirs = scipy_euler(sp(q), convention)
    # As rotations: the angles must reproduce the input everywhere, gimbal lock included
    # (SciPy's own answer reproduces to about the same accuracy at lock, within eps it is ~eps).
    locked = tq.euler_gimbal_lock(q, convention)
    rebuilt = torch.as_tensor(Rotation.from_euler(convention, ours.numpy()).as_matrix())
    err = (rebuilt - R).abs().amax((-2, -1))
    assert err[~locked].max() <= TOL
    assert torch.cat([err[locked], err.new_zeros(1)]).max() <= 4e-7  # within a small multiple of eps = 1e-7
    # As raw angles, the same rule as SciPy's: equal wherever the angles are well conditioned.
    middle = ours[:, 1] if convention[0].lower() == convention[2].lower() else ours[:, 1] + math.pi / 2
    distance_to_lock = torch.minimum(middle.abs(), (math.pi - middle).abs())
    conditioned = distance_to_lock > 1e-3
    diff = wrapped(ours - theirs).abs().amax(-1)
    assert diff[conditioned].max() <= TOL
    # ... and at lock both put the whole rotation in the first angle, with the third 0 (a matrix
    # is tested on its own entries: rows exactly eps from lock may round the other way).
    assert (ours[tq.euler_gimbal_lock(q if source == "quat" else R, convention), 2] == 0).all()
    assert (theirs[locked, 2].abs() <= 1e-12).all()


def test_lock_rule_agrees_with_scipy_on_the_cube_rotations():
    q = tq.matrix_to_quat(cube_rotations())
    for convention in CONVENTIONS:
        ours, theirs = tq.quat_to_euler(q, convention), scipy_euler(sp(q), convention)
        assert (wrapped(ours - theirs).abs() <= 1e-12).all(), convention


def test_axis_angle_matches_scipy():
    q = singular_and_uniform()
    v = tq.quat_to_axis_angle(q)
    ref = torch.as_tensor(sp(q).as_rotvec())
    # At exactly pi the axis sign is a free choice: compare those as rotations.
    angle = ref.norm(dim=-1)
    regular = angle < math.pi - 1e-6
    assert (v[regular] - ref[regular]).abs().max() <= TOL
    assert (tq.axis_angle_to_matrix(v) - tq.quat_to_matrix(q)).abs().max() <= TOL
    assert (v.norm(dim=-1) <= math.pi + 1e-15).all()
    assert (tq.matrix_to_axis_angle(tq.quat_to_matrix(q))[regular] - ref[regular]).abs().max() <= TOL


def test_axis_angle_to_quat_and_matrix_match_scipy():
    g = torch.Generator().manual_seed(4)
    v = torch.cat([torch.randn(300, 3, generator=g, dtype=torch.float64) * 2,  # angles beyond pi too
                   tq.quat_to_axis_angle(singular_and_uniform())])
    ref = Rotation.from_rotvec(v.numpy())
    assert sign_free_error(tq.axis_angle_to_quat(v), tq.quat_xyzw_to_wxyz(torch.as_tensor(ref.as_quat()))) <= TOL
    assert (tq.axis_angle_to_matrix(v) - torch.as_tensor(ref.as_matrix())).abs().max() <= TOL


def test_multiply_rotate_and_distance_match_scipy():
    p, q = singular_and_uniform(), uniform(len(singular_and_uniform()), seed=7)
    assert sign_free_error(tq.quat_multiply(p, q), tq.quat_xyzw_to_wxyz(torch.as_tensor((sp(p) * sp(q)).as_quat()))) <= TOL
    v = torch.randn(len(p), 3, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    assert (tq.quat_rotate(p, v) - torch.as_tensor(sp(p).apply(v.numpy()))).abs().max() <= TOL
    ref = torch.as_tensor((sp(p).inv() * sp(q)).magnitude())
    assert (tq.quat_geodesic_distance(p, q) - ref).abs().max() <= TOL
    assert (tq.matrix_geodesic_distance(tq.quat_to_matrix(p), tq.quat_to_matrix(q)) - ref).abs().max() <= TOL


def test_quat_distance_of_scaled_float32_inputs_is_the_distance_of_their_rotations():
    # no input is normalised: the documented domain is |q1|^2 |q2|^2 a normal float32
    p, q = singular_and_uniform(), uniform(len(singular_and_uniform()), seed=7)
    ref = torch.as_tensor((sp(p).inv() * sp(q)).magnitude())
    for a, b in ((1e-9, 1e-9), (1e9, 1e9), (1e-18, 1.0), (1e18, 1.0), (1e-9, 1e9), (3.0, 0.25)):
        d = tq.quat_geodesic_distance((p * a).float(), (q * b).float())
        assert (d.double() - ref).abs().max() <= 1e-5, (a, b)


def test_distance_at_singular_points_matches_scipy():
    q = singular_and_uniform()
    ident = tq.quat_identity(len(q), dtype=torch.float64)
    ref = torch.as_tensor(sp(q).magnitude())
    assert (tq.quat_geodesic_distance(ident, q) - ref).abs().max() <= TOL
    assert (tq.matrix_geodesic_distance(tq.quat_to_matrix(ident), tq.quat_to_matrix(q)) - ref).abs().max() <= TOL


def test_slerp_matches_scipy():
    q0, q1 = uniform(50, seed=8), uniform(50, seed=9)
    t = torch.linspace(0, 1, 7, dtype=torch.float64)
    for a, b in zip(q0, q1):
        ref = Slerp([0.0, 1.0], sp(torch.stack([a, b])))(t.numpy())
        ours = tq.quat_slerp(a, b, t)
        assert (tq.quat_to_matrix(ours) - torch.as_tensor(ref.as_matrix())).abs().max() <= TOL


def test_rot6d_round_trip_and_gram_schmidt():
    R = tq.quat_to_matrix(singular_and_uniform())
    assert (tq.rot6d_to_matrix(tq.matrix_to_rot6d(R)) - R).abs().max() <= TOL
    x = torch.randn(100, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    a1, a2 = x[:, :3].numpy(), x[:, 3:].numpy()
    b1 = a1 / np.linalg.norm(a1, axis=1, keepdims=True)
    b2 = a2 - np.sum(b1 * a2, axis=1, keepdims=True) * b1
    b2 /= np.linalg.norm(b2, axis=1, keepdims=True)
    ref = np.stack([b1, b2, np.cross(b1, b2)], axis=-1)  # columns
    assert (tq.rot6d_to_matrix(x) - torch.as_tensor(ref)).abs().max() <= TOL


def test_rot9d_is_the_nearest_rotation():
    M = torch.randn(200, 3, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    U, _, Vt = np.linalg.svd(M.numpy())
    d = np.sign(np.linalg.det(U @ Vt))
    ref = U @ (np.eye(3) * np.stack([np.ones_like(d), np.ones_like(d), d], -1)[:, None, :]) @ Vt
    R = tq.rot9d_to_matrix(M)
    assert (R - torch.as_tensor(ref)).abs().max() <= 1e-11
    assert (torch.linalg.det(R) - 1).abs().max() <= TOL
    assert (tq.rot9d_to_matrix(M.flatten(-2)) - R).abs().max() == 0  # row-major 9-vector
