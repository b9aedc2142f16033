"""A formula written out as straight-line Python: its forward steps and its reverse mode.

The host paths (:mod:`torchquat._host`) run a formula of :mod:`torchquat._formulas` on Python
floats or NumPy columns, where each step costs an interpreter call. The formula is traced once per
set of options with symbolic :class:`Node` values (constants folded, repeated steps merged), and
the trace is written out as three functions:

* ``forward(*inputs, *parameters) -> (outputs, saved)``: the steps the outputs need, in the
  formula's order (so the same roundings), and the values the backward reads;
* ``evaluate(*inputs, *parameters) -> outputs``: the same steps, keeping nothing (no gradient);
* ``backward(*inputs, *parameters, *saved, *output_gradients) -> input gradients``: each step's
  adjoint by the textbook derivative of one elementary function, reading the saved values instead
  of recomputing them. Signs are carried symbolically, so negation and subtraction cost no step.

On NumPy columns each value is deleted after its last use, so that the next step's result reuses
its memory while it is in cache.

No derivative is written by hand, and the formula stays the one source. ``where`` passes the
adjoint to the side it selected, as ``torch.where`` does. Float options (thresholds such as
``lock_sine``) are *parameters*, arguments of the generated functions, so a new value generates
nothing; the others (names, flags) are constants of the code.
"""

import math
import re
from typing import Callable, Dict, List, NamedTuple, Tuple

import numpy

from ._backends import ARRAY_FUNCTIONS, FLOAT_FUNCTIONS

_CACHE: Dict[Tuple, "Generated"] = {}


class _Graph:
    """The steps of a trace, in order; a step already taken with the same arguments is reused
    (the same operation on the same values rounds the same way)."""

    def __init__(self):
        self.nodes: List[Node] = []
        self.memo: Dict[Tuple, Node] = {}

    def node(self, op: str, args) -> "Node":
        a = args
        # Negations move outwards until a sum absorbs them; each rewrite is exact, signed zeros included
        if op == "neg" and _negated(a[0]):
            return a[0].args[0]
        if op in ("mul", "div") and (_negated(a[0]) or _negated(a[1])):
            inner = self.node(op, tuple(x.args[0] if _negated(x) else x for x in a))
            return inner if _negated(a[0]) and _negated(a[1]) else self.node("neg", (inner,))
        if op == "add" and _negated(a[1]):
            return self.node("sub", (a[0], a[1].args[0]))
        if op == "add" and _negated(a[0]):
            return self.node("sub", (a[1], a[0].args[0]))
        if op == "sub" and _negated(a[1]):
            return self.node("add", (a[0], a[1].args[0]))
        keys = tuple(("v", a.index) if isinstance(a, Node) else ("c", repr(a)) for a in args)
        if op in ("add", "mul"):  # (IEEE addition and multiplication commute exactly)
            keys = tuple(sorted(keys))
        key = (op,) + keys
        found = self.memo.get(key)
        if found is None:
            found = self.memo[key] = Node(self, op, args)
        return found


def _negated(x) -> bool:
    return isinstance(x, Node) and x.op == "neg"


def _is_one(x) -> bool:
    """A constant 1.0: a product or quotient with it is the other value, exactly."""
    return type(x) is float and x == 1.0


class Node:
    """One step of a traced formula: an operation and its arguments (Nodes or constants)."""

    __slots__ = ("op", "args", "index", "graph")

    def __init__(self, graph: _Graph, op: str, args=()):
        self.op, self.args, self.graph, self.index = op, tuple(args), graph, len(graph.nodes)
        graph.nodes.append(self)

    def _new(self, op, *args):
        return self.graph.node(op, args)

    def __add__(self, o): return self._new("add", self, o)
    def __radd__(self, o): return self._new("add", o, self)
    def __sub__(self, o): return self._new("sub", self, o)
    def __rsub__(self, o): return self._new("sub", o, self)
    def __mul__(self, o): return self if _is_one(o) else self._new("mul", self, o)
    def __rmul__(self, o): return self if _is_one(o) else self._new("mul", o, self)
    def __truediv__(self, o): return self if _is_one(o) else self._new("div", self, o)
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


class _Trace:
    """The namespace of :mod:`torchquat._backends` for tracing."""

    pi = math.pi

    @staticmethod
    def _apply(op, *args):
        node = next((a for a in args if isinstance(a, Node)), None)
        return FLOAT_FUNCTIONS[op](*args) if node is None else node._new(op, *args)  # (constants fold)

    def sqrt(self, x): return self._apply("sqrt", x)
    def sin(self, x): return self._apply("sin", x)
    def cos(self, x): return self._apply("cos", x)
    def atan2(self, y, x): return self._apply("atan2", y, x)
    def fmod(self, x, y): return self._apply("fmod", x, y)
    def abs(self, x): return self._apply("abs", x)
    def sign(self, x): return self._apply("sign", x)
    def where(self, c, a, b): return self._apply("where", c, a, b)


# how each operation is written, from its arguments' names
_FORWARD = {
    "add": "{0} + {1}", "sub": "{0} - {1}", "mul": "{0} * {1}", "div": "{0} / {1}", "neg": "-{0}",
    "lt": "{0} < {1}", "le": "{0} <= {1}", "and": "{0} & {1}", "or": "{0} | {1}",
    "sqrt": "sqrt({0})", "sin": "sin({0})", "cos": "cos({0})", "atan2": "atan2({0}, {1})", "fmod": "fmod({0}, {1})",
    "abs": "abs({0})", "sign": "sign({0})", "where": "where({0}, {1}, {2})",
}
# each argument's adjoint contribution as (sign, term), from the node's adjoint {a}, its value {v},
# its arguments {0}, {1}, ... and {r}, a per-node value written once before the terms (_ONCE)
_BACKWARD = {
    "add": ((1, "{a}"), (1, "{a}")), "sub": ((1, "{a}"), (-1, "{a}")), "neg": ((-1, "{a}"),),
    "mul": ((1, "{a} * {1}"), (1, "{a} * {0}")), "div": ((1, "{a} / {1}"), (-1, "{a} * {v} / {1}")),
    "sqrt": ((1, "{a} * {half} / {v}"),), "sin": ((1, "{a} * {cos}"),), "cos": ((-1, "{a} * {sin}"),),
    "atan2": ((1, "{r} * {1}"), (-1, "{r} * {0}")),
    "fmod": ((1, "{a}"), None), "abs": ((1, "{a} * {sign}"),),
    "where": (None, (1, "where({0}, {a}, {zero})"), (1, "where({0}, {zero}, {a})")),
}
_ONCE = {"atan2": "{a} / ({0} * {0} + {1} * {1})"}
# NumPy's where costs about four products: a product with the (boolean) condition selects instead
# ({n}: the condition's negation, computed once)
_ARRAY_WHERE = (None, (1, "{a} * {0}"), (1, "{a} * {n}"))
# the function of its argument that a derivative reads ({cos}, {sin}, {sign}): the forward's value
# where the formula computed it too, so that the backward does not compute it again
_DERIVATIVE_FACTOR = {"sin": "cos", "cos": "sin", "abs": "sign"}


class Generated(NamedTuple):
    forward: Callable  # outputs and the values the backward reads
    evaluate: Callable  # outputs only
    backward: Callable  # input gradients from the inputs, the saved values and the output gradients
    parameters: Tuple[str, ...]  # the float options, in the order the functions take them


class _Names:
    """The text of a value in generated code: ``v<index>`` for a step; for a constant, its literal
    in code on floats, and in code on NumPy columns a 0-d array of the columns' dtype bound in the
    code's scope (a product with one costs 0.4 us at 1,000 rows, with a Python float 0.65, and a
    selection between two of them keeps the dtype)."""

    def __init__(self, dtype):
        self.dtype, self.scope = dtype, {}

    def __call__(self, x) -> str:
        if isinstance(x, Node):
            return f"v{x.index}"
        if isinstance(x, bool):
            return repr(x)
        text = repr(float(x))
        if self.dtype is None:
            return text
        name = f"k_{text}".replace("-", "m").replace(".", "_").replace("+", "p")
        self.scope[name] = numpy.array(float(x), self.dtype)
        return name


def _backward_lines(nodes: List[Node], outputs, n_inputs: int, name: _Names, computed: List[bool]) -> List[str]:
    """The backward's lines; ``computed`` marks the steps the forward takes (their values can be saved)."""
    arrays = name.dtype is not None
    memo = nodes[0].graph.memo if nodes else {}
    varies = [False] * len(nodes)  # depends on an input
    for node in nodes:
        varies[node.index] = node.op == "input" or any(isinstance(a, Node) and varies[a.index] for a in node.args)
    carries = [False] * len(nodes)  # its adjoint reaches an input (not through a comparison or sign)
    for node in nodes:
        carries[node.index] = node.op == "input" or any(
            rule is not None and isinstance(arg, Node) and carries[arg.index]
            for arg, rule in zip(node.args, _BACKWARD.get(node.op, ())))
    needed = [False] * len(nodes)  # carries an adjoint back from an output to an input
    for o in outputs:
        if isinstance(o, Node):
            needed[o.index] = carries[o.index]
    for node in reversed(nodes):
        if needed[node.index] and node.op in _BACKWARD:
            for arg, rule in zip(node.args, _BACKWARD[node.op]):
                if rule is not None and isinstance(arg, Node) and carries[arg.index]:
                    needed[arg.index] = True
    lines: List[str] = []
    adjoint: Dict[int, Tuple[str, int]] = {}  # node -> (name, sign): its adjoint is sign * name

    def contribute(index: int, sign: int, term: str):
        plain = re.fullmatch(r"[ag]\d+", term) is not None
        if index not in adjoint:
            if not plain:
                lines.append(f"    a{index} = {term}")
                term = f"a{index}"
            adjoint[index] = (term, sign)
            return
        current, old = adjoint[index]
        term = term if plain else f"({term})"
        if old == sign:
            lines.append(f"    a{index} = {current} + {term}")
        else:  # (the positive one first: no negation)
            lines.append(f"    a{index} = {current} - {term}" if old > 0 else f"    a{index} = {term} - {current}")
            sign = 1
        adjoint[index] = (f"a{index}", sign)

    doubled, negated = set(), set()
    for k, o in enumerate(outputs):
        if isinstance(o, Node) and needed[o.index]:
            contribute(o.index, 1, f"g{k}")
    for node in reversed(nodes):
        if not needed[node.index] or node.op not in _BACKWARD or node.index not in adjoint:
            continue
        adjoint_name, sign = adjoint[node.index]
        condition = node.args[0] if node.op == "where" else None
        rules = _ARRAY_WHERE if arrays and isinstance(condition, Node) and varies[condition.index] else _BACKWARD[node.op]
        args = list(map(name, node.args))
        fields = dict(a=adjoint_name, v=f"v{node.index}", r=f"r{node.index}",
                      half=name(0.5), two=name(2.0), zero=name(0.0))
        function = _DERIVATIVE_FACTOR.get(node.op)
        if function is not None:
            same = memo.get((function, ("v", node.args[0].index)))
            fields[function] = f"v{same.index}" if same is not None and computed[same.index] else f"{function}({args[0]})"
        if node.op == "mul" and node.args[0] is node.args[1]:  # (x * x: one term, twice)
            # (the squares of a sum of squares share one adjoint: it is doubled once for all of them)
            fields["a"] = f"d{adjoint_name}"
            if fields["a"] not in doubled:
                doubled.add(fields["a"])
                lines.append(f"    d{adjoint_name} = {name(2.0)} * {adjoint_name}")
            rules = ((1, "{a} * {0}"), None)
        if node.op in _ONCE:
            lines.append(f"    r{node.index} = " + _ONCE[node.op].format(*args, **fields))
        for arg, rule in zip(node.args, rules):
            if rule is not None and isinstance(arg, Node) and needed[arg.index]:
                if "{n}" in rule[1]:  # (the negated condition: once, where a side reads it)
                    fields["n"] = f"n{condition.index}"
                    if condition.index not in negated:
                        negated.add(condition.index)
                        lines.append(f"    n{condition.index} = ~{args[0]}")
                contribute(arg.index, sign * rule[0], rule[1].format(*args, **fields))
    results = []
    for i in range(n_inputs):
        result, sign = adjoint.get(i, (name(0.0), 1))
        results.append(result if sign > 0 else f"-{result}")
    lines.append("    return [" + ", ".join(results) + "]")
    return lines


def _generate(formula, n_inputs: int, static: dict, dtype) -> Generated:
    name = _Names(dtype)
    graph = _Graph()
    inputs = [Node(graph, "input") for _ in range(n_inputs)]
    parameters = tuple(sorted(k for k, v in static.items() if type(v) is float))
    options = dict(static, **{k: Node(graph, "parameter") for k in parameters})
    outputs = formula(_Trace(), *inputs, **options)
    nodes = graph.nodes
    arguments = [f"v{i}" for i in range(n_inputs + len(parameters))]
    # the steps the outputs need (all that the backward reads are among them)
    used = [False] * len(nodes)
    for o in outputs:
        if isinstance(o, Node):
            used[o.index] = True
    for node in reversed(nodes):
        if used[node.index]:
            for arg in node.args:
                if isinstance(arg, Node):
                    used[arg.index] = True
    backward = _backward_lines(nodes, outputs, n_inputs, name, used)
    steps = [node for node in nodes[len(arguments):] if used[node.index]]
    read = set(map(int, re.findall(r"\bv(\d+)\b", "\n".join(backward))))
    saved = [f"v{node.index}" for node in steps if node.index in read]
    body = [f"    v{node.index} = " + _FORWARD[node.op].format(*map(name, node.args)) for node in steps]
    results = f"({''.join(name(o) + ', ' for o in outputs)})"
    forward = [f"def forward({', '.join(arguments)}):", *body, f"    return {results}, ({''.join(s + ', ' for s in saved)})"]
    evaluate = [f"def evaluate({', '.join(arguments)}):", *body, f"    return {results}"]
    gradients = [f"g{k}" for k in range(len(outputs))]
    functions = [forward, evaluate, [f"def backward({', '.join(arguments + saved + gradients)}):"] + backward]
    if dtype is not None:
        functions = list(map(_free_after_last_use, functions))
    scope = dict(FLOAT_FUNCTIONS if dtype is None else ARRAY_FUNCTIONS, inf=math.inf, nan=math.nan, **name.scope)
    title = f"<torchquat: {formula.__name__}{'' if dtype is None else ' on ' + str(dtype)}>"
    exec(compile("\n\n".join("\n".join(f) for f in functions), title, "exec"), scope)
    return Generated(scope["forward"], scope["evaluate"], scope["backward"], parameters)


_VALUE = re.compile(r"\b(?:[varn]|d[ag])\d+\b")


def _free_after_last_use(lines: List[str]) -> List[str]:
    """``del`` each value the function made after the line that reads it last, unless it is
    returned: NumPy then reuses its memory for the next step while it is still in cache (a
    formula's 40-60 live columns of 1,000 rows would not stay there; 10-20% of a step's time)."""
    arguments = set(_VALUE.findall(lines[0]))
    last: Dict[str, int] = {}
    for k, line in enumerate(lines[1:-1], 1):
        for value in _VALUE.findall(line.split("=", 1)[1]):
            last[value] = k
    for value in _VALUE.findall(lines[-1]):
        last.pop(value, None)
    out = [lines[0]]
    for k, line in enumerate(lines[1:-1], 1):
        out.append(line)
        dead = sorted({v for v in _VALUE.findall(line.split("=", 1)[1]) if last.get(v) == k and v not in arguments})
        if dead:
            out.append("    del " + ", ".join(dead))
    return out + lines[-1:]


def generated(formula, n_inputs: int, static: dict, dtype=None) -> Tuple[Generated, list]:
    """The generated functions of ``formula`` (on floats or, given a NumPy ``dtype``, on NumPy
    columns of it) and the values of their parameters in ``static``; generated once per formula,
    dtype and constants."""
    key = (formula, n_inputs, dtype, *[(k, v) for k, v in static.items() if type(v) is not float]) if static \
        else (formula, n_inputs, dtype)
    code = _CACHE.get(key)
    if code is None:
        code = _CACHE[key] = _generate(formula, n_inputs, static, dtype)
    return code, [static[k] for k in code.parameters] if code.parameters else ()
