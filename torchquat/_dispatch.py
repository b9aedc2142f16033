"""The one dispatcher: runs a formula of :mod:`torchquat._formulas` on validated tensors.

One source, four paths:

* **one row** and **CPU batches** (:mod:`torchquat._host`): the formula on Python floats or on
  NumPy columns, where PyTorch's per-operation dispatch would cost more than the arithmetic; their
  gradient is the formula's generated reverse mode.
* **eager tensors** (GPU tensors, ``torch.func`` transforms, traces, tensor subclasses): the
  formula on the batch's columns (``unbind(-1)``), one PyTorch operation a step, autograd's
  backward. Inside a user's ``torch.compile`` or ``torch.export`` this is what gets traced.
* **compiled** (:func:`use_compiled_kernels`): ``torch.compile`` of that same eager function, once
  per formula and set of options; inductor fuses it into one loop. Its gradient is a second
  compiled loop, the vector-Jacobian product of the same function (``torch.func.vjp``), which
  recomputes the forward from the inputs instead of saving its intermediates.
"""

import os
import types
from typing import Callable, Dict, Sequence, Tuple

import torch
from torch import Tensor

from ._backends import TENSORS
from ._host import Gradient, columns, has_storage, one_row

__all__ = ["use_compiled_kernels", "compiled_kernels_enabled", "run"]

_enabled = os.environ.get("TORCHQUAT_COMPILE", "0").lower() in ("1", "true", "yes", "on")
_compiled: Dict[Tuple, Callable] = {}
_is_compiling, _is_tracing = torch.compiler.is_compiling, torch.jit.is_tracing
# Inductor's CPU tiling heuristic turns a loop whose loads are strided (the columns of (N, C) rows)
# into scalar code: 4-8x slower for the kernels with sin, cos or atan2 at 1e6 rows (Euler <-> quat:
# 41 -> 8.6 ms, quat -> Euler 83 -> 13 ms), the others within 1.4x.
_INDUCTOR_OPTIONS = {"cpp.enable_tiling_heuristics": False}


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


def _compile(function, name: str) -> Callable:
    # a code object of its own: dynamo keeps compiled graphs, and its recompile limit, per code object
    code = function.__code__.replace(co_name=f"{name}_{len(_compiled)}")
    function = types.FunctionType(code, function.__globals__, code.co_name, None, function.__closure__)
    try:
        return torch.compile(function, dynamic=True, fullgraph=True, options=_INDUCTOR_OPTIONS)
    except RuntimeError:  # (a torch whose inductor has no such option: its defaults)
        return torch.compile(function, dynamic=True, fullgraph=True)


def _kernels(formula, out_shape, row_dims: int, static) -> Tuple[Callable, Callable]:
    """The compiled forward of a formula and its compiled vector-Jacobian product."""
    key = (formula, out_shape, row_dims, tuple(sorted(static.items())))
    kernels = _compiled.get(key)
    if kernels is None:
        def forward(*inputs):
            return eager(formula, inputs, out_shape, row_dims, static)

        def vjp(*inputs_and_gradient):
            # At a million rows the forward's saved intermediates (5-10 columns) cost more to write
            # and read back than the forward costs to recompute inside the backward's loop.
            _, pullback = torch.func.vjp(forward, *inputs_and_gradient[:-1])
            return pullback(inputs_and_gradient[-1])

        kernels = _compiled[key] = (_compile(forward, formula.__name__), _compile(vjp, formula.__name__ + "_vjp"))
    return kernels


def _compiled_gradients(vjp, grad, inputs):
    return [g if x.requires_grad else None for g, x in zip(vjp(*inputs, grad), inputs)]


def run(formula, inputs: Sequence[Tensor], out_shape: Tuple[int, ...], row_dims: int = 1, **static) -> Tensor:
    """Run ``formula`` on validated ``inputs`` (one dtype and device; each row ``row_dims`` trailing
    dimensions: 1 for vectors, 2 for matrices) on the path that fits; ``out_shape`` is the output's
    trailing shape, ``static`` the formula's options."""
    if not (_is_compiling() or _is_tracing()):
        def fallback(tensors):
            return eager(formula, tensors, out_shape, row_dims, static)

        out = one_row(formula, inputs, out_shape, row_dims, static, fallback)
        if out is not None:
            return out
        if _enabled:
            if all(has_storage(x) for x in inputs):
                forward, vjp = _kernels(formula, out_shape, row_dims, static)
                if torch.is_grad_enabled() and any(x.requires_grad for x in inputs):
                    with torch.no_grad():
                        out = forward(*inputs)
                    return Gradient.apply(out, _compiled_gradients, vjp, fallback, *inputs)
                return forward(*inputs)
        else:
            out = columns(formula, inputs, out_shape, row_dims, static, fallback)
            if out is not None:
                return out
    return eager(formula, inputs, out_shape, row_dims, static)
