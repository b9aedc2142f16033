"""Whole-row loads and stores in the compiled kernels' C++ (``torchquat._row_stores``)."""

import re

import pytest
import torch

from torchquat import _dispatch, _row_stores
from torchquat.bench import ops as bench_ops


def _shuffle_value(expression, vectors):
    """The lanes of a C++ expression made of ``__builtin_shufflevector`` calls and vector names."""
    expression = expression.strip()
    if not expression.startswith("__builtin_shufflevector("):
        return vectors[expression]
    parts, depth, current = [], 0, ""
    for ch in expression[len("__builtin_shufflevector("):-1]:
        depth += (ch == "(") - (ch == ")")
        if ch == "," and depth == 0:
            parts.append(current)
            current = ""
        else:
            current += ch
    parts.append(current)
    both = _shuffle_value(parts[0], vectors) + _shuffle_value(parts[1], vectors)
    indices = [int(p) for p in parts[2:]]
    assert len(indices) == len(_shuffle_value(parts[0], vectors))
    return [both[i] if i >= 0 else None for i in indices]


def _run(statements, vectors):
    for statement in statements:
        name, expression = re.fullmatch(r"auto (\w+) = (.*);", statement).groups()
        vectors[name] = _shuffle_value(expression, vectors)


@pytest.mark.parametrize("width", [3, 4, 9])
@pytest.mark.parametrize("lanes", [4, 8, 16])
def test_the_shuffles_transpose_columns_to_rows_and_back(width, lanes):
    rows = [[(r, c) for c in range(width)] for r in range(lanes)]  # entry (row, column)
    flat = [entry for row in rows for entry in row]
    vectors = {f"c{c}": [row[c] for row in rows] for c in range(width)}
    _run(_row_stores._rows_from_columns(width, lanes, [f"c{c}" for c in range(width)],
                                        [f"r{m}" for m in range(width)]), vectors)
    assert [entry for m in range(width) for entry in vectors[f"r{m}"]] == flat
    vectors = {f"r{m}": flat[m * lanes:(m + 1) * lanes] for m in range(width)}
    statements = _row_stores._columns_from_rows(width, lanes, [f"r{m}" for m in range(width)],
                                                [f"c{c}" for c in range(width)])
    _run(statements, vectors)
    assert all(vectors[f"c{c}"] == [(r, c) for r in range(lanes)] for c in range(width))
    # rows of 3: two shuffles a vector; of 4: two rounds of pairs; of 9: strides of 3, then 3 of them
    most = {3: 6, 4: 8, 9: 36 if lanes >= 8 else 72}[width]
    assert sum(s.count("__builtin_shufflevector") for s in statements) <= most


_STORES = """    [&]
    {
        __at_align__ std::array<float, 16> tmpbuf;
        tmpA.store(tmpbuf.data(), static_cast<int64_t>(16));
        #pragma GCC unroll 16
        for (long x0_inner = 0; x0_inner < static_cast<int64_t>(16); x0_inner++)
        {
            PTR[static_cast<int64_t>(OFFSET3L*x0 + 3L*x0_inner)] = tmpbuf[x0_inner];
        }
    }
    ()
    ;
"""


def test_a_row_of_scattered_stores_becomes_a_guarded_transpose_with_inductors_stores_as_fallback():
    stores = "".join(_STORES.replace("tmpA", f"tmp{k}").replace("PTR", f"out_ptr{k}").replace("OFFSET", "")
                     for k in range(3))
    source = "{\n" + stores + "}\n"
    rewritten = _row_stores.rewrite(source)
    assert "if (out_ptr1 + 0 == out_ptr0 + 1 && out_ptr2 + 0 == out_ptr0 + 2)" in rewritten
    assert stores in rewritten  # inductor's own stores, where the check fails or no shuffles exist
    assert rewritten.count("__builtin_memcpy(tq_row") == 3
    # two of a row's three columns, or another stride, are left alone
    assert _row_stores.rewrite("{\n" + stores.split("    [&]")[1] + "}\n") == "{\n" + stores.split("    [&]")[1] + "}\n"
    wide = stores.replace("3L*", "5L*")
    assert _row_stores.rewrite(wide) == wide


def test_stores_into_one_pointer_need_each_column_once():
    store = _STORES.replace("PTR", "out_ptr0")
    complete = "".join(store.replace("tmpA", f"tmp{k}").replace("OFFSET", f"{k}L + " if k else "") for k in (2, 0, 1))
    rewritten = _row_stores.rewrite(complete)
    assert "if (true)" in rewritten and "tq_column0; tmp0.store" in rewritten and "tq_column2; tmp2.store" in rewritten
    twice = "".join(store.replace("tmpA", f"tmp{k}").replace("OFFSET", "1L + " if k else "") for k in (0, 1, 1))
    assert _row_stores.rewrite(twice) == twice


# one op of each layout (rows of 3, 4 or 9 in; rows of 3, 4 or 9 or none out; two inputs), float64's
# wider vectors (VectorizedN), and a training graph; each case compiles twice (6-8 s a compile)
_CASES = [("euler_to_quat_ZYX", torch.float32, False), ("matrix_to_axis_angle", torch.float32, False),
          ("quat_to_matrix", torch.float32, False), ("quat_multiply", torch.float32, False),
          ("quat_geodesic_distance", torch.float32, False), ("axis_angle_to_quat", torch.float64, False),
          ("axis_angle_to_quat", torch.float32, True)]


def _compiled_outputs(name, dtype, backward, rows):
    op = bench_ops.OPS_BY_NAME[name]
    inputs = bench_ops.make_inputs(rows, dtype)
    args = tuple(inputs[k].detach().clone().requires_grad_(backward) for k in op.args)
    _dispatch._compiled = {}
    with torch.set_grad_enabled(backward):
        out = op.tq_fn(*args)
        if not backward:
            return (out,)
        grad = torch.randn(out.shape, dtype=dtype, generator=torch.Generator().manual_seed(1))
        return (out.detach(),) + torch.autograd.grad(out, args, grad)


@pytest.mark.slow
@pytest.mark.parametrize("name, dtype, backward", _CASES)
def test_compiled_kernels_write_inductors_numbers_bit_for_bit_through_whole_rows(name, dtype, backward, compiled,
                                                                                monkeypatch):
    import torch._functorch.config as functorch_config
    import torch._inductor.config as inductor_config

    monkeypatch.setattr(_dispatch, "_compiled", {})
    rewritten = []
    original = _row_stores.rewrite

    def counting(source):
        result = original(source)
        rewritten.append(result != source)
        return result

    monkeypatch.setattr(_row_stores, "rewrite", counting)
    rows = 3 * 16 + 5  # full vectors of 8 or 16 lanes, and a tail
    # every compile generates its C++ here (no cached kernel), so the count below is this test's
    with inductor_config.patch(fx_graph_cache=False), functorch_config.patch(enable_autograd_cache=False):
        monkeypatch.setattr(_row_stores, "ENABLED", False)
        stock = _compiled_outputs(name, dtype, backward, rows)
        assert not rewritten  # (the marker is off: inductor's C++ is not even read)
        monkeypatch.setattr(_row_stores, "ENABLED", True)
        rows_at_once = _compiled_outputs(name, dtype, backward, rows)
    for a, b in zip(stock, rows_at_once):
        assert torch.equal(a, b)
    if _row_stores.options():
        assert any(rewritten), "no kernel's loads or stores were rewritten"


def test_a_users_own_compile_is_left_as_inductor_writes_it(monkeypatch):
    import torch._inductor.config as inductor_config

    if not _row_stores.options():
        pytest.skip("the rewrite cannot act with this torch")
    seen = []
    original = _row_stores.rewrite
    monkeypatch.setattr(_row_stores, "rewrite", lambda source: seen.append(source) or original(source))

    def rows_of_four(x):
        a, b, c = x.unbind(-1)
        return torch.stack([a * b, b * c, c * a, a + b + c], -1)

    x = torch.randn(100, 3)
    with torch.no_grad(), inductor_config.patch(fx_graph_cache=False):
        out = torch.compile(rows_of_four, dynamic=True)(x)
    torch.testing.assert_close(out, rows_of_four(x))
    assert not seen
