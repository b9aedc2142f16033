"""BOP scene_gt.json: one pose per (image, object) with ids in meta, written back with the same numbers;
unknown keys ignored, missing ones named."""

import json

import numpy as np
import pytest

from torchquat.cli import main
from torchquat.io import PoseFileError, read_poses, write_poses

# Two images of a BOP scene (LM-O style: cam_R_m2c row-major, cam_t_m2c in mm), the second with
# two objects and a key this reader does not use.
SCENE = {
    "0": [{"cam_R_m2c": [0.0963063, 0.99404401, 0.0510079, 0.57332098, -0.0135081, -0.81922001, -0.81365103,
                         0.10814, -0.57120699],
           "cam_t_m2c": [-105.3577515, -117.52119142, 1014.8770132], "obj_id": 1}],
    "3": [{"cam_R_m2c": [0.0950661, 0.98330897, -0.155129, 0.74159598, -0.173913, -0.64791101, -0.66407597,
                         -0.0534489, -0.74575198],
           "cam_t_m2c": [-62.55634, -24.3004, 1026.4199], "obj_id": 5, "visib_fract": 0.8},
          {"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 500], "obj_id": 8}],
}


def _scene(tmp_path, data=SCENE):
    path = tmp_path / "scene_gt.json"
    path.write_text(json.dumps(data))
    return path


def test_one_pose_per_image_and_object_written_back_the_same(tmp_path):
    poses = read_poses(_scene(tmp_path))
    assert poses.meta["image_id"].tolist() == [0, 3, 3] and poses.meta["obj_id"].tolist() == [1, 5, 8]
    assert str(poses.maps) == ("model -> camera, OpenCV camera axes (x right, y down, z forward), "
                               "translations in mm")
    assert poses.positions[0].tolist() == SCENE["0"][0]["cam_t_m2c"]
    assert poses.rotations[1].reshape(9).tolist() == SCENE["3"][0]["cam_R_m2c"]  # (row-major)
    out = tmp_path / "out" / "scene_gt.json"
    out.parent.mkdir()
    write_poses(out, poses)
    back = json.loads(out.read_text())
    expected = {k: [{key: e[key] for key in ("cam_R_m2c", "cam_t_m2c", "obj_id")} for e in v] for k, v in SCENE.items()}
    assert back == expected  # (visib_fract is not a scene_gt key this format keeps)


def test_missing_key_is_named_unknown_ignored(tmp_path, capsys):
    data = json.loads(json.dumps(SCENE))
    del data["3"][1]["cam_t_m2c"]
    with pytest.raises(PoseFileError, match="image 3, object 1: missing cam_t_m2c"):
        read_poses(_scene(tmp_path, data))
    assert main(["convert", str(tmp_path / "scene_gt.json"), str(tmp_path / "o.csv")]) == 2
    assert "image 3, object 1: missing cam_t_m2c" in capsys.readouterr().err
    data["3"][1]["cam_t_m2c"] = [0, 0, 1]
    data["3"][1]["cam_R_m2c"] = [1, 0, 0, 0, 1, 0, 0, 0, 2]
    with pytest.raises(PoseFileError, match="image 3, object 1: cam_R_m2c matrix is not a rotation"):
        read_poses(_scene(tmp_path, data))


def test_bop_to_colmap_and_tum_say_what_they_do(tmp_path, capsys):
    src = _scene(tmp_path)
    assert main(["convert", str(src), str(tmp_path / "poses.tum")]) == 0
    err = capsys.readouterr().err
    assert "c2m = inv(m2c)" in err and "millimetres" not in err and "written in mm, not rescaled" in err
    tum = read_poses(tmp_path / "poses.tum")
    R = np.array(SCENE["0"][0]["cam_R_m2c"]).reshape(3, 3)
    centre = -R.T @ np.array(SCENE["0"][0]["cam_t_m2c"])  # the camera in the model frame, in mm
    assert np.abs(tum.positions[0].numpy() - centre).max() < 1e-9
    (tmp_path / "m").mkdir()
    assert main(["convert", str(src), str(tmp_path / "m" / "images.txt")]) == 0
    assert "the model frame stands for colmap's world frame" in capsys.readouterr().err
    colmap = read_poses(tmp_path / "m" / "images.txt")
    assert np.abs(colmap.positions.numpy() - read_poses(src).positions.numpy()).max() < 1e-12
