"""The CPU paths: one rotation on Python floats, a batch on NumPy columns.

On the CPU every PyTorch operation costs its dispatch (2-5 us) whatever it computes: a formula of
20-50 steps spends most of its time there up to thousands of rows, and autograd's backward adds a
node a step. The same formula runs here on Python floats (0.05 us a step) for one rotation and on
NumPy columns (about half of PyTorch's cost a step, in blocks that stay in cache) for a batch; its
gradient is the generated reverse mode of :mod:`torchquat._reverse`, and one autograd node
(:class:`_HostGradient`) hands it to autograd. Anything these paths do not take (a GPU tensor, a
tensor subclass, a ``torch.func`` transform, a trace) returns ``None``, and the caller runs the
tensor formula.
"""

import math
from typing import Callable, Optional, Sequence

import numpy
import torch
from torch import Tensor

from ._backends import ARRAYS, FLOATS
from ._reverse import vjp_function

_PLAIN = (Tensor, torch.nn.Parameter)  # (a subclass may change what tolist and numpy read)
_NUMPY_DTYPES = {torch.float32: numpy.float32, torch.float64: numpy.float64}
_FLOAT_FAILURES = (ZeroDivisionError, ValueError, OverflowError)
# Rows per block of a NumPy batch: 64 KB a float32 column, so that the few columns a formula step
# reads and writes stay in a core's cache (any CPU's L2 holds several).
BLOCK_ROWS = 16_384


def has_storage(x: Tensor) -> bool:
    """False for the wrappers of ``torch.func`` transforms (vmap, grad, jvp), which have none."""
    try:
        x.data_ptr()
    except RuntimeError:
        return False
    return True


class _HostGradient(torch.autograd.Function):
    """A result of these paths, whose backward is the formula's generated vector-Jacobian product
    on the same floats or columns. Where that is not finite, or the gradient is differentiated
    again (``create_graph``), the backward runs ``fallback`` (the tensor formula) under autograd,
    so higher derivatives are autograd's."""

    @staticmethod
    def forward(ctx, out: Tensor, values, widths, formula, static, fallback: Callable, *inputs):
        ctx.values, ctx.widths, ctx.formula, ctx.static, ctx.fallback = values, widths, formula, static, fallback
        ctx.save_for_backward(*inputs)
        return out

    @staticmethod
    def backward(ctx, grad):
        inputs = ctx.saved_tensors
        grads = None
        if not torch.is_grad_enabled():
            arrays = isinstance(ctx.values[0], numpy.ndarray)  # (NumPy rows, or floats for one row)
            grads = (_column_gradients if arrays else _row_gradients)(ctx, grad, [x.requires_grad for x in inputs])
            if grads is not None:
                grads = [g.view(x.shape) if g is not None else None for g, x in zip(grads, inputs)]
        if grads is None:
            inputs = [x.view_as(x) for x in inputs]  # (each slot its own node: the same tensor may fill two)
            wanted = [x for x in inputs if x.requires_grad]
            with torch.enable_grad():
                out = ctx.fallback(inputs)
            found = iter(torch.autograd.grad(out, wanted, grad, create_graph=torch.is_grad_enabled(),
                                             allow_unused=True))
            grads = [next(found) if x.requires_grad else None for x in inputs]
        return (None,) * 6 + tuple(grads)


def _split(flat, widths):
    start = 0
    for width in widths:
        yield flat[start:start + width]
        start += width


def _row_gradients(ctx, grad: Tensor, wanted):
    try:
        flat = vjp_function(ctx.formula, len(ctx.values), ctx.static)(*ctx.values, *grad.reshape(-1).tolist())
    except _FLOAT_FAILURES:
        return None
    if not all(map(math.isfinite, flat)):
        return None
    dtype = _NUMPY_DTYPES[grad.dtype]
    return [torch.from_numpy(numpy.array(part, dtype=dtype)) if want else None
            for part, want in zip(_split(flat, ctx.widths), wanted)]


def _column_gradients(ctx, grad: Tensor, wanted):
    n_values = sum(ctx.widths)
    vjp = vjp_function(ctx.formula, n_values, ctx.static, arrays=True)
    rows = max(a.shape[0] for a in ctx.values)
    g = grad.detach().reshape(rows, -1).numpy()
    out = numpy.empty((rows, n_values), dtype=g.dtype)
    with numpy.errstate(all="ignore"):
        for start, stop, block in _blocks(ctx.values, rows):
            for k, column in enumerate(vjp(*block, *g[start:stop].T.copy())):
                out[start:stop, k] = column
    if not numpy.isfinite(out).all():
        return None
    grads, first = [], 0
    for a, width, want in zip(ctx.values, ctx.widths, wanted):
        block = out[:, first:first + width]
        first += width
        if not want:
            grads.append(None)
            continue
        if a.shape[0] == 1 and rows > 1:  # (one row broadcast over the batch: its gradient sums)
            block = block.sum(0, keepdims=True, dtype=g.dtype)
        grads.append(torch.from_numpy(numpy.ascontiguousarray(block)))
    return grads


def _usable(inputs: Sequence[Tensor]) -> bool:
    for x in inputs:  # (each attribute read of a tensor costs 0.05-0.3 us: few, cheapest first)
        if type(x) not in _PLAIN or not x.is_cpu or not has_storage(x):
            return False
    return inputs[0].dtype in _NUMPY_DTYPES


def one_row(formula, inputs: Sequence[Tensor], out_shape, row_dims: int, static, fallback) -> Optional[Tensor]:
    """The formula on one row of Python floats, or ``None`` where that path does not apply."""
    values, widths, grad = [], [], False
    for x in inputs:
        if type(x) not in _PLAIN or not x.is_cpu:
            return None
        shape = x.shape
        widths.append(shape[-1] if row_dims == 1 else 9)
        if x.numel() != widths[-1] or not has_storage(x):
            return None
        grad = grad or x.requires_grad
        if len(shape) != row_dims:
            values += x.reshape(-1).tolist()
        elif row_dims == 1:
            values += x.tolist()
        else:
            for row in x.tolist():
                values += row
    numpy_dtype = _NUMPY_DTYPES.get(inputs[0].dtype)
    if numpy_dtype is None:
        return None
    try:
        out = formula(FLOATS, *values, **static)
    except _FLOAT_FAILURES:
        return None
    batch = inputs[0].shape[:-row_dims]
    for x in inputs[1:]:
        if x.shape[:-row_dims] != batch:
            batch = torch.broadcast_shapes(batch, x.shape[:-row_dims])
    # (NumPy builds and shapes a small array faster than torch.tensor; each entry rounded once)
    result = torch.from_numpy(numpy.array(out, dtype=numpy_dtype).reshape(batch + out_shape))
    if grad and torch.is_grad_enabled():
        return _HostGradient.apply(result, values, widths, formula, static, fallback, *inputs)
    return result


def _blocks(arrays, rows: int):
    """``(start, stop, columns)`` for each block of rows: each input's columns in that block,
    contiguous (NumPy takes up to 3x as long a step on strided ones) and in cache; a one-row
    input's own columns in every block (broadcast)."""
    for start in range(0, rows, BLOCK_ROWS):
        stop = min(start + BLOCK_ROWS, rows)
        yield start, stop, [c for a in arrays for c in (a if a.shape[0] == 1 else a[start:stop]).T.copy()]


def columns(formula, inputs: Sequence[Tensor], out_shape, row_dims: int, static, fallback) -> Optional[Tensor]:
    """The formula on NumPy columns of a CPU batch, block by block, or ``None`` where this path does
    not apply. Each input has the batch shape, or is one row (broadcast)."""
    if not _usable(inputs):
        return None
    batch, widths = None, [x.shape[-1] if row_dims == 1 else 9 for x in inputs]
    for x, width in zip(inputs, widths):
        if x.numel() != width:
            if batch is not None and x.shape[:-row_dims] != batch:
                return None
            batch = x.shape[:-row_dims]
    if batch is None:
        return None
    rows = math.prod(batch)
    arrays = [x.detach().reshape(-1, width).numpy() for x, width in zip(inputs, widths)]
    out = numpy.empty((rows, math.prod(out_shape)), dtype=_NUMPY_DTYPES[inputs[0].dtype])
    with numpy.errstate(all="ignore"):
        for start, stop, block in _blocks(arrays, rows):
            for k, column in enumerate(formula(ARRAYS, *block, **static)):
                out[start:stop, k] = column
    result = torch.from_numpy(out).view(batch + out_shape)
    if torch.is_grad_enabled() and any(x.requires_grad for x in inputs):
        return _HostGradient.apply(result, arrays, widths, formula, static, fallback, *inputs)
    return result

