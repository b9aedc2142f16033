"""Forward kinematics over a joint tree: local rotations and offsets to world poses.

The tree is walked one depth at a time: every joint at depth ``d`` gathers its parent's world
pose from depth ``d - 1`` and is composed in one batched product, so the work is one pass per
tree depth (7 for a 19-joint BVH body, 16 for SMPL-H hands), not one per joint.
"""

from typing import List, Sequence, Tuple, Union

import torch
from torch import Tensor

from .errors import ShapeError
from .quaternion import quat_multiply, quat_rotate

__all__ = ["forward_kinematics", "tree_levels"]

Parents = Union[Sequence[int], Tensor]


def tree_levels(parents: Parents, fn: str = "tree_levels") -> List[List[int]]:
    """Group the joints of a tree by depth.

    Args:
        parents: the parent index of each joint, ``-1`` for the root (exactly one root).
        fn: the calling function's name, for error messages.

    Returns:
        ``levels[d]``: the indices of the joints at depth ``d``, in index order.

    Example:
        >>> tree_levels([-1, 0, 1, 0])
        [[0], [1, 3], [2]]
    """
    parents = [int(p) for p in (parents.tolist() if isinstance(parents, Tensor) else parents)]
    count = len(parents)
    bad = [j for j, p in enumerate(parents) if not -1 <= p < count or p == j]
    if bad:
        raise ValueError(f"{fn}: expected parents in [-1, {count}) and not the joint itself, got "
                         f"parents[{bad[0]}] = {parents[bad[0]]}")
    roots = [j for j, p in enumerate(parents) if p == -1]
    if len(roots) != 1:
        raise ValueError(f"{fn}: expected exactly one root (parent -1) in parents, got {len(roots)}")
    children: List[List[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    levels, seen = [roots], 1
    while True:
        below = sorted(c for j in levels[-1] for c in children[j])
        if not below:
            break
        levels.append(below)
        seen += len(below)
    if seen != count:  # joints never reached from the root sit on a cycle
        raise ValueError(f"{fn}: parents do not form a tree: {count - seen} joints are not reached from the root")
    return levels


def forward_kinematics(parents: Parents, offsets: Tensor, rotations: Tensor,
                       root_positions: Tensor) -> Tuple[Tensor, Tensor]:
    """World positions and world rotations of every joint from local rotations along a tree.

    A joint's world rotation is its parent's world rotation times its local rotation; its world
    position is its parent's world position plus the parent's world rotation applied to the
    joint's offset. The root sits at ``root_positions`` with its local rotation (its own offset is
    not added: BVH position channels replace the root's offset, as bvhio reads them).

    Args:
        parents: parent index of each joint (``-1`` for the one root), a sequence or 1-D tensor.
        offsets: each joint's translation from its parent, in the parent's frame, ``(J, 3)`` or
            per frame ``(..., J, 3)``.
        rotations: local rotations as quaternions ``(..., J, 4)`` (``w, x, y, z``) or matrices
            ``(..., J, 3, 3)``.
        root_positions: world position of the root, ``(..., 3)``.

    Returns:
        ``(positions, world_rotations)``: ``(..., J, 3)`` and the rotations in the input's
        representation, ``(..., J, 4)`` or ``(..., J, 3, 3)``.

    Shape:
        The leading dims of the three tensors broadcast. Differentiable in all three.

    Example:
        >>> q = axis_angle_to_quat(torch.tensor([[0.0, 0.0, math.pi / 2], [0.0, 0.0, 0.0]]))
        >>> offsets = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
        >>> positions, world = torchquat.kinematics.forward_kinematics([-1, 0], offsets, q, torch.zeros(3))
        >>> torch.allclose(positions, torch.tensor([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), atol=1e-6)
        True
        >>> world.shape
        torch.Size([2, 4])
    """
    fn = "forward_kinematics"
    levels = tree_levels(parents, fn)
    parents = [int(p) for p in (parents.tolist() if isinstance(parents, Tensor) else parents)]
    count = len(parents)
    matrices = rotations.dim() >= 3 and tuple(rotations.shape[-2:]) == (3, 3) and rotations.shape[-3] == count
    if not matrices and (rotations.dim() < 2 or tuple(rotations.shape[-2:]) != (count, 4)):
        raise ShapeError(f"{fn}: expected rotations of shape (..., {count}, 4) or (..., {count}, 3, 3) for "
                             f"{count} joints, got {tuple(rotations.shape)}")
    if offsets.dim() < 2 or tuple(offsets.shape[-2:]) != (count, 3):
        raise ShapeError(f"{fn}: expected offsets of shape ({count}, 3) or (..., {count}, 3), "
                             f"got {tuple(offsets.shape)}")
    if root_positions.dim() < 1 or root_positions.shape[-1] != 3:
        raise ShapeError(f"{fn}: expected root_positions of shape (..., 3), got {tuple(root_positions.shape)}")
    for name, x in (("rotations", rotations), ("offsets", offsets), ("root_positions", root_positions)):
        if not x.is_floating_point():
            raise TypeError(f"{fn}: expected {name} of a floating dtype, got {x.dtype}")
    rot_batch = rotations.shape[:-3] if matrices else rotations.shape[:-2]
    try:
        batch = torch.broadcast_shapes(rot_batch, offsets.shape[:-2], root_positions.shape[:-1])
    except RuntimeError:
        raise ShapeError(f"{fn}: batch shapes do not broadcast: rotations {tuple(rot_batch)}, offsets "
                             f"{tuple(offsets.shape[:-2])}, root_positions "
                             f"{tuple(root_positions.shape[:-1])}") from None
    tail = (3, 3) if matrices else (4,)
    rotations = rotations.expand(*batch, count, *tail)
    offsets = offsets.expand(*batch, count, 3)
    axis = len(batch)  # the joint dim

    def pick(x: Tensor, index: List[int]) -> Tensor:
        return x.index_select(axis, torch.tensor(index, device=x.device))

    root = levels[0]
    world_rot = [pick(rotations, root)]
    world_pos = [root_positions.expand(*batch, 3).unsqueeze(-2)]
    for depth in range(1, len(levels)):
        above = {j: i for i, j in enumerate(levels[depth - 1])}
        slot = [above[parents[j]] for j in levels[depth]]  # each joint's parent within the level above
        parent_rot, parent_pos = pick(world_rot[-1], slot), pick(world_pos[-1], slot)
        local, offset = pick(rotations, levels[depth]), pick(offsets, levels[depth])
        if matrices:
            world_rot.append(parent_rot @ local)
            world_pos.append(parent_pos + (parent_rot @ offset.unsqueeze(-1)).squeeze(-1))
        else:
            world_rot.append(quat_multiply(parent_rot, local))
            world_pos.append(parent_pos + quat_rotate(parent_rot, offset))
    order = [j for level in levels for j in level]
    back = [0] * count
    for i, j in enumerate(order):
        back[j] = i
    return pick(torch.cat(world_pos, axis), back), pick(torch.cat(world_rot, axis), back)
