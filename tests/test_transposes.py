"""How large eager batches move between rows and contiguous columns (``torchquat._planes``): by a
matrix product with the identity, or, where this CPU's products that write rows are slow (MKL on
an AMD EPYC), by stacks and strided writes. Both must give the same numbers and gradients, and a
caller may write any output in place."""

import pytest
import torch

import torchquat._math as tqmath
import torchquat._planes as _planes
from function_table import ALL, DispatchRecorder, fix_transposes
from test_batch_size_paths import BLOCKED, BLOCKED_ROWS, PATH_DEPENDENT, _tiled, _whole_and_blocked


def _run(fn, make, dtype=torch.float64):
    """Forward, gradients and the no-graph forward of ``fn`` on ``make()``'s inputs."""
    inputs = tuple(x.to(dtype) for x in make())
    leaves = tuple(x.clone().requires_grad_() for x in inputs)
    out = fn(*leaves)
    grad = torch.randn(out.shape, dtype=out.dtype, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        values = fn(*inputs)
    return [out.detach(), *torch.autograd.grad(out, leaves, grad), values]


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_copies_give_the_numbers_of_the_identity_products(name, monkeypatch):
    # Without a table the two move the same numbers; a table (quat -> matrix's sums of products,
    # the angles' forms) is applied by a product in both, which may sum in another order: an ulp.
    fn, generic, singular = ALL[name]
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    results = {}
    for setting in ("matmul", "copy"):
        fix_transposes(monkeypatch, setting)
        results[setting] = _run(fn, generic) + _run(fn, singular)
    if name.endswith("geodesic_distance"):
        # At distance pi (a maximum) the gradient is a direction that rounding noise picks (a strided
        # addcmul and a contiguous one may round differently): compared elsewhere only.
        for start in (0, 4):
            away = (results["matmul"][start] - torch.pi).abs() > 1e-6
            for k in (start + 1, start + 2):
                for setting in results:
                    results[setting][k] = results[setting][k][away]
    for a, b in zip(results["matmul"], results["copy"]):
        torch.testing.assert_close(b, a, rtol=4 * torch.finfo(a.dtype).eps, atol=4 * torch.finfo(a.dtype).eps,
                                   equal_nan=True)


@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_copies_leave_no_product_that_writes_rows(name, monkeypatch):
    # The point of the copies: every matrix product left writes planes ((few, many) results), the
    # kind MKL runs fast on every CPU seen; none writes rows of a few entries.
    fn, generic, _ = ALL[name]
    monkeypatch.setattr(tqmath, "SMALL_BATCH_ROWS", 0)
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    fix_transposes(monkeypatch, "copy")
    inputs = tuple(torch.cat([x] * 40) for x in generic())  # (more rows than any table has entries)
    shapes = []

    class Products(DispatchRecorder):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            out = super().__torch_dispatch__(func, types, args, kwargs)
            if func.overloadpacket.__name__ in ("mm", "addmm", "bmm"):
                shapes.append(tuple(out.shape))
            return out

    leaves = tuple(x.clone().requires_grad_() for x in inputs)
    with Products():
        out = fn(*leaves)
        torch.autograd.grad(out, leaves, torch.ones_like(out))
        with torch.no_grad():
            fn(*inputs)
    assert all(rows <= 16 < cols for rows, cols in shapes), shapes


@pytest.mark.parametrize("name", BLOCKED)
def test_blocks_write_their_rows_in_place_with_copies(name, monkeypatch):
    fn, generic, _ = ALL[name]
    fix_transposes(monkeypatch, "copy")
    inputs = [x.to(torch.float32) for x in _tiled(generic(), BLOCKED_ROWS)]
    (whole, whole_ops), (blocked, blocked_ops) = _whole_and_blocked(fn, inputs, monkeypatch)
    assert len(blocked_ops) > 7 * len(whole_ops)  # it did run in blocks
    torch.testing.assert_close(blocked, whole, rtol=0, atol=4 * torch.finfo(torch.float32).eps)


SIZES = [1, 1000, 40_000]  # the small path, the large path's strided and contiguous columns


@pytest.mark.parametrize("setting", ["matmul", "copy"])
@pytest.mark.parametrize("rows", SIZES)
@pytest.mark.parametrize("name", PATH_DEPENDENT)
def test_outputs_may_be_written_in_place(name, rows, setting, monkeypatch):
    # An output made as a view inside a closed form's forward was one autograd forbids writing in
    # place ("a view ... created inside a custom Function"): 11 functions at 40,000 rows refused
    # `out.mul_(3)`. Now it works and the gradient is that of 3 * out; where the backward keeps
    # the output itself (as torch.exp's does), autograd reports the write when it is needed.
    fix_transposes(monkeypatch, setting)
    fn, generic, _ = ALL[name]
    inputs = tuple(x.to(torch.float32)[:rows] for x in _tiled(generic(), rows))
    leaves = tuple(x.clone().requires_grad_() for x in inputs)
    expected = torch.autograd.grad((3 * fn(*leaves)).sum(), leaves)
    out = fn(*leaves)
    out.mul_(3)
    try:
        grads = torch.autograd.grad(out.sum(), leaves)
    except RuntimeError as error:
        assert "modified by an inplace operation" in str(error)
        return
    for g, e in zip(grads, expected):
        torch.testing.assert_close(g, e, rtol=1e-5, atol=1e-5)


def test_the_setting_is_read_from_the_environment(monkeypatch):
    for setting, expected in (("matmul", True), ("copy", False), (" Copy ", False)):
        fix_transposes(monkeypatch, setting)
        assert _planes.by_matmul("rows", 4) is expected and _planes.by_matmul("columns", 3) is expected
    fix_transposes(monkeypatch, "fast")
    with pytest.raises(ValueError, match="TORCHQUAT_TRANSPOSES='fast': use matmul, copy or auto"):
        _planes.by_matmul("rows", 4)


def test_auto_times_each_direction_once_and_outside_the_callers_recording(monkeypatch):
    fix_transposes(monkeypatch, "auto")
    timed = []
    real = _planes._matmul_wins
    monkeypatch.setattr(_planes, "_matmul_wins", lambda d, k: timed.append((d, k)) or real(d, k))
    with DispatchRecorder() as recorder:
        first = _planes.by_matmul("rows", 4)
    assert recorder.names == [] and timed == [("rows", 4)]
    assert _planes.by_matmul("rows", 4) is first and timed == [("rows", 4)]  # (kept)
    _planes.by_matmul("columns", 4)
    assert timed == [("rows", 4), ("columns", 4)]


def test_a_buffer_of_rows_is_the_output_itself(monkeypatch):
    monkeypatch.setattr(tqmath, "PLANAR_ROWS", 0)
    fix_transposes(monkeypatch, "copy")
    a, b = torch.randn(6), torch.randn(6)
    buffer = _planes.plane_buffer(2, [a, b])
    torch.mul(a, 2.0, out=_planes.slot(buffer, 0))
    torch.mul(b, 3.0, out=_planes.slot(buffer, 1))
    out = _planes.rows(buffer)
    assert out.shape == (6, 2) and out.is_contiguous() and out.data_ptr() == buffer.data_ptr()
    assert torch.equal(out, torch.stack((2 * a, 3 * b), -1))
    planes = _planes.plane_buffer(2, [a, b], output=False)  # for a table: contiguous planes
    assert planes.shape == (2, 6) and planes.is_contiguous()
