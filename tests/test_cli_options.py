"""Every command-line option out of range: exit status 2 and one line on stderr naming the
option (and, for numbers, the range and the value given), never a traceback."""

import subprocess
import sys
from pathlib import Path

import pytest

from torchquat.cli import MAX_CHUNK_SIZE, main

SAMPLE = str(Path(__file__).resolve().parents[1] / "examples" / "data" / "sample_trajectory.tum")
HUGE = "1000000000000"


def run_cli(argv, capsys):
    """``torchquat ARGV`` in this process: (exit status, stderr)."""
    try:
        status = main(list(argv))
    except SystemExit as stop:  # (argparse's own errors exit from the parser)
        status = stop.code
    return status, capsys.readouterr().err


def assert_one_line_error(status, err, *fragments):
    assert status == 2, err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    for fragment in fragments:
        assert fragment in err, err


@pytest.mark.parametrize("extra, fragments", [
    (["--chunk-size", HUGE], ["--chunk-size", f"from 1 to {MAX_CHUNK_SIZE}", HUGE]),
    (["--chunk-size", "0"], ["--chunk-size", f"from 1 to {MAX_CHUNK_SIZE}", "got 0"]),
    (["--chunk-size", "-1"], ["--chunk-size", "got -1"]),
    (["--chunk-size", "abc"], ["--chunk-size", "'abc'"]),
    (["--chunk-size", ""], ["--chunk-size"]),
    (["--dtype", "float16"], ["--dtype", "float16"]),
    (["--to", ""], ["--to is empty"]),
    (["--to", "euler:"], ["invalid convention ''"]),
    (["--from", ""], ["--from is empty"]),
    (["--times", ""], ["--times is empty"]),
    (["--degrees"], ["--degrees"]),
])
def test_convert_options_out_of_range(extra, fragments, tmp_path, capsys):
    out = tmp_path / "out.csv"
    status, err = run_cli(["convert", SAMPLE, str(out), *extra], capsys)
    assert_one_line_error(status, err, *fragments)
    assert not out.exists()


@pytest.mark.parametrize("args, fragment", [(["", "out.tum"], "IN is empty"), ([SAMPLE, ""], "OUT is empty")])
def test_convert_empty_file_names(args, fragment, capsys):
    assert_one_line_error(*run_cli(["convert", *args], capsys), fragment)


@pytest.mark.parametrize("extra, fragments", [
    (["--n", "0"], ["--n", "from 1 to 10000000", "got 0"]),
    (["--n", "1", HUGE], ["--n", HUGE]),
    (["--n", "-3"], ["--n", "got -3"]),
    (["--n"], ["--n"]),
    (["--threads", "0"], ["--threads", "from 1 to 1024", "got 0"]),
    (["--threads", "100000"], ["--threads", "got 100000"]),
    (["--rounds", "0"], ["--rounds", "from 1 to 1000", "got 0"]),
    (["--rounds", HUGE], ["--rounds", HUGE]),
    (["--min-run-time", "-1"], ["--min-run-time", "from 0 to 3600", "got -1.0"]),
    (["--min-run-time", "nan"], ["--min-run-time", "got nan"]),
    (["--min-run-time", "inf"], ["--min-run-time", "got inf"]),
    (["--seed", "-1"], ["--seed", "got -1"]),
    (["--seed", str(2 ** 64)], ["--seed", str(2 ** 64)]),
    (["--json", ""], ["--json"]),
    (["--device", ""], ["--device"]),
    (["--device", "no_such_device"], ["--device no_such_device"]),
    (["--ops", ""], ["--ops", "''"]),
    (["--peers", ""], ["--peers", "''"]),
    (["--dtype", "int8"], ["--dtype", "int8"]),
    (["--allocator", ""], ["--allocator"]),
])
def test_bench_options_out_of_range(extra, fragments, capsys):
    status, err = run_cli(["bench", "--allocator", "none", *extra], capsys)
    assert_one_line_error(status, err, *fragments)


@pytest.mark.parametrize("extra, fragments", [
    (["--n", "0"], ["--n", "from 1 to 1000000", "got 0"]),
    (["--n", HUGE], ["--n", HUGE]),
    (["--n", "-1"], ["--n", "got -1"]),
    (["--n", "x"], ["--n", "'x'"]),
    (["--seed", "-1"], ["--seed", "got -1"]),
    (["--seed", str(10 ** 20)], ["--seed", str(10 ** 20)]),
    (["--json", ""], ["--json"]),
    (["--dtype", "float16"], ["--dtype"]),
    (["--oracle", ""], ["--oracle"]),
])
def test_crosscheck_options_out_of_range(extra, fragments, capsys):
    status, err = run_cli(["crosscheck", *extra], capsys)
    assert_one_line_error(status, err, *fragments)


def test_a_huge_chunk_size_is_refused_as_a_user_would_meet_it(tmp_path):
    # (it ended in a MemoryError traceback)
    result = subprocess.run([sys.executable, "-m", "torchquat", "convert", SAMPLE, str(tmp_path / "o.tum"),
                             "--chunk-size", HUGE], capture_output=True, text=True, timeout=120)
    assert_one_line_error(result.returncode, result.stderr, "--chunk-size", HUGE)
    assert not (tmp_path / "o.tum").exists()


@pytest.mark.parametrize("module", ["torchquat.bench", "torchquat.crosscheck"])
def test_the_module_entry_points_give_one_line_too(module):
    result = subprocess.run([sys.executable, "-m", module, "--n", "x"], capture_output=True, text=True, timeout=120)
    assert_one_line_error(result.returncode, result.stderr, "--n", "'x'")
