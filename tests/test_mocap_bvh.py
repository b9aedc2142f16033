"""BVH semantics on small synthetic files: per-joint orders against SciPy, position channels on any
joint, End Sites and channels kept on write, write+read keeping the motion."""

import numpy as np
import pytest
import torch

from torchquat.io import Motion, Skeleton, read_bvh, write_bvh

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation

# Four joints, each with another channel layout: root XYZ with positions; a ZXY joint; a YXZ
# joint with its own position channels (after its rotations); a one-axis joint; End Sites.
HIERARCHY = """HIERARCHY
ROOT root
{
  OFFSET 1.0 2.0 3.0
  CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
  JOINT spine
  {
    OFFSET 0.0 10.0 0.5
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT arm
    {
      OFFSET 5.0 1.0 -1.0
      CHANNELS 6 Yrotation Xrotation Zrotation Xposition Yposition Zposition
      End Site
      {
        OFFSET 0.0 -7.0 0.0
      }
    }
  }
  JOINT leg
  {
    OFFSET -2.0 -1.0 0.0
    CHANNELS 1 Zrotation
    End Site
    {
      OFFSET 0.0 -9.0 0.0
    }
  }
}
MOTION
"""
ORDERS = {"root": "XYZ", "spine": "ZXY", "arm": "YXZ", "leg": "Z"}
WIDTH = 6 + 3 + 6 + 1


def frames(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = rng.uniform(-170, 170, (count, WIDTH)).round(4)
    values[:, :3] = rng.uniform(-50, 50, (count, 3)).round(4)     # root position
    values[:, 12:15] = rng.uniform(-5, 5, (count, 3)).round(4)    # arm position channels
    values[:, [4, 7, 10]] /= 2  # middle angles within (-90, 90): the decomposition gives them back
    return values.round(4)


def bvh_text(values: np.ndarray, frame_time: str = "0.0083333") -> str:
    rows = "\n".join(" ".join(f"{v:.4f}" for v in row) for row in values)
    return HIERARCHY + f"Frames: {len(values)}\nFrame Time: {frame_time}\n{rows}\n"


@pytest.fixture
def synthetic(tmp_path):
    values = frames(7)
    path = tmp_path / "mixed.bvh"
    path.write_text(bvh_text(values))
    return path, values


def reference_world(values: np.ndarray):
    """World positions by SciPy, one joint at a time (the textbook recursion)."""
    def rot(order, angles):
        return Rotation.from_euler(order, angles, degrees=True)
    out = []
    for row in values:
        r_root = rot("XYZ", row[3:6])
        p_root = row[0:3]
        r_spine = r_root * rot("ZXY", row[6:9])
        p_spine = p_root + r_root.apply([0.0, 10.0, 0.5])
        p_arm = p_spine + r_spine.apply(row[12:15])  # position channels replace the arm's offset
        p_leg = p_root + r_root.apply([-2.0, -1.0, 0.0])
        out.append([p_root, p_spine, p_arm, p_leg])
    return np.array(out)


def test_skeleton_channels_and_end_sites_are_read(synthetic):
    path, values = synthetic
    m = read_bvh(path)
    s = m.skeleton
    assert s.names == ["root", "spine", "arm", "leg"]
    assert s.parents == [-1, 0, 1, 0]
    assert s.orders == ["XYZ", "ZXY", "YXZ", "Z"]
    assert s.end_sites == [None, None, (0.0, -7.0, 0.0), (0.0, -9.0, 0.0)]
    assert m.frame_time == 0.0083333 and m.num_frames == 7
    np.testing.assert_array_equal(m.root_positions.numpy(), values[:, :3])
    np.testing.assert_array_equal(m.translations[:, 2].numpy(), values[:, 12:15])
    np.testing.assert_array_equal(m.translations[:, 3].numpy(), np.tile([-2.0, -1.0, 0.0], (7, 1)))


@pytest.mark.parametrize("joint,columns", [("root", slice(3, 6)), ("spine", slice(6, 9)),
                                           ("arm", slice(9, 12)), ("leg", slice(15, 16))])
def test_each_joint_rotation_is_scipy_intrinsic_euler_of_its_channels(synthetic, joint, columns):
    path, values = synthetic
    m = read_bvh(path)
    j = m.skeleton.index(joint)
    expected = Rotation.from_euler(ORDERS[joint], values[:, columns], degrees=True)
    ours = Rotation.from_quat(m.rotations[:, j].numpy()[:, [1, 2, 3, 0]])
    assert (ours.inv() * expected).magnitude().max() < 1e-12


def test_world_positions_follow_the_textbook_recursion(synthetic):
    path, values = synthetic
    positions, world = read_bvh(path).world()
    np.testing.assert_allclose(positions.numpy(), reference_world(values), rtol=0, atol=1e-11)


@pytest.mark.parametrize("order", [None, "ZYX"])
def test_write_then_read_keeps_the_motion(synthetic, tmp_path, order):
    path, _ = synthetic
    m = read_bvh(path)
    out = tmp_path / "again.bvh"
    assert write_bvh(out, m.to("rot6d"), order=order) == 7
    back = read_bvh(out)
    assert back.skeleton.names == m.skeleton.names and back.skeleton.parents == m.skeleton.parents
    assert back.skeleton.end_sites == m.skeleton.end_sites
    if order is None:  # each joint's own channels, the one-axis joint padded to a full order
        assert back.skeleton.channels[:3] == m.skeleton.channels[:3]
        assert back.skeleton.orders[3] == "ZXY"
    else:
        assert set(back.skeleton.orders) == {"ZYX"}
    angle = torch.stack([back.rotations, m.rotations]).double()
    dot = (angle[0] * angle[1]).sum(-1).abs().clamp(max=1)
    assert (2 * torch.acos(dot)).max() < 1e-7
    np.testing.assert_allclose(back.world()[0].numpy(), m.world()[0].numpy(), rtol=0, atol=1e-9)
    assert back.frame_time == m.frame_time


def test_written_angles_are_the_channels_of_the_file(synthetic, tmp_path):
    path, values = synthetic
    out = tmp_path / "again.bvh"
    write_bvh(out, read_bvh(path))
    text = out.read_text().split("Frame Time:")[1].splitlines()[1:]
    written = np.array([line.split() for line in text], dtype=float)
    np.testing.assert_allclose(written[:, :16], values, rtol=0, atol=1e-9)
    np.testing.assert_allclose(written[:, 16:], 0.0, atol=1e-9)  # the one-axis joint, padded to 'ZXY'


def test_motion_without_bvh_channels_writes_positions_and_default_order(tmp_path):
    skeleton = Skeleton(["a", "b", "c"], [-1, 0, 1], torch.tensor([[0.0, 0, 0], [0, 1, 0], [0, 1, 0]]))
    q = torchquat_random(4, 3)
    root = torch.arange(12.0).reshape(4, 3)
    out = tmp_path / "amass_like.bvh"
    write_bvh(out, Motion(skeleton, q, "quat", root, 0.01))
    back = read_bvh(out)
    assert back.skeleton.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    assert back.skeleton.orders == ["ZXY"] * 3
    np.testing.assert_allclose(back.root_positions.numpy(), root.numpy())
    dot = (back.rotations * q.double()).sum(-1).abs()
    np.testing.assert_allclose(dot.numpy(), 1.0, atol=1e-12)


def torchquat_random(*shape):
    import torchquat
    return torchquat.random_quat(shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)


def test_write_refuses_a_bad_order_and_unwritable_names(synthetic, tmp_path):
    import torchquat
    m = read_bvh(synthetic[0])
    with pytest.raises(torchquat.ConventionError, match="write_bvh: invalid order 'zxy'"):
        write_bvh(tmp_path / "x.bvh", m, order="zxy")
    bad = Motion(Skeleton(["left{arm"], [-1], torch.zeros(1, 3)), torch.zeros(1, 1, 4), "quat", torch.zeros(1, 3), 1)
    with pytest.raises(ValueError, match="write_bvh: joint name 'left{arm'"):
        write_bvh(tmp_path / "y.bvh", bad)
    assert not (tmp_path / "x.bvh").exists() and not (tmp_path / "y.bvh").exists()


def test_motion_to_and_slicing_share_the_skeleton(synthetic):
    m = read_bvh(synthetic[0])
    six = m.to("rot6d")
    assert six.rotations.shape == (7, 4, 6) and six.representation == "rot6d" and six.skeleton is m.skeleton
    euler = m.to("euler:ZXY", degrees=True).to("euler:ZXY")
    np.testing.assert_allclose(euler.to("quat").rotations.numpy(), m.rotations.numpy(), atol=1e-12)
    assert m[2:5].num_frames == 3 and m[2:5].translations.shape == (3, 4, 3)


def test_names_with_spaces_and_braces_on_the_name_line(tmp_path):
    text = HIERARCHY.replace("ROOT root\n{", "ROOT root {").replace("JOINT leg", "JOINT left leg")
    path = tmp_path / "spaces.bvh"
    path.write_text(text + "Frames: 1\nFrame Time: 0.1\n" + " ".join(["0"] * WIDTH) + "\n")
    m = read_bvh(path)
    assert m.skeleton.names == ["root", "spine", "arm", "left leg"]
    write_bvh(tmp_path / "again.bvh", m)
    assert read_bvh(tmp_path / "again.bvh").skeleton.names == m.skeleton.names
