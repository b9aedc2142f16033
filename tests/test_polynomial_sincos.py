"""The float32 cos and sin of the compiled CPU kernels that build rotations from half angles
(``_polynomials.polynomial_cos_sin``): its accuracy, its common sign and special values, where the
dispatcher takes it (angles within ``_polynomials.POLYNOMIAL_SINCOS_RANGE``), and those kernels against
float64."""

import math

import pytest
import torch

import torchquat as tq
from torchquat import _polynomials
from function_table import ALL, traced_targets

F32, F64 = torch.float32, torch.float64


def _common_sign_errors(x: torch.Tensor):
    """The polynomial's ``(c, s)`` of float32 ``x``, the sign ``sigma`` with ``(c, s) ~ sigma (cos x,
    sin x)``, and the errors of ``sigma c`` and ``sigma s`` against float64's cos and sin of ``x``."""
    c, s = _polynomials.polynomial_cos_sin(x)
    cos, sin = torch.cos(x.double()), torch.sin(x.double())
    sigma = torch.sign(c.double() * cos + s.double() * sin)
    return c, s, sigma, (sigma * c.double() - cos).abs(), (sigma * s.double() - sin).abs()


def test_the_polynomial_is_cos_and_sin_up_to_one_sign_common_to_both_within_a_float32_ulp():
    g = torch.Generator().manual_seed(0)
    bound = _polynomials.POLYNOMIAL_SINCOS_RANGE
    # uniform over the range, near every multiple of pi/4 up to 40 (the reduction's and the
    # quadrant's edges), and within 4 where rotations' half angles lie
    quarter_turns = torch.arange(-160, 161, dtype=F64) * math.pi / 4
    x = torch.cat([(torch.rand(1_000_000, generator=g, dtype=F64) * 2 - 1) * bound,
                   (quarter_turns[:, None] + torch.linspace(-1e-5, 1e-5, 201, dtype=F64)).flatten(),
                   torch.rand(200_000, generator=g, dtype=F64) * 8 - 4]).to(F32)
    c, s, sigma, cos_error, sin_error = _common_sign_errors(x)
    assert torch.all(sigma.abs() == 1)  # one sign for both (never 0: cos and sin are not both ~0)
    # within float32's spacing at 1 (1.19e-7; torch.sin, SLEEF's, is within 3.6e-8)
    assert cos_error.max() < 1.2e-7 and sin_error.max() < 1.2e-7
    assert cos_error.mean() < 2e-8 and sin_error.mean() < 2e-8
    # and the pair has unit norm to rounding
    assert ((c.double() ** 2 + s.double() ** 2) - 1).abs().max() < 3e-7


def test_the_polynomials_sine_is_accurate_relative_to_small_angles():
    x = torch.cat([torch.logspace(-30, -0.11, 4000), -torch.logspace(-30, -0.11, 4000)])  # (to 0.776 < pi/4)
    c, s, sigma, _, _ = _common_sign_errors(x)
    assert torch.all(sigma == 1)  # (below pi/4 no sign is dropped)
    assert (s.double() / torch.sin(x.double()) - 1).abs().max() < 1.2e-7


def test_the_polynomial_keeps_sines_signed_zeros_and_gives_nan_where_torch_does():
    x = torch.tensor([0.0, -0.0, math.inf, -math.inf, math.nan])
    c, s = _polynomials.polynomial_cos_sin(x)
    assert c[:2].tolist() == [1.0, 1.0] and s[:2].tolist() == [0.0, 0.0]
    assert torch.signbit(s[:2]).tolist() == [False, True]  # sin(-0.0) = -0.0, as torch.sin
    assert torch.isnan(torch.sin(x[2:])).all() and torch.isnan(c[2:]).all() and torch.isnan(s[2:]).all()


def _trig_calls(fn, *inputs) -> int:
    """How many ``torch.cos`` and ``torch.sin`` calls dynamo's graph of ``fn`` on ``inputs`` makes."""
    targets = traced_targets(fn, *inputs)
    return targets.count(torch.cos) + targets.count(torch.sin)


def test_the_polynomial_is_taken_only_in_marked_float32_cpu_graphs_without_a_gradient():
    x = torch.randn(8)
    assert _trig_calls(_polynomials.cos_sin_up_to_sign, x) == 2  # a user's own compiled code: torch's
    _polynomials.KERNEL_CALL.polynomial_sincos = True  # (as the dispatcher sets it for angles in range)
    try:
        assert _trig_calls(_polynomials.cos_sin_up_to_sign, x) == 0
        assert _trig_calls(_polynomials.cos_sin_up_to_sign, x.double()) == 2  # float64: torch's
        leaf = x.clone().requires_grad_()
        assert _trig_calls(_polynomials.cos_sin_up_to_sign, leaf) == 2  # a recorded gradient: torch's exact one
        with torch.no_grad():
            assert _trig_calls(_polynomials.cos_sin_up_to_sign, leaf) == 0
    finally:
        _polynomials.KERNEL_CALL.polynomial_sincos = False
    # eager: torch's, bit for bit
    c, s = _polynomials.cos_sin_up_to_sign(x)
    assert torch.equal(c, torch.cos(x)) and torch.equal(s, torch.sin(x))


def test_the_dispatcher_takes_the_polynomial_only_for_angles_within_its_range(compiled, monkeypatch):
    import torchquat._dispatch as dispatch

    graphs = []

    def backend(gm, example_inputs):
        targets = [node.target for node in gm.graph.nodes if node.op == "call_function"]
        graphs.append(targets.count(torch.cos) + targets.count(torch.sin))
        return gm.forward

    monkeypatch.setattr(dispatch, "_backend", backend)
    monkeypatch.setattr(dispatch, "_compiled", {})
    torch._dynamo.reset()
    angles = torch.rand(64, 3, generator=torch.Generator().manual_seed(0)) * 6 - 3
    bound = _polynomials.POLYNOMIAL_SINCOS_RANGE

    def trig_calls(call):
        before = len(graphs)
        call()
        return graphs[before:]  # (the graph traced by this call, if any)

    with torch.no_grad():
        assert trig_calls(lambda: tq.euler_to_quat(angles, "ZYX")) == [0]
        assert trig_calls(lambda: tq.axis_angle_to_matrix(angles)) == [0]
        edge = angles.clone()
        edge[5, 1] = -bound  # (the range's edge is in it)
        assert trig_calls(lambda: tq.euler_to_quat(edge, "ZYX")) == []  # the same graph
        for outside in (bound * 1.001, math.nan, math.inf):
            beyond = angles.clone()
            beyond[7, 2] = outside
            # a graph of its own with torch's cos and sin, traced once
            traced = trig_calls(lambda: tq.euler_to_quat(beyond, "ZYX"))
            assert traced in ([6], [])
        assert len([n for n in graphs if n == 6]) == 1
        assert trig_calls(lambda: tq.euler_to_quat(angles.double(), "ZYX")) == [6]
    leaf = angles.clone().requires_grad_()
    assert all(n > 0 for n in trig_calls(lambda: tq.euler_to_quat(leaf, "ZYX")))


def _big_batch(n=1_000, scale=20.0, seed=3):
    """Float32 angles or rotation vectors, wide enough for many quarter turns of the half angles."""
    g = torch.Generator().manual_seed(seed)
    return ((torch.rand(n, 3, generator=g, dtype=F64) * 2 - 1) * scale).to(F32)


KERNELS = ["euler_to_quat[ZYX]", "euler_to_quat[zxz]", "euler_to_matrix[XYZ]", "euler_to_matrix[ZXZ]",
           "axis_angle_to_quat", "axis_angle_to_matrix"]


@pytest.mark.slow
@pytest.mark.parametrize("name", KERNELS)
def test_compiled_float32_rotations_without_a_gradient_match_float64_in_and_beyond_the_range(name, compiled):
    fn, generic, singular = ALL[name]
    bound = _polynomials.POLYNOMIAL_SINCOS_RANGE
    beyond = _big_batch(64, 1.0, seed=4)
    # 2^20 rad on one axis (a norm float32 computes exactly): the three-part reduction is 0.03 off
    # at 1e6, so these batches must take torch's cos and sin
    beyond[::8] = torch.tensor([2.0 ** 20, 0.0, 0.0])
    batches = [singular()[0].to(F32), generic()[0].to(F32), _big_batch(), _big_batch(200, bound, seed=5), beyond]
    for x in batches:
        with torch.no_grad():
            out = fn(x)
        exact = fn(x.double())
        if out.shape[-1] == 4:
            assert torch.all(out[..., 0] >= 0)
            # as rotations: a quaternion with w ~ 0 and its negative are both right
            out, exact = tq.quat_to_matrix(out.double()), tq.quat_to_matrix(exact)
        error = (out.double() - exact).abs().flatten(1).amax(1)
        tolerance = torch.full_like(error, 2e-6)
        if name.startswith("axis_angle"):  # (a float32 norm of a rotation vector rounds its angle: 1.5 ulp
            # of |v|, unless the vector lies on an axis)
            off_axis = (x == 0).sum(-1) < 2
            tolerance = tolerance + off_axis * 3e-7 * torch.linalg.vector_norm(x.double(), dim=-1)
        assert torch.all(error <= tolerance), (x.abs().max(), (error - tolerance).max())
