"""forward_kinematics: the textbook per-joint recursion, batch shapes, matrices and quaternions,
gradients, one pass per tree depth, and its errors."""

import pytest
import torch

import torchquat
from torchquat.kinematics import forward_kinematics, tree_levels

# A branching tree, joints not in depth order: depth 0: 3; 1: 0, 5; 2: 1, 4; 3: 2
PARENTS = [3, 0, 1, -1, 5, 3]


def sample(batch=(), joints=6, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    q = torchquat.random_quat((*batch, joints), generator=g, dtype=dtype)
    offsets = torch.randn(joints, 3, generator=g, dtype=dtype)
    root = torch.randn(*batch, 3, generator=g, dtype=dtype)
    return q, offsets, root


def recursion(parents, offsets, q, root):
    """One joint at a time, parents first: the definition."""
    R = torchquat.quat_to_matrix(q)
    world_r, world_p = {}, {}
    pending = list(range(len(parents)))
    while pending:
        for j in list(pending):
            p = parents[j]
            if p == -1:
                world_r[j], world_p[j] = R[..., j, :, :], root
            elif p in world_r:
                world_r[j] = world_r[p] @ R[..., j, :, :]
                world_p[j] = world_p[p] + (world_r[p] @ offsets[..., j, :, None])[..., 0]
            else:
                continue
            pending.remove(j)
    order = range(len(parents))
    return torch.stack([world_p[j] for j in order], -2), torch.stack([world_r[j] for j in order], -3)


@pytest.mark.parametrize("batch", [(), (1,), (5,), (2, 3)], ids=str)
def test_quaternions_match_the_per_joint_recursion(batch):
    q, offsets, root = sample(batch)
    positions, world = forward_kinematics(PARENTS, offsets, q, root)
    expected_p, expected_r = recursion(PARENTS, offsets, q, root)
    assert positions.shape == (*batch, 6, 3) and world.shape == (*batch, 6, 4)
    torch.testing.assert_close(positions, expected_p, rtol=0, atol=1e-12)
    torch.testing.assert_close(torchquat.quat_to_matrix(world), expected_r, rtol=0, atol=1e-12)


def test_matrices_give_the_same_answer_in_matrices():
    q, offsets, root = sample((4,))
    positions, world = forward_kinematics(torch.tensor(PARENTS), offsets, torchquat.quat_to_matrix(q), root)
    expected_p, expected_r = recursion(PARENTS, offsets, q, root)
    assert world.shape == (4, 6, 3, 3)
    torch.testing.assert_close(positions, expected_p, rtol=0, atol=1e-12)
    torch.testing.assert_close(world, expected_r, rtol=0, atol=1e-12)


def test_batch_dims_broadcast_and_per_frame_offsets():
    q, offsets, root = sample((3, 1))
    per_frame = offsets.expand(2, 6, 3) * torch.tensor([1.0, 2.0], dtype=offsets.dtype)[:, None, None]
    positions, _ = forward_kinematics(PARENTS, per_frame, q, root)
    assert positions.shape == (3, 2, 6, 3)
    torch.testing.assert_close(positions[:, 1], recursion(PARENTS, 2 * offsets, q[:, 0], root[:, 0])[0])


def test_float32_in_float32_out():
    q, offsets, root = sample((2,), dtype=torch.float32)
    positions, world = forward_kinematics(PARENTS, offsets, q, root)
    assert positions.dtype == world.dtype == torch.float32


def test_gradcheck_in_float64():
    q, offsets, root = sample((2,))
    inputs = (offsets.requires_grad_(), q.requires_grad_(), root.requires_grad_())
    assert torch.autograd.gradcheck(lambda *x: forward_kinematics(PARENTS, *x), inputs)


def test_one_quaternion_product_per_tree_depth(monkeypatch):
    calls = []
    import torchquat.kinematics
    original = torchquat.kinematics.quat_multiply
    monkeypatch.setattr(torchquat.kinematics, "quat_multiply", lambda p, q: calls.append(p.shape) or original(p, q))
    q, offsets, root = sample((10,), joints=6)
    forward_kinematics(PARENTS, offsets, q, root)
    assert [shape[-2] for shape in calls] == [2, 2, 1]  # depths 1, 2, 3 hold 2, 2 and 1 joints


def test_tree_levels_and_its_errors():
    assert tree_levels(PARENTS) == [[3], [0, 5], [1, 4], [2]]
    with pytest.raises(ValueError, match="exactly one root"):
        tree_levels([-1, -1])
    with pytest.raises(ValueError, match="not reached from the root"):
        tree_levels([-1, 2, 1])
    with pytest.raises(ValueError, match=r"parents\[1\] = 7"):
        tree_levels([-1, 7])


def test_shape_errors_name_the_argument():
    q, offsets, root = sample((2,))
    with pytest.raises(torchquat.ShapeError, match=r"forward_kinematics: expected rotations of shape \(\.\.\., 6, 4\)"):
        forward_kinematics(PARENTS, offsets, q[..., :3], root)
    with pytest.raises(torchquat.ShapeError, match="expected offsets of shape"):
        forward_kinematics(PARENTS, offsets[:5], q, root)
    with pytest.raises(torchquat.ShapeError, match="batch shapes do not broadcast"):
        forward_kinematics(PARENTS, offsets, q, torch.zeros(3, 3, dtype=q.dtype))


def test_runs_under_compile_fullgraph_and_vmap():
    q, offsets, root = sample((4,))
    expected = forward_kinematics(PARENTS, offsets, q, root)
    compiled = torch.compile(lambda o, r, p: forward_kinematics(PARENTS, o, r, p), fullgraph=True, backend="eager")
    for got, want in zip(compiled(offsets, q, root), expected):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    mapped = torch.func.vmap(lambda r, p: forward_kinematics(PARENTS, offsets, r, p)[0])(q, root)
    torch.testing.assert_close(mapped, expected[0], rtol=0, atol=1e-12)
