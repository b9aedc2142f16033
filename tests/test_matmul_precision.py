"""Where a float32 matmul would round its inputs (TF32 on CUDA, when the user allows it), no kernel
may use one: every table contraction is then written as sums. Checked on the CPU by declaring
every matmul rounding, and recording the operations each function dispatches."""

import pytest
import torch

import torchquat._math as tqmath
from function_table import ALL, DispatchRecorder

MATMULS = {"mm", "addmm", "bmm", "baddbmm", "mv", "addmv", "matmul", "dot", "vdot", "addbmm", "_addmm_activation"}


def test_matmul_rounds_only_for_float32_cuda_with_tf32_allowed():
    x = torch.zeros(2, 4)
    assert not tqmath.matmul_rounds(x) and not tqmath.matmul_rounds(x.double())
    previous = torch.get_float32_matmul_precision()
    try:
        torch.set_float32_matmul_precision("high")
        assert not tqmath.matmul_rounds(x)  # the CPU's skinny matmuls stay float32 (test_float32_precision)
    finally:
        torch.set_float32_matmul_precision(previous)


@pytest.mark.parametrize("name", sorted(ALL))
def test_no_kernel_uses_a_matmul_where_matmuls_round(name, monkeypatch):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        inputs = make()
        expected = fn(*inputs)
        monkeypatch.setattr(tqmath, "matmul_rounds", lambda x: True)
        leaves = [x.clone().requires_grad_() for x in inputs]
        with DispatchRecorder() as recorder:
            out = fn(*leaves)
            grads = torch.autograd.grad(out.sum(), leaves)
        monkeypatch.setattr(tqmath, "matmul_rounds", lambda x: False)
        assert not set(recorder.names) & MATMULS, (name, set(recorder.names) & MATMULS)
        assert all(g.shape == x.shape for g, x in zip(grads, leaves))
        if "to_euler" not in name:  # (at lock the angles follow rounding; the paths' agreement is tested elsewhere)
            assert torch.allclose(out.nan_to_num(7.0), expected.nan_to_num(7.0), atol=1e-12, rtol=0), name
