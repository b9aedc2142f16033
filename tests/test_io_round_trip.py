"""Values written read back exactly; every plain representation recovers itself from its columns."""

import numpy as np
import pytest
import torch

import torchquat
from torchquat.io import Poses, iter_poses, read_poses, write_poses
from torchquat.io.numtext import format_floats, format_nanoseconds, format_rows


def sample_values(rng) -> np.ndarray:
    return np.concatenate([
        rng.standard_normal(4000) * 10.0 ** rng.integers(-20, 20, 4000),
        np.round(rng.standard_normal(2000), 6), rng.random(2000) * 2 - 1,
        [0.0, -0.0, 1.0, -1.0, 0.1, 1 / 3, 1e16, 9.999999999999999e15, 1e-5, 9.99e-6, 5e-324, 1.7976931348623157e308],
    ])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_formatted_floats_parse_back_to_the_same_value(dtype):
    with np.errstate(over="ignore"):
        values = sample_values(np.random.default_rng(0)).astype(dtype)
    values = values[np.isfinite(values)]
    text = format_rows([format_floats(values[:, None])])
    back = np.array(text.split(), dtype=dtype)
    np.testing.assert_array_equal(back, values)
    # and as short as the shortest repr for values that came from short decimals (float32's: numpy's,
    # from the float32 rounding interval, not the float64 one of its exact value: 0.6305, not 0.630500019)
    short = np.round(np.random.default_rng(1).standard_normal(1000), 5).astype(dtype)
    words = format_rows([format_floats(short[:, None])]).decode().split()
    shortest = repr if dtype == np.float64 else str
    assert all(dtype(w) == v and len(w) <= len(shortest(v)) for w, v in zip(words, short))
    assert format_rows([format_floats(np.array([[0.6305, 1.638, -0.3311]], dtype=dtype))]) == b"0.6305 1.638 -0.3311\n"


def test_nanoseconds_are_written_exactly():
    ns = np.array([0, 1, 999_999_999, 1_000_000_000, 1403715524907143168, -5])
    words = format_rows([format_nanoseconds(ns)]).decode().split()
    from decimal import Decimal
    assert [int(Decimal(w) * 10**9) for w in words] == ns.tolist()


REPRESENTATIONS = [(name, False) for name in ("quat", "quat_xyzw", "matrix", "euler:ZYX", "euler:xzx", "axis_angle",
                                               "rot6d")] + [("euler:ZYX", True), ("euler:xzx", True)]


@pytest.mark.parametrize("representation,degrees", REPRESENTATIONS)
@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_plain_files_recover_their_representation(tmp_path, representation, degrees, suffix):
    q = torchquat.quat_standardize(
        torchquat.random_quat((50,), generator=torch.Generator().manual_seed(3), dtype=torch.float64))
    poses = Poses(q, "quat", positions=torch.randn(50, 3, dtype=torch.float64),
                  timestamps_ns=np.arange(50, dtype=np.int64) * 33_333_333 + 10**18)
    path = tmp_path / f"poses{suffix}"
    write_poses(path, poses, representation=representation, degrees=degrees)
    back = read_poses(path)
    assert back.representation == representation and back.degrees == (degrees and "euler" in representation)
    expected = torchquat.convert(q, "quat", representation, degrees=degrees)
    torch.testing.assert_close(back.rotations, expected, rtol=0, atol=0)
    torch.testing.assert_close(back.positions, poses.positions, rtol=0, atol=0)
    np.testing.assert_array_equal(back.timestamps_ns, poses.timestamps_ns)


def test_npy_holds_the_rotation_array_alone(tmp_path):
    q = torchquat.random_quat((10,), dtype=torch.float64)
    write_poses(tmp_path / "r.npy", Poses(q, "quat"), representation="matrix")
    array = np.load(tmp_path / "r.npy")
    assert array.shape == (10, 3, 3)
    back = read_poses(tmp_path / "r.npy")
    assert back.representation == "matrix"
    torch.testing.assert_close(back.to("quat").rotations, torchquat.quat_standardize(q))


def test_streaming_yields_bounded_chunks_in_order(tmp_path):
    path = tmp_path / "t.tum"
    path.write_text("".join(f"{i} 0 0 {i} 0 0 0 1\n" for i in range(95)))
    chunks = list(iter_poses(path, chunk_size=10))
    assert [len(c) for c in chunks] == [10] * 9 + [5]
    np.testing.assert_array_equal(np.concatenate([c.positions[:, 2].numpy() for c in chunks]), np.arange(95))


def test_kitti_times_file_gives_the_time_of_each_row(tmp_path):
    (tmp_path / "p.kitti").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    (tmp_path / "times.txt").write_text("0.000000e+00\n1.036594e-01\n2.073190e-01\n")
    from torchquat.io import convert_file
    convert_file(tmp_path / "p.kitti", tmp_path / "p.tum", times=tmp_path / "times.txt")
    rows = [line.split() for line in (tmp_path / "p.tum").read_text().splitlines() if not line.startswith("#")]
    assert [float(r[0]) for r in rows] == [0.0, 0.1036594, 0.207319]
