"""One rotation on the CPU, in Python floats.

At one rotation every PyTorch operation costs its dispatch (2-5 us on the CPUs measured) whatever
it computes, so a conversion of 15-25 operations takes 40-180 us, and autograd's backward adds a
node per operation; no formula with fewer operations keeps the guarantees (pytorch-kinematics'
13-operation matrix -> Euler is wrong at gimbal lock). Python's own floats cost about 0.05 us an
operation. So a kernel given CPU tensors of one row each, with no trace, compile or ``torch.func``
transform watching, reads them with ``tolist()`` (0.6 us; on the CPU there is no device to wait
for), computes the same formulas in double precision, and writes a fresh tensor of the input's
dtype (each entry rounded once: a float32 result is the float64 one rounded) through
``torch.from_numpy`` (so, like any such tensor, its storage cannot be resized in place). Where a graph is
recorded, one autograd node (:class:`_OneRowGradient`) holds the formulas' vector-Jacobian
product, also in Python floats; a graph of the gradient (double backward) differentiates the tensor
kernel instead, so higher derivatives are the tensor kernels' own. While compiled autograd is on,
a call that records a graph takes the tensor kernel; a node recorded before it was switched on gives
that trace the formulas' Jacobian as a constant.

A public function offers its arguments as given (``kernel.at_one_row``) before it validates them:
validation's attribute reads (3-5 us) were a quarter to a third of a one-row call. :func:`run`
accepts only what validation passes unchanged (plain tensors or parameters, CPU, one float32 or
float64 dtype, each one row of the row's own shape); anything else, a list or a ``(2, 2)``
"quaternion" say, returns ``None``, and the public function validates, with its errors, and calls
the kernel as before.

Anything unusual goes back to the tensor kernel (:func:`run` returns ``None``): a non-finite
input, an exception from ``math`` (a zero quaternion's division, say), a row a formula leaves to it
(:class:`Fallback`: collinear 6D columns with a gradient), a tensor subclass other than
``nn.Parameter``. The formulas are the kernels' own, with their choices
(``torchquat._one_row_formulas``; their gradients in ``torchquat._one_row_gradients``).
"""

import math
import os
import sys
from typing import Callable, NamedTuple, Optional, Tuple

import numpy
import torch
from torch import Tensor

from ._closed_form import _is_legacy_batched, _transformed

# On by default; TORCHQUAT_ONE_ROW=0 (or setting this to False) leaves one row to the tensor kernels.
ENABLED = os.environ.get("TORCHQUAT_ONE_ROW", "1").lower() not in ("0", "false", "no", "off")
_NUMPY_DTYPES = {torch.float32: numpy.float32, torch.float64: numpy.float64}
_isfinite = math.isfinite
_tracing = torch._C._get_tracing_state
_is_compiling = torch.compiler.is_compiling
_grad_enabled = torch.is_grad_enabled


class Fallback(Exception):
    """Raised by a formula for a row it leaves to the tensor kernel."""


# tensors whose methods are torch's own (a learnable rotation is often an nn.Parameter)
_PLAIN = frozenset((Tensor, torch.nn.Parameter))
_FAILURES = (ZeroDivisionError, ValueError, OverflowError, Fallback)


class OneRow(NamedTuple):
    """A kernel's one-row form: the name of its functions (``torchquat._one_row_formulas.name(*rows,
    dtype, **static)`` of flat lists of floats returns a flat list or one float;
    ``torchquat._one_row_gradients.name_vjp`` the same and its vector-Jacobian product; looked up at
    the first call, since those modules read the kernels' own tables), each input's row size, and
    the output's row shape."""

    name: str
    row_sizes: Tuple[int, ...]
    out_shape: Tuple[int, ...]


_FORMULAS = {}


def _formula(name: str) -> Optional[Callable]:
    """The function ``name`` of the formulas (or, for ``..._vjp``, the gradients) module; ``None``
    where there is none (a one-row form may have values only: a recorded call then takes the kernel)."""
    fn = _FORMULAS.get(name, False)
    if fn is False:
        from . import _one_row_formulas, _one_row_gradients
        fn = _FORMULAS[name] = getattr(_one_row_gradients if name.endswith("_vjp") else _one_row_formulas, name, None)
    return fn


def _flat(t: Tensor, size: int):
    """The one row of ``t`` as a list of floats, and ``t``'s number of batch dims; ``None`` unless
    ``t``, of ``size`` entries, is a ``(1, ..., 1, size)`` row, a ``(1, ..., 1, 3, 3)`` matrix for
    ``size`` 9 (read row-major), or for ``size`` 1 any shape (one number per row: slerp's ``t``)."""
    # (a public function's input is not yet validated: a (2, 2) "quaternion"; the shape is read once,
    # since every attribute read and Size index is a good part of this call's cost)
    shape = t.shape
    dims = len(shape)
    if size == 9:
        if dims < 2 or shape[-1] != 3 or shape[-2] != 3:
            return None
        batch_dims = dims - 2
    elif size == 1:
        batch_dims = dims
    elif not dims or shape[-1] != size:
        return None
    else:
        batch_dims = dims - 1
    values = t.tolist()
    for _ in range(batch_dims):
        values = values[0]
    return ([values] if size == 1 else values[0] + values[1] + values[2] if size == 9 else values), batch_dims


def _tensor(values, numpy_dtype, shape: tuple) -> Tensor:
    # (torch.from_numpy: 1.1-1.9 us, where torch.tensor(values, dtype=...) takes 4.5 us and a copy
    # into torch's own memory 2 us more; like every from_numpy tensor, its storage is not resizable)
    return torch.from_numpy(numpy.array(values, dtype=numpy_dtype).reshape(shape))


# torch.autograd.Function.apply less its Python wrapper, which serves torch.func transforms (never
# active here: run() has checked) and setup_context (not used): 13k fewer of a recorded one-row
# call's 114k instructions (callgrind, quat_geodesic_distance); bound at the first recorded call
_apply_node = None


def run(one_row: OneRow, kernel: Callable, *tensors: Tensor, **static) -> Optional[Tensor]:
    """``one_row``'s formula on ``tensors`` of one row each, as a tensor of their dtype and batch
    shape (with its gradient node where autograd records), or ``None`` where the tensor kernel must
    run instead (see the module docstring). ``kernel``: the tensor kernel, for double backward."""
    # (first: under compile a size test would guard the graph on its batch size; then the first
    # input's size, which turns a batch away at a third of the checks' cost, since every public call
    # of a batch pays this; then the transforms: under vmap a tensor's numel() is a sample's, and
    # forward-mode AD would not see through the floats)
    if not ENABLED or _is_compiling():
        return None
    first = tensors[0]
    if (type(first) not in _PLAIN or first.numel() != one_row.row_sizes[0]  # (a public argument: a list, say)
            or _transformed() or _tracing() is not None):
        return None
    dtype = first.dtype
    numpy_dtype = _NUMPY_DTYPES.get(dtype)
    if numpy_dtype is None:
        return None
    rows, batch_dims, records, total = [], 0, False, 0.0
    for t, size in zip(tensors, one_row.row_sizes):
        # (the first input's type, size and dtype are tested above; one rotation against a batch,
        # rotate's vectors say, returns at the other's numel())
        if t is not first and (type(t) not in _PLAIN or t.numel() != size or t.dtype is not dtype) or not t.is_cpu:
            return None
        row = _flat(t, size)
        if row is None:
            return None
        values, dims = row
        if t.requires_grad:
            records = True
        total += sum(values)
        rows.append(values)
        if dims > batch_dims:
            batch_dims = dims
    if not _isfinite(total):  # (a sum is finite only if every term is: NaN and inf take the tensor kernel's way)
        return None
    shape = (1,) * batch_dims + one_row.out_shape
    try:
        if not (records and _grad_enabled()):
            return _tensor(_formula(one_row.name)(*rows, dtype=dtype, **static), numpy_dtype, shape)
        with_gradient = _formula(one_row.name + "_vjp")
        if with_gradient is None or _compiled_autograd_enabled():
            return None
        out, vjp = with_gradient(*rows, dtype=dtype, **static)
    except _FAILURES:
        return None
    # what the backward needs, read now: the first-order backward then unpacks no saved tensor
    out = numpy.array(out, dtype=numpy_dtype).reshape(shape)
    plan = (out, vjp, kernel, static, numpy_dtype, out.size,
            # (as tuples: NumPy reads a torch.Size as a sequence, 7x the time of a reshape)
            tuple(tuple(t.shape) for t in tensors))
    global _apply_node
    if _apply_node is None:
        _apply_node = _bind_apply()
    return _apply_node(plan, *tensors)


def _compiled_autograd_enabled() -> bool:
    """Whether ``torch._dynamo.compiled_autograd`` is on (it can be only once imported): the tensor
    kernels' nodes then keep the gradient's numbers in tensors, which its traces take as inputs.
    (This node's backward, traced, takes the formulas' Jacobian as constants: correct, but each new
    row's would recompile the trace.)"""
    module = sys.modules.get("torch._dynamo.compiled_autograd")
    return module is not None and module.compiled_autograd_enabled


def _bind_apply() -> Callable:
    apply = getattr(torch._C, "_FunctionBase", object).__dict__.get("apply")
    return _OneRowGradient.apply if apply is None else apply.__get__(None, _OneRowGradient)


class _OneRowGradient(torch.autograd.Function):
    """The node of a one-row call: its backward is the formulas' vector-Jacobian product."""

    @staticmethod
    def forward(ctx, plan: tuple, *inputs: Tensor):
        ctx.plan = plan
        ctx.save_for_backward(*inputs)
        return torch.from_numpy(plan[0])

    @staticmethod
    def backward(ctx, grad: Tensor):
        _, vjp, kernel, static, numpy_dtype, out_size, shapes = ctx.plan
        wanted = ctx.needs_input_grad[1:]
        create_graph = _grad_enabled()
        compiling = _is_compiling()
        if compiling and not create_graph:
            # compiled autograd traces this backward: reading the traced gradient's numbers would
            # specialise the graph on them (dynamo then fails its own guard). The formulas'
            # Jacobian, from the vector-Jacobian product of each unit vector, is a constant of the
            # trace instead, and the gradient one product with it.
            rows = [vjp([float(i == j) for j in range(out_size)]) for i in range(out_size)]
            flat = grad.reshape(1, out_size)
            return (None, *[(flat @ torch.tensor([row[k] for row in rows], dtype=grad.dtype)).reshape(shape)
                            if w else None for k, (shape, w) in enumerate(zip(shapes, wanted))])
        if create_graph or (not compiling and _is_legacy_batched(grad)) or type(grad) is not Tensor:
            # A graph of the gradient (double backward), or autograd's batched gradients: the
            # tensor kernel's own derivative, of views of the inputs (as _closed_form does)
            with torch.enable_grad():
                views = [x.view_as(x) for x in ctx.saved_tensors]
                output = kernel(*views, **static)
                targets = [x for x, w in zip(views, wanted) if w]
                found = iter(torch.autograd.grad(output, targets, grad, create_graph=create_graph, allow_unused=True))
            return (None, *(next(found) if w else None for w in wanted))
        grads = vjp(_flat(grad, out_size)[0])
        return (None, *[_tensor(g, numpy_dtype, shape) if w else None for g, shape, w in zip(grads, shapes, wanted)])
