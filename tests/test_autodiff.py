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
