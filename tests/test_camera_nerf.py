"""NeRF transforms.json: every field and number kept through a read and write, COLMAP <-> NeRF round
trips within 1e-12 with the convention stated on stderr, and bad frames named by index."""

import json

import numpy as np
import pytest

from torchquat.cli import main
from torchquat.io import PoseFileError, read_poses, write_poses

# Two frames of the NeRF synthetic "lego" scene (transforms_train.json, r_0; transforms_test.json,
# r_0), with nerfstudio's top-level fields and per-frame extras around them.
REAL = {
    "camera_angle_x": 0.6911112070083618,
    "camera_model": "OPENCV",
    "fl_x": 1111.0111084745065, "fl_y": 1111.0111084745065, "cx": 400.0, "cy": 400.0, "w": 800, "h": 800,
    "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
    "aabb_scale": 16,
    "frames": [
        {"file_path": "./train/r_0", "rotation": 0.012566370614359171, "sharpness": 31.752987436300323,
         "transform_matrix": [[-0.9999021887779236, 0.004192245192825794, -0.013345719315111637, -0.05379832163453102],
                              [-0.013988681137561798, -0.2996590733528137, 0.95394366979599, 3.845470428466797],
                              [-4.656612873077393e-10, 0.9540371894836426, 0.29968830943107605, 1.2080823183059692],
                              [0.0, 0.0, 0.0, 1.0]]},
        {"file_path": "./test/r_0", "rotation": 0.031415926535897934, "colmap_im_id": 7,
         "transform_matrix": [[-0.9999999403953552, 0.0, 0.0, 0.0],
                              [0.0, -0.7341099977493286, 0.6790305972099304, 2.737260103225708],
                              [0.0, 0.6790306568145752, 0.7341098785400391, 2.959291696548462],
                              [0.0, 0.0, 0.0, 1.0]]},
    ],
    "applied_transform": [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [-0.0, -0.0, -1.0, -0.0]],
}


def _json(path):
    return json.loads(path.read_text())


def test_real_transforms_json_keeps_every_field_and_number(tmp_path):
    src, out = tmp_path / "transforms.json", tmp_path / "again" / "transforms.json"
    src.write_text(json.dumps(REAL, indent=4))
    out.parent.mkdir()
    poses = read_poses(src)
    assert poses.meta["file_path"].tolist() == ["./train/r_0", "./test/r_0"]
    assert str(poses.maps).startswith("camera -> world, OpenGL")
    write_poses(out, poses)
    assert _json(out) == REAL  # (== on floats: every number is the same float64)
    assert "sharpness" not in _json(out)["frames"][1]  # (a field one frame lacks is not invented)
    assert main(["convert", str(src), str(tmp_path / "cli.json"), "--to", "nerf"]) == 0
    assert _json(tmp_path / "cli.json") == REAL


def _random_c2w(rng, n):
    from scipy.spatial.transform import Rotation
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    m[:, :3, 3] = rng.normal(size=(n, 3)) * 3
    return m


def test_nerf_colmap_nerf_round_trip(tmp_path):
    frames = [{"file_path": f"images/{k:03d}.png", "transform_matrix": m.tolist()}
              for k, m in enumerate(_random_c2w(np.random.default_rng(1), 50))]
    src = tmp_path / "transforms.json"
    src.write_text(json.dumps({"frames": frames}))
    (tmp_path / "sparse").mkdir()
    assert main(["convert", str(src), str(tmp_path / "sparse" / "images.bin")]) == 0
    assert main(["convert", str(tmp_path / "sparse" / "images.bin"), str(tmp_path / "back.json"), "--to", "nerf"]) == 0
    back = _json(tmp_path / "back.json")["frames"]
    assert [f["file_path"] for f in back] == [f["file_path"] for f in frames]
    error = np.abs(np.array([f["transform_matrix"] for f in back]) - np.array([f["transform_matrix"] for f in frames]))
    assert error.max() <= 1e-12


def test_colmap_nerf_colmap_round_trip_and_formula(tmp_path, capsys):
    pycolmap = pytest.importorskip("pycolmap")
    from test_camera_colmap import _model, _pycolmap_poses
    model = _model(tmp_path, seed=3)
    out = tmp_path / "transforms.json"
    assert main(["convert", str(model / "text" / "images.txt"), str(out)]) == 0
    err = capsys.readouterr().err
    assert "c2w = inv(w2c) @ diag(1, -1, -1, 1)" in err and "not moved, recentred or rescaled" in err
    expected = _pycolmap_poses(model / "text")
    nerf = read_poses(out)
    for k, frame in enumerate(_json(out)["frames"]):  # the formula, against pycolmap's own matrices
        w2c = np.eye(4)
        w2c[:3] = pycolmap.Reconstruction(str(model / "text")).images[frame["colmap_im_id"]].cam_from_world().matrix()
        c2w = np.linalg.inv(w2c) @ np.diag([1.0, -1.0, -1.0, 1.0])
        assert np.abs(np.array(frame["transform_matrix"]) - c2w).max() <= 1e-12
    (tmp_path / "back").mkdir()
    write_poses(tmp_path / "back" / "images.txt", nerf, format="colmap")
    back = read_poses(tmp_path / "back" / "images.txt")
    for k, image_id in enumerate(back.meta["image_id"].tolist()):
        q, t, _, name = expected[image_id]
        q_back = back.rotations[k].numpy()
        assert min(np.abs(q_back - q).max(), np.abs(q_back + q).max()) <= 1e-12  # (q and -q: one rotation)
        assert np.abs(back.positions[k].numpy() - t).max() <= 1e-12 and back.meta["name"][k] == name


def _bad(tmp_path, document):
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(document))
    return path


@pytest.mark.parametrize("matrix, why", [
    ([[1, 0, 0, 0], [0, 1, 0, 0]], r"shape \(2, 4\)"),
    ([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]], "rotation part"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "last row"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]], "reflection"),
    ("identity", "not a table of numbers"),
])
def test_bad_transform_matrix_names_the_frame(tmp_path, matrix, why):
    good = np.eye(4).tolist()
    path = _bad(tmp_path, {"frames": [{"transform_matrix": good}, {"transform_matrix": good},
                                      {"file_path": "c", "transform_matrix": matrix}]})
    with pytest.raises(PoseFileError, match=rf"frames\[2\]: transform_matrix is neither a rigid 4x4 nor a rigid "
                       rf"3x4 transform.*{why}"):
        read_poses(path)


def test_rigid_3x4_is_accepted_and_missing_frames_is_named(tmp_path, capsys):
    poses = read_poses(_bad(tmp_path, {"frames": [{"transform_matrix": np.eye(4)[:3].tolist()}]}))
    assert poses.positions.tolist() == [[0.0, 0.0, 0.0]]
    with pytest.raises(PoseFileError, match="needs a top-level object with a list 'frames'"):
        read_poses(_bad(tmp_path, {"camera_angle_x": 0.5}))
    with pytest.raises(PoseFileError, match=r"frames\[0\] has no transform_matrix"):
        read_poses(_bad(tmp_path, {"frames": [{"file_path": "a"}]}))
    assert main(["convert", str(tmp_path / "transforms.json"), str(tmp_path / "o.tum")]) == 2
    assert "frames[0] has no transform_matrix" in capsys.readouterr().err
    (tmp_path / "transforms.json").write_text('{"frames": [\n  {,}]}')
    with pytest.raises(PoseFileError, match=r"transforms.json:2: not valid JSON"):
        read_poses(tmp_path / "transforms.json")
