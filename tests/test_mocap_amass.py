"""AMASS .npz files (synthetic, in the layout of SMPL-H and SMPL-X captures): rotations, both
frame-rate keys, the kept arrays, and the motion .npz and BVH they convert to."""

import numpy as np
import pytest
import torch

import torchquat
from torchquat.io import read_amass, read_bvh, read_motion, write_motion
from torchquat.io.amass import smpl_skeleton


def amass_file(tmp_path, joints: int, rate_key: str, frames: int = 6, seed: int = 0):
    rng = np.random.default_rng(seed)
    poses = rng.normal(scale=0.8, size=(frames, 3 * joints))
    poses[0, :3] = 0.0  # a zero rotation: axis-angle's singular point
    arrays = {"poses": poses, "trans": rng.normal(size=(frames, 3)), rate_key: np.array(120.0 if joints == 52 else 30),
              "betas": rng.normal(size=16), "gender": np.array("female"), "dmpls": rng.normal(size=(frames, 8))}
    path = tmp_path / f"amass_{joints}.npz"
    np.savez(path, **arrays)
    return path, arrays


@pytest.mark.parametrize("joints,rate_key", [(52, "mocap_framerate"), (55, "mocap_frame_rate"),
                                             (24, "mocap_framerate")])
def test_rotations_are_axis_angle_to_quat_of_each_triple(tmp_path, joints, rate_key):
    path, arrays = amass_file(tmp_path, joints, rate_key)
    m = read_amass(path)
    expected = torchquat.axis_angle_to_quat(torch.from_numpy(arrays["poses"]).reshape(6, joints, 3))
    assert m.representation == "quat" and m.rotations.shape == (6, joints, 4)
    torch.testing.assert_close(m.rotations, expected, rtol=0, atol=0)
    np.testing.assert_array_equal(m.root_positions.numpy(), arrays["trans"])
    assert m.frame_time == pytest.approx(1 / float(arrays[rate_key]))
    assert len(m.skeleton) == joints and m.skeleton.parents[0] == -1


def test_other_arrays_are_kept(tmp_path):
    path, arrays = amass_file(tmp_path, 52, "mocap_framerate")
    m = read_amass(path)
    assert sorted(m.extras) == ["betas", "dmpls", "gender"]
    assert str(m.extras["gender"]) == "female"
    np.testing.assert_array_equal(m.extras["betas"], arrays["betas"])


def test_smpl_family_trees():
    for joints in (24, 52, 55):
        names, parents = smpl_skeleton(joints)
        assert len(names) == len(set(names)) == len(parents) == joints
        assert all(p < j for j, p in enumerate(parents))  # parents come first, as in SMPL
    names, parents = smpl_skeleton(55)
    assert names[22:25] == ["jaw", "left_eye_smplhf", "right_eye_smplhf"] and parents[22:25] == [15, 15, 15]
    assert names[25] == "left_index1" and parents[25] == 20 and parents[54] == 53


@pytest.mark.parametrize("representation", ["rot6d", "euler:ZYX", "matrix"])
def test_motion_npz_round_trip(tmp_path, representation):
    path, _ = amass_file(tmp_path, 52, "mocap_framerate")
    m = read_amass(path)
    out = tmp_path / "motion.npz"
    write_motion(out, m, representation=representation)
    with np.load(out) as data:
        assert data["rotation"].shape[:2] == (6, 52)
        assert list(data["joint_names"][:2]) == ["pelvis", "left_hip"]
        assert str(data["representation"]) == representation
    back = read_motion(out)
    assert back.skeleton.names == m.skeleton.names and back.skeleton.parents == m.skeleton.parents
    dot = (back.quaternions() * m.rotations).sum(-1).abs()
    torch.testing.assert_close(dot, torch.ones_like(dot), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.extras["betas"], m.extras["betas"])


def test_amass_to_bvh_keeps_the_rotations(tmp_path):
    path, arrays = amass_file(tmp_path, 52, "mocap_framerate")
    m = read_amass(path)
    out = tmp_path / "amass.bvh"
    write_motion(out, m)
    back = read_bvh(out)
    order = [back.skeleton.index(name) for name in m.skeleton.names]  # BVH lists joints depth first
    dot = (back.rotations[:, order] * m.rotations).sum(-1).abs()
    torch.testing.assert_close(dot, torch.ones_like(dot), rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.root_positions.numpy(), arrays["trans"], rtol=0, atol=1e-12)
    assert back.frame_time == m.frame_time
