"""RotationHead: always a rotation, equals Linear + the core map, gradients reach the Linear."""

import math

import pytest
import torch

import torchquat
from torchquat.nn import GeodesicLoss, RotationHead

REPS = ["quat", "rot6d", "rot9d", "axis_angle", "euler"]
OUTPUTS = ["matrix", "quat"]
IN = 12


def make_head(rep, output="matrix", seed=0, dtype=torch.float32):
    torch.manual_seed(seed)
    return RotationHead(IN, rep, output, convention="ZYX" if rep == "euler" else None, dtype=dtype)


def as_matrix(y, output):
    return y if output == "matrix" else torchquat.quat_to_matrix(y)


@pytest.mark.parametrize("output", OUTPUTS)
@pytest.mark.parametrize("rep", REPS)
@pytest.mark.parametrize("scale", [0.0, 1e-6, 1.0, 1e6, 1e25], ids=lambda s: f"scale={s:g}")
def test_head_outputs_orthonormal_det_one(rep, output, scale):
    if rep == "axis_angle" and scale > 1e18:
        pytest.skip("documented: a rotation angle of 1e19 rad or more overflows its square in float32")
    head = make_head(rep, output)
    x = torch.randn(64, IN, generator=torch.Generator().manual_seed(2)) * scale
    with torch.no_grad():
        y = head(x)
    assert y.shape == ((64, 3, 3) if output == "matrix" else (64, 4))
    assert torch.isfinite(y).all()
    R = as_matrix(y, output).double()
    eye = torch.eye(3, dtype=torch.float64).expand(64, 3, 3)
    torch.testing.assert_close(R @ R.mT, eye, rtol=0, atol=2e-6)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(64, dtype=torch.float64), rtol=0, atol=3e-6)
    if output == "quat":
        torch.testing.assert_close(y.norm(dim=-1), torch.ones(64), rtol=0, atol=1e-6)
        assert (y[..., 0] >= 0).all()


@pytest.mark.parametrize("output", OUTPUTS)
@pytest.mark.parametrize("rep", REPS)
def test_head_equals_linear_then_core_map(rep, output):
    head = make_head(rep, output, dtype=torch.float64)
    x = torch.randn(5, 2, IN, dtype=torch.float64)
    z = head.linear(x)
    R = {
        "quat": lambda: torchquat.quat_to_matrix(z),
        "rot6d": lambda: torchquat.rot6d_to_matrix(z),
        "rot9d": lambda: torchquat.rot9d_to_matrix(z),
        "axis_angle": lambda: torchquat.axis_angle_to_matrix(z),
        "euler": lambda: torchquat.euler_to_matrix(z, "ZYX"),
    }[rep]()
    got = head(x)
    if output == "matrix":
        torch.testing.assert_close(got, R)
    else:
        expected = (torchquat.quat_standardize(torchquat.quat_normalize(z)) if rep == "quat"
                    else torchquat.matrix_to_quat(R))
        torch.testing.assert_close(got, expected)


@pytest.mark.parametrize("output", OUTPUTS)
@pytest.mark.parametrize("rep", REPS)
def test_gradients_reach_the_linear_layer(rep, output):
    head = make_head(rep, output)
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(16, IN, generator=gen)
    target = torchquat.random_quat(16, generator=gen)
    y = head(x)
    loss = GeodesicLoss(output)(y, target if output == "quat" else torchquat.quat_to_matrix(target))
    loss.backward()
    for p in (head.linear.weight, head.linear.bias):
        assert torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0


@pytest.mark.parametrize("rep", REPS)
def test_gradcheck_float64(rep):
    head = make_head(rep, "matrix", dtype=torch.float64)
    x = torch.randn(3, IN, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(head, (x,))


@pytest.mark.parametrize("output", OUTPUTS)
@pytest.mark.parametrize("rep", REPS)
def test_non_finite_features_give_nan_rows_and_leave_others_alone(rep, output):
    head = make_head(rep, output)
    x = torch.randn(4, IN)
    x[1, 3] = float("nan")
    x[2, 0] = float("inf")
    with torch.no_grad():
        y = head(x).flatten(1)
        clean = head(x[[0, 3]]).flatten(1)
    assert torch.isnan(y[1]).all() and torch.isnan(y[2]).all()
    torch.testing.assert_close(y[[0, 3]], clean)


def test_head_without_batch_dims_and_with_many():
    head = make_head("rot6d")
    assert head(torch.randn(IN)).shape == (3, 3)
    assert head(torch.randn(2, 3, 4, IN)).shape == (2, 3, 4, 3, 3)


@pytest.mark.parametrize("rep", REPS)
def test_bfloat16_autocast_gives_rotations_and_gradients(rep):
    head = make_head(rep)
    x = torch.randn(32, IN)
    target = torchquat.quat_to_matrix(torchquat.random_quat(32))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        R = head(x)
        loss = GeodesicLoss()(R, target)
    assert R.dtype == torch.bfloat16
    R = R.double()
    torch.testing.assert_close(R @ R.mT, torch.eye(3, dtype=torch.float64).expand(32, 3, 3), rtol=0, atol=2e-2)
    loss.float().backward()
    assert torch.isfinite(head.linear.weight.grad).all()


def test_float16_head_computes_in_float32_inside():
    head = make_head("rot9d", dtype=torch.float16)
    R = head(torch.randn(8, IN, dtype=torch.float16))
    assert R.dtype == torch.float16
    torch.testing.assert_close(torch.linalg.det(R.float()), torch.ones(8), rtol=0, atol=5e-3)


BAD_HEADS = [
    ((IN, "rot5d"), {}, "RotationHead: unknown representation 'rot5d': use one of 'quat', 'rot6d'"),
    ((IN, "matrix"), {}, "RotationHead: unknown representation 'matrix'"),
    ((IN, "rot6d", "euler"), {}, "RotationHead: unknown output 'euler': use 'matrix' or 'quat'"),
    ((IN, "euler"), {}, "RotationHead: 'euler' needs a convention"),
    ((IN, "euler"), {"convention": "ZZX"}, "RotationHead: invalid convention 'ZZX'"),
    ((IN, "rot6d"), {"convention": "ZYX"}, "RotationHead: convention='ZYX' only applies to representation='euler'"),
    ((0, "rot6d"), {}, "RotationHead: expected in_features to be a positive int, got 0"),
    ((2.5, "rot6d"), {}, "RotationHead: expected in_features to be a positive int, got 2.5"),
]


@pytest.mark.parametrize("args,kwargs,message", BAD_HEADS, ids=[m for _, _, m in BAD_HEADS])
def test_head_rejects_bad_configuration(args, kwargs, message):
    with pytest.raises(ValueError, match=message):
        RotationHead(*args, **kwargs)


@pytest.mark.parametrize("shape", [(5, IN + 1), (IN, 5), ()], ids=str)
def test_head_rejects_wrong_feature_size(shape):
    head = make_head("rot6d")
    with pytest.raises(torchquat.ShapeError, match=rf"RotationHead: expected features of shape \(\.\.\., {IN}\), "
                                                   rf"got {re_shape(shape)}"):
        head(torch.randn(shape))


def test_head_takes_any_integer_size_and_names_a_dtype_mismatch():
    import numpy as np

    assert RotationHead(np.int64(IN)).in_features == IN and type(RotationHead(np.int64(IN)).in_features) is int
    with pytest.raises(ValueError, match="positive int, got True"):
        RotationHead(True)
    head = make_head("rot6d")  # float32 parameters
    with pytest.raises(TypeError, match=r"RotationHead: features are torch.float64 but the head's parameters are torch.float32"):
        head(torch.randn(5, IN, dtype=torch.float64))  # (was PyTorch's "mat1 and mat2 must have the same dtype")
    assert head.double()(torch.randn(5, IN, dtype=torch.float64)).dtype == torch.float64


def re_shape(shape):
    return str(tuple(shape)).replace("(", r"\(").replace(")", r"\)")


def test_euler_head_reads_its_outputs_as_zyx_angles():
    head = RotationHead(2, "euler:ZYX", bias=False, dtype=torch.float64)
    with torch.no_grad():
        head.linear.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]], dtype=torch.float64))
    yaw, roll = 0.3, -1.1
    got = head(torch.tensor([yaw, roll], dtype=torch.float64))
    c, s = math.cos, math.sin
    Rz = torch.tensor([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]], dtype=torch.float64)
    Rx = torch.tensor([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]], dtype=torch.float64)
    torch.testing.assert_close(got, Rz @ Rx)  # intrinsic Z then X: R = Rz(yaw) Ry(0) Rx(roll)


@pytest.mark.parametrize("representation", ["quat", "rot6d"])
@pytest.mark.parametrize("dtype,scale", [(torch.float16, 1e-5), (torch.float16, 1e-7), (torch.float32, 1e-39),
                                         (torch.float32, 1e-44), (torch.float64, 1e-310)])
def test_tiny_linear_outputs_still_give_rotations(representation, dtype, scale):
    # the power-of-two scale 2^-e was computed in the output's dtype: inf for float16 outputs below
    # 3e-5 (a real model's) and for subnormal float32 ones, and inf * y gave NaN rotations
    head = RotationHead(4, representation).to(dtype)
    g = torch.Generator().manual_seed(2)
    with torch.no_grad():
        head.linear.weight.copy_((torch.randn(head.linear.weight.shape, generator=g, dtype=torch.float64) * scale).to(dtype))
        head.linear.bias.zero_()
    R = head(torch.randn(3, 4, generator=g, dtype=torch.float64).to(dtype))
    assert R.dtype == dtype
    R = R.double()
    eye = torch.eye(3, dtype=torch.float64).expand(3, 3, 3)
    tolerance = 2e-3 if dtype == torch.float16 else 1e-6
    torch.testing.assert_close(R @ R.mT, eye, rtol=0, atol=tolerance)
    assert (torch.linalg.det(R) > 0).all()


@pytest.mark.parametrize("dtype", [torch.int64, torch.bool])
def test_head_rejects_integer_features_with_a_type_error(dtype):
    with pytest.raises(TypeError, match=f"RotationHead: expected features to be a floating-point tensor, got dtype {dtype}"):
        make_head("rot6d")(torch.ones(5, IN, dtype=dtype))
