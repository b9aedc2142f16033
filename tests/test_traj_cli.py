"""``torchquat eval``: statistics, JSON, plot, and the bad inputs (exit 2, one line, no traceback)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from torchquat.cli import main


def write_tum(path, times, positions, quats_xyzw):
    rows = np.column_stack((times, positions, quats_xyzw))
    np.savetxt(path, rows, fmt="%.17g")
    return path


@pytest.fixture
def pair(tmp_path):
    rng = np.random.default_rng(0)
    n = 60
    times = 100 + np.arange(n) * 0.1
    positions = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    ref = write_tum(tmp_path / "ref.tum", times, positions, quats)
    est = write_tum(tmp_path / "est.txt", times[3:] + 0.004, positions[3:] + rng.normal(scale=0.05, size=(n - 3, 3)),
                    quats[3:])
    return ref, est


def test_eval_prints_statistics_and_writes_json(pair, tmp_path, capsys):
    ref, est = pair
    out = tmp_path / "stats.json"
    assert main(["eval", str(ref), str(est), "--align", "--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert "57 pairs within 0.01 s" in captured.err
    assert "rmse" in captured.out and "SE(3) Umeyama alignment" in captured.out
    stats = json.loads(out.read_text())
    assert list(stats) == ["rmse", "mean", "median", "std", "min", "max", "sse"]
    assert 0 < stats["min"] <= stats["median"] <= stats["max"] < 0.5


def test_eval_rpe_in_meters_and_plot(pair, tmp_path):
    pytest.importorskip("matplotlib")
    ref, est = pair
    png = tmp_path / "eval.png"
    assert main(["eval", str(ref), str(est), "--metric", "rpe", "--delta", "2", "--delta-unit", "meters",
                 "--relation", "rotation_angle_deg", "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_no_pair_within_max_difference_exits_2_with_a_hint(pair, capsys):
    ref, est = pair
    assert main(["eval", str(ref), str(est), "--max-difference", "0.001"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--max-difference" in err[0] and "--offset" in err[0]
    assert main(["eval", str(ref), str(est), "--offset", "-0.004", "--max-difference", "0.001"]) == 0


def test_different_lengths_without_times_names_both(tmp_path, capsys):
    rows = np.tile(np.eye(3, 4).ravel(), (5, 1))
    np.savetxt(tmp_path / "a.txt", rows)
    np.savetxt(tmp_path / "b.txt", rows[:4])
    assert main(["eval", str(tmp_path / "a.txt"), str(tmp_path / "b.txt")]) == 2
    err = capsys.readouterr().err
    assert "a.txt has 5 poses" in err and "b.txt 4" in err


def test_colmap_poses_are_evaluated_as_camera_poses_in_the_world(tmp_path, capsys):
    """COLMAP stores world -> camera: eval inverts it (as convert does for TUM) and says so."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(6, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)  # (w, x, y, z): world -> camera rotations
    centres = rng.normal(size=(6, 3)) * 4
    w, x, y, z = q.T
    R = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(6, 3, 3)
    t = -np.einsum("nij,nj->ni", R, centres)  # t = -R c
    def text(values):
        return " ".join(f"{v:.17g}" for v in values)
    images = [f"{k + 1} {text(q[k])} {text(t[k])} 1 im{k}.png\n\n" for k in range(6)]
    (tmp_path / "images.txt").write_text("".join(images))
    tum = [f"{k} {text(centres[k])} {text([-x[k], -y[k], -z[k], w[k]])}\n" for k in range(6)]
    (tmp_path / "gt.tum").write_text("".join(tum))  # (camera -> world: the conjugate, xyzw)
    for relation in ("translation_part", "rotation_angle_deg"):
        assert main(["eval", str(tmp_path / "gt.tum"), str(tmp_path / "images.txt"), "-r", relation]) == 0
        captured = capsys.readouterr()
        assert float(captured.out.split("max")[1].split()[0]) < 1e-9
        assert "images.txt: poses changed from world -> camera" in captured.err and "c2w = inv(w2c)" in captured.err
    assert main(["eval", str(tmp_path / "images.txt"), str(tmp_path / "images.txt")]) == 0  # (both sides)


def test_malformed_file_is_file_and_line(pair, tmp_path):
    ref, _ = pair
    bad = tmp_path / "bad.tum"
    bad.write_text("# header\n1 0 0 0 0 0 0 1\n2 0 zero 0 0 0 0 1\n")
    result = subprocess.run([sys.executable, "-m", "torchquat", "eval", str(ref), str(bad)], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 2
    assert f"{bad}:3:" in result.stderr and "Traceback" not in result.stderr


def test_nan_poses_are_counted_not_fatal(pair, monkeypatch, capsys):
    import torchquat.io
    ref, est = pair
    real = torchquat.io.read_poses

    def read_with_nan(path, *args, **kwargs):  # the readers refuse NaN: put one in after reading
        poses = real(path, *args, **kwargs)
        if str(path) == str(est):
            poses.positions = poses.positions.clone()
            poses.positions[10, 0] = float("nan")
        return poses
    monkeypatch.setattr(torchquat.io, "read_poses", read_with_nan)
    assert main(["eval", str(ref), str(est), "--align", "--scale"]) == 0
    captured = capsys.readouterr()
    assert "1 of 57 errors are NaN" in captured.err
    assert "nan" not in captured.out.lower()


def test_unknown_relation(pair, capsys):
    ref, est = pair
    assert main(["eval", str(ref), str(est), "--relation", "nope"]) == 2
    assert "--relation: expected one of translation_part" in capsys.readouterr().err


def test_eval_is_lazy():
    code = "import sys, torchquat.cli; torchquat.cli.build_parser(); print('torchquat.traj' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60).stdout
    assert out.strip() == "False"
