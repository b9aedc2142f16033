"""The compiled kernels' partitioner: a training graph saves no boolean mask for its backward."""

import warnings
from unittest import mock

import pytest
import torch

import torchquat as tq
from torchquat.conventions import parse_convention

partition = pytest.importorskip("torchquat._partition", reason="this torch has no custom inductor partitioner")
aot = pytest.importorskip("functorch.compile")


def backward_input_dtypes(partition_fn, fn, x):
    """Dtypes of the tensors the backward graph receives (saved ones and the output gradient),
    and the gradient it computes."""
    seen = {}

    def forward_compiler(gm, _):
        return aot.make_boxed_func(gm.forward)

    def backward_compiler(gm, _):
        seen["dtypes"] = [node.meta["val"].dtype for node in gm.graph.find_nodes(op="placeholder")
                          if isinstance(node.meta.get("val"), torch.Tensor)]
        return aot.make_boxed_func(gm.forward)

    compiled = aot.aot_function(fn, fw_compiler=forward_compiler, bw_compiler=backward_compiler,
                                partition_fn=partition_fn)
    x = x.clone().requires_grad_()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (grad,) = torch.autograd.grad(compiled(x).sum(), x)
    return seen["dtypes"], grad


def column_wise(kernel, **static):
    """The kernel's compiled form (what inductor traces), as a plain function."""
    def fn(x):
        with mock.patch("torch.compiler.is_compiling", return_value=True):
            return kernel.eager(x, **static)
    return fn


def test_masks_are_recomputed_not_saved():
    q = tq.random_quat(64, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    fn = column_wise(tq.euler.quat_to_euler_unchecked, convention=parse_convention("ZYX", "test"), eps=1e-7)
    default, default_grad = backward_input_dtypes(aot.min_cut_rematerialization_partition, fn, q)
    ours, grad = backward_input_dtypes(partition.NoSavedMasks(), fn, q)
    assert torch.bool in default  # what the rule is for: the default saves the lock and branch masks
    assert torch.bool not in ours
    assert torch.allclose(grad, default_grad, atol=1e-12)


def test_kernels_without_masks_keep_the_default_partition():
    angles = torch.randn(64, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    fn = column_wise(tq.euler.euler_to_matrix_unchecked, convention=parse_convention("XYZ", "test"))
    default, _ = backward_input_dtypes(aot.min_cut_rematerialization_partition, fn, angles)
    ours, _ = backward_input_dtypes(partition.NoSavedMasks(), fn, angles)
    assert torch.bool not in default
    assert ours == default
