"""The small-batch kernels' closed-form backward passes (torchquat._closed_form) against autograd
through the same forward, and the ways around them (double backward, torch.func, forward mode)."""

import pytest
import torch

import torchquat as tq
from torchquat import _euler_small
from torchquat.conventions import EULER_CONVENTIONS
from torchquat import _euler_rotations as E
from rotation_samples import CONVENTIONS, all_singular, cube_rotations, lock_angles, uniform


def _samples():
    # uniform rotations, non-unit quaternions, and the singular sets (identity, half turns,
    # exact and near gimbal lock for every convention)
    q = torch.cat([uniform(40, seed=3), all_singular(), tq.matrix_to_quat(cube_rotations())])
    scale = torch.linspace(0.5, 2.0, q.shape[0], dtype=q.dtype).unsqueeze(-1)
    return q * scale


def _layout(x, conv, is_matrix):
    return _euler_small.matrix_layout(x, conv) if is_matrix else _euler_small.quat_layout(x, conv)


@pytest.mark.parametrize("is_matrix", [False, True], ids=["quat", "matrix"])
@pytest.mark.parametrize("convention", CONVENTIONS)
def test_closed_form_backward_matches_autograd_of_the_forward(convention, is_matrix):
    conv, eps = EULER_CONVENTIONS[convention], 1e-7
    q = _samples()
    x = tq.quat_to_matrix(q) if is_matrix else q
    grad = torch.randn(x.shape[0], 3, dtype=x.dtype, generator=torch.Generator().manual_seed(7))
    by_autograd = x.clone().requires_grad_()
    expected = _euler_small.angles(_layout(by_autograd, conv, is_matrix), conv, eps)
    (g_expected,) = torch.autograd.grad(expected, by_autograd, grad)
    closed_form = x.clone().requires_grad_()
    got = _euler_small.euler_angles(closed_form, conv, eps, is_matrix)
    (g_got,) = torch.autograd.grad(got, closed_form, grad)
    assert torch.equal(got, expected)
    assert torch.isfinite(g_got).all()
    # the gradients near lock reach 1 / sin(eps) = 1e7: compare relative to their size
    assert ((g_got - g_expected).abs() / (1.0 + g_expected.abs())).max() < 1e-12


@pytest.mark.parametrize("rows", [1, 5, 40])
@pytest.mark.parametrize("is_matrix", [False, True], ids=["quat", "matrix"])
@pytest.mark.parametrize("convention", ["ZYX", "xyz", "ZXZ", "yzy"])
def test_values_without_a_graph_equal_the_plain_forward_bit_for_bit(convention, is_matrix, rows):
    # no-grad calls take the rule's `values` (atan2 of every pair, then a choice); autograd's plain
    # forward chooses first: a user must get the same angles with and without requires_grad
    conv, eps = EULER_CONVENTIONS[convention], 1e-7
    q = torch.cat([all_singular(), uniform(40, seed=11)])[:rows] if rows < 40 else _samples()[:rows]
    x = tq.quat_to_matrix(q) if is_matrix else q
    plain = _euler_small.angles(_layout(x.clone().requires_grad_(), conv, is_matrix), conv, eps).detach()
    assert torch.equal(_euler_small.euler_angles(x, conv, eps, is_matrix), plain)
    with torch.no_grad():
        assert torch.equal(_euler_small.euler_angles(x.clone().requires_grad_(), conv, eps, is_matrix), plain)


def test_the_public_functions_record_one_backward_node():
    q = tq.random_quat(3, generator=torch.Generator().manual_seed(0), dtype=torch.float64).requires_grad_()
    assert type(tq.quat_to_euler(q, "ZYX").grad_fn).__name__ == "_ClosedFormBackward"
    assert type(tq.matrix_to_euler(tq.quat_to_matrix(q), "xyx").grad_fn).__name__ == "_ClosedFormBackward"


@pytest.mark.parametrize("convention", ["ZYX", "xyz", "ZXZ", "yzy"])
def test_double_backward_is_exact(convention):
    q = uniform(4, seed=5).requires_grad_()
    assert torch.autograd.gradgradcheck(lambda x: tq.quat_to_euler(x, convention), (q,))
    R = tq.quat_to_matrix(uniform(4, seed=6)).requires_grad_()
    assert torch.autograd.gradgradcheck(lambda x: tq.matrix_to_euler(x, convention), (R,))


def test_torch_func_and_forward_mode_take_the_plain_forward():
    q = uniform(3, seed=8)
    jac_rev = torch.func.vmap(torch.func.jacrev(lambda x: tq.quat_to_euler(x, "ZYX")))(q)
    jac_fwd = torch.func.vmap(torch.func.jacfwd(lambda x: tq.quat_to_euler(x, "ZYX")))(q)
    assert torch.allclose(jac_rev, jac_fwd, atol=1e-12)
    rows = []
    for i in range(3):
        x = q[i].clone().requires_grad_()
        rows.append(torch.stack([torch.autograd.grad(tq.quat_to_euler(x, "ZYX")[k], x)[0] for k in range(3)]))
    assert torch.allclose(jac_rev, torch.stack(rows), atol=1e-12)
    import torch.autograd.forward_ad as fwAD
    tangent = torch.randn(3, 4, dtype=q.dtype, generator=torch.Generator().manual_seed(9))
    with fwAD.dual_level():
        out = tq.quat_to_euler(fwAD.make_dual(q.clone().requires_grad_(), tangent), "ZYX")
        jvp = fwAD.unpack_dual(out).tangent
    assert torch.allclose(jvp, (jac_rev @ tangent.unsqueeze(-1)).squeeze(-1), atol=1e-12)


@pytest.mark.parametrize("target", ["quat", "matrix"])
@pytest.mark.parametrize("convention", CONVENTIONS)
def test_euler_to_rotation_jacobians_match_autograd(convention, target):
    # the forward's Jacobian rows (one outer product with each angle's factors differentiated)
    conv = EULER_CONVENTIONS[convention]
    plain, with_jacobian = {"quat": (E._euler_to_quat_small, E._euler_to_quat_with_jacobian),
                            "matrix": (E.euler_to_matrix_small, E._euler_to_matrix_with_jacobian)}[target]
    angles = torch.cat([torch.randn(20, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(4)) * 3,
                        lock_angles(convention)[0]])
    value, jacobian = with_jacobian(angles, conv)
    assert torch.equal(value, plain(angles, conv))
    expected = torch.func.vmap(torch.func.jacrev(lambda a: plain(a, conv)))(angles)  # (n, output..., 3)
    assert torch.allclose(jacobian, expected.reshape(angles.shape[0], -1, 3).transpose(-1, -2), atol=1e-14, rtol=0)
    x = angles.clone().requires_grad_()
    out = {"quat": tq.euler_to_quat, "matrix": tq.euler_to_matrix}[target](x, convention)
    assert type(out.grad_fn).__name__ == "_ClosedFormBackward"
    grad = torch.randn(out.shape, dtype=out.dtype, generator=torch.Generator().manual_seed(5))
    (g,) = torch.autograd.grad(out, x, grad)
    expected_g = (expected.reshape(angles.shape[0], -1, 3) * grad.reshape(angles.shape[0], -1, 1)).sum(-2)
    assert torch.allclose(g, expected_g, atol=1e-13, rtol=0)


@pytest.mark.parametrize("planes", [False, True], ids=["strided", "planar"])
@pytest.mark.parametrize("convention", CONVENTIONS)
def test_euler_to_quat_columnwise_backward_matches_autograd(convention, planes, monkeypatch):
    # large batches: dq = e_L q / 2, q e_R / 2 and (cos a_L e_M + sin a_L e_L x e_M) q / 2 per angle,
    # on generic angles, gimbal lock, angles past pi (w's sign flips) and zeros
    import torchquat._math as tqmath
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0 if planes else 10**12)
    conv = EULER_CONVENTIONS[convention]
    generator = torch.Generator().manual_seed(8)
    angles = torch.cat([(torch.rand(30, 3, dtype=torch.float64, generator=generator) - 0.5) * 14,
                        lock_angles(convention)[0], torch.zeros(1, 3, dtype=torch.float64),
                        torch.tensor([[3.0, 1.0, -2.0], [1.0, 3.0, -2.0]], dtype=torch.float64) * torch.pi / 3])
    grad = torch.randn(angles.shape[0], 4, dtype=angles.dtype, generator=generator)
    leaf = angles.clone().requires_grad_()
    expected = E.euler_to_quat_columnwise(leaf, conv)
    (g_expected,) = torch.autograd.grad(expected, leaf, grad)
    leaf = angles.clone().requires_grad_()
    got = tq.euler_to_quat(leaf, convention)
    assert type(got.grad_fn).__name__ == "_ClosedFormBackward"
    (g_got,) = torch.autograd.grad(got, leaf, grad)
    assert torch.equal(got, expected)
    assert torch.allclose(g_got, g_expected, atol=1e-14, rtol=0)


@pytest.mark.parametrize("is_matrix, planes", [(False, True), (True, False), (True, True)],
                         ids=["quat planar", "matrix strided", "matrix planar"])  # (strided quaternions: autograd)
@pytest.mark.parametrize("convention", CONVENTIONS)
def test_columnwise_euler_angles_backward_matches_autograd(convention, is_matrix, planes, monkeypatch):
    # large batches: the forms' gradient from each atan2 (t1 constant at lock, the pick's weights)
    # mapped back through the tables, at uniform, singular and lock rotations
    import torchquat._math as tqmath
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0 if planes else 10**12)
    conv = EULER_CONVENTIONS[convention]
    q = torch.cat([_samples(), tq.euler_to_quat(lock_angles(convention)[0] + torch.tensor([0.0, 1e-5, 0.0], dtype=torch.float64),
                                                convention)])
    x = tq.quat_to_matrix(q) if is_matrix else q
    from torchquat import _euler_forms as forms
    plain = forms.matrix_to_euler_columnwise if is_matrix else forms.quat_to_euler_planar
    grad = torch.randn(x.shape[0], 3, dtype=x.dtype, generator=torch.Generator().manual_seed(17))
    leaf = x.clone().requires_grad_()
    expected = plain(leaf, conv, 1e-7)
    (g_expected,) = torch.autograd.grad(expected, leaf, grad)
    leaf = x.clone().requires_grad_()
    got = (tq.matrix_to_euler if is_matrix else tq.quat_to_euler)(leaf, convention, eps=1e-7)
    assert type(got.grad_fn).__name__ == "_ClosedFormBackward"
    (g_got,) = torch.autograd.grad(got, leaf, grad)
    assert torch.equal(got, expected)
    assert torch.isfinite(g_got).all()
    assert torch.allclose(g_got, g_expected, atol=1e-12, rtol=1e-12)


def test_quat_to_matrix_planar_backward_matches_autograd(monkeypatch):
    # large batches on contiguous columns: the products' gradient through the table, and |q|^2's
    import torchquat._math as tqmath
    from torchquat import matrix as M
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    q = _samples() * torch.logspace(-3, 3, _samples().shape[0], dtype=torch.float64).unsqueeze(-1)
    grad = torch.randn(q.shape[0], 3, 3, dtype=q.dtype, generator=torch.Generator().manual_seed(23))
    leaf = q.clone().requires_grad_()
    expected = M._quat_to_matrix_planar(leaf)
    (g_expected,) = torch.autograd.grad(expected, leaf, grad)
    leaf = q.clone().requires_grad_()
    got = tq.quat_to_matrix(leaf)
    assert type(got.grad_fn).__name__ == "_ClosedFormBackward"
    (g_got,) = torch.autograd.grad(got, leaf, grad)
    assert torch.equal(got, expected)
    scale = q.norm(dim=-1, keepdim=True)  # the gradient scales as 1 / |q|
    assert torch.allclose(g_got * scale, g_expected * scale, atol=1e-13, rtol=0)


def test_a_matrix_forms_abcd_norm_is_a_constant():
    # the column-wise matrix -> Euler takes |abcd|^2 as a number: its table column must be all 0
    from torchquat._euler_forms import DENSE, forms_tables
    for name in EULER_CONVENTIONS:
        _, matrix_table, offset = forms_tables(name)[:3]
        assert not any(row[13] for row in matrix_table)
        assert DENSE[name][3] == offset[13] == (1.0 if EULER_CONVENTIONS[name].symmetric else 2.0)


def test_matrix_to_quat_jacobian_matches_autograd_for_every_shepperd_choice():
    from torchquat import matrix as M
    # uniform rotations, the singular sets (identity, half turns about every axis) and the cube's 24
    q = torch.cat([uniform(30, seed=12), all_singular(), tq.matrix_to_quat(cube_rotations())])
    R = tq.quat_to_matrix(q)
    value, jacobian = M._matrix_to_quat_with_jacobian(R)
    assert torch.equal(value, M._matrix_to_quat_small(R))
    assert set(M._shepperd_parts(R)[1].tolist()) == {0, 1, 2, 3}  # every one of Shepperd's four rows is taken
    leaves = R.clone().requires_grad_()
    plain = M._matrix_to_quat_small(leaves)
    expected = torch.stack([torch.autograd.grad(plain[:, k].sum(), leaves, retain_graph=True)[0].flatten(-2)
                            for k in range(4)], dim=-1)  # rows are independent: per-row Jacobians
    assert torch.allclose(jacobian, expected, atol=1e-14, rtol=0)
    few = R[:40].clone().requires_grad_()
    out = tq.matrix_to_quat(few)
    assert type(out.grad_fn).__name__ == "_ClosedFormBackward"
    grad = torch.randn(out.shape, dtype=out.dtype, generator=torch.Generator().manual_seed(13))
    (g,) = torch.autograd.grad(out, few, grad)
    assert torch.allclose(g.flatten(-2), (expected[:40] * grad.unsqueeze(-2)).sum(-1), atol=1e-14, rtol=0)


@pytest.mark.parametrize("fn", [tq.matrix_to_quat, lambda a: tq.euler_to_quat(a, "xzy"), lambda a: tq.euler_to_matrix(a, "ZXZ")],
                         ids=["matrix_to_quat", "euler_to_quat", "euler_to_matrix"])
def test_double_backward_of_the_jacobian_rules_is_exact(fn):
    x = tq.quat_to_matrix(uniform(4, seed=14)) if fn is tq.matrix_to_quat else \
        torch.randn(4, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(14))
    assert type(fn(x.clone().requires_grad_()).grad_fn).__name__ == "_ClosedFormBackward"
    assert torch.autograd.gradgradcheck(fn, (x.requires_grad_(),))


BATCHED_GRADS = {
    "quat_to_euler": lambda q: tq.quat_to_euler(q, "ZYX"), "quat_to_euler[xyz]": lambda q: tq.quat_to_euler(q, "xyz"),
    "matrix_to_euler": lambda q: tq.matrix_to_euler(tq.quat_to_matrix(q), "ZXZ"),
    "euler_to_quat": lambda q: tq.euler_to_quat(q[..., :3], "ZYX"), "euler_to_matrix": lambda q: tq.euler_to_matrix(q[..., :3], "yxz"),
    "matrix_to_quat": lambda q: tq.matrix_to_quat(tq.quat_to_matrix(q)), "axis_angle_to_quat": lambda q: tq.axis_angle_to_quat(q[..., 1:]),
    "quat_to_axis_angle": tq.quat_to_axis_angle, "rot6d_to_matrix": lambda q: tq.rot6d_to_matrix(torch.cat([q, q[..., :2] * 2 + 1], -1)),
    "quat_geodesic_distance": lambda q: tq.quat_geodesic_distance(q, q.flip(0)),
}


@pytest.mark.parametrize("name", sorted(BATCHED_GRADS))
def test_closed_forms_run_under_autograds_batched_gradients(name):
    # torch.autograd.functional.jacobian(vectorize=True) runs each backward under vmap (is_grads_batched)
    q = uniform(3, seed=15).requires_grad_()
    assert torch.autograd.grad(BATCHED_GRADS[name](q).sum(), q)[0].shape == q.shape  # (the closed form runs)
    fn = BATCHED_GRADS[name]
    assert torch.allclose(torch.autograd.functional.jacobian(fn, q.detach(), vectorize=True),
                          torch.autograd.functional.jacobian(fn, q.detach(), vectorize=False), atol=1e-13, rtol=0)


def _node_names(node, seen=None) -> set:
    """The class names of the autograd nodes of a graph."""
    seen = set() if seen is None else seen
    if node is not None and node not in seen:
        seen.add(node)
        for child, _ in node.next_functions:
            _node_names(child, seen)
    return {type(n).__name__ for n in seen}


@pytest.mark.parametrize("rows", [3, 2_048], ids=["closed-form", "columns"])
@pytest.mark.parametrize("name", sorted(BATCHED_GRADS))
def test_compiled_autograd_traces_the_closed_form_backward_whole(name, rows):
    # torch.compile's compiled autograd traces the nodes' Python backward: the same gradients, and
    # no graph break (the legacy-vmap test, a pybind function dynamo cannot trace, broke every graph)
    from torch._dynamo import compiled_autograd
    from torch._dynamo.utils import counters

    fn = BATCHED_GRADS[name]
    q = uniform(rows, seed=16).requires_grad_()
    weights = torch.linspace(0.5, 1.5, q.shape[0], dtype=q.dtype)

    def loss(out):
        return ((out.flatten(1).sum(-1) if out.dim() > 1 else out) * weights).sum()

    (expected,) = torch.autograd.grad(loss(fn(q)), q)
    torch._dynamo.reset()
    counters.clear()
    out = fn(q)
    # (a few rows: one closed-form node; 2,048: the columns' closed forms, or autograd's own nodes for
    # the kernels whose float64 columns record plain operations there)
    assert rows > 3 or "_ClosedFormBackward" in _node_names(out.grad_fn)
    with compiled_autograd._enable(lambda gm: torch.compile(gm, backend="eager")):
        loss(out).backward()
    assert sum(counters["graph_break"].values()) == 0, dict(counters["graph_break"])
    torch.testing.assert_close(q.grad, expected, rtol=1e-12, atol=1e-12)


def test_compiled_autograd_traces_the_compiled_kernels_backward_hooks_whole(compiled):
    # with the compiled kernels on, their node's hooks (the batched-gradients check) and the
    # first-order node's backward are traced too
    from torch._dynamo import compiled_autograd
    from torch._dynamo.utils import counters

    fn = tq.quat_to_matrix  # (the quickest to compile)
    q = uniform(64, seed=17).requires_grad_()
    weights = torch.linspace(0.5, 1.5, 9, dtype=q.dtype).reshape(3, 3)
    (expected,) = torch.autograd.grad((fn(q) * weights).sum(), q)
    out = fn(q)
    assert "CompiledFunctionBackward" in _node_names(out.grad_fn)
    counters.clear()
    with compiled_autograd._enable(lambda gm: torch.compile(gm, backend="eager")):
        (out * weights).sum().backward()
    assert sum(counters["graph_break"].values()) == 0, dict(counters["graph_break"])
    torch.testing.assert_close(q.grad, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("rows", [1, 3], ids=["one-row", "closed-form"])
def test_compiled_autograd_keeps_second_derivatives(rows):
    # a graph of the gradient asked for while compiled autograd is on: the same Hessian-vector product
    from torch._dynamo import compiled_autograd

    x = uniform(rows, seed=18).requires_grad_()

    def second(x):
        (g,) = torch.autograd.grad(tq.quat_to_euler(x, "ZYX").pow(2).sum(), x, create_graph=True)
        return g, torch.autograd.grad(g.sum(), x)[0]

    g_expected, h_expected = second(x)
    torch._dynamo.reset()
    with compiled_autograd._enable(lambda gm: torch.compile(gm, backend="eager")):
        g, h = second(x)
    torch.testing.assert_close(g, g_expected, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(h, h_expected, rtol=1e-10, atol=1e-10)
    assert h.abs().sum() > 0
