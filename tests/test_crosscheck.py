"""``torchquat crosscheck``: it passes, covers every convention and oracle, and catches a bug."""

import contextlib
import io
import json
import math
import subprocess
import sys

import pytest
import torch

import torchquat
from torchquat.crosscheck import PK_MISSING, SCIPY_MISSING, main
from torchquat.crosscheck._core import Row, err_angles, err_quat, err_rotvec

pytest.importorskip("scipy")
pytest.importorskip("pytorch_kinematics")

CONVENTIONS = set(torchquat.EULER_CONVENTIONS)


def run_crosscheck(tmp_path, *argv):
    """Run in-process; return (exit status, stdout, stderr, the JSON report)."""
    out, err = io.StringIO(), io.StringIO()
    report = tmp_path / "report.json"
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([*argv, "--json", str(report)])
    data = json.loads(report.read_text()) if report.exists() else None
    return status, out.getvalue(), err.getvalue(), data


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    return run_crosscheck(tmp_path_factory.mktemp("crosscheck"), "--n", "64")


def test_passes_against_both_oracles(default_run):
    status, out, _, data = default_run
    assert status == 0, "\n".join(line for line in out.splitlines() if "FAIL" in line)
    assert data["failed"] == 0 and data["checks"] == len(data["rows"]) > 300
    assert f"{data['checks']} checks, 0 failed" in out


@pytest.mark.parametrize("oracle", ["scipy", "pk"])
@pytest.mark.parametrize("function", ["euler_to_quat", "euler_to_matrix", "matrix_to_euler"])
def test_rows_for_all_24_conventions(default_run, oracle, function):
    expected = CONVENTIONS if (oracle, function) != ("pk", "matrix_to_euler") else {
        c for c in CONVENTIONS if c.isupper()}  # pytorch-kinematics has intrinsic only
    in_json = {r["case"].split(" ")[0] for r in default_run[3]["rows"]
               if r["oracle"] == oracle and r["function"] == function and "one row" not in r["case"]}
    assert in_json == expected
    printed = set()
    for line in default_run[1].split("Worst case")[0].splitlines():  # the full table
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 7 and cells[0] == function and cells[2] == oracle and "one row" not in cells[1]:
            printed.add(cells[1].split(" ")[0])
    assert printed == expected


def test_table_has_every_column_and_the_tolerances(default_run):
    out = default_run[1]
    assert "| function" in out and "max error" in out and "tolerance" in out and "status" in out
    assert "| quat_to_euler" in out and "| scipy " in out and "| pk " in out
    for r in default_run[3]["rows"]:
        assert r["status"] == "PASS" and r["tolerance"] > 0


def test_one_row_at_a_time_rows_for_every_function_with_a_one_row_path(default_run):
    # a call on one row may take a path of its own: checked against SciPy too
    one_row = {r["function"] for r in default_run[3]["rows"] if "one row at a time" in r["case"]}
    assert one_row == {"quat_to_matrix", "matrix_to_quat", "axis_angle_to_quat", "quat_to_axis_angle",
                       "axis_angle_to_matrix", "matrix_to_axis_angle", "quat_rotate", "quat_multiply",
                       "quat_geodesic_distance", "matrix_geodesic_distance", "euler_to_quat", "euler_to_matrix",
                       "quat_to_euler", "matrix_to_euler", "quat_slerp"}


def test_convention_mappings_verified(default_run):
    mapping = [r for r in default_run[3]["rows"] if r["function"] == "convention mapping"]
    assert {r["oracle"] for r in mapping} == {"scipy", "pk"}
    assert all(r["status"] == "PASS" for r in mapping)


def _perturbed(fn, only=None):
    def broken(x, *args, **kwargs):
        y = fn(x, *args, **kwargs)
        return y if only is not None and args[0] != only else y + 1e-6
    return broken


@pytest.mark.parametrize("name, only, failing", [
    ("quat_to_matrix", None, {("quat_to_matrix", case, oracle) for oracle in ("scipy", "pk")
                              for case in ("random", "non-unit q", "small angle", "half turn", "near half turn")}
     | {("quat_to_matrix", case + ", one row at a time", "scipy")
        for case in ("random", "non-unit q", "small angle", "half turn", "near half turn")}),
    ("euler_to_quat", "ZYX", {("euler_to_quat", "ZYX", "scipy"), ("euler_to_quat", "ZYX (rzyx)", "pk"),
                              ("euler_to_quat", "24 conventions, one row at a time", "scipy")}),
])
def test_a_broken_function_fails_and_is_named(tmp_path, monkeypatch, name, only, failing):
    monkeypatch.setattr(torchquat, name, _perturbed(getattr(torchquat, name), only))
    status, out, _, data = run_crosscheck(tmp_path, "--n", "16", "--quiet")
    assert status == 1
    failed = {(r["function"], r["case"], r["oracle"]) for r in data["rows"] if r["status"] == "FAIL"}
    assert failed == failing
    assert f"{len(data['rows'])} checks, {len(failing)} failed" in out
    assert any(line.startswith(f"| {name} ") and "FAIL" in line for line in out.splitlines())


def test_an_exception_is_a_failed_row_not_a_traceback(tmp_path, monkeypatch):
    def boom(*args, **kwargs):
        raise RuntimeError("deliberate")

    monkeypatch.setattr(torchquat, "quat_slerp", boom)
    status, out, _, data = run_crosscheck(tmp_path, "--n", "16", "--oracle", "scipy")
    assert status == 1
    bad = [r for r in data["rows"] if r["status"] == "FAIL"]
    assert {r["function"] for r in bad} == {"quat_slerp"}
    assert all("RuntimeError: deliberate" in r["note"] for r in bad)


def _hide(monkeypatch, *modules):
    for name in list(sys.modules):
        if any(name == m or name.startswith(m + ".") for m in modules):
            monkeypatch.setitem(sys.modules, name, None)
    for m in modules:
        monkeypatch.setitem(sys.modules, m, None)  # importing it now raises ImportError


def test_missing_pytorch_kinematics_says_how_to_install(tmp_path, monkeypatch):
    _hide(monkeypatch, "pytorch_kinematics")
    status, out, err, data = run_crosscheck(tmp_path, "--n", "16")
    assert PK_MISSING in err
    assert "pip install pytorch-kinematics" in err and 'pip install "torchquat[test]"' in err
    assert status == 0 and {r["oracle"] for r in data["rows"]} == {"scipy"}


def test_no_oracle_at_all_is_exit_2(tmp_path, monkeypatch):
    _hide(monkeypatch, "pytorch_kinematics", "scipy")
    status, _, err, data = run_crosscheck(tmp_path, "--n", "16")
    assert status == 2 and data is None
    assert PK_MISSING in err and SCIPY_MISSING in err


def test_requested_oracle_missing_is_exit_2(tmp_path, monkeypatch):
    _hide(monkeypatch, "pytorch_kinematics")
    status, _, err, _ = run_crosscheck(tmp_path, "--n", "16", "--oracle", "pk")
    assert status == 2 and PK_MISSING in err


def test_usage_error_is_exit_2(tmp_path):
    assert run_crosscheck(tmp_path, "--n", "0")[0] == 2


def test_json_into_a_missing_folder_is_exit_2_before_the_run(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys.modules["torchquat.crosscheck"], "crosscheck", lambda *args: pytest.fail("the check ran"))
    assert main(["--json", str(tmp_path / "no" / "report.json")]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert not (tmp_path / "no").exists()


def test_float32_passes(tmp_path):
    status, out, _, data = run_crosscheck(tmp_path, "--n", "32", "--dtype", "float32", "--oracle", "scipy")
    assert status == 0, out
    assert data["dtype"] == "float32" and all(r["tolerance"] >= 1e-7 for r in data["rows"]
                                              if r["function"] != "convention mapping")


def test_does_not_change_torch_state(tmp_path):
    threads, dtype = torch.get_num_threads(), torch.get_default_dtype()
    run_crosscheck(tmp_path, "--n", "8", "--oracle", "scipy")
    assert torch.get_num_threads() == threads and torch.get_default_dtype() == dtype


def test_python_dash_m(tmp_path):
    result = subprocess.run([sys.executable, "-m", "torchquat.crosscheck", "--n", "50"],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert " checks, 0 failed" in result.stdout


def test_tf_axes_mapping_covers_all_24():
    from torchquat.crosscheck._pk import TF_AXES

    assert sorted(TF_AXES.values()) == sorted(CONVENTIONS)
    assert TF_AXES["sxyz"] == "xyz" and TF_AXES["rzyx"] == "ZYX" and TF_AXES["rzxz"] == "ZXZ"


def test_metrics():
    q = torch.tensor([[0.5, 0.5, 0.5, 0.5]], dtype=torch.float64)
    assert err_quat(-q, q) == 0.0
    pi = torch.tensor([math.pi], dtype=torch.float64)
    assert err_angles(pi, -pi) < 1e-15
    v = torch.tensor([[math.pi, 0.0, 0.0]], dtype=torch.float64)
    assert err_rotvec(-v, v) == 0.0  # a half turn about x and about -x agree
    assert err_rotvec(-v / 2, v / 2) == pytest.approx(math.pi)  # a quarter turn: the sign matters
    nan = err_quat(torch.full((1, 4), math.nan), q)
    assert math.isinf(nan) and not Row("f", "c", "o", "m", nan, 1.0).passed


def test_a_seed_out_of_range_is_a_usage_error(tmp_path):
    status, _, err, _ = run_crosscheck(tmp_path, "--n", "3", "--seed", str(10 ** 20))
    assert status == 2 and "--seed" in err  # (was two "(oracle crashed)" rows, exit 1: a failed check)


def test_a_json_that_cannot_be_written_is_exit_2_not_a_failed_check(tmp_path, monkeypatch):
    import torchquat.io.files as files

    def no_space(*_):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(files.os, "replace", no_space)
    status, out, err, data = run_crosscheck(tmp_path, "--n", "3", "-q")
    assert status == 2 and "No space left on device" in err and data is None
    assert " 0 failed" in out
