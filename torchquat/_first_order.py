"""Compiled kernels' gradients are first-order: a second derivative through them raises instead of
coming out as 0 or ``None``, and a batch of output gradients raises a clear error."""

import functools

import torch
from torch import Tensor

from . import _closed_form

_SECOND_ORDER = ("torchquat's compiled kernels are first-order: a derivative of their gradient is not available. "
                 "Switch them off (torchquat.use_compiled_kernels(False)) for double backward and Hessians; "
                 "torch.func transforms run the eager kernels")
_BATCHED_GRADIENTS = ("torchquat's compiled kernels take one output gradient at a time: a batch of them "
                      "(torch.autograd.grad(..., is_grads_batched=True), torch.autograd.functional.jacobian or "
                      "hessian with vectorize=True) cannot run through their compiled backward. Use vectorize=False, "
                      "torch.func.jacrev (torch.func transforms run the eager kernels), or switch the compiled "
                      "kernels off (torchquat.use_compiled_kernels(False))")


def first_order_only(output: Tensor, tensors) -> Tensor:
    """``output`` of a compiled kernel, whose gradients raise if differentiated again.

    A compiled backward asked for a graph (``create_graph``) gives a gradient that cannot be
    differentiated, and when the incoming gradient needs none (a loss linear in the kernel's
    output) nothing even connects that gradient to the inputs: a Hessian came out as 0, or
    ``None``, silently. So with a graph asked for, each input's gradient gets a zero term through
    an error node on that input, and a second derivative raises instead. A hook on the compiled
    backward node adds it (1.00-1.06x the time with the backward at 1 and 8,192 rows, where an
    autograd Function on the output took 1.05-1.15x); where the node's edges are not the inputs'
    own, that Function does. An output that no compiled node made (a boolean mask, or a call that ran
    eagerly past the recompile limit) is returned as it is: eager kernels are differentiable
    any number of times."""
    node = _compiled_node(output)
    if node is None:
        return output
    # (inductor's backward reads its inputs' storage, which autograd's legacy vmap tensors lack:
    # without this a batch of output gradients fails with "Cannot access data pointer")
    node.register_prehook(_batched_gradients_prehook)
    edges = [(x, (x.grad_fn, x.output_nr) if x.grad_fn is not None else None) for x in tensors if x.requires_grad]
    slots = {}
    for k, (next_node, index) in enumerate(node.next_functions):
        for x, edge in edges:
            if (next_node, index) == edge or (edge is None and getattr(next_node, "variable", None) is x):
                slots[k] = x
    if len(set(map(id, slots.values()))) != len({id(x) for x, _ in edges}):  # (aot gives a repeated input one edge)
        return FirstOrder.apply(output, *tensors)
    node.register_hook(functools.partial(_second_order_hook, slots))
    return output


def _compiled_node(output: Tensor):
    """The compiled function's backward node behind ``output`` (through views that
    aot_autograd regenerates outside the graph), or None."""
    node = output.grad_fn
    for _ in range(4):
        if node is None or type(node).__name__ == "CompiledFunctionBackward":
            return node
        if len(node.next_functions) != 1 or "View" not in type(node).__name__ and "Strided" not in type(node).__name__:
            return None
        node = node.next_functions[0][0]
    return None


def _batched_gradients_prehook(grad_outputs):
    if any(_closed_form._legacy_batched(g) for g in grad_outputs if g is not None):
        raise RuntimeError(_BATCHED_GRADIENTS)
    return None


def _second_order_hook(slots, grad_inputs, grad_outputs):
    if not torch.is_grad_enabled():  # (first order; batched gradients never get here: the prehook raises)
        return None
    grads = list(grad_inputs)
    for k, x in slots.items():
        term = _error_term(x)
        grads[k] = term if grads[k] is None else grads[k] + term
    return tuple(grads)


def _error_term(x: Tensor) -> Tensor:
    """Zeros shaped as ``x``, connected to it through a node that raises when differentiated."""
    return torch._C._functions.DelayedError(_SECOND_ORDER.encode(), 2)(torch.zeros_like(x), x)[0]


class FirstOrder(torch.autograd.Function):
    """Identity on a compiled kernel's output, given its inputs: the same as the hook of
    :func:`first_order_only`, as an autograd node of its own."""

    @staticmethod
    def forward(ctx, output, *inputs):
        ctx.save_for_backward(*inputs)
        return output.clone()  # (not a view: callers may write into the result in place)

    @staticmethod
    def backward(ctx, grad, *_):
        if _closed_form._legacy_batched(grad):  # (the compiled node behind it would fail obscurely)
            raise RuntimeError(_BATCHED_GRADIENTS)
        if not torch.is_grad_enabled():
            return (grad,) + (None,) * len(ctx.needs_input_grad[1:])
        return (grad,) + tuple(_error_term(x) if wanted else None
                               for x, wanted in zip(ctx.saved_tensors, ctx.needs_input_grad[1:]))

