"""The command line, run as a user would: exit codes, messages on stderr, no tracebacks."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def torchquat(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "torchquat", *map(str, args)], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


def assert_user_error(result: subprocess.CompletedProcess, *fragments: str) -> None:
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in result.stderr


def test_sample_trajectory_converts_to_euler_degrees(tmp_path):
    out = tmp_path / "out.csv"
    result = torchquat("convert", REPO / "examples" / "data" / "sample_trajectory.tum", out, "--to", "euler:ZYX",
                       "--degrees")
    assert result.returncode == 0, result.stderr
    assert "as tum" in result.stderr and "euler:ZYX in degrees" in result.stderr  # says what it assumed
    lines = out.read_text().splitlines()
    assert lines[0] == "timestamp,x,y,z,ZYX_1_deg,ZYX_2_deg,ZYX_3_deg" and len(lines) == 501


def test_malformed_line_gives_file_line_and_exit_2(tmp_path):
    src = tmp_path / "in.txt"
    src.write_text("# header\n" + "0 0 0 0 0 0 0 1\n" * 5 + "0 0 0 0 0 0 1\n" + "0 0 0 0 0 0 0 1\n")
    out = tmp_path / "out.tum"
    out.write_text("old\n")
    result = torchquat("convert", src, out)
    assert_user_error(result, f"{src}:7:", "expected 8")
    assert out.read_text() == "old\n"
    assert sorted(os.listdir(tmp_path)) == ["in.txt", "out.tum"]


@pytest.mark.parametrize("case", ["missing", "unreadable", "unknown_extension", "same_file", "empty", "bad_target",
                                  "ambiguous_output", "chunk_size_0"])
def test_user_errors_exit_2_without_traceback(tmp_path, case):
    good = tmp_path / "good.tum"
    good.write_text("0 0 0 0 0 0 0 1\n")
    args = {
        "missing": (tmp_path / "nope.tum", tmp_path / "o.tum"),
        "unreadable": (tmp_path, tmp_path / "o.tum"),  # a directory
        "unknown_extension": (good.rename(tmp_path / "good.xyz"), tmp_path / "o.tum"),
        "same_file": (good, good),
        "empty": ((tmp_path / "e.txt"), tmp_path / "o.tum"),
        "bad_target": (good, tmp_path / "o.csv", "--to", "euler:ZZX"),
        "ambiguous_output": (good, tmp_path / "o.txt"),
        "chunk_size_0": (good, tmp_path / "o.tum", "--chunk-size", "0"),
    }[case]
    if case == "empty":
        (tmp_path / "e.txt").write_text("")
    result = torchquat("convert", *args)
    assert_user_error(result, "error:")
    assert not (tmp_path / "o.tum").exists()


def test_unreadable_file_permission(tmp_path):
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        pytest.skip("root can read files without read permission")
    src = tmp_path / "locked.tum"
    src.write_text("0 0 0 0 0 0 0 1\n")
    src.chmod(0)
    assert_user_error(torchquat("convert", src, tmp_path / "o.tum"), "Permission denied")


@pytest.mark.parametrize("command", [[], ["convert"], ["crosscheck"], ["bench"]])
def test_help_shows_examples(command):
    result = torchquat(*command, "--help")
    assert result.returncode == 0
    assert "examples:" in result.stdout and "torchquat" in result.stdout


def test_no_command_prints_usage_and_exits_2():
    result = torchquat()
    assert result.returncode == 2 and "convert" in result.stderr


def test_missing_lazy_subcommand_module_is_a_clear_error():
    """crosscheck/bench are imported only when chosen; a missing one is a message, not a traceback."""
    code = ("import sys; sys.modules['torchquat.bench'] = None\n"
            "from torchquat.cli import main; sys.exit(main(['bench']))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert_user_error(result, "torchquat.bench is missing")


def test_convert_does_not_import_the_lazy_subcommands():
    code = ("import sys; from torchquat.cli import main; main(['convert', '--help'])")
    probe = code.replace("main(['convert', '--help'])", "") + (
        "\nimport contextlib, io\nwith contextlib.redirect_stdout(io.StringIO()):\n"
        "    try:\n        main(['convert', '--help'])\n    except SystemExit:\n        pass\n"
        "print(sorted(m for m in sys.modules if m in ('torchquat.bench', 'torchquat.crosscheck')))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert result.stdout.strip().splitlines()[-1] == "[]", result.stderr
