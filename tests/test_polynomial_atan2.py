"""The float32 ``atan2`` of the compiled CPU kernels (``_polynomials.polynomial_atan2``): its accuracy and
special values, where it is used, and the compiled kernels that use it against eager."""

import math

import pytest
import torch

import torchquat as tq
from torchquat import _math, _polynomials
from function_table import ALL, compiled_as_the_polynomial_kernels_are, traced_targets

F32 = torch.float32


def _ulps(value: torch.Tensor, exact: torch.Tensor) -> torch.Tensor:
    """``|value - exact|`` in units of float32's spacing at ``exact`` (float64)."""
    magnitude = exact.abs().to(F32)
    spacing = torch.nextafter(magnitude, torch.tensor(math.inf)).double() - magnitude.double()
    return (value.double() - exact).abs() / spacing


def _sweep(n=1_000_000, seed=0):
    """Both arguments of any sign, magnitudes spread over 1e-13 to 1e13 and ratios likewise."""
    g = torch.Generator().manual_seed(seed)
    magnitude = lambda: torch.exp(torch.randn(n, generator=g) * 6.0)  # noqa: E731
    return torch.randn(n, generator=g) * magnitude(), torch.randn(n, generator=g) * magnitude()


def test_the_polynomial_is_within_two_ulps_in_every_quadrant_and_octant():
    y, x = _sweep()
    exact = torch.atan2(y.double(), x.double())
    error = _ulps(_polynomials.polynomial_atan2(y, x), exact)
    for region in (x > 0, x < 0, y.abs() > x.abs(), y.abs() <= x.abs()):
        assert region.sum() > 100_000
        assert error[region].max() <= 2.0
    assert error.mean() < 0.5
    # (for scale: torch.atan2 itself is within 1 ulp)
    assert _ulps(torch.atan2(y, x), exact).max() <= 1.0


def test_the_polynomial_is_accurate_relative_to_small_results():
    # the distances and Euler angles read atan2(tiny, 1): relative accuracy, not absolute
    x = torch.ones(4000)
    y = torch.logspace(-30, 0, 4000)
    exact = torch.atan2(y.double(), x.double())
    assert (_polynomials.polynomial_atan2(y, x).double() / exact - 1).abs().max() < 1.2e-7


def test_the_polynomial_keeps_atan2s_special_values():
    values = torch.tensor([0.0, -0.0, 1.0, -1.0, math.inf, -math.inf, math.nan, 1e-40, -1e-40, 3e38, -3e38])
    y, x = torch.meshgrid(values, values, indexing="ij")
    ours = _polynomials.polynomial_atan2(y, x)
    # correctly rounded reference: float64's atan2 rounded once
    expected = torch.atan2(y.double(), x.double()).to(F32)
    assert torch.equal(ours.isnan(), expected.isnan())
    finite = ~expected.isnan()
    assert torch.equal(ours[finite], expected[finite])
    assert torch.equal(torch.signbit(ours[finite]), torch.signbit(expected[finite]))  # -0.0 and -pi kept
    # half turns: atan2(+-0, negative) is +-pi exactly, as torch.atan2
    assert _polynomials.polynomial_atan2(torch.tensor([0.0, -0.0]), torch.tensor([-2.0, -2.0])).tolist() == [
        torch.tensor(math.pi).item(), -torch.tensor(math.pi).item()]


def test_atan_of_the_octants_ratio_is_within_one_and_a_half_ulps_on_the_unit_interval():
    a = torch.cat([torch.rand(1_000_000, generator=torch.Generator().manual_seed(3)), torch.linspace(0, 1, 100_001)])
    assert _ulps(_polynomials._atan_of_ratio(a), torch.atan(a.double())).max() <= 1.6


SIGN_HINTS = [(True, False), (False, True), (True, True)]


@pytest.mark.parametrize("y_nonnegative, x_nonnegative", SIGN_HINTS)
def test_a_half_plane_or_quadrant_known_to_the_caller_gives_the_general_forms_bits(y_nonnegative, x_nonnegative):
    # the distances, quat -> axis-angle and the middle Euler angle pass square roots and abs values
    y, x = _sweep(200_000, seed=1)
    specials = torch.tensor([0.0, -0.0, 1.0, -1.0, math.inf, -math.inf, math.nan, 1e-40, -1e-40, 3e38, -3e38])
    y = torch.cat([y, specials.repeat_interleave(len(specials))])
    x = torch.cat([x, specials.repeat(len(specials))])
    # what the caller promises: +0.0, positive or NaN (abs turns -0.0 into +0.0)
    y, x = (y.abs() if y_nonnegative else y), (x.abs() if x_nonnegative else x)
    hinted = _polynomials.polynomial_atan2(y, x, y_nonnegative, x_nonnegative)
    general = _polynomials.polynomial_atan2(y, x)
    assert torch.equal(hinted.isnan(), general.isnan()) and torch.equal(hinted.isnan(), torch.atan2(y, x).isnan())
    keep = ~general.isnan()
    assert torch.equal(hinted[keep], general[keep])
    assert torch.equal(torch.signbit(hinted[keep]), torch.signbit(general[keep]))
    assert _ulps(hinted[keep], torch.atan2(y.double(), x.double())[keep]).max() <= 2.0


def test_without_special_values_only_pairs_of_zeros_and_of_infinities_change():
    values = torch.tensor([0.0, 1e-40, 1.0, 3e38, math.inf, math.nan])
    y, x = (t.flatten() for t in torch.meshgrid(values, values, indexing="ij"))
    swept_y, swept_x = _sweep(100_000, seed=2)
    y, x = torch.cat([y, swept_y.abs()]), torch.cat([x, swept_x.abs()])
    plain = _polynomials.polynomial_atan2(y, x, True, True, special_values=False)
    guarded = _polynomials.polynomial_atan2(y, x, True, True)
    changed = ~((plain == guarded) | (plain.isnan() & guarded.isnan()))
    both = ((y == 0) & (x == 0)) | ((y == math.inf) & (x == math.inf))
    assert torch.equal(changed, both) and plain[both].isnan().all()


def _atan2_calls(fn, *inputs) -> int:
    """How many ``torch.atan2`` calls dynamo's graph of ``fn`` on ``inputs`` makes."""
    return traced_targets(fn, *inputs).count(torch.atan2)


def test_the_polynomial_is_taken_only_in_the_marked_kernels_float32_cpu_graphs_without_a_gradient():
    y, x = torch.randn(8), torch.randn(8)
    # a user's own compiled code: torch.atan2 (the polynomial would multiply its compile time)
    assert _atan2_calls(_polynomials.atan2, y, x) == 1
    _polynomials.KERNEL_CALL.polynomial_atan2 = True  # (as the dispatcher sets it around a marked kernel)
    try:
        assert _atan2_calls(_polynomials.atan2, y, x) == 0
        assert _atan2_calls(_polynomials.atan2, y.double(), x.double()) == 1  # float64: torch's
        leaf = y.clone().requires_grad_()
        # a recorded gradient: the polynomial's value, torch.atan2's derivative (an autograd.Function)
        assert _atan2_calls(_polynomials.atan2, leaf, x) == 0
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(_polynomials, "TRAINING_POLYNOMIAL", False)
            assert _atan2_calls(_polynomials.atan2, leaf, x) == 1
        with torch.no_grad():
            assert _atan2_calls(_polynomials.atan2, leaf, x) == 0
    finally:
        _polynomials.KERNEL_CALL.polynomial_atan2 = False
    # eager: torch.atan2 always, bit for bit
    assert torch.equal(_polynomials.atan2(y, x), torch.atan2(y, x))


def test_with_a_gradient_the_marked_kernels_take_the_polynomials_value_and_atan2s_exact_derivative():
    # Through min and max the polynomial's own derivative is 0 on the diagonal |x| = |y| (so training
    # graphs kept SLEEF's atan2, an out-of-line call); the autograd.Function keeps its value and
    # gives torch.atan2's derivative everywhere.
    y = torch.tensor([1.0, -2.0, 0.5, 3.0, -1e-3, 0.0, 7.0, -4.0], dtype=F32)
    x = torch.tensor([1.0, 2.0, -0.5, 0.25, 5.0, -2.0, -7.0, -1e-4], dtype=F32)
    w = torch.randn(8, generator=torch.Generator().manual_seed(5), dtype=F32)
    leaves = y.clone().requires_grad_(), x.clone().requires_grad_()
    _polynomials.KERNEL_CALL.polynomial_atan2 = True
    try:
        torch._dynamo.reset()
        out = torch.compile(_polynomials.atan2, backend="aot_eager", fullgraph=True)(*leaves)
        grads = torch.autograd.grad(out, leaves, w)
    finally:
        _polynomials.KERNEL_CALL.polynomial_atan2 = False
    assert torch.equal(out.detach(), _polynomials.polynomial_atan2(y, x))
    expected = torch.autograd.grad(torch.atan2(*leaves), leaves, w)
    for g, e in zip(grads, expected):
        assert torch.equal(g, e)
    own = torch.autograd.grad(_polynomials.polynomial_atan2(*leaves), leaves, w)
    assert not torch.equal(own[0][:3], expected[0][:3])  # (the diagonal rows: not a vacuous check)


def test_the_marked_kernels_graphs_take_the_polynomial_and_a_users_compile_does_not(compiled, monkeypatch):
    import torchquat._dispatch as dispatch

    calls, inputs, current = {}, {}, "inputs"

    def backend(gm, example_inputs):
        nodes = list(gm.graph.nodes)
        calls[current] = sum(node.target is torch.atan2 for node in nodes if node.op == "call_function")
        inputs[current] = [node.name for node in nodes if node.op == "placeholder"
                           and not node.name.startswith("l_tensors_") and not (node.name[0] == "s" and node.name[1:].isdigit())]
        return gm.forward

    monkeypatch.setattr(dispatch, "_backend", backend)
    monkeypatch.setattr(dispatch, "_compiled", {})
    torch._dynamo.reset()
    q = tq.random_quat(64, generator=torch.Generator().manual_seed(1))
    R = tq.quat_to_matrix(q)
    marked = {"q2e": lambda: tq.quat_to_euler(q, "ZYX"), "R2e": lambda: tq.matrix_to_euler(R, "zxz"),
              "q2aa": lambda: tq.quat_to_axis_angle(q), "R2aa": lambda: tq.matrix_to_axis_angle(R),
              "qdist": lambda: tq.quat_geodesic_distance(q, q.flip(0)),
              "Rdist": lambda: tq.matrix_geodesic_distance(R, R.flip(0))}
    for current, call in marked.items():
        with torch.no_grad():
            call()
        assert calls[current] == 0, current
        if _math.literals_trace():  # (its numbers are literals of the graph, not inputs)
            assert inputs[current] == [], current
    # with a gradient: the polynomial's value, atan2's derivative (an autograd.Function, or the
    # distance's closed-form rule, whose forward records nothing)
    current = "distance with a gradient"
    tq.quat_geodesic_distance(q.clone().requires_grad_(), q)
    assert calls[current] == 0
    current = "with a gradient"
    leaf = q.clone().requires_grad_()
    tq.quat_to_euler(leaf, "ZYX")
    assert calls[current] == 0
    monkeypatch.setattr(_polynomials, "TRAINING_POLYNOMIAL", False)
    current = "with a gradient, SLEEF's atan2"
    tq.quat_to_euler(leaf, "ZYX")
    assert calls[current] == 3  # t1, the middle angle, the double angle
    tq.use_compiled_kernels(False)
    torch._dynamo.reset()
    current = "a user's compile"
    torch.compile(lambda x: tq.quat_to_euler(x, "ZYX"), backend=backend, fullgraph=True)(q)
    assert calls[current] == 3


KERNELS = ["quat_to_euler[ZYX]", "quat_to_euler[zxz]", "matrix_to_euler[XZY]", "matrix_to_euler[ZXZ]"]
OTHER_KERNELS = ["quat_to_axis_angle", "matrix_to_axis_angle", "quat_geodesic_distance", "matrix_geodesic_distance"]


def _compiled_and_eager_in_float32(fn, inputs):
    """``fn`` on the inputs rounded to float32 without a gradient: compiled (the switch on), then eager."""
    inputs = tuple(x.to(F32) for x in inputs)
    with torch.no_grad():
        out = fn(*inputs)
        tq.use_compiled_kernels(False)
        try:
            return out, fn(*inputs)
        finally:
            tq.use_compiled_kernels(True)


@pytest.mark.slow
@pytest.mark.parametrize("name", KERNELS)
def test_compiled_float32_euler_angles_without_a_gradient_agree_with_eager(name, compiled):
    fn, generic, singular = ALL[name]
    convention = name[-4:-1]
    for make in (generic, singular):
        out, ref = _compiled_and_eager_in_float32(fn, make())
        # as rotations (next to lock single angles are ill-conditioned; exact half turns are
        # test_compiled_kernels.py's test_compiled_exact_half_turns_are_plus_pi_as_eager)
        assert torch.allclose(tq.euler_to_matrix(out, convention), tq.euler_to_matrix(ref, convention), atol=2e-6)
        assert out.abs().max() <= math.pi


@pytest.mark.slow
@pytest.mark.parametrize("name", OTHER_KERNELS)
def test_compiled_float32_distances_and_rotation_vectors_without_a_gradient_agree_with_eager(name, compiled):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        out, ref = _compiled_and_eager_in_float32(fn, make())
        assert torch.equal(out.isnan(), ref.isnan())
        out, ref = out.nan_to_num(), ref.nan_to_num()
        if "distance" in name:
            assert torch.allclose(out, ref, atol=2e-6, rtol=0)
            assert torch.equal(out == 0, ref == 0)  # equal inputs (and q against -q): exactly 0 on both paths
        else:  # as rotations (a half turn's vector and its negative are one rotation)
            assert torch.allclose(tq.axis_angle_to_matrix(out), tq.axis_angle_to_matrix(ref), atol=2e-6)
            assert torch.linalg.vector_norm(out, dim=-1).max() <= math.pi * (1 + 1e-6)



@pytest.mark.slow
def test_the_polynomial_keeps_its_accuracy_and_special_values_with_contracted_multiply_adds():
    from torchquat import _dispatch

    general = compiled_as_the_polynomial_kernels_are(lambda y, x: _polynomials.polynomial_atan2(y, x))
    if general is None:
        pytest.skip("this torch's inductor has no option to contract multiply-adds")
    name, value = _dispatch._CONTRACT_OPTION
    assert _dispatch._polynomial_options()[name] == value
    first_quadrant = compiled_as_the_polynomial_kernels_are(
        lambda y, x: _polynomials.polynomial_atan2(y, x, True, True))
    y, x = _sweep(400_000, seed=4)
    exact = torch.atan2(y.double(), x.double())
    assert _ulps(general(y, x), exact).max() <= 2.0 and _ulps(general(y, x), exact).mean() < 0.5
    exact_first = torch.atan2(y.abs().double(), x.abs().double())
    assert _ulps(first_quadrant(y.abs(), x.abs()), exact_first).max() <= 2.0
    values = torch.tensor([0.0, -0.0, 1.0, -1.0, math.inf, -math.inf, math.nan, 1e-40, -1e-40, 3e38, -3e38])
    y, x = (t.flatten() for t in torch.meshgrid(values, values, indexing="ij"))
    ours, expected = general(y, x), torch.atan2(y.double(), x.double()).to(F32)
    assert torch.equal(ours.isnan(), expected.isnan())
    finite = ~expected.isnan()
    assert torch.equal(ours[finite], expected[finite])
    assert torch.equal(torch.signbit(ours[finite]), torch.signbit(expected[finite]))
