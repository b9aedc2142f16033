"""Smoke tests of ``torchquat bench``: structure of the table and the JSON, and the peer sanity
check. No timing is asserted (the numbers depend on the machine and its load)."""

import argparse
import importlib.util
import json
import os

import pytest
import torch

from torchquat import bench
from torchquat.bench import ops as bench_ops
from torchquat.bench import options as bench_options
from torchquat.bench import peers as bench_peers
from torchquat.bench import runner, timing

OPS = ["quat_to_matrix", "quat_to_euler_ZYX", "quat_multiply"]
ARGS = ["--n", "1", "10", "--ops", *OPS, "--min-run-time", "0.001", "--allocator", "none"]


def _installed(peer):
    module = dict((name, module) for name, module, *_ in bench_peers.PEER_SPECS)[peer]
    return importlib.util.find_spec(module) is not None


INSTALLED = [p for p in bench_peers.PEER_NAMES if _installed(p)]


def test_add_arguments_defaults():
    parser = bench.add_arguments(argparse.ArgumentParser())
    args = parser.parse_args([])
    assert args.n == [1, 1000, 1_000_000]
    assert args.threads == 1 and args.dtype == "float32" and args.backward is True
    assert args.ops is None and args.json is None
    args = parser.parse_args(["--no-backward", "--ops", "quat_to_matrix", "--peers", "roma"])
    assert args.backward is False and args.ops == ["quat_to_matrix"] and args.peers == ["roma"]


def test_bench_table_and_json(tmp_path, capsys):
    path = tmp_path / "bench.json"
    assert bench.main(ARGS + ["--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "### N = 1\n" in out and "### N = 10\n" in out
    assert "| op | pass | torchquat |" in out
    assert "allocator: glibc defaults" in out
    for label in ("quat -> matrix", "quat -> Euler ZYX", "quat product"):
        assert f"| {label} | fwd |" in out and f"| {label} | fwd+bwd |" in out
    for peer in INSTALLED:
        assert f" {peer} |" in out.splitlines()[out.splitlines().index("### N = 1") + 2]

    data = json.loads(path.read_text())
    assert set(data) == {"meta", "results", "summary", "agreement", "legend"}
    assert data["meta"]["ns"] == [1, 10] and data["meta"]["threads"] == 1 and data["meta"]["device"] == "cpu"
    assert isinstance(data["meta"]["cpu"], str)
    results = data["results"]
    mine = [r for r in results if r["impl"] == "torchquat"]
    assert {(r["op"], r["n"], r["pass"]) for r in mine} == {
        (op, n, p) for op in OPS for n in (1, 10) for p in ("fwd", "fwd+bwd")}
    for r in mine:
        assert r["error"] is None and r["median_s"] > 0 and r["runs"] >= 3
    floors = [r for r in results if r["impl"] == "floor"]
    assert len(floors) == len(OPS) * 2 and all(r["median_s"] > 0 for r in floors)
    assert all(r["pass"] == "fwd" for r in results if r["impl"] == "scipy")
    for s in data["summary"]:
        assert (s["floor_s"] is not None) == (s["pass"] == "fwd")
    for op in OPS:
        assert data["legend"][op]["torchquat"].startswith("torchquat.")


@pytest.mark.parametrize("peer", INSTALLED)
def test_installed_peers_agree(peer):
    """Every installed peer's call computes the same rotation as torchquat (the bench's check)."""
    [loaded] = bench_peers.load_peers([peer])
    assert loaded.error is None, loaded.error
    inputs = bench_ops.make_check_inputs(torch.float32)
    assert loaded.impls
    for name, impl in loaded.impls.items():
        ok, err = bench_ops.check_agreement(bench_ops.OPS_BY_NAME[name], impl, inputs, 1e-3)
        assert ok, f"{peer} {name}: max abs error {err}"


def test_disagreeing_peer_is_marked_and_not_counted(tmp_path, capsys, monkeypatch):
    """A peer that computes a different rotation gets "≠" and is never the fastest peer."""
    wrong = bench_ops.Impl(lambda q: torch.zeros(q.shape[:-1] + (3, 3)), lambda d: (d["q"],), "zeros")
    spec = ("fake", "torch", lambda mod: {"quat_to_matrix": wrong}, True, None)
    monkeypatch.setattr(bench_peers, "PEER_SPECS", [spec])
    monkeypatch.setattr(bench_options, "PEER_NAMES", ["fake"])
    path = tmp_path / "b.json"
    assert bench.main(["--n", "1", "--ops", "quat_to_matrix", "--no-backward", "--min-run-time", "0.001",
                       "--allocator", "none", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "| quat -> matrix | fwd |" in out and "≠ " in out
    data = json.loads(path.read_text())
    assert data["agreement"][0]["agrees"] is False
    assert data["summary"][0]["fastest_peer"] is None and data["summary"][0]["speedup"] is None


def test_missing_peer_is_skipped_with_install_hint(capsys, monkeypatch):
    spec = ("ghost", "no_such_module_torchquat_test", lambda mod: {}, True, None)
    monkeypatch.setattr(bench_peers, "PEER_SPECS", [spec])
    monkeypatch.setattr(bench_options, "PEER_NAMES", ["ghost"])
    assert bench.main(["--n", "1", "--ops", "quat_to_matrix", "--no-backward", "--min-run-time", "0.001",
                       "--allocator", "none"]) == 0
    out = capsys.readouterr().out
    assert "Skipped ghost" in out and 'pip install "torchquat[bench]"' in out


def test_bad_arguments_exit_2(capsys):
    assert bench.main(["--ops", "no_such_op", "--allocator", "none"]) == 2
    assert bench.main(["--peers", "no_such_peer", "--allocator", "none"]) == 2
    assert "unknown" in capsys.readouterr().err
    assert bench.main(["--device", "no_such_device", "--allocator", "none"]) == 2
    assert "--device no_such_device" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert bench.main(["--device", "cuda", "--allocator", "none"]) == 2


def test_json_into_a_missing_folder_is_refused_before_the_run(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(bench_ops, "make_inputs", None)  # (a run would fail: the check comes first)
    assert bench.main(["--json", str(tmp_path / "no" / "x.json"), "--allocator", "none"]) == 2
    err = capsys.readouterr().err
    assert "--json" in err and "no such folder" in err


def test_floor_kernel_shapes():
    f = timing.floor_fn(5, 4, (3, 3), torch.float32)  # inputs smaller than the output: a copy
    assert f().shape == (5, 3, 3)
    f = timing.floor_fn(5, 18, (), torch.float32)  # two matrices in, one angle out: a sum of 18 planes
    assert f().shape == (5,)


def test_no_reexec_inside_a_test_runner():
    assert timing.relaunch_argv() is None


def test_rounds_go_over_every_op_and_keep_each_cells_fastest_median_at_every_batch_size(monkeypatch, tmp_path):
    # a slow spell on the machine: every cell is fast in its second round only, large batches too
    # (in one go, a slow minute had taken a whole N = 1e6 cell to 0.6x its speed)
    real_callable, timed = runner._callable, []

    def tagged(impl, inputs, backward, seed):
        fn = real_callable(impl, inputs, backward, seed)

        def call():
            return fn()
        call.timed_as = impl.call
        return call

    def fake_measure(fn, min_run_time, threads, min_runs=3):
        name = getattr(fn, "timed_as", "floor")
        timed.append(name)
        median = 2.0 if name == "floor" else 1.0 if timed.count(name) % 3 == 2 else 3.0
        return timing.Timing(median=median, iqr=0.0, runs=3, calls=3)

    monkeypatch.setattr(runner, "_callable", tagged)
    monkeypatch.setattr(timing, "measure", fake_measure)
    path = tmp_path / "bench.json"
    args = ["--n", "1", "20000", "--ops", "quat_multiply", "quat_to_matrix", "--peers", "none", "--no-backward",
            "--allocator", "none", "--rounds", "3", "--json", str(path)]
    assert bench.main(args) == 0
    mine = {(r["n"], r["op"]): r["median_s"] for r in json.loads(path.read_text())["results"] if r["impl"] == "torchquat"}
    assert mine == {(n, op): 1.0 for n in (1, 20000) for op in ("quat_multiply", "quat_to_matrix")}
    product, matrix = "torchquat.quat_multiply(p, q)", "torchquat.quat_to_matrix(q)"
    one_n = [product] + ["floor"] * 3 + [matrix] + ["floor"] * 3 + [product, matrix] * 2
    assert timed == one_n * 2  # each round over both ops in turn (the floors once, in the first)


@pytest.mark.parametrize("how, status", [("SIGINT", 130), ("SIGTERM", 143)])
def test_a_stopped_run_reports_the_finished_measurements(how, status, monkeypatch, tmp_path, capsys):
    # Ctrl-C, or the SIGTERM of `timeout` or a job scheduler, during the third (N, op): the table and
    # the JSON keep the first two and drop the one in progress
    import os
    import signal
    import threading

    if how == "SIGTERM" and threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers are installed from the main thread only")
    real_measure, calls, handler = timing.measure, [], signal.getsignal(signal.SIGTERM)

    def measure(fn, min_run_time, threads, min_runs=3):
        calls.append(fn)
        if len(calls) == 11:  # 2 (N, op) x (2 passes + 3 floor probes) = 10 calls finished
            if how == "SIGINT":
                raise KeyboardInterrupt
            os.kill(os.getpid(), signal.SIGTERM)
        return real_measure(fn, min_run_time, threads, min_runs)

    monkeypatch.setattr(timing, "measure", measure)
    path = tmp_path / "bench.json"
    args = ["--n", "1", "--ops", "quat_to_matrix", "quat_multiply", "quat_rotate", "matrix_to_quat", "--peers", "none",
            "--min-run-time", "0.001", "--rounds", "1", "--allocator", "none", "--json", str(path)]
    assert bench.main(args) == status
    out = capsys.readouterr().out
    assert f"Stopped by {how} after 2 of 4 (N, op) measurements" in out
    assert "| quat -> matrix | fwd+bwd |" in out and "| quat product | fwd |" in out and "rotate vectors" not in out.split("Calls timed")[0]
    data = json.loads(path.read_text())
    assert data["meta"]["stopped_by"] == how and (data["meta"]["finished"], data["meta"]["planned"]) == (2, 4)
    assert {r["op"] for r in data["results"]} == {"quat_to_matrix", "quat_multiply"}
    assert signal.getsignal(signal.SIGTERM) is handler and len(calls) == 11  # the handler is put back


def test_a_run_stopped_in_a_later_round_keeps_every_op_with_the_rounds_it_finished(monkeypatch, tmp_path, capsys):
    # Ctrl-C in the second round, at the second op: both ops keep their first round's medians, and
    # the first op its second round's faster one
    times, calls = iter([3.0, 2.0, 2.0, 2.0, 3.0, 2.0, 2.0, 2.0, 1.0]), []

    def measure(fn, min_run_time, threads, min_runs=3):
        calls.append(fn)
        if len(calls) == 10:  # round 1: 2 ops x (1 pass + 3 floor probes); round 2: the first op
            raise KeyboardInterrupt
        return timing.Timing(median=next(times), iqr=0.0, runs=3, calls=3)

    monkeypatch.setattr(timing, "measure", measure)
    path = tmp_path / "bench.json"
    args = ["--n", "1", "--ops", "quat_to_matrix", "quat_multiply", "--peers", "none", "--no-backward",
            "--rounds", "3", "--allocator", "none", "--json", str(path)]
    assert bench.main(args) == 130
    assert "Stopped by SIGINT after 2 of 2 (N, op) measurements" in capsys.readouterr().out
    data = json.loads(path.read_text())
    mine = {r["op"]: r["median_s"] for r in data["results"] if r["impl"] == "torchquat"}
    assert mine == {"quat_to_matrix": 1.0, "quat_multiply": 3.0}
    assert (data["meta"]["finished"], data["meta"]["planned"]) == (2, 2)


def test_bad_threads_and_seed_exit_2_without_a_traceback(capsys):
    assert bench.main(["--threads", "0", "--ops", "quat_to_matrix", "--allocator", "none"]) == 2
    assert "--threads must be from 1 to 1024, got 0" in capsys.readouterr().err
    assert bench.main(["--seed", str(2 ** 64), "--ops", "quat_to_matrix", "--allocator", "none"]) == 2
    assert "--seed" in capsys.readouterr().err


_FAST = ["--ops", "quat_to_matrix", "--peers", "none", "--no-backward", "--min-run-time", "0.001", "--rounds", "1",
         "--allocator", "none"]


def test_an_error_at_a_later_size_keeps_what_finished(tmp_path, capsys, monkeypatch):
    # an allocation failure at a large N used to lose the whole run, table and JSON
    make_inputs = bench_ops.make_inputs

    def failing(n, *args, **kwargs):
        if n == 7:
            raise RuntimeError("can't allocate memory")
        return make_inputs(n, *args, **kwargs)

    monkeypatch.setattr(bench_ops, "make_inputs", failing)
    path = tmp_path / "b.json"
    assert bench.main(["--n", "1", "7", "--json", str(path), *_FAST]) == 1
    captured = capsys.readouterr()
    assert "error at N=7" in captured.err and "can't allocate memory" in captured.err
    data = json.loads(path.read_text())
    assert data["meta"]["stopped_by"].startswith("error at N=7")
    assert {r["n"] for r in data["results"]} == {1}
    assert "quat -> matrix" in captured.out


def test_a_json_that_cannot_be_written_is_exit_2_and_keeps_the_old_file(tmp_path, capsys, monkeypatch):
    import torchquat.io.files as files

    def no_space(*_):
        raise OSError(28, "No space left on device")

    path = tmp_path / "b.json"
    path.write_text("old")
    monkeypatch.setattr(files.os, "replace", no_space)
    assert bench.main(["--n", "1", "--json", str(path), *_FAST]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert path.read_text() == "old" and os.listdir(tmp_path) == ["b.json"]


@pytest.mark.parametrize("option, message", [
    (["--rounds", "0"], "--rounds must be from 1 to 1000, got 0"),
    (["--min-run-time", "-1"], "--min-run-time must be from 0 to 3600, got -1.0"),
    (["--min-run-time", "nan"], "--min-run-time must be from 0 to 3600, got nan"),
    (["--json", ""], "--json needs a file name"),
    (["--peers", "none", "roma"], "name peers or none, not both"),
])
def test_options_out_of_range_exit_2_before_the_run(option, message, capsys, monkeypatch):
    # (--rounds 0 was clamped to 1, --json "" wrote nothing and --peers none roma dropped none, silently)
    monkeypatch.setattr(bench_ops, "make_inputs", None)  # (a run would fail: the checks come first)
    assert bench.main(["--ops", "quat_to_matrix", "--allocator", "none", *option]) == 2
    assert message in capsys.readouterr().err


def test_a_value_named_twice_is_timed_once(tmp_path, monkeypatch):
    calls = []

    def fake_measure(fn, min_run_time, threads, min_runs=3):
        calls.append(fn)
        return timing.Timing(median=1.0, iqr=0.0, runs=3, calls=3)

    monkeypatch.setattr(timing, "measure", fake_measure)
    path = tmp_path / "b.json"
    args = ["--n", "1", "1", "--ops", "quat_to_matrix", "quat_to_matrix", "--peers", "none", "none",
            "--no-backward", "--rounds", "1", "--allocator", "none", "--json", str(path)]
    assert bench.main(args) == 0
    data = json.loads(path.read_text())
    assert data["meta"]["ns"] == [1] and data["meta"]["planned"] == 1
    assert len(calls) == 1 + 3  # torchquat once, the floor's three preallocations
    assert [(r["impl"], r["n"]) for r in data["results"]] == [("torchquat", 1), ("floor", 1)]


def test_a_peer_whose_agreement_check_raises_is_err_not_different(tmp_path, capsys, monkeypatch):
    def broken_output(out):
        raise TypeError("cannot convert this output")

    crashing = bench_ops.Impl(lambda q: q, lambda d: (d["q"],), "identity", to_tq=broken_output)
    spec = ("fake", "torch", lambda mod: {"quat_to_matrix": crashing}, True, None)
    monkeypatch.setattr(bench_peers, "PEER_SPECS", [spec])
    monkeypatch.setattr(bench_options, "PEER_NAMES", ["fake"])
    path = tmp_path / "b.json"
    assert bench.main(["--n", "1", "--ops", "quat_to_matrix", "--no-backward", "--min-run-time", "0.001",
                       "--rounds", "1", "--allocator", "none", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| quat -> matrix | fwd |"))
    assert row.split(" | ")[3] == "err" and "≠" not in row
    assert "err fake on quat_to_matrix: the agreement check raised TypeError: cannot convert this output" in out
    data = json.loads(path.read_text())
    assert data["summary"][0]["fastest_peer"] is None
    assert data["agreement"][0]["error"].startswith("TypeError")


def test_mallopt_line_states_the_threshold_it_sets(monkeypatch):
    monkeypatch.setattr(timing, "_mallopt", lambda: True)
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    line = timing.steady_allocator("mallopt")
    assert "2^31-1" in line and "2 GiB" in line and "equivalent" not in line
