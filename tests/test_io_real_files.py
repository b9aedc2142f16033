"""Conversions of the real KITTI, TUM and EuRoC files, checked against SciPy in the test."""

import subprocess
import sys
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

from torchquat.io import read_poses

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation


def run_convert(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "torchquat", "convert", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def data_rows(path: Path, delimiter=None):
    lines = [line for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return [line.split(delimiter) for line in lines]


def same_rotation(q_xyzw_a: np.ndarray, q_xyzw_b: np.ndarray) -> np.ndarray:
    """Angle between rotations given as SciPy quaternions (sign-invariant)."""
    return (Rotation.from_quat(q_xyzw_a).inv() * Rotation.from_quat(q_xyzw_b)).magnitude()


def file_of(shared_data: Path, name: str) -> Path:
    path = shared_data / name
    if not path.exists():
        pytest.skip(f"{name} not in {shared_data}")
    return path


def test_kitti_to_tum_matches_scipy_and_keeps_positions(shared_data, tmp_path):
    src = file_of(shared_data, "KITTI_00_gt.txt")
    out = tmp_path / "kitti.tum"
    result = run_convert(src, out)
    assert result.returncode == 0, result.stderr
    given = np.array(data_rows(src), dtype=float).reshape(-1, 3, 4)
    written = data_rows(out)
    assert len(written) == len(given)
    values = np.array(written, dtype=float)
    np.testing.assert_array_equal(values[:, 0], np.arange(len(given)))  # row index as time
    expected = Rotation.from_matrix(given[:, :, :3]).as_quat()  # SciPy projects to the nearest rotation
    assert same_rotation(values[:, 4:8], expected).max() < 1e-6
    source_text = [row for row in data_rows(src)]
    for i in (0, 1, len(given) // 2, len(given) - 1):  # positions: the same decimal value as the input
        for col, field in zip((1, 2, 3), (3, 7, 11)):
            assert Decimal(written[i][col]) == Decimal(source_text[i][field])


def test_tum_to_euler_csv_matches_scipy(shared_data, tmp_path):
    src = file_of(shared_data, "freiburg1_xyz-groundtruth.txt")
    out = tmp_path / "angles.csv"
    result = run_convert(src, out, "--to", "euler:ZYX", "--degrees")
    assert result.returncode == 0, result.stderr
    lines = out.read_text().splitlines()
    assert lines[0] == "timestamp,x,y,z,ZYX_1_deg,ZYX_2_deg,ZYX_3_deg"
    rows = [line.split(",") for line in lines[1:]]
    given = data_rows(src)
    assert len(rows) == len(given)
    angles = np.array(rows, dtype=float)[:, 4:]
    quats = np.array(given, dtype=float)[:, 4:8]
    expected = Rotation.from_quat(quats).as_euler("ZYX", degrees=True)
    # compare rotations, not angles (angle wrap-around), to the data's 4-decimal precision
    assert same_rotation(Rotation.from_euler("ZYX", angles, degrees=True).as_quat(),
                         Rotation.from_euler("ZYX", expected, degrees=True).as_quat()).max() < 1e-9
    for written, source in zip(rows, given):  # timestamps and positions: same decimal values
        assert [Decimal(v) for v in written[:4]] == [Decimal(v) for v in source[:4]]


def test_euroc_to_tum_and_back_preserves_ns_and_positions(shared_data, tmp_path):
    src = file_of(shared_data, "V102_groundtruth.csv")
    tum, back = tmp_path / "v102.tum", tmp_path / "v102_back.csv"
    assert run_convert(src, tum).returncode == 0
    result = run_convert(tum, back, "--to", "euroc")
    assert result.returncode == 0, result.stderr
    given = data_rows(src, ",")
    tum_rows = data_rows(tum)
    back_rows = data_rows(back, ",")
    assert len(given) == len(tum_rows) == len(back_rows)
    for source, seconds, again in zip(given, tum_rows, back_rows):
        assert Decimal(seconds[0]) * 10**9 == int(source[0])  # ns -> s exactly
        assert again[0] == source[0]  # and back to the same integer
        assert [Decimal(v) for v in again[1:4]] == [Decimal(v) for v in source[1:4]]
    wxyz = np.array(given, dtype=float)[:, 4:8]
    expected = Rotation.from_quat(wxyz, scalar_first=True).as_quat()
    assert same_rotation(np.array(tum_rows, dtype=float)[:, 4:8], expected).max() < 1e-12
    back_wxyz = np.array(back_rows, dtype=float)[:, 4:8]
    assert same_rotation(Rotation.from_quat(back_wxyz, scalar_first=True).as_quat(), expected).max() < 1e-12


def test_read_poses_gives_each_file_in_its_own_representation(shared_data):
    kitti = read_poses(file_of(shared_data, "KITTI_00_gt.txt"))
    tum = read_poses(file_of(shared_data, "freiburg1_xyz-groundtruth.txt"))
    euroc = read_poses(file_of(shared_data, "V102_groundtruth.csv"))
    assert (kitti.representation, tum.representation, euroc.representation) == ("matrix", "quat_xyzw", "quat")
    assert (len(kitti), len(tum), len(euroc)) == (4541, 3000, 16702)
    assert euroc.timestamps_ns[0] == 1403715524907143168
