"""Small numerical helpers shared by the conversion modules."""

import contextlib
import math
import sys

import torch
from torch import Tensor

from ._closed_form import _transformed


def safe_sqrt(x2: Tensor) -> Tensor:
    """``sqrt(x2)`` whose gradient is 0 (not NaN or inf) where ``x2 == 0``; NaN stays NaN.

    The kink of a norm at zero has no derivative; a zero subgradient keeps training finite.
    The discarded branch is fed 1 so autograd never evaluates ``1 / sqrt(0)`` (kornia's pattern).
    """
    zero = x2 == 0
    return torch.where(zero, 0.0, torch.sqrt(torch.where(zero, 1.0, x2)))


def norm_twice_differentiable(x: Tensor) -> Tensor:
    """``vector_norm(x, dim=-1)``, the same numbers bit for bit, with derivatives of every order 0
    where ``x`` is 0 (``vector_norm``'s gradient there is 0, its second derivative NaN): for plain
    forwards that double backward and ``torch.func`` differentiate. The zero rows' norm is taken
    of ones and discarded, so nothing evaluates ``0 / 0``."""
    zero = (x == 0).all(-1, keepdim=True)
    norm = torch.linalg.vector_norm(torch.where(zero, 1.0, x), dim=-1, keepdim=True)
    return torch.where(zero, 0.0, norm).squeeze(-1)


def sum_of_squares(columns) -> Tensor:
    """``sum(c * c for c in columns)``, in one pass per column."""
    total = columns[0] * columns[0]
    for c in columns[1:]:
        total = torch.addcmul(total, c, c)
    return total


def sum_of_products(a, b) -> Tensor:
    """``sum(x * y for x, y in zip(a, b))``, in one pass per pair of columns."""
    total = a[0] * b[0]
    for x, y in zip(a[1:], b[1:]):
        total = torch.addcmul(total, x, y)
    return total


def zero_to_inf(x: Tensor) -> Tensor:
    """``x`` with its zeros replaced by ``inf``: ``v / zero_to_inf(|v|)`` is the unit vector of ``v``,
    and 0 (as ``vector_norm``'s gradient) where the norm is 0, also where it underflowed to 0 for a
    non-zero ``v`` (a clamp to the smallest float would give a huge vector there)."""
    return torch.where(x > constant("zero", 0.0, x), x, constant("inf", math.inf, x))


def small_angle_threshold(dtype: torch.dtype) -> float:
    """Squared angle below which Taylor series replace ``sin(t)/t`` and friends: ``sqrt(eps)``.

    The series kept (to ``t^4``) are exact to rounding there, and above it the closed forms have
    no cancellation worse than ``eps / t``, so both values and gradients stay accurate.
    """
    return torch.finfo(dtype).eps ** 0.5


SMALL_BATCH_ROWS = 4096
"""Batches up to this many rows take the few-operation paths (constant tables and small matmuls),
where per-operation dispatch dominates; larger ones take elementwise paths that make fewer passes
over memory. Both give the same results to rounding; the tests run both."""

GPU_SMALL_BATCH_ROWS = 1 << 20
"""The same bound off the CPU (on a GPU), where eager time follows the number of kernel launches
rather than passes over memory: about 10 us of host time per operation on an H100, so a call on
1e6 rows costs about what it costs on one. There the few-operation paths win up to much larger
batches; each kernel sets a ``gpu_share`` of this bound at its crossover measured on an H100
(``docs/bench_profile.md``, "On a GPU"): 1/4 where the tables' wider rows cost more from about
1e6 rows (Euler -> quat, Euler -> matrix, matrix -> quat's looked-up Jacobians), 4 where they
still won at 4e6 rows."""

PLANAR_ROWS = 32768
"""Eager CPU batches from ``share *`` this many rows work on contiguous columns
(``torchquat._planes``), each kernel with the share of its measured crossover (forward+backward):
1/32 (1,024 rows: every large batch) for matrix -> Euler, 1/4 (8,192 rows) for quat -> matrix,
the product, rotating vectors, 6D and the matrix distance, 1/2 for matrix -> quat and the
quaternion distance, 1 for Euler -> quat and axis-angle -> quat, 2 for quat -> Euler. Below,
strided columns still sit in cache and the transposing matmuls and their backward nodes cost
more than they save."""

BLOCK_ROWS = 65536
"""Eager CPU batches of at least ``BLOCK_MIN_BLOCKS`` times this many rows, with nothing to
differentiate, run block by block (:func:`torchquat._dispatch.kernel`'s ``blocked_row_dims``):
a large-batch kernel makes 15 to 45 passes over columns of its batch, and a block's columns
(256 KB in float32) stay in the CPU's cache between passes where 1e6 rows' (4 MB each) go to
memory; each block's final transposing matmul writes its slice of the output in place
(:func:`torchquat._planes.lend`). Measured at 1e6 rows: 1.06-1.42x faster in float32,
1.05-1.53x in float64, and the temporaries a block's, not the batch's (peak memory 5 MB instead
of 76 for the matrix distance; ``docs/bench_profile.md``, "Blocks of rows"). Not below quat -> Euler's
planar bound (2 x ``PLANAR_ROWS``), so that a block takes the whole batch's path."""

BLOCK_MIN_BLOCKS = 8
"""Blocking starts at this many blocks (524,288 rows on one thread): at 540,000 rows every kernel
gains or breaks even (0.98-1.36x); at 270,000 some lose up to 15%."""


def block_rows() -> int:
    """The rows of a block: ``BLOCK_ROWS`` per intra-op thread. ATen splits an elementwise operation
    into chunks of at least 32,768 elements, one per thread; so a block of ``BLOCK_ROWS`` times
    the thread count keeps every operation as parallel as on the whole batch, and each thread's
    share of a column (the working set of its core) at ``BLOCK_ROWS`` rows. (On many cores the
    whole batch's shares are already that small below ``BLOCK_MIN_BLOCKS`` blocks.)"""
    return BLOCK_ROWS * torch.get_num_threads()


HALF_IDENTITY = {k: tuple(tuple(0.5 * float(i == j) for j in range(k)) for i in range(k)) for k in (3, 4)}
"""``I / 2`` tables: half angles (and the chain rule's 1/2) folded into a transposing matmul."""


def matmul_rounds(x: Tensor) -> bool:
    """Whether a float32 matmul on ``x``'s device may round its inputs: on CUDA when the user
    allows TF32 (``torch.backends.cuda.matmul.allow_tf32``, or a float32 matmul precision other
    than "highest"), whose 10-bit mantissa would make a table contraction good to 1e-3 only.
    (CPU matmuls of these shapes stay float32 under the CPU's bf16/tf32 settings: tested.)"""
    return x.is_cuda and x.dtype == torch.float32 and (
        torch.backends.cuda.matmul.allow_tf32 or torch.get_float32_matmul_precision() != "highest")


def is_small(x: Tensor, row_numel: int, share: float = 1.0, gpu_share: float = 1.0) -> bool:
    """Whether ``x`` (rows of ``row_numel`` numbers) is a small batch (a shape and device test, not
    data): at most ``share * SMALL_BATCH_ROWS`` rows on the CPU, ``gpu_share * GPU_SMALL_BATCH_ROWS``
    elsewhere (kernels whose table path costs more per row set smaller shares, at their measured
    crossovers).

    Inside a ``torch.compile`` trace the answer is no: inductor fuses elementwise code into one
    loop, and a matmul would split it. Where a matmul would round (:func:`matmul_rounds`) it is no
    too: the large-batch paths are written without matmuls.
    """
    rows = SMALL_BATCH_ROWS * share if x.is_cpu else GPU_SMALL_BATCH_ROWS * gpu_share  # (is_cpu: 0.05 us, device.type: 0.3)
    # (is_compiling first: a size test on a symbolic batch would guard the user's graph on it, one
    # recompile per crossover, and make torch.export refuse a dynamic batch dimension)
    return not torch.compiler.is_compiling() and x.numel() <= rows * row_numel and not matmul_rounds(x)


def matmul3(a: Tensor, b: Tensor) -> Tensor:
    """``a @ b`` for batches of 3 x 3 matrices, as a broadcast product and sum where a matmul
    would round (:func:`matmul_rounds`)."""
    if matmul_rounds(a):
        return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)
    return a @ b


_CONSTANTS = {}


# float32's sign bit and the rest, as int32 masks
_SIGN_BIT, _MAGNITUDE_BITS = -0x80000000, 0x7FFFFFFF


def _bitwise_signs(*tensors: Tensor) -> bool:
    """Whether a trace may take the sign bits of ``tensors`` as integers: ``torch.compile`` tracing
    float32 CPU tensors that record no gradient. Inductor's CPU loops call SLEEF's ``copysign`` out of
    line (``Sleef_copysignf8``), and every vector register live in the loop is spilled around that call;
    integer masks stay in registers. In one process at 1e6 rows: Euler ZYX -> quat 0.77x the time,
    axis-angle -> quat 0.78x, quat -> Euler ZYX 0.85x (``docs/bench_profile.md``, "copysign")."""
    return (torch.compiler.is_compiling() and all(t.dtype == torch.float32 and t.is_cpu for t in tensors)
            and not (torch.is_grad_enabled() and any(t.requires_grad for t in tensors)))


def copysign(magnitude: Tensor, sign: Tensor) -> Tensor:
    """``torch.copysign(magnitude, sign)``, the same bits; by integer masks where
    :func:`_bitwise_signs` allows (NaN's sign bit too, as ``torch.copysign``)."""
    if _bitwise_signs(magnitude, sign):
        bits = (magnitude.view(torch.int32) & _MAGNITUDE_BITS) | (sign.view(torch.int32) & _SIGN_BIT)
        return bits.view(torch.float32)
    return torch.copysign(magnitude, sign)


def sign_bit(x: Tensor) -> Tensor:
    """``torch.signbit(x)`` (``-0.0`` and negative NaNs included), as a vectorised loop: inductor's CPU
    code has no vector ``signbit``; the int32 view's sign where :func:`_bitwise_signs` allows, else
    ``copysign(1, x) < 0``."""
    if _bitwise_signs(x):
        return x.view(torch.int32) < 0
    return torch.copysign(torch.ones_like(x), x) < 0


def constant(name: str, values, like: Tensor, dtype=None) -> Tensor:
    """A constant table in ``like``'s dtype (or ``dtype``) and device, built once per (dtype, device).

    Inside a ``torch.compile`` trace it is built inline (it becomes a graph constant) rather than
    taken from the cache, so tracing has no side effects.
    """
    dtype = like.dtype if dtype is None else dtype
    if torch.compiler.is_compiling():
        return torch.tensor(values, dtype=dtype, device=like.device)
    key = (name, dtype) if like.is_cpu else (name, dtype, like.device)  # (reading .device costs 0.2 us)
    table = _CONSTANTS.get(key)
    if table is None:
        if _transformed():  # (a factory call under torch.func can return a wrapped tensor: not cached)
            return torch.tensor(values, dtype=dtype, device=like.device)
        with torch.inference_mode(False):  # (an inference tensor cached would break later training)
            table = _CONSTANTS[key] = torch.tensor(values, dtype=dtype, device=like.device)
    return table


# Inside a torch.compile trace, dynamo turns every float it reads out of a module-level table
# into an input of the graph (``specialize_float`` is off by default): boxed in a tensor on every
# call (108 of them for matrix -> quat on a GPU: 0.46-1.05 ms of host time beside a 39-47 us kernel;
# 34 us of 70 at one rotation on a CPU) and a variable, not a literal, in the fused loop. A table
# reached through :func:`literal` is a compile-time constant instead.
_LITERALS = {}


def _reachable_tables():
    """Every tuple, list and dict reachable from torchquat's module-level names, by ``id``."""
    found = {}
    pending = [value for module_name, module in list(sys.modules.items())
               if module_name == "torchquat" or module_name.startswith("torchquat.")
               for name, value in vars(module).items() if not name.startswith("__")]  # (not __builtins__)
    while pending:
        value = pending.pop()
        if isinstance(value, (tuple, list, dict)) and id(value) not in found:
            found[id(value)] = value
            pending.extend(value.values() if isinstance(value, dict) else value)
    return found


def _assume_constant_result(fn):
    decorate = getattr(torch.compiler, "assume_constant_result", None)  # (torch 2.2 and later)
    return fn if decorate is None else decorate(fn)


def _frozen(value):
    """A copy of ``value`` in new tuples: dynamo tracks a list it has already met by identity
    (and would give back the variable with its source), a new tuple it does not."""
    if isinstance(value, (tuple, list)):
        return tuple(_frozen(v) for v in value)
    return value


@_assume_constant_result
def _literal_by_id(key: int):
    """A copy of the table whose ``id`` is ``key``, made by dynamo's call at trace time (never
    traced): a constant of the graph, with no source to guard or lift."""
    if key not in _LITERALS:
        _LITERALS.update(_reachable_tables())
    return _frozen(_LITERALS[key]) if key in _LITERALS else None


# Whether dynamo traces literal(): id() of a tuple traces in torch 2.13, not in 2.11. None until
# the compiled kernels' dispatcher asks (literals_trace()); literal() is the identity until then.
LITERALS_TRACE = None


@_assume_constant_result
def _literals_on() -> bool:
    """``LITERALS_TRACE``, read by a trace without a guard on it (a guard would recompile a user's
    own compiled code once when the probe switches literals on)."""
    return bool(LITERALS_TRACE)


def literal(table):
    """``table`` (a module-level tuple or list of numbers, or one inside a module-level
    container, or one passed to :func:`register_literal`), read as a compile-time constant inside a
    ``torch.compile`` trace: its numbers become literals of the fused loop rather than inputs
    that every call boxes in tensors. Eager, or where dynamo cannot trace it: ``table`` itself.
    (Not on a table that is already a literal's: dynamo cannot take the id of a constant.)"""
    if torch.compiler.is_compiling() and isinstance(table, (tuple, list)) and _literals_on():
        found = _literal_by_id(id(table))
        return table if found is None else found
    return table


def register_literal(value):
    """Make ``value`` (a tuple that lives as long as the code that reads it, such as a
    compiled kernel's static options) one that :func:`literal` finds; returns it."""
    _LITERALS[id(value)] = value
    return value


def literals_trace() -> bool:
    """Whether :func:`literal` works inside this torch's traces, found by tracing a probe (with
    dynamo's plain "eager" backend: no code is generated) and kept in ``LITERALS_TRACE``: True once
    it works, False once dynamo refuses it; a probe that a user's setting stopped (dynamo disabled)
    is tried again with the next compiled kernel."""
    global LITERALS_TRACE
    if LITERALS_TRACE is None:
        probe = register_literal((0.5, (2.0,)))
        inputs = []

        def graph_inputs(gm, example_inputs):
            inputs.extend(node for node in gm.graph.nodes if node.op == "placeholder")
            return gm.forward

        def read_probe(x):  # (literal()'s lookup itself: LITERALS_TRACE stays None meanwhile)
            table = _literal_by_id(id(probe))
            return x * table[0] + table[1][0]

        stance = getattr(torch.compiler, "set_stance", None)  # (a user's "force_eager" would skip the trace)
        try:
            with stance("default") if stance is not None else contextlib.nullcontext():
                out = torch.compile(read_probe, backend=graph_inputs, fullgraph=True, dynamic=False)(
                    torch.ones(2, device="cpu"))
            if torch.equal(out, torch.full((2,), 2.5)) and len(inputs) == 1:  # (x alone: no number lifted)
                LITERALS_TRACE = True
        except Exception as error:
            if "Unsupported" in type(error).__name__:  # (torch 2.11: id() of a tuple)
                LITERALS_TRACE = False
    return bool(LITERALS_TRACE)


def sparse_columns(table, offset=None):
    """Each column of ``table`` (a matrix, or a vector: one column) as its non-zero
    ``(row, coefficient)`` terms and its offset, for :func:`combine`."""
    table, offset = literal(table), literal(offset)
    if not isinstance(table[0], (list, tuple)):
        table = [[v] for v in table]
    return tuple((tuple((r, row[k]) for r, row in enumerate(table) if row[k] != 0), offset[k] if offset else 0.0)
                 for k in range(len(table[0])))


def combine(columns, terms, out=None):
    """``sum_r k_r * columns[r] + offset`` for one :func:`sparse_columns` entry, with the
    coefficients as Python numbers (literals in a compiled graph). ``out``: a tensor the last pass
    writes into (eager, nothing recording a graph)."""
    last = len(terms[0]) - (0 if terms[1] else 1)  # (the index of the last pass)
    if terms[0]:
        (first, k), rest = terms[0][0], terms[0][1:]
        if k == 1:
            total = columns[first] if last else (columns[first] if out is None else out.copy_(columns[first]))
        else:
            total = torch.mul(columns[first], k, out=None if last else out)
        for n, (r, k) in enumerate(rest, 1):  # one pass per term: add and sub take the coefficient as alpha
            target = out if n == last else None
            total = (torch.sub(total, columns[r], alpha=-k, out=target) if k < 0
                     else torch.add(total, columns[r], alpha=k, out=target))
    else:
        total = torch.zeros_like(columns[0]) if out is None else out.zero_()
    return torch.add(total, terms[1], out=out) if terms[1] else total


def bilinear_terms(table, n_b: int):
    """The non-zero ``(i, j, T[i * n_b + j])`` of each column of ``table``, a positive one first
    (built once, for :func:`bilinear`)."""
    return tuple(tuple((r // n_b, r % n_b, k) for r, k in sorted(terms, key=lambda term: -term[1]))
                 for terms, _ in sparse_columns(table))


def bilinear(a, b, terms, out=None):
    """``sum_ij T[i * len(b) + j] a_i b_j`` for each column of a table given as its
    :func:`bilinear_terms`, from the columns ``a`` and ``b``: one product and one ``addcmul`` per
    term, each a single pass. ``out``: optional planes (a ``torchquat._planes.plane_buffer``,
    returned filled; or a sequence of planes and ``None``) that each column's last pass writes into."""
    results = []
    for c, ((i, j, k), *rest) in enumerate(literal(terms)):
        target = None if out is None else out[c]
        if not rest:
            total = torch.mul(a[i], b[j], out=target) if k == 1 else torch.mul(a[i] * b[j], k, out=target)
        else:
            total = a[i] * b[j]
            total = total if k == 1 else total * k
            for n, (i, j, k) in enumerate(rest, 1):
                total = torch.addcmul(total, a[i], b[j], value=k, out=target if n == len(rest) else None)
        results.append(total)
    return out if isinstance(out, Tensor) else results  # (a filled buffer goes to rows() as it is)


OUTER_PRODUCT_MATMUL_ROWS = 256
"""From this many rows :func:`outer_product` spreads its factors by matmuls (measured crossover)."""
# (4, 16) 0/1 tables: row i of the first repeats a_i four times, of the second tiles b
_OUTER_SELECT = tuple(tuple(tuple(float((j // 4 if side == 0 else j % 4) == i) for j in range(16)) for i in range(4))
                      for side in (0, 1))


def outer_product(a: Tensor, b: Tensor) -> Tensor:
    """``(a_i b_j)`` flattened, ``(..., 4), (..., 4) -> (..., 16)``: a broadcast product for a few
    rows; from 256 rows each factor is spread by a 0/1 matmul first (exact for finite numbers:
    ``x * 1 + 0 * y``), then one contiguous product instead of a broadcast over dimensions of 4
    (1.6 ns an entry: 35 us against 18 us at 1,000 rows, 127 against 43 at 4,096)."""
    if torch.compiler.is_compiling() or a.numel() < OUTER_PRODUCT_MATMUL_ROWS * 4 or matmul_rounds(a):
        return (a.unsqueeze(-1) * b.unsqueeze(-2)).flatten(-2)
    return (a @ constant("outer_select_a", _OUTER_SELECT[0], a)) * (b @ constant("outer_select_b", _OUTER_SELECT[1], b))


def contract(x: Tensor, name: str, values) -> Tensor:
    """``x @ table`` for a small constant ``table`` (a vector or a matrix of a few columns).

    Eager: one matmul, the fewest dispatches. Under ``torch.compile``: the same sums written
    column by column with the table's numbers as literals, which inductor fuses with their
    neighbours into one vectorised loop (a broadcast product and reduction over a dimension of
    size 4 would use a quarter of the vector lanes, and a table buffer is re-read every call).
    Where a matmul would round (:func:`matmul_rounds`): the same sums, eagerly.
    """
    if torch.compiler.is_compiling() or matmul_rounds(x):
        columns = x.unbind(-1)
        out = [combine(columns, terms) for terms in sparse_columns(values)]
        return out[0] if not isinstance(values[0], (list, tuple)) else torch.stack(out, dim=-1)
    return x @ constant(name, values, x)
