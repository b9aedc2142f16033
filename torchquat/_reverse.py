"""Reverse-mode derivatives of a formula, generated once as straight-line Python.

One rotation's backward pass is the gradient of a formula of :mod:`torchquat._formulas` at a
handful of floats. Autograd would spend a dispatch on each of its steps; instead the formula is
traced once (per set of options) with symbolic :class:`Node` values, and the trace is written out
as a Python function of floats that computes the values and then their adjoints, each step by the
textbook derivative of one elementary function. No derivative is written by hand, and the tensor
formula stays the one source. ``where`` passes the adjoint to the side it selected, as
``torch.where`` does.
"""

import math
import re
from typing import Callable, Dict, List, Tuple

import numpy

from ._backends import _float_sign

_CACHE: Dict[Tuple, Callable] = {}


class Node:
    """One step of a traced formula: an operation and its arguments (Nodes or float constants)."""

    __slots__ = ("op", "args", "index", "trace")

    def __init__(self, trace: List["Node"], op: str, *args):
        self.op, self.args, self.trace, self.index = op, args, trace, len(trace)
        trace.append(self)

    def _new(self, op, *args):
        return Node(self.trace, op, *args)

    def __add__(self, o): return self._new("add", self, o)
    def __radd__(self, o): return self._new("add", o, self)
    def __sub__(self, o): return self._new("sub", self, o)
    def __rsub__(self, o): return self._new("sub", o, self)
    def __mul__(self, o): return self._new("mul", self, o)
    def __rmul__(self, o): return self._new("mul", o, self)
    def __truediv__(self, o): return self._new("div", self, o)
    def __rtruediv__(self, o): return self._new("div", o, self)
    def __neg__(self): return self._new("neg", self)
    def __lt__(self, o): return self._new("lt", self, o)
    def __le__(self, o): return self._new("le", self, o)
    def __gt__(self, o): return self._new("lt", o, self)
    def __ge__(self, o): return self._new("le", o, self)
    def __and__(self, o): return self._new("and", self, o)
    def __rand__(self, o): return self._new("and", o, self)
    def __or__(self, o): return self._new("or", self, o)
    def __ror__(self, o): return self._new("or", o, self)


def _node_of(args):
    return next(a for a in args if isinstance(a, Node))


class _Trace:
    """The namespace of :mod:`torchquat._backends` for tracing."""

    pi = math.pi

    @staticmethod
    def _apply(op, *args):
        if not any(isinstance(a, Node) for a in args):  # (constants fold)
            return _FLOAT_OPS[op](*args)
        return _node_of(args)._new(op, *args)

    def sqrt(self, x): return self._apply("sqrt", x)
    def sin(self, x): return self._apply("sin", x)
    def cos(self, x): return self._apply("cos", x)
    def atan2(self, y, x): return self._apply("atan2", y, x)
    def fmod(self, x, y): return self._apply("fmod", x, y)
    def abs(self, x): return self._apply("abs", x)
    def sign(self, x): return self._apply("sign", x)
    def where(self, c, a, b): return self._apply("where", c, a, b)


_FLOAT_OPS = {"sqrt": math.sqrt, "sin": math.sin, "cos": math.cos, "atan2": math.atan2, "fmod": math.fmod,
              "abs": abs, "sign": _float_sign, "where": lambda c, a, b: a if c else b}

# how each operation is written, from its arguments' names
_FORWARD = {
    "add": "{0} + {1}", "sub": "{0} - {1}", "mul": "{0} * {1}", "div": "{0} / {1}", "neg": "-{0}",
    "lt": "{0} < {1}", "le": "{0} <= {1}", "and": "{0} & {1}", "or": "{0} | {1}",
    "sqrt": "sqrt({0})", "sin": "sin({0})", "cos": "cos({0})", "atan2": "atan2({0}, {1})", "fmod": "fmod({0}, {1})",
    "abs": "abs({0})", "sign": "sign({0})", "where": "where({0}, {1}, {2})",
}
# each argument's adjoint contribution, from the node's adjoint (a), value (v) and arguments
_BACKWARD = {
    "add": ("{a}", "{a}"), "sub": ("{a}", "-{a}"), "neg": ("-{a}",),
    "mul": ("{a} * {1}", "{a} * {0}"), "div": ("{a} / {1}", "-{a} * {v} / {1}"),
    "sqrt": ("{a} * 0.5 / {v}",), "sin": ("{a} * cos({0})",), "cos": ("-{a} * sin({0})",),
    "atan2": ("{a} * {1} / ({0} * {0} + {1} * {1})", "-{a} * {0} / ({0} * {0} + {1} * {1})"),
    "fmod": ("{a}", None), "abs": ("{a} * sign({0})",),
    "where": (None, "where({0}, {a}, 0.0)", "where({0}, 0.0, {a})"),
}


def _name(x) -> str:
    return f"v{x.index}" if isinstance(x, Node) else repr(float(x) if not isinstance(x, bool) else x)


def _generate(formula, n_inputs: int, static: dict, arrays: bool) -> Callable:
    trace: List[Node] = []
    inputs = [Node(trace, "input") for _ in range(n_inputs)]
    outputs = formula(_Trace(), *inputs, **static)
    varies = [False] * len(trace)  # depends on an input
    for node in trace:
        varies[node.index] = node.op == "input" or any(isinstance(a, Node) and varies[a.index] for a in node.args)
    needed = [False] * len(trace)  # carries an adjoint back from an output
    for o in outputs:
        if isinstance(o, Node):
            needed[o.index] = varies[o.index]
    for node in reversed(trace):
        if needed[node.index] and node.op in _BACKWARD:
            for arg, rule in zip(node.args, _BACKWARD[node.op]):
                if rule is not None and isinstance(arg, Node) and varies[arg.index]:
                    needed[arg.index] = True
    names = [f"v{i}" for i in range(n_inputs)]
    grads = [f"g{k}" for k in range(len(outputs))]
    lines = []
    started = set()  # adjoints assigned so far: the first contribution is assigned, later ones added

    def contribute(index: int, term: str):
        lines.append(f"    a{index} = a{index} + {term}" if index in started else f"    a{index} = {term}")
        started.add(index)

    for k, o in enumerate(outputs):
        if isinstance(o, Node) and needed[o.index]:
            contribute(o.index, f"g{k}")
    for node in reversed(trace):
        if not needed[node.index] or node.op not in _BACKWARD or node.index not in started:
            continue
        rules = _BACKWARD[node.op]
        if node.op == "where" and arrays and isinstance(node.args[0], Node):  # (NumPy's where costs 5 products)
            rules = (None, "{a} * {0}", "{a} * ~{0}")
        for arg, rule in zip(node.args, rules):
            if rule is not None and isinstance(arg, Node) and needed[arg.index]:
                contribute(arg.index, rule.format(*map(_name, node.args), a=f"a{node.index}", v=f"v{node.index}"))
    lines.append("    return [" + ", ".join(f"a{i}" if i in started else "0.0" for i in range(n_inputs)) + "]")
    # the forward steps the adjoints read, and the steps those read (the rest is never computed)
    used = [False] * len(trace)
    for index in map(int, re.findall(r"\bv(\d+)\b", "\n".join(lines))):
        used[index] = True
    for node in reversed(trace):
        if used[node.index]:
            for arg in node.args:
                if isinstance(arg, Node):
                    used[arg.index] = True
    forward = [f"    v{node.index} = " + _FORWARD[node.op].format(*map(_name, node.args))
               for node in trace[n_inputs:] if used[node.index]]
    lines = [f"def vjp({', '.join(names + grads)}):"] + forward + lines
    scope = dict(ARRAY_FUNCTIONS if arrays else FLOAT_FUNCTIONS, inf=math.inf, nan=math.nan)
    exec(compile("\n".join(lines), f"<torchquat vjp of {formula.__name__}>", "exec"), scope)
    return scope["vjp"]


FLOAT_FUNCTIONS = {"sqrt": math.sqrt, "sin": math.sin, "cos": math.cos, "atan2": math.atan2, "fmod": math.fmod,
                   "abs": abs, "sign": _float_sign, "where": _FLOAT_OPS["where"]}
ARRAY_FUNCTIONS = {"sqrt": numpy.sqrt, "sin": numpy.sin, "cos": numpy.cos, "atan2": numpy.arctan2,
                   "fmod": numpy.fmod, "abs": numpy.abs, "sign": numpy.sign, "where": numpy.where}


def vjp_function(formula, n_inputs: int, static: dict, arrays: bool = False) -> Callable:
    """``vjp(*inputs, *output_gradients) -> input gradients`` of ``formula``, in floats or, with
    ``arrays``, in NumPy columns (generated once per formula and options)."""
    key = (formula, n_inputs, tuple(sorted(static.items())), arrays)
    fn = _CACHE.get(key)
    if fn is None:
        fn = _CACHE[key] = _generate(formula, n_inputs, static, arrays)
    return fn
