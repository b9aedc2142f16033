"""torchquat against ``pytorch_kinematics.transforms`` (PyTorch3D's conventions plus tf's
``quaternion_from_euler``), in float64 on uniform and singular rotations.

pytorch-kinematics is itself inexact in places (square roots at 180 degrees, ``asin`` near
gimbal lock), so rotations are compared as matrices where the representation is not unique and
the tolerances say what the oracle can do.
"""

import math

import pytest
import torch

import torchquat as tq
from rotation_samples import INTRINSIC, lock_angles, singular_and_uniform, uniform

pkt = pytest.importorskip("pytorch_kinematics.transforms.rotation_conversions")

F64 = torch.float64
TF_AXES = [f"{frame}{seq}" for frame in "sr" for seq in
           ["xyz", "xyx", "xzy", "xzx", "yzx", "yzy", "yxz", "yxy", "zxy", "zxz", "zyx", "zyz"]]


def sign_free(a, b):
    return torch.minimum((a - b).abs().amax(-1), (a + b).abs().amax(-1)).max()


def test_quat_to_matrix_and_back():
    q = singular_and_uniform()
    assert (tq.quat_to_matrix(q) - pkt.quaternion_to_matrix(q)).abs().max() <= 1e-14
    R = tq.quat_to_matrix(q)
    # pk takes square roots of 1 + tr-like terms: about 1e-8 accurate near 180 degrees.
    assert sign_free(tq.matrix_to_quat(R), pkt.matrix_to_quaternion(R)) <= 1e-7
    u = uniform(200)
    assert sign_free(tq.matrix_to_quat(tq.quat_to_matrix(u)), pkt.matrix_to_quaternion(tq.quat_to_matrix(u))) <= 1e-14


def test_axis_angle_conversions():
    q = uniform(300)
    v = tq.quat_to_axis_angle(q)
    assert (v - pkt.quaternion_to_axis_angle(tq.quat_standardize(q))).abs().max() <= 1e-13
    assert sign_free(tq.axis_angle_to_quat(v), pkt.axis_angle_to_quaternion(v)) <= 1e-14
    assert (tq.axis_angle_to_matrix(v) - pkt.axis_angle_to_matrix(v)).abs().max() <= 1e-14
    R = tq.quat_to_matrix(q)
    assert (tq.axis_angle_to_matrix(tq.matrix_to_axis_angle(R)) - pkt.axis_angle_to_matrix(pkt.matrix_to_axis_angle(R))).abs().max() <= 1e-12


def test_product_and_vector_rotation():
    p, q = uniform(100, 1), uniform(100, 2)
    assert sign_free(tq.quat_multiply(p, q), pkt.quaternion_raw_multiply(p, q)) <= 1e-15
    v = torch.randn(100, 3, dtype=F64)
    assert (tq.quat_rotate(p, v) - pkt.quaternion_apply(p, v)).abs().max() <= 1e-14


def test_rot6d_uses_columns_where_pytorch_kinematics_uses_rows():
    R = tq.quat_to_matrix(uniform(100))
    assert torch.equal(tq.matrix_to_rot6d(R), pkt.matrix_to_rotation_6d(R.mT))
    x = torch.randn(100, 6, dtype=F64)
    assert (tq.rot6d_to_matrix(x) - pkt.rotation_6d_to_matrix(x).mT).abs().max() <= 1e-14


@pytest.mark.parametrize("convention", INTRINSIC)
def test_intrinsic_euler_matches_pytorch3d_convention(convention):
    g = torch.Generator().manual_seed(0)
    angles = torch.cat([(torch.rand(300, 3, generator=g, dtype=F64) * 2 - 1) * math.pi, lock_angles(convention, n=3)[0]])
    assert (tq.euler_to_matrix(angles, convention) - pkt.euler_angles_to_matrix(angles, convention)).abs().max() <= 1e-14
    R = tq.euler_to_matrix(angles, convention)
    theirs = pkt.matrix_to_euler_angles(R, convention)
    ours = tq.matrix_to_euler(R, convention)
    # Ours reproduces every rotation, lock included. pk's (PyTorch3D's) path does away from
    # lock only: at it, it returns NaN or a different rotation, the bug this library fixes.
    assert (tq.euler_to_matrix(ours, convention) - R).abs().max() <= 4e-7
    regular = ~tq.euler_gimbal_lock(tq.matrix_to_quat(R), convention, eps=1e-3)
    assert (pkt.euler_angles_to_matrix(theirs[regular], convention) - R[regular]).abs().max() <= 1e-12
    assert (ours[regular] - theirs[regular]).abs().max() <= 1e-12


@pytest.mark.parametrize("axes", TF_AXES)
def test_tf_quaternion_from_euler_all_24_axes_strings(axes):
    # tf's 's' (static) frame is extrinsic, 'r' (rotating) intrinsic, letters in the order applied
    convention = axes[1:] if axes[0] == "s" else axes[1:].upper()
    angles = torch.cat([(torch.rand(200, 3, dtype=F64) * 2 - 1) * math.pi, lock_angles(convention, n=2)[0]])
    given = angles.clone()
    theirs = pkt.quaternion_from_euler(given.clone(), axes)  # it halves its argument in place
    assert sign_free(tq.euler_to_quat(given, convention), theirs) <= 1e-14
    assert torch.equal(given, angles)


def test_pytorch_kinematics_mutates_its_input_and_we_do_not():
    angles = torch.tensor([0.3, 0.2, 0.1], dtype=F64)
    mine = angles.clone()
    tq.euler_to_quat(mine, "xyz")
    assert torch.equal(mine, angles)
    theirs = angles.clone()
    pkt.quaternion_from_euler(theirs, "sxyz")
    assert not torch.equal(theirs, angles)  # the reason every pk call here gets a clone


def test_gradients_at_the_identity_are_finite_here_and_nan_in_pytorch_kinematics():
    R = torch.eye(3, dtype=F64, requires_grad=True)
    (ours,) = torch.autograd.grad(tq.matrix_to_quat(R).sum(), R)
    assert torch.isfinite(ours).all()
    (theirs,) = torch.autograd.grad(pkt.matrix_to_quaternion(R).sum(), R)
    assert not torch.isfinite(theirs).all()
