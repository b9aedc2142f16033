"""Convert and RotateVectors: each equals its functional call, validates at construction."""

import pytest
import torch
from torch import nn

import torchquat
from torchquat.nn import Convert, RotateVectors

BATCH_SHAPES = [(), (1,), (3, 1, 2)]


def _sample(rep: str, shape, gen):
    """Inputs valid for ``rep`` (random rotations, expressed in that representation)."""
    q = torchquat.random_quat(shape, generator=gen, dtype=torch.float64)
    if rep == "quat":
        return q
    return torchquat.convert(q, "quat", rep, convention="ZYX")


PAIRS = [("quat", "matrix"), ("matrix", "quat"), ("euler", "quat"), ("quat", "euler"), ("axis_angle", "rot6d"),
         ("rot6d", "axis_angle"), ("rot9d", "quat"), ("matrix", "rot9d"), ("quat_xyzw", "euler"), ("euler", "euler")]


@pytest.mark.parametrize("src,dst", PAIRS, ids=[f"{s}-{d}" for s, d in PAIRS])
@pytest.mark.parametrize("shape", BATCH_SHAPES, ids=str)
def test_convert_equals_functional_convert(src, dst, shape):
    gen = torch.Generator().manual_seed(0)
    x = _sample(src, shape, gen)
    conv = "ZYX" if "euler" in (src, dst) else None
    got = Convert(src, dst, convention=conv)(x)
    torch.testing.assert_close(got, torchquat.convert(x, src, dst, convention=conv), rtol=0, atol=0)


def test_convert_inline_convention_and_degrees():
    x = torch.tensor([[30.0, -20.0, 10.0]], dtype=torch.float64)
    layer = Convert("euler:xyz", "matrix", degrees=True)
    torch.testing.assert_close(layer(x), torchquat.euler_to_matrix(x, "xyz", degrees=True))
    assert repr(layer) == "Convert(src='euler', dst='matrix', convention='xyz', degrees=True)"


def test_convert_between_two_euler_conventions_keeps_both():
    x = torch.randn(6, 3, dtype=torch.float64)
    layer = Convert("euler:ZYX", "euler:xyz")
    torch.testing.assert_close(layer(x), torchquat.convert(x, "euler:ZYX", "euler:xyz"), rtol=0, atol=0)
    torch.testing.assert_close(torchquat.euler_to_matrix(layer(x), "xyz"), torchquat.euler_to_matrix(x, "ZYX"))
    assert repr(layer) == "Convert(src='euler:ZYX', dst='euler:xyz', degrees=False)"


def test_convert_is_stateless_and_composes_in_sequential():
    layer = Convert("euler", "quat", convention="ZYX")
    assert list(layer.parameters()) == [] and list(layer.buffers()) == [] and layer.state_dict() == {}
    seq = nn.Sequential(Convert("euler", "quat", convention="ZYX"), Convert("quat", "rot6d"),
                        Convert("rot6d", "matrix"))
    x = torch.randn(7, 3, dtype=torch.float64)
    torch.testing.assert_close(seq(x), torchquat.euler_to_matrix(x, "ZYX"))


BAD_CONVERT = [
    (("quaternion", "matrix"), {}, "Convert: unknown representation 'quaternion'"),
    (("quat", "rotmat"), {}, "Convert: unknown representation 'rotmat'"),
    (("euler", "quat"), {}, "Convert: 'euler' needs a convention"),
    (("euler", "quat"), {"convention": "XYZW"}, "Convert: invalid convention 'XYZW'"),
    (("euler", "quat"), {"convention": "xYz"}, "Convert: invalid convention 'xYz'"),
    (("euler:ZYX", "quat"), {"convention": "xyz"}, "Convert: two conventions given"),
    (("quat", "matrix"), {"convention": "ZYX"}, "Convert: convention='ZYX' only applies to Euler angles"),
    (("quat", "axis_angle"), {"degrees": True}, "Convert: degrees=True only applies to Euler angles"),
    ((3, "quat"), {}, "Convert: expected a representation name, got 3"),
    (("euler:ZYX", "quat"), {"degrees": "no"}, "Convert: expected degrees to be True or False, got 'no'"),
]


@pytest.mark.parametrize("args,kwargs,message", BAD_CONVERT, ids=[m for _, _, m in BAD_CONVERT])
def test_convert_rejects_bad_tokens_at_construction(args, kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        Convert(*args, **kwargs)


def test_convert_wrong_input_shape_is_a_shape_error_naming_the_layer():
    # (it named the functional convert: "convert: expected x ...")
    with pytest.raises(torchquat.ShapeError, match=r"^Convert: expected x of shape \(\.\.\., 4\), got \(5, 3\)"):
        Convert("quat", "matrix")(torch.zeros(5, 3))
    with pytest.raises(TypeError, match=r"^Convert: expected x to be a floating-point tensor"):
        Convert("quat", "matrix")(torch.zeros(5, 4, dtype=torch.int64))
    rot9d = Convert("rot9d", "quat")  # (3 x 3 matrices and rows of 9 both)
    assert torch.equal(rot9d(torch.eye(3)), rot9d(torch.eye(3).flatten()))


@pytest.mark.parametrize("q_shape,v_shape", [
    ((4,), (3,)), ((5, 4), (5, 3)), ((2, 1, 4), (1, 7, 3)), ((1, 4), (6, 3)),
    ((4,), (6, 3)), ((2, 1, 4), (5, 3)),
], ids=str)
def test_rotate_vectors_equals_quat_rotate_with_broadcasting(q_shape, v_shape):
    gen = torch.Generator().manual_seed(1)
    q = torchquat.random_quat(q_shape[:-1], generator=gen, dtype=torch.float64)
    v = torch.randn(v_shape, generator=gen, dtype=torch.float64)
    got = RotateVectors()(q, v)
    torch.testing.assert_close(got, torchquat.quat_rotate(q, v), rtol=0, atol=0)
    expected = (torchquat.quat_to_matrix(q) @ v.unsqueeze(-1)).squeeze(-1)  # R @ v, independently
    torch.testing.assert_close(got, expected)


def test_rotate_vectors_rejects_batches_that_do_not_broadcast():
    with pytest.raises(torchquat.ShapeError, match="^RotateVectors: expected q and v with broadcastable"):
        RotateVectors()(torch.randn(2, 4), torch.randn(3, 3))
    with pytest.raises(torchquat.ShapeError, match=r"^RotateVectors: expected q of shape \(\.\.\., 4\)"):
        RotateVectors()(torch.randn(2, 3), torch.randn(2, 3))
    with pytest.raises(torchquat.ShapeError, match=r"^RotateVectors: expected v of shape \(\.\.\., 3\)"):
        RotateVectors()(torch.randn(2, 4), torch.randn(2, 4))
