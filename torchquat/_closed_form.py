"""Closed-form backward passes for the small-batch kernels.

For a few rows every dispatch counts, and autograd's backward runs one node per forward
operation: a conversion of 15 to 30 operations pays 4 to 6 times its forward again in the
backward. A :class:`Rule` gives a kernel a backward of a few operations instead: its forward
saves what the gradient needs (often the rows' Jacobians, computed alongside the values), and its
backward contracts the incoming gradient with them in one node.

Only first derivatives take the closed form. Asked for a graph of the gradient (double backward),
the backward differentiates the rule's plain forward by autograd, so higher derivatives stay
exact. Under ``torch.func`` transforms and forward-mode AD, which a custom backward does not
serve, the plain forward runs instead. With nothing to differentiate, a rule's ``values`` (when
it has one) runs: the same numbers without the substitutions that only keep autograd finite.
"""

from typing import Callable, NamedTuple, Optional

import torch
from torch import Tensor


class Rule(NamedTuple):
    """``plain(*inputs, **options)``: the forward, differentiable by autograd;
    ``forward(*inputs, **options) -> (output, saved tensors)``: the same output, and what the
    backward needs; ``backward(grad, inputs, saved, **options) -> gradients`` (one per input, in
    each input's broadcast batch shape); ``values(*inputs, **options)``, optional: the same
    output bit for bit, with no autograd graph to keep finite (so fewer operations)."""

    plain: Callable
    forward: Callable
    backward: Callable
    values: Optional[Callable] = None


def jacobian_rule(plain: Callable, with_jacobian: Callable, values: Optional[Callable] = None) -> Rule:
    """A :class:`Rule` for a one-input row-wise kernel whose ``with_jacobian(x, **options)``
    returns the output and each row's Jacobian, shaped ``(..., x's row size, output's row size)``;
    ``values`` as in :class:`Rule`."""

    def forward(x, **options):
        y, jacobian = with_jacobian(x, **options)
        return y, (jacobian,)

    def backward(grad, inputs, saved, **options):
        (jacobian,) = saved  # (a broadcast product and sum: cheaper than a batched matmul for few rows)
        g = grad.reshape(jacobian.shape[:-2] + (1, jacobian.shape[-1]))
        return ((jacobian * g).sum(-1).view(inputs[0].shape),)

    return Rule(plain, forward, backward, values)


_any_autocast = getattr(torch._C, "_is_any_autocast_enabled", lambda: True)


def autocast_device(x: Tensor) -> Optional[str]:
    """``x``'s device type if autocast is on for it, else None: the common answer, no, in one C
    call (``x.device.type`` alone costs 0.3 us, a tenth of an operation at one rotation)."""
    if _any_autocast() and torch.is_autocast_enabled(device := x.device.type):
        return device
    return None


_is_legacy_batched = getattr(torch._C._functorch, "is_legacy_batchedtensor", lambda x: False)


def _legacy_batched(grad: Tensor) -> bool:
    """Whether ``grad`` is one of autograd's batched gradients (``is_grads_batched``, legacy vmap).
    False in code that compiled autograd traces: no such gradient reaches a trace, and dynamo
    cannot trace the test (a pybind function: a graph break in every backward graph)."""
    return not torch.compiler.is_compiling() and _is_legacy_batched(grad)


_functorch_active = torch._C._are_functorch_transforms_active
_forward_ad = torch.autograd.forward_ad


def _transformed() -> bool:
    """Whether ``torch.func`` transforms or forward-mode AD are active (they need the plain forward)."""
    # (the names bound once: this runs on every kernel call, 0.2 us less at one rotation)
    return _functorch_active() or getattr(_forward_ad, "_current_level", -1) >= 0


def differentiated(inputs) -> bool:
    """Whether anything may differentiate a call on ``inputs``: autograd records (grad mode on and an
    input requiring grad) or a ``torch.func`` transform or forward-mode AD is active. Where not, a
    rule's value form may run (``Rule.values``: the same numbers, without the blends that keep
    gradients finite). (In a trace of ``torch.func.grad`` the inputs need not require a gradient.)"""
    return (torch.is_grad_enabled() and any(x.requires_grad for x in inputs)) or _transformed()


def records_graph(inputs) -> bool:
    """Whether a call on ``inputs`` records a graph that :func:`apply` gives its closed-form
    backward (grad mode on, an input requiring grad, and no ``torch.func`` transform)."""
    for x in inputs:  # (requires_grad first: the common no-grad call pays one attribute read)
        if x.requires_grad:
            return torch.is_grad_enabled() and not _transformed()
    return False



class _ClosedForm(torch.autograd.Function):
    @staticmethod
    def forward(ctx, rule: Rule, options: dict, *inputs: Tensor):
        output, saved = rule.forward(*inputs, **options)
        ctx.rule, ctx.options, ctx.n_inputs = rule, options, len(inputs)
        ctx.save_for_backward(*inputs, *saved)
        # A view made here (rows reshaped into matrices, say) would be an output that autograd
        # forbids writing in place; detached, it is a tensor of its own on the same memory.
        return output.detach() if output._is_view() else output

    @staticmethod
    def backward(ctx, grad: Tensor):
        if (device := autocast_device(grad)) is not None:  # (a backward run inside an autocast region:
            # the forward ran in the inputs' precision, and so does its gradient, matmuls included)
            with torch.autocast(device, enabled=False):
                return _ClosedForm.backward(ctx, grad)
        tensors = ctx.saved_tensors
        inputs, saved = tensors[:ctx.n_inputs], tensors[ctx.n_inputs:]
        wanted = ctx.needs_input_grad[2:]
        create_graph = torch.is_grad_enabled()
        if create_graph or _legacy_batched(grad):
            # A graph of the gradient was asked for, or the gradient is batched by autograd's
            # is_grads_batched (jacobian(vectorize=True)), whose legacy vmap has no batching rule
            # for the closed forms' out= writes and broadcasts: differentiate the plain forward,
            # of views of the inputs: the partial derivatives, connected to the inputs' graphs. (Of
            # the inputs themselves, an input computed from another, or the same tensor twice,
            # would add the path through the other to its own derivative.)
            with torch.enable_grad():
                inputs = [x.view_as(x) for x in inputs]
                output = ctx.rule.plain(*inputs, **ctx.options)
                targets = [x for x, w in zip(inputs, wanted) if w]
                found = iter(torch.autograd.grad(output, targets, grad, create_graph=create_graph, allow_unused=True))
            return (None, None, *(next(found) if w else None for w in wanted))
        grads = ctx.rule.backward(grad, inputs, saved, **ctx.options)
        result = [None, None]
        for g, x, w in zip(grads, inputs, wanted):  # broadcast inputs get their gradient summed back
            result.append((g if g.shape == x.shape else g.sum_to_size(x.shape)) if w else None)
        return tuple(result)


TRACED = True
VALUE_FORMS = True  # (where nothing differentiates: the rules' value forms in traces, and quat -> Euler's columns)


def traced_rule(rule: Rule) -> Callable:
    """``rule``'s kernel for ``torch.compile`` traces: a function of ``(*inputs, **options)`` that gives
    ``rule.values``'s output (``rule.plain``'s if it has none, or under ``torch.func`` transforms)
    where nothing records a graph, and where autograd records, an ``autograd.Function`` of
    ``rule.forward``'s output that saves only the inputs, whose backward runs ``rule.forward`` again
    for what the closed form needs, then ``rule.backward``. (The value forms drop the blends that keep
    autograd finite: 0.83-0.94x the time of six kernels at 1e6 rows on a Zen 4; switch
    ``VALUE_FORMS``. A rule whose value form is slower compiled is given here with ``values=None``.)"""

    class TracedRule(torch.autograd.Function):
        @staticmethod
        def forward(options, *inputs):
            return rule.forward(*inputs, **dict(options))[0]

        @staticmethod
        def setup_context(ctx, inputs, output):
            ctx.options = inputs[0]
            ctx.save_for_backward(*inputs[1:])

        @staticmethod
        def backward(ctx, grad):
            inputs, options = ctx.saved_tensors, dict(ctx.options)
            grads = rule.backward(grad, inputs, rule.forward(*inputs, **options)[1], **options)
            return (None, *(g if g.shape == x.shape else g.sum_to_size(x.shape) for g, x in zip(grads, inputs)))

    def traced(*inputs: Tensor, **options):
        if (TRACED and torch.compiler.is_dynamo_compiling() and torch.is_grad_enabled()
                and any(x.requires_grad for x in inputs)
                and not (len(inputs) == 2 and inputs[0] is inputs[1])):  # (dynamo refuses a tensor twice)
            return TracedRule.apply(tuple(options.items()), *inputs)
        if VALUE_FORMS and rule.values is not None and torch.compiler.is_dynamo_compiling() and not differentiated(inputs):
            return rule.values(*inputs, **options)
        return rule.plain(*inputs, **options)

    return traced


def apply(rule: Rule, *inputs: Tensor, **options):
    """``rule``'s output with its closed-form backward when autograd records; ``rule.plain`` under
    transforms; else ``rule.values`` (or ``rule.plain`` if it has none)."""
    if records_graph(inputs):
        return _ClosedForm.apply(rule, options, *inputs)
    return apply_without_closed_form(rule, *inputs, **options)


def apply_without_closed_form(rule: Rule, *inputs: Tensor, **options):
    """``rule.values`` when nothing records a graph and it has one, else ``rule.plain`` (for batches
    where autograd's backward beats the closed form's)."""
    if rule.values is not None and not differentiated(inputs):
        return rule.values(*inputs, **options)
    return rule.plain(*inputs, **options)
