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

import torch
from torch import Tensor

from ._backends import FLOATS, TENSORS
from ._dual import jacobian

__all__ = ["use_compiled_kernels", "compiled_kernels_enabled", "run"]

_enabled = os.environ.get("TORCHQUAT_COMPILE", "0").lower() in ("1", "true", "yes", "on")
_compiled: Dict[Tuple, Callable] = {}
_PLAIN = (Tensor, torch.nn.Parameter)  # (tensor subclasses may override what tolist reads)
_FLOAT_FAILURES = (ZeroDivisionError, ValueError, OverflowError)


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
    """A one-row result whose vector-Jacobian product is the Jacobian of :mod:`torchquat._dual`, in
    Python floats. Differentiated again (``create_graph``), the backward runs the eager formula
    under autograd instead, so higher derivatives are autograd's."""

    @staticmethod
    def forward(ctx, out: Tensor, rows, formula, out_shape, static, *inputs):
        ctx.rows, ctx.formula, ctx.out_shape, ctx.static = rows, formula, out_shape, static
        ctx.save_for_backward(*inputs)
        return out

    @staticmethod
    def backward(ctx, grad):
        inputs = ctx.saved_tensors
        if torch.is_grad_enabled():
            inputs = [x.view_as(x) for x in inputs]  # (each slot its own node: the same tensor may fill two)
            wanted = [x for x in inputs if x.requires_grad]
            out = eager(ctx.formula, inputs, ctx.out_shape, ctx.static)
            found = iter(torch.autograd.grad(out, wanted, grad, create_graph=True, allow_unused=True))
            grads = [next(found) if x.requires_grad else None for x in inputs]
            return (None,) * 5 + tuple(grads)
        g = grad.reshape(-1).tolist()
        vjp = [sum(gi * row[j] for gi, row in zip(g, ctx.rows)) for j in range(len(ctx.rows[0]))]
        grads, start = [], 0
        for x in inputs:
            n = x.shape[-1]
            grads.append(torch.tensor(vjp[start:start + n], dtype=x.dtype).view(x.shape) if x.requires_grad else None)
            start += n
        return (None,) * 5 + tuple(grads)


def _one_row(formula, inputs: Sequence[Tensor], out_shape, static):
    """The formula on one row of Python floats, or ``None`` where that path does not apply."""
    values, grad = [], False
    for x in inputs:
        if type(x) not in _PLAIN or not x.is_cpu or x.numel() != x.shape[-1] or not _has_storage(x):
            return None
        grad = grad or x.requires_grad
        values += x.reshape(-1).tolist()
    grad = grad and torch.is_grad_enabled()
    try:
        if grad:
            out, rows = jacobian(formula, values, static)
        else:
            out = formula(FLOATS, *values, **static)
    except _FLOAT_FAILURES:
        return None
    if grad and not all(math.isfinite(d) for row in rows for d in row):
        return None  # (a singular point of the floats' derivatives: the tensor formula's safe substitutes)
    batch = inputs[0].shape[:-1] if len(inputs) == 1 else torch.broadcast_shapes(*(x.shape[:-1] for x in inputs))
    result = torch.tensor(out, dtype=inputs[0].dtype).view(batch + out_shape)
    if grad:
        return _OneRowGradient.apply(result, rows, formula, out_shape, static, *inputs)
    return result


def eager(formula, inputs: Sequence[Tensor], out_shape, static) -> Tensor:
    """The formula on the batch's columns; also what :func:`use_compiled_kernels` compiles."""
    columns = [c for x in inputs for c in x.unbind(-1)]
    out = formula(TENSORS, *columns, **static)
    reference = next(o for o in out if isinstance(o, Tensor))
    out = [o if isinstance(o, Tensor) else torch.full_like(reference, o) for o in out]
    if len(inputs) > 1 and any(o.shape != reference.shape for o in out):  # (an output reads some inputs)
        out = torch.broadcast_tensors(*out)
    if not out_shape:
        return out[0]
    return torch.stack(out, -1).unflatten(-1, out_shape) if len(out_shape) > 1 else torch.stack(out, -1)


def _kernel(formula, out_shape, static) -> Callable:
    key = (formula, out_shape, tuple(sorted(static.items())))
    compiled = _compiled.get(key)
    if compiled is None:
        def kernel(*inputs):
            return eager(formula, inputs, out_shape, static)
        # a code object of its own: dynamo keeps compiled graphs, and its recompile limit, per code object
        code = kernel.__code__.replace(co_name=f"{formula.__name__}_{len(_compiled)}")
        kernel = types.FunctionType(code, kernel.__globals__, code.co_name, None, kernel.__closure__)
        compiled = _compiled[key] = torch.compile(kernel, dynamic=True, fullgraph=True)
    return compiled


def run(formula, inputs: Sequence[Tensor], out_shape: Tuple[int, ...], **static) -> Tensor:
    """Run ``formula`` on validated ``inputs`` (each ``(..., C)``, one dtype and device) on the path
    that fits; ``out_shape`` is the output's trailing shape, ``static`` the formula's options."""
    tracing = torch.compiler.is_compiling() or torch.jit.is_tracing()
    if not tracing and inputs[0].numel() == inputs[0].shape[-1]:
        out = _one_row(formula, inputs, out_shape, static)
        if out is not None:
            return out
    if _enabled and not tracing and all(_has_storage(x) for x in inputs):
        return _kernel(formula, out_shape, static)(*inputs)
    return eager(formula, inputs, out_shape, static)
