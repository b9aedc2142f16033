"""Contiguous columns for the large-batch eager kernels.

A large-batch kernel works column by column: ``q.unbind(-1)`` and, at the end,
``torch.stack(columns, -1)``. In eager PyTorch on the CPU both ends are slow for a rows-of-k
layout. ``unbind`` gives strided views, and an eager kernel on strided views loses its vectorised
loop (per 1e6 float32 rows, one thread: ``atan2`` 25 ms instead of 1.3, ``sqrt`` 12 instead of
about 0.5, a product 0.8 instead of 0.45). ``torch.stack(columns, -1)`` interleaves at 8.7 ms
for 4 columns and 19 ms for 9, and ``.t().contiguous()`` is no faster. A matrix product with the
identity does the same transposes in 1.3-1.8 ms (4 columns) and 5-6 ms (9): MKL reads and writes
either layout at memory speed. A product with any other constant table (the final linear
combination of a kernel) costs the same, so :func:`rows` takes one.

That holds for Intel CPUs. On an AMD EPYC (the same torch and MKL) a matrix product whose result
has rows of a few entries is slower than any copy (interleaving 4 planes of 65,536 rows: 0.74 ms,
against 0.53 ms for ``out.copy_(planes.t())`` and 0.03 ms for a plain copy of the same bytes), and
reading rows of 3 into planes 2.5x slower than ``torch.stack(x.unbind(-1), 0)``, while products
that write planes stay fast. So each transpose direction and row width is timed once per process
(:func:`by_matmul`, 3-11 ms each on the EPYC, or set by ``TORCHQUAT_TRANSPOSES``): where the product loses,
columns are read by a stack of the rows' entries, and the output is written without a product:
the last passes write strided columns of the output rows (:func:`plane_buffer`), or planes are
copied transposed, or (where autograd records) stacked along the last dimension.

The identity product is exact for finite numbers (``x * 1 + 0 * y``); it turns ``-0.0`` into
``+0.0``, and a row holding an infinity gets NaN in its other columns (``0 * inf``). Both stay
within what the kernels promise: no rotation has an infinite entry.

Only eager CPU batches of at least ``share * PLANAR_ROWS`` rows take this path, the share a
kernel's measured crossover (below, strided columns sit in cache and the two matmuls cost more
than they save). Under ``torch.compile`` inductor
fuses ``unbind`` and ``stack`` into its single loop, and on a GPU a float32 matrix product may
run in TF32 (10-bit mantissa) when the user allows it, so there the plain ops run.
"""

import os
import threading
import time
from typing import Dict, Optional, Sequence, Tuple

import torch
from torch import Tensor

from . import _math
from ._closed_form import _transformed
from ._math import combine, constant, sparse_columns


def planar(x: Tensor, row_numel: int = 1, share: float = 1.0) -> bool:
    """Whether column code on ``x`` (rows of ``row_numel``) should use contiguous planes: eager, on
    the CPU, and at least ``share * PLANAR_ROWS`` rows (a kernel's measured crossover)."""
    return (not torch.compiler.is_compiling() and x.is_cpu
            and x.numel() >= _math.PLANAR_ROWS * share * row_numel)


_IDENTITIES = {k: tuple(tuple(float(i == j) for j in range(k)) for i in range(k)) for k in range(1, 17)}
_SPARSE = {}


def _eye(k: int, like: Tensor) -> Tensor:
    return constant(f"eye{k}", _IDENTITIES[k], like)


TRANSPOSES_VARIABLE = "TORCHQUAT_TRANSPOSES"
"""The environment variable that fixes how contiguous columns are transposed: ``matmul`` (products
with the identity, both directions), ``copy`` (stacks and strided writes), or unset (or ``auto``):
timed once per process, each direction and row width on its own (:func:`by_matmul`)."""

_BY_MATMUL: Dict[Tuple[str, int], bool] = {}
_TIMED_ROWS = 16384


def _fastest(call) -> float:
    times = []
    for _ in range(5):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times)


def _matmul_wins(direction: str, k: int) -> bool:
    """Time a product with the identity against a stack, on ``_TIMED_ROWS`` rows of ``k`` float32
    (fresh tensors, no gradient; the fastest of 5 calls each: 3-11 ms on the EPYC, 50 ms more for the first, which warms MKL up)."""
    eye = torch.eye(k)
    with torch.no_grad():
        if direction == "rows":  # planes -> rows
            planes, out = torch.rand(k, _TIMED_ROWS), torch.empty(_TIMED_ROWS, k)
            by_product = lambda: torch.mm(planes.t(), eye, out=out)  # noqa: E731
            by_copy = lambda: torch.stack(planes.unbind(0), -1, out=out)  # noqa: E731
        else:  # rows -> planes
            x, out = torch.rand(_TIMED_ROWS, k), torch.empty(k, _TIMED_ROWS)
            by_product = lambda: torch.mm(eye, x.t(), out=out)  # noqa: E731
            by_copy = lambda: torch.stack(x.unbind(-1), 0, out=out)  # noqa: E731
        by_product(), by_copy()  # (warm-up)
        return _fastest(by_product) <= _fastest(by_copy)


def by_matmul(direction: str, k: int) -> bool:
    """Whether contiguous columns are transposed by a matrix product (else by a copy) in
    ``direction`` (``"columns"``: rows of ``k`` into planes; ``"rows"``: ``k`` planes into rows).

    Fixed by ``TORCHQUAT_TRANSPOSES`` (``matmul`` or ``copy``), else timed once per process and
    ``(direction, k)`` and kept: on an Intel CPU the product wins both ways, on an AMD EPYC it loses
    into rows of every width and from rows of 3 (see the module's docstring). The two give the same
    numbers where no table is applied, but for the identity product's ``-0.0 -> +0.0``; with a table,
    the same to rounding.

    Example:
        >>> by_matmul("rows", 4) in (True, False)
        True
    """
    key = (direction, k)
    choice = _BY_MATMUL.get(key)
    if choice is None:
        setting = os.environ.get(TRANSPOSES_VARIABLE, "auto").strip().lower()
        if setting in ("matmul", "copy"):
            choice = setting == "matmul"
        elif setting in ("auto", ""):
            choice = _timed(direction, k)
        else:
            raise ValueError(f"{TRANSPOSES_VARIABLE}={setting!r}: use matmul, copy or auto")
        _BY_MATMUL[key] = choice
    return choice


def _timed(direction: str, k: int) -> bool:
    # (outside any dispatch mode or tracer of the caller's: its own small tensors, timed, not recorded)
    try:
        from torch.utils._python_dispatch import _disable_current_modes
    except ImportError:  # pragma: no cover - an older torch: timed as it is
        return _matmul_wins(direction, k)
    with _disable_current_modes():
        return _matmul_wins(direction, k)


_lent = threading.local()


def lend(out: Optional[Tensor]) -> None:
    """Lend ``out``, a contiguous ``(M, m)`` tensor, to the first of this thread's next :func:`rows`
    on contiguous columns whose result has that shape and dtype: it is written into ``out``
    instead of a fresh tensor (the dispatcher's blocks of rows write their output in place; see
    ``_dispatch``), which ends the loan. ``None`` ends a loan no :func:`rows` took."""
    _lent.out = out


def _borrow(shape, dtype) -> Optional[Tensor]:
    """The lent tensor, if it has ``shape`` and ``dtype`` (which ends the loan), else ``None``."""
    out = getattr(_lent, "out", None)
    if out is None or out.shape != shape or out.dtype != dtype:
        return None
    _lent.out = None
    return out


def _to_rows(planes: Tensor, table: Optional[Tensor] = None) -> Tensor:
    """``(k, M) -> (M, k)`` (or ``planes.T @ table``), contiguous, into a lent tensor if it fits."""
    m = planes.shape[0] if table is None else table.shape[1]
    out = _borrow((planes.shape[1], m), planes.dtype)
    if by_matmul("rows", m):
        return torch.mm(planes.t(), _eye(m, planes) if table is None else table, out=out)
    if table is not None:  # (a product that writes planes is fast either way)
        planes = torch.mm(table.t(), planes)
    # (ATen's blocked transposing copy: 0.45-0.83 ms for 3-9 planes of 65,536 rows on the EPYC,
    # against 0.62-1.27 for a stack along the last dimension)
    out = planes.new_empty((planes.shape[1], m)) if out is None else out
    return out.copy_(planes.t())


def _combined(cols, table, name: str, offset, out: Optional[Tensor] = None):
    """``combine`` of each column of ``table``: one pass per term (fused under compile); ``out``:
    a tensor whose last dimension's entries the columns' last passes write (eager, no graph)."""
    terms = None if torch.compiler.is_compiling() else _SPARSE.get(name)
    if terms is None:
        terms = sparse_columns(table, offset)
        if not torch.compiler.is_compiling():
            _SPARSE[name] = terms
    return tuple(combine(cols, t, out=None if out is None else out.select(-1, j)) for j, t in enumerate(terms))


def _with_offset(planes, offset):
    if offset is None:
        return tuple(planes)
    return tuple(p + v if v else p for p, v in zip(planes, offset))


def columns(x: Tensor, table=None, name: str = "", offset=None, share: float = 1.0) -> Tuple[Tensor, ...]:
    """The entries of ``x``'s last dimension, or of ``x @ table + offset``, each a tensor of
    ``x``'s batch shape: contiguous results of one matmul on the eager CPU path (see the module's
    docstring), ``unbind``'s views (and one pass per term of the table) otherwise.

    Args:
        x: any tensor with a last dimension of a few (``k``) entries.
        table: optional nested sequence of numbers, ``k`` rows of ``m``: a linear map of the rows.
        name: the table's key in the constants' cache (required with ``table``).
        offset: optional ``m`` numbers added to the mapped entries.
        share: the kernel's crossover as a share of ``PLANAR_ROWS`` (see :func:`planar`).

    Returns:
        ``k`` (or ``m``) tensors.

    Shape:
        ``(..., k)`` -> ``k`` (or ``m``) times ``(...)``.

    Example:
        >>> w, x, y, z = columns(torch.tensor([[1., 2., 3., 4.], [5., 6., 7., 8.]]))
        >>> y
        tensor([3., 7.])
        >>> columns(torch.tensor([[1., 2.]]), ((1., 0.5), (1., 0.0)), "demo", offset=(0.0, 1.0))
        (tensor([3.]), tensor([1.5000]))
    """
    k = x.shape[-1]
    if not planar(x, k, share):
        cols = x.unbind(-1)
        return cols if table is None else _combined(cols, table, name, offset)
    flat = x.reshape(-1, k)
    if by_matmul("columns", k):
        matrix = _eye(k, flat) if table is None else constant(name + "^T", tuple(zip(*table)), flat)
        planes = torch.mm(matrix, flat.t())
    else:
        planes = torch.stack(flat.unbind(-1), 0)
        if table is not None:
            planes = torch.mm(constant(name + "^T", tuple(zip(*table)), flat), planes)
    return _with_offset(planes.view((planes.shape[0],) + x.shape[:-1]).unbind(0), offset)


def combinations(cols: Sequence[Tensor], table, name: str, offset=None, share: float = 1.0) -> Tuple[Tensor, ...]:
    """The columns of ``stack(cols, -1) @ table + offset``, each a tensor of the batch shape: on the
    eager CPU path one matmul of the stacked columns (contiguous results), else one pass per term.

    Args:
        cols: ``k`` tensors of one batch shape (they broadcast), or a filled :func:`plane_buffer`.
        table: nested sequence of numbers, ``k`` rows of ``m``.
        name: the table's key in the constants' cache.
        offset: optional ``m`` numbers added to the results.
        share: as for :func:`columns`.

    Returns:
        ``m`` tensors.

    Shape:
        ``k`` times ``(...)`` -> ``m`` times ``(...)``.

    Example:
        >>> combinations([torch.tensor([1., 2.]), torch.tensor([3., 4.])], ((1., 1.), (0., -1.)), "demo2")
        (tensor([1., 2.]), tensor([-2., -2.]))
    """
    if isinstance(cols, Tensor):  # a plane_buffer, filled
        planes = cols
    elif torch.compiler.is_compiling() or not planar(max(cols, key=Tensor.numel), 1, share):
        return _combined(cols, table, name, offset)
    else:
        planes = torch.stack(torch.broadcast_tensors(*cols), 0)
    out = torch.mm(constant(name + "^T", tuple(zip(*table)), planes), planes.view(len(cols), -1))
    return _with_offset(out.view((out.shape[0],) + planes.shape[1:]).unbind(0), offset)


def plane_buffer(k: int, cols: Sequence[Tensor], share: float = 1.0, output: bool = True) -> Optional[Tensor]:
    """An empty ``(k, *batch)`` tensor for a kernel's last ``k`` columns to be written into (``out=``),
    so that :func:`rows` transposes them without stacking them first (a pass over all of them:
    1.6 ms for 4 columns of 1e6, 4.6 ms for 9). Only on the path of contiguous columns and where
    nothing records a graph (autograd refuses ``out=``, as ``torch.func`` transforms and forward-mode
    AD do): a closed-form rule's forward and backward, and values; ``None`` elsewhere. ``cols``: the columns the planes are computed from (their
    broadcast batch shape, dtype and device).

    ``output``: the buffer goes to :func:`rows` with no table. Where rows are not written by a
    matrix product (:func:`by_matmul`) it is then a view of the output rows themselves, its planes
    strided columns (a lent block of the output if one fits), and :func:`rows` returns those rows:
    the last passes' strided writes cost less than any transpose after them. ``False`` (planes for
    :func:`combinations`, or for :func:`rows` with a table): always contiguous planes."""
    if torch.compiler.is_compiling() or _transformed():  # (out= has no batching or forward-AD rule)
        return None
    like = max(cols, key=Tensor.numel)
    if (not planar(like, 1, share) or like.dim() == 0
            or (torch.is_grad_enabled() and any(c.requires_grad for c in cols))):
        return None
    shape = like.shape
    if any(c.shape != shape for c in cols):  # (broadcast_shapes costs 10 us: only when they differ)
        shape = torch.broadcast_shapes(*(c.shape for c in cols))
    if output and not by_matmul("rows", k):
        out = _borrow((shape.numel(), k), like.dtype)
        out = torch.empty(shape + (k,), dtype=like.dtype, device=like.device) if out is None else out.view(shape + (k,))
        return out.movedim(-1, 0)
    return torch.empty((k,) + shape, dtype=like.dtype, device=like.device)


def _of_rows(buffer: Tensor) -> bool:
    """Whether a filled :func:`plane_buffer` is a view of output rows (its planes strided columns)."""
    return buffer.dim() > 1 and buffer.shape[0] > 1 and buffer.stride(0) == 1


def slot(buffer: Optional[Tensor], i: int) -> Optional[Tensor]:
    """Row ``i`` of a :func:`plane_buffer` (an ``out=`` argument), or ``None`` without one."""
    return None if buffer is None else buffer[i]


def _written_out(cols: Sequence[Tensor], table, name: str) -> Tensor:
    """``stack(cols, -1) @ table`` with no matrix product into rows: each output column summed term
    by term, its last pass writing a strided column of the rows (into a lent block if one fits);
    where autograd or a transform records, the sums and one stack."""
    shape, m = cols[0].shape, len(table[0])
    if _transformed() or (torch.is_grad_enabled() and any(c.requires_grad for c in cols)):
        return torch.stack(_combined(cols, table, name, None), -1)
    out = _borrow((shape.numel(), m), cols[0].dtype)
    out = torch.empty(shape + (m,), dtype=cols[0].dtype, device=cols[0].device) if out is None else out.view(shape + (m,))
    _combined(cols, table, name, None, out=out)
    return out


def rows(cols: Sequence[Tensor], table=None, name: str = "", share: float = 1.0) -> Tensor:
    """``torch.stack(cols, -1)``, or its product with a constant ``table`` (``k x m``, named
    ``name`` for the constants' cache): fast on the eager CPU path (see the module's docstring).

    Args:
        cols: ``k`` tensors of one batch shape (they broadcast), or a filled :func:`plane_buffer`.
        table: optional nested sequence of numbers, ``k`` rows of ``m``.
        name: the table's key in the constants' caches (required with ``table``; one name, one table).
        share: as for :func:`columns`.

    Returns:
        The columns side by side, or their linear combinations.

    Shape:
        ``k`` times ``(...)`` -> ``(..., k)``, or ``(..., m)`` with ``table``.

    Example:
        >>> rows([torch.tensor([1., 2.]), torch.tensor([3., 4.])], ((1., 1.), (0., -1.)), "demo_rows")
        tensor([[ 1., -2.],
                [ 2., -2.]])
    """
    if isinstance(cols, Tensor):  # a plane_buffer, filled
        if _of_rows(cols):  # (written in place: the rows themselves)
            if table is None:
                return cols.movedim(0, -1)
            cols = cols.contiguous()
        if table is not None and not by_matmul("rows", len(table[0])):
            return _written_out(cols.unbind(0), table, name)
        planes = cols
    elif torch.compiler.is_compiling() or not planar(max(cols, key=Tensor.numel), 1, share):
        if table is not None:  # written out: inductor fuses the sums into its loop, a matmul it would not
            cols = _combined(cols, table, name, None)
        return torch.stack(torch.broadcast_tensors(*cols), -1)
    elif not by_matmul("rows", len(cols) if table is None else len(table[0])):
        cols = torch.broadcast_tensors(*cols)
        if table is not None:
            return _written_out(cols, table, name)
        out = _borrow((cols[0].numel(), len(cols)), cols[0].dtype)
        return torch.stack(cols, -1, out=None if out is None else out.view(cols[0].shape + (len(cols),)))
    else:
        planes = torch.stack(torch.broadcast_tensors(*cols), 0)
    batch = planes.shape[1:]
    flat = planes.view(len(cols), -1)
    matrix = None if table is None else constant(name, table, flat)
    out = _to_rows(flat, matrix)
    return out.view(batch + (out.shape[-1],))
