"""Optional ``torch.compile``'d kernels, switched on with :func:`use_compiled_kernels`.

Eager PyTorch pays one pass over memory and one dispatch per elementwise operation; a rotation
conversion is 20 to 40 of them. Inductor fuses each kernel into a single loop that runs at the
memory floor for large batches; a compiled call's fixed cost (about 30 us on a CPU) makes most
kernels slower than eager for small ones, which then run eagerly (``compiled_from_rows``). The price
is a compile of a few seconds per kernel on first use (cached on disk by inductor), and a C++
compiler at run time, so the path is opt-in. The eager code is the same source: inside a user's
own ``torch.compile`` region, under ``torch.func`` transforms, or when switched off, the eager
kernel runs and is traced as usual.

Eager, the same dispatcher runs large CPU batches with nothing to differentiate block by block,
so that each pass over a block's columns stays in cache (``_blocked``). A compiled backward is
first-order: a second derivative through it raises (``_first_order``).
"""

import functools
import os
import types
from typing import Callable, Dict, Optional, Tuple

import torch
from torch import Tensor

from . import _blocked, _closed_form, _first_order, _math, _one_row, _polynomials, _row_stores

__all__ = ["use_compiled_kernels", "compiled_kernels_enabled", "kernel"]

_enabled = os.environ.get("TORCHQUAT_COMPILE", "0").lower() in ("1", "true", "yes", "on")
_compiled: Dict[Tuple, Callable] = {}
_past_limit = set()  # compiled functions that reached dynamo's recompile limit
_set_stance = getattr(torch.compiler, "set_stance", None)  # (torch 2.6 and later)
_backend = "inductor"  # tests swap in "eager" to check tracing and caching without compiling C++
# one flag read instead of a device lookup and a per-device query (0.5 us a call at one rotation)
_any_autocast = _closed_form._any_autocast
_is_compiling = torch.compiler.is_compiling  # (one lookup a call fewer: 0.03 us on every kernel call)


def use_compiled_kernels(enabled: bool = True) -> None:
    """Route every conversion through ``torch.compile``'d kernels (or back to eager).

    Also set by the environment variable ``TORCHQUAT_COMPILE=1``. Results are the same to
    rounding; gradients are first-order only on this path: a second derivative through a
    compiled kernel raises (double backward and Hessians need eager; torch.func runs eager).

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
    """Whether :func:`use_compiled_kernels` is on."""
    return _enabled


def _fresh_copy(fn: Callable, tag: int) -> Callable:
    """``fn`` with a code object of its own: dynamo keeps compiled graphs (and its limit of 8
    recompiles) per code object, so each kernel and static combination (24 Euler conventions,
    say) gets its own."""
    code = fn.__code__.replace(co_name=f"{fn.__name__}_{tag}")
    copy = types.FunctionType(code, fn.__globals__, code.co_name, fn.__defaults__, fn.__closure__)
    copy.__kwdefaults__ = fn.__kwdefaults__
    return copy


# Inductor inlines a pointwise value into each of its readers unless it holds more operations than
# this (default 50 on the CPU): the polynomial atan2's ~30 operations, read by several others in the
# Euler kernels, made their compile 5-17x longer (m2e: 5 -> 65-89 s); with 20, 2x; with 10 (session
# 23, Estrin's form) 1.0-1.6x, at the same speed. The polynomial cos and sin (~15 operations each, read
# by the products of Euler -> quat) took E -> q's compile from 3.3 to 23.5 s (uncached), 8.3 s with
# 20, 5.9 s with 10 (E -> R 5.7 -> 8.0 s), at the same speed.
_POLYNOMIAL_OPTIONS = {"realize_cpu_opcount_threshold": 10}
# With multiply-adds contracted into fma (inductor's CPU default is off, to match eager's roundings
# bit for bit, which these polynomial graphs do not anyway) the polynomials' chains of a * b + c take
# one instruction a link: 0.89-0.98x the time at 1e6 rows (medians of 20 in-process rounds; quat ->
# Euler ZYX 0.89x, the distances 0.94-0.95x), every accuracy test holding. The exact zeros the kernels
# promise do not rest on rounding (the distances' differences are exactly 0 for equal inputs). Older
# torch has no such option: it compiles these graphs without it.
_CONTRACT_OPTION = ("cpp.enable_floating_point_contract_flag", "fast")


def _polynomial_options() -> dict:
    import torch._inductor.config as inductor_config  # (loaded by then: this is a compile)
    name, value = _CONTRACT_OPTION
    options = dict(_POLYNOMIAL_OPTIONS)
    if hasattr(inductor_config.cpp, name.split(".", 1)[1]):
        options[name] = value
    return options


# Kernels whose compiled CPU loops run faster on 256-bit vectors than on the 512-bit ones inductor
# picks where the CPU has them (kernel(vector_bits=256)): measured on an AMD EPYC (Zen 4, which
# splits each 512-bit operation in two), in-process A/B at 1e6 float32 rows, 20 rounds, forward /
# with the backward: matrix -> Euler 0.74-0.79x / 0.94-0.98x, matrix -> quat 0.86x / 0.94x, 6D ->
# matrix 0.92x / 0.88x, the product 0.85x / 0.90x. The others lose on 256 bits (Euler -> quat
# 1.16x / 1.46x, quat -> Euler 1.18x / 1.30x), the distances and quat -> matrix are even. Not
# measured on a CPU with full 512-bit units (an Intel Xeon).
_VECTOR_BITS: Dict[Callable, int] = {}


def _widest_cpu_vectors() -> int:
    """The bit width of the vectors inductor's C++ code would use on this CPU (0 if unknown)."""
    try:
        from torch._inductor.cpu_vec_isa import pick_vec_isa
        return pick_vec_isa().bit_width()
    except Exception:  # (an older or newer torch without it: inductor's own choice stands)
        return 0


def _compiled_for(fn: Callable, static: Tuple, context: Tuple = (), polynomial: bool = False) -> Callable:
    """The compiled ``fn`` for its static options (sorted ``(name, value)`` pairs) and the call's
    ``context`` (grad, inference mode, dtype, and for some kernels whether cos and sin are
    polynomial): one compiled function for each. ``polynomial``: a kernel whose float32 graphs
    without a gradient take a polynomial of ``_polynomials`` (``atan2``, or cos and sin)."""
    key = (fn, static, context)
    compiled = _compiled.get(key)
    if compiled is None:
        options, numbers = dict(static), ()
        if _math.literals_trace():  # (once: it also switches the tables' literals on; see _math.literal)
            # a float option (an eps) is then a literal of the graph, not an input boxed in a tensor every call
            options = {name: value for name, value in static if type(value) is not float}
            numbers = _math.register_literal(tuple((name, value) for name, value in static if type(value) is float))

        def bound(*tensors):
            return fn(*tensors, **options, **dict(_math.literal(numbers)))

        # not functools.partial: torch.compile wraps those in one shared frame
        # Inductor's CPU tiling heuristic drops to scalar code (std::atan2 per element, 10-25x
        # slower) when many loads are strided, as the columns of an (N, 4) input are.
        inductor_options = None
        if _backend == "inductor":
            inductor_options = {"cpp.enable_tiling_heuristics": False}
            try:  # training graphs: see _partition.NoSavedMasks (inductor's option is recent)
                from ._partition import NoSavedMasks
                inductor_options["custom_partitioner_fn"] = NoSavedMasks()
            except ImportError:
                pass
            if polynomial and not context[0] and context[2] == torch.float32:
                inductor_options.update(_polynomial_options())
            bits = _VECTOR_BITS.get(fn)
            if bits is not None and _widest_cpu_vectors() > bits:  # (never narrower than the CPU's own)
                inductor_options["cpp.simdlen"] = bits
            inductor_options.update(_row_stores.options())
        compiled = _compiled[key] = torch.compile(_fresh_copy(bound, len(_compiled)), dynamic=True, fullgraph=True,
                                                     backend=_backend, options=inductor_options)
    return compiled


# Kernels made of two others through the quaternion (Euler and axis-angle -> matrix, matrix ->
# axis-angle) pass its four columns from one formula to the next in traces that record no
# gradient: inductor then writes one loop, where the stack between the two kernels is an (N, 4)
# buffer that one loop writes (four strided columns) and a second reads back (0.84-0.90x the time at
# 1e6 rows on an AMD EPYC with AVX-512, session 30; False: two loops, for an A/B in one process).
# Training traces keep the two kernels, each with its closed-form rule (_closed_form.traced_rule).
FUSED_COMPOSITES = True


def compiled_without_gradient(*inputs: Tensor) -> bool:
    """Whether a composite kernel on ``inputs`` passes the quaternion's columns on: in a
    ``torch.compile`` trace (the dispatcher's or a user's) where autograd records nothing for them.
    (The columns' formulas are the kernels' plain ones, differentiable: a transform that does
    differentiate such a trace gets autograd's gradients of the same function.)"""
    return (FUSED_COMPOSITES and torch.compiler.is_compiling()
            and not (torch.is_grad_enabled() and any(x.requires_grad for x in inputs)))


def _sincos_candidate(t: Tensor, context: Tuple) -> bool:
    """Whether a compiled call may take the polynomial cos and sin: float32 on the CPU, no gradient
    recorded, a non-empty first input (the polynomials are for the graphs inference takes)."""
    return not context[0] and context[2] == torch.float32 and t.is_cpu and t.numel() > 0


def _sincos_mode(largest: float, direct_bound: float) -> int:
    """Which cos and sin (``_polynomials.SINCOS_*``) a call whose first input's largest entry in
    magnitude is ``largest`` needs: the direct polynomials within ``direct_bound``, the reduced ones
    within ``_polynomials.POLYNOMIAL_SINCOS_RANGE``, else (or NaN: no comparison holds) torch's."""
    if not largest <= _polynomials.POLYNOMIAL_SINCOS_RANGE:
        return _polynomials.SINCOS_TORCH
    return _polynomials.SINCOS_DIRECT if largest <= direct_bound else _polynomials.SINCOS_REDUCED


def _largest_entry(x: Tensor) -> Tensor:
    """The largest ``|entry|`` of ``x`` (NaN if any is), a row's entries compared first: inductor
    then fuses the reduction into the kernel's own loop over rows (a reduction over the flat input
    is a second loop of its own, as costly as a separate ``aminmax``)."""
    columns = x.unbind(-1)
    largest = columns[0].abs()
    for column in columns[1:]:
        largest = torch.maximum(largest, column.abs())
    return largest.amax()


_with_largest_entries: Dict[Callable, Callable] = {}


def _with_largest_entry(fn: Callable) -> Callable:
    """``fn``, also returning its first input's :func:`_largest_entry` (one wrapper per kernel, so
    that its compiled functions are found again)."""
    checked = _with_largest_entries.get(fn)
    if checked is None:
        def checked(*tensors, **static):
            return fn(*tensors, **static), _largest_entry(tensors[0])

        checked = _with_largest_entries[fn] = functools.wraps(fn)(checked)
    return checked


# the cos and sin each polynomial kernel's last checked call needed, its next call's first guess
_sincos_guesses: Dict[Tuple, int] = {}


def _call_compiled(fn: Callable, static_items: Tuple, context: Tuple, tensors: Tuple[Tensor, ...],
                   polynomial_atan2: bool, sincos: int = _polynomials.SINCOS_TORCH):
    """The compiled ``fn``'s output for this call's ``context``, or ``None`` where it must run eagerly
    (past dynamo's recompile limit without ``torch.compiler.set_stance``)."""
    compiled = _compiled_for(fn, static_items, context, polynomial_atan2 or bool(sincos))
    if compiled in _past_limit:
        if _set_stance is None:
            return None
        # its graphs still serve the layouts they were made for; a new one runs eagerly at once (no
        # guard failure, recompile attempt and warning a call)
        with _set_stance("eager_on_recompile"):
            return compiled(*tensors)
    if polynomial_atan2:  # (read only if this call traces; other kernels leave it alone)
        _polynomials.KERNEL_CALL.polynomial_atan2 = True
    if sincos:
        _polynomials.KERNEL_CALL.polynomial_sincos = sincos
    try:
        return compiled(*tensors)
    except Exception as error:
        if type(error).__name__ != "FailOnRecompileLimitHit":
            raise
        _past_limit.add(compiled)
        return None
    finally:
        if polynomial_atan2:
            _polynomials.KERNEL_CALL.polynomial_atan2 = False
        if sincos:
            _polynomials.KERNEL_CALL.polynomial_sincos = _polynomials.SINCOS_TORCH


def _call_checking_sincos(fn: Callable, static_items: Tuple, context: Tuple, tensors: Tuple[Tensor, ...],
                          polynomial_atan2: bool, direct_bound: float):
    """A polynomial kernel's compiled call (float32 CPU, no gradient: :func:`_sincos_candidate`). The
    graph of the cos and sin this kernel's last call needed (at its first call, those an ``aminmax``
    of the input picks) runs and also returns the input's :func:`_largest_entry`, fused into its loop;
    where that entry needs other cos and sin (:func:`_sincos_mode`), their graph runs again on the
    input. So every output is the one its input's range calls for, and a call in the range of
    the last costs one loop: a separate ``aminmax`` first took 0.6-1.0 ms per 1e6 rows of 3, a fifth
    of Euler -> quat. ``None`` where it must run eagerly (as :func:`_call_compiled`)."""
    key = (fn, static_items)
    sincos = _sincos_guesses.get(key)
    if sincos is None:  # (a kernel's first call: no graph is compiled that its input does not need)
        low, high = torch.aminmax(tensors[0])
        sincos = _sincos_mode(float(torch.maximum(high, low.neg())), direct_bound)
    checked = _with_largest_entry(fn)
    for _ in range(2):  # (the second graph's answer is the first's: the same input's largest entry)
        result = _call_compiled(checked, static_items, context + (sincos,), tensors, polynomial_atan2, sincos)
        if result is None:
            return None
        output, largest = result
        needed = _sincos_mode(float(largest), direct_bound)
        if needed == sincos:
            break
        sincos = needed
    _sincos_guesses[key] = sincos
    return output


# Multiplies every kernel's ``compiled_from_rows`` (tests set 0 to compile every batch size).
COMPILED_FROM_SCALE = 1


def _small_cpu_batch(tensors: Tuple[Tensor, ...], row_dims: Tuple[int, ...], rows: int) -> bool:
    """Whether the inputs are CPU tensors of fewer than ``rows * COMPILED_FROM_SCALE`` rows each."""
    if not tensors[0].is_cpu:
        return False
    bound = rows * COMPILED_FROM_SCALE
    for t, r in zip(tensors, row_dims):
        if t.numel() >= bound and t.shape[:t.dim() - r].numel() >= bound:  # (numel first: 0.1 us)
            return False
    return True



def kernel(fn: Optional[Callable] = None, *, blocked_row_dims: Optional[Tuple[int, ...]] = None,
           compiled_from_rows: int = 0, polynomial_atan2: bool = False, polynomial_sincos: float = 0.0,
           one_row: Optional[_one_row.OneRow] = None, vector_bits: Optional[int] = None) -> Callable:
    """Mark an unchecked kernel ``fn(*tensors, **static_options)`` as compilable.

    Static options (an Euler convention, an ``eps``) are bound before compiling, so each
    combination gets its own graph and dynamo never guards on them.

    ``blocked_row_dims`` (each tensor's number of row dimensions: 1 for quaternions, 2 for
    matrices) marks a kernel whose large eager CPU batches run block by block when nothing is
    differentiated (see ``_math.BLOCK_ROWS``). Used as ``@kernel`` or ``@kernel(blocked_row_dims=...)``.

    ``compiled_from_rows`` (with ``blocked_row_dims``): with the compiled kernels on, CPU batches
    of fewer rows run eagerly, where a compiled call's fixed cost (dynamo's guards and wrappers,
    about 30 us) is more than eager code takes: the crossover measured on a CPU, forward and with
    the backward (``docs/bench_profile.md``, "Session 14"). Off the CPU every batch is compiled.

    ``polynomial_atan2``: the kernel's compiled float32 CPU graphs compute ``atan2`` by
    ``_polynomials.polynomial_atan2`` (compiled with the inductor option that keeps their compile
    time in bounds; with a gradient, with ``torch.atan2``'s derivative); nowhere else.

    ``polynomial_sincos`` (a bound in radians, 0 for none): the same for the half angles' cos and
    sin (``_polynomials.cos_sin_up_to_sign``, ``cos_sinc_of_squares``), in calls whose first input's
    entries all lie within ``_polynomials.POLYNOMIAL_SINCOS_RANGE``: the polynomials without a range
    reduction (``_polynomials.half_cos_sinc``) where they all lie within the bound, the reduced ones
    (``polynomial_cos_sin``) elsewhere; other calls take a graph of their own with ``torch.cos`` and
    ``torch.sin``. The graphs find the largest entry in their own loop and a call whose guess was
    wrong runs again (:func:`_call_checking_sincos`).

    ``one_row`` (a :class:`torchquat._one_row.OneRow`): the kernel's formulas in Python floats, which
    a call on one CPU row takes, with one autograd node of its own where a graph is recorded (see
    ``torchquat._one_row``). The kernel then also has ``at_one_row(*tensors, **static)``, the same
    for a public function's unvalidated arguments, or ``None``: validation's 3-5 us were a quarter
    to a third of a one-row call's time.

    ``vector_bits`` (256): the kernel's compiled CPU graphs use vectors of at most that many bits
    where inductor would take wider ones (see ``_VECTOR_BITS``).
    """
    if fn is None:
        return functools.partial(kernel, blocked_row_dims=blocked_row_dims, compiled_from_rows=compiled_from_rows,
                                 polynomial_atan2=polynomial_atan2, polynomial_sincos=polynomial_sincos,
                                 one_row=one_row, vector_bits=vector_bits)
    if vector_bits is not None:
        _VECTOR_BITS[fn] = vector_bits

    @functools.wraps(fn)
    def dispatch(*tensors, **static):
        if one_row is not None:
            out = _one_row.run(one_row, fn, *tensors, **static)
            if out is not None:
                return out
        if _any_autocast() and torch.is_autocast_enabled(device := tensors[0].device.type):
            # Autocast would round the kernels' small matmuls to bfloat16/float16; rotations
            # are computed in the input's precision (float32 at least) and returned in it.
            with torch.autocast(device, enabled=False):
                return dispatch(*tensors, **static)
        if (_enabled and not _is_compiling() and not torch._C._are_functorch_transforms_active()
                and not (compiled_from_rows and _small_cpu_batch(tensors, blocked_row_dims, compiled_from_rows))):
            # Dynamo guards on grad and inference mode and the dtype, and keeps 8 graphs per
            # function: a training loop's train / eval / inference calls, each with a last
            # short batch or a sliced input, would run past them. So each of those gets a
            # compiled function of its own; and past the limit (a ninth layout in one of them)
            # the call runs eagerly instead of failing (fullgraph=True makes the limit an error).
            context = (torch.is_grad_enabled() and any(t.requires_grad for t in tensors),
                       torch.is_inference_mode_enabled(), tensors[0].dtype)
            static_items = tuple(sorted(static.items()))
            if polynomial_sincos and _sincos_candidate(tensors[0], context):
                output = _call_checking_sincos(fn, static_items, context, tensors, polynomial_atan2, polynomial_sincos)
            else:
                if polynomial_sincos:  # (a graph for each answer: the trace reads it as a constant)
                    context += (_polynomials.SINCOS_TORCH,)
                output = _call_compiled(fn, static_items, context, tensors, polynomial_atan2)
                if output is not None and context[0]:
                    output = _first_order.first_order_only(output, tensors)
            if output is not None:
                return output
        if (blocked_row_dims is not None and not _is_compiling()
                and (tensors[0].numel() >= _blocked.BLOCKED_FROM or tensors[-1].numel() >= _blocked.BLOCKED_FROM
                     or (len(tensors) > 2 and any(t.numel() >= _blocked.BLOCKED_FROM for t in tensors[1:-1])))
                and not torch._C._are_functorch_transforms_active()):
            out = _blocked.run_blocked(fn, tensors, blocked_row_dims, static)
            if out is not None:
                return out
        return fn(*tensors, **static)

    dispatch.eager = fn
    if one_row is not None:
        # A public function's first step, ``at_one_row(*tensors, **static)``: its arguments as
        # given, before validation, since run() accepts only what validation would pass unchanged
        # (plain CPU float32/float64 tensors of one row each, of the row's shape, of one dtype);
        # None for anything else (then the public function validates, with its errors, and calls
        # the kernel). (A partial: no Python frame of its own.)
        at_one_row = functools.partial(_one_row.run, one_row, fn)
        dispatch.at_one_row = at_one_row
    return dispatch
