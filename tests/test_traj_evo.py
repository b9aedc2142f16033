"""torchquat.traj against evo on real data: association, APE and RPE for every relation, with and
without alignment and scale (TUM fr1/xyz with an RGBD-SLAM estimate; KITTI 00 with a perturbed copy)."""

import copy
import itertools

import numpy as np
import pytest
import torch

import torchquat.traj as traj
from torchquat.io import read_poses

evo = pytest.importorskip("evo", reason="evo (the reference implementation) is not installed")
from evo import main_ape, main_rpe  # noqa: E402
from evo.core import geometry, metrics, sync  # noqa: E402
from evo.tools import file_interface  # noqa: E402

ALIGNMENTS = list(itertools.product((False, True), (False, True)))  # (align, scale)
RTOL = 1e-9


def file_of(shared_data, name):
    path = shared_data / name
    if not path.exists():
        pytest.skip(f"{name} not in {shared_data}")
    return path


def assert_close_to_evo(ours: torch.Tensor, theirs: np.ndarray, what: str):
    ours = ours.numpy()
    assert ours.shape == theirs.shape, what
    scale = np.maximum(np.abs(theirs), 1e-12)
    worst = np.max(np.abs(ours - theirs) / scale)
    assert worst <= RTOL, f"{what}: relative difference {worst:.2e}"


@pytest.fixture(scope="module")
def tum(shared_data):
    gt, est = file_of(shared_data, "freiburg1_xyz-groundtruth.txt"), file_of(shared_data, "freiburg1_xyz-rgbdslam.txt")
    ref_evo, est_evo = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(gt)),
                                                   file_interface.read_tum_trajectory_file(str(est)), max_diff=0.01)
    ref, estimate = read_poses(gt), read_poses(est)
    ia, ib = traj.associate(ref.timestamps, estimate.timestamps, max_difference=0.01)
    return ref_evo, est_evo, ref, estimate, ia, ib


def test_association_is_evos(tum):
    ref_evo, est_evo, ref, estimate, ia, ib = tum
    assert len(ia) == 785 == ref_evo.num_poses
    np.testing.assert_array_equal(ref.timestamps[ia.numpy()], ref_evo.timestamps)
    np.testing.assert_array_equal(estimate.timestamps[ib.numpy()], est_evo.timestamps)


@pytest.mark.parametrize("relation", traj.RELATIONS)
def test_tum_ape_and_rpe_equal_evos(tum, relation):
    ref_evo, est_evo, ref, estimate, ia, ib = tum
    r, e = ref[ia.numpy()], estimate[ib.numpy()]
    pose_relation = metrics.PoseRelation[relation]
    for align, scale in ALIGNMENTS:
        expected = main_ape.ape(copy.deepcopy(ref_evo), copy.deepcopy(est_evo), pose_relation, align=align,
                                correct_scale=scale)
        assert_close_to_evo(traj.ape(r, e, relation, align=align, scale=scale), expected.np_arrays["error_array"],
                            f"ape {relation} align={align} scale={scale}")
        for delta, unit in ((1, "frames"), (20, "frames"), (0.05, "meters")):
            expected = main_rpe.rpe(copy.deepcopy(ref_evo), copy.deepcopy(est_evo), pose_relation, delta=delta,
                                    delta_unit=metrics.Unit[unit], align=align, correct_scale=scale)
            ours = traj.rpe(r, e, delta, unit, relation, align=align, scale=scale)
            assert_close_to_evo(ours, expected.np_arrays["error_array"],
                                f"rpe {relation} {delta} {unit} align={align} scale={scale}")
            stats = traj.error_statistics(ours)
            for key, value in expected.stats.items():
                assert float(stats[key]) == pytest.approx(value, rel=RTOL, abs=1e-15), key


@pytest.fixture(scope="module")
def kitti(shared_data, tmp_path_factory):
    """KITTI 00 and a copy perturbed by a drifting rotation, noise and a scale of 1.05, by index."""
    gt = file_of(shared_data, "KITTI_00_gt.txt")
    given = np.loadtxt(gt).reshape(-1, 3, 4)[:1500]
    rng = np.random.default_rng(7)
    Rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    drift = Rotation.from_rotvec(np.cumsum(rng.normal(scale=2e-4, size=(len(given), 3)), axis=0)).as_matrix()
    perturbed = np.empty_like(given)
    perturbed[:, :, :3] = drift @ given[:, :, :3]
    perturbed[:, :, 3] = 1.05 * given[:, :, 3] + rng.normal(scale=0.3, size=(len(given), 3))
    folder = tmp_path_factory.mktemp("kitti")
    ref_path, est_path = folder / "gt.txt", folder / "est.txt"
    np.savetxt(ref_path, given.reshape(-1, 12), fmt="%.17g")
    np.savetxt(est_path, perturbed.reshape(-1, 12), fmt="%.17g")
    return (file_interface.read_kitti_poses_file(str(ref_path)), file_interface.read_kitti_poses_file(str(est_path)),
            read_poses(ref_path), read_poses(est_path), ref_path, est_path)


@pytest.mark.parametrize("relation", traj.RELATIONS)
def test_kitti_by_index_equals_evo(kitti, relation):
    ref_evo, est_evo, ref, est = kitti[:4]
    pose_relation = metrics.PoseRelation[relation]
    for align, scale in ALIGNMENTS:
        expected = main_ape.ape(copy.deepcopy(ref_evo), copy.deepcopy(est_evo), pose_relation, align=align,
                                correct_scale=scale)
        assert_close_to_evo(traj.ape(ref, est, relation, align=align, scale=scale), expected.np_arrays["error_array"],
                            f"kitti ape {relation} {align} {scale}")
    for delta, unit in ((10, "frames"), (100.0, "meters")):
        expected = main_rpe.rpe(copy.deepcopy(ref_evo), copy.deepcopy(est_evo), pose_relation, delta=delta,
                                delta_unit=metrics.Unit[unit], align=True, correct_scale=True)
        assert_close_to_evo(traj.rpe(ref, est, delta, unit, relation, align=True, scale=True),
                            expected.np_arrays["error_array"], f"kitti rpe {relation} {unit}")


def test_align_equals_evos_umeyama(kitti):
    ref_evo, est_evo = kitti[:2]
    x, y = est_evo.positions_xyz, ref_evo.positions_xyz
    for scale in (False, True):
        r, t, s = geometry.umeyama_alignment(x.T, y.T, scale)
        R, T, S = traj.align(torch.from_numpy(x), torch.from_numpy(y), scale=scale)
        np.testing.assert_allclose(R.numpy(), r, rtol=0, atol=1e-9)
        np.testing.assert_allclose(T.numpy(), t, rtol=1e-9, atol=1e-9 * np.abs(t).max())
        assert float(S) == pytest.approx(s, rel=1e-9)


def test_cli_json_equals_evo(kitti, tmp_path):
    import json
    import subprocess
    import sys
    ref_evo, est_evo, _, _, ref_path, est_path = kitti
    out = tmp_path / "ape.json"
    result = subprocess.run([sys.executable, "-m", "torchquat", "eval", str(ref_path), str(est_path), "--align",
                             "--scale", "-r", "angle_deg", "--json", str(out)], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert "associated by index" in result.stderr
    expected = main_ape.ape(ref_evo, est_evo, metrics.PoseRelation.rotation_angle_deg, align=True,
                            correct_scale=True).stats
    written = json.loads(out.read_text())
    assert set(written) == {"rmse", "mean", "median", "std", "min", "max", "sse"}
    for key, value in expected.items():
        assert written[key] == pytest.approx(value, rel=RTOL)
