"""One rotation on the CPU with nothing to differentiate is computed in Python floats
(``torchquat._one_row``): it must give what the tensor kernels give, for every function and on the
singular sets, round once to the input's dtype, issue no tensor operation but the output's, and
leave every other call (gradients, NaN, compile, vmap, tracing) to the tensor kernels."""

import math
import pickle

import pytest
import torch

import torchquat as tq
import torchquat._one_row as one_row
from function_table import ALL, DispatchRecorder, assert_paths_agree, same_output

# the functions whose kernels have a one-row form, each with its test name's stem
ONE_ROW = sorted(name for name in ALL if name.split("[")[0] in {
    "quat_to_matrix", "matrix_to_quat", "quat_multiply", "quat_rotate", "axis_angle_to_quat", "quat_to_axis_angle",
    "axis_angle_to_matrix", "matrix_to_axis_angle", "rot6d_to_matrix", "quat_geodesic_distance",
    "matrix_geodesic_distance", "euler_to_quat", "euler_to_matrix", "quat_to_euler", "matrix_to_euler", "quat_slerp"})
WITH_GRADIENT = ONE_ROW  # (every one-row form has its gradient node; run() allows one without)
TOLERANCE = {torch.float64: 1e-12, torch.float32: 2e-6}


def _one_row_each(fn, inputs):
    """``fn`` called on each row alone (a one-row path), stacked."""
    return torch.stack([fn(*(x[i] for x in inputs)) for i in range(inputs[0].shape[0])])


def _assert_same(name, got, expected, atol):
    if "to_euler" in name:  # as rotations: next to lock single angles follow the rounding
        convention = name[-4:-1]
        got, expected = (tq.euler_to_matrix(a.double(), convention) for a in (got, expected))
    elif name.endswith("to_quat") or "to_quat[" in name:  # q or -q: w's sign is the rounding's where w ~ 0
        assert (got[..., 0] >= 0).all()
        sign = torch.where((got * expected).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(got.dtype)
        expected = expected * sign
    assert torch.equal(got.isnan(), expected.isnan())
    assert same_output(name, got.double().nan_to_num(7.0), expected.double().nan_to_num(7.0), atol), name


def test_every_one_row_function_is_covered():
    assert len(ONE_ROW) == 12 + 4 * 24


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=str)
@pytest.mark.parametrize("kind", ["generic", "singular"])
@pytest.mark.parametrize("name", ONE_ROW)
def test_one_row_gives_the_tensor_kernels_answer(name, kind, dtype):
    fn, generic, singular = ALL[name]
    inputs = tuple(x.to(dtype) for x in (generic() if kind == "generic" else singular()))
    _assert_same(name, _one_row_each(fn, inputs), fn(*inputs), TOLERANCE[dtype])


@pytest.mark.parametrize("name", ONE_ROW)
def test_one_row_issues_no_tensor_operation_but_its_output(name):
    fn, generic, _ = ALL[name]
    inputs = tuple(x[0] for x in generic())
    with DispatchRecorder() as one:
        fn(*inputs)
    with DispatchRecorder() as two:
        fn(*(torch.stack([x, x]) for x in inputs))
    # (slerp's float t is filled into a tensor by the public function first)
    assert one.names == (["full", "lift_fresh"] if name == "quat_slerp" else ["lift_fresh"]) and len(two.names) > 3


@pytest.mark.parametrize("name", [n for n in ONE_ROW if n != "quat_slerp"])  # (slerp's t = 0.3 is rounded
def test_float32_is_the_float64_result_rounded_once(name):  # to each dtype: test_slerp_one_row)
    fn, generic, _ = ALL[name]
    for i in range(3):  # (generic rows: no lock test or collinearity threshold between the dtypes)
        inputs = tuple(x[i].float() for x in generic())
        assert torch.equal(fn(*inputs), fn(*(x.double() for x in inputs)).float()), name


@pytest.mark.parametrize("batch", [(), (1,), (1, 1, 1)], ids=str)
def test_one_row_keeps_batch_shape_dtype_and_gives_fresh_memory(batch):
    q = torch.tensor([0.9, -0.1, 0.3, 0.2]).reshape(batch + (4,))
    v = torch.tensor([1.0, 2.0, 3.0]).reshape(batch + (3,))
    R = tq.quat_to_matrix(q)
    two = torch.cat([q.reshape(1, 4)] * 2)
    assert R.shape == batch + (3, 3) and R.dtype == torch.float32
    assert torch.allclose(R.reshape(3, 3), tq.quat_to_matrix(two)[0], atol=1e-6)
    assert tq.quat_to_euler(q, "ZYX").shape == batch + (3,)
    assert tq.quat_geodesic_distance(q, q).shape == batch
    assert tq.quat_rotate(q, v.reshape(3)).shape == batch + (3,)  # broadcast against a batch-less vector
    assert tq.quat_multiply(q.reshape(4), q).shape == batch + (4,)
    out = tq.quat_rotate(q, v)
    out.add_(1.0)  # writable, and not the input's memory
    assert torch.equal(v, torch.tensor([1.0, 2.0, 3.0]).reshape(batch + (3,)))
    R.share_memory_()  # (NumPy-backed, as torch.from_numpy's: shared, pickled and sent to DataLoader
    assert R.is_shared() and torch.equal(pickle.loads(pickle.dumps(R)), R)  # workers as any tensor)
    half = q.to(torch.bfloat16)  # computed in float32, returned in bfloat16
    assert torch.equal(tq.quat_to_matrix(half), tq.quat_to_matrix(half.float()).to(torch.bfloat16))


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_inputs_take_the_tensor_kernels(value):
    q = torch.tensor([value, 0.1, 0.2, 0.3])
    for fn in (tq.quat_to_matrix, lambda x: tq.quat_to_euler(x, "zxz"), tq.quat_to_axis_angle):
        assert torch.equal(fn(q).isnan(), fn(torch.stack([q, q]))[0].isnan())
    assert tq.quat_to_matrix(q).isnan().any()


def test_degenerate_inputs_give_nan_as_the_tensor_kernels():
    zero = torch.zeros(4, dtype=torch.float64)
    unit = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    assert tq.quat_to_matrix(zero).isnan().all()
    assert tq.quat_to_euler(zero, "ZYX").isnan().all()
    assert tq.quat_geodesic_distance(zero, unit).isnan()
    assert tq.quat_to_axis_angle(zero).isnan().all()
    collinear = torch.tensor([1.0, 2.0, 3.0, 2.0, 4.0, 6.0])
    assert tq.rot6d_to_matrix(collinear).isnan().all()
    assert tq.rot6d_to_matrix(torch.tensor([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])).isnan().all()
    assert tq.rot6d_to_matrix(torch.stack([collinear, collinear]))[0].isnan().all()


def test_gimbal_lock_rule_at_one_row():
    # SciPy's rule: at lock the third angle is 0 and the first carries the rotation
    for convention in ("ZYX", "xyz", "ZXZ", "yxy"):
        middle = math.pi / 2 if convention[0].lower() != convention[2].lower() else 0.0
        q = tq.euler_to_quat(torch.tensor([0.3, middle, 0.4], dtype=torch.float64), convention)
        angles = tq.quat_to_euler(q, convention)
        assert angles[2] == 0.0
        assert torch.allclose(tq.euler_to_matrix(angles, convention), tq.quat_to_matrix(q), atol=1e-12)


def _tensor_kernels(monkeypatch, fn, *inputs):
    monkeypatch.setattr(one_row, "ENABLED", False)
    try:
        return fn(*inputs)
    finally:
        monkeypatch.setattr(one_row, "ENABLED", True)


def _gradients(fn, inputs):
    leaves = [x.detach().clone().requires_grad_() for x in inputs]
    out = fn(*leaves)
    weights = torch.linspace(0.5, 1.5, out.numel(), dtype=out.dtype).view(out.shape)  # (not a sum: its
    # gradient would be symmetric in the outputs)
    return out.detach(), torch.autograd.grad((out * weights).sum(), leaves)


@pytest.mark.parametrize("name", WITH_GRADIENT)
def test_one_row_gradcheck(name):
    fn, generic, _ = ALL[name]
    for i in range(2):
        inputs = tuple(x[i].detach().clone().requires_grad_() for x in generic())
        out = fn(*inputs)
        assert type(out.grad_fn).__name__ == "_OneRowGradientBackward", name  # the one-row node
        assert torch.autograd.gradcheck(fn, inputs)
    # double backward: the tensor kernel's derivative, through the node
    assert torch.autograd.gradgradcheck(fn, inputs)


@pytest.mark.parametrize("kind", ["generic", "singular"])
@pytest.mark.parametrize("name", WITH_GRADIENT)
def test_one_row_gradients_are_the_tensor_kernels(name, kind, monkeypatch):
    fn, generic, singular = ALL[name]
    inputs = generic() if kind == "generic" else singular()
    for i in range(inputs[0].shape[0]):
        row = tuple(x[i] for x in inputs)
        out, grads = _gradients(fn, row)
        ref, ref_grads = _tensor_kernels(monkeypatch, _gradients, fn, row)
        if "distance" in name and ref > torch.pi - 1e-6:  # the maximum's kink: rounding picks a side
            assert torch.allclose(out, ref, atol=1e-12) and all(torch.isfinite(g).all() for g in grads)
            continue
        assert_paths_agree(name, kind == "singular", out[None], ref[None], [g[None] for g in grads],
                           [g[None] for g in ref_grads], atol=1e-12, grad_atol=1e-9, grad_rtol=1e-9)


def test_slerp_one_row(monkeypatch):
    q0 = torch.tensor([0.9, -0.1, 0.3, 0.2], dtype=torch.float64, requires_grad=True)
    q1 = torch.tensor([0.1, 0.8, -0.3, 0.6], dtype=torch.float64)  # (not orthogonal to q0: no arc tie)
    t = torch.tensor(0.25, dtype=torch.float64, requires_grad=True)
    out, grads = _gradients(tq.quat_slerp, (q0, q1, t))
    ref, ref_grads = _tensor_kernels(monkeypatch, _gradients, tq.quat_slerp, (q0, q1, t))
    assert torch.allclose(out, ref, atol=1e-15) and all(torch.allclose(a, b, atol=1e-12) for a, b in zip(grads, ref_grads))
    # a formula without a gradient (run() allows one) leaves a recorded call to the tensor kernel
    import torchquat._one_row_gradients as gradients
    monkeypatch.delattr(gradients, "quat_slerp_vjp")
    monkeypatch.setattr(one_row, "_FORMULAS", {})
    assert type(tq.quat_slerp(q0, q1, t).grad_fn).__name__ == "_ClosedFormBackward"
    t = torch.tensor(0.25, dtype=torch.float32)
    q0, q1 = q0.detach().float(), q1.float()  # float32 is the float64 result rounded once
    assert torch.equal(tq.quat_slerp(q0, q1, t), tq.quat_slerp(q0.double(), q1.double(), t.double()).float())


_Q = (0.9, -0.1, 0.3, 0.2)
_V = (0.3, -1.2, 0.5)
_R = tuple(tq.quat_to_matrix(torch.tensor(_Q)).flatten().tolist())
# each public function with a one-row path, before validation (kernel.at_one_row), and one valid
# row of each argument: (entries, row shape)
PUBLIC = {
    "quat_to_matrix": (tq.quat_to_matrix, [(_Q, (4,))]),
    "matrix_to_quat": (tq.matrix_to_quat, [(_R, (3, 3))]),
    "quat_multiply": (tq.quat_multiply, [(_Q, (4,)), (_Q[::-1], (4,))]),
    "quat_rotate": (tq.quat_rotate, [(_Q, (4,)), (_V, (3,))]),
    "axis_angle_to_quat": (tq.axis_angle_to_quat, [(_V, (3,))]),
    "quat_to_axis_angle": (tq.quat_to_axis_angle, [(_Q, (4,))]),
    "axis_angle_to_matrix": (tq.axis_angle_to_matrix, [(_V, (3,))]),
    "matrix_to_axis_angle": (tq.matrix_to_axis_angle, [(_R, (3, 3))]),
    "rot6d_to_matrix": (tq.rot6d_to_matrix, [(_R[:6], (6,))]),
    "quat_geodesic_distance": (tq.quat_geodesic_distance, [(_Q, (4,)), (_Q[::-1], (4,))]),
    "matrix_geodesic_distance": (tq.matrix_geodesic_distance, [(_R, (3, 3)), (_R[::-1], (3, 3))]),
    "euler_to_quat": (lambda a: tq.euler_to_quat(a, "ZYX"), [(_V, (3,))]),
    "euler_to_matrix": (lambda a: tq.euler_to_matrix(a, "zxz"), [(_V, (3,))]),
    "quat_to_euler": (lambda q: tq.quat_to_euler(q, "XYZ"), [(_Q, (4,))]),
    "matrix_to_euler": (lambda R: tq.matrix_to_euler(R, "yzy"), [(_R, (3, 3))]),
}
# shapes of a row's entries that validation refuses
WRONG_SHAPES = {(4,): [(2, 2), (4, 1)], (3,): [(3, 1), (1, 3, 1)], (6,): [(2, 3), (3, 2)],
                (3, 3): [(9,), (1, 9), (3, 1, 3), (9, 1)]}


def _error(fn, *args):
    try:
        fn(*args)
    except Exception as error:  # (the test compares the errors: type and text)
        return type(error), str(error)
    return None


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_public_one_row_path_validates_as_the_tensor_path(name, monkeypatch):
    fn, rows = PUBLIC[name]
    valid = [torch.tensor(values).reshape(shape) for values, shape in rows]
    with DispatchRecorder() as recorder:
        expected = fn(*valid)
    assert recorder.names == ["lift_fresh"]  # the one-row path, from the public function
    for k, (values, shape) in enumerate(rows):  # each argument in a shape of the same size, refused
        for wrong in WRONG_SHAPES[shape]:
            args = valid[:k] + [torch.tensor(values).reshape(wrong)] + valid[k + 1:]
            error = _error(fn, *args)
            assert error is not None and error[0] is tq.ShapeError, (name, wrong)
            assert error == _tensor_kernels(monkeypatch, _error, fn, *args)
        integers = valid[:k] + [valid[k].round().to(torch.int64)] + valid[k + 1:]  # (other types: TypeError)
        error = _error(fn, *integers)
        assert error is not None and error == _tensor_kernels(monkeypatch, _error, fn, *integers)
    # lists are read as tensors; float16 and mixed dtypes are computed as the tensor path computes them
    assert torch.equal(fn(*[x.tolist() for x in valid]), expected)
    for args in ([x.half() for x in valid], [x.double() if k else x for k, x in enumerate(valid)]):
        got, ref = fn(*args), _tensor_kernels(monkeypatch, fn, *args)
        assert got.dtype == ref.dtype and torch.allclose(got.double(), ref.double(), atol=2e-3 if got.dtype == torch.half else 1e-6)


def test_a_parameter_takes_the_one_row_path(monkeypatch):
    q = torch.nn.Parameter(torch.tensor(_Q, dtype=torch.float64))
    with torch.no_grad(), DispatchRecorder() as recorder:
        tq.quat_to_matrix(q)
    assert recorder.names == ["lift_fresh"]
    R = tq.quat_to_matrix(q)
    assert type(R.grad_fn).__name__ == "_OneRowGradientBackward"
    (grad,) = torch.autograd.grad(R[0, 1], q)
    R_ref = _tensor_kernels(monkeypatch, tq.quat_to_matrix, q)
    (ref,) = torch.autograd.grad(R_ref[0, 1], q)
    assert torch.allclose(R, R_ref, atol=1e-15) and torch.allclose(grad, ref, atol=1e-14)


def test_euler_options_at_one_row(monkeypatch):
    # degrees and an explicit eps take the validated path (degrees converted with tensor operations)
    q = torch.tensor(_Q, dtype=torch.float64)
    for kwargs in ({"degrees": True}, {"eps": 1e-3}, {"degrees": False, "eps": None}):
        for fn, x in ((lambda q: tq.quat_to_euler(q, "ZYX", **kwargs), q),
                      (lambda R: tq.matrix_to_euler(R, "zxz", **kwargs), tq.quat_to_matrix(q))):
            assert torch.allclose(fn(x), _tensor_kernels(monkeypatch, fn, x), atol=1e-12)
    with pytest.raises(ValueError, match="degrees"):
        tq.euler_to_quat(torch.tensor(_V), "ZYX", degrees="no")


def test_tracing_and_transforms_take_the_tensor_kernels():
    q = torch.tensor([0.9, -0.1, 0.3, 0.2], dtype=torch.float64)
    traced = torch.jit.trace(tq.quat_to_matrix, q)  # a trace, not a constant
    other = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    assert torch.allclose(traced(other), tq.quat_to_matrix(other))
    batched = torch.func.vmap(tq.quat_to_matrix)(torch.stack([q, other]))
    assert torch.allclose(batched[1], tq.quat_to_matrix(other))
    jacobian = torch.func.jacrev(lambda x: tq.quat_to_euler(x, "ZYX"))(q)
    assert torch.allclose(jacobian, torch.autograd.functional.jacobian(lambda x: tq.quat_to_euler(x, "ZYX"), q))


def test_switched_off_the_tensor_kernels_run(monkeypatch):
    q = torch.tensor([0.9, -0.1, 0.3, 0.2])
    monkeypatch.setattr(one_row, "ENABLED", False)
    with DispatchRecorder() as recorder:
        tq.quat_to_matrix(q)
    assert len(recorder.names) > 1


def test_inference_mode():
    with torch.inference_mode():
        R = tq.quat_to_matrix(torch.tensor([0.9, -0.1, 0.3, 0.2]))
    assert R.shape == (3, 3)


@pytest.mark.parametrize("convention", ["ZYX", "xzy", "ZXZ", "yxy"])
def test_matrices_that_are_not_rotations_give_the_tensor_kernels_answer(convention, monkeypatch):
    # each function reads R as the kernels do (the Euler forms linear in R, Shepperd's row), so the
    # answer for a matrix that is not a rotation does not depend on the batch size either
    g = torch.Generator().manual_seed(3)
    for R in torch.randn(6, 3, 3, generator=g, dtype=torch.float64):
        for fn in (lambda R: tq.matrix_to_euler(R, convention), tq.matrix_to_quat, tq.matrix_to_axis_angle,
                   lambda R: tq.matrix_geodesic_distance(R, R.flip(0))):
            out, grads = _gradients(fn, (R,))
            ref, ref_grads = _tensor_kernels(monkeypatch, _gradients, fn, (R,))
            assert torch.allclose(out, ref, atol=1e-12)
            assert torch.allclose(grads[0], ref_grads[0], atol=1e-9)


def test_batched_gradients_and_hessians_take_the_tensor_kernels_derivative():
    # autograd's batched gradients (jacobian(vectorize=True)) and second derivatives run through the
    # node's backward into the tensor kernel's own derivative
    q = torch.tensor([0.9, -0.1, 0.3, 0.2], dtype=torch.float64)
    fn = lambda x: tq.quat_to_euler(x, "ZXZ")
    vectorized = torch.autograd.functional.jacobian(fn, q, vectorize=True)
    assert torch.allclose(vectorized, torch.autograd.functional.jacobian(fn, q))
    hessian = torch.autograd.functional.hessian(lambda x: fn(x).sum(), q)
    two = torch.autograd.functional.hessian(lambda x: fn(torch.stack([x, x]))[0].sum(), q)
    assert torch.allclose(hessian, two)


# one function of each kind (the Euler ones in one convention each)
STEMS = sorted({name.split("[")[0]: name for name in ONE_ROW}.values())


@pytest.mark.parametrize("name", STEMS)
def test_compiled_autograd_through_the_one_row_node_gives_its_gradients(name):
    # torch.compile's compiled autograd traces the node's Python backward: the formulas' Jacobian
    # is then a constant of the trace (reading the traced gradient's numbers made dynamo fail a
    # guard); while it is on, a recorded call takes the tensor kernel (no constants to recompile on)
    from torch._dynamo import compiled_autograd

    fn, generic, _ = ALL[name]
    inputs = generic()
    traced = []

    def compiler(gm):
        traced.append(gm)
        return torch.compile(gm, backend="eager")

    torch._dynamo.reset()
    for i in range(2):  # (the second row: the cached graph, with that row's own Jacobian)
        row = tuple(x[i].detach().clone().requires_grad_() for x in inputs)
        out = fn(*row)
        weights = torch.linspace(0.5, 1.5, out.numel(), dtype=out.dtype).reshape(out.shape)
        expected = torch.autograd.grad((out * weights).sum(), row)
        out = fn(*row)  # a node recorded before compiled autograd is switched on: its traced backward
        assert type(out.grad_fn).__name__ == "_OneRowGradientBackward", name
        with compiled_autograd._enable(compiler):
            (out * weights).sum().backward()
            found = [x.grad for x in row]
            for x in row:
                x.grad = None
            out = fn(*row)  # recorded while it is on: the tensor kernel's nodes
            assert type(out.grad_fn).__name__ != "_OneRowGradientBackward", name
            (out * weights).sum().backward()
        for x, g, g_found in zip(row, expected, found):
            torch.testing.assert_close(g_found, g, rtol=1e-12, atol=1e-12)
            torch.testing.assert_close(x.grad, g, rtol=1e-9, atol=1e-9)  # (as the one-row tests against the kernels)
    assert traced, "compiled autograd compiled nothing"
