"""The guarantees of SPEC section 3 for every function: batch shapes, purity, row independence,
torch.compile(fullgraph=True), torch.func.vmap, dtypes and half precision."""

import pytest
import torch

import torchquat as tq
from function_table import ALL, BINARY
from rotation_samples import BATCH_SHAPES

NAMES = sorted(ALL)


def _batched(inputs, shape):
    """Reshape generic (n, ...) inputs of n >= prod(shape) rows into batch ``shape``."""
    n = 1
    for s in shape:
        n *= s
    return tuple(x[:n].reshape(*shape, *x.shape[1:]) for x in inputs)


@pytest.mark.parametrize("shape", BATCH_SHAPES, ids=str)
@pytest.mark.parametrize("name", NAMES)
def test_any_batch_shape_gives_the_same_rows(name, shape):
    fn, generic, _ = ALL[name]
    inputs = generic()
    flat = fn(*inputs)
    out = fn(*_batched(inputs, shape))
    n = out.numel() // max(1, flat[0].numel()) if flat.dim() else 1
    assert out.shape[: len(shape)] == shape
    assert torch.allclose(out.reshape(-1, *flat.shape[1:]), flat[:n], atol=1e-12, rtol=0)


@pytest.mark.parametrize("name", NAMES)
def test_inputs_are_never_modified(name):
    fn, generic, singular = ALL[name]
    for inputs in (generic(), singular()):
        before = tuple(x.clone() for x in inputs)
        fn(*inputs)
        assert all(torch.equal(a, b) for a, b in zip(inputs, before))


@pytest.mark.parametrize("name", NAMES)
def test_each_output_row_depends_only_on_its_own_input_row(name):
    fn, generic, _ = ALL[name]
    inputs = generic()
    out = fn(*inputs)
    for poison in (float("nan"), 1e30, 0.0):
        spoiled = tuple(torch.cat([x[:1], torch.full_like(x[1:], poison)]) for x in inputs)
        assert torch.equal(fn(*spoiled)[0], out[0])


@pytest.mark.parametrize("name", NAMES)
def test_runs_under_torch_compile_fullgraph(name):
    fn, generic, _ = ALL[name]
    inputs = generic()
    torch._dynamo.reset()
    compiled = torch.compile(fn, fullgraph=True, backend="eager")  # tracing is what can break
    assert torch.allclose(compiled(*inputs), fn(*inputs), atol=1e-12, rtol=0, equal_nan=True)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["quat_to_matrix", "matrix_to_quat", "quat_to_euler[ZYX]", "rot9d_to_matrix"])
def test_inductor_compiles_forward_and_backward(name):
    fn, generic, _ = ALL[name]
    inputs = tuple(x.float().requires_grad_() for x in generic())
    torch._dynamo.reset()
    compiled = torch.compile(fn, fullgraph=True)
    out = compiled(*inputs)
    ref = fn(*inputs)
    assert torch.allclose(out, ref, atol=1e-5)
    g1 = torch.autograd.grad(out.sum(), inputs)
    g2 = torch.autograd.grad(ref.sum(), inputs)
    assert all(torch.allclose(a, b, atol=1e-4) for a, b in zip(g1, g2))


@pytest.mark.parametrize("name", NAMES)
def test_vmap_matches_the_batched_call(name):
    fn, generic, _ = ALL[name]
    inputs = generic()
    assert torch.allclose(torch.func.vmap(fn)(*inputs), fn(*inputs), atol=1e-12, rtol=0)


@pytest.mark.parametrize("name", NAMES)
def test_per_sample_jacobians_by_vmap_of_jacrev_and_jacfwd(name):
    # vmap over jacrev / jacfwd (per-sample Jacobians) equals the diagonal blocks of jacrev of the batch
    fn, generic, _ = ALL[name]
    inputs = tuple(x[:3] for x in generic())
    argnums = tuple(range(len(inputs)))
    out_dims = fn(*inputs).dim() - 1
    batched = torch.func.jacrev(fn, argnums=argnums)(*inputs)  # each (3, out row, 3, in row)
    for transform in (torch.func.jacrev, torch.func.jacfwd):
        per_sample = torch.func.vmap(transform(fn, argnums=argnums))(*inputs)
        for row_jacobians, J in zip(per_sample, batched):
            for i in range(3):
                torch.testing.assert_close(row_jacobians[i], J[i][(slice(None),) * out_dims + (i,)])


def test_first_use_under_inference_mode_or_torch_func_does_not_break_later_calls():
    # Nothing computed under inference_mode or torch.func may leak into later calls (an inference
    # tensor cannot be saved for training, a wrapped tensor breaks later transforms).
    q = tq.random_quat(3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    R = tq.quat_to_matrix(q)
    with torch.inference_mode():
        tq.matrix_to_quat(R), tq.quat_rotate(q, R[..., 0]), tq.matrix_geodesic_distance(R, R.flip(0))
    for fn, x in ((tq.matrix_to_quat, R), (lambda v: tq.quat_rotate(q, v), R[..., 0]),
                  (lambda M: tq.matrix_geodesic_distance(M, R.flip(0)), R)):
        x = x.clone().requires_grad_()
        assert torch.isfinite(torch.autograd.grad(fn(x).sum(), x)[0]).all()
    f = lambda x: tq.quat_to_euler(x, "ZYX")
    H = torch.func.hessian(f)(q[0])
    assert torch.isfinite(H).all()
    torch.testing.assert_close(torch.func.jacrev(f)(q[0]), torch.func.jacfwd(f)(q[0]))


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float32])
@pytest.mark.parametrize("name", NAMES)
def test_low_precision_is_computed_in_float32_and_returned_in_its_dtype(name, dtype):
    fn, generic, _ = ALL[name]
    inputs = tuple(x.to(dtype) for x in generic())
    out = fn(*inputs)
    assert out.dtype == dtype
    reference = fn(*(x.float() for x in inputs))
    assert torch.allclose(out.float(), reference.to(dtype).float(), atol=0, rtol=0, equal_nan=True)


@pytest.mark.parametrize("name", ["quat_to_matrix", "quat_to_euler[ZYX]", "quat_multiply", "rot6d_to_matrix"])
def test_gradients_flow_in_half_precision(name):
    fn, generic, _ = ALL[name]
    inputs = tuple(x.to(torch.bfloat16).requires_grad_() for x in generic())
    grads = torch.autograd.grad(fn(*inputs).float().sum(), inputs)
    assert all(g.dtype == torch.bfloat16 and torch.isfinite(g).all() for g in grads)


def test_float32_and_float64_inputs_are_kept():
    q = torch.randn(3, 4)
    assert tq.quat_to_matrix(q).dtype == torch.float32
    assert tq.quat_to_matrix(q.double()).dtype == torch.float64
    assert tq.random_quat(2).dtype == torch.get_default_dtype()
    assert tq.random_quat(2, dtype=torch.float16).dtype == torch.float16


@pytest.mark.parametrize("name", sorted(BINARY))
def test_mixed_precision_arguments_give_the_promoted_dtype_in_either_order(name):
    fn, generic, _ = BINARY[name]
    a, b = (x.float() for x in generic())  # (float32 numbers: exact in float64)
    reference = fn(a.double(), b.double())
    for first, second in ((a, b.double()), (a.double(), b)):
        out = fn(first, second)
        assert out.dtype == torch.float64  # (float32 first used to round the float64 result)
        torch.testing.assert_close(out, reference, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_autocast_does_not_lower_the_precision(name):
    fn, generic, _ = ALL[name]
    inputs = tuple(x.float().requires_grad_() for x in generic())
    expected = fn(*inputs)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = fn(*inputs)
        grads = torch.autograd.grad(out.sum(), inputs)
    assert out.dtype == torch.float32
    assert torch.allclose(out, expected, atol=1e-6, rtol=0)
    assert all(torch.isfinite(g).all() for g in grads)


def _autograd_matmuls(output):
    """The matmul nodes of ``output``'s autograd graph, outside the closed-form Functions (whose
    backward is one node): autocast, if active during the backward, rounds their gradients."""
    found, seen, stack = [], set(), [output.grad_fn]
    while stack:
        node = stack.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        if type(node).__name__.startswith(("MmBackward", "AddmmBackward", "BmmBackward", "BaddbmmBackward")):
            found.append(type(node).__name__)
        stack.extend(next_node for next_node, _ in node.next_functions)
    return found


@pytest.mark.parametrize("repeats", [1, 625])
@pytest.mark.parametrize("name", NAMES)
def test_a_backward_inside_an_autocast_region_keeps_the_precision(name, repeats):
    # the closed-form backward passes ran their matmuls under the caller's autocast: relative
    # errors of 1e-3 (bfloat16) in the gradients of the Euler angles, 6D, 9D, the distances ...
    fn, generic, _ = ALL[name]
    inputs = tuple(x.float().repeat((repeats,) + (1,) * (x.dim() - 1)).requires_grad_() for x in generic())
    out = fn(*inputs)
    weights = torch.randn(out.shape, generator=torch.Generator().manual_seed(5))
    expected = torch.autograd.grad((weights * out).sum(), inputs)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        grads = torch.autograd.grad((weights * fn(*inputs)).sum(), inputs)
    # (a matmul that autograd records, as PyTorch's own, is rounded: run backward outside autocast)
    tolerance = 2e-2 if _autograd_matmuls(out) else 1e-5
    for g, e in zip(grads, expected):
        assert (g - e).abs().max() <= tolerance * e.abs().max(), (g - e).abs().max() / e.abs().max()


@pytest.mark.parametrize("src, dst", [("matrix", "matrix"), ("matrix", "rot9d"), ("quat", "quat"), ("rot9d", "rot9d"),
                                      ("quat_xyzw", "quat")])
def test_convert_within_a_representation_returns_a_fresh_tensor(src, dst):
    # (matrix -> matrix used to hand back R itself, and matrix -> rot9d a view of it)
    x = tq.convert(tq.random_quat(4, generator=torch.Generator().manual_seed(0)), "quat", src).requires_grad_()
    with torch.no_grad():
        out = tq.convert(x, src, dst)
    assert out.untyped_storage().data_ptr() != x.untyped_storage().data_ptr()
    assert not out.requires_grad
    before = x.detach().clone()
    out.view(-1)[0] = 7.0
    assert torch.equal(x.detach(), before)


_BROADCAST_CALLS = {
    "rotate one quaternion": lambda n: tq.quat_rotate(_ONE_Q, torch.ones(n, 3)),
    "rotate (1, 4)": lambda n: tq.quat_rotate(_ONE_Q[None], torch.ones(n, 3)),
    "product with one": lambda n: tq.quat_multiply(torch.ones(n, 4), _ONE_Q),
    "distance to one": lambda n: tq.quat_geodesic_distance(torch.ones(n, 4), _ONE_Q),
    "matrix distance to one": lambda n: tq.matrix_geodesic_distance(torch.eye(3).expand(n, 3, 3) * 1.0, torch.eye(3)),
    "slerp with a tensor t": lambda n: tq.quat_slerp(torch.ones(n, 4), _ONE_Q, torch.full((n,), 0.3)),
}
_ONE_Q = torch.tensor([0.5, 0.5, 0.5, 0.5])


@pytest.mark.parametrize("call", sorted(_BROADCAST_CALLS))
def test_compiled_user_code_that_broadcasts_does_not_recompile_for_each_batch_size(call):
    # a set of the batch sizes in the broadcast check specialised each size: one graph per
    # size until fullgraph=True failed at the ninth
    from torch._dynamo.testing import CompileCounter
    counter = CompileCounter()  # (no dynamo reset: it would make later tests compile their kernels again)
    fn = torch.compile(_BROADCAST_CALLS[call], fullgraph=True, backend=counter)
    for n in range(100, 1100, 100):
        torch.testing.assert_close(fn(n), _BROADCAST_CALLS[call](n))
    assert counter.frame_count <= 2  # the first size, then one dynamic graph


# one entry per kernel family (every table entry: 118 exports, about 40 s)
_EXPORTED = ["quat_to_matrix", "matrix_to_quat", "quat_to_euler[zxz]", "quat_to_euler[YXZ]", "matrix_to_euler[xzy]",
             "euler_to_quat[ZYZ]", "euler_to_matrix[XYZ]", "quat_to_axis_angle", "axis_angle_to_quat",
             "axis_angle_to_matrix", "matrix_to_axis_angle", "rot6d_to_matrix", "rot9d_to_matrix",
             "quat_geodesic_distance", "matrix_geodesic_distance", "quat_rotate", "quat_multiply", "quat_slerp"]


@pytest.mark.parametrize("name", _EXPORTED)
def test_torch_export_with_a_dynamic_batch_runs_at_another_size(name):
    fn, generic, _ = ALL[name]
    inputs = generic()
    module = _Unary(fn) if len(inputs) == 1 else _Binary(fn)
    batch = torch.export.Dim("batch", min=2, max=100_000)
    program = torch.export.export(module, tuple(inputs), dynamic_shapes=tuple({0: batch} for _ in inputs))
    other = tuple(torch.cat([x, x[:3]]) for x in inputs)
    torch.testing.assert_close(program.module()(*other), fn(*other), equal_nan=True)


class _Unary(torch.nn.Module):
    def __init__(self, fn):
        super().__init__()
        self.fn = fn

    def forward(self, x):
        return self.fn(x)


class _Binary(_Unary):
    def forward(self, a, b):
        return self.fn(a, b)
