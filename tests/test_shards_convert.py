"""Many files into a folder (SPEC section 9): ``torchquat.io.convert_files`` and ``torchquat convert
IN... OUT/`` on a ``distributed.LocalCluster`` started here, on 127.0.0.1 only."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from torchquat.cli import main
from torchquat.io import convert_file, convert_files
from torchquat.io.shards import is_many_files, plan_files

distributed = pytest.importorskip("distributed")
pytest.importorskip("dask")

KITTI_LINES = 300


@pytest.fixture(scope="module")
def scheduler():
    """A small cluster of two one-thread workers (threads of this process: quick to start), closed at the end."""
    threads = torch.get_num_threads()
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, host="127.0.0.1", protocol="tcp://",
                                       dashboard_address=None)
    try:
        yield cluster.scheduler_address
    finally:
        cluster.close()
        torch.set_num_threads(threads)


def _kitti_lines(shared_data: Path):
    return (shared_data / "KITTI_00_gt.txt").read_text().splitlines()


@pytest.fixture
def shards(tmp_path, shared_data):
    """Six KITTI shards in two folders, and a corrupted one (line 7 has 3 numbers)."""
    lines = _kitti_lines(shared_data)
    root = tmp_path / "in"
    for i in range(6):
        folder = root / f"seq{i % 2}"
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"part{i}.txt").write_text("\n".join(lines[i * KITTI_LINES:(i + 1) * KITTI_LINES]) + "\n")
    (root / "seq0" / "broken.txt").write_text("\n".join(lines[:6] + ["1 2 3"] + lines[6:20]) + "\n")
    return root


def _outputs(folder: Path):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def test_corrupted_shard_among_good_ones(shards, tmp_path, scheduler):
    out = tmp_path / "out"
    summary = convert_files([shards], out, to="tum", scheduler=scheduler)
    assert (len(summary.written), len(summary.skipped), len(summary.failed)) == (6, 0, 1)
    failed = summary.failed[0]
    assert failed.src.endswith("broken.txt") and failed.message.startswith(f"{failed.src}:7: ")
    # nothing for the broken shard, not even a temporary file
    assert _outputs(out) == sorted(f"seq{i % 2}/part{i}.tum" for i in range(6))
    assert all(r.rows == KITTI_LINES for r in summary.written)


def test_each_output_equals_the_one_file_conversion(shards, tmp_path, scheduler):
    out = tmp_path / "out"
    summary = convert_files([shards / "seq0", shards / "seq1"], out, to="euler:ZYX", ext=".csv", degrees=True,
                            scheduler=scheduler)
    assert len(summary.written) == 6
    for result in summary.written:
        alone = tmp_path / "alone.csv"
        convert_file(result.src, alone, to="euler:ZYX", degrees=True)
        assert Path(result.dst).read_bytes() == alone.read_bytes(), result.src


def test_a_worker_converts_on_one_thread_to_the_same_bytes(shards, tmp_path, monkeypatch):
    """On a worker (option one_thread) no read-ahead thread is started; the output is the one-file one."""
    from torchquat.io import streaming
    from torchquat.io.shards import convert_one
    started = []
    monkeypatch.setattr(streaming, "_read_ahead", lambda chunks: started.append(1) or chunks)
    threads = torch.get_num_threads()
    try:
        result = convert_one(str(shards / "seq1" / "part1.txt"), str(tmp_path / "w.tum"), {"to": "tum", "one_thread": True})
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(threads)
    assert (result.status, result.rows, started) == ("written", KITTI_LINES, [])
    convert_one(str(shards / "seq1" / "part1.txt"), str(tmp_path / "here.tum"), {"to": "tum"})
    assert started == [1]  # (in the calling process the read-ahead thread is kept)
    convert_file(shards / "seq1" / "part1.txt", tmp_path / "alone.tum")
    assert (tmp_path / "w.tum").read_bytes() == (tmp_path / "here.tum").read_bytes() == (tmp_path / "alone.tum").read_bytes()


def test_a_second_run_resumes(shards, tmp_path, scheduler):
    out = tmp_path / "out"
    (shards / "seq0" / "broken.txt").unlink()
    first = convert_files([shards], out, to="kitti", scheduler=scheduler)
    assert len(first.written) == 6
    lost = out / "seq1" / "part3.kitti"
    lost.unlink()  # as if the run had been interrupted before this file
    (out / "seq1" / ".part5.kitti.x1y2.tmp").write_text("half")  # a killed worker's temporary file
    os.utime(out / "seq1" / ".part5.kitti.x1y2.tmp", (1, 1))
    second = convert_files([shards], out, to="kitti", scheduler=scheduler)
    assert [Path(r.dst).name for r in second.written] == ["part3.kitti"] and len(second.skipped) == 5
    alone = tmp_path / "alone.kitti"
    convert_file(shards / "seq1" / "part3.txt", alone)
    assert lost.read_bytes() == alone.read_bytes()
    again = convert_files([shards], out, to="kitti", scheduler=scheduler, overwrite=True)
    assert len(again.written) == 6
    assert not list(out.rglob(".*.tmp"))


def test_an_input_newer_than_its_output_is_redone(shards, tmp_path):
    out = tmp_path / "out"
    assert len(convert_files([shards / "seq1"], out, to="tum", workers=1).written) == 3
    os.utime(shards / "seq1" / "part1.txt", (4e9, 4e9))
    summary = convert_files([shards / "seq1"], out, to="tum", workers=1)
    assert [Path(r.src).name for r in summary.written] == ["part1.txt"] and len(summary.skipped) == 2


def test_cli_scheduler_address(shards, tmp_path, scheduler, capsys):
    out = tmp_path / "out"
    status = main(["convert", str(shards), f"{out}/", "--to", "rot6d", "--ext", ".parquet", "--scheduler", scheduler])
    err = capsys.readouterr().err
    assert status == 2
    assert "6 written, 0 skipped, 1 failed" in err
    assert f"error: {shards / 'seq0' / 'broken.txt'}:7: expected 12 numbers" in err
    assert "Traceback" not in err
    assert _outputs(out) == sorted(f"seq{i % 2}/part{i}.parquet" for i in range(6))
    status = main(["convert", str(shards / "seq1"), str(out / "seq1"), "--to", "rot6d", "--ext", "parquet",
                   "--scheduler", scheduler])  # (a folder's files keep their paths relative to it)
    assert status == 0 and "0 written, 3 skipped, 0 failed" in capsys.readouterr().err


def test_cli_local_cluster_of_processes(shards, tmp_path):
    """--workers 2 starts a local cluster of processes (in a fresh interpreter, as a user would)."""
    out = tmp_path / "out"
    (shards / "seq0" / "broken.txt").unlink()
    run = subprocess.run([sys.executable, "-m", "torchquat", "convert", str(shards / "seq*" / "*.txt"), str(out),
                          "--to", "tum", "--workers", "2"], capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr
    assert "6 written, 0 skipped, 0 failed" in run.stderr and "Traceback" not in run.stderr
    assert _outputs(out) == sorted(f"seq{i % 2}/part{i}.tum" for i in range(6))


def test_one_file_takes_the_one_file_path(shards, tmp_path, capsys):
    out = tmp_path / "one.tum"
    assert main(["convert", str(shards / "seq1" / "part1.txt"), str(out)]) == 0
    assert f"wrote {KITTI_LINES} poses to {out}" in capsys.readouterr().err
    assert main(["convert", str(shards / "seq1" / "part1.txt"), str(out), "--workers", "2"]) == 2
    assert "apply to many files" in capsys.readouterr().err


def test_plan_relative_paths_and_names(shards, tmp_path):
    out = tmp_path / "out"
    plan = plan_files([shards / "seq0" / "part0.txt", shards / "seq1" / "part1.txt"], out, to="euroc")
    assert [os.path.relpath(d, out) for _, d in plan] == ["seq0/part0.csv", "seq1/part1.csv"]
    plan = plan_files([str(shards / "**" / "part*.txt")], out)
    assert [os.path.relpath(d, out) for _, d in plan] == sorted(f"seq{i % 2}/part{i}.npz" for i in range(6))
    (shards / "seq1" / "part1.csv").write_text("x")
    with pytest.raises(ValueError, match="would both be written to"):
        plan_files([shards / "seq1"], out, to="quat", ext=".csv")
    with pytest.raises(ValueError, match="matches no file"):
        plan_files([str(shards / "*.nothing")], out)
    with pytest.raises(ValueError, match="ext must be one of"):
        plan_files([shards], out, ext=".tum")
    with pytest.raises(ValueError, match="unknown representation"):
        plan_files([shards], out, to="quaternion")
    assert is_many_files([str(shards)], "x.tum") and not is_many_files([str(shards / "seq0" / "part0.txt")], "x.tum")


def _camera_inputs(root: Path) -> Path:
    """A COLMAP model (with its cameras.txt and points3D.txt), a BOP scene (with scene_camera.json),
    a NeRF transforms_train.json and a TUM file, under root."""
    import json
    (root / "model" / "sparse").mkdir(parents=True)
    (root / "model" / "sparse" / "images.txt").write_text("1 1 0 0 0 1 2 3 1 a.png\n\n2 0.6 0 0.8 0 1 2 4 3 b.png\n\n")
    (root / "model" / "sparse" / "cameras.txt").write_text("1 PINHOLE 640 480 500 500 320 240\n")
    (root / "model" / "sparse" / "points3D.txt").write_text("")
    (root / "scene" / "000001").mkdir(parents=True)
    gt = {"0": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [10, 20, 300], "obj_id": 5}],
          "3": [{"cam_R_m2c": [0, -1, 0, 1, 0, 0, 0, 0, 1], "cam_t_m2c": [1, 2, 3], "obj_id": 2}]}
    (root / "scene" / "000001" / "scene_gt.json").write_text(json.dumps(gt))
    camera = {"0": {"cam_K": [1, 0, 0, 0, 1, 0, 0, 0, 1]}}
    (root / "scene" / "000001" / "scene_camera.json").write_text(json.dumps(camera))
    (root / "nerf").mkdir()
    frame = {"file_path": "./r_0", "transform_matrix": [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]}
    (root / "nerf" / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [frame]}))
    (root / "traj.tum").write_text("0 1 2 3 0 0 0 1\n1 1 2 4 0 0 0 1\n")
    return root


@pytest.mark.parametrize("to, name", [("colmap", "images.txt"), ("nerf", "transforms.json"), ("bop", "scene_gt.json")])
def test_camera_formats_get_their_file_names_in_mirrored_folders(tmp_path, to, name):
    from torchquat.io import read_poses
    root = _camera_inputs(tmp_path / "in")
    out = tmp_path / "out"
    assert main(["convert", str(root), f"{out}/", "--to", to, "--workers", "1"]) == 0
    # (a folder's images.bin, transforms*.json, scene_gt*.json are taken, not cameras.txt or scene_camera.json;
    # an input named as a camera format's file keeps its folder, any other gets a folder of its own name)
    assert _outputs(out) == [f"model/sparse/{name}", f"nerf/transforms_train/{name}", f"scene/000001/{name}",
                             f"traj/{name}"]
    for k, (src, dst) in enumerate(plan_files([root], out, to=to)):  # (each as the one-file conversion writes it)
        one = tmp_path / "one" / str(k) / name
        one.parent.mkdir(parents=True)
        convert_file(src, one, to=to)
        assert Path(dst).read_bytes() == one.read_bytes() and len(read_poses(dst)) == len(read_poses(src))


def test_argument_errors(shards, tmp_path, capsys):
    with pytest.raises(ValueError, match="workers must be a positive integer"):
        convert_files([shards], tmp_path / "out", workers=0)
    with pytest.raises(ValueError, match="not both"):
        convert_files([shards], tmp_path / "out", workers=2, scheduler="tcp://127.0.0.1:1")
    assert main(["convert", str(shards), str(tmp_path / "out"), "--times", "t.txt"]) == 2
    assert "--times" in capsys.readouterr().err
    assert main(["convert", str(shards / "nothing*.txt"), str(tmp_path / "out")]) == 2
    assert "matches no file" in capsys.readouterr().err


def test_unreachable_scheduler_is_one_line(shards, tmp_path, capsys, monkeypatch):
    import torchquat.io.cluster
    monkeypatch.setattr(torchquat.io.cluster, "SCHEDULER_TIMEOUT", "1s")
    status = main(["convert", str(shards), str(tmp_path / "out"), "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert status == 2 and "cannot reach the Dask scheduler" in err and "Traceback" not in err
