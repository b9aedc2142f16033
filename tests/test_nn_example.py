"""The training example runs end to end (``--quick``) and writes its table and plot."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "examples" / "train_rotation_head.py"


def test_train_rotation_head_quick_writes_table_and_plot(tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--out", str(tmp_path / "out")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if line.startswith("|")]
    assert lines[0] == "| head | mean (deg) | median (deg) | max (deg) |"
    heads = [line.split("|")[1].strip() for line in lines[2:]]
    assert heads == ["quat", "euler (ZYX)", "axis_angle", "rot6d", "rot9d"]
    for line in lines[2:]:
        mean, median, worst = (float(cell) for cell in line.split("|")[2:5])
        assert 0 <= median <= worst <= 180 and 0 <= mean <= worst
    table = (tmp_path / "out" / "train_rotation_head.md").read_text()
    assert "\n".join(lines) in table
    png = (tmp_path / "out" / "train_rotation_head.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
