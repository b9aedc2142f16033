"""The real 455-frame, 19-joint capture: world positions against bvhio, local rotations against
SciPy, and a write+read that keeps the motion (the figures of SPEC section 8)."""

from pathlib import Path

import numpy as np
import pytest

from torchquat.io import read_bvh, write_bvh

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation

NAME = "mocapbank_walk.bvh"


@pytest.fixture(scope="module")
def walk_path() -> Path:
    path = Path(__file__).resolve().parents[1].parent / "shared" / "data" / NAME
    if not path.exists():
        pytest.skip(f"{NAME} not found at {path} (real data lives outside the repository, in ../shared/data)")
    return path


@pytest.fixture(scope="module")
def walk(walk_path):
    return read_bvh(walk_path)


def channel_table(path: Path) -> np.ndarray:
    """The frame lines, read independently of torchquat."""
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Frame Time")) + 1
    return np.array([line.split() for line in lines[start:] if line.strip()], dtype=float)


def test_shape_of_the_capture(walk):
    assert walk.rotations.shape == (455, 19, 4)
    assert walk.skeleton.names[0] == "Hips" and walk.skeleton.parents[0] == -1
    assert walk.frame_time == pytest.approx(0.033333)
    assert sum(site is not None for site in walk.skeleton.end_sites) == 5


def test_world_positions_equal_bvhio_at_every_frame(walk, walk_path):
    bvhio = pytest.importorskip("bvhio")
    root = bvhio.readAsHierarchy(str(walk_path))
    joints = [joint for joint, _, _ in root.layout()]
    assert [j.Name for j in joints] == walk.skeleton.names
    theirs = np.empty((walk.num_frames, len(joints), 3))
    for frame in range(walk.num_frames):
        root.loadPose(frame)
        theirs[frame] = [tuple(j.PositionWorld) for j in joints]
    ours = walk.world()[0].numpy()
    # bvhio computes in float32 (PyGLM vec3): 1e-6 relative to each joint's distance from the origin
    scale = np.linalg.norm(theirs, axis=-1, keepdims=True)
    assert (np.abs(ours - theirs) <= 1e-6 * scale).all(), np.max(np.abs(ours - theirs) / scale)


def test_local_rotations_equal_scipy_from_euler_of_the_channels(walk, walk_path):
    values = channel_table(walk_path)
    column = 0
    for j, channels in enumerate(walk.skeleton.channels):
        rotation = [column + k for k, c in enumerate(channels) if c.endswith("rotation")]
        expected = Rotation.from_euler(walk.skeleton.orders[j], values[:, rotation], degrees=True)
        ours = Rotation.from_quat(walk.rotations[:, j].numpy()[:, [1, 2, 3, 0]])
        assert (ours.inv() * expected).magnitude().max() < 1e-12, walk.skeleton.names[j]
        column += len(channels)
    assert column == values.shape[1]


def test_root_positions_are_the_position_channels(walk, walk_path):
    np.testing.assert_array_equal(walk.root_positions.numpy(), channel_table(walk_path)[:, :3])


def test_write_and_read_keep_the_motion(walk, tmp_path):
    out = tmp_path / "walk.bvh"
    write_bvh(out, walk.to("rot6d"))
    back = read_bvh(out)
    assert back.skeleton.channels == walk.skeleton.channels
    assert back.skeleton.end_sites == walk.skeleton.end_sites
    np.testing.assert_array_equal(back.skeleton.offsets.numpy(), walk.skeleton.offsets.numpy())
    before, after = walk.world()[0].numpy(), back.world()[0].numpy()
    assert np.abs(before - after).max() < 1e-4
    assert np.abs(before - after).max() < 1e-9  # (shortest round-trip digits: far inside the figure)
