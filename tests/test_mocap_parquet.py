"""A ``Motion`` as Parquet (SPEC section 8): one row per frame, ``<joint>:<column>`` rotation
columns, the skeleton in the schema's metadata; reading it back gives the same motion."""

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import torchquat
from torchquat.io import Motion, Poses, read_bvh, read_motion, read_poses, write_motion, write_poses
from torchquat.io.mocap import motion_format

from test_mocap_cli import convert  # noqa: F401 (a fixture)
from test_mocap_errors import GOOD

pq = pytest.importorskip("pyarrow.parquet")

WALK = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mocapbank_walk.bvh"


@pytest.fixture
def bvh(tmp_path) -> Path:
    """The real walk when it is there (outside the repository), else a small BVH."""
    if WALK.exists():
        return WALK
    path = tmp_path / "small.bvh"
    path.write_text(GOOD)
    return path


def assert_same_motion(back: Motion, motion: Motion) -> None:
    s, t = back.skeleton, motion.skeleton
    assert s.names == t.names and s.parents == t.parents and s.channels == t.channels
    assert s.end_sites == t.end_sites and torch.equal(s.offsets, t.offsets.to(s.offsets.dtype))
    assert back.frame_time == motion.frame_time and back.rotations.dtype == torch.float64
    got = torchquat.convert(back.rotations, back.representation, "matrix", degrees=back.degrees)
    want = torchquat.convert(motion.rotations, motion.representation, "matrix", degrees=motion.degrees)
    assert (got - want).abs().max() <= 1e-12
    assert torch.equal(back.root_positions, motion.root_positions)


@pytest.mark.parametrize("representation", ["rot6d", "quat"])
def test_bvh_to_parquet_and_back_is_the_same_motion(tmp_path, bvh, representation):
    motion = read_bvh(bvh)
    path = tmp_path / "walk.parquet"
    assert write_motion(path, motion, representation) == motion.num_frames
    names = pq.read_schema(path).names
    own = {"rot6d": [f"r6_{i}" for i in range(1, 7)], "quat": ["qw", "qx", "qy", "qz"]}[representation]
    first = motion.skeleton.names[0]
    assert names[:3 + len(own)] == ["root_x", "root_y", "root_z"] + [f"{first}:{c}" for c in own]
    assert len(names) == 3 + len(own) * len(motion.skeleton)
    assert motion_format(path) == "motion"
    back = read_motion(path)
    assert back.representation == representation and back.num_frames == motion.num_frames
    assert_same_motion(back, motion)


def test_euler_degrees_translations_and_extras_survive(tmp_path):
    path = tmp_path / "small.bvh"
    path.write_text(GOOD)
    motion = read_bvh(path)
    moving = torch.arange(motion.num_frames * 6, dtype=torch.float64).reshape(-1, 2, 3)
    motion.translations, motion.extras = moving, {"betas": np.arange(4.0), "gender": np.array("female")}
    out = tmp_path / "m.parquet"
    write_motion(out, motion, "euler:ZXY", degrees=True)
    assert "hips:ZXY_1_deg" in pq.read_schema(out).names and "knee:tz" in pq.read_schema(out).names
    back = read_motion(out)
    assert back.representation == "euler:ZXY" and back.degrees
    assert_same_motion(back, motion)
    assert torch.equal(back.translations, moving)
    assert np.array_equal(back.extras["betas"], np.arange(4.0)) and str(back.extras["gender"]) == "female"


def test_found_by_content_without_the_extension(tmp_path):
    path = tmp_path / "small.bvh"
    path.write_text(GOOD)
    motion = read_bvh(path)
    out = tmp_path / "m.parquet"
    write_motion(out, motion, "rot6d")
    renamed = tmp_path / "m.data"
    shutil.copy(out, renamed)
    assert motion_format(renamed) == "motion"
    assert_same_motion(read_motion(renamed), motion)


def test_cli_bvh_to_rot6d_parquet(tmp_path, bvh, convert):  # noqa: F811
    out = tmp_path / "walk.parquet"
    result = convert(bvh, out, "--to", "rot6d")
    assert result.returncode == 0, result.stderr
    back = read_motion(out)
    assert back.representation == "rot6d"
    assert_same_motion(back, read_bvh(bvh))
    again = tmp_path / "again.bvh"
    assert convert(out, again).returncode == 0  # (a motion Parquet is a motion input too)
    assert read_bvh(again).skeleton.names == back.skeleton.names


def test_a_plain_pose_parquet_still_reads_as_poses(tmp_path):
    poses = Poses(torchquat.random_quat((5,), dtype=torch.float64), "quat", positions=torch.zeros(5, 3,
                  dtype=torch.float64))
    path = tmp_path / "poses.parquet"
    write_poses(path, poses)
    assert motion_format(path) is None
    back = read_poses(path)
    assert back.representation == "quat" and torch.equal(back.rotations, poses.rotations)
    with pytest.raises(Exception, match="not a motion file"):
        read_motion(path)
