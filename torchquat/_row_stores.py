"""Whole-row vector loads and stores in torchquat's compiled CPU loops.

Inductor's vectorised C++ loop (torch 2.13) reads a column of ``(N, C)`` rows with one scalar load
per row into a stack buffer, and writes each column of a ``stack(columns, -1)`` back with one
scalar store per row. On rows of 3, 4 or 9 floats those loads and stores, not the arithmetic,
bound the compiled kernels (``docs/bench_profile.md``, sessions 27 and 33). Here the same loop's
``C`` columns are moved as ``C`` whole vectors of rows, transposed in registers by shuffles
(``__builtin_shufflevector``): rows of 4 by two rounds of pairs, 8 shuffles for 4 vectors; other
widths by a chain of two-input shuffles per vector.

This module rewrites inductor's C++ source for torchquat's own graphs, and nothing else:

- it acts only while inductor compiles a graph whose options carry the marker of :func:`options`
  (the dispatcher passes them to every kernel's ``torch.compile``): a post-grad pass that does
  nothing, whose ``uuid`` puts this file's hash into inductor's cache key, so that a cached kernel
  is always the one this code writes, and a user's own compile is never touched;
- loads: the main vectorised body's gathered loads of all ``C`` entries of the same rows
  (``k + C*x + C*x_inner`` for each ``k < C``, a literal ``C``, the vector's full length), in one
  block, become ``C`` vector loads of those rows (the same bytes) and shuffles;
- stores: ``C`` consecutive scattered stores of one row's columns become shuffles and ``C`` vector
  stores, where a run-time check finds the ``C`` output pointers to be one row's consecutive
  entries (a ``stack`` passes each column as its own pointer into one buffer), and inductor's own
  stores where it does not;
- the tail of each loop (fewer rows than a vector) keeps inductor's code, and so does a compiler
  without ``__builtin_shufflevector`` (clang, GCC 12 and later; the preprocessor checks);
- x86-64 only (measured there).

So every value is inductor's, bit for bit; only how the memory is moved changes. ``ENABLED =
False``, before a kernel's first compile, turns the rewrite off.
"""

import functools
import platform
import re
from typing import Dict, List, Optional, Sequence, Tuple

ENABLED = True

# One scattered store of inductor's vectorised C++ loop (torch 2.13's CppVecKernel): the column's
# vector into a stack buffer, then a scalar store per row at a stride of C.
_STORE = re.compile(
    r"(?P<indent>[ \t]*)\[&\]\s*\{\s*"
    r"__at_align__ std::array<(?P<type>float|double), (?P<lanes>\d+)> tmpbuf;\s*"
    r"(?P<value>tmp\w+)\.store\(tmpbuf\.data\(\), static_cast<int64_t>\((?P=lanes)\)\);\s*"
    r"#pragma GCC unroll (?P=lanes)\s*"
    r"for \(long (?P<var>x\d+)_inner = 0; (?P=var)_inner < static_cast<int64_t>\((?P=lanes)\); (?P=var)_inner\+\+\)\s*"
    r"\{\s*"
    r"(?P<pointer>\w+)\[static_cast<int64_t>\((?:(?P<offset>\d+)L \+ )?(?P<stride>\d+)L\*(?P=var) \+ (?P=stride)L\*(?P=var)_inner\)\]"
    r" = tmpbuf\[(?P=var)_inner\];\s*"
    r"\}\s*\}\s*\(\)\s*;[ \t]*\n")

# One gathered load of the same loop: a scalar load per row at a stride of C into a stack buffer,
# then the column's vector from it.
_LOAD = re.compile(
    r"(?P<indent>[ \t]*)auto (?P<value>tmp\w+) =\s*\[&\]\s*\{\s*"
    r"__at_align__ std::array<(?P<type>float|double), (?P<lanes>\d+)> tmpbuf;\s*"
    r"#pragma GCC unroll (?P=lanes)\s*"
    r"for \(long (?P<var>x\d+)_inner = 0; (?P=var)_inner < static_cast<int64_t>\((?P=lanes)\); (?P=var)_inner\+\+\)\s*"
    r"\{\s*"
    r"tmpbuf\[(?P=var)_inner\] = (?P<pointer>in_ptr\d+)\[static_cast<int64_t>\((?:(?P<offset>\d+)L \+ )?(?P<stride>\d+)L\*(?P=var) \+ (?P=stride)L\*(?P=var)_inner\)\];\s*"
    r"\}\s*"
    r"return (?P<vector>at::vec::Vectorized<(?P=type)>|at::vec::VectorizedN<(?P=type),\d+>)::loadu"
    r"\(tmpbuf\.data\(\), static_cast<int64_t>\((?P=lanes)\)\);\s*"
    r"\}\s*\(\)\s*;[ \t]*\n")

_ROW_WIDTHS = (3, 4, 9)  # the row widths torchquat's kernels read and write
_SHUFFLES_AVAILABLE = "#if defined(__clang__) || (defined(__GNUC__) && __GNUC__ >= 12)"


class _Access:
    """One gathered load or scattered store of a column, as matched."""
    __slots__ = ("start", "end", "indent", "type", "lanes", "value", "var", "pointer", "offset", "stride", "text",
                 "vector")

    def __init__(self, match: "re.Match"):
        self.start, self.end = match.start(), match.end()
        self.indent = match.group("indent")
        self.type, self.lanes = match.group("type"), int(match.group("lanes"))
        self.value, self.var, self.pointer = match.group("value"), match.group("var"), match.group("pointer")
        self.offset, self.stride = int(match.group("offset") or 0), int(match.group("stride"))
        self.text = match.group(0)
        self.vector = match.groupdict().get("vector")  # (loads: the class they return)

    def shape(self) -> Tuple:
        return (self.type, self.lanes, self.var, self.stride)


def _store_groups(source: str) -> List[List[_Access]]:
    """The scattered stores of ``source`` in runs of consecutive ones of one shape (only blanks
    between them), each run cut into groups of one row's ``stride`` columns."""
    runs: List[List[_Access]] = []
    for match in _STORE.finditer(source):
        store = _Access(match)
        last = runs[-1][-1] if runs else None
        if last is not None and last.shape() == store.shape() and not source[last.end:store.start].strip():
            runs[-1].append(store)
        else:
            runs.append([store])
    groups = []
    for run in runs:
        width = run[0].stride
        if width not in _ROW_WIDTHS or len(run) % width:
            continue
        groups += [run[i:i + width] for i in range(0, len(run), width)]
    return groups


def _enclosing_block(source: str, position: int) -> int:
    """Where the innermost ``{`` block around ``position`` opens (-1 at the top level)."""
    depth = 0
    for i in range(position - 1, -1, -1):
        if source[i] == "}":
            depth += 1
        elif source[i] == "{":
            if depth == 0:
                return i
            depth -= 1
    return -1


def _load_groups(source: str) -> List[List[_Access]]:
    """The gathered loads of ``source`` that read all ``stride`` entries of the same rows in one
    block (each entry once), one group per such set, each sorted by entry."""
    sets: Dict[Tuple, List[_Access]] = {}
    for match in _LOAD.finditer(source):
        load = _Access(match)
        sets.setdefault((_enclosing_block(source, load.start), load.pointer, load.vector) + load.shape(), []).append(load)
    groups = []
    for loads in sets.values():
        width = loads[0].stride
        if width in _ROW_WIDTHS and sorted(load.offset for load in loads) == list(range(width)):
            groups.append(sorted(loads, key=lambda load: load.offset))
    return groups


def _chain(sources: Sequence[Tuple[int, int]], names: Sequence[str], lanes: int) -> str:
    """A C++ expression for one vector whose lane ``j`` is lane ``sources[j][1]`` of vector
    ``sources[j][0]`` (``names``): two-input ``__builtin_shufflevector``s, one per vector after the
    first two (so ``k`` vectors take ``k - 1``)."""
    order = []
    for vector, _ in sources:
        if vector not in order:
            order.append(vector)
    first = order[0]
    second = order[1] if len(order) > 1 else first
    indices = [lane if v == first else (lanes + lane if v == second else -1) for v, lane in sources]
    expression = f"__builtin_shufflevector({names[first]}, {names[second]}, {', '.join(map(str, indices))})"
    for step in range(2, len(order)):
        done = set(order[:step])
        indices = [j if v in done else (lanes + lane if v == order[step] else -1) for j, (v, lane) in enumerate(sources)]
        expression = f"__builtin_shufflevector({expression}, {names[order[step]]}, {', '.join(map(str, indices))})"
    return expression


def _rows_from_columns(width: int, lanes: int, columns: Sequence[str], rows: Sequence[str], prefix: str = "tq") -> List[str]:
    """C++ statements that set the vectors ``rows`` (``width`` of them, the flat row-major entries of
    ``lanes`` rows) from the vectors ``columns`` (one per entry of a row): a transpose in registers.
    Rows of 4 take two rounds of pairs (8 shuffles); other widths a chain per vector."""
    if width == 4 and lanes % 4 == 0:
        half, quarter = lanes // 2, lanes // 4
        pairs = [f"{prefix}_pair{k}" for k in range(4)]  # (c0, c1) and (c2, c3) of rows [0, L/2), [L/2, L)
        statements = []
        for k, (a, b, low) in enumerate([(0, 1, 0), (0, 1, half), (2, 3, 0), (2, 3, half)]):
            sources = [(0 if j % 2 == 0 else 1, low + j // 2) for j in range(lanes)]
            statements.append(f"auto {pairs[k]} = " + _chain(sources, [columns[a], columns[b]], lanes) + ";")
        for m in range(4):
            left, right = (0, 2) if m < 2 else (1, 3)
            first_row = (m % 2) * quarter  # within the half
            sources = [(0 if j % 4 < 2 else 1, 2 * (first_row + j // 4) + j % 2) for j in range(lanes)]
            statements.append(f"auto {rows[m]} = " + _chain(sources, [pairs[left], pairs[right]], lanes) + ";")
        return statements
    if width == 9 and lanes >= 8:  # through the nine strides of 3 of each three vectors' 3 * lanes entries (2 shuffles each)
        streams = {(g, r): f"{prefix}_stream{g}{r}" for g in range(3) for r in range(3)}
        statements = []
        for (g, r), name in streams.items():
            entries = [divmod(3 * lanes * g + 3 * j + r, 9) for j in range(lanes)]  # (row, column)
            statements.append(f"auto {name} = " + _chain([(c, row) for row, c in entries], columns, lanes) + ";")
        for m in range(9):
            offsets = [(m % 3) * lanes + j for j in range(lanes)]  # within the three vectors of m // 3
            sources = [((m // 3) * 3 + o % 3, o // 3) for o in offsets]
            statements.append(f"auto {rows[m]} = " + _chain(sources, list(streams.values()), lanes) + ";")
        return statements
    statements = []
    for m in range(width):
        sources = [tuple(reversed(divmod(m * lanes + j, width))) for j in range(lanes)]  # (column, row)
        statements.append(f"auto {rows[m]} = " + _chain(sources, columns, lanes) + ";")
    return statements


def _columns_from_rows(width: int, lanes: int, rows: Sequence[str], columns: Sequence[str], prefix: str = "tq") -> List[str]:
    """C++ statements that set the vectors ``columns`` (entry ``k`` of ``lanes`` rows each) from
    the vectors ``rows`` (their flat row-major entries): the inverse of :func:`_rows_from_columns`."""
    if width == 4 and lanes % 4 == 0:
        half = lanes // 2
        pairs = [f"{prefix}_pair{k}" for k in range(4)]  # as in _rows_from_columns
        statements = []
        for k, (first, low) in enumerate([(0, 0), (0, half), (2, 0), (2, half)]):
            row_vectors = (0, 1) if low == 0 else (2, 3)
            sources = []
            for j in range(lanes):
                vector, lane = divmod(4 * (j // 2) + first + j % 2, lanes)
                sources.append((vector, lane))
            statements.append(f"auto {pairs[k]} = " + _chain(sources, [rows[row_vectors[0]], rows[row_vectors[1]]], lanes) + ";")
        for k in range(4):
            left, right = (0, 1) if k < 2 else (2, 3)
            sources = [(0 if i < half else 1, 2 * (i % half) + k % 2) for i in range(lanes)]
            statements.append(f"auto {columns[k]} = " + _chain(sources, [pairs[left], pairs[right]], lanes) + ";")
        return statements
    if width == 9 and lanes >= 8:  # the inverse of _rows_from_columns's strides of 3
        streams = [f"{prefix}_stream{g}{r}" for g in range(3) for r in range(3)]
        statements = []
        for g in range(3):
            for r in range(3):
                sources = [divmod(3 * lanes * g + 3 * j + r, lanes) for j in range(lanes)]  # (row vector, lane)
                statements.append(f"auto {streams[3 * g + r]} = " + _chain(sources, rows, lanes) + ";")
        for k in range(9):
            sources = [(3 * ((9 * i + k) // (3 * lanes)) + k % 3, ((9 * i + k) % (3 * lanes)) // 3) for i in range(lanes)]
            statements.append(f"auto {columns[k]} = " + _chain(sources, streams, lanes) + ";")
        return statements
    statements = []
    for k in range(width):
        sources = [divmod(width * i + k, lanes) for i in range(lanes)]  # (row vector, lane)
        statements.append(f"auto {columns[k]} = " + _chain(sources, rows, lanes) + ";")
    return statements


def _vector_type(kind: str, lanes: int) -> Tuple[str, str]:
    """The name of a GCC vector type of ``lanes`` ``kind``s (float or double), and its typedef."""
    name = f"tq_{kind}x{lanes}"
    return name, f"typedef {kind} {name} __attribute__((vector_size({lanes * (4 if kind == 'float' else 8)})));"


def _transposed(group: Sequence[_Access]) -> str:
    """C++ that writes the group's columns as whole rows where its pointers are one row's entries,
    and inductor's own stores elsewhere."""
    original = "".join(s.text for s in group)
    same_pointer = len({s.pointer for s in group}) == 1
    if same_pointer:  # one pointer: the offsets say which column each store is
        group = sorted(group, key=lambda s: s.offset)
        if [s.offset for s in group] != list(range(group[0].offset, group[0].offset + len(group))):
            return original
    first = group[0]
    width, lanes, kind, indent = first.stride, first.lanes, first.type, first.indent
    vector, typedef = _vector_type(kind, lanes)
    base = f"({first.pointer} + {first.offset})" if first.offset else first.pointer
    check = "true" if same_pointer else " && ".join(f"{s.pointer} + {s.offset} == {base} + {j}"
                                                    for j, s in enumerate(group) if j)
    lines = [_SHUFFLES_AVAILABLE, f"if ({check})", "{", "    " + typedef]
    for j, s in enumerate(group):
        lines.append(f"    {vector} tq_column{j}; {s.value}.store(&tq_column{j}, static_cast<int64_t>({lanes}));")
    lines.append(f"    {kind}* tq_row = {base} + {width}L*{first.var};")
    outs = [f"tq_out{m}" for m in range(width)]
    lines += ["    " + line for line in _rows_from_columns(width, lanes, [f"tq_column{j}" for j in range(width)], outs)]
    lines += [f"    __builtin_memcpy(tq_row + {m * lanes}, &{out}, sizeof({out}));" for m, out in enumerate(outs)]
    lines += ["}", "else", "#endif", "{"]
    body = [indent + line if not line.startswith("#") else line for line in lines]
    return "\n".join(body) + "\n" + original + indent + "}\n"


def _shuffled_loads(group: Sequence[_Access], tag: int) -> str:
    """C++ that defines the group's column vectors from ``stride`` whole-vector loads of its rows."""
    first = group[0]
    width, lanes, kind, indent = first.stride, first.lanes, first.type, first.indent
    (vector, typedef), prefix = _vector_type(kind, lanes), f"tq_load{tag}"
    rows, columns = [f"{prefix}_row{m}" for m in range(width)], [f"{prefix}_column{k}" for k in range(width)]
    lines = [_SHUFFLES_AVAILABLE, typedef]
    for m, row in enumerate(rows):
        lines.append(f"{vector} {row}; __builtin_memcpy(&{row}, {first.pointer} + {width}L*{first.var} + {m * lanes}, sizeof({row}));")
    lines += _columns_from_rows(width, lanes, rows, columns, prefix)
    lines += [f"auto {load.value} = {load.vector}::loadu(&{columns[load.offset]}, static_cast<int64_t>({lanes}));"
              for load in group]
    body = [line if line.startswith("#") else indent + line for line in lines]
    return "\n".join(body + ["#else"]) + "\n" + "".join(load.text for load in sorted(group, key=lambda load: load.start)) + "#endif\n"


def rewrite(source: str) -> str:
    """``source`` (inductor's C++ for one kernel) with each group of a row's gathered column loads
    and scattered column stores done as whole-row vectors (see the module's docstring); unchanged
    where there is none."""
    edits = []  # (start, end, text): non-overlapping spans of source to replace
    for group in _store_groups(source):
        edits.append((min(s.start for s in group), max(s.end for s in group), _transposed(group)))
    for tag, group in enumerate(_load_groups(source)):
        first, *others = sorted(group, key=lambda load: load.start)
        edits.append((first.start, first.end, _shuffled_loads(group, tag)))
        edits += [(load.start, load.end, "") for load in others]
    if not edits:
        return source
    pieces, position = [], 0
    for start, end, text in sorted(edits):
        pieces += [source[position:start], text]
        position = end
    pieces.append(source[position:])
    return "".join(pieces)


@functools.lru_cache(maxsize=None)
def _marker():
    """The post-grad pass that marks torchquat's compiles (it changes nothing in the graph)."""
    from torch._inductor.custom_graph_pass import CustomGraphPass, get_hash_for_files

    class RowStores(CustomGraphPass):
        def __call__(self, graph) -> None:
            return None

        def uuid(self) -> Optional[object]:
            return get_hash_for_files((__file__,))

    return RowStores()


@functools.lru_cache(maxsize=None)
def _install() -> bool:
    """Wrap inductor's ``CppScheduling.define_kernel`` (once) so that the C++ of a marked compile
    is rewritten; False where this torch has no such method (the rewrite then never acts)."""
    try:
        from torch._inductor import config
        from torch._inductor.codegen.cpp import CppScheduling
        marker = _marker()
    except Exception:
        return False
    define_kernel = getattr(CppScheduling, "define_kernel", None)
    if define_kernel is None:
        return False

    @functools.wraps(define_kernel)
    def define_kernel_with_row_stores(self, src_code, *args, **kwargs):
        if config.post_grad_custom_post_pass is marker and isinstance(src_code, str):
            src_code = rewrite(src_code)
        return define_kernel(self, src_code, *args, **kwargs)

    CppScheduling.define_kernel = define_kernel_with_row_stores
    return True


def options() -> Dict[str, object]:
    """The inductor options that mark a torchquat kernel's compile for the rewrite (none where it
    is off or cannot act)."""
    if not ENABLED or platform.machine().lower() not in ("x86_64", "amd64") or not _install():
        return {}
    return {"post_grad_custom_post_pass": _marker()}
