"""The float32 cos and sin of the compiled CPU kernels that build rotations from half angles:
the reduced polynomial (``_polynomials.polynomial_cos_sin``) and the direct ones without a reduction
(``half_cos_sinc``, ``direct_cos_sinc``): their accuracy, signs and special values, where the
dispatcher takes each (angles within ``_polynomials.POLYNOMIAL_SINCOS_RANGE``, and within the
kernels' direct bounds), and those kernels against float64."""

import math

import pytest
import torch

import torchquat as tq
from torchquat import _polynomials
from function_table import ALL, compiled_as_the_polynomial_kernels_are, traced_targets

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


def _float64_errors(x: torch.Tensor, c: torch.Tensor, sin: torch.Tensor):
    exact = x.double()
    return (c.double() - torch.cos(exact)).abs(), (sin.double() - torch.sin(exact)).abs()


def test_the_direct_polynomials_are_cos_and_sin_over_their_ranges():
    g = torch.Generator().manual_seed(1)
    # half_cos_sinc: y up to 1.0005 pi / 2 (the direct Euler bound's half angle); direct_cos_sinc: x up to
    # 1.0005 pi (a rotation vector's half angle for entries within the direct bound), both signs
    half_euler = _polynomials.DIRECT_EULER_ANGLES / 2
    half_vector = _polynomials.DIRECT_ROTATION_VECTOR_ENTRIES * 3 ** 0.5 / 2
    for fn, top, cos_bound, sin_bound in ((_polynomials.half_cos_sinc, half_euler, 1e-7, 2.2e-7),
                                          (_polynomials.direct_cos_sinc, half_vector, 3.8e-7, 2.8e-7)):
        x = torch.cat([torch.rand(1_000_000, generator=g, dtype=F64) * 2 - 1,
                       torch.linspace(-1, 1, 200_001, dtype=F64)]).mul(top).to(F32)
        assert x.abs().max() <= top * (1 + 2 ** -23)
        c, sinc = fn(x * x)
        cos_error, sin_error = _float64_errors(x, c, x * sinc)
        assert cos_error.max() < cos_bound and sin_error.max() < sin_bound, (fn, cos_error.max(), sin_error.max())
        assert cos_error.mean() < 6e-8 and sin_error.mean() < 6e-8
        # exact at 0: cos 0 = 1, sin(x) / x = 1, so x * sinc keeps -0.0 and tiny angles to the last bit
        tiny = torch.tensor([0.0, -0.0, 1e-30, -1e-20, 1e-4])
        c, sinc = fn(tiny * tiny)
        assert c[:4].tolist() == [1.0] * 4 and sinc[:4].tolist() == [1.0] * 4
        assert torch.signbit(tiny * sinc).tolist() == [False, True, False, True, False]
        assert ((tiny * sinc).double() / torch.sin(tiny.double()))[2:].sub(1).abs().max() < 1.2e-7


def test_the_direct_bounds_hold_float32_pi_and_the_polynomials_range():
    # float32's pi (8.7e-8 above pi) is an Euler angle atan2 returns: it takes the direct polynomial
    assert torch.tensor(math.pi, dtype=F32).item() <= _polynomials.DIRECT_EULER_ANGLES
    # the half angle of a rotation vector with every entry at the bound: within direct_cos_sinc's range
    half = 3 ** 0.5 * _polynomials.DIRECT_ROTATION_VECTOR_ENTRIES / 2
    assert math.pi < half <= 1.0005 * math.pi
    assert _polynomials.DIRECT_EULER_ANGLES / 2 <= 1.0005 * math.pi / 2


def _trig_calls(fn, *inputs) -> int:
    """How many ``torch.cos`` and ``torch.sin`` calls dynamo's graph of ``fn`` on ``inputs`` makes."""
    targets = traced_targets(fn, *inputs)
    return targets.count(torch.cos) + targets.count(torch.sin)


def test_the_polynomial_is_taken_only_in_marked_float32_cpu_graphs_without_a_gradient():
    x = torch.randn(8)
    assert _trig_calls(_polynomials.cos_sin_up_to_sign, x) == 2  # a user's own compiled code: torch's
    # (as the dispatcher sets it for angles in the direct bound: no reduction either)
    _polynomials.KERNEL_CALL.polynomial_sincos = _polynomials.SINCOS_DIRECT
    try:
        targets = traced_targets(_polynomials.cos_sin_up_to_sign, x)
        assert torch.cos not in targets and torch.sin not in targets and torch.round not in targets
        assert traced_targets(_polynomials.cos_sinc_of_squares, x * x) != []  # its polynomials
    finally:
        _polynomials.KERNEL_CALL.polynomial_sincos = _polynomials.SINCOS_TORCH
    assert _polynomials.cos_sinc_of_squares(x * x) is None  # eager: the caller's own forms
    _polynomials.KERNEL_CALL.polynomial_sincos = _polynomials.SINCOS_REDUCED  # (for angles in the range)
    try:
        assert torch.round in traced_targets(_polynomials.cos_sin_up_to_sign, x)
        assert _trig_calls(_polynomials.cos_sin_up_to_sign, x) == 0
        assert _trig_calls(_polynomials.cos_sin_up_to_sign, x.double()) == 2  # float64: torch's
        leaf = x.clone().requires_grad_()
        assert _trig_calls(_polynomials.cos_sin_up_to_sign, leaf) == 2  # a recorded gradient: torch's exact one
        with torch.no_grad():
            assert _trig_calls(_polynomials.cos_sin_up_to_sign, leaf) == 0
    finally:
        _polynomials.KERNEL_CALL.polynomial_sincos = _polynomials.SINCOS_TORCH
    # eager: torch's, bit for bit
    c, s = _polynomials.cos_sin_up_to_sign(x)
    assert torch.equal(c, torch.cos(x)) and torch.equal(s, torch.sin(x))


def test_the_dispatcher_takes_the_polynomial_only_for_angles_within_its_range(compiled, monkeypatch):
    import torchquat._dispatch as dispatch

    graphs, reductions = [], []

    def backend(gm, example_inputs):
        # (the graph's own calls and its subgraphs': a training graph applies the kernel's
        # closed-form rule as an autograd.Function, whose forward and backward are subgraphs)
        targets = [node.target for module in gm.modules() for node in module.graph.nodes if node.op == "call_function"]
        graphs.append(targets.count(torch.cos) + targets.count(torch.sin))
        reductions.append(targets.count(torch.round))  # (the reduced polynomial's k = round(2x / pi))
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
        # within pi (and float32's pi itself): the direct polynomials, no reduction
        direct = angles.clone()
        direct[3] = torch.tensor([math.pi, -math.pi, _polynomials.DIRECT_EULER_ANGLES])
        assert trig_calls(lambda: tq.euler_to_quat(direct, "ZYX")) == [0] and reductions[-1] == 0
        assert trig_calls(lambda: tq.euler_to_quat(angles, "ZYX")) == []  # the same graph
        assert trig_calls(lambda: tq.axis_angle_to_matrix(angles)) == [0] and reductions[-1] == 0
        # rotation vectors' entries within 2 pi / sqrt(3): direct (their half angle within pi)
        vectors = angles.clone()
        vectors[9] = _polynomials.DIRECT_ROTATION_VECTOR_ENTRIES
        assert trig_calls(lambda: tq.axis_angle_to_matrix(vectors)) == []
        # past the direct bounds (within the reduced range): the reduced polynomial, its graph once
        wide = angles.clone()
        wide[5, 1] = -bound  # (the range's edge is in it)
        assert trig_calls(lambda: tq.euler_to_quat(wide, "ZYX")) == [0] and reductions[-1] > 0
        wide[5, 1] = -_polynomials.DIRECT_EULER_ANGLES * 1.0001
        assert trig_calls(lambda: tq.euler_to_quat(wide, "ZYX")) == []  # the same graph
        vectors[9, 2] *= 1.0001
        assert trig_calls(lambda: tq.axis_angle_to_matrix(vectors)) == [0] and reductions[-1] > 0
        for outside in (bound * 1.001, math.nan, math.inf):
            beyond = angles.clone()
            beyond[7, 2] = outside
            # a graph of its own with torch's cos and sin, traced once
            traced = trig_calls(lambda: tq.euler_to_quat(beyond, "ZYX"))
            assert traced in ([6], [])
        assert len([n for n in graphs if n == 6]) == 1
        assert trig_calls(lambda: tq.euler_to_quat(angles.double(), "ZYX")) == [6]
    leaf = angles.clone().requires_grad_()  # (torch's cos and sin: the polynomials' derivatives are not theirs)
    assert all(n > 0 for n in trig_calls(lambda: tq.euler_to_quat(leaf, "ZYX")))


def test_a_call_whose_range_differs_from_the_last_runs_again_with_the_graph_its_own_range_needs(compiled, monkeypatch):
    import torchquat._dispatch as dispatch

    runs = []  # (each graph's number of cos and sin calls, every time it runs)

    def backend(gm, example_inputs):
        trig = sum(node.target in (torch.cos, torch.sin) for node in gm.graph.nodes if node.op == "call_function")
        rounds = sum(node.target is torch.round for node in gm.graph.nodes if node.op == "call_function")

        def forward(*args):
            runs.append("torch" if trig else "reduced" if rounds else "direct")
            return gm.forward(*args)

        return forward

    monkeypatch.setattr(dispatch, "_backend", backend)
    monkeypatch.setattr(dispatch, "_compiled", {})
    monkeypatch.setattr(dispatch, "_sincos_guesses", {})
    torch._dynamo.reset()
    g = torch.Generator().manual_seed(1)
    within = torch.rand(64, 3, generator=g) * 6 - 3
    wide, beyond = within * 100, within.clone()
    beyond[10, 0] = math.nan

    def graphs_run(x):
        before = len(runs)
        with torch.no_grad():
            out = tq.euler_to_quat(x, "ZYX")
        return runs[before:], out

    first, direct = graphs_run(within)
    assert first == ["direct"]
    assert graphs_run(wide)[0] == ["direct", "reduced"]  # (the guess was the last call's range)
    assert graphs_run(wide)[0] == ["reduced"]
    ran, out = graphs_run(within)  # the reduced polynomial would be right too, but not the same numbers
    assert ran == ["reduced", "direct"] and torch.equal(out, direct)
    ran, out = graphs_run(beyond)
    assert ran == ["direct", "torch"] and torch.isnan(out[10]).all() and not torch.isnan(out[:10]).any()
    ran, out = graphs_run(within)
    assert ran == ["torch", "direct"] and torch.equal(out, direct)
    # each kernel (and static option) guesses from its own last call, and its first call from an
    # aminmax of its input: no graph is compiled that the input does not need
    assert graphs_run(beyond)[0] == ["direct", "torch"]
    with torch.no_grad():
        before = len(runs)
        tq.euler_to_quat(within, "XYZ")
        tq.euler_to_quat(wide, "ZXZ")
        tq.axis_angle_to_quat(beyond)
    assert runs[before:] == ["direct", "reduced", "torch"]


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
    # the direct polynomials' edge: every angle, or every entry of a rotation vector, at the bound
    # (a vector's half angle 1.0005 pi), both signs, and the largest float32 within it
    direct_bound = (_polynomials.DIRECT_ROTATION_VECTOR_ENTRIES if name.startswith("axis_angle")
                    else _polynomials.DIRECT_EULER_ANGLES)
    top = torch.tensor(direct_bound, dtype=F64).to(F32)
    top = torch.where(top.double() > direct_bound, torch.nextafter(top, torch.zeros(())), top)
    signs = torch.tensor([[1.0, 1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    at_the_bound = torch.cat([signs * top, _big_batch(200, 1.0, seed=6) * top])
    batches = [singular()[0].to(F32), generic()[0].to(F32), at_the_bound, _big_batch(),
               _big_batch(200, bound, seed=5), beyond]
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


@pytest.mark.slow
def test_the_polynomials_keep_their_accuracy_with_contracted_multiply_adds():
    # compiled as the kernels' polynomial graphs are: multiply-adds contracted into fma where torch's
    # inductor has that option (_dispatch._polynomial_options); the bounds of the eager tests above
    compile_ = compiled_as_the_polynomial_kernels_are
    reduced = compile_(_polynomials.polynomial_cos_sin)
    if reduced is None:
        pytest.skip("this torch's inductor has no option to contract multiply-adds")
    half = compile_(lambda y: (lambda c, r: (c, y * r))(*_polynomials.half_cos_sinc(y * y)))
    wide = compile_(lambda x: (lambda c, r: (c, x * r))(*_polynomials.direct_cos_sinc(x * x)))
    g = torch.Generator().manual_seed(5)
    x = ((torch.rand(400_000, generator=g, dtype=F64) * 2 - 1) * _polynomials.POLYNOMIAL_SINCOS_RANGE).to(F32)
    c, s = reduced(x)
    cos, sin = torch.cos(x.double()), torch.sin(x.double())
    sigma = torch.sign(c.double() * cos + s.double() * sin)
    assert torch.all(sigma.abs() == 1)
    assert (sigma * c.double() - cos).abs().max() < 1.2e-7 and (sigma * s.double() - sin).abs().max() < 1.2e-7
    for fn, top, cos_bound, sin_bound in ((half, _polynomials.DIRECT_EULER_ANGLES / 2, 1e-7, 2.2e-7),
                                          (wide, _polynomials.DIRECT_ROTATION_VECTOR_ENTRIES * 3 ** 0.5 / 2, 3.8e-7, 2.8e-7)):
        y = ((torch.rand(400_000, generator=g, dtype=F64) * 2 - 1) * top).to(F32)
        cos_error, sin_error = _float64_errors(y, *fn(y))
        assert cos_error.max() < cos_bound and sin_error.max() < sin_bound, (cos_error.max(), sin_error.max())
        zeros = torch.tensor([0.0, -0.0])
        c, s = fn(zeros)
        assert c.tolist() == [1.0, 1.0] and torch.signbit(s).tolist() == [False, True]
    c, s = reduced(torch.tensor([0.0, -0.0]))
    assert c.tolist() == [1.0, 1.0] and torch.signbit(s).tolist() == [False, True]
