"""The one dispatcher: runs a formula of :mod:`torchquat._formulas` on validated tensors.

Three paths, one source:

* **one row** (a CPU call on a single rotation, nothing to differentiate or trace): the formula on
  Python floats. At one row every PyTorch operation costs its dispatch (2-5 us) whatever it
  computes, while a float operation costs about 0.05 us; the result is computed in double
  precision and rounded once to the input's dtype. Anything the floats refuse (a division by zero,
  say) takes the tensor path, which gives NaN.
* **eager**: the formula on the columns of the batch (``unbind(-1)``), one PyTorch operation per
  arithmetic step; autograd records them, so the backward is autograd's.
* **compiled** (:func:`use_compiled_kernels`): ``torch.compile`` of that same eager function, once
  per formula and set of options; inductor fuses it into one loop.
"""

import math
import os
import types
from typing import Callable, Dict, Sequence, Tuple

import numpy
import torch
from torch import Tensor

from ._backends import FLOATS, TENSORS
from ._reverse import vjp_function

__all__ = ["use_compiled_kernels", "compiled_kernels_enabled", "run"]

_enabled = os.environ.get("TORCHQUAT_COMPILE", "0").lower() in ("1", "true", "yes", "on")
_compiled: Dict[Tuple, Callable] = {}
_PLAIN = (Tensor, torch.nn.Parameter)  # (tensor subclasses may override what tolist reads)
_FLOAT_FAILURES = (ZeroDivisionError, ValueError, OverflowError)
# Rows per block of a large eager CPU batch: 64 KB a float32 column, so that the few columns a
# formula step reads and writes stay in a core's cache (any CPU's L2 holds several).
BLOCK_ROWS = 16_384
_is_compiling, _is_tracing = torch.compiler.is_compiling, torch.jit.is_tracing
_NUMPY_DTYPES = {torch.float32: numpy.float32, torch.float64: numpy.float64}


def use_compiled_kernels(enabled: bool = True) -> None:
    """Route every conversion through ``torch.compile``'d kernels (or back to eager).

    Also set by the environment variable ``TORCHQUAT_COMPILE=1``. Results are the same to
    rounding. The first call of each kernel compiles it (seconds; inductor keeps the result in its
    on-disk cache, so later processes start faster); single rotations stay on Python floats.

    Args:
        enabled: True to use compiled kernels, False for plain eager PyTorch (the default).

    Example:
        >>> use_compiled_kernels(False)
        >>> compiled_kernels_enabled()
        False
    """
    global _enabled
    _enabled = bool(enabled)


def compiled_kernels_enabled() -> bool:
    """Whether :func:`use_compiled_kernels` is on.

    Returns:
        The switch's state.

    Example:
        >>> compiled_kernels_enabled()
        False
    """
    return _enabled


def _has_storage(x: Tensor) -> bool:
    """False for the wrappers of ``torch.func`` transforms (vmap, grad, jvp), which have none."""
    try:
        x.data_ptr()
    except RuntimeError:
        return False
    return True


class _OneRowGradient(torch.autograd.Function):
    """A one-row result whose backward is the formula's generated vector-Jacobian product
    (:mod:`torchquat._reverse`), in Python floats. Where that is not finite, or the gradient is
    differentiated again (``create_graph``), the backward runs the eager formula under autograd, so
    higher derivatives are autograd's."""

    @staticmethod
    def forward(ctx, out: Tensor, values, formula, out_shape, row_dims, static, *inputs):
        ctx.values, ctx.formula, ctx.out_shape, ctx.row_dims, ctx.static = values, formula, out_shape, row_dims, static
        ctx.save_for_backward(*inputs)
        return out

    @staticmethod
    def backward(ctx, grad):
        inputs = ctx.saved_tensors
        grads = None
        if not torch.is_grad_enabled():
            try:
                flat = vjp_function(ctx.formula, len(ctx.values), ctx.static)(*ctx.values, *grad.reshape(-1).tolist())
                if all(map(math.isfinite, flat)):
                    grads, start = [], 0
                    for x in inputs:
                        n = x.numel()
                        grads.append(torch.tensor(flat[start:start + n], dtype=x.dtype).view(x.shape)
                                     if x.requires_grad else None)
                        start += n
            except _FLOAT_FAILURES:
                pass
        if grads is None:
            inputs = [x.view_as(x) for x in inputs]  # (each slot its own node: the same tensor may fill two)
            wanted = [x for x in inputs if x.requires_grad]
            with torch.enable_grad():
                out = eager(ctx.formula, inputs, ctx.out_shape, ctx.row_dims, ctx.static)
            found = iter(torch.autograd.grad(out, wanted, grad, create_graph=torch.is_grad_enabled(),
                                             allow_unused=True))
            grads = [next(found) if x.requires_grad else None for x in inputs]
        return (None,) * 6 + tuple(grads)


def _one_row(formula, inputs: Sequence[Tensor], out_shape, row_dims: int, static):
    """The formula on one row of Python floats, or ``None`` where that path does not apply."""
    values, grad = [], False
    for x in inputs:  # (each attribute read of a tensor costs 0.05-0.3 us: few, cheapest first)
        if type(x) not in _PLAIN or not x.is_cpu:
            return None
        shape = x.shape
        if x.numel() != (shape[-1] if row_dims == 1 else 9) or not _has_storage(x):
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
        return _OneRowGradient.apply(result, values, formula, out_shape, row_dims, static, *inputs)
    return result


def blocked(formula, inputs: Sequence[Tensor], out_shape, row_dims: int, static) -> Tensor:
    """:func:`eager` block by block, for large CPU batches of one batch shape: each block's columns
    are made contiguous and stay in cache across the formula's 20-50 passes, where a whole batch's
    columns go through memory on every pass."""
    batch = inputs[0].shape[:-row_dims]
    rows = [x.reshape(-1, 9 if row_dims == 2 else x.shape[-1]) for x in inputs]
    n, width = rows[0].shape[0], math.prod(out_shape)
    record = torch.is_grad_enabled() and any(x.requires_grad for x in inputs)
    out = None if record else inputs[0].new_empty((n, width))
    pieces = []
    for start in range(0, n, BLOCK_ROWS):
        columns = [c for x in rows for c in x[start:start + BLOCK_ROWS].t().contiguous().unbind(0)]
        values = formula(TENSORS, *columns, **static)
        if record:
            pieces.append(torch.stack(values, -1))
        else:
            torch.stack(values, -1, out=out[start:start + BLOCK_ROWS])
    out = torch.cat(pieces) if record else out
    return out.view(batch + out_shape) if out_shape else out.view(batch)


def eager(formula, inputs: Sequence[Tensor], out_shape, row_dims: int, static) -> Tensor:
    """The formula on the batch's columns; also what :func:`use_compiled_kernels` compiles."""
    columns = [c for x in inputs for c in (x.flatten(-2) if row_dims == 2 else x).unbind(-1)]
    out = formula(TENSORS, *columns, **static)
    reference = next(o for o in out if isinstance(o, Tensor))
    out = [o if isinstance(o, Tensor) else torch.full_like(reference, o) for o in out]
    if len(inputs) > 1 and any(o.shape != reference.shape for o in out):  # (an output reads some inputs)
        out = torch.broadcast_tensors(*out)
    if not out_shape:
        return out[0]
    return torch.stack(out, -1).unflatten(-1, out_shape) if len(out_shape) > 1 else torch.stack(out, -1)


def _kernel(formula, out_shape, row_dims: int, static) -> Callable:
    key = (formula, out_shape, row_dims, tuple(sorted(static.items())))
    compiled = _compiled.get(key)
    if compiled is None:
        def kernel(*inputs):
            return eager(formula, inputs, out_shape, row_dims, static)
        # a code object of its own: dynamo keeps compiled graphs, and its recompile limit, per code object
        code = kernel.__code__.replace(co_name=f"{formula.__name__}_{len(_compiled)}")
        kernel = types.FunctionType(code, kernel.__globals__, code.co_name, None, kernel.__closure__)
        compiled = _compiled[key] = torch.compile(kernel, dynamic=True, fullgraph=True)
    return compiled


def run(formula, inputs: Sequence[Tensor], out_shape: Tuple[int, ...], row_dims: int = 1, **static) -> Tensor:
    """Run ``formula`` on validated ``inputs`` (one dtype and device; each row ``row_dims`` trailing
    dimensions: 1 for vectors, 2 for matrices) on the path that fits; ``out_shape`` is the output's
    trailing shape, ``static`` the formula's options."""
    tracing = _is_compiling() or _is_tracing()
    if not tracing:
        out = _one_row(formula, inputs, out_shape, row_dims, static)
        if out is not None:
            return out
    if not tracing and all(_has_storage(x) for x in inputs):
        if _enabled:
            return _kernel(formula, out_shape, row_dims, static)(*inputs)
        batch = inputs[0].shape[:-row_dims]
        if inputs[0].is_cpu and math.prod(batch) >= 2 * BLOCK_ROWS and all(x.shape[:-row_dims] == batch for x in inputs):
            return blocked(formula, inputs, out_shape, row_dims, static)
    return eager(formula, inputs, out_shape, row_dims, static)
