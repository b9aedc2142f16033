"""Poses.inverse and Poses.to_camera_axes (exact round trips), conversions to the camera's pose in the
world, identifiers as columns of plain outputs, and detection by file name."""

import numpy as np
import pytest
import torch

import torchquat
from torchquat.io import Poses, detect_format, output_plan, read_poses, write_poses
from torchquat.io.cameras import FORMAT_MAPS, PoseMap, to_convention


def _poses(representation, maps, n=64, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    q = q / q.norm(dim=1, keepdim=True)
    rotations = torchquat.convert(q, "quat", representation)
    return Poses(rotations, representation, positions=torch.randn(n, 3, generator=g, dtype=torch.float64) * 10,
                 maps=maps, meta={"image_id": np.arange(n)})


@pytest.mark.parametrize("representation", ["quat", "quat_xyzw", "matrix"])
@pytest.mark.parametrize("fmt", ["colmap", "nerf", "bop"])
def test_camera_axes_round_trip_is_exact(representation, fmt):
    poses = _poses(representation, FORMAT_MAPS[fmt])
    other = "opengl" if FORMAT_MAPS[fmt].camera_axes == "opencv" else "opencv"
    turned = poses.to_camera_axes(other)
    assert turned.maps.camera_axes == other
    back = turned.to_camera_axes(FORMAT_MAPS[fmt].camera_axes)
    assert torch.equal(back.rotations, poses.rotations) and torch.equal(back.positions, poses.positions)
    # and it is the rotation D = diag(1, -1, -1) on the camera's side
    R, Rt = poses.to("matrix").rotations, turned.to("matrix").rotations
    D = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    expected = D @ R if FORMAT_MAPS[fmt].target == "camera" else R @ D
    assert (Rt - expected).abs().max() < 1e-14


@pytest.mark.parametrize("representation", ["quat", "quat_xyzw", "matrix", "rot6d"])
def test_inverse_is_the_inverse_and_round_trips(representation):
    poses = _poses(representation, FORMAT_MAPS["colmap"])
    inverse = poses.inverse()
    assert inverse.maps == FORMAT_MAPS["colmap"].inverse() and inverse.representation == representation
    R, t = poses.to("matrix").rotations, poses.positions
    Ri, ti = inverse.to("matrix").rotations, inverse.positions
    assert (Ri @ R - torch.eye(3, dtype=torch.float64)).abs().max() < 1e-14
    assert (Ri @ t[..., None] + ti[..., None]).abs().max() < 1e-13
    back = inverse.inverse()
    assert back.maps == poses.maps
    if representation != "rot6d":
        assert torch.equal(back.rotations, poses.rotations)  # (a conjugate or transpose: exact)
    assert (back.positions - poses.positions).abs().max() <= 1e-13


def test_colmap_to_world_pose_is_the_camera_centre(tmp_path):
    poses = _poses("quat", FORMAT_MAPS["colmap"], n=5)
    world = to_convention(poses, "tum")
    R = torchquat.quat_to_matrix(poses.rotations)
    centre = -(R.transpose(-1, -2) @ poses.positions[..., None])[..., 0]
    assert (world.positions - centre).abs().max() < 1e-13
    assert world.maps == PoseMap("camera", "world", "opencv")
    assert to_convention(world, "tum") is world  # (already there: nothing changes, nothing noted)


def test_plain_outputs_keep_identifiers(tmp_path):
    poses = _poses("quat", FORMAT_MAPS["colmap"], n=4)
    poses.meta = {"image_id": np.array([3, 5, 7, 9]), "camera_id": np.array([1, 1, 2, 2]),
                  "name": np.array(["a.png", "b,c.png", "d.png", "e.png"])}
    write_poses(tmp_path / "p.csv", poses)
    lines = (tmp_path / "p.csv").read_text().splitlines()
    assert lines[0] == "image_id,camera_id,name,x,y,z,qw,qx,qy,qz" and lines[2].startswith('5,1,"b,c.png",')
    write_poses(tmp_path / "p.npz", poses)
    with np.load(tmp_path / "p.npz") as data:
        assert data["name"].tolist() == poses.meta["name"].tolist() and data["image_id"].tolist() == [3, 5, 7, 9]
    again = read_poses(tmp_path / "p.npz")  # (the camera's pose in the world, as written)
    assert (again.positions - to_convention(poses, "npz").positions).abs().max() == 0


def test_formats_found_by_name(tmp_path):
    assert output_plan(tmp_path / "images.bin") == ("colmap", "quat")
    assert output_plan(tmp_path / "transforms_train.json") == ("nerf", "matrix")
    assert output_plan(tmp_path / "scene_gt.json") == ("bop", "matrix")
    assert output_plan(tmp_path / "poses.txt", "colmap") == ("colmap", "quat")
    with pytest.raises(ValueError, match="nerf output is written to a .json file"):
        output_plan(tmp_path / "poses.txt", "nerf")
    (tmp_path / "anything.json").write_text('{"frames": []}')
    assert detect_format(tmp_path / "anything.json") == "nerf"
    (tmp_path / "gt.json").write_text('{"0": []}')
    assert detect_format(tmp_path / "gt.json") == "bop"
    assert detect_format(tmp_path / "images.txt") == "colmap"
