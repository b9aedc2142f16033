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


IMAGES_TXT = ("# COLMAP images.txt\n1 0.5 0.5 0.5 0.5 1 2 3 1 my image.png\n\n"
              "4 0 1 0 0 0 0 1 2 b,c.png\n2.5 3.5 -1\n9 0.6 0 0.8 0 -4 5 6.25 1 x.jpg\n\n")


def _colmap_to(tmp_path, suffix):
    """images.txt -> p.SUFFIX by the command line; (what was read, what reads back)."""
    from torchquat.cli import main
    (tmp_path / "images.txt").write_text(IMAGES_TXT)
    assert main(["convert", str(tmp_path / "images.txt"), str(tmp_path / f"p.{suffix}")]) == 0
    return read_poses(tmp_path / "images.txt"), read_poses(tmp_path / f"p.{suffix}")


def _same_world_poses_and_ids(source, back):
    world = to_convention(source, "tum")  # (what a plain output holds: the camera's pose in the world)
    assert torch.equal(back.rotations, world.rotations) and torch.equal(back.positions, world.positions)
    assert back.meta.keys() == source.meta.keys() == {"image_id", "camera_id", "name"}
    for key, values in source.meta.items():
        assert back.meta[key].dtype.kind == values.dtype.kind and back.meta[key].tolist() == values.tolist()


def test_colmap_csv_reads_back_with_its_identifiers(tmp_path):
    source, back = _colmap_to(tmp_path, "csv")
    assert (tmp_path / "p.csv").read_text().splitlines()[0] == "image_id,camera_id,name,x,y,z,qw,qx,qy,qz"
    _same_world_poses_and_ids(source, back)
    assert back.meta["name"].tolist() == ["my image.png", "b,c.png", "x.jpg"]
    (tmp_path / "again").mkdir()
    write_poses(tmp_path / "again" / "images.txt", back)
    again = read_poses(tmp_path / "again" / "images.txt")  # (and back to COLMAP: the same ids and numbers)
    assert again.meta["name"].tolist() == source.meta["name"].tolist()
    assert (again.positions - source.positions).abs().max() < 1e-14


def test_identifier_columns_errors_name_the_line(tmp_path):
    from torchquat.io import PoseFileError
    path = tmp_path / "ids.csv"
    path.write_text("image_id,name,x,y,z,qw,qx,qy,qz\n1,a.png,0,0,0,1,0,0,0\n2.5,b.png,0,0,0,1,0,0,0\n")
    with pytest.raises(PoseFileError, match=r"ids.csv:3: column 'image_id' holds '2.5'"):
        read_poses(path)
    path.write_text("image_id,name,x,y,z,qw,qx,qy,qz\n# c\n1,0,0,0,1,0,0,0\n")
    with pytest.raises(PoseFileError, match=r"ids.csv:3: expected 9 columns"):
        read_poses(path)


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
