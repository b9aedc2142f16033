"""COLMAP images.txt / images.bin: read as pycolmap reads them, written so that pycolmap reads them,
streamed in chunks, and malformed or truncated files reported with file:line or the byte offset."""

import shutil

import numpy as np
import pytest
import torch

from torchquat.cli import main
from torchquat.io import PoseFileError, iter_poses, read_poses, write_poses

pycolmap = pytest.importorskip("pycolmap")

NAMES = ["img_000.jpg", "cam1/img_001.jpg", "frame-02.png", "x.JPG", "img_004.jpg", "a/b/c.png", "img_006.jpg"]


def _model(folder, seed=0):
    """A pycolmap reconstruction of 7 images on 2 cameras (ids not contiguous, some w < 0),
    written as text to folder/text and binary to folder/bin."""
    rng = np.random.default_rng(seed)
    model = pycolmap.Reconstruction()
    for camera_id in (1, 3):
        model.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=640, height=480,
                                                          params=[500.0, 501.0, 320.0, 240.0], camera_id=camera_id))
    for k, name in enumerate(NAMES):
        xyzw = rng.normal(size=4)
        xyzw /= np.linalg.norm(xyzw)
        image = pycolmap.Image(name=name, camera_id=(1, 3)[k % 2], image_id=10 + 3 * k)
        model.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(xyzw), rng.normal(size=3) * 5))
    for kind in ("text", "bin"):
        (folder / kind).mkdir()
    model.write_text(str(folder / "text"))
    model.write_binary(str(folder / "bin"))
    return folder


@pytest.fixture(scope="module")
def colmap_model(tmp_path_factory):
    return _model(tmp_path_factory.mktemp("colmap"))


def _pycolmap_poses(folder):
    """{image_id: (q wxyz, t, camera_id, name)} as pycolmap reads the model in ``folder``."""
    model = pycolmap.Reconstruction(str(folder))
    out = {}
    for image_id, image in model.images.items():
        pose = image.cam_from_world()
        x, y, z, w = pose.rotation.quat  # (pycolmap's Rotation3d.quat is xyzw)
        out[image_id] = (np.array([w, x, y, z]), np.asarray(pose.translation), image.camera_id, image.name)
    return out


@pytest.mark.parametrize("kind, file", [("text", "images.txt"), ("bin", "images.bin")])
def test_every_image_reads_as_pycolmap_reads_it(colmap_model, kind, file):
    poses = read_poses(colmap_model / kind / file)
    expected = _pycolmap_poses(colmap_model / kind)
    assert poses.representation == "quat" and str(poses.maps).startswith("world -> camera, OpenCV")
    assert sorted(poses.meta["image_id"].tolist()) == sorted(expected)
    for k, image_id in enumerate(poses.meta["image_id"].tolist()):
        q, t, camera_id, name = expected[image_id]
        assert np.abs(poses.rotations[k].numpy() - q).max() <= 1e-12
        assert np.abs(poses.positions[k].numpy() - t).max() <= 1e-12
        assert poses.meta["camera_id"][k] == camera_id and poses.meta["name"][k] == name


@pytest.mark.parametrize("kind, file", [("text", "images.txt"), ("bin", "images.bin")])
def test_pycolmap_reads_what_we_write(colmap_model, tmp_path, kind, file):
    poses = read_poses(colmap_model / kind / file)
    out = tmp_path / "model"
    out.mkdir()
    for other in (colmap_model / kind).iterdir():  # the model's other files, as they were
        if other.name not in ("images.txt", "images.bin", "frames.txt", "frames.bin", "rigs.txt", "rigs.bin"):
            shutil.copy(other, out / other.name)
    write_poses(out / file, poses)
    ours, theirs = _pycolmap_poses(out), _pycolmap_poses(colmap_model / kind)
    assert ours.keys() == theirs.keys()
    for image_id, (q, t, camera_id, name) in theirs.items():
        assert np.array_equal(ours[image_id][0], q) and np.array_equal(ours[image_id][1], t)
        assert ours[image_id][2:] == (camera_id, name)


def test_text_and_binary_stream_in_chunks(colmap_model):
    for path in (colmap_model / "text" / "images.txt", colmap_model / "bin" / "images.bin"):
        chunks = list(iter_poses(path, chunk_size=3))
        assert [len(c) for c in chunks] == [3, 3, 1]
        whole = read_poses(path)
        assert torch.equal(torch.cat([c.rotations for c in chunks]), whole.rotations)
        assert np.concatenate([c.meta["name"] for c in chunks]).tolist() == whole.meta["name"].tolist()


def test_points_lines_are_skipped_and_names_keep_spaces(tmp_path):
    path = tmp_path / "images.txt"
    path.write_text("# comment\n\n1 1 0 0 0 1 2 3 1 my image.png\n1.5 2.5 -1 3 4 7\n"
                    "2 0 1 0 0 0 0 0 2 b.png\n\n")
    poses = read_poses(path)
    assert poses.meta["name"].tolist() == ["my image.png", "b.png"]  # (COLMAP itself stops at the space)
    assert poses.meta["camera_id"].tolist() == [1, 2]
    assert poses.positions.tolist() == [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]


def test_malformed_line_names_file_and_line_exit_2_nothing_written(colmap_model, tmp_path, capsys):
    lines = (colmap_model / "text" / "images.txt").read_text().splitlines(keepends=True)
    data = [i for i, line in enumerate(lines) if line.strip() and not line.startswith("#")]
    bad = data[4]  # the third image's line (each image has a points line after it)
    lines[bad] = lines[bad].replace(" ", " x", 1)
    src = tmp_path / "images.txt"
    src.write_text("".join(lines))
    out = tmp_path / "out.tum"
    assert main(["convert", str(src), str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{src}:{bad + 1}:" in err and "IMAGE_ID QW QX QY QZ" in err and "Traceback" not in err
    assert not out.exists()


def test_truncated_binary_names_the_byte_offset(colmap_model, tmp_path, capsys):
    data = (colmap_model / "bin" / "images.bin").read_bytes()
    for cut in (5, 40, len(data) - 3):
        src = tmp_path / "images.bin"
        src.write_bytes(data[:cut])
        with pytest.raises(PoseFileError, match=rf"truncated: the file ends at byte {cut} in "):
            read_poses(src)
    assert main(["convert", str(src), str(tmp_path / "out.tum")]) == 2
    assert f"{src}: truncated: the file ends at byte {len(data) - 3}" in capsys.readouterr().err
    assert not (tmp_path / "out.tum").exists()


def test_binary_with_points_skips_them(tmp_path):
    """2D points (24 bytes each) between images are stepped over, also across read blocks."""
    import struct
    from torchquat.io import colmap
    body = b""
    for k in range(3):
        points = [200_000, 0, 5][k]  # 4.8 MB of points: more than one read block
        body += struct.pack("<I7dI", k + 1, 1, 0, 0, 0, k, 0, 0, 1) + f"n{k}".encode() + b"\0"
        body += struct.pack("<Q", points) + bytes(24 * points)
    path = tmp_path / "images.bin"
    path.write_bytes(struct.pack("<Q", 3) + body)
    poses = read_poses(path)
    assert poses.meta["name"].tolist() == ["n0", "n1", "n2"] and poses.positions[:, 0].tolist() == [0, 1, 2]
    assert colmap.is_binary(path) and not colmap.is_binary(tmp_path / "images.txt")
