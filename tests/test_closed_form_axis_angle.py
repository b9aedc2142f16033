"""The axis-angle kernels' closed-form Jacobians (torchquat._closed_form) against autograd through
the plain small-batch forward, on generic rotations and at the singular ones."""

import math

import pytest
import torch

import torchquat as tq
from torchquat import axis_angle as A
from function_table import quats, singular_axis_angles, singular_quats, vectors

F64 = torch.float64
EPS = torch.finfo(F64).eps


def _axes(n=4, seed=11):
    axes = torch.randn(n, 3, generator=torch.Generator().manual_seed(seed), dtype=F64)
    return torch.nn.functional.normalize(axes, dim=-1)


def _singular_vectors():
    axes = _axes()
    threshold = EPS ** 0.25  # the series' threshold on theta (theta^2 < sqrt(eps))
    near = [threshold * f for f in (1 - 1e-12, 1.0, 1 + 1e-12, 0.5, 2.0)]
    angles = near + [0.0, 1e-300, 1e-12, 1e-9, 1e-5, math.pi - 1e-9, math.pi, 2 * math.pi, 3 * math.pi, -math.pi]
    return torch.cat([singular_axis_angles()] + [axes * a for a in angles])


def _singular_quats():
    q = singular_quats()
    axes = _axes()
    one = torch.ones(axes.shape[0], 1, dtype=F64)
    below, above = [torch.cat([w * one, axes * (EPS ** 0.5 * f)], dim=-1)  # |u| / w around sqrt(eps)
                    for w, f in ((1.0, 1 - 1e-9), (-1.0, 1 + 1e-9))]
    special = torch.tensor([[1.0, 0, 0, 0], [-1.0, 0, 0, 0], [2.0, 0, 0, 0], [1e-3, 0, 0, 0],
                            [0.0, 1, 0, 0], [-0.0, 0, 0.6, 0.8], [0.0, 0, 3, 4], [1e-300, 0, 0, 1]], dtype=F64)
    return torch.cat([q, -q, q * 3.7, q * 1e-3, below, above, torch.cat([0 * one, axes], dim=-1), special])


CASES = {  # name -> (plain forward, with_jacobian, public function, generic inputs, singular inputs)
    "axis_angle_to_quat": (A._axis_angle_to_quat_small, A._axis_angle_to_quat_with_jacobian, tq.axis_angle_to_quat,
                           lambda n=40, seed=3: vectors(n, seed) * 3, _singular_vectors),
    "quat_to_axis_angle": (A._quat_to_axis_angle_small, A._quat_to_axis_angle_with_jacobian, tq.quat_to_axis_angle,
                           lambda n=40, seed=4: quats(n, seed), _singular_quats),
}


def _jacrev(plain, x):
    """Autograd's Jacobian of the plain forward, as ``(rows, input size, output size)``."""
    return torch.func.vmap(torch.func.jacrev(plain))(x).transpose(-1, -2)


def _assert_close(got, expected):
    # the Jacobians scale as 1 / |q| for quat_to_axis_angle: compare relative to each row's size
    size = 1.0 + expected.abs().amax(dim=(-2, -1), keepdim=True)
    assert ((got - expected).abs() / size).max() < 1e-13


@pytest.mark.parametrize("inputs", ["generic", "singular"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_jacobian_matches_autograd_of_the_plain_forward(name, inputs):
    plain, with_jacobian, _, generic, singular = CASES[name]
    x = (generic if inputs == "generic" else singular)()
    value, jacobian = with_jacobian(x)
    assert torch.equal(value, plain(x))
    expected = _jacrev(plain, x)
    assert torch.isfinite(expected).all() and torch.isfinite(jacobian).all()
    _assert_close(jacobian, expected)


@pytest.mark.parametrize("name", sorted(CASES))
def test_the_public_function_takes_the_closed_form_backward(name):
    plain, _, public, generic, singular = CASES[name]
    for x in torch.cat([generic(), singular()]).split(200):  # (the closed form serves a few hundred rows)
        leaf = x.clone().requires_grad_()
        out = public(leaf)
        assert type(out.grad_fn).__name__ == "_ClosedFormBackward"
        assert torch.equal(out, plain(x))
        grad = torch.randn(out.shape, dtype=F64, generator=torch.Generator().manual_seed(5))
        (g,) = torch.autograd.grad(out, leaf, grad)
        expected = (_jacrev(plain, x) * grad.unsqueeze(-2)).sum(-1)
        _assert_close(g.unsqueeze(-1), expected.unsqueeze(-1))


_COLUMNS_WITH_A_GRAPH_ABOVE = {"axis_angle_to_quat": 768, "quat_to_axis_angle": 512}
_VALUES_OF_THEIR_OWN = {"axis_angle_to_quat"}


@pytest.mark.parametrize("rows", [1, 7, 300, 1000])  # 1000: above quat_to_axis_angle's closed form
@pytest.mark.parametrize("name", sorted(CASES))
def test_values_without_a_graph_equal_the_plain_forward(name, rows):
    # Nothing to differentiate: the rule's values path runs, without the substitutes that keep
    # autograd finite (the series branch takes those rows). Same numbers with or without a graph.
    plain, _, public, generic, singular = CASES[name]
    x = torch.cat([singular(), generic(3000, seed=7)])[:rows]
    expected = plain(x)
    # (axis_angle_to_quat's values path has its own formula, no series: equal to rounding)
    rtol = 2 * torch.finfo(F64).eps if name in _VALUES_OF_THEIR_OWN else 0
    torch.testing.assert_close(public(x), expected, rtol=rtol, atol=0, equal_nan=True)
    # (with a graph to record, batches above these bounds take the columns' closed form, faster
    # forward and backward there: the same numbers to rounding)
    atol = 4 * torch.finfo(F64).eps if rows > _COLUMNS_WITH_A_GRAPH_ABOVE.get(name, rows) else 0
    torch.testing.assert_close(public(x.clone().requires_grad_()).detach(), expected, rtol=0, atol=atol, equal_nan=True)
    with torch.no_grad():
        torch.testing.assert_close(public(x.clone().requires_grad_()), expected, rtol=rtol, atol=0, equal_nan=True)


@pytest.mark.parametrize("name", sorted(_COLUMNS_WITH_A_GRAPH_ABOVE))
def test_batches_above_the_closed_form_get_the_same_gradient(name):
    # with a graph, larger batches take the columns' closed form (before, quat_to_axis_angle's
    # autograd through the table up to 32,768 rows: 1.1-1.4x slower forward and backward)
    _, _, public, generic, _ = CASES[name]
    x = generic(1500, seed=6)
    leaf = x.clone().requires_grad_()
    out = public(leaf)
    assert type(out.grad_fn).__name__ == "_ClosedFormBackward"
    (g,) = torch.autograd.grad(out.sum(), leaf)
    pieces = [chunk.clone().requires_grad_() for chunk in x.split(100)]
    g_pieces = torch.autograd.grad(sum(public(p).sum() for p in pieces), pieces)
    assert torch.allclose(g, torch.cat(g_pieces), atol=1e-13, rtol=0)


@pytest.mark.parametrize("shape", [(), (1,), (2, 1, 3)])
@pytest.mark.parametrize("name", sorted(CASES))
def test_batch_shapes(name, shape):
    plain, _, public, generic, _ = CASES[name]
    x = generic()[:math.prod(shape)].reshape(shape + (-1,))
    leaf = x.clone().requires_grad_()
    out = public(leaf)
    (g,) = torch.autograd.grad(out.sum(), leaf)
    reference = x.clone().requires_grad_()
    (expected,) = torch.autograd.grad(plain(reference).sum(), reference)
    assert g.shape == x.shape
    assert torch.allclose(g, expected, atol=1e-14, rtol=0)


@pytest.mark.parametrize("name", sorted(CASES))
def test_double_backward_is_exact(name):
    _, _, public, generic, _ = CASES[name]
    x = generic()[:4].clone().requires_grad_()
    assert torch.autograd.gradgradcheck(public, (x,))


@pytest.mark.parametrize("name", sorted(CASES))
def test_float32_jacobian_matches_autograd(name):
    # float32's cancellations next to the thresholds are the largest relative to its eps. (Against
    # float64 the half turns would differ: there the float32 angle may round to the other side of pi.)
    plain, with_jacobian, _, generic, singular = CASES[name]
    x = torch.cat([generic(), singular()])
    x = x[(x.abs().amax(-1) > 1e-30) & (x.abs().amax(-1) < 1e30)].float()  # float32's range
    value, jacobian = with_jacobian(x)
    assert torch.equal(value, plain(x))
    expected = _jacrev(plain, x)
    size = 1.0 + expected.abs().amax(dim=(-2, -1), keepdim=True)
    assert ((jacobian - expected).abs() / size).max() < 1e-6


COLUMNWISE = {  # name -> (the large batches' plain forward (autograd's, and compiled), their rule)
    "axis_angle_to_quat": (A._axis_angle_to_quat_columnwise, A._AXIS_ANGLE_TO_QUAT_COLUMNWISE),
    "quat_to_axis_angle": (A._quat_to_axis_angle_columnwise, A._QUAT_TO_AXIS_ANGLE_COLUMNWISE),
}


@pytest.mark.parametrize("planes", [False, True], ids=["strided", "planar"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_large_batch_closed_form_matches_autograd_of_the_columnwise_forward(name, planes, monkeypatch):
    # Large batches: values without substitutes (sin(x) / x down to x^2 < eps^2) and the
    # Jacobian's own series, against autograd through the column code with its series
    import torchquat._math as tqmath
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0 if planes else 10**12)
    plain, rule = COLUMNWISE[name]
    _, _, public, generic, singular = CASES[name]
    x = torch.cat([generic(), singular()])
    grad = torch.randn(x.shape[0], 4 if name == "axis_angle_to_quat" else 3, dtype=F64,
                       generator=torch.Generator().manual_seed(21))
    leaf = x.clone().requires_grad_()
    expected = plain(leaf)
    (g_expected,) = torch.autograd.grad(expected, leaf, grad)
    leaf = x.clone().requires_grad_()
    out = public(leaf)
    assert type(out.grad_fn).__name__ == "_ClosedFormBackward"
    (g,) = torch.autograd.grad(out, leaf, grad)
    size = 1.0 + expected.detach().abs().amax(-1, keepdim=True)
    assert ((out.detach() - expected.detach()).abs() / size).max() < 4 * EPS
    torch.testing.assert_close(public(x), out.detach(), rtol=0, atol=0, equal_nan=True)  # values: the same numbers
    assert torch.isfinite(g).all()
    size = 1.0 + g_expected.abs().amax(-1, keepdim=True)
    assert ((g - g_expected).abs() / size).max() < 1e-13


@pytest.mark.parametrize("fn", [tq.axis_angle_to_quat, tq.axis_angle_to_matrix, tq.quat_to_axis_angle,
                                tq.matrix_to_axis_angle])
def test_second_derivatives_at_the_zero_rotation_are_exact(fn):
    # The map is analytic there, but a norm's second derivative at 0 is NaN even where no
    # gradient flows through it: the plain forward (double backward, torch.func) takes the
    # series in v . v and the square root of a substitute, no norm
    v = torch.tensor([[0.0, 0.0, 0.0], [1e-9, -2e-9, 0.0], [3e-5, 0.0, -1e-5], [0.3, -0.2, 0.5]], dtype=torch.float64)
    x = {tq.quat_to_axis_angle: tq.axis_angle_to_quat(v), tq.matrix_to_axis_angle: tq.axis_angle_to_matrix(v)}.get(fn, v)
    x = x.clone().requires_grad_()
    assert torch.autograd.gradcheck(fn, (x,))
    assert torch.autograd.gradgradcheck(fn, (x,))
    hessian = torch.autograd.functional.hessian(lambda y: fn(y).pow(2).sum() + fn(y).sum(), x[:1])
    assert torch.isfinite(hessian).all()
