"""The opt-in compiled path (``use_compiled_kernels``) gives the eager answers and gradients."""

import operator

import pytest
import torch

import torchquat as tq
from function_table import ALL, assert_paths_agree, compiled_against_eager
from rotation_samples import cube_rotations

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
        # the compiled kernels are the column-wise forms, eager small batches the table forms
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


def test_every_convention_and_dtype_gets_its_own_graph_without_hitting_the_recompile_limit(compiled, monkeypatch):
    import torchquat._dispatch as dispatch
    monkeypatch.setattr(dispatch, "_backend", "eager")
    monkeypatch.setattr(dispatch, "_compiled", {})
    q = tq.random_quat(50, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    for convention in sorted(tq.EULER_CONVENTIONS):
        for dtype in (torch.float32, torch.float64):
            out = tq.quat_to_euler(q.to(dtype), convention)
            assert torch.isfinite(out).all()
    assert torch.isfinite(tq.quat_to_euler(q[:1], "ZYX")).all()  # size 1 is a second graph of the same kernel
    assert len(dispatch._compiled) == 48  # 24 conventions x the two default eps (float32, float64)


def test_compiled_quat_distance_of_a_zero_quaternion_has_a_nan_gradient_as_eager(compiled, monkeypatch):
    # The compiled formula's NaN for a zero quaternion must reach the gradient too (a where's NaN
    # branch passed none: the row's gradient was 0, a NaN loss with a silent zero step)
    import torchquat._dispatch as dispatch
    monkeypatch.setattr(dispatch, "_backend", "eager")  # (the formula, traced; inductor gives the same)
    monkeypatch.setattr(dispatch, "_compiled", {})
    q1 = torch.tensor([[0.0, 0, 0, 0], [1, 0, 0, 0], [0.6, 0.8, 0, 0]], dtype=torch.float64)
    q2 = torch.tensor([[0.0, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0]], dtype=torch.float64)
    out, grads, ref, ref_grads = compiled_against_eager(tq.quat_geodesic_distance, (q1, q2))
    torch.testing.assert_close(out, ref, equal_nan=True, rtol=0, atol=1e-15)
    for g, ref_g in zip(grads, ref_grads):
        assert torch.isnan(g[:2]).all() and torch.isnan(ref_g[:2]).all()
        torch.testing.assert_close(g[2], ref_g[2], rtol=0, atol=1e-15)


def test_a_training_loops_modes_and_layouts_never_hit_the_recompile_limit(compiled, monkeypatch):
    # Train (grad), eval (no_grad) and inference_mode calls, each with a full and a last short batch,
    # contiguous and as a column slice of a network output, in two dtypes: dynamo's 8 graphs per
    # function ran out at the ninth variant, an error under fullgraph=True (found by an audit)
    import torchquat._dispatch as dispatch
    monkeypatch.setattr(dispatch, "_backend", "eager")
    monkeypatch.setattr(dispatch, "_compiled", {})
    torch._dynamo.reset()
    outputs = torch.randn(64, 7, dtype=torch.float64)  # e.g. a pose head: translation and quaternion
    for dtype in (torch.float32, torch.float64):
        for n in (64, 1):
            for sliced in (False, True):
                for mode in ("train", "eval", "inference"):
                    x = outputs[:n, 3:7].to(dtype)
                    x = x if sliced else x.contiguous()
                    tq.use_compiled_kernels(False)
                    expected = tq.quat_to_axis_angle(x)
                    tq.use_compiled_kernels(True)
                    if mode == "train":
                        x = x.detach().requires_grad_()
                        out = tq.quat_to_axis_angle(x)
                        out.sum().backward()
                        assert torch.isfinite(x.grad).all()
                    else:
                        with torch.no_grad() if mode == "eval" else torch.inference_mode():
                            out = tq.quat_to_axis_angle(x)
                    torch.testing.assert_close(out.detach(), expected, rtol=0, atol=1e-5 if dtype == torch.float32 else 1e-12)


def test_past_the_recompile_limit_a_call_runs_eagerly_instead_of_failing(compiled, monkeypatch):
    import torchquat._dispatch as dispatch
    monkeypatch.setattr(dispatch, "_backend", "eager")
    monkeypatch.setattr(dispatch, "_compiled", {})
    monkeypatch.setattr(dispatch, "_past_limit", set())
    torch._dynamo.reset()
    q = tq.random_quat(24, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    # ranks and unit dimensions: each a graph of its own in one context, more than dynamo keeps
    shapes = [(24,), (2, 12), (12, 2), (1, 24), (24, 1), (2, 3, 4), (1, 1, 24), (2, 1, 12), (1, 2, 12),
              (2, 2, 6), (1, 2, 3, 4), (2, 3, 2, 2)]
    for shape in shapes:
        x = q.reshape(shape + (4,))
        tq.use_compiled_kernels(False)
        expected = tq.quat_to_matrix(x)
        tq.use_compiled_kernels(True)
        torch.testing.assert_close(tq.quat_to_matrix(x), expected, rtol=0, atol=1e-15)
    assert len(dispatch._compiled) == 1  # one context throughout: the limit was reached, and passed
    # and remembered: later calls neither retry a compile nor warn again (they did, 80x slower)
    import io
    import logging
    log = io.StringIO()
    handler = logging.StreamHandler(log)
    logging.getLogger("torch._dynamo").addHandler(handler)
    try:
        for _ in range(5):
            torch.testing.assert_close(tq.quat_to_matrix(x), expected, rtol=0, atol=1e-15)
    finally:
        logging.getLogger("torch._dynamo").removeHandler(handler)
    assert "recompile_limit" not in log.getvalue()
    assert len(dispatch._past_limit) == 1


@pytest.mark.slow
@pytest.mark.parametrize("convention", ["ZYX", "xyz", "zxz"])
def test_compiled_exact_half_turns_are_plus_pi_as_eager(convention, compiled):
    # inductor's columns keep a negated zero (-0), whose atan2 against a negative x is -pi
    cube = cube_rotations()
    q = tq.matrix_to_quat(cube)
    for dtype in (torch.float64, torch.float32):
        for x, fn in ((q, tq.quat_to_euler), (-q, tq.quat_to_euler), (cube, tq.matrix_to_euler),
                      (torch.where(cube == 0, -0.0, cube), tq.matrix_to_euler)):
            x = x.to(dtype)
            tq.use_compiled_kernels(False)
            expected = torch.cat([fn(r, convention)[None] for r in x])
            tq.use_compiled_kernels(True)
            angles = fn(x.repeat((50,) + (1,) * (x.dim() - 1)), convention)[:len(x)]
            assert not (angles[:, [0, 2]] == -torch.pi).any()
            torch.testing.assert_close(angles, expected, rtol=0, atol=1e-6 if dtype == torch.float32 else 1e-12)


def test_compiled_graphs_take_only_the_input_tensors_and_their_sizes(compiled, monkeypatch):
    # Dynamo turns every float a trace reads from a module-level table (or a float static option,
    # an eps) into a graph input that each call boxes in a tensor: 0.5-1 ms of host time for
    # matrix -> quat on a GPU. Read through _math.literal, they are literals of the graph.
    import torchquat._dispatch as dispatch
    import torchquat._math as tqmath

    if not tqmath.literals_trace():
        pytest.skip(f"this torch's dynamo ({torch.__version__}) cannot trace id() of a tuple: literals stay inputs")
    inputs_of = {}

    def graph_inputs(gm, example_inputs):
        inputs_of.setdefault(current, []).extend(
            node.name for node in gm.graph.nodes
            if node.op == "placeholder" and not node.name.startswith("l_tensors_")
            and not (node.name[0] == "s" and node.name[1:].isdigit()))  # (a size: dynamic=True)
        return gm.forward

    monkeypatch.setattr(dispatch, "_backend", graph_inputs)
    monkeypatch.setattr(dispatch, "_compiled", {})
    torch._dynamo.reset()
    names = sorted(set(KERNELS) | {"matrix_to_euler[ZYX]", "quat_to_euler[xyz]", "euler_to_quat[xzx]",
                                   "matrix_to_axis_angle", "axis_angle_to_matrix", "euler_to_matrix[zxz]"})
    for current in names:
        fn, generic, _ = ALL[current]
        leaves = tuple(x.detach().clone().requires_grad_() for x in generic())
        torch.autograd.grad(fn(*leaves).sum(), leaves)
        with torch.no_grad():
            fn(*(x.detach() for x in leaves))
    assert set(inputs_of) == set(names)  # (each was compiled)
    assert {name: inputs for name, inputs in inputs_of.items() if inputs} == {}


def test_small_cpu_batches_run_eagerly_where_eager_is_faster(monkeypatch):
    # A compiled call costs about 30 us before any work: below each kernel's measured crossover
    # (compiled_from_rows) a CPU batch runs the eager kernel instead.
    import torchquat._dispatch as dispatch

    monkeypatch.setattr(dispatch, "_backend", "eager")
    monkeypatch.setattr(dispatch, "_compiled", {})
    torch._dynamo.reset()
    g = torch.Generator().manual_seed(0)
    q = tq.random_quat(2048, generator=g, dtype=torch.float64)
    v = torch.randn(1024, 3, generator=g, dtype=torch.float64)
    compiled_kernels = lambda: {key[0].__name__ for key in dispatch._compiled}
    tq.use_compiled_kernels(True)
    try:
        small = tq.quat_to_matrix(q[:2047])
        assert compiled_kernels() == set()
        large = tq.quat_to_matrix(q)
        assert compiled_kernels() == {"quat_to_matrix_unchecked"}
        # the largest input counts: one rotation applied to many vectors is a large batch
        tq.quat_rotate(q[:1], v)
        assert "rotate_unchecked" in compiled_kernels()
        # one rotation takes the Python floats of torchquat._one_row, compiled kernels on or not
        tq.quat_to_euler(q[:1], "ZYX")
        assert "quat_to_euler_unchecked" not in compiled_kernels()
        # a kernel that the compiled path runs faster at every size compiles for two rotations
        tq.quat_to_euler(q[:2], "ZYX")
        assert "quat_to_euler_unchecked" in compiled_kernels()
    finally:
        tq.use_compiled_kernels(False)
    torch.testing.assert_close(small, tq.quat_to_matrix(q[:2047]), rtol=0, atol=0)  # (eager: bit for bit)
    torch.testing.assert_close(large, tq.quat_to_matrix(q), rtol=0, atol=1e-15)


def test_the_literal_index_holds_torchquats_tables_and_nothing_else(monkeypatch):
    # the index of module-level containers keeps what it finds alive: never the builtins
    # (an interactive session's `_`, the last value it displayed, can be a large tensor list)
    import builtins

    import torchquat._math as tqmath
    from torchquat.matrix import _SHEPPERD

    marker = [object()]
    monkeypatch.setattr(builtins, "_", marker, raising=False)
    index = tqmath._reachable_tables()
    assert id(_SHEPPERD) in index and id(_SHEPPERD[0]) in index
    assert id(marker) not in index and id(vars(builtins)) not in index


def test_switching_the_literals_on_recompiles_no_users_compiled_code(monkeypatch):
    # literal() reads the probe's answer without a guard on it: a user's own compiled region,
    # traced before the first compiled kernel ran the probe, keeps its graph afterwards
    import torchquat._math as tqmath
    from torch._dynamo.testing import CompileCounter

    monkeypatch.setattr(tqmath, "LITERALS_TRACE", None)
    torch._dynamo.reset()
    counter = CompileCounter()
    user = torch.compile(lambda x: tq.quat_to_euler(x, "ZYX") * 2, fullgraph=True, backend=counter)
    q = tq.random_quat(5000, generator=torch.Generator().manual_seed(2), dtype=torch.float64)  # (the column forms)
    first = user(q)
    if not tqmath.literals_trace():
        pytest.skip(f"this torch's dynamo ({torch.__version__}) cannot trace id() of a tuple")
    torch.testing.assert_close(user(q), first, rtol=0, atol=0)
    assert counter.frame_count == 1


@pytest.mark.parametrize("guard", ["hook", "node"])
@pytest.mark.parametrize("name", ["quat_to_matrix", "quat_to_euler[YXZ]", "rot6d_to_matrix", "quat_multiply"])
def test_a_second_derivative_through_a_compiled_kernel_raises_and_the_first_stays_right(name, guard, compiled, monkeypatch):
    # For a loss linear in the kernel's output, the compiled backward's gradient was connected to
    # nothing: torch.autograd.functional.hessian and hvp gave 0, autograd.grad(allow_unused) None
    # (inductor, as shipped: dynamo's "eager" backend has no aot_autograd backward to guard, and
    # graphs cached by earlier tests would make the backend depend on the order tests run in)
    if guard == "node":  # (the fallback, where the compiled node's edges are not the inputs' own)
        monkeypatch.setattr(tq._first_order, "first_order_only", lambda out, tensors: tq._first_order.FirstOrder.apply(out, *tensors))
    fn, generic, _ = ALL[name]
    if name == "quat_multiply":  # (the same tensor twice: one edge per argument)
        fn, x = (lambda q: ALL[name][0](q, q)), generic()[0]
    else:
        (x,) = generic()
    w = torch.randn(fn(x).shape, dtype=x.dtype, generator=torch.Generator().manual_seed(3))
    loss = lambda y: (w * fn(y)).sum()
    with pytest.raises(RuntimeError, match="compiled kernels are first-order"):
        torch.autograd.functional.hessian(loss, x)
    with pytest.raises(RuntimeError, match="compiled kernels are first-order"):
        torch.autograd.functional.hvp(loss, x, torch.ones_like(x))
    leaf = x.clone().requires_grad_()
    (graphed,) = torch.autograd.grad(loss(leaf), leaf, create_graph=True)  # its value is right
    tq.use_compiled_kernels(False)
    (expected,) = torch.autograd.grad(loss(leaf), leaf)
    torch.testing.assert_close(graphed.detach(), expected, rtol=0, atol=1e-10)
    assert torch.func.hessian(loss)(x).abs().max() > 0  # (the true Hessian is not 0: the check is not vacuous)


def test_the_same_tensor_twice_through_a_compiled_kernel_can_be_written_in_place(compiled):
    # the guard's fallback returned a view of the output: an in-place op on the result raised
    a = torch.randn(6, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(4), requires_grad=True)
    y = tq.quat_multiply(a, a)
    y.mul_(2.0)
    (g,) = torch.autograd.grad(y.sum(), a)
    tq.use_compiled_kernels(False)
    (expected,) = torch.autograd.grad((2.0 * tq.quat_multiply(a, a)).sum(), a)
    torch.testing.assert_close(g, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("guard", ["hook", "node"])
def test_a_batch_of_output_gradients_through_a_compiled_kernel_raises_a_clear_error(guard, compiled, monkeypatch):
    # inductor's backward reads its inputs' storage, which autograd's vmap (is_grads_batched,
    # jacobian(vectorize=True)) tensors lack: it failed with "Cannot access data pointer"
    if guard == "node":
        monkeypatch.setattr(tq._first_order, "first_order_only", lambda out, tensors: tq._first_order.FirstOrder.apply(out, *tensors))
    fn, generic, _ = ALL["quat_to_matrix"]
    (x,) = generic()
    with pytest.raises(RuntimeError, match="one output gradient at a time"):
        torch.autograd.functional.jacobian(fn, x, vectorize=True)
    leaf = x.clone().requires_grad_()
    with pytest.raises(RuntimeError, match="one output gradient at a time"):
        torch.autograd.grad(fn(leaf), leaf, torch.eye(9, dtype=x.dtype).reshape(9, 1, 3, 3).expand((9,) + fn(x).shape),
                            is_grads_batched=True)
    unbatched, through_func = torch.autograd.functional.jacobian(fn, x), torch.func.jacrev(fn)(x)
    tq.use_compiled_kernels(False)
    expected = torch.autograd.functional.jacobian(fn, x, vectorize=True)
    torch.testing.assert_close(unbatched, expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(through_func, expected, rtol=0, atol=1e-12)


def test_copysign_and_sign_bit_keep_torchs_bits_in_traces_without_sleefs_call():
    from torchquat._math import copysign, sign_bit

    specials = [0.0, -0.0, 1.5, -1.5, float("inf"), -float("inf"), float("nan"), -float("nan"), 1e-45, -1e-45, 3e38]
    grid = torch.tensor(specials)
    magnitude, sign = (t.flatten() for t in torch.meshgrid(grid, grid, indexing="ij"))
    targets = []

    def backend(gm, example_inputs):
        targets.extend(node.target for node in gm.graph.nodes if node.op == "call_function")
        return gm.forward

    def both(a, b):
        return copysign(a, b), sign_bit(b)

    expected = torch.copysign(magnitude, sign).view(torch.int32), torch.signbit(sign)
    for compiler in (backend, "inductor"):
        torch._dynamo.reset()
        with torch.no_grad():
            got, negative = torch.compile(both, backend=compiler, fullgraph=True)(magnitude, sign)
        assert torch.equal(got.view(torch.int32), expected[0]) and torch.equal(negative, expected[1])
    # float32 traces that record no gradient take integer masks (inductor's CPU code would call
    # SLEEF's copysign out of line); eagerly, with a gradient or in float64, torch's copysign
    assert torch.copysign not in targets and operator.and_ in targets and operator.or_ in targets
    targets.clear()
    torch._dynamo.reset()
    leaf = magnitude[:8].clone().requires_grad_()
    got = torch.compile(lambda a, b: copysign(a, b), backend=backend, fullgraph=True)(leaf, sign[:8])
    assert torch.copysign in targets
    assert torch.equal(torch.autograd.grad(got.sum(), leaf)[0], torch.autograd.grad(torch.copysign(leaf, sign[:8]).sum(), leaf)[0])
    assert torch.equal(copysign(magnitude.double(), sign.double()).view(torch.int64),
                       torch.copysign(magnitude.double(), sign.double()).view(torch.int64))


TRACED_RULES = ["axis_angle_to_quat", "quat_to_axis_angle", "euler_to_quat[ZYZ]", "matrix_to_euler[xzy]", "quat_multiply", "rot6d_to_matrix",
                "quat_geodesic_distance", "matrix_geodesic_distance"]


def _function_applications(gm) -> int:
    return sum("autograd_function_apply" in getattr(node.target, "__name__", "")
               for node in gm.graph.nodes if node.op == "call_function")


def test_training_graphs_of_kernels_with_a_closed_form_rule_apply_it_as_one_function(compiled, monkeypatch):
    # With a gradient, these kernels' traces apply their closed-form rule as an autograd.Function
    # that saves only the inputs (its backward a few products a row: autograd's through the
    # forward's columns took up to 1.3x the time at 1e6 rows); without one, the plain forward.
    import torchquat._closed_form as closed_form
    import torchquat._dispatch as dispatch

    applications = {}

    def backend(gm, example_inputs):
        applications[current] = _function_applications(gm)
        return gm.forward

    monkeypatch.setattr(dispatch, "_backend", backend)
    monkeypatch.setattr(dispatch, "_compiled", {})
    torch._dynamo.reset()
    for name in TRACED_RULES:
        fn, generic, _ = ALL[name]
        leaves = tuple(x.detach().clone().requires_grad_() for x in generic())
        current = name, "grad"
        fn(*leaves)
        with torch.no_grad():
            current = name, "no grad"
            fn(*leaves)
        assert applications[name, "grad"] == 1 and applications[name, "no grad"] == 0, name
    monkeypatch.setattr(closed_form, "TRACED", False)
    current = "switched off"
    fn, generic, _ = ALL["quat_geodesic_distance"]
    fn(*(x.detach().clone().requires_grad_() for x in generic()))
    assert applications[current] == 0


@pytest.mark.parametrize("name", ["quat_multiply", "quat_geodesic_distance", "matrix_geodesic_distance"])
def test_a_closed_form_rules_compiled_gradients_sum_over_broadcast_batch_dims(name, compiled):
    # the rule's backward gives gradients in the broadcast batch shape; each input gets its own
    # shape back (float32, inductor: the graphs training takes)
    fn, generic, _ = ALL[name]
    a, b = (x.to(torch.float32) for x in generic())
    a, b = a[:4].unsqueeze(1), b[:3].unsqueeze(0)  # (4, 1, ...) against (1, 3, ...)
    out, grads, ref, ref_grads = compiled_against_eager(fn, (a, b))
    assert out.shape[:2] == (4, 3) and [g.shape for g in grads] == [a.shape, b.shape]
    torch.testing.assert_close(out, ref, rtol=0, atol=2e-6)
    for g, ref_g in zip(grads, ref_grads):
        torch.testing.assert_close(g, ref_g, rtol=1e-5, atol=2e-5)


# kernels made of two others through the quaternion (_dispatch.compiled_without_gradient)
COMPOSITE_KERNELS = ["euler_to_matrix[zxz]", "euler_to_matrix[XYZ]", "axis_angle_to_matrix", "matrix_to_axis_angle"]


def _stacks_read(gm) -> int:
    """How many ``torch.stack`` results a traced graph reads (dynamo keeps unread ones)."""
    return sum(node.target is torch.stack and len(node.users) > 0 for node in gm.graph.nodes)


@pytest.mark.parametrize("name", COMPOSITE_KERNELS)
def test_composite_kernels_traces_without_a_gradient_pass_the_quaternions_columns_on(name, compiled, monkeypatch):
    # The stack of the quaternion between the two formulas is an (N, 4) buffer inductor writes in
    # one loop and reads back in a second; without it the kernel is one loop. Training traces keep
    # the two kernels (each with its closed-form rule), with the switch on or off.
    import torchquat._dispatch as dispatch

    fn, generic, _ = ALL[name]
    inputs = generic()  # (made first: they may come from compiled kernels too)
    stacks = {}

    def backend(gm, example_inputs):
        stacks[current] = _stacks_read(gm)
        return gm.forward

    monkeypatch.setattr(dispatch, "_backend", backend)
    for fused in (True, False):
        monkeypatch.setattr(dispatch, "FUSED_COMPOSITES", fused)
        monkeypatch.setattr(dispatch, "_compiled", {})
        torch._dynamo.reset()
        leaves = tuple(x.detach().clone().requires_grad_() for x in inputs)
        current = fused, "grad"
        fn(*leaves)
        current = fused, "no grad"
        with torch.no_grad():
            fn(*leaves)
    assert stacks[True, "no grad"] == stacks[False, "no grad"] - 1 >= 1, stacks
    assert stacks[True, "grad"] == stacks[False, "grad"], stacks


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])  # (float32: the polynomial cos, sin, atan2)
@pytest.mark.parametrize("name", COMPOSITE_KERNELS)
def test_composite_kernels_in_one_loop_agree_with_two_loops_and_with_eager(name, dtype, compiled, monkeypatch):
    # One loop lets the C++ compiler contract multiply-adds across the two formulas: float32
    # matrices may move by an ulp or two, never further, and NaN where two loops give NaN
    import torchquat._dispatch as dispatch

    fn, generic, singular = ALL[name]
    inputs = [tuple(x.to(dtype) for x in make()) for make in (generic, singular)]
    outputs = {}
    with torch.no_grad():
        for fused in (True, False):
            monkeypatch.setattr(dispatch, "FUSED_COMPOSITES", fused)
            monkeypatch.setattr(dispatch, "_compiled", {})
            torch._dynamo.reset()
            outputs[fused] = [fn(*x) for x in inputs]
        tq.use_compiled_kernels(False)
        try:
            exact = [fn(*(t.double() for t in x)) for x in inputs]
        finally:
            tq.use_compiled_kernels(True)
    eps = torch.finfo(dtype).eps
    for one_loop, two_loops, ref in zip(outputs[True], outputs[False], exact):
        assert torch.equal(one_loop.isnan(), two_loops.isnan()) and torch.equal(one_loop.isnan(), ref.isnan())
        torch.testing.assert_close(one_loop, two_loops, rtol=0, atol=4 * eps, equal_nan=True)
        torch.testing.assert_close(one_loop.double(), ref, rtol=0, atol=64 * eps, equal_nan=True)


@pytest.mark.parametrize("widest", [512, 256, 128])
def test_kernels_marked_for_256_bit_vectors_get_them_only_where_the_cpu_has_wider(widest, compiled, monkeypatch):
    # (inductor's simdlen names one width: on a CPU without it the loops would not be vectorised)
    import torchquat._dispatch as dispatch

    simdlen = {}

    def compile_recording(fn, **kwargs):
        simdlen[current] = (kwargs.get("options") or {}).get("cpp.simdlen")
        return fn  # (runs the traced function eagerly)

    marked = ["matrix_to_quat", "matrix_to_euler[xzy]", "rot6d_to_matrix", "quat_multiply"]
    names = marked + ["quat_to_matrix", "euler_to_quat[ZYZ]", "matrix_to_axis_angle"]
    inputs = {name: ALL[name][1]() for name in names}  # (made first: they may come from compiled kernels)
    monkeypatch.setattr(torch, "compile", compile_recording)
    monkeypatch.setattr(dispatch, "_backend", "inductor")
    monkeypatch.setattr(dispatch, "_compiled", {})
    monkeypatch.setattr(dispatch, "_widest_cpu_vectors", lambda: widest)
    for current in names:
        ALL[current][0](*inputs[current])
    assert simdlen == {name: 256 if widest > 256 and name in marked else None for name in names}


def test_matrix_to_axis_angles_trace_without_a_gradient_passes_shepperds_raw_row_on(compiled, monkeypatch):
    # The rotation vector depends on neither the quaternion's scale nor its sign: the no-gradient
    # trace skips the normalisation (rsqrt) and the sign key (sign); a training trace keeps both
    import torchquat._dispatch as dispatch

    fn, generic, _ = ALL["matrix_to_axis_angle"]
    inputs = generic()
    targets = {}

    def backend(gm, example_inputs):
        targets[current] = [getattr(node.target, "__name__", str(node.target)) for node in gm.graph.nodes]
        return gm.forward

    monkeypatch.setattr(dispatch, "_backend", backend)
    monkeypatch.setattr(dispatch, "_compiled", {})
    torch._dynamo.reset()
    leaves = tuple(x.detach().clone().requires_grad_() for x in inputs)
    current = "grad"
    fn(*leaves)
    current = "no grad"
    with torch.no_grad():
        fn(*leaves)
    for name in ("rsqrt", "sign"):
        assert name not in targets["no grad"] and name in targets["grad"], (name, targets)


VALUE_FORM_KERNELS = ["matrix_to_euler[xzy]", "quat_to_euler[zxz]", "quat_to_euler[YXZ]", "rot6d_to_matrix", "quat_to_axis_angle",
                      "matrix_to_axis_angle", "quat_geodesic_distance", "matrix_geodesic_distance"]


@pytest.mark.parametrize("name", VALUE_FORM_KERNELS + ["axis_angle_to_quat"])
def test_traces_without_a_gradient_take_the_rules_value_forms_with_the_same_numbers(name, compiled, monkeypatch):
    # Where nothing records a gradient a traced rule (and quat -> Euler's columns) runs its value
    # form: no safe_sqrt blend, no (n - n) / n, no substitutes at gimbal lock. Axis-angle -> quat keeps its plain form there (the
    # value form's cos and sin are torch's, not the compiled polynomials). Graphs run eagerly here,
    # so the same numbers are the same bits, NaN rows included.
    import torchquat._closed_form as closed_form
    import torchquat._dispatch as dispatch

    fn, generic, singular = ALL[name]
    inputs = [tuple(x.to(dtype) for x in make()) for make in (generic, singular) for dtype in (torch.float32, torch.float64)]
    traces, outputs = {}, {}

    def backend(gm, example_inputs):
        names = [getattr(node.target, "__name__", str(node.target)) for node in gm.graph.nodes]
        traces.setdefault(current, []).append([n for n in names if n != "_are_functorch_transforms_active"])
        return gm.forward

    monkeypatch.setattr(dispatch, "_backend", backend)
    for current in (True, False):
        monkeypatch.setattr(closed_form, "VALUE_FORMS", current)
        monkeypatch.setattr(dispatch, "_compiled", {})
        monkeypatch.setattr(dispatch, "_sincos_guesses", {})  # (each variant traces the same graphs)
        torch._dynamo.reset()
        with torch.no_grad():
            outputs[current] = [fn(*x) for x in inputs]
    assert len(traces[True]) == len(traces[False]) >= 2
    if name in VALUE_FORM_KERNELS:
        assert all(len(v) < len(p) for v, p in zip(traces[True], traces[False])), traces
    else:
        assert traces[True] == traces[False]
    for with_values, plain in zip(outputs[True], outputs[False]):
        assert torch.equal(with_values.nan_to_num(), plain.nan_to_num()) and torch.equal(with_values.isnan(), plain.isnan())


@pytest.mark.parametrize("name", ["quat_geodesic_distance", "matrix_geodesic_distance"])
def test_a_users_compile_of_torch_func_grad_keeps_the_differentiable_forms(name):
    # In a trace of torch.func.grad the inputs need not require a gradient; the value forms'
    # plain sqrt would give NaN where the distance is 0 (the first row)
    fn, _, _ = ALL[name]
    first = tq.random_quat(2048, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    second = torch.cat([first[:1], tq.random_quat(2047, dtype=torch.float64, generator=torch.Generator().manual_seed(1))])
    if name == "matrix_geodesic_distance":
        first, second = tq.quat_to_matrix(first), tq.quat_to_matrix(second)

    def total(x):
        return fn(x, second).sum()

    torch._dynamo.reset()
    compiled = torch.compile(torch.func.grad(total), backend="eager", fullgraph=True, dynamic=True)(first)
    assert torch.isfinite(compiled).all()
    assert compiled[0].abs().max() == 0
    torch.testing.assert_close(compiled, torch.func.grad(total)(first), rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["quat_to_axis_angle", "matrix_to_axis_angle"])
def test_a_users_compile_of_torch_func_grad_of_rotation_vectors_is_finite_at_the_identity(name):
    # (the value forms drop the series branch's substitutes: NaN gradients at the identity, row 0)
    fn, _, _ = ALL[name]
    q = tq.random_quat(2048, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    x = torch.cat([torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64), q[1:]])
    if name == "matrix_to_axis_angle":
        x = tq.quat_to_matrix(x)

    def total(x):
        return fn(x).sum()

    torch._dynamo.reset()
    compiled = torch.compile(torch.func.grad(total), backend="eager", fullgraph=True, dynamic=True)(x)
    assert torch.isfinite(compiled).all()
    torch.testing.assert_close(compiled, torch.func.grad(total)(x), rtol=0, atol=1e-12)
