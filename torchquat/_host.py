"""The CPU paths: one rotation on Python floats, a batch on NumPy columns.

On the CPU every PyTorch operation costs its dispatch (2-5 us) whatever it computes: a formula of
20-50 steps spends most of its time there up to thousands of rows, and autograd's backward adds a
node a step. The same formula, written out as straight-line code by :mod:`torchquat._codegen`,
runs here on Python floats (0.05 us a step) for one rotation and on NumPy columns (about half of
PyTorch's cost a step, in blocks that stay in cache) for a batch; the forward keeps the values its
generated reverse mode reads, and one autograd node (:class:`Gradient`) hands that reverse
mode to autograd. Anything these paths do not take (a GPU tensor, a
tensor subclass, a ``torch.func`` transform, a trace) returns ``None``, and the caller runs the
tensor formula.
"""

import math
from typing import Callable, Optional, Sequence

import numpy
import torch
from torch import Tensor

from ._codegen import generated

_PLAIN = (Tensor, torch.nn.Parameter)  # (a subclass may change what tolist and numpy read)
_NUMPY_DTYPES = {torch.float32: numpy.dtype(numpy.float32), torch.float64: numpy.dtype(numpy.float64)}
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


class Gradient(torch.autograd.Function):
    """A result whose backward is ``gradients(tape, grad, inputs)``: the generated reverse mode on
    the floats or columns the forward kept, or a compiled vector-Jacobian product (each input's
    gradient, ``None`` where it needs none). Where that returns ``None`` (a gradient that is not
    finite), or the gradient is differentiated again (``create_graph``), the backward runs
    ``fallback`` (the tensor formula) under autograd, so higher derivatives are autograd's.

    ``out`` is the result, or the NumPy array it wraps: a tensor made inside ``forward`` costs
    autograd 1-2 us less per call than an argument returned as the output."""

    @staticmethod
    def forward(ctx, out, gradients: Callable, tape, fallback: Callable, *inputs):
        ctx.gradients, ctx.tape, ctx.fallback = gradients, tape, fallback
        ctx.save_for_backward(*inputs)
        return torch.from_numpy(out) if isinstance(out, numpy.ndarray) else out

    @staticmethod
    def backward(ctx, grad):
        inputs = ctx.saved_tensors
        grads = None if torch.is_grad_enabled() else ctx.gradients(ctx.tape, grad, inputs)
        if grads is None:
            inputs = [x.view_as(x) for x in inputs]  # (each slot its own node: the same tensor may fill two)
            wanted = [x for x in inputs if x.requires_grad]
            with torch.enable_grad():
                out = ctx.fallback(inputs)
            found = iter(torch.autograd.grad(out, wanted, grad, create_graph=torch.is_grad_enabled(),
                                             allow_unused=True))
            return (None,) * 4 + tuple(next(found) if x.requires_grad else None for x in inputs)
        return (None,) * 4 + tuple(grads)


def _row_gradients(tape, grad: Tensor, inputs):
    code, parameters, values, saved = tape
    grad = grad.tolist()  # (a float, or nested lists of one output row)
    if type(grad) is float:
        grad = [grad]
    while type(grad[0]) is list:
        grad = [g for row in grad for g in row]
    try:
        flat = code.backward(*values, *parameters, *saved, *grad)
    except _FLOAT_FAILURES:
        return None
    if not math.isfinite(sum(flat)):  # (an overflowing sum only falls back)
        return None
    flat, grads, start = numpy.array(flat, dtype=_NUMPY_DTYPES[inputs[0].dtype]), [], 0
    for x in inputs:  # (each one row: its numel values)
        width = x.numel()
        grads.append(torch.from_numpy(flat[start:start + width].reshape(tuple(x.shape))) if x.requires_grad else None)
        start += width
    return grads


def _column_gradients(tape, grad: Tensor, inputs):
    code, parameters, blocks, widths, (rows, out_width) = tape
    g = grad.numpy(force=True).reshape(rows, out_width)
    grads = [numpy.empty((rows, width), dtype=g.dtype) for width in widths]
    with numpy.errstate(all="ignore"):
        for start, stop, block, saved in blocks:
            gradients = g[start:stop].T.copy() if out_width > 1 else (g[start:stop, 0],)
            columns = iter(code.backward(*block, *parameters, *saved, *gradients))
            for array in grads:
                for j in range(array.shape[1]):
                    array[start:stop, j] = next(columns)
        result = []
        for a, x, width in zip(grads, inputs, widths):
            if not x.requires_grad:
                result.append(None)
                continue
            if x.numel() == width < a.size:  # (one row broadcast over the batch: its gradient sums)
                a = a.sum(0)
            if not math.isfinite(a.sum()):  # (an overflowing sum only falls back)
                return None
            result.append(torch.from_numpy(a.reshape(x.shape)))
    return result


def one_row(formula, inputs: Sequence[Tensor], out_shape, row_dims: int, static, fallback) -> Optional[Tensor]:
    """The formula on one row of Python floats, or ``None`` where that path does not apply."""
    values, grad, dims = [], False, row_dims
    for x in inputs:
        if type(x) not in _PLAIN or not x.is_cpu:
            return None
        shape = x.shape
        if x.numel() != (shape[-1] if row_dims == 1 else 9) or not has_storage(x):
            return None
        grad = grad or x.requires_grad
        row = x.tolist()
        if len(shape) > row_dims:  # (leading 1s: unwrapping the nested list costs less than a reshape)
            dims = max(dims, len(shape))
            for _ in range(len(shape) - row_dims):
                row = row[0]
        if row_dims == 1:
            values += row
        else:
            for matrix_row in row:
                values += matrix_row
    numpy_dtype = _NUMPY_DTYPES.get(inputs[0].dtype)
    if numpy_dtype is None:
        return None
    code, parameters = generated(formula, len(values), static)
    keep = grad and torch.is_grad_enabled()
    try:
        if keep:
            out, saved = code.forward(*values, *parameters)
        else:
            out = code.evaluate(*values, *parameters)
    except _FLOAT_FAILURES:
        return None
    # Every input is one row, so the batch shape is all 1s, as many as the longest input has. NumPy
    # builds and shapes a small array faster than torch.tensor (each entry rounded once).
    result = numpy.array(out, dtype=numpy_dtype).reshape((1,) * (dims - row_dims) + out_shape)
    if keep:
        return Gradient.apply(result, _row_gradients, (code, parameters, values, saved), fallback, *inputs)
    return torch.from_numpy(result)


def _block(arrays, start: int):
    """Each input's columns in the block of rows from ``start``: contiguous (NumPy takes up to 3x as
    long a step on strided ones) and in cache; a one-row input's own columns (broadcast)."""
    return [c for a in arrays for c in (a if len(a) == 1 else a[start:start + BLOCK_ROWS]).T.copy()]


def columns(formula, inputs: Sequence[Tensor], out_shape, row_dims: int, static, fallback) -> Optional[Tensor]:
    """The formula on NumPy columns of a CPU batch, block by block, or ``None`` where this path does
    not apply. Each input has the batch shape, or is one row (broadcast)."""
    batch, widths, keep = None, [], False
    for x in inputs:  # (each attribute read of a tensor costs 0.05-0.3 us: few, cheapest first)
        if type(x) not in _PLAIN or not x.is_cpu or not has_storage(x):
            return None
        width = x.shape[-1] if row_dims == 1 else 9
        widths.append(width)
        if x.numel() != width:
            if batch is None:
                batch = x.shape[:-row_dims]
            elif x.shape[:-row_dims] != batch:
                return None
        keep = keep or x.requires_grad
    dtype = _NUMPY_DTYPES.get(inputs[0].dtype)
    if batch is None or dtype is None:
        return None
    keep = keep and torch.is_grad_enabled()
    rows = math.prod(batch)
    arrays = [x.numpy(force=True).reshape(-1, width) for x, width in zip(inputs, widths)]
    code, parameters = generated(formula, sum(widths), static, dtype)
    out = numpy.empty((rows, math.prod(out_shape)), dtype)
    blocks = []  # (what the backward reads: each block's columns and saved values)
    with numpy.errstate(all="ignore"):
        for start in range(0, rows, BLOCK_ROWS):
            stop = start + BLOCK_ROWS
            block = _block(arrays, start)
            if keep:
                outputs, saved = code.forward(*block, *parameters)
                blocks.append((start, stop, block, saved))
            else:
                outputs = code.evaluate(*block, *parameters)
            for k, column in enumerate(outputs):
                out[start:stop, k] = column
    result = out.reshape(batch + out_shape)
    if keep:
        return Gradient.apply(result, _column_gradients, (code, parameters, blocks, widths, out.shape), fallback, *inputs)
    return torch.from_numpy(result)
