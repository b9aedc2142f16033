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

The identity product is exact for finite numbers (``x * 1 + 0 * y``); it turns ``-0.0`` into
``+0.0``, and a row holding an infinity gets NaN in its other columns (``0 * inf``). Both stay
within what the kernels promise: no rotation has an infinite entry.

Only eager CPU batches of at least ``share * PLANAR_ROWS`` rows take this path, the share a
kernel's measured crossover (below, strided columns sit in cache and the two matmuls cost more
than they save). Under ``torch.compile`` inductor
fuses ``unbind`` and ``stack`` into its single loop, and on a GPU a float32 matrix product may
run in TF32 (10-bit mantissa) when the user allows it, so there the plain ops run.
"""

import threading
from typing import Optional, Sequence, Tuple

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


_lent = threading.local()


def lend(out: Optional[Tensor]) -> None:
    """Lend ``out``, a contiguous ``(M, m)`` tensor, to the first of this thread's next :func:`rows`
    on contiguous columns whose result has that shape and dtype: it is written into ``out``
    instead of a fresh tensor (the dispatcher's blocks of rows write their output in place; see
    ``_dispatch``), which ends the loan. ``None`` ends a loan no :func:`rows` took."""
    _lent.out = out


def _to_rows(planes: Tensor, table: Optional[Tensor] = None) -> Tensor:
    """``(k, M) -> (M, k)`` (or ``planes.T @ table``), contiguous, into a lent tensor if it fits."""
    matrix = _eye(planes.shape[0], planes) if table is None else table
    out = getattr(_lent, "out", None)
    if out is not None:
        if out.shape == (planes.shape[1], matrix.shape[1]) and out.dtype == planes.dtype:
            _lent.out = None
        else:
            out = None
    return torch.mm(planes.t(), matrix, out=out)


def _combined(cols, table, name: str, offset):
    """``combine`` of each column of ``table``: one pass per term (fused under compile)."""
    terms = None if torch.compiler.is_compiling() else _SPARSE.get(name)
    if terms is None:
        terms = sparse_columns(table, offset)
        if not torch.compiler.is_compiling():
            _SPARSE[name] = terms
    return tuple(combine(cols, t) for t in terms)


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
    matrix = _eye(k, flat) if table is None else constant(name + "^T", tuple(zip(*table)), flat)
    planes = torch.mm(matrix, flat.t())
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


def plane_buffer(k: int, cols: Sequence[Tensor], share: float = 1.0) -> Optional[Tensor]:
    """An empty ``(k, *batch)`` tensor for a kernel's last ``k`` columns to be written into (``out=``),
    so that :func:`rows` transposes them without stacking them first (a pass over all of them:
    1.6 ms for 4 columns of 1e6, 4.6 ms for 9). Only on the path of contiguous columns and where
    nothing records a graph (autograd refuses ``out=``, as ``torch.func`` transforms and forward-mode
    AD do): a closed-form rule's forward and backward, and values; ``None`` elsewhere. ``cols``: the columns the planes are computed from (their
    broadcast batch shape, dtype and device)."""
    if torch.compiler.is_compiling() or _transformed():  # (out= has no batching or forward-AD rule)
        return None
    like = max(cols, key=Tensor.numel)
    if (not planar(like, 1, share) or like.dim() == 0
            or (torch.is_grad_enabled() and any(c.requires_grad for c in cols))):
        return None
    shape = like.shape
    if any(c.shape != shape for c in cols):  # (broadcast_shapes costs 10 us: only when they differ)
        shape = torch.broadcast_shapes(*(c.shape for c in cols))
    return torch.empty((k,) + shape, dtype=like.dtype, device=like.device)


def slot(buffer: Optional[Tensor], i: int) -> Optional[Tensor]:
    """Row ``i`` of a :func:`plane_buffer` (an ``out=`` argument), or ``None`` without one."""
    return None if buffer is None else buffer[i]


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
        planes = cols
    elif torch.compiler.is_compiling() or not planar(max(cols, key=Tensor.numel), 1, share):
        if table is not None:  # written out: inductor fuses the sums into its loop, a matmul it would not
            cols = _combined(cols, table, name, None)
        return torch.stack(torch.broadcast_tensors(*cols), -1)
    else:
        planes = torch.stack(torch.broadcast_tensors(*cols), 0)
    batch = planes.shape[1:]
    flat = planes.view(len(cols), -1)
    matrix = None if table is None else constant(name, table, flat)
    out = _to_rows(flat, matrix)
    return out.view(batch + (out.shape[-1],))
