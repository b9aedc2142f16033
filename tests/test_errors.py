"""Bad input gets a clear error naming the function, the argument, what was expected and what came."""

import pytest
import torch

import torchquat as tq


@pytest.mark.parametrize("fn, shape, message", [
    (tq.quat_to_matrix, (5, 3), "quat_to_matrix: expected q of shape (..., 4), got (5, 3)"),
    (tq.matrix_to_quat, (5, 3), "matrix_to_quat: expected R of shape (..., 3, 3), got (5, 3)"),
    (tq.matrix_to_quat, (3,), "matrix_to_quat: expected R of shape (..., 3, 3), got (3,)"),
    (tq.axis_angle_to_quat, (5, 4), "axis_angle_to_quat: expected v of shape (..., 3), got (5, 4)"),
    (tq.quat_to_axis_angle, (2, 3), "quat_to_axis_angle: expected q of shape (..., 4), got (2, 3)"),
    (tq.axis_angle_to_matrix, (), "axis_angle_to_matrix: expected v of shape (..., 3), got ()"),
    (tq.matrix_to_axis_angle, (3, 4), "matrix_to_axis_angle: expected R of shape (..., 3, 3), got (3, 4)"),
    (tq.rot6d_to_matrix, (9,), "rot6d_to_matrix: expected x of shape (..., 6), got (9,)"),
    (tq.matrix_to_rot6d, (6,), "matrix_to_rot6d: expected R of shape (..., 3, 3), got (6,)"),
    (tq.rot9d_to_matrix, (6,), "rot9d_to_matrix: expected x of shape (..., 9) or (..., 3, 3), got (6,)"),
    (tq.quat_normalize, (3,), "quat_normalize: expected q of shape (..., 4), got (3,)"),
    (tq.quat_standardize, (3,), "quat_standardize: expected q of shape (..., 4), got (3,)"),
    (tq.quat_conjugate, (3,), "quat_conjugate: expected q of shape (..., 4), got (3,)"),
    (tq.quat_inverse, (3,), "quat_inverse: expected q of shape (..., 4), got (3,)"),
    (tq.quat_wxyz_to_xyzw, (3,), "quat_wxyz_to_xyzw: expected q of shape (..., 4), got (3,)"),
    (tq.quat_from_jpl, (3,), "quat_from_jpl: expected q of shape (..., 4), got (3,)"),
    (lambda q: tq.euler_gimbal_lock(q, "ZYX"), (5,), "euler_gimbal_lock: expected q of shape (..., 4) or (..., 3, 3), got (5,)"),
])
def test_wrong_trailing_shape_raises_shape_error(fn, shape, message):
    with pytest.raises(tq.ShapeError) as err:
        fn(torch.zeros(shape))
    assert str(err.value) == message
    assert isinstance(err.value, ValueError)


@pytest.mark.parametrize("fn, args, message", [
    (tq.euler_to_quat, (torch.zeros(3),), "euler_to_quat: expected angles of shape (..., 3), got (4,)"),
    (tq.euler_to_matrix, (torch.zeros(3),), "euler_to_matrix: expected angles of shape (..., 3), got (4,)"),
])
def test_euler_shape_errors(fn, args, message):
    with pytest.raises(tq.ShapeError, match=r"expected angles of shape \(\.\.\., 3\), got \(4,\)"):
        fn(torch.zeros(4), "ZYX")


@pytest.mark.parametrize("convention", ["xYz", "XXY", "xyy", "ZY", "ZYXZ", "abc", "", 3, None])
@pytest.mark.parametrize("fn, x", [
    (tq.euler_to_quat, torch.zeros(3)), (tq.euler_to_matrix, torch.zeros(3)),
    (tq.quat_to_euler, torch.tensor([1.0, 0, 0, 0])), (tq.matrix_to_euler, torch.eye(3)),
    (tq.euler_gimbal_lock, torch.tensor([1.0, 0, 0, 0])),
])
def test_invalid_conventions_raise_convention_error(fn, x, convention):
    with pytest.raises(tq.ConventionError) as err:
        fn(x, convention)
    assert str(err.value) == (
        f"{fn.__name__}: invalid convention {convention!r}: use 3 letters all from 'xyz' (extrinsic) "
        "or all from 'XYZ' (intrinsic), adjacent letters different, e.g. 'ZYX' or 'zxz'")
    assert isinstance(err.value, ValueError)


def test_convention_has_no_default():
    with pytest.raises(TypeError):
        tq.euler_to_quat(torch.zeros(3))


@pytest.mark.parametrize("fn, x", [
    (tq.quat_to_matrix, torch.zeros(2, 4, dtype=torch.int64)),
    (tq.quat_to_matrix, torch.zeros(2, 4, dtype=torch.bool)),
    (tq.axis_angle_to_quat, torch.zeros(3, dtype=torch.int32)),
    (lambda a: tq.euler_to_quat(a, "ZYX"), torch.zeros(3, dtype=torch.int64)),
])
def test_integer_input_raises_type_error(fn, x):
    with pytest.raises(TypeError, match="expected .* to be a floating-point tensor, got dtype"):
        fn(x)


@pytest.mark.parametrize("fn, a, b, message", [
    (tq.quat_multiply, (2, 4), (3, 4), "quat_multiply: expected p and q with broadcastable batch shapes, got (2,) and (3,)"),
    (tq.quat_rotate, (2, 4), (3, 3), "quat_rotate: expected q and v with broadcastable batch shapes, got (2,) and (3,)"),
    (tq.quat_geodesic_distance, (5, 2, 4), (3, 4), "quat_geodesic_distance: expected q1 and q2 with broadcastable batch shapes, got (5, 2) and (3,)"),
    (tq.matrix_geodesic_distance, (2, 3, 3), (4, 3, 3), "matrix_geodesic_distance: expected R1 and R2 with broadcastable batch shapes, got (2,) and (4,)"),
])
def test_batch_shapes_that_do_not_broadcast_raise_shape_error(fn, a, b, message):
    with pytest.raises(tq.ShapeError) as err:
        fn(torch.ones(a), torch.ones(b))
    assert str(err.value) == message


def test_slerp_shape_error_and_t_broadcasting():
    with pytest.raises(tq.ShapeError, match="quat_slerp: expected q0 and q1 with broadcastable batch shapes"):
        tq.quat_slerp(torch.ones(2, 4), torch.ones(3, 4), 0.5)
    q0, q1 = tq.random_quat(5), tq.random_quat(5)
    assert tq.quat_slerp(q0, q1, torch.linspace(0, 1, 5)).shape == (5, 4)
    assert tq.quat_slerp(q0[0], q1[0], torch.linspace(0, 1, 7)).shape == (7, 4)
    with pytest.raises(tq.ShapeError, match="quat_slerp: expected q0 and q1 and t with broadcastable batch shapes"):
        tq.quat_slerp(q0, q1, torch.rand(3))  # t's batch (3,) against (5,)


def test_convert_errors_name_the_problem():
    with pytest.raises(ValueError, match="convert: unknown representation 'quaternion': use one of"):
        tq.convert(torch.zeros(4), "quaternion", "matrix")
    with pytest.raises(tq.ConventionError, match="convert: 'euler' needs a convention"):
        tq.convert(torch.zeros(3), "euler", "quat")
    with pytest.raises(tq.ConventionError, match="convert: invalid convention 'XYx'"):
        tq.convert(torch.zeros(3), "euler:XYx", "quat")
    with pytest.raises(tq.ShapeError, match=r"convert: expected x of shape \(\.\.\., 6\), got \(5,\) \(for src='rot6d'\)"):
        tq.convert(torch.zeros(5), "rot6d", "quat")


def test_degenerate_input_gives_nan_never_a_plausible_rotation():
    zero = torch.zeros(4)
    for fn in (tq.quat_to_matrix, tq.quat_normalize, tq.quat_inverse, tq.quat_to_axis_angle,
               lambda q: tq.quat_to_euler(q, "ZYX"), lambda q: tq.quat_rotate(q, torch.ones(3))):
        assert fn(zero).isnan().all()
    q = torch.tensor([0.5, -0.5, 0.5, 0.5])
    for rows in (1, 3, 5000):  # (one row on floats, batches on NumPy columns, selections on bits)
        zeros, units = zero.expand(rows, 4), q.expand(rows, 4)
        assert tq.quat_geodesic_distance(zeros, units).isnan().all()
        assert tq.quat_geodesic_distance(units, zeros).isnan().all()
    assert torch.func.vmap(tq.quat_geodesic_distance)(zero[None], q[None]).isnan().all()  # (the tensor formula)
    collinear = torch.tensor([1.0, 2.0, 3.0, 2.0, 4.0, 6.0])
    assert tq.rot6d_to_matrix(collinear).isnan().all()
    assert tq.rot6d_to_matrix(torch.tensor([1.0, 2.0, 3.0, 0.0, 0.0, 0.0])).isnan().all()
    assert tq.rot6d_to_matrix(torch.tensor([0.0, 0.0, 0.0, 1.0, 0.0, 0.0])).isnan().all()
    assert tq.rot9d_to_matrix(torch.full((9,), float("nan"))).isnan().all()
    # nearly but not exactly collinear is a real rotation
    R = tq.rot6d_to_matrix(torch.tensor([1.0, 0.0, 0.0, 1.0, 1e-3, 0.0], dtype=torch.float64))
    assert torch.allclose(R, torch.eye(3, dtype=torch.float64))


# --- found by an audit of the functions against the contract ---

def test_rot9d_of_rank_0_or_1_is_nan_not_a_plausible_rotation():
    # every rotation that keeps a rank-1 matrix's one direction is as near: none is the answer
    # (a zero matrix gave the identity, a rank-1 one an arbitrary rotation, with no sign of it)
    for dtype in (torch.float32, torch.float64):
        rank2 = torch.diag(torch.tensor([2.0, 1.0, 0.0], dtype=dtype))
        rank1 = torch.outer(torch.tensor([1.0, 2.0, 3.0], dtype=dtype), torch.tensor([0.5, -1.0, 2.0], dtype=dtype))
        M = torch.stack([torch.zeros(3, 3, dtype=dtype), rank1, rank1 + 1e-16 * rank2, rank2,
                         torch.tensor([[0.0, -2.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 0.5]], dtype=dtype)])
        leaf = M.clone().requires_grad_()
        R = tq.rot9d_to_matrix(leaf)
        assert R[:3].isnan().all() and torch.isfinite(R[3:]).all()
        torch.testing.assert_close(R[3], torch.eye(3, dtype=dtype))  # (rank 2: still one nearest rotation)
        (g,) = torch.autograd.grad(R[3:].sum(), leaf)
        assert torch.isfinite(g).all() and (g[:3] == 0).all()  # (each row its own)
        assert tq.convert(M[:1], "rot9d", "quat").isnan().all()


@pytest.mark.parametrize("fn", [
    lambda eps: tq.quat_to_euler(torch.tensor([1.0, 0, 0, 0]), "ZYX", eps=eps),
    lambda eps: tq.matrix_to_euler(torch.eye(3), "ZYX", eps=eps),
    lambda eps: tq.euler_gimbal_lock(torch.tensor([1.0, 0, 0, 0]), "ZYX", eps=eps),
    lambda eps: tq.convert(torch.tensor([1.0, 0, 0, 0]), "quat", "euler:ZYX", eps=eps),
], ids=["quat_to_euler", "matrix_to_euler", "euler_gimbal_lock", "convert"])
def test_eps_out_of_range_is_refused_naming_the_function(fn):
    # inf gave "math domain error"; NaN and negative values switched the lock rule off silently, and
    # eps above pi/2 is no threshold (the test compares sines: 3.2 never found a lock)
    name = ["quat_to_euler", "matrix_to_euler", "euler_gimbal_lock", "convert"]
    for eps in (float("inf"), float("nan"), -1e-6, 1.6):
        with pytest.raises(ValueError, match=r"^\w+: expected eps between 0 and pi/2 radians") as err:
            fn(eps)
        assert str(err.value).split(":")[0] in name
    with pytest.raises(TypeError, match="expected eps to be a number of radians, got 'a'"):
        fn("a")
    for eps in (0.0, 1e-3, torch.pi / 2):  # (the range's ends included)
        fn(eps)


def test_distinct_eps_values_do_not_grow_any_cache():
    from torchquat import _codegen, _dispatch

    q = tq.random_quat(5, generator=torch.Generator().manual_seed(0))
    tq.quat_to_euler(q, "ZYX"), tq.quat_to_euler(q, "ZYX", eps=1e-3)
    before = len(_dispatch._compiled), len(_codegen._CACHE)
    for k in range(200):
        tq.quat_to_euler(q, "ZYX", eps=1e-4 * (k + 1))
        tq.quat_to_euler(q[0], "ZYX", eps=1e-4 * (k + 1))
        tq.euler_gimbal_lock(q, "ZYX", eps=1e-4 * (k + 1))
    assert (len(_dispatch._compiled), len(_codegen._CACHE)) == before


def test_list_and_numpy_inputs_whose_shape_decides_the_form():
    import numpy as np

    m = [[0.0, -2.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 0.5]]
    expected = tq.rot9d_to_matrix(torch.tensor(m))
    for x in (m, np.array(m), np.array(m).reshape(9), sum(m, [])):  # (NumPy's float64 stays float64)
        torch.testing.assert_close(tq.rot9d_to_matrix(x).float(), expected)
    torch.testing.assert_close(tq.convert(np.array(m), "rot9d", "matrix").float(), expected)
    assert tq.euler_gimbal_lock(np.eye(3), "ZYX").shape == () and tq.euler_gimbal_lock([1.0, 0, 0, 0], "ZYX").shape == ()


def test_convert_checks_euler_options_wherever_they_are_given():
    # generic code may pass a convention to every conversion (ignored where no Euler angles are
    # involved), but a misspelt one, or an eps out of range, was accepted there silently
    q = torch.tensor([1.0, 0.0, 0.0, 0.0])
    torch.testing.assert_close(tq.convert(q, "quat", "matrix", convention="ZYX", degrees=True, eps=1e-3), torch.eye(3))
    with pytest.raises(tq.ConventionError, match="^convert: invalid convention 'bogus'"):
        tq.convert(q, "quat", "matrix", convention="bogus")
    with pytest.raises(ValueError, match="^convert: expected eps between 0 and pi/2"):
        tq.convert(q, "quat", "matrix", eps=-3)
    for fn in (lambda d: tq.euler_to_quat(torch.zeros(3), "ZYX", degrees=d),
               lambda d: tq.quat_to_euler(q, "ZYX", degrees=d), lambda d: tq.convert(torch.zeros(3), "euler:ZYX", "quat", degrees=d)):
        with pytest.raises(ValueError, match="expected degrees to be True or False, got 'False'"):
            fn("False")  # (a string: it was truthy, so degrees)
        fn(0), fn(True)


def test_slerp_t_and_devices_are_named_in_errors():
    q = torch.tensor([1.0, 0.0, 0.0, 0.0])
    for t in ("a", None, 1j):
        with pytest.raises(TypeError, match="^quat_slerp: expected t to be a number"):
            tq.quat_slerp(q, q, t)
    meta = torch.empty(4, device="meta")
    for fn in (tq.quat_multiply, tq.quat_geodesic_distance, lambda a, b: tq.quat_slerp(a, b, 0.5)):
        with pytest.raises(RuntimeError, match=r"^\w+: expected \w+ and \w+ on one device, got cpu and meta"):
            fn(q, meta)
    with pytest.raises(RuntimeError, match="^quat_rotate: expected q and v on one device"):
        tq.quat_rotate(q, torch.empty(3, device="meta"))


def test_factories_take_numpy_sizes_and_refuse_non_float_dtypes():
    import numpy as np

    assert tq.random_quat(np.int64(3)).shape == (3, 4) and tq.quat_identity(np.int64(2)).shape == (2, 4)
    assert tq.random_quat((np.int64(2), 3)).shape == (2, 3, 4)
    for fn in (tq.random_quat, tq.quat_identity):
        for dtype in (torch.int64, torch.complex64, torch.bool):
            with pytest.raises(TypeError, match=r"^\w+: expected a floating-point dtype"):
                fn(3, dtype=dtype)
        with pytest.raises(TypeError, match="expected shape to be an int or a sequence of ints"):
            fn(2.5)


def _public_tensor_calls():
    """Every public function that takes tensors, with a ``None`` in each tensor argument's place."""
    q, v, R = torch.zeros(4), torch.zeros(3), torch.eye(3)
    calls = {
        "quat_to_matrix": lambda x: tq.quat_to_matrix(x), "matrix_to_quat": lambda x: tq.matrix_to_quat(x),
        "euler_to_quat": lambda x: tq.euler_to_quat(x, "ZYX"), "quat_to_euler": lambda x: tq.quat_to_euler(x, "ZYX"),
        "euler_to_matrix": lambda x: tq.euler_to_matrix(x, "ZYX"), "matrix_to_euler": lambda x: tq.matrix_to_euler(x, "ZYX"),
        "euler_gimbal_lock": lambda x: tq.euler_gimbal_lock(x, "ZYX"),
        "axis_angle_to_quat": tq.axis_angle_to_quat, "quat_to_axis_angle": tq.quat_to_axis_angle,
        "axis_angle_to_matrix": tq.axis_angle_to_matrix, "matrix_to_axis_angle": tq.matrix_to_axis_angle,
        "rot6d_to_matrix": tq.rot6d_to_matrix, "matrix_to_rot6d": tq.matrix_to_rot6d, "rot9d_to_matrix": tq.rot9d_to_matrix,
        "convert": lambda x: tq.convert(x, "quat", "matrix"),
        "quat_conjugate": tq.quat_conjugate, "quat_inverse": tq.quat_inverse, "quat_normalize": tq.quat_normalize,
        "quat_standardize": tq.quat_standardize, "quat_wxyz_to_xyzw": tq.quat_wxyz_to_xyzw,
        "quat_xyzw_to_wxyz": tq.quat_xyzw_to_wxyz, "quat_from_jpl": tq.quat_from_jpl, "quat_to_jpl": tq.quat_to_jpl,
    }
    cases = [(name, "x" if name in ("convert", "rot6d_to_matrix", "rot9d_to_matrix") else None, fn)
             for name, fn in calls.items()]
    for name, first, second, make in (
            ("quat_multiply", "p", "q", lambda a, b: tq.quat_multiply(a, b)),
            ("quat_rotate", "q", "v", lambda a, b: tq.quat_rotate(a, b)),
            ("quat_slerp", "q0", "q1", lambda a, b: tq.quat_slerp(a, b, 0.5)),
            ("quat_geodesic_distance", "q1", "q2", lambda a, b: tq.quat_geodesic_distance(a, b)),
            ("matrix_geodesic_distance", "R1", "R2", lambda a, b: tq.matrix_geodesic_distance(a, b))):
        other = {"quat_rotate": v, "matrix_geodesic_distance": R}.get(name, q)
        this = R if name == "matrix_geodesic_distance" else q
        cases.append((name, first, lambda x, make=make, other=other: make(x, other)))
        cases.append((name, second, lambda x, make=make, this=this: make(this, x)))
    return cases


@pytest.mark.parametrize("name, argument, call", _public_tensor_calls(), ids=lambda c: c if isinstance(c, str) else "")
def test_none_where_a_tensor_belongs_is_a_type_error_naming_function_and_argument(name, argument, call):
    with pytest.raises(TypeError, match=rf"^{name}: expected \w+ to be a tensor, got NoneType$") as err:
        call(None)
    if argument is not None:
        assert f"expected {argument} to be a tensor" in str(err.value)


@pytest.mark.parametrize("factory", [tq.quat_identity, tq.random_quat])
@pytest.mark.parametrize("shape", [-1, (2, -3), (-2,)])
def test_negative_sizes_are_a_value_error(factory, shape):
    with pytest.raises(ValueError, match=rf"^{factory.__name__}: expected a shape of non-negative sizes"):
        factory(shape)


@pytest.mark.parametrize("token", ["euler:", "euler:XYZW", "euler:xYz", "quat:ZYX"])
def test_malformed_convert_tokens_raise_convention_error_even_with_a_convention_keyword(token):
    with pytest.raises(tq.ConventionError if token.startswith("euler") else ValueError, match="^convert: "):
        tq.convert(torch.zeros(3), token, "matrix", convention="XYZ")
