"""Parquet as a plain pose format (SPEC section 5): the CSV's column names, round trips, errors."""

import subprocess
import sys

import numpy as np
import pytest
import torch

from torchquat.cli import main
from torchquat.io import PoseFileError, Poses, convert_file, read_poses, write_poses
from torchquat.io.plain import rotation_columns

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

REPRESENTATIONS = [("quat", False), ("quat_xyzw", False), ("matrix", False), ("euler:ZYX", False),
                   ("euler:zxz", True), ("axis_angle", False), ("rot6d", False)]


def _poses(n=50, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    q = q / q.norm(dim=1, keepdim=True)
    return Poses(q, "quat", positions=torch.randn(n, 3, generator=g, dtype=torch.float64),
                 timestamps=np.arange(n) * 0.25 + 1e9)


@pytest.mark.parametrize("representation,degrees", REPRESENTATIONS)
def test_round_trip_every_representation(tmp_path, representation, degrees):
    poses = _poses()
    path = tmp_path / "p.parquet"
    assert write_poses(path, poses, representation=representation, degrees=degrees) == len(poses)
    names = pq.read_schema(path).names
    assert names == ["timestamp", "x", "y", "z"] + rotation_columns(representation, degrees)
    back = read_poses(path)
    assert back.representation == representation and back.degrees == degrees
    expected = poses.to(representation, degrees=degrees)
    assert torch.equal(back.rotations, expected.rotations.reshape(back.rotations.shape))
    assert torch.equal(back.positions, poses.positions) and np.array_equal(back.timestamps, poses.timestamps)


def test_same_columns_and_values_as_the_csv(tmp_path, shared_data):
    src = shared_data / "freiburg1_xyz-groundtruth.txt"
    convert_file(src, tmp_path / "a.csv", to="euler:ZYX", degrees=True)
    convert_file(src, tmp_path / "a.parquet", to="euler:ZYX", degrees=True)
    csv = np.loadtxt(tmp_path / "a.csv", delimiter=",", skiprows=1)
    table = pq.read_table(tmp_path / "a.parquet")
    assert table.column_names == open(tmp_path / "a.csv").readline().strip().split(",")
    assert np.array_equal(np.stack([c.to_numpy() for c in table.columns], axis=1), csv)


def test_chunks_and_row_groups(tmp_path, monkeypatch):
    import torchquat.io.parquet as parquet
    monkeypatch.setattr(parquet, "ROW_GROUP_ROWS", 64)
    poses = _poses(1000)
    path = tmp_path / "p.parquet"
    write_poses(path, (poses[i:i + 100] for i in range(0, 1000, 100)))
    assert pq.ParquetFile(path).metadata.num_row_groups == 10
    back = read_poses(path)
    assert torch.equal(back.rotations, poses.rotations) and len(back) == 1000


def test_cli_round_trip_through_parquet(tmp_path, shared_data):
    src = shared_data / "KITTI_00_gt.txt"
    assert main(["convert", str(src), str(tmp_path / "k.parquet"), "--to", "rot6d", "--dtype", "float32"]) == 0
    assert pq.read_schema(tmp_path / "k.parquet").field("r6_1").type == pa.float32()
    assert main(["convert", str(tmp_path / "k.parquet"), str(tmp_path / "k.kitti")]) == 0
    a = np.loadtxt(src)
    b = np.loadtxt(tmp_path / "k.kitti")
    np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-6)  # float32: 7 digits


def test_euroc_times_survive(tmp_path, shared_data):
    src = shared_data / "V102_groundtruth.csv"
    convert_file(src, tmp_path / "v.parquet")
    convert_file(tmp_path / "v.parquet", tmp_path / "v.csv", to="euroc")
    ns = np.loadtxt(src, delimiter=",", usecols=0, dtype=np.int64)
    back = np.loadtxt(tmp_path / "v.csv", delimiter=",", usecols=0, dtype=np.int64)
    assert np.abs(back - ns).max() < 1000  # float64 seconds: well under a microsecond


def test_bad_files_are_named(tmp_path):
    path = tmp_path / "bad.parquet"
    path.write_bytes(b"not parquet at all")
    with pytest.raises(PoseFileError, match="not a readable Parquet file"):
        read_poses(path)
    pq.write_table(pa.table({"a": [1.0], "b": [2.0]}), path)
    with pytest.raises(PoseFileError, match="unrecognised CSV header 'a,b'"):
        read_poses(path)
    pq.write_table(pa.table({"qw": [1.0, None], "qx": [0.0] * 2, "qy": [0.0] * 2, "qz": [0.0] * 2}), path)
    with pytest.raises(PoseFileError, match=r"column 'qw' row 1 is missing \(null\)"):
        read_poses(path)
    pq.write_table(pa.table({"qw": [1.0, 2.0], "qx": [0.0] * 2, "qy": [0.0] * 2, "qz": [0.0] * 2}), path)
    with pytest.raises(PoseFileError, match="rotation row 1"):
        read_poses(path)
    pq.write_table(pa.table({"qw": ["1"], "qx": [0.0], "qy": [0.0], "qz": [0.0]}), path)
    with pytest.raises(PoseFileError, match="column 'qw' has type string, not numbers"):
        read_poses(path)


def test_without_pyarrow_the_error_names_the_extra(tmp_path):
    code = ("import sys; sys.modules['pyarrow'] = None\n"
            "from torchquat.cli import main\n"
            f"sys.exit(main(['convert', {str(tmp_path / 'a.tum')!r}, {str(tmp_path / 'a.parquet')!r}]))")
    (tmp_path / "a.tum").write_text("0 1 2 3 0 0 0 1\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "need pyarrow" in run.stderr and "torchquat[dask]" in run.stderr
    assert not (tmp_path / "a.parquet").exists()


def test_colmap_identifiers_survive_parquet(tmp_path):
    from test_camera_conventions import _colmap_to, _same_world_poses_and_ids
    source, back = _colmap_to(tmp_path, "parquet")
    assert pq.read_schema(tmp_path / "p.parquet").names[:3] == ["image_id", "camera_id", "name"]
    _same_world_poses_and_ids(source, back)
