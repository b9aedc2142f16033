"""Gradients: gradcheck in float64 at generic points, and finite gradients at every singular set
(identity, half turns about every axis, gimbal lock for all 24 conventions, zero axis-angle)."""

import pytest
import torch

import torchquat as tq
from function_table import ALL


@pytest.mark.parametrize("name", sorted(ALL))
def test_gradcheck_at_generic_points(name):
    fn, generic, _ = ALL[name]
    inputs = tuple(x.requires_grad_() for x in generic())
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-7)


@pytest.mark.parametrize("name", sorted(ALL))
def test_gradients_are_finite_at_singular_points(name):
    fn, _, singular = ALL[name]
    inputs = tuple(x.clone().requires_grad_() for x in singular())
    out = fn(*inputs)
    grad_out = torch.randn(out.shape, dtype=out.dtype, generator=torch.Generator().manual_seed(0))
    grads = torch.autograd.grad(out, inputs, grad_out, allow_unused=True)
    for g in grads:
        assert g is None or torch.isfinite(g).all(), f"non-finite gradient rows: {(~torch.isfinite(g)).any(-1).nonzero().flatten().tolist()}"


@pytest.mark.parametrize("name", ["quat_geodesic_distance", "matrix_geodesic_distance"])
def test_distance_gradient_at_zero_is_finite_and_descends_elsewhere(name):
    fn, generic, _ = ALL[name]
    a, b = generic()
    a = a.clone().requires_grad_()
    (g,) = torch.autograd.grad(fn(a, a.detach()).sum(), a)
    assert torch.isfinite(g).all()
    d = fn(a, b).sum()
    (g,) = torch.autograd.grad(d, a)
    with torch.no_grad():
        stepped = a - 1e-4 * g
    assert fn(stepped, b).sum() < d


def test_rot9d_backward_is_finite_when_singular_values_coincide():
    R = tq.quat_to_matrix(tq.random_quat(8, generator=torch.Generator().manual_seed(1), dtype=torch.float64))
    M = torch.cat([R, 2.5 * R, torch.diag_embed(torch.tensor([[1.0, 1.0, 0.0], [3.0, 3.0, -3.0]], dtype=torch.float64))])
    M.requires_grad_()
    (g,) = torch.autograd.grad(tq.rot9d_to_matrix(M).square().mul(torch.arange(9.0, dtype=torch.float64).view(3, 3)).sum(), M)
    assert torch.isfinite(g).all()


def test_rot9d_gradient_matches_finite_differences_at_a_rotation():
    # a rotation input has three equal singular values: where autograd through svd is NaN
    R = tq.quat_to_matrix(tq.random_quat(2, generator=torch.Generator().manual_seed(2), dtype=torch.float64))
    assert torch.autograd.gradcheck(tq.rot9d_to_matrix, (R.clone().requires_grad_(),), eps=1e-6, atol=1e-7)


@pytest.mark.parametrize("name", ["quat_multiply", "quat_rotate", "quat_geodesic_distance", "matrix_geodesic_distance",
                                  "quat_slerp"])
@pytest.mark.parametrize("rows", [1, 40_000], ids=["small", "large"])
def test_create_graph_gives_the_same_gradient_when_one_input_comes_from_the_other(name, rows):
    # With create_graph the closed forms re-differentiate their plain forward; each input's
    # partial derivative must stay its own (the same tensor twice, or b computed from a).
    fn, generic, _ = ALL[name]
    a = generic()[0]
    a = a.repeat((-(-rows // a.shape[0]),) + (1,) * (a.dim() - 1))[:rows].clone().requires_grad_()
    second = (lambda x: x[..., 1:]) if name == "quat_rotate" else (lambda x: x)  # (rotate: a vector)
    for b_of_a in (lambda a: second(a), lambda a: second(0.5 * a + 0.1)):
        def loss():
            out = fn(a, b_of_a(a))
            return (out * torch.linspace(0.5, 1.5, out.numel(), dtype=a.dtype).view(out.shape)).sum()
        plain, = torch.autograd.grad(loss(), a)
        graphed, = torch.autograd.grad(loss(), a, create_graph=True)
        torch.testing.assert_close(graphed, plain, rtol=0, atol=1e-12)


def test_double_backward_hessian_equals_torch_func_hessian_with_related_inputs():
    q = tq.random_quat(1, generator=torch.Generator().manual_seed(3), dtype=torch.float64)[0]
    shift = torch.tensor([0.1, 0.2, 0.0, 0.3], dtype=torch.float64)
    f = lambda q: tq.quat_geodesic_distance(q, 0.5 * q + shift)
    x = q.clone().requires_grad_()
    (g,) = torch.autograd.grad(f(x), x, create_graph=True)
    H = torch.stack([torch.autograd.grad(g[i], x, retain_graph=True)[0] for i in range(4)])
    torch.testing.assert_close(H, torch.func.hessian(f)(q), rtol=0, atol=1e-10)


def test_rot9d_forward_mode_matches_reverse_mode_and_finite_differences():
    x = torch.randn(5, 9, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    t = torch.randn(5, 9, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    _, tangent = torch.func.jvp(tq.rot9d_to_matrix, (x,), (t,))
    J = torch.func.vmap(torch.func.jacrev(tq.rot9d_to_matrix))(x)  # the closed-form backward
    torch.testing.assert_close(tangent, (J * t[:, None, None, :]).sum(-1), rtol=0, atol=1e-12)
    fd = (tq.rot9d_to_matrix(x + 1e-6 * t) - tq.rot9d_to_matrix(x - 1e-6 * t)) / 2e-6
    torch.testing.assert_close(tangent, fd, rtol=0, atol=1e-8)
    R = tq.quat_to_matrix(tq.random_quat(3, dtype=torch.float64)).flatten(-2)  # equal singular values
    assert torch.isfinite(torch.func.jvp(tq.rot9d_to_matrix, (R,), (torch.ones_like(R),))[1]).all()


@pytest.mark.parametrize("dtype,scale", [(torch.float64, 1e-20), (torch.float64, 1e20), (torch.float32, 1e-8)])
def test_rot9d_gradient_is_scale_invariant(dtype, scale):
    # R(c M) = R(M), so the gradient at c M is the gradient at M over c. An absolute eps floor on
    # s_i + s_j shrank the gradients of matrices with small singular values (1e-8 in float32: 87%)
    g = torch.Generator().manual_seed(11)
    M = torch.randn(4, 3, 3, generator=g, dtype=torch.float64)
    W = torch.randn(4, 3, 3, generator=g, dtype=torch.float64)

    def gradient(x):
        x = x.clone().requires_grad_()
        (grad,) = torch.autograd.grad((tq.rot9d_to_matrix(x) * W.to(x.dtype)).sum(), x)
        return grad.double()

    expected = gradient(M.to(dtype))
    tolerance = 1e-13 if dtype == torch.float64 else 1e-4  # (float32 SVDs: 1e-5 apart at any scale)
    torch.testing.assert_close(gradient((scale * M).to(dtype)) * scale, expected, rtol=0, atol=tolerance * expected.abs().max())


def _rot9d_hessian_by_differences(f, M, eps=1e-6):
    """The Hessian of scalar ``f`` at ``M`` (3 x 3) from central differences of its first-order
    gradient (the closed-form backward, checked against differences of R above)."""
    def gradient(x):
        x = x.clone().requires_grad_()
        return torch.autograd.grad(f(x), x)[0].flatten()
    steps = eps * torch.eye(9, dtype=M.dtype).view(9, 3, 3)
    return torch.stack([(gradient(M + d) - gradient(M - d)) / (2 * eps) for d in steps])


@pytest.mark.parametrize("at", ["generic", "rotation", "reflection"])
def test_rot9d_second_derivatives_match_differences_of_the_gradient(at):
    # Before, torch.func.hessian, jacrev(jacrev) and jacfwd(jacrev) returned 0 and
    # autograd.functional.jvp returned 0 (the backward ran under no_grad); create_graph raised.
    g = torch.Generator().manual_seed(8)
    M = {"generic": torch.randn(3, 3, dtype=torch.float64, generator=g),
         "rotation": 2.0 * tq.quat_to_matrix(tq.random_quat(1, generator=g, dtype=torch.float64))[0],  # s1 = s2 = s3
         "reflection": torch.diag(torch.tensor([3.0, 2.0, -1.0], dtype=torch.float64))}[at]  # det < 0: s'3 < 0
    W = torch.randn(3, 3, dtype=torch.float64, generator=g)
    f = lambda x: (tq.rot9d_to_matrix(x) * W).sum() + tq.rot9d_to_matrix(x)[..., 0, 1].pow(2).sum()
    expected = _rot9d_hessian_by_differences(f, M)
    assert expected.abs().max() > 0.1  # (the check is not vacuous)
    with torch.no_grad():  # (functorch runs the backward without grad mode here)
        under_no_grad = torch.func.hessian(f)(M)
    for H in (torch.func.hessian(f)(M), torch.func.jacrev(torch.func.jacrev(f))(M),
              torch.func.jacrev(torch.func.jacfwd(f))(M), under_no_grad,
              torch.func.vmap(torch.func.hessian(f))(M.expand(2, 3, 3))[1],  # (linalg.solve: wrong here)
              torch.autograd.functional.hessian(f, M), torch.autograd.functional.hessian(f, M, vectorize=True)):
        torch.testing.assert_close(H.reshape(9, 9), expected, rtol=0, atol=1e-8)
    x = M.clone().requires_grad_()
    (grad,) = torch.autograd.grad(f(x), x, create_graph=True)
    rows = torch.stack([torch.autograd.grad(grad.flatten()[i], x, retain_graph=True)[0].flatten() for i in range(9)])
    torch.testing.assert_close(rows, expected, rtol=0, atol=1e-8)


@pytest.mark.parametrize("dtype,scale", [(torch.float32, 1e-38), (torch.float32, 1e30), (torch.float64, 1e-300)])
def test_rot9d_gradient_with_a_graph_equals_the_closed_form_at_any_scale(dtype, scale):
    # the differentiable form's floor is relative (an absolute one lost the digits below 1e-36 in float32)
    g = torch.Generator().manual_seed(10)
    M = (torch.randn(4, 3, 3, generator=g, dtype=torch.float64) * scale).to(dtype)
    W = torch.randn(4, 3, 3, generator=g, dtype=torch.float64).to(dtype)
    gradients = []
    for create_graph in (False, True):
        x = M.clone().requires_grad_()
        gradients.append(torch.autograd.grad((tq.rot9d_to_matrix(x) * W).sum(), x, create_graph=create_graph)[0].detach())
    torch.testing.assert_close(gradients[1], gradients[0], rtol=0, atol=1e3 * torch.finfo(dtype).eps * gradients[0].abs().max())


def test_rot9d_jvp_by_double_backward_equals_forward_mode():
    # torch.autograd.functional.jvp differentiates the backward in its incoming gradient: it was 0
    x = torch.randn(5, 9, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    t = torch.randn(5, 9, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    _, expected = torch.func.jvp(tq.rot9d_to_matrix, (x,), (t,))
    _, tangent = torch.autograd.functional.jvp(tq.rot9d_to_matrix, x, t)
    torch.testing.assert_close(tangent, expected, rtol=0, atol=1e-12)


def test_rot9d_gradient_penalty_through_a_loss_linear_in_the_rotation():
    # the once-differentiable version raised here (and before that, was silently 100% off)
    layer = torch.nn.Linear(4, 9, dtype=torch.float64)
    x = torch.randn(5, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    target = tq.quat_to_matrix(tq.random_quat(5, generator=torch.Generator().manual_seed(7), dtype=torch.float64))

    def penalty(weight):
        w = weight.clone().requires_grad_()
        loss = -(tq.rot9d_to_matrix(torch.nn.functional.linear(x, w, layer.bias)) * target).sum()
        (g,) = torch.autograd.grad(loss, w, create_graph=True)
        return g.pow(2).sum(), w

    value, w = penalty(layer.weight.detach())
    (analytic,) = torch.autograd.grad(value, w)
    direction = torch.randn(layer.weight.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(8))
    numeric = (penalty(layer.weight.detach() + 1e-6 * direction)[0] - penalty(layer.weight.detach() - 1e-6 * direction)[0]) / 2e-6
    torch.testing.assert_close((analytic * direction).sum(), numeric.detach(), rtol=1e-6, atol=1e-8)


def test_rot9d_batched_jacobians_equal_the_unbatched_ones():
    # jacobian(vectorize=True) runs the backward under autograd's legacy vmap (is_grads_batched);
    # with create_graph the backward applies the projection again there
    x = torch.randn(4, 9, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    jacobian = torch.autograd.functional.jacobian
    expected = jacobian(tq.rot9d_to_matrix, x)
    for create_graph in (False, True):
        torch.testing.assert_close(jacobian(tq.rot9d_to_matrix, x, vectorize=True, create_graph=create_graph).detach(),
                                   expected, rtol=0, atol=1e-14)


def test_rot9d_gradient_at_a_zero_matrix_is_finite():
    # A zero matrix has no nearest rotation (NaN, as a zero quaternion); its gradient stays finite,
    # and so do its neighbours' in a batch: the relative floor of s_i + s_j was 0 there (0 / 0)
    # (then a floor of the smallest normal number gave gradients of 1e307, inf at random: the
    # floor is 1 for a zero matrix, as for a unit-scale one)
    for dtype in (torch.float32, torch.float64):
        M = torch.zeros(2, 3, 3, dtype=dtype, requires_grad=True)
        R = tq.rot9d_to_matrix(M)
        assert R.isnan().all()
        G = 10.0 * torch.randn(2, 3, 3, dtype=dtype, generator=torch.Generator().manual_seed(1))
        (g,) = torch.autograd.grad((R * G).sum(), M)
        assert torch.isfinite(g).all() and g.abs().max() <= 4 * G.abs().max()
        _, tangent = torch.func.jvp(tq.rot9d_to_matrix, (M.detach(),), (torch.ones_like(M),))
        assert torch.isfinite(tangent).all()


_PROPER = [a + b + a for axes in ("XYZ", "xyz") for a in axes for b in axes if a != b]  # the 12 proper-Euler conventions


@pytest.mark.parametrize("convention", _PROPER)
@pytest.mark.parametrize("source", ["quat", "matrix"])
def test_second_derivatives_at_a_proper_euler_lock_are_finite_on_every_path(convention, source):
    # at middle angle 0 (the identity is one such rotation) vector_norm's second derivative made
    # the small batches' double backward NaN, while large batches gave finite numbers
    q = tq.random_quat(1100, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    q[0] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    q[1] = tq.euler_to_quat(torch.tensor([0.3, 0.0, 0.0], dtype=torch.float64), convention)
    x = q if source == "quat" else tq.quat_to_matrix(q)
    fn = (lambda y: tq.quat_to_euler(y, convention)) if source == "quat" else (lambda y: tq.matrix_to_euler(y, convention))
    rows = []
    for batch in (x[:2], x):
        leaf = batch.clone().requires_grad_()
        (g,) = torch.autograd.grad(fn(leaf).sum(), leaf, create_graph=True)
        (h,) = torch.autograd.grad((g * torch.linspace(0.5, 1.5, g[0].numel(), dtype=g.dtype).reshape(g.shape[1:])).sum(), leaf)
        assert torch.isfinite(g).all() and torch.isfinite(h).all()
        rows.append(h[:2])
    torch.testing.assert_close(rows[0], rows[1], rtol=1e-9, atol=1e-9)


def test_second_derivative_of_the_quat_distance_at_zero_is_the_same_on_every_path():
    # the small batches' chord norms had a NaN second derivative at distance 0; large batches gave 0
    q0 = tq.random_quat(1, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    results = []
    for rows in (1, 600, 5_000, 20_000):
        target = q0.expand(rows, 4).clone()
        leaf = target.clone().requires_grad_()
        (g,) = torch.autograd.grad((tq.quat_geodesic_distance(target, leaf) ** 2).sum(), leaf, create_graph=True)
        (h,) = torch.autograd.grad(g[:, 1].sum(), leaf)
        assert torch.isfinite(h).all()
        results.append(h[0])
    for h in results[1:]:
        torch.testing.assert_close(h, results[0], rtol=0, atol=1e-12)
