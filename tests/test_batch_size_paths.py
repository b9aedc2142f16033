"""Small batches take few-operation paths (tables, small matmuls), large ones elementwise paths:
both must give the same answers and finite gradients."""

import pytest
import torch

import torchquat as tq
import torchquat._math as tqmath
from function_table import ALL, BINARY, assert_paths_agree, singular_quats

PATH_DEPENDENT = ["quat_to_matrix", "quat_multiply", "quat_rotate", "matrix_to_quat", "axis_angle_to_quat",
                  "quat_geodesic_distance", "rot6d_to_matrix", "euler_to_quat[ZYZ]", "euler_to_quat[xzy]"] + [
    f"{fn}[{c}]" for fn in ("euler_to_matrix", "quat_to_euler", "matrix_to_euler") for c in ("ZYX", "xyz", "ZXZ", "yxy")]



@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_small_and_large_batch_paths_agree(name, monkeypatch):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        inputs = tuple(x.clone().requires_grad_() for x in make())
        small = fn(*inputs)
        g_small = torch.autograd.grad(small.sum(), inputs)
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
        large = fn(*inputs)
        g_large = torch.autograd.grad(large.sum(), inputs)
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 4096)
        assert_paths_agree(name, make is singular, small, large, g_small, g_large, atol=1e-14, grad_atol=1e-12)


def test_a_batch_above_the_threshold_matches_one_below():
    q = torch.cat([singular_quats(), tq.random_quat(5000, generator=torch.Generator().manual_seed(0), dtype=torch.float64)])
    assert q.shape[0] > tqmath.SMALL_BATCH_ROWS
    big = tq.quat_to_matrix(q)
    pieces = torch.cat([tq.quat_to_matrix(chunk) for chunk in q.split(1000)])
    assert torch.allclose(big, pieces, atol=1e-15, rtol=0)
    assert torch.allclose(tq.quat_multiply(q, q.flip(0)), torch.cat([tq.quat_multiply(a, b) for a, b in zip(q.split(1000), q.flip(0).split(1000))]), atol=1e-15)


@pytest.mark.parametrize("large", [False, True], ids=["small path", "large path"])
@pytest.mark.parametrize("name", sorted(BINARY))
def test_two_input_functions_broadcast_across_ranks(name, large, monkeypatch):
    # one argument a single row without batch dims, the other a batch: as if the row were repeated
    fn, generic, _ = BINARY[name]
    a, b = generic()
    if large:
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    for single_first in (True, False):
        x, y = (a[0], b) if single_first else (a, b[0])
        repeated = (a[0].expand_as(a), b) if single_first else (a, b[0].expand_as(b))
        assert torch.allclose(fn(x, y), fn(*repeated), atol=1e-14, rtol=0), (name, single_first)
