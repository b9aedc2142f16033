"""The fast paths of `torchquat convert`: block reading, polars parsing/formatting, the read-ahead thread.

Each fast path must give what the plain numpy, line-by-line path gives: the same values, the
same errors at the same line numbers, OUT untouched on failure.
"""

import io
import os
import threading
from itertools import islice

import numpy as np
import pytest

from torchquat.io import PoseFileError, convert_file, read_poses
from torchquat.io import fastpath
from torchquat.io.checks import _orthogonality_error_and_det
from torchquat.io.numtext import Floats, Integers, Nanoseconds, format_nanoseconds
from torchquat.io.textparse import LineChunk, iter_line_chunks, parse_table
from torchquat.io.textwrite import format_table

HAS_POLARS = fastpath.polars() is not None
needs_polars = pytest.mark.skipif(not HAS_POLARS, reason="polars not installed (pip install torchquat[fast])")


@pytest.fixture(params=[False, True], ids=["numpy", "polars"])
def polars_on(request):
    if request.param and not HAS_POLARS:
        pytest.skip("polars not installed")
    previous = fastpath.use_polars(request.param)
    yield request.param
    fastpath.use_polars(previous)


@needs_polars
def test_threads_asking_for_polars_at_once_all_get_it(monkeypatch):
    # The read-ahead thread and the writer ask first at the same time: neither may see "tried,
    # nothing yet" and take the numpy path for its first chunk while the other is importing.
    import builtins
    import time
    real_import = builtins.__import__

    def slow_import(name, *args, **kwargs):
        if name == "polars":
            time.sleep(0.2)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", slow_import)
    monkeypatch.setitem(fastpath._STATE, "tried", False)
    monkeypatch.setitem(fastpath._STATE, "module", None)
    got = []
    threads = [threading.Thread(target=lambda: got.append(fastpath.polars())) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(got) == 4 and all(module is not None and module.__name__ == "polars" for module in got)


def numbers_of(path):
    """Every number of a text file, as floats, row by row (comments skipped)."""
    rows = []
    for line in open(path):
        if line.strip() and not line.startswith("#") and not line[0].isalpha():  # no comment, no CSV header
            rows.append([float(v) for v in line.replace(",", " ").split()])
    return np.array(rows)


def kitti_rows(n: int, seed: int = 0) -> str:
    import torch

    import torchquat
    rng = np.random.default_rng(seed)
    R = torchquat.convert(torch.from_numpy(rng.standard_normal((n, 4))), "quat", "matrix").numpy()
    t = rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-8, 8, (n, 1))
    pose = np.concatenate([R, t[:, :, None]], axis=2).reshape(n, 12)
    return "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in pose)


# --- reading blocks of lines ---------------------------------------------------------------------

@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 64, 1000])
@pytest.mark.parametrize("ending", ["\n", ""])
def test_blocks_hold_the_same_lines_as_iterating_the_file(chunk, ending):
    rng = np.random.default_rng(chunk)
    lines = ["x" * int(k) for k in rng.integers(0, 300, 500)]
    data = ("\n".join(lines) + ending).encode()
    expected, stream, first = [], io.BytesIO(data), 1
    while True:
        part = list(islice(stream, chunk))
        if not part:
            break
        expected.append((first, part))
        first += len(part)
    got = [(c.first_line, c.lines, c.count) for c in iter_line_chunks(io.BytesIO(data), chunk)]
    assert [(f, ls) for f, ls, _ in got] == expected
    assert all(count == len(ls) <= chunk for _, ls, count in got)


def test_line_chunk_from_lines_or_block():
    a, b = LineChunk(5, [b"1 2\n", b"3 4"]), LineChunk(5, block=b"1 2\n3 4")
    assert a.block == b.block and a.lines == b.lines and a.count == b.count == 2
    first, lines = b
    assert first == 5 and lines == [b"1 2\n", b"3 4"]


@pytest.mark.parametrize("text", [
    "1 2 3\n4 5 6\n",
    "1 2 3\n\n4 5 6\n",            # blank line
    "1 2 3\n \n4 5 6\n",           # short whitespace line
    "1 2 3\r\n4 5 6\r\n",          # CRLF
    "1\t2  3\n  4 5 6 \n",         # tabs, double and leading/trailing spaces
    "# c\n1 2 3\n4 5 6 # note\n",  # comments
    "1 2 3\n4 5",                  # too few numbers
    "1 2 3\n4 5 x\n",              # not a number
    "1 2 3\n4 5 6 7\n",            # too many
    "1 2 3\n4 nan 6\n",            # not finite
    "1 2 3\n4 5 6",                # no final newline
])
def test_parse_table_same_result_with_and_without_polars(text):
    results = []
    for enabled in ([False, True] if HAS_POLARS else [False]):
        previous = fastpath.use_polars(enabled)
        try:
            table = parse_table("f.txt", LineChunk(10, block=text.encode()), (3,), "three numbers",
                                keep_first_text=True)
            results.append((table.values.tolist(), table.line_numbers.tolist(), table.first_fields))
            assert table.first_fields == [line.split()[0] for line in text.encode().splitlines()
                                          if line.strip() and not line.strip().startswith(b"#")]
        except PoseFileError as err:
            results.append(("error", err.line, str(err)))
        finally:
            fastpath.use_polars(previous)
    assert all(r == results[0] for r in results)
    expected = _parse_line_by_line(text)  # what the former, always line-by-line, code gave
    assert results[0][:2] == expected


def _parse_line_by_line(text):
    """The former parse_table: comments and <=2-byte blank lines dropped, else first bad line."""
    lines = io.BytesIO(text.encode()).readlines()
    numbered = [(10 + i, line) for i, line in enumerate(lines)]
    if "#" in text or any(len(line) <= 2 and not line.strip() for line in lines):
        numbered = [(n, line) for n, line in numbered if line.strip() and not line.strip().startswith(b"#")]
    rows = []
    for number, line in numbered:
        try:
            values = [float(f) for f in line.split()]
        except ValueError:
            return ("error", number)
        if len(values) != 3 or not np.all(np.isfinite(values)):
            return ("error", number)
        rows.append(values)
    return (rows, [n for n, _ in numbered])


@needs_polars
@pytest.mark.parametrize("token", ["1e5", "+1", ".5", "5.", "-.5", "1E+05", "0x10", "1_0", "\u0661", "nan", "-inf",
                                   "Infinity", "1d5", "1.0.0", "--1", "1e", "e5", "1,5", "0001", "1e400", "1e-400",
                                   "true", '"1"', "1f", "0b1", "1.5e+3", "-0", "4.9e-324", "2.2250738585072011e-308"])
def test_every_token_polars_accepts_parses_as_loadtxt_does(token):
    block = f"0 {token} 2\n".encode()
    fast = fastpath.parse_block(block, 1, (3,), None)
    if fast is None:
        return  # refused: the numpy path decides, as without polars
    slow = np.loadtxt(io.BytesIO(block), ndmin=2, comments=None, quotechar=None)
    np.testing.assert_array_equal(fast, slow)
    assert np.signbit(fast).tolist() == np.signbit(slow).tolist()


# --- formatting ----------------------------------------------------------------------------------

EXTREMES = np.array([0.0, -0.0, 1.0, -1.0, 0.1, 1e-5, 1.5e-5, 9.99e-6, 1e-4, 123456789.0, 1e15, 1e16, 1e17,
                     1.7976931348623157e308, 5e-324, 2.2250738585072014e-308, 1 / 3, 0.30000000000000004, 1e22,
                     1e-300, -2.5e-7, 9007199254740993.0, 0.9999999999999999, 5.551115e-17, 1e-291, 3e290])


@needs_polars
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_polars_text_reads_back_to_the_same_values(dtype):
    rng = np.random.default_rng(3)
    random = rng.standard_normal(4000) * 10.0 ** rng.integers(-300, 300, 4000)
    with np.errstate(over="ignore"):
        values = np.concatenate([EXTREMES, random]).astype(dtype)
    values = values[np.isfinite(values)]
    table = values.reshape(-1, 1)
    columns = [Integers(np.arange(len(table)) - 5), Nanoseconds(rng.integers(-2**62, 2**62, len(table))),
               Floats(table)]
    previous = fastpath.use_polars(True)
    try:
        fast = format_table(columns).split(b"\n")
    finally:
        fastpath.use_polars(False)
    try:
        slow = format_table(columns).split(b"\n")
    finally:
        fastpath.use_polars(previous)
    assert len(fast) == len(slow) == len(table) + 1
    for a, b, v in zip(fast[:-1], slow[:-1], values):
        fa, fb = a.split(), b.split()
        assert fa[0] == fb[0] and fa[1] == fb[1]  # integers and exact seconds: the same text
        assert dtype(fa[2]) == dtype(fb[2]) == v, (fa[2], fb[2], v)
        for text in (fa[2], fb[2]):  # significant digits: at most 17 (float64) or 9 (float32)
            mantissa = text.split(b"e")[0].replace(b"-", b"").replace(b".", b"").strip(b"0")
            assert len(mantissa) <= (17 if dtype == np.float64 else 9), text


@needs_polars
def test_polars_seconds_text_matches_format_nanoseconds():
    ns = np.array([0, 1, -1, 5_000_000_000, 1403715524907143168, -1403715524907143168, 999_999_999,
                   1_000_000_001, 9_223_372_036_854_775_807, -9_223_372_036_854_775_807, -10])
    expected = [bytes(f[0][f[0] != 0]) for f in format_nanoseconds(ns)]
    got = fastpath._seconds_text(fastpath.polars(), ns).to_list()
    assert [g.encode() for g in got] == expected


# --- whole conversions ---------------------------------------------------------------------------

@pytest.mark.parametrize("name,target", [
    ("KITTI_00_gt.txt", "out.tum"), ("KITTI_00_gt.txt", "out.csv"), ("V102_groundtruth.csv", "out.tum"),
    ("freiburg1_xyz-groundtruth.txt", "out.csv"), ("freiburg1_xyz-groundtruth.txt", "out.kitti"),
    ("V102_groundtruth.csv", "out_euroc.csv"),
])
def test_conversions_give_the_same_values_with_and_without_polars(shared_data, tmp_path, name, target):
    src = shared_data / name
    if not src.exists():
        pytest.skip(f"{name} not in {shared_data}")
    if not HAS_POLARS:
        pytest.skip("polars not installed")
    outputs = {}
    for enabled in (False, True):
        previous = fastpath.use_polars(enabled)
        try:
            out = tmp_path / f"{enabled}_{target}"
            convert_file(src, out, to="euroc" if "euroc" in target else None, chunk_size=700)
            outputs[enabled] = out
        finally:
            fastpath.use_polars(previous)
    slow, fast = (numbers_of(outputs[k]) for k in (False, True))
    np.testing.assert_array_equal(slow, fast)
    assert open(outputs[False]).readline() == open(outputs[True]).readline()  # the same header


def test_kitti_row_index_is_written_as_integers(tmp_path, polars_on):
    src = tmp_path / "in.kitti"
    src.write_text(kitti_rows(30))
    convert_file(src, tmp_path / "out.tum", chunk_size=7)
    times = [line.split()[0] for line in open(tmp_path / "out.tum") if not line.startswith("#")]
    assert times == [str(i) for i in range(30)]


@pytest.mark.parametrize("bad", ["1 0 0 0 0 1 0 0 0 0 1\n", "1 0 0 0 0 1 0 0 0 0 1 x\n", "1 0 0 0 0 1 0 0 0 0 1 nan\n",
                                 "2 0 0 0 0 1 0 0 0 0 1 0\n"])
def test_malformed_line_in_a_late_chunk_is_named_and_out_untouched(tmp_path, polars_on, bad):
    n, bad_at = 5000, 4711  # chunk 48 of 50 at chunk_size 100: the read-ahead thread is well ahead
    lines = kitti_rows(n).splitlines(keepends=True)
    lines[bad_at] = bad
    src = tmp_path / "in.kitti"
    src.write_text("".join(lines))
    out = tmp_path / "out.tum"
    out.write_bytes(b"precious\n")
    before = threading.active_count()
    with pytest.raises(PoseFileError) as info:
        convert_file(src, out, chunk_size=100)
    assert info.value.line == bad_at + 1
    assert f"{src}:{bad_at + 1}:" in str(info.value)
    assert out.read_bytes() == b"precious\n"
    assert sorted(os.listdir(tmp_path)) == ["in.kitti", "out.tum"]
    assert threading.active_count() == before  # the read-ahead thread has stopped


def test_error_while_writing_stops_the_read_ahead_thread(tmp_path, monkeypatch):
    from torchquat.io import formats
    src = tmp_path / "in.kitti"
    src.write_text(kitti_rows(2000))
    calls = []

    def failing(poses, report, row):
        calls.append(row)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return Integers(np.arange(row, row + len(poses)))
    monkeypatch.setattr(formats, "time_column", failing)
    before = threading.active_count()
    with pytest.raises(OSError):
        convert_file(src, tmp_path / "out.tum", chunk_size=50)
    assert threading.active_count() == before
    assert sorted(os.listdir(tmp_path)) == ["in.kitti"]


def test_progress_is_reported_in_the_callers_thread_up_to_the_file_size(tmp_path):
    src = tmp_path / "in.kitti"
    src.write_text(kitti_rows(1000))
    seen = []
    convert_file(src, tmp_path / "out.tum", chunk_size=64,
                 on_chunk=lambda done: seen.append((done, threading.current_thread() is threading.main_thread())))
    positions = [done for done, _ in seen]
    assert len(seen) == 16 and all(main for _, main in seen)
    assert positions == sorted(positions) and positions[-1] == src.stat().st_size


def test_read_back_after_fast_conversion_round_trips(tmp_path, polars_on):
    src = tmp_path / "in.kitti"
    src.write_text(kitti_rows(500, seed=7))
    convert_file(src, tmp_path / "out.tum", chunk_size=128)
    convert_file(tmp_path / "out.tum", tmp_path / "back.kitti", chunk_size=128)
    original, back = numbers_of(src), numbers_of(tmp_path / "back.kitti")
    np.testing.assert_allclose(back, original, rtol=0, atol=1e-12)
    positions = read_poses(tmp_path / "out.tum").positions.numpy()
    np.testing.assert_array_equal(positions, original[:, [3, 7, 11]])  # positions pass through bit-exact


def test_orthogonality_error_matches_the_einsum_definition():
    rng = np.random.default_rng(5)
    R = rng.standard_normal((1000, 3, 3))
    gram = np.einsum("nki,nkj->nij", R, R) - np.eye(3)
    error, det = _orthogonality_error_and_det(R)
    np.testing.assert_allclose(error, np.abs(gram).reshape(-1, 9).max(axis=1), rtol=1e-14)
    np.testing.assert_allclose(det, np.linalg.det(R), rtol=1e-12, atol=1e-12)


def test_without_the_read_ahead_thread_the_same_output_and_errors(tmp_path, polars_on):
    """read_ahead=False (a cluster's worker): no thread started, the same bytes, the same error line."""
    src = tmp_path / "in.kitti"
    src.write_text(kitti_rows(1000))
    counts = {}
    for read_ahead in (True, False):
        seen = []
        convert_file(src, tmp_path / f"{read_ahead}.tum", chunk_size=64, read_ahead=read_ahead,
                     on_chunk=lambda done: seen.append(threading.active_count()))
        counts[read_ahead] = max(seen)
    assert (tmp_path / "False.tum").read_bytes() == (tmp_path / "True.tum").read_bytes()
    assert counts[False] == threading.active_count() < counts[True]
    lines = kitti_rows(1000).splitlines(keepends=True)
    lines[777] = "1 2 3\n"
    src.write_text("".join(lines))
    with pytest.raises(PoseFileError) as info:
        convert_file(src, tmp_path / "bad.tum", chunk_size=64, read_ahead=False)
    assert info.value.line == 778 and not (tmp_path / "bad.tum").exists()
