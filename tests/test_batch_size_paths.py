"""Small batches take few-operation paths (tables, small matmuls), large ones elementwise paths:
both must give the same answers and finite gradients. Large eager CPU batches come in two
layouts, strided columns and, from ``PLANAR_ROWS`` rows, contiguous ones (``torchquat._planes``):
each large-batch test runs on both."""

import pytest
import torch

import torchquat as tq
import torchquat._math as tqmath
import torchquat._planes as _planes
from torchquat._dispatch import kernel
from function_table import ALL, BINARY, DispatchRecorder, assert_paths_agree, fix_transposes, quats, singular_quats
from rotation_samples import cube_rotations, lock_angles

PATH_DEPENDENT = ["quat_to_matrix", "quat_multiply", "quat_rotate", "matrix_to_quat", "axis_angle_to_quat",
                  "quat_to_axis_angle", "quat_slerp", "quat_geodesic_distance", "matrix_geodesic_distance", "rot6d_to_matrix", "euler_to_quat[ZYZ]", "euler_to_quat[xzy]"] + [
    f"{fn}[{c}]" for fn in ("euler_to_matrix", "quat_to_euler", "matrix_to_euler") for c in ("ZYX", "xyz", "ZXZ", "yxy")]


LAYOUTS = {"strided": 10**12, "planar": 0}


@pytest.fixture(params=sorted(LAYOUTS))
def large_batches(request, monkeypatch):
    """A callable that sends every batch down the large-batch path, in the layout the test runs on."""
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", LAYOUTS[request.param])
    return lambda: monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)


# Rows up to which a GPU batch takes the table path (``GPU_SMALL_BATCH_ROWS`` times the kernel's
# gpu_share), as measured on an H100 (docs/bench_profile.md, "On a GPU").
GPU_TABLE_ROWS = {"quat_to_matrix": 4 << 20, "quat_multiply": 4 << 20, "rot6d_to_matrix": 4 << 20,
                  "quat_to_axis_angle": 4 << 20, "matrix_to_euler[ZYX]": 4 << 20, "matrix_to_euler[yxy]": 4 << 20,
                  "quat_to_euler[ZYX]": 1 << 20, "quat_to_euler[ZXZ]": 1 << 20, "axis_angle_to_quat": 1 << 20,
                  "quat_geodesic_distance": 1 << 20, "euler_to_quat[ZYZ]": 1 << 18, "euler_to_quat[xzy]": 1 << 18,
                  "euler_to_matrix[ZYX]": 1 << 18, "matrix_to_quat": 1 << 18}


def _dispatched(fn, inputs, rows, device):
    """The operations ``fn``'s forward and backward dispatch on empty inputs of ``rows`` rows."""
    shaped = tuple(torch.empty((rows,) + x.shape[1:], dtype=x.dtype, device=device, requires_grad=True)
                   for x in inputs)
    with DispatchRecorder() as recorder:
        out = fn(*shaped)
        torch.autograd.grad(out, shaped, torch.ones_like(out))
    return recorder.names


@pytest.mark.parametrize("name", sorted(GPU_TABLE_ROWS))
def test_gpu_batches_take_the_table_path_up_to_the_measured_crossover(name):
    # Off the CPU, launches and not memory passes set the cost, so the few-operation path runs far
    # larger batches there. Shape-only decisions: empty tensors on the meta device stand in for a GPU.
    fn, generic, _ = ALL[name]
    # (1,024 rows: past the table path's own size-dependent choices, e.g. the outer product's matmul)
    inputs, rows = generic(), GPU_TABLE_ROWS[name]
    table_path = _dispatched(fn, inputs, 1024, "meta")
    assert _dispatched(fn, inputs, rows, "meta") == table_path
    assert _dispatched(fn, inputs, rows + 1, "meta") != table_path


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_small_and_large_batch_paths_agree(name, large_batches, monkeypatch):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        inputs = tuple(x.clone().requires_grad_() for x in make())
        small = fn(*inputs)
        g_small = torch.autograd.grad(small.sum(), inputs)
        large_batches()
        large = fn(*inputs)
        g_large = torch.autograd.grad(large.sum(), inputs)
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 4096)
        assert_paths_agree(name, make is singular, small, large, g_small, g_large, atol=1e-14, grad_atol=1e-12)


@pytest.mark.parametrize("dtype, tiny", [(torch.float64, 1e-150), (torch.float32, 1e-12)], ids=["float64", "float32"])
@pytest.mark.parametrize("convention", ["ZYX", "xyz", "ZXZ", "yxy"])
def test_large_batches_are_scale_invariant_and_nan_for_the_zero_quaternion(convention, dtype, tiny, large_batches):
    # The forms are quadratic and 2h squares them again: unscaled, tiny quaternions underflowed
    # to a false gimbal lock. q = 0 (all forms 0) would read as a plausible (0, 0, 0).
    # (generic quaternions, and some at lock or 1e-4 from it: not on the lock test's threshold, where
    # any rounding may flip the decision)
    angles, offset = lock_angles(convention)
    at_lock = tq.euler_to_quat(angles[(offset == 0) | (offset >= 1e-4)], convention)
    q = torch.cat([quats(32), at_lock]).to(dtype)
    batch = torch.cat([torch.zeros(2, 4, dtype=dtype), q, tiny * q, 3.0 * q])
    reference = tq.euler_to_matrix(tq.quat_to_euler(q, convention), convention).double()
    large_batches()
    angles = tq.quat_to_euler(batch, convention)
    assert angles[:2].isnan().all() and not angles[2:].isnan().any()
    for part in angles[2:].split(len(q)):
        R = tq.euler_to_matrix(part, convention).double()
        assert (R - reference).abs().max() < (1e-13 if dtype == torch.float64 else 1e-5)


@pytest.mark.xfail(strict=True, reason="documented limit: the large path's squared minors underflow for |q| < 3e-10 in float32")
def test_large_batch_quat_distance_of_tiny_quaternions(large_batches):
    q1, q2 = quats(64, seed=1).float(), quats(64, seed=2).float()
    reference = tq.quat_geodesic_distance(q1, q2)
    large_batches()
    assert torch.allclose(tq.quat_geodesic_distance(1e-12 * q1, 1e-12 * q2), reference, atol=1e-5)


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_large_batch_paths_pass_gradcheck_and_gradgradcheck(name, large_batches):
    fn, generic, _ = ALL[name]
    large_batches()
    inputs = tuple(x[:3].clone().requires_grad_() for x in generic())
    assert torch.autograd.gradcheck(fn, inputs)
    assert torch.autograd.gradgradcheck(fn, inputs)


def test_planar_columns_and_rows_round_trip_exactly(monkeypatch):
    # the identity matmuls must move numbers without rounding: tiny, huge, subnormal, signed
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    x = torch.tensor([[1e-38, -3e38, 1.0 + 2**-23, 5e-45], [-0.1, 7.0, -1e-30, 2.0**-126]])
    for dtype in (torch.float32, torch.float64):
        v = x.to(dtype)
        cols = _planes.columns(v)
        assert all(c.is_contiguous() for c in cols) and torch.equal(torch.stack(cols, -1), v)
        assert torch.equal(_planes.rows(cols), v) and _planes.rows(cols).is_contiguous()


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_planes_written_in_place_give_the_same_numbers(name, monkeypatch):
    # Where nothing records a graph (a closed form's forward and backward, values) the last passes
    # write into one plane_buffer that rows() transposes without a stack: the same numbers as stacking
    from torchquat import _euler_rotations, axis_angle, distance, matrix, quaternion, rot6d, slerp
    fn, generic, singular = ALL[name]
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)

    def run():
        results = []
        for make in (generic, singular):
            inputs = tuple(x.clone().requires_grad_() for x in make())
            out = fn(*inputs)
            grad = torch.randn(out.shape, dtype=out.dtype, generator=torch.Generator().manual_seed(3))
            results += [out.detach(), *torch.autograd.grad(out, inputs, grad)]
            with torch.no_grad():
                results.append(fn(*make()))
        return results

    written = run()
    for module in (axis_angle, distance, _euler_rotations, matrix, quaternion, rot6d, slerp):
        monkeypatch.setattr(module, "plane_buffer", lambda *args, **kwargs: None)
    for a, b in zip(written, run()):
        torch.testing.assert_close(a, b, rtol=0, atol=0, equal_nan=True)


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_forward_on_contiguous_columns_writes_its_output_planes_without_a_stack(name, monkeypatch):
    # the point of plane_buffer: the last passes write the planes that rows() transposes, so no
    # torch.stack (a pass over every output column) is dispatched when nothing records a graph
    fix_transposes(monkeypatch, "matmul")  # (it counts the transposing matrix products; test_transposes.py the copies)
    fn, generic, _ = ALL[name]
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    inputs = generic()
    with torch.no_grad(), DispatchRecorder() as record:
        fn(*inputs)
    assert "mm" in record.names and "stack" not in record.names, record.names
    leaves = tuple(x.clone().requires_grad_() for x in inputs)
    with DispatchRecorder() as record:
        out = fn(*leaves)
        if type(out.grad_fn).__name__ == "_ClosedFormBackward":  # its forward and backward write planes too
            torch.autograd.grad(out, leaves, torch.ones_like(out))
            assert "stack" not in record.names, record.names


def test_plane_buffer_only_where_nothing_records(monkeypatch):
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    a, b = torch.randn(5, 1), torch.randn(1, 3)
    assert _planes.plane_buffer(4, [a, b]).shape == (4, 5, 3)  # the broadcast batch shape
    leaf = a.clone().requires_grad_()
    assert _planes.plane_buffer(4, [leaf, b]) is None  # autograd refuses out=
    with torch.no_grad():
        assert _planes.plane_buffer(4, [leaf, b]) is not None
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 10**12)
    assert _planes.plane_buffer(4, [a, b]) is None  # strided columns: rows() stacks them


def test_outer_products_from_256_rows_are_exact():
    # from 256 rows the small-batch kernels spread each factor by a 0/1 matmul before one product
    x = torch.cat([singular_quats(), torch.tensor([[1e-300, -1e300, 1.0 + 2**-52, 5e-324]], dtype=torch.float64),
                   torch.randn(300, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(4))])
    y = x.flip(0)
    assert x.shape[0] >= 256
    assert torch.equal(tqmath.outer_product(x, y), (x.unsqueeze(-1) * y.unsqueeze(-2)).flatten(-2))


@pytest.mark.parametrize("fn", [tq.quat_to_matrix, lambda q: tq.quat_multiply(q, q.flip(0)),
                                lambda q: tq.quat_to_euler(q, "xyz")], ids=["quat_to_matrix", "quat_multiply", "quat_to_euler"])
def test_small_batches_spread_by_matmul_match_the_broadcast(fn, monkeypatch):
    q = torch.cat([singular_quats(), tq.random_quat(400, generator=torch.Generator().manual_seed(5), dtype=torch.float64)])
    results = []
    for rows in (tqmath.OUTER_PRODUCT_MATMUL_ROWS, 10**9):  # the 0/1 matmuls, then the broadcast product
        monkeypatch.setattr(tqmath, "OUTER_PRODUCT_MATMUL_ROWS", rows)
        leaf = q.clone().requires_grad_()
        out = fn(leaf)
        results.append((out, torch.autograd.grad(out.sum(), leaf)[0]))
    (spread, g_spread), (broadcast, g_broadcast) = results
    assert torch.equal(spread, broadcast)  # the same products, summed in the same table contraction
    assert torch.allclose(g_spread, g_broadcast, atol=1e-14, rtol=0) and torch.isfinite(g_spread).all()


def test_a_batch_above_the_threshold_matches_one_below():
    q = torch.cat([singular_quats(), tq.random_quat(5000, generator=torch.Generator().manual_seed(0), dtype=torch.float64)])
    assert q.shape[0] > tqmath.SMALL_BATCH_ROWS
    big = tq.quat_to_matrix(q)
    pieces = torch.cat([tq.quat_to_matrix(chunk) for chunk in q.split(1000)])
    assert torch.allclose(big, pieces, atol=1e-15, rtol=0)
    assert torch.allclose(tq.quat_multiply(q, q.flip(0)), torch.cat([tq.quat_multiply(a, b) for a, b in zip(q.split(1000), q.flip(0).split(1000))]), atol=1e-15)


def test_a_batch_on_contiguous_columns_matches_small_batches():
    q = torch.cat([singular_quats(), tq.random_quat(tqmath.PLANAR_ROWS, generator=torch.Generator().manual_seed(1), dtype=torch.float64)])
    v = torch.randn(q.shape[0], 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    R = tq.quat_to_matrix(q)
    for fn, args in ((tq.quat_to_matrix, (q,)), (tq.quat_multiply, (q, q.flip(0))), (tq.quat_rotate, (q, v)),
                     (tq.quat_to_euler, (q, "ZXZ")), (tq.matrix_to_euler, (R, "xyz")), (tq.euler_to_matrix, (v, "ZYX")),
                     (tq.matrix_geodesic_distance, (R, R.flip(0))), (tq.quat_geodesic_distance, (q, q.flip(0)))):
        tensors = [a for a in args if isinstance(a, torch.Tensor)]
        whole = fn(*args)
        pieces = torch.cat([fn(*chunk, *args[len(tensors):]) for chunk in zip(*(t.split(1000) for t in tensors))])
        if fn.__name__.endswith("to_euler"):  # at lock and at +-pi the angles follow rounding, the rotation does not
            whole, pieces = (tq.euler_to_matrix(a, args[-1]) for a in (whole, pieces))
        assert torch.allclose(whole, pieces, atol=1e-13, rtol=0), fn.__name__


@pytest.mark.parametrize("large", [False, True], ids=["small path", "large path"])
@pytest.mark.parametrize("name", sorted(BINARY))
@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_two_input_functions_broadcast_across_ranks(name, large, layout, monkeypatch):
    # one argument a single row without batch dims, the other a batch: as if the row were repeated
    fn, generic, _ = BINARY[name]
    a, b = generic()
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", LAYOUTS[layout])
    if large:
        monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    for single_first in (True, False):
        x, y = (a[0], b) if single_first else (a, b[0])
        repeated = (a[0].expand_as(a), b) if single_first else (a, b[0].expand_as(b))
        assert torch.allclose(fn(x, y), fn(*repeated), atol=1e-14, rtol=0), (name, single_first)


# Large eager CPU batches with nothing to differentiate run block by block (``_math.BLOCK_ROWS``):
# each block must take the whole batch's path and give its numbers.
BLOCKED = ["quat_to_matrix", "matrix_to_quat", "euler_to_quat[ZYX]", "euler_to_quat[xzx]", "quat_to_euler[ZYX]",
           "quat_to_euler[xzx]", "euler_to_matrix[ZYX]", "euler_to_matrix[yxy]", "matrix_to_euler[ZYX]",
           "matrix_to_euler[yxy]", "quat_rotate", "axis_angle_to_quat", "quat_to_axis_angle", "axis_angle_to_matrix",
           "matrix_to_axis_angle", "quat_multiply", "rot6d_to_matrix", "quat_geodesic_distance", "matrix_geodesic_distance",
           "quat_slerp"]
# (axis-angle -> matrix stacks its columns; the distances' output is one column: no transposing matmul)
WRITTEN_IN_PLACE = sorted(set(BLOCKED) - {"axis_angle_to_matrix", "quat_geodesic_distance", "matrix_geodesic_distance"})
BLOCKED_ROWS = tqmath.BLOCK_MIN_BLOCKS * tqmath.BLOCK_ROWS + 777  # (one thread's blocks, and a ragged end)


def _tiled(inputs, rows):
    """The rows of ``inputs`` repeated to ``rows`` rows, each copy a little rotated (distinct rows)."""
    out = []
    for x in inputs:
        reps = -(-rows // x.shape[0])
        tiled = x.repeat((reps,) + (1,) * (x.dim() - 1))[:rows]
        out.append(tiled + 1e-3 * torch.sin(torch.arange(rows, dtype=x.dtype)).view((rows,) + (1,) * (x.dim() - 1)))
    return out


@pytest.fixture(autouse=True)
def _threads():
    """The blocked tests' sizes are one thread's (blocks scale with the thread count): restore it."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def _whole_and_blocked(fn, inputs, monkeypatch):
    """``fn(*inputs)`` without blocks and with them (on one thread), and the operations each dispatched."""
    torch.set_num_threads(1)
    results = []
    for min_blocks in (10**12, tqmath.BLOCK_MIN_BLOCKS):
        monkeypatch.setattr(tqmath, "BLOCK_MIN_BLOCKS", min_blocks)
        with DispatchRecorder() as recorder:
            out = fn(*inputs)
        results.append((out, recorder.names))
    return results


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("name", BLOCKED)
def test_blocked_batches_give_the_whole_batchs_numbers(name, dtype, monkeypatch):
    # Within an ulp, as for any two batch sizes: vectorised atan2 gives a last bit that depends on
    # where a row falls in its loop, and MKL sums a table matmul's terms in an order that depends
    # on the matrix's size (past about 262,000 columns, quat -> Euler's forms round differently).
    fn, generic, _ = ALL[name]
    inputs = [x.to(dtype) for x in _tiled(generic(), BLOCKED_ROWS)]
    (whole, whole_ops), (blocked, blocked_ops) = _whole_and_blocked(fn, inputs, monkeypatch)
    assert len(blocked_ops) > 7 * len(whole_ops)  # it did run in blocks
    assert blocked.shape == whole.shape and blocked.dtype == whole.dtype
    torch.testing.assert_close(blocked, whole, rtol=0, atol=4 * torch.finfo(dtype).eps)


@pytest.mark.parametrize("name", BLOCKED)
def test_a_block_takes_the_whole_batchs_path(name, monkeypatch):
    # The block size sits above every crossover of the kernels (quat -> Euler's planar bound is
    # the highest), so a block dispatches the operations of the large batch it comes from.
    fn, generic, _ = ALL[name]
    monkeypatch.setattr(tqmath, "BLOCK_MIN_BLOCKS", 10**12)

    torch.set_num_threads(1)

    def dispatched(rows):
        inputs = [torch.zeros((rows,) + x.shape[1:], dtype=torch.float32) for x in generic()]
        with DispatchRecorder() as recorder:
            fn(*inputs)
        return recorder.names

    dispatched(tqmath.BLOCK_ROWS)  # a first call builds the kernel's constant tables (lift_fresh)
    assert dispatched(tqmath.BLOCK_ROWS) == dispatched(4 * tqmath.BLOCK_ROWS)


@pytest.mark.parametrize("name", WRITTEN_IN_PLACE)
def test_blocks_write_their_output_in_place(name, monkeypatch):
    # Each block but the first lends its slice of the output to the kernel's final transposing
    # matmul: one copy of the output less per block than with nothing lent.
    fn, generic, _ = ALL[name]
    inputs = [x.to(torch.float32) for x in _tiled(generic(), BLOCKED_ROWS)]
    (_, lent_ops), = _whole_and_blocked(fn, inputs, monkeypatch)[1:]
    monkeypatch.setattr(_planes, "lend", lambda out: None)
    (_, unlent_ops), = _whole_and_blocked(fn, inputs, monkeypatch)[1:]
    assert unlent_ops.count("copy_") - lent_ops.count("copy_") == tqmath.BLOCK_MIN_BLOCKS - 1


def test_which_batches_are_blocked(monkeypatch):
    # Batch dims of any rank, and one row against many (one rotation for a point cloud), are
    # blocked; strided and differentiated inputs run whole.
    fn, generic, _ = ALL["quat_geodesic_distance"]
    q1, q2 = (x.to(torch.float32) for x in _tiled(generic(), tqmath.BLOCK_MIN_BLOCKS * tqmath.BLOCK_ROWS))
    for a, b in ((q1.view(2, -1, 4), q2.view(2, -1, 4)), (q1[:1], q2), (q2, q1[0]), (q1[:1].view(1, 1, 4), q2)):
        (whole, whole_ops), (blocked, blocked_ops) = _whole_and_blocked(fn, (a, b), monkeypatch)
        assert len(blocked_ops) > 7 * len(whole_ops)
        assert blocked.shape == whole.shape
        torch.testing.assert_close(blocked, whole, rtol=0, atol=4 * torch.finfo(torch.float32).eps)
    for case in (q1.T.contiguous().T, q1.clone().requires_grad_()):
        (whole, whole_ops), (blocked, blocked_ops) = _whole_and_blocked(fn, (case, q2), monkeypatch)
        assert blocked_ops == whole_ops and torch.equal(blocked, whole)
        assert blocked.requires_grad == case.requires_grad


def test_one_rotation_for_many_vectors_is_blocked(monkeypatch):
    fn, generic, _ = ALL["quat_rotate"]
    q, v = (x.to(torch.float32) for x in _tiled(generic(), BLOCKED_ROWS))
    (whole, whole_ops), (blocked, blocked_ops) = _whole_and_blocked(fn, (q[3], v), monkeypatch)
    assert len(blocked_ops) > 7 * len(whole_ops) and blocked.shape == whole.shape == v.shape
    torch.testing.assert_close(blocked, whole, rtol=0, atol=4 * torch.finfo(torch.float32).eps)


def test_a_batch_from_a_middle_argument_is_blocked(monkeypatch):
    # slerp(one q0, many q1, a number): the batch comes from neither the first nor the last tensor
    q0, q1 = (x.to(torch.float32) for x in _tiled(ALL["quat_slerp"][1](), BLOCKED_ROWS))
    (whole, whole_ops), (blocked, blocked_ops) = _whole_and_blocked(lambda a, b: tq.quat_slerp(a, b, 0.3), (q0[3], q1), monkeypatch)
    assert len(blocked_ops) > 7 * len(whole_ops) and blocked.shape == whole.shape == q1.shape
    torch.testing.assert_close(blocked, whole, rtol=0, atol=4 * torch.finfo(torch.float32).eps)


def test_one_pair_at_many_times_is_a_large_batch_and_blocked(monkeypatch):
    # slerp's batch may come from t alone (a whole path between two rotations): the columns, in
    # blocks, and the numbers of the rows' path
    fix_transposes(monkeypatch, "matmul")  # (it counts the transposing matrix products; test_transposes.py the copies)
    q0, q1 = tq.random_quat(2, generator=torch.Generator().manual_seed(6))
    t = torch.linspace(-0.25, 1.25, BLOCKED_ROWS)
    (whole, whole_ops), (blocked, blocked_ops) = _whole_and_blocked(tq.quat_slerp, (q0, q1, t), monkeypatch)
    assert len(blocked_ops) > 7 * len(whole_ops) and blocked.shape == whole.shape == (BLOCKED_ROWS, 4)
    assert "mm" in whole_ops and "cat" not in whole_ops  # the columns' transposes; the rows stack their two times
    torch.testing.assert_close(blocked, whole, rtol=0, atol=4 * torch.finfo(torch.float32).eps)
    rows = torch.cat([tq.quat_slerp(q0, q1, part) for part in t.split(2048)])
    torch.testing.assert_close(whole, rows, rtol=0, atol=4 * torch.finfo(torch.float32).eps)


@pytest.mark.parametrize("final", ["fresh", "view of the lent slice"])
def test_a_kernel_whose_intermediate_takes_the_lent_slice_still_returns_its_output(final, monkeypatch):
    # A kernel whose transposing matmul makes an intermediate of the output's shape writes that
    # into the lent slice; its output, computed from it, must still land there intact.
    fix_transposes(monkeypatch, "matmul")  # (it counts the transposing matrix products; test_transposes.py the copies)
    @kernel(blocked_row_dims=(1,))
    def swapped_pairs(x):
        y = _planes.rows(_planes.columns(x))  # (takes the loan: the output's shape)
        return y.flip(-1) if final == "fresh" else y.view(-1, 2, 2).transpose(-2, -1)  # (2 x 2 "matrices")

    x = torch.randn(BLOCKED_ROWS, 4, generator=torch.Generator().manual_seed(3))
    (whole, _), (blocked, blocked_ops) = _whole_and_blocked(swapped_pairs, (x,), monkeypatch)
    assert blocked_ops.count("mm") == 2 * tqmath.BLOCK_MIN_BLOCKS  # blocked, on contiguous columns
    assert torch.equal(blocked, whole)


@pytest.mark.parametrize("transposes", ["matmul", "copy"])
def test_blocks_grow_with_the_thread_count(transposes, monkeypatch):
    # Each operation keeps one 32,768-element chunk or more per thread: two threads, blocks of twice
    # the rows (so 8 one-thread blocks' worth of rows runs whole).
    fix_transposes(monkeypatch, transposes)  # (the timed choice may differ between the thread counts' calls)
    fn, generic, _ = ALL["quat_geodesic_distance"]
    q1, q2 = (x.to(torch.float32) for x in _tiled(generic(), tqmath.BLOCK_MIN_BLOCKS * tqmath.BLOCK_ROWS))
    fn(q1, q2)  # (a first call may make a cached constant: one operation more in its record)
    (_, one_thread_whole), (_, one_thread_blocked) = _whole_and_blocked(fn, (q1, q2), monkeypatch)
    torch.set_num_threads(2)
    assert tqmath.block_rows() == 2 * tqmath.BLOCK_ROWS
    with DispatchRecorder() as recorder:
        fn(q1, q2)
    assert recorder.names == one_thread_whole != one_thread_blocked


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_transforms_run_the_large_batch_paths(name, large_batches):
    # vmap and torch.func.grad on large batches: the contiguous columns' out= buffers have no
    # batching rule, so under a transform the plain column code runs.
    fn, generic, _ = ALL[name]
    inputs = generic()
    large_batches()
    expected = fn(*inputs)
    stacked = [torch.stack((x, x.flip(0))) for x in inputs]
    out = torch.func.vmap(fn)(*stacked)
    assert torch.allclose(out[0], expected, atol=1e-12, rtol=0) and torch.allclose(out[1], fn(*(x.flip(0) for x in inputs)), atol=1e-12, rtol=0)
    grads = torch.func.grad(lambda *x: fn(*x).sum(), argnums=tuple(range(len(inputs))))(*inputs)
    leaves = [x.clone().requires_grad_() for x in inputs]
    references = torch.autograd.grad(fn(*leaves).sum(), leaves)
    for g, r in zip(grads, references):
        assert torch.allclose(g, r, atol=1e-10, rtol=0)


def test_threads_blocking_at_once_keep_their_own_outputs(monkeypatch):
    # The slice a block lends to its final matmul is the calling thread's (the io reader thread,
    # or a user's worker threads, may run kernels at the same time).
    import threading

    torch.set_num_threads(1)
    generator = torch.Generator().manual_seed(4)
    batches = [tq.random_quat(BLOCKED_ROWS, generator=generator) for _ in range(2)]
    monkeypatch.setattr(tqmath, "BLOCK_MIN_BLOCKS", 10**12)
    expected = [tq.quat_to_matrix(q) for q in batches]
    monkeypatch.setattr(tqmath, "BLOCK_MIN_BLOCKS", 8)
    results = [[], []]

    def work(i):
        for _ in range(3):
            results[i].append(tq.quat_to_matrix(batches[i]))

    workers = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    for got, want in zip(results, expected):
        assert len(got) == 3 and all(torch.equal(g, want) for g in got)


@pytest.mark.parametrize("transposes", ["matmul", "copy"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("convention", ["ZYX", "xyz", "ZXZ", "yxy"])
def test_large_batch_euler_values_equal_the_differentiable_forward_bit_for_bit(convention, dtype, transposes, large_batches,
                                                                               monkeypatch):
    # With nothing to differentiate the angles skip the substitutions that keep autograd finite
    # (safe_sqrt's, and t1's (0, 1) pair at lock); a user must get the same angles either way
    # (with the copies too: atan2 written into strided columns of the rows would round differently).
    fix_transposes(monkeypatch, transposes)
    large_batches()
    q = torch.cat([singular_quats(), quats(200, seed=5)]).to(dtype)
    q = torch.cat([q, q[:50] * 1e-12, torch.zeros(2, 4, dtype=dtype)])
    R = tq.quat_to_matrix(q[:-52])
    for fn, x in ((tq.quat_to_euler, q), (tq.matrix_to_euler, R)):
        values = fn(x, convention)
        differentiable = fn(x.clone().requires_grad_(), convention)
        assert differentiable.grad_fn is not None
        torch.testing.assert_close(values, differentiable.detach(), rtol=0, atol=0, equal_nan=True)


def _near_the_lock_boundary(convention: str, dtype, rows: int = 2000):
    """Rotations whose middle angle is within 10% of ``eps`` from 0 / pi/2 off lock's edge, where the
    rounding of each path decides: float64 angles turned into quaternions and matrices."""
    g = torch.Generator().manual_seed(7)
    eps = 1e-7 if dtype == torch.float64 else 1e-6
    lock_at = 0.0 if convention.upper()[0] == convention.upper()[2] else torch.pi / 2
    offset = eps * (1.0 + 0.1 * (2 * torch.rand(rows, generator=g, dtype=torch.float64) - 1))
    middle = lock_at + offset if lock_at == 0.0 else lock_at - offset
    angles = torch.stack((torch.rand(rows, generator=g, dtype=torch.float64) * 6 - 3, middle,
                          torch.rand(rows, generator=g, dtype=torch.float64) * 6 - 3), dim=-1)
    q = tq.euler_to_quat(angles, convention).to(dtype)
    return q, tq.quat_to_matrix(q)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("convention", ["ZYX", "xyz", "ZXZ"])
@pytest.mark.parametrize("rows", [1000, 1500, 70_000, BLOCKED_ROWS], ids=["small", "strided", "planar", "blocked"])
def test_gimbal_lock_mask_is_the_test_quat_to_euler_applied_at_every_batch_size(rows, convention, dtype):
    # Near eps each path's rounding decides, so a row may lock in one batch size and not in
    # another (both angles give its rotation); euler_gimbal_lock must take the same decision as
    # the conversion of the same batch: a True row is one whose third angle was set to 0.
    torch.set_num_threads(1)
    for x, to_euler in zip(_near_the_lock_boundary(convention, dtype), (tq.quat_to_euler, tq.matrix_to_euler)):
        x = _tiled([x], rows)[0] if rows > x.shape[0] else x[:rows]
        mask = tq.euler_gimbal_lock(x, convention)
        zero = to_euler(x, convention)[..., 2] == 0
        assert 0 < mask.sum() < rows  # the boundary is crossed
        assert zero[mask].all(), (to_euler.__name__, int((mask & ~zero).sum()))
        # (an unlocked third angle is 0 only by rounding: t1's pair (y, 0) in float32)
        assert (zero & ~mask).sum() <= rows // 100


@pytest.mark.parametrize("convention", sorted(tq.EULER_CONVENTIONS))
def test_exact_half_turns_give_the_same_angles_on_every_path_and_never_minus_pi(convention):
    # yaw = 180 degrees came out as +pi on one batch size and -pi on another (and -pi for -q where
    # q gave +pi): a wrap into [-pi, pi) on the small path, signed zeros in strided columns
    cube = cube_rotations()
    negative_zeros = torch.where(cube == 0, -0.0, cube)  # (as many matrices written by NumPy code hold)
    q = tq.matrix_to_quat(cube)
    reference = None
    for rows in (1, 1100, 70_000):  # small, strided / column-wise, contiguous planes and blocks
        repeat = -(-rows // len(cube))
        for name, x, fn in (("q", q, tq.quat_to_euler), ("-q", -q, tq.quat_to_euler),
                            ("R", cube, tq.matrix_to_euler), ("R with -0", negative_zeros, tq.matrix_to_euler)):
            batch = x.repeat((repeat,) + (1,) * (x.dim() - 1))[:max(rows, len(cube))]
            angles = fn(batch, convention)[:len(cube)] if rows > 1 else torch.cat([fn(r, convention)[None] for r in x])
            outer = angles[:, [0, 2]]
            assert not (outer == -torch.pi).any(), (rows, name, angles[(outer == -torch.pi).any(-1)])
            if reference is None:
                reference = angles
            torch.testing.assert_close(angles, reference, rtol=0, atol=1e-12, msg=f"{rows} rows, {name}")
    # and they are the rotations
    torch.testing.assert_close(tq.euler_to_matrix(reference, convention), cube, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_angles_a_few_ulps_above_minus_pi_stay_within_pi_on_every_path(dtype):
    # the large batches' wrap, ceil((t3 - pi) / 2 pi), rounded t3 - pi to -2 pi for t3 an ulp or
    # two above -pi and returned pi plus those ulps: outside SPEC's [-pi, pi]
    import math
    g = torch.Generator().manual_seed(0)
    a = (torch.rand(5000, 3, generator=g, dtype=torch.float64) - 0.5) * 2
    a[:, 0] = -math.pi + (torch.arange(5000) % 64).double() * 2.0 ** -51
    q = tq.euler_to_quat(a, "ZYX").to(dtype)
    limit = torch.tensor(math.pi, dtype=dtype)
    for rows in (1000, 5000):  # small, column-wise
        for angles in (tq.quat_to_euler(q[:rows], "ZYX"), tq.matrix_to_euler(tq.quat_to_matrix(q[:rows]), "ZYX"),
                       tq.quat_to_euler(q[:rows], "xyz"), tq.matrix_to_euler(tq.quat_to_matrix(q[:rows]), "zyz")):
            assert (angles.abs() <= limit).all()


def _batched_gradients_match_a_loop(fn, inputs):
    leaves = tuple(x.clone().requires_grad_() for x in inputs)
    out = fn(*leaves)
    grads = torch.randn((3,) + out.shape, dtype=out.dtype, generator=torch.Generator().manual_seed(4))
    batched = torch.autograd.grad(out, leaves, grads, is_grads_batched=True)
    for k, g in enumerate(grads):
        for got, expected in zip(batched, torch.autograd.grad(fn(*leaves), leaves, g)):
            torch.testing.assert_close(got[k], expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", sorted(ALL))
def test_batched_gradients_match_a_loop_on_small_batches(name):
    # torch.autograd.functional.jacobian(vectorize=True) runs the backward under autograd's
    # legacy vmap (is_grads_batched)
    fn, generic, _ = ALL[name]
    _batched_gradients_match_a_loop(fn, generic())


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_batched_gradients_match_a_loop_on_large_batches(name, large_batches):
    # the closed forms' out= writes and broadcasts have no batching rule there (a RuntimeError
    # from quat_to_matrix, rot6d, quat_to_axis_angle and slerp): their backward differentiates
    # the plain forward instead
    fn, generic, _ = ALL[name]
    large_batches()
    _batched_gradients_match_a_loop(fn, generic())


def test_quat_distance_of_large_norms_is_right_with_or_without_a_graph_up_to_4096_rows():
    # the columns square products of the inputs (norms 3e-10 to 4e9 in float32): taken without a
    # graph from 1,537 rows, an eval call at norm 1e10 was 2.8 rad off where training was right
    q1, q2 = quats(2000, seed=1).float(), quats(2000, seed=2).float()
    reference = tq.quat_geodesic_distance(q1.double(), q2.double()).float()
    for scale in (1e-11, 1e10):
        leaf = (scale * q1).requires_grad_()
        with torch.no_grad():
            evaluated = tq.quat_geodesic_distance(scale * q1, scale * q2)
        assert torch.equal(evaluated, tq.quat_geodesic_distance(leaf, scale * q2).detach())
        torch.testing.assert_close(evaluated, reference, rtol=0, atol=2e-6)


_SCALE_INVARIANT = {
    "quat_to_matrix": tq.quat_to_matrix,
    "quat_rotate": lambda q: tq.quat_rotate(q, torch.tensor([1.0, -2.0, 0.5], dtype=q.dtype).expand(q.shape[:-1] + (3,))),
    "quat_to_axis_angle": tq.quat_to_axis_angle,
    "quat_to_euler[ZYX]": lambda q: tq.quat_to_euler(q, "ZYX"),
    "quat_to_euler[zxz]": lambda q: tq.quat_to_euler(q, "zxz"),
    "quat_geodesic_distance": lambda q: tq.quat_geodesic_distance(q, torch.tensor([0.9, -0.1, 0.3, 0.2], dtype=q.dtype)),
    "quat_normalize": tq.quat_normalize,
    "quat_slerp": lambda q: tq.quat_slerp(q, torch.tensor([0.9, -0.1, 0.3, 0.2], dtype=q.dtype), 0.3),
    "convert[quat->rot6d]": lambda q: tq.convert(q, "quat", "rot6d"),
}
# the README's ranges for gradients: narrower than the values' (1e-19 to 1e19 in float32), as the
# intermediates of some paths' gradients reach |q|^-4 (inf or NaN below) or |q|^-4 against |q|^4
# (a term lost to underflow above: finite gradients, wrong by 20-50%)
_GRADIENT_NORMS = {torch.float32: (1e-9, 1e9), torch.float64: (1e-75, 1e75)}


@pytest.mark.parametrize("rows", [1, 600, 1_100, 5_000, 9_000])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("name", sorted(_SCALE_INVARIANT))
def test_gradients_of_non_unit_quaternions_scale_as_one_over_the_norm_in_the_documented_range(name, dtype, rows):
    # (outside it, on some paths, the values are right and the gradients are not: see the README)
    fn = _SCALE_INVARIANT[name]
    q = torch.tensor([0.5, 0.5, 0.5, 0.5], dtype=dtype).repeat(rows, 1)
    weights = None
    gradients = []
    for scale in (1.0, *_GRADIENT_NORMS[dtype]):
        leaf = (q * scale).requires_grad_()
        out = fn(leaf)
        weights = torch.linspace(0.3, 1.7, out[0].numel(), dtype=dtype).reshape(out.shape[1:]) if weights is None else weights
        (g,) = torch.autograd.grad((out * weights).sum(), leaf)
        assert torch.isfinite(out).all() and torch.isfinite(g).all(), (scale, g[0])
        gradients.append(g * scale)
    tolerance = 1e-4 if dtype == torch.float32 else 1e-10
    for g in gradients[1:]:
        torch.testing.assert_close(g, gradients[0], rtol=tolerance, atol=tolerance * gradients[0].abs().max())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_quat_inverse_gradient_is_finite_in_the_documented_range(dtype):
    for scale in _GRADIENT_NORMS[dtype]:
        for rows in (1, 5_000):
            leaf = (torch.tensor([0.5, 0.5, 0.5, 0.5], dtype=dtype).repeat(rows, 1) * scale).requires_grad_()
            (g,) = torch.autograd.grad(tq.quat_inverse(leaf).sum(), leaf)
            assert torch.isfinite(g).all(), scale
