"""The closed-form backward passes of ``rot6d_to_matrix`` and ``quat_geodesic_distance`` (both
of its rules: small-batch chords, large-batch minors) (torchquat._closed_form) against autograd
through the same forward, at generic and singular inputs, and the double-backward path."""

import math

import numpy as np
import pytest
import torch

import torchquat as tq
import torchquat._math as tqmath
import torchquat._one_row as one_row
from torchquat import distance, rot6d
from rotation_samples import all_singular, cube_rotations, uniform

F64 = torch.float64


@pytest.fixture(autouse=True)
def tensor_kernels(monkeypatch):
    """These tests are of the tensor kernels' closed forms, single rows included: the one-row path
    (torchquat._one_row; its own tests in test_one_row.py) is switched off here."""
    monkeypatch.setattr(one_row, "ENABLED", False)


def _grads(fn, inputs, grad):
    leaves = [x.clone().requires_grad_() for x in inputs]
    out = fn(*leaves)
    return out, torch.autograd.grad(out, leaves, grad)


def _relative_error(got, expected):
    return ((got - expected).abs() / (1.0 + expected.abs())).max().item()


@pytest.fixture(params=["small", "large", "large planar"])
def distance_plain(request, monkeypatch):
    """Each distance test runs on both rules: the small-batch chords and the large-batch minors
    (Lagrange's identity, on strided and on contiguous columns), with the plain forward the public
    function must agree with."""
    if request.param.startswith("large"):
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
        monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0 if request.param == "large planar" else 10**12)
        return distance._quat_distance_columnwise
    return distance._quat_distance_small


def _check_closed_form(public, plain, x1, x2, row_dims, seed, tol):
    """A distance's closed-form gradients against autograd through its plain forward: the same
    output bit for bit, finite where autograd's are, within ``tol``."""
    grad = torch.randn(torch.broadcast_shapes(x1.shape, x2.shape)[:-row_dims], dtype=F64,
                       generator=torch.Generator().manual_seed(seed))
    expected, g_expected = _grads(plain, (x1, x2), grad)
    leaves = [x1.clone().requires_grad_(), x2.clone().requires_grad_()]
    got = public(*leaves)
    assert type(got.grad_fn).__name__ == "_ClosedFormBackward"
    g_got = torch.autograd.grad(got, leaves, grad)
    assert torch.equal(got, expected)
    for a, b in zip(g_got, g_expected):
        assert a.shape == b.shape
        assert torch.equal(torch.isfinite(a), torch.isfinite(b))
        assert _relative_error(a, b) < tol
    return g_got


def _check_distance(plain, q1, q2, tol=1e-12):
    _check_closed_form(tq.quat_geodesic_distance, plain, q1, q2, 1, 11, tol)


def _turn(q, axis_angle):
    return tq.quat_multiply(q, tq.axis_angle_to_quat(axis_angle.expand(q.shape[:-1] + (3,))))


# ---------------------------------------------------------------- quat_geodesic_distance


@pytest.mark.parametrize("rule", ["_QUAT_DISTANCE", "_QUAT_DISTANCE_COLUMNWISE"])
def test_quat_distance_rule_forward_is_the_plain_forward(rule, monkeypatch):
    q1, q2 = uniform(30, seed=1) * 2.0, uniform(30, seed=2) * 0.3
    rule = getattr(distance, rule)
    out, _ = rule.forward(q1, q2)
    assert torch.equal(out, rule.plain(q1, q2))
    if rule is distance._QUAT_DISTANCE_COLUMNWISE:
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    assert torch.equal(out, tq.quat_geodesic_distance(q1, q2))  # the no-grad path


def test_quat_distance_gradient_generic_non_unit(distance_plain):
    scale = torch.linspace(0.1, 10.0, 40, dtype=F64).unsqueeze(-1)
    _check_distance(distance_plain, uniform(40, seed=3) * scale, uniform(40, seed=4) * scale.flip(0))


def test_quat_distance_gradient_at_zero_distance_is_zero(distance_plain):
    q = uniform(20, seed=5)
    for other in (q, -2.0 * q, 0.5 * q):  # identical, q and -q, scaled
        _check_distance(distance_plain, q, other)
        leaf = q.clone().requires_grad_()
        (g,) = torch.autograd.grad(tq.quat_geodesic_distance(leaf, other).sum(), leaf)
        assert torch.equal(g, torch.zeros_like(g))


def test_quat_distance_gradient_at_pi(distance_plain):
    q = uniform(20, seed=6)
    axis = torch.tensor([0.0, 0.6, 0.0, -0.8], dtype=F64)  # a pure quaternion: a half turn
    _check_distance(distance_plain, q, tq.quat_multiply(q, axis.expand(20, 4)))
    # exact ties of the two chords (distance exactly pi: the gradient is 0 there)
    p = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5]], dtype=F64)
    q = torch.tensor([[0.0, 1.0, 0.0, 0.0], [0.5, -0.5, 0.5, -0.5]], dtype=F64)
    _check_distance(distance_plain, p, 3.0 * q)
    leaf = p.clone().requires_grad_()
    out = tq.quat_geodesic_distance(leaf, q)
    assert torch.equal(out, torch.full_like(out, math.pi))
    (g,) = torch.autograd.grad(out.sum(), leaf)
    assert torch.equal(g, torch.zeros_like(g))


@pytest.mark.parametrize("angle", [1e-12, 1e-9, 1e-6, math.pi - 1e-9, math.pi - 1e-6])
def test_quat_distance_gradient_near_zero_and_pi(angle, distance_plain):
    q = uniform(30, seed=7) * 1.7
    axis = torch.randn(30, 3, dtype=F64, generator=torch.Generator().manual_seed(8))
    near = _turn(q, axis / axis.norm(dim=-1, keepdim=True) * angle)
    _check_distance(distance_plain, q, near)
    _check_distance(distance_plain, q, -0.25 * near)


def test_quat_distance_gradient_at_singular_sets_and_cube_pairs(distance_plain):
    s = all_singular()
    _check_distance(distance_plain, s, s.flip(0) * 1.5)
    _check_distance(distance_plain, s, s.roll(1, 0))
    cube = tq.matrix_to_quat(cube_rotations())  # every pair: 0, 90, 120, 180 degrees, exact ties
    _check_distance(distance_plain, cube.unsqueeze(1), cube.unsqueeze(0))


def test_quat_distance_gradient_when_a_chord_norm_underflows(distance_plain):
    # |p - q| squares to 0: vector_norm says 0 and its gradient is 0, not C / 0
    p = torch.tensor([1.0, 5e-201, 0.0, 0.0], dtype=F64)
    q = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64)
    _check_distance(distance_plain, p, q)
    _check_distance(distance_plain, p, -q)


@pytest.mark.parametrize("shapes", [((6, 4), (1, 4)), ((4,), (6, 4)), ((6, 4), (4,)), ((2, 1, 4), (3, 4)), ((4,), (4,))])
def test_quat_distance_gradient_broadcasts(shapes, distance_plain):
    g = torch.Generator().manual_seed(9)
    q1 = torch.randn(shapes[0], dtype=F64, generator=g)
    q2 = torch.randn(shapes[1], dtype=F64, generator=g)
    _check_distance(distance_plain, q1, q2)


def test_quat_distance_double_backward(distance_plain):
    g = torch.Generator().manual_seed(10)
    q1 = (torch.randn(3, 4, dtype=F64, generator=g)).requires_grad_()
    q2 = (torch.randn(3, 4, dtype=F64, generator=g)).requires_grad_()
    assert torch.autograd.gradgradcheck(tq.quat_geodesic_distance, (q1, q2))
    q3 = torch.randn(1, 4, dtype=F64, generator=g).requires_grad_()
    assert torch.autograd.gradgradcheck(tq.quat_geodesic_distance, (q1, q3))


def test_quat_distance_float32_gradient_matches_float64(distance_plain):
    q1, q2 = uniform(10, seed=12), uniform(10, seed=13)
    leaves = [q1.float().requires_grad_(), q2.float().requires_grad_()]
    g32 = torch.autograd.grad(tq.quat_geodesic_distance(*leaves).sum(), leaves)
    g64 = _grads(distance_plain, (q1, q2), torch.ones(10, dtype=F64))[1]
    for a, b in zip(g32, g64):
        assert a.dtype == torch.float32
        assert (a.double() - b).abs().max() < 1e-4


# ---------------------------------------------------------------- matrix_geodesic_distance, large eager batches


@pytest.fixture
def matrix_distance_rule(monkeypatch):
    """Large eager CPU batches take the column-wise matrix distance with its closed-form backward
    (contiguous columns); its plain forward, differentiated by autograd, is the reference."""
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    return distance._matrix_distance_columnwise


def _check_matrix_distance(plain, R1, R2, tol=1e-12):
    grads = _check_closed_form(tq.matrix_geodesic_distance, plain, R1, R2, 2, 31, tol)
    assert all(torch.isfinite(g).all() for g in grads)


def _matrices(n, seed):
    return tq.quat_to_matrix(uniform(n, seed=seed))


def test_matrix_distance_rule_forward_is_the_plain_forward(matrix_distance_rule):
    R1, R2 = _matrices(30, 41), _matrices(30, 42)
    out, _ = distance._MATRIX_DISTANCE_COLUMNWISE.forward(R1, R2)
    assert torch.equal(out, matrix_distance_rule(R1, R2))
    assert torch.equal(out, tq.matrix_geodesic_distance(R1, R2))  # the no-grad path


def test_matrix_distance_gradient_generic_and_non_orthogonal(matrix_distance_rule):
    R1, R2 = _matrices(40, 43), _matrices(40, 44)
    _check_matrix_distance(matrix_distance_rule, R1, R2)
    noise = 1e-3 * torch.randn(40, 3, 3, dtype=F64, generator=torch.Generator().manual_seed(45))
    _check_matrix_distance(matrix_distance_rule, R1 + noise, R2)


def test_matrix_distance_gradient_at_zero_distance_is_zero(matrix_distance_rule):
    R = _matrices(20, 46)
    _check_matrix_distance(matrix_distance_rule, R, R)
    leaf = R.clone().requires_grad_()
    (g,) = torch.autograd.grad(tq.matrix_geodesic_distance(leaf, R).sum(), leaf)
    assert torch.equal(g, torch.zeros_like(g))


@pytest.mark.parametrize("angle", [1e-12, 1e-9, 1e-6, 0.3, math.pi - 1e-6, math.pi - 1e-9])
def test_matrix_distance_gradient_near_zero_and_pi(angle, matrix_distance_rule):
    q = uniform(30, seed=47)
    axis = torch.randn(30, 3, dtype=F64, generator=torch.Generator().manual_seed(48))
    near = tq.quat_to_matrix(_turn(q, axis / axis.norm(dim=-1, keepdim=True) * angle))
    _check_matrix_distance(matrix_distance_rule, tq.quat_to_matrix(q), near, tol=1e-9)


def test_matrix_distance_gradient_at_cube_pairs(matrix_distance_rule):
    cube = cube_rotations()  # every pair: 0, 90, 120, 180 degrees
    _check_matrix_distance(matrix_distance_rule, cube.unsqueeze(1), cube.unsqueeze(0))


@pytest.mark.parametrize("shapes", [((6, 3, 3), (1, 3, 3)), ((3, 3), (6, 3, 3)), ((2, 1, 3, 3), (3, 3, 3))])
def test_matrix_distance_gradient_broadcasts(shapes, matrix_distance_rule):
    R1 = _matrices(math.prod(shapes[0][:-2]), 49).reshape(shapes[0])
    R2 = _matrices(math.prod(shapes[1][:-2]), 50).reshape(shapes[1])
    _check_matrix_distance(matrix_distance_rule, R1, R2)


def test_matrix_distance_double_backward(matrix_distance_rule):
    R1, R2 = _matrices(3, 51).requires_grad_(), _matrices(3, 52).requires_grad_()
    assert torch.autograd.gradcheck(tq.matrix_geodesic_distance, (R1, R2))
    assert torch.autograd.gradgradcheck(tq.matrix_geodesic_distance, (R1, R2))


# ---------------------------------------------------------------- rot6d_to_matrix


@pytest.fixture(params=["small", "large", "large planar"])
def rot6d_plain(request, monkeypatch):
    """Each rot6d test runs on both rules: the small batches' and the columns' (strided and
    contiguous), with the plain forward the public function must agree with."""
    if request.param.startswith("large"):
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
        monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0 if request.param == "large planar" else 10**12)
        return rot6d._rot6d_columnwise
    return rot6d._rot6d_small


def _check_rot6d(plain, x, tol=1e-12):
    grad = torch.randn(x.shape[:-1] + (3, 3), dtype=F64, generator=torch.Generator().manual_seed(21))
    expected, (g_expected,) = _grads(plain, (x,), grad)
    leaf = x.clone().requires_grad_()
    got = tq.rot6d_to_matrix(leaf)
    assert type(got.grad_fn).__name__ == "_ClosedFormBackward"
    (g_got,) = torch.autograd.grad(got, leaf, grad)
    torch.testing.assert_close(got, expected, rtol=0, atol=0, equal_nan=True)
    assert torch.equal(torch.isfinite(g_got), torch.isfinite(g_expected))
    return g_got, g_expected


def test_rot6d_rule_forward_is_the_plain_forward():
    x = torch.randn(30, 6, dtype=F64, generator=torch.Generator().manual_seed(20))
    out, _ = rot6d._ROT6D.forward(x)
    assert torch.equal(out, rot6d._ROT6D.plain(x))
    assert torch.equal(out, tq.rot6d_to_matrix(x))  # the no-grad path


@pytest.mark.parametrize("shape", [(6,), (40, 6), (2, 3, 6)])
def test_rot6d_gradient_generic(shape, rot6d_plain):
    g = torch.Generator().manual_seed(22)
    x = torch.randn(shape, dtype=F64, generator=g) * torch.rand(shape[:-1] + (1,), dtype=F64, generator=g).mul(20.0)
    g_got, g_expected = _check_rot6d(rot6d_plain, x)
    assert _relative_error(g_got, g_expected) < 1e-12


def test_rot6d_gradient_at_rotations(rot6d_plain):
    # the 6D of rotations (orthonormal columns), the cube's included
    R = torch.cat([tq.quat_to_matrix(torch.cat([uniform(30, seed=23), all_singular()])), cube_rotations()])
    g_got, g_expected = _check_rot6d(rot6d_plain, tq.matrix_to_rot6d(R) * 3.0)
    assert _relative_error(g_got, g_expected) < 1e-12


def _rot6d_gradient_extended(x, grad):
    """Gram-Schmidt's gradient in numpy's extended precision (80-bit on x86; where longdouble is
    double this reference is only as good as float64, and the bound below still holds)."""
    x, grad = x.numpy().astype(np.longdouble), grad.numpy().astype(np.longdouble)
    a1, a2 = x[:, :3], x[:, 3:]
    r1 = np.sqrt((a1 * a1).sum(-1, keepdims=True))
    b1 = a1 / r1
    d = (b1 * a2).sum(-1, keepdims=True)
    b2 = a2 - d * b1
    n = np.sqrt((b2 * b2).sum(-1, keepdims=True))
    b2 = b2 / n
    b3 = np.cross(b1, b2)
    w = sum(np.cross(b, grad[:, :, k]) for k, b in enumerate((b1, b2, b3)))  # sum_k b_k x G_k
    t = (b1 * w).sum(-1, keepdims=True) / n
    return np.concatenate([(np.cross(w, b1) - d * t * b3) / r1, t * b3], axis=-1)


@pytest.mark.parametrize("offset", [1e-3, 1e-6, 1e-9, 1e-12])
def test_rot6d_gradient_nearly_collinear(offset, rot6d_plain):
    # a2 = 2.5 a1 + offset: the Jacobian grows like |a2| / n and float64 loses digits in proportion.
    # The closed form stays within that bound of an extended-precision reference (autograd through
    # the column code's unnormalised projection does not: 5e-5 against 2e-9 at 1e-9)
    g = torch.Generator().manual_seed(24)
    a1 = torch.randn(20, 3, dtype=F64, generator=g)
    x = torch.cat([a1, 2.5 * a1 + offset * torch.randn(20, 3, dtype=F64, generator=g)], dim=-1)
    g_got, g_expected = _check_rot6d(rot6d_plain, x)
    grad = torch.randn(x.shape[:-1] + (3, 3), dtype=F64, generator=torch.Generator().manual_seed(21))
    reference = torch.from_numpy(_rot6d_gradient_extended(x, grad).astype(np.float64))
    finite = torch.isfinite(g_expected).all(-1)
    a2 = x[..., 3:]
    b1 = x[..., :3] / x[..., :3].norm(dim=-1, keepdim=True)
    n = (a2 - b1 * (b1 * a2).sum(-1, keepdim=True)).norm(dim=-1)
    condition = a2.norm(dim=-1) / n
    err = (g_got - reference).abs().amax(-1) / reference.abs().amax(-1)
    assert (err[finite] <= 1e-12 + 1e-14 * condition[finite]).all()


def test_rot6d_collinear_gives_nan(rot6d_plain):
    a1 = torch.tensor([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]], dtype=F64)
    x = torch.cat([a1, torch.tensor([[2.0, 4.0, 6.0], [1.0, 0.0, 0.0]], dtype=F64)], dim=-1)
    leaf = x.clone().requires_grad_()
    out = tq.rot6d_to_matrix(leaf)
    assert torch.isnan(out).all()
    torch.autograd.grad(out.sum(), leaf)  # NaN gradients, as autograd's, but no error
    _check_rot6d(rot6d_plain, x)


def test_rot6d_double_backward():
    x = torch.randn(3, 6, dtype=F64, generator=torch.Generator().manual_seed(25)).requires_grad_()
    assert torch.autograd.gradgradcheck(tq.rot6d_to_matrix, (x,))


def test_rot6d_torch_func_and_forward_mode_take_the_plain_forward():
    x = torch.randn(3, 6, dtype=F64, generator=torch.Generator().manual_seed(26))
    jac_rev = torch.func.vmap(torch.func.jacrev(tq.rot6d_to_matrix))(x)
    jac_fwd = torch.func.vmap(torch.func.jacfwd(tq.rot6d_to_matrix))(x)
    assert torch.allclose(jac_rev, jac_fwd, atol=1e-12)
    leaf = x.clone().requires_grad_()
    out = tq.rot6d_to_matrix(leaf)  # the closed form, one output entry at a time
    rows = torch.stack([torch.autograd.grad(out[:, i, j].sum(), leaf, retain_graph=True)[0]
                        for i in range(3) for j in range(3)], dim=1).unflatten(1, (3, 3))
    assert torch.allclose(jac_rev, rows, atol=1e-12)
