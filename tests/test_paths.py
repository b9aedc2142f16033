"""Every path runs the same formula: one rotation on Python floats and CPU batches on NumPy columns
(the formula's generated code and reverse mode), the tensor formula, and the opt-in compiled kernel
(``use_compiled_kernels``) give the same answers and gradients."""

import numpy
import pytest
import torch

import torchquat as tq
from function_table import ALL, assert_paths_agree, compiled_against_eager

# One representative per kernel; compiling all 100+ table entries would take minutes.
# every kernel with a column-wise compiled form, and one of each other kind
KERNELS = ["quat_to_matrix", "matrix_to_quat", "quat_to_euler[zxz]", "quat_to_euler[YXZ]", "matrix_to_euler[xzy]",
           "euler_to_quat[ZYZ]", "euler_to_matrix[XYZ]", "quat_to_axis_angle", "axis_angle_to_quat", "rot6d_to_matrix",
           "quat_geodesic_distance", "matrix_geodesic_distance", "quat_rotate", "quat_multiply", "quat_slerp"]


@pytest.mark.slow
@pytest.mark.parametrize("name", KERNELS)
def test_compiled_kernel_matches_eager_with_finite_gradients(name, compiled):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        out, grads, ref, ref_grads = compiled_against_eager(fn, make())
        assert_paths_agree(name, make is singular, out, ref, grads, ref_grads, atol=1e-12, grad_atol=1e-9, grad_rtol=1e-9)


def test_vmap_and_user_compile_trace_the_eager_kernel(compiled):
    q = torch.randn(5, 4, dtype=torch.float64)
    tq.use_compiled_kernels(False)
    expected = tq.quat_to_matrix(q)
    tq.use_compiled_kernels(True)
    # under functorch transforms and inside a user's compiled region the eager kernel is traced
    assert torch.allclose(torch.func.vmap(tq.quat_to_matrix)(q), expected, atol=1e-15)
    torch._dynamo.reset()
    outer = torch.compile(lambda x: tq.quat_to_matrix(x) * 2, fullgraph=True, backend="eager")
    assert torch.allclose(outer(q), expected * 2, atol=1e-15)


def test_switch_and_environment_variable():
    assert not tq.compiled_kernels_enabled()
    tq.use_compiled_kernels(True)
    assert tq.compiled_kernels_enabled()
    tq.use_compiled_kernels(False)
    assert not tq.compiled_kernels_enabled()


def test_the_environment_variable_switches_the_compiled_kernels_on():
    import subprocess
    import sys

    code = "import torchquat; print(torchquat.compiled_kernels_enabled())"
    env = dict(__import__("os").environ, TORCHQUAT_COMPILE="1")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"


@pytest.mark.parametrize("name", sorted(ALL))
def test_one_rotation_on_floats_equals_its_row_of_the_eager_batch_with_the_same_gradients(name):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        inputs = make()
        rows = inputs[0].shape[0]
        for i in range(min(rows, 8)):
            row = tuple(x[i] if x.dim() > 0 and x.shape[0] == rows else x for x in inputs)
            leaves = tuple(x.clone().requires_grad_() for x in row)
            batch_leaves = tuple(x.clone().unsqueeze(0).expand(2, *x.shape).clone().requires_grad_() for x in row)
            one = fn(*leaves)
            batch = fn(*batch_leaves)
            assert torch.isfinite(one).all() == torch.isfinite(batch[0]).all(), (name, i)
            finite = torch.isfinite(one)
            if "to_euler" in name:
                convention = name[-4:-1]
                assert torch.allclose(tq.euler_to_matrix(one, convention), tq.euler_to_matrix(batch[0], convention),
                                      atol=1e-12), (name, i)
                continue
            assert torch.allclose(one[finite], batch[0][finite], atol=1e-12, rtol=0), (name, i)
            if not finite.all() or "distance" in name and (one > torch.pi - 1e-6).any():
                continue  # (the kink of a distance at pi: which one-sided gradient comes out follows rounding)
            grads = torch.autograd.grad(one.sum(), leaves, allow_unused=True)
            batch_grads = torch.autograd.grad(batch[0].sum(), batch_leaves, allow_unused=True)
            for g, b in zip(grads, batch_grads):
                if g is None or b is None:
                    assert g is None or not g.any()
                    continue
                assert torch.isfinite(g).all(), (name, i)
                if make is generic:
                    assert torch.allclose(g, b[0], atol=1e-9, rtol=1e-9), (name, i)


@pytest.mark.parametrize("name", ["quat_to_matrix", "matrix_to_quat", "quat_to_euler[ZYX]", "quat_slerp",
                                  "quat_geodesic_distance", "axis_angle_to_quat", "rot6d_to_matrix"])
def test_second_derivatives_of_one_rotation_are_autograds_of_the_eager_formula(name):
    fn, generic, _ = ALL[name]
    row = tuple((x[0] if x.dim() > 0 else x).clone().requires_grad_() for x in generic())
    assert torch.autograd.gradgradcheck(fn, row)


@pytest.mark.parametrize("shapes", [((1,), (1,)), ((1, 1), (1,)), ((), (1, 1, 1))], ids=str)
@pytest.mark.parametrize("name", ["quat_to_matrix", "matrix_to_quat", "quat_geodesic_distance",
                                  "matrix_geodesic_distance", "quat_rotate"])
def test_one_row_with_leading_ones_has_the_tensor_formulas_shape_values_and_gradients(name, shapes):
    # one row given as (1, 4), (1, 1, 4), ... and broadcast against a plain row
    fn, generic, _ = ALL[name]
    inputs = tuple(x[2].reshape(lead + x.shape[1:]) for x, lead in zip(generic(), shapes))
    leaves = tuple(x.clone().requires_grad_() for x in inputs)
    out = fn(*leaves)
    weights = torch.linspace(0.5, 1.5, out.numel(), dtype=out.dtype).view(out.shape)
    grads = torch.autograd.grad(out, leaves, weights)
    reference_out, vjp = torch.func.vjp(fn, *inputs)  # (wrapped tensors: the tensor formula)
    assert out.shape == reference_out.shape and out.dtype == reference_out.dtype
    assert torch.allclose(out, reference_out, atol=1e-12, rtol=0)
    for g, r, x in zip(grads, vjp(weights), inputs):
        assert g.shape == x.shape
        assert torch.allclose(g, r, atol=1e-9, rtol=1e-9), name


@pytest.mark.parametrize("rows", [1, 5, 3000], ids=["one row", "batch", "large batch"])
@pytest.mark.parametrize("name", sorted(ALL))
def test_the_generated_reverse_mode_equals_autograd_of_the_tensor_formula(name, rows):
    # One row (floats) and CPU batches (NumPy columns) get their values and gradient from the code
    # that torchquat._codegen writes out from the formula; torch.func.vjp runs the tensor formula
    # under autograd instead (its wrapped tensors take that path). Large batches select on bits.
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        def rows_of(x):
            if rows > 5:  # (every row repeated: generic and singular rows side by side in one block)
                return x.repeat((-(-rows // x.shape[0]),) + (1,) * (x.dim() - 1))
            return x[:rows]
        inputs = tuple(rows_of(x) if x.dim() > 1 or (x.dim() == 1 and x.shape[0] > 4) else x for x in make())
        if rows == 1:
            inputs = tuple(x[0] if x.dim() > 1 else x for x in inputs)
        leaves = tuple(x.clone().requires_grad_() for x in inputs)
        out = fn(*leaves)
        weights = torch.linspace(0.5, 1.5, out.numel(), dtype=out.dtype).view(out.shape)
        generated = torch.autograd.grad(out, leaves, weights, allow_unused=True)
        reference_out, vjp = torch.func.vjp(fn, *inputs)
        reference = vjp(weights)
        assert torch.allclose(out, reference_out, atol=1e-12, equal_nan=True)
        for g, r in zip(generated, reference):
            g = torch.zeros_like(r) if g is None else g
            finite = torch.isfinite(r)
            assert torch.isfinite(g).all(), name
            assert torch.allclose(g[finite], r[finite], atol=1e-9, rtol=1e-9), (name, make.__name__)


@pytest.mark.parametrize("dtype", [numpy.float32, numpy.float64])
def test_the_selection_on_bits_equals_numpys_where_for_every_value(dtype):
    from torchquat._backends import _BLEND_ROWS, _array_where

    special = numpy.array([0.0, -0.0, 1.0, -2.5, numpy.inf, -numpy.inf, numpy.nan, 1e-40, 3e38], dtype)
    rng = numpy.random.default_rng(0)
    a = rng.choice(special, _BLEND_ROWS * 2)
    b = rng.choice(special, _BLEND_ROWS * 2)
    condition = rng.random(_BLEND_ROWS * 2) < 0.5
    cases = [(a, b), (a, numpy.array(1.0, dtype)), (numpy.array(-0.0, dtype), b), (a, 0.5), (-1.0, 1.0),
             (a[:1], b)]
    for x, y in cases:
        expected = numpy.where(condition, x, y)
        got = _array_where(condition, x, y)
        assert got.dtype == expected.dtype and got.shape == expected.shape
        assert numpy.array_equal(got.view(numpy.uint8), expected.view(numpy.uint8))  # (bit for bit)


@pytest.mark.slow
def test_compiled_gradients_pass_gradcheck_and_second_derivatives_are_autograds(compiled):
    # the compiled backward is a second kernel (the formula's vector-Jacobian product); a gradient
    # differentiated again runs the tensor formula under autograd
    tq.use_compiled_kernels(True)
    q = torch.randn(5, 4, dtype=torch.float64, requires_grad=True)
    p = torch.randn(1, 4, dtype=torch.float64, requires_grad=True)  # (broadcast: its gradient sums)
    assert torch.autograd.gradcheck(tq.quat_geodesic_distance, (p, q))
    assert torch.autograd.gradgradcheck(tq.quat_to_matrix, (q,))
