"""Group axioms and the quaternion algebra: products, inverses, layouts, slerp, sampling."""

import math

import pytest
import torch

import torchquat as tq
from rotation_samples import uniform

F64 = torch.float64


@pytest.fixture(params=["eager", "compiled"])
def slerp_path(request):
    """The slerp tests run eagerly and through the compiled kernel (one rotation stays on floats)."""
    tq.use_compiled_kernels(request.param == "compiled")
    yield
    tq.use_compiled_kernels(False)


def test_hamilton_rules():
    one, i, j, k = torch.eye(4, dtype=F64)
    m = tq.quat_multiply
    assert torch.equal(m(i, j), k) and torch.equal(m(j, k), i) and torch.equal(m(k, i), j)
    assert torch.equal(m(i, i), -one) and torch.equal(m(m(i, j), k), -one)


def test_product_is_associative_and_composes_matrices():
    p, q, r = uniform(50, 1), uniform(50, 2), uniform(50, 3)
    m = tq.quat_multiply
    assert (m(m(p, q), r) - m(p, m(q, r))).abs().max() <= 1e-15
    assert (tq.quat_to_matrix(m(p, q)) - tq.quat_to_matrix(p) @ tq.quat_to_matrix(q)).abs().max() <= 1e-14


def test_inverse_and_conjugate():
    q = torch.randn(50, 4, dtype=F64)
    ident = tq.quat_identity(50, dtype=F64)
    assert (tq.quat_multiply(q, tq.quat_inverse(q)) - ident).abs().max() <= 1e-14
    u = tq.quat_normalize(q)
    assert (tq.quat_multiply(tq.quat_conjugate(u), u) - ident).abs().max() <= 1e-15
    assert (tq.quat_to_matrix(tq.quat_conjugate(u)) - tq.quat_to_matrix(u).mT).abs().max() <= 1e-15


@pytest.mark.parametrize("dtype, scales", [(torch.float32, (1e20, 1e-20, 3e38, 1e-36)),
                                           (torch.float64, (1e160, 1e-160, 1e308, 1e-300))], ids=["float32", "float64"])
def test_normalize_takes_norms_whose_squares_overflow_or_underflow(dtype, scales):
    # the README's cure for such quaternions: |q|^2 is inf or 0 for them, the direction is not
    u = tq.quat_normalize(torch.randn(50, 4, dtype=torch.float64)).to(dtype)
    for scale in scales:
        torch.testing.assert_close(tq.quat_normalize(u * scale), u, rtol=0, atol=4 * torch.finfo(dtype).eps)


def test_non_unit_quaternions_are_the_rotation_of_their_direction():
    q = torch.randn(50, 4, dtype=F64) * 7
    u = q / q.norm(dim=-1, keepdim=True)
    assert (tq.quat_to_matrix(q) - tq.quat_to_matrix(u)).abs().max() <= 1e-14
    v = torch.randn(50, 3, dtype=F64)
    assert (tq.quat_rotate(q, v) - tq.quat_rotate(u, v)).abs().max() <= 1e-14


def test_broadcasting_one_rotation_over_many_points():
    q = uniform(1)[0]
    v = torch.randn(4, 5, 3, dtype=F64)
    assert tq.quat_rotate(q, v).shape == (4, 5, 3)
    assert (tq.quat_rotate(q, v) - v @ tq.quat_to_matrix(q).mT).abs().max() <= 1e-14
    assert tq.quat_multiply(uniform(3).view(3, 1, 4), uniform(2).view(1, 2, 4)).shape == (3, 2, 4)


def test_standardize_picks_one_representative_per_rotation():
    q = torch.cat([uniform(100), torch.tensor([[0.0, -1.0, 0, 0], [0.0, 0.0, -1.0, 0.0], [0, 0, 0, -1.0],
                                                [0.0, 0.0, -0.6, 0.8], [-1.0, 0, 0, 0]], dtype=F64)])
    s = tq.quat_standardize(q)
    assert torch.equal(tq.quat_standardize(-q), s)
    assert (s[:, 0] >= 0).all()
    assert (tq.quat_to_matrix(s) - tq.quat_to_matrix(q)).abs().max() <= 1e-15


def test_layout_round_trips():
    q = uniform(10)
    assert torch.equal(tq.quat_xyzw_to_wxyz(tq.quat_wxyz_to_xyzw(q)), q)
    assert torch.equal(tq.quat_wxyz_to_xyzw(q)[:, 3], q[:, 0])
    assert torch.equal(tq.quat_from_jpl(tq.quat_to_jpl(q)), q)


def test_identity():
    assert torch.equal(tq.quat_identity(), torch.tensor([1.0, 0.0, 0.0, 0.0]))
    assert tq.quat_identity((2, 3), dtype=F64).shape == (2, 3, 4)
    assert torch.equal(tq.quat_to_matrix(tq.quat_identity(dtype=F64)), torch.eye(3, dtype=F64))


def test_slerp_endpoints_shortest_path_and_constant_speed(slerp_path):
    q0, q1 = uniform(30, 4), uniform(30, 5)
    assert (tq.quat_slerp(q0, q1, 0.0) - q0).abs().max() <= 1e-15
    end = tq.quat_slerp(q0, q1, 1.0)
    assert (tq.quat_to_matrix(end) - tq.quat_to_matrix(q1)).abs().max() <= 1e-14
    total = tq.quat_geodesic_distance(q0, q1)
    for t in (0.25, 0.5, 0.8):
        mid = tq.quat_slerp(q0, q1, t)
        assert (mid.norm(dim=-1) - 1).abs().max() <= 1e-14
        assert (tq.quat_geodesic_distance(q0, mid) - t * total).abs().max() <= 1e-12
    # the sign of q1 does not change the path
    assert (tq.quat_slerp(q0, -q1, 0.3) - tq.quat_slerp(q0, q1, 0.3)).abs().max() <= 1e-15


def test_slerp_between_equal_and_nearly_equal_rotations(slerp_path):
    q = uniform(5, 6)
    assert (tq.quat_slerp(q, q, 0.4) - q).abs().max() <= 1e-15
    tiny = tq.quat_multiply(q, tq.axis_angle_to_quat(torch.tensor([1e-10, 0.0, 0.0], dtype=F64)))
    out = tq.quat_slerp(q, tiny, 0.5)
    assert torch.isfinite(out).all() and (tq.quat_geodesic_distance(out, q) - 0.5e-10).abs().max() <= 1e-15


def test_random_quat_is_uniform_on_so3():
    q = tq.random_quat(200_000, generator=torch.Generator().manual_seed(0), dtype=F64)
    assert (q.norm(dim=-1) - 1).abs().max() <= 1e-14
    # Haar measure: E[R] = 0, and the angle has density (1 - cos t) / pi on [0, pi].
    assert tq.quat_to_matrix(q).mean(0).abs().max() < 0.01
    angle = tq.quat_geodesic_distance(q, tq.quat_identity(dtype=F64))
    for t in (0.5, 1.0, 2.0, 3.0):
        cdf = (t - math.sin(t)) / math.pi
        assert abs((angle <= t).double().mean().item() - cdf) < 0.005


def test_random_quat_generator_dtype_and_shape():
    a = tq.random_quat((2, 3), generator=torch.Generator().manual_seed(1))
    b = tq.random_quat((2, 3), generator=torch.Generator().manual_seed(1))
    assert torch.equal(a, b) and a.shape == (2, 3, 4)
    assert tq.random_quat(dtype=torch.bfloat16).dtype == torch.bfloat16


@pytest.mark.parametrize("src, dst, kwargs", [
    ("quat", "matrix", {}), ("matrix", "euler", {"convention": "ZYX"}), ("euler:zxz", "axis_angle", {}),
    ("axis_angle", "rot6d", {}), ("rot6d", "rot9d", {}), ("rot9d", "quat", {}), ("quat_xyzw", "quat", {}),
])
def test_convert_agrees_with_the_direct_functions(src, dst, kwargs):
    q = uniform(20, 7)
    R = tq.quat_to_matrix(q)
    conv = kwargs.get("convention") or (src.partition(":")[2] or None)
    given = {
        "quat": q, "matrix": R, "axis_angle": tq.quat_to_axis_angle(q), "rot6d": tq.matrix_to_rot6d(R),
        "rot9d": R.flatten(-2), "quat_xyzw": tq.quat_wxyz_to_xyzw(q),
        "euler": tq.quat_to_euler(q, conv) if conv else None,
    }[src.partition(":")[0]]
    out = tq.convert(given, src, dst, **kwargs)
    back = tq.convert(out, dst, "matrix", **kwargs)
    assert (back - R).abs().max() <= 1e-13


# Every conversion with a function of its own: convert returns that function's numbers, at one
# rotation (Python floats) and on batches (the small and the large kernels). Through the hubs matrix ->
# Euler went by the quaternion, up to 2.2e-5 rad off in float32 where the angles read off R are 6.7e-7.
_NAMED = {
    ("quat", "matrix", ()): tq.quat_to_matrix,
    ("matrix", "quat", ()): tq.matrix_to_quat,
    ("euler:ZYX", "quat", ()): lambda x: tq.euler_to_quat(x, "ZYX"),
    ("euler", "quat", (("convention", "zxz"), ("degrees", True))): lambda x: tq.euler_to_quat(x, "zxz", degrees=True),
    ("quat", "euler:ZYX", ()): lambda q: tq.quat_to_euler(q, "ZYX"),
    ("euler:XYZ", "matrix", ()): lambda x: tq.euler_to_matrix(x, "XYZ"),
    ("matrix", "euler:ZYX", ()): lambda R: tq.matrix_to_euler(R, "ZYX"),
    ("matrix", "euler:zxz", (("degrees", True), ("eps", 1e-3))): lambda R: tq.matrix_to_euler(R, "zxz", degrees=True, eps=1e-3),
    ("axis_angle", "quat", ()): tq.axis_angle_to_quat,
    ("quat", "axis_angle", ()): tq.quat_to_axis_angle,
    ("axis_angle", "matrix", ()): tq.axis_angle_to_matrix,
    ("matrix", "axis_angle", ()): tq.matrix_to_axis_angle,
    ("rot6d", "matrix", ()): tq.rot6d_to_matrix,
    ("matrix", "rot6d", ()): tq.matrix_to_rot6d,
    ("rot6d", "euler:ZYX", ()): lambda x: tq.matrix_to_euler(tq.rot6d_to_matrix(x), "ZYX"),
    ("rot6d", "axis_angle", ()): lambda x: tq.matrix_to_axis_angle(tq.rot6d_to_matrix(x)),
    ("axis_angle", "rot6d", ()): lambda v: tq.matrix_to_rot6d(tq.axis_angle_to_matrix(v)),
}


@pytest.mark.parametrize("dtype", [torch.float32, F64])
@pytest.mark.parametrize("rows", [1, 7, 3000])
@pytest.mark.parametrize("src, dst, options", list(_NAMED))
def test_convert_returns_the_named_functions_numbers(src, dst, options, rows, dtype):
    q = uniform(rows, 11).to(dtype)
    R = tq.quat_to_matrix(q)
    kind = src.partition(":")[0]
    convention = src.partition(":")[2] or dict(options).get("convention")
    x = {"quat": q, "matrix": R, "axis_angle": tq.quat_to_axis_angle(q), "rot6d": tq.matrix_to_rot6d(R),
         "euler": tq.quat_to_euler(q, convention, degrees=dict(options).get("degrees", False)) if convention else None}[kind]
    out = tq.convert(x, src, dst, **dict(options))
    assert torch.equal(out, _NAMED[(src, dst, options)](x))
    assert out.dtype == dtype and out.shape[0] == rows


def test_convert_quaternion_outputs_are_standardized_and_rot9d_takes_matrices():
    q = -tq.quat_standardize(uniform(10, 8))
    assert (tq.convert(q, "quat", "quat")[:, 0] >= 0).all()
    R = tq.quat_to_matrix(q)
    assert torch.allclose(tq.convert(R, "rot9d", "matrix"), R, atol=1e-14)
    deg = tq.convert(R, "matrix", "euler", convention="XYZ", degrees=True)
    assert torch.allclose(deg, tq.matrix_to_euler(R, "XYZ") * 180 / math.pi)


def test_slerp_takes_t_as_a_number_a_sequence_or_a_tensor(slerp_path):
    import numpy as np

    q0 = tq.random_quat(3, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    q1 = tq.random_quat(3, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    per_row = tq.quat_slerp(q0, q1, torch.tensor([0.25, 0.25, 0.25], dtype=torch.float64))
    for t in (0.25, np.float64(0.25), [0.25, 0.25, 0.25], np.array([0.25, 0.25, 0.25]), torch.tensor(0.25)):
        assert torch.allclose(tq.quat_slerp(q0, q1, t), per_row, atol=1e-15, rtol=0), type(t)
    assert (tq.quat_slerp(q0, q1, 0) - q0).abs().max() <= 1e-15  # an int is a number too


def test_slerp_of_a_zero_quaternion_is_nan_and_other_norms_are_normalised(slerp_path):
    # a zero quaternion gave a plausible 0.45 q1 (README: "A zero quaternion ... gives NaN")
    q1 = tq.random_quat(3, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    zero = torch.zeros(3, 4, dtype=torch.float64)
    assert torch.isnan(tq.quat_slerp(zero, q1, 0.3)).all()
    assert torch.isnan(tq.quat_slerp(q1, zero, 0.3)).all()
    q0 = tq.random_quat(3, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    torch.testing.assert_close(tq.quat_slerp(5.0 * q0, 0.01 * q1, 0.3), tq.quat_slerp(q0, q1, 0.3), rtol=0, atol=1e-15)


@pytest.mark.parametrize("dtype", [torch.int64, torch.bool, torch.complex64])
def test_slerp_refuses_a_non_floating_t_tensor(dtype):
    q = tq.random_quat(2, generator=torch.Generator().manual_seed(7))
    with pytest.raises(TypeError, match="quat_slerp: expected t to be a number or a floating-point tensor"):
        tq.quat_slerp(q[0], q[1], torch.ones(1, dtype=dtype))


def test_slerp_second_derivatives_are_continuous_at_and_near_equal_inputs(slerp_path):
    # The Hessian at q0 = q1 was O(1) off (a zeroth-order series), and just outside the series'
    # band the closed form's second derivatives lose eps / angle^2: H(d) - H(0) must shrink like d
    w = torch.randn(4, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    e = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    u = torch.tensor([0.0, 0.6, 0.0, 0.8], dtype=torch.float64)

    def f(q):
        return (tq.quat_slerp(q, e, 0.3) * w).sum()

    at_equal = torch.func.hessian(f)(e)
    assert torch.isfinite(at_equal).all()
    for d in (1e-9, 1.4e-8, 2e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3):
        assert (torch.func.hessian(f)(e + d * u) - at_equal).abs().max() < 10 * d


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
def test_slerp_between_orthogonal_quaternions_keeps_q1_on_every_path(dtype, slerp_path):
    # <q0, q1> = 0 (a half turn apart): both arcs are equally short, and the dot products round
    # to +-1e-17 differently on each path (fused multiply-adds in the columns'); the choice
    # depended on the batch size (midpoints 180 degrees apart on half the rows)
    q0 = tq.random_quat(2000, generator=torch.Generator().manual_seed(12), dtype=dtype)
    for unit in torch.eye(4, dtype=dtype)[1:]:
        q1 = tq.quat_multiply(q0, unit) * 3.0
        expected = (q0 + q1 / 3.0) * math.sqrt(0.5)  # q1 kept: equal weights sin(pi / 4) / sin(pi / 2)
        torch.testing.assert_close(tq.quat_slerp(q0, q1, 0.5), expected, rtol=0, atol=8 * torch.finfo(dtype).eps)
