"""``torchquat convert`` with motions: BVH and AMASS in, (T, J, k) rotations or BVH out; a bad
frame line gives file:line, exit status 2 and no output."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import torchquat
from torchquat.io import read_bvh

from test_mocap_errors import FIRST_FRAME_LINE, GOOD


def run_convert(*args) -> subprocess.CompletedProcess:
    """The command line in a process of its own (exit status, stderr, no traceback)."""
    return subprocess.run([sys.executable, "-m", "torchquat", "convert", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture
def convert(capfd):
    """The command line in this process (a fresh one costs seconds of imports): a function of the
    arguments returning an object with ``returncode`` and ``stderr``."""
    from torchquat.cli import main
    threads = torch.get_num_threads()  # (convert runs with one thread)

    def run(*args):
        status = main(["convert", *map(str, args)])
        return subprocess.CompletedProcess(args, status, "", capfd.readouterr().err)
    yield run
    torch.set_num_threads(threads)


def test_real_bvh_to_rot6d_npz_and_back_to_bvh(tmp_path, convert):
    src = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mocapbank_walk.bvh"
    if not src.exists():
        pytest.skip(f"{src.name} not found at {src} (real data lives outside the repository)")
    npz, bvh = tmp_path / "walk.npz", tmp_path / "walk.bvh"
    result = convert(src, npz, "--to", "rot6d")
    assert result.returncode == 0, result.stderr
    assert "as bvh" in result.stderr and "wrote 455 frames" in result.stderr
    motion = read_bvh(src)
    with np.load(npz) as data:
        assert data["rotation"].shape == (455, 19, 6)
        assert list(data["joint_names"]) == motion.skeleton.names
        expected = torchquat.matrix_to_rot6d(torchquat.quat_to_matrix(motion.rotations))
        np.testing.assert_allclose(data["rotation"], expected.numpy(), rtol=0, atol=1e-12)
    result = convert(npz, bvh)
    assert result.returncode == 0, result.stderr
    back = read_bvh(bvh)
    assert back.skeleton.channels == motion.skeleton.channels
    assert (back.world()[0] - motion.world()[0]).abs().max() < 1e-4


def test_a_bad_frame_line_exits_2_with_file_and_line_and_writes_nothing(tmp_path, convert):
    lines = GOOD.splitlines()
    lines[FIRST_FRAME_LINE] = "0 1 2 3 4 5 6 7"
    src = tmp_path / "bad.bvh"
    src.write_text("\n".join(lines) + "\n")
    for out, run in ((tmp_path / "out.npz", run_convert), (tmp_path / "out.bvh", convert)):
        result = run(src, out)
        assert result.returncode == 2
        assert f"{src}:{FIRST_FRAME_LINE + 1}: a frame line has 8 numbers" in result.stderr
        assert "Traceback" not in result.stderr
        assert not out.exists()
    assert os.listdir(tmp_path) == ["bad.bvh"]  # no temporary file left behind


def test_bvh_found_by_content_and_by_from(tmp_path, convert):
    src = tmp_path / "capture.txt"  # a BVH under another extension
    src.write_text(GOOD)
    out = tmp_path / "angles.npz"
    result = convert(src, out, "--to", "euler:ZXY", "--degrees")
    assert result.returncode == 0, result.stderr
    with np.load(out) as data:
        np.testing.assert_allclose(data["rotation"][0, 0], [3, 4, 5], atol=1e-12)
        assert bool(data["degrees"]) and str(data["representation"]) == "euler:ZXY"
    src.rename(tmp_path / "capture.dat")
    result = convert(tmp_path / "capture.dat", tmp_path / "q.npy", "--from", "bvh")
    assert result.returncode == 0, result.stderr
    assert np.load(tmp_path / "q.npy").shape == (3, 2, 4)


def test_amass_to_bvh_and_pose_files_refused_as_bvh(tmp_path, convert):
    poses = np.random.default_rng(0).normal(size=(5, 165))
    src = tmp_path / "smplx.npz"
    np.savez(src, poses=poses, trans=np.zeros((5, 3)), mocap_frame_rate=np.array(60.0), gender=np.array("male"))
    out = tmp_path / "smplx.bvh"
    result = convert(src, out, "--to", "bvh")
    assert result.returncode == 0, result.stderr
    assert "as amass (5 frames, 55 joints)" in result.stderr
    back = read_bvh(out)
    assert len(back.skeleton) == 55 and back.frame_time == pytest.approx(1 / 60)
    tum = tmp_path / "poses.tum"
    tum.write_text("0.0 1 2 3 0 0 0 1\n")
    result = convert(tum, tmp_path / "poses.bvh")
    assert result.returncode == 2 and "BVH output needs a motion" in result.stderr
    assert not (tmp_path / "poses.bvh").exists()
    assert torch.is_tensor(back.rotations)
