"""Rotation samples shared by the tests: uniform draws plus the singular sets.

Every sample set is a float64 tensor of unit quaternions ``(w, x, y, z)``; the sets mix uniform
rotations with the places where rotation code breaks: the identity and tiny angles, half turns,
and gimbal lock (exactly, and 1e-9 to 1e-3 rad away from it).
"""

import itertools
import math

import numpy as np
import torch

from torchquat import EULER_CONVENTIONS

CONVENTIONS = sorted(EULER_CONVENTIONS)  # all 24
INTRINSIC = [c for c in CONVENTIONS if c.isupper()]
SMALL_ANGLES = [0.0, 1e-12, 1e-9, 1e-7, 1e-5, 1e-3]
NEAR_LOCK_OFFSETS = [0.0, 1e-9, 1e-8, 1e-6, 1e-5, 1e-3]  # not 1e-7: that is eps itself
BATCH_SHAPES = [(), (1,), (3, 1, 2)]


def _axes(n, rng):
    axes = rng.normal(size=(n, 3))
    axes = np.concatenate([np.eye(3), -np.eye(3), axes / np.linalg.norm(axes, axis=1, keepdims=True)])
    return axes


def axis_angle_quats(axes, angles):
    """Quaternions of every (axis, angle) pair, float64."""
    qs = [[math.cos(a / 2), *(math.sin(a / 2) * np.asarray(ax))] for ax in axes for a in angles]
    return torch.tensor(qs, dtype=torch.float64)


def uniform(n=500, seed=0):
    """Uniformly distributed unit quaternions (normalised Gaussians), both signs of w."""
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return q / q.norm(dim=-1, keepdim=True)


def near_identity(seed=1):
    """The identity and rotations by 1e-12 .. 1e-3 rad about coordinate and random axes."""
    return axis_angle_quats(_axes(5, np.random.default_rng(seed)), SMALL_ANGLES)


def half_turns(seed=2):
    """180-degree rotations about x, y, z, their negatives and random axes, and just short of them."""
    angles = [math.pi, math.pi - 1e-9, math.pi - 1e-6, math.pi - 1e-3]
    return axis_angle_quats(_axes(5, np.random.default_rng(seed)), angles)


def cube_rotations():
    """The 24 rotations of the cube as exact matrices (entries 0, +-1), float64.

    They are exactly at gimbal lock for many conventions and exactly half turns for others,
    with no rounding in the input at all.
    """
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            R = np.zeros((3, 3))
            for row, col in enumerate(perm):
                R[row, col] = signs[row]
            if np.linalg.det(R) > 0:
                mats.append(R)
    return torch.tensor(np.array(mats), dtype=torch.float64)


def lock_angles(convention, n=8, seed=3):
    """Euler angles at gimbal lock of ``convention`` and 1e-9 .. 1e-3 rad away from it.

    Returns ``(angles, offset)``: angles ``(m, 3)`` float64 and each row's distance from lock.
    """
    rng = np.random.default_rng(seed)
    symmetric = convention[0].lower() == convention[2].lower()
    locks = [0.0, math.pi] if symmetric else [math.pi / 2, -math.pi / 2]
    rows, offsets = [], []
    for lock in locks:
        for off in NEAR_LOCK_OFFSETS:
            for sign in (1.0, -1.0):
                middle = lock + sign * off
                if symmetric and not 0.0 <= middle <= math.pi:
                    continue
                if not symmetric and abs(middle) > math.pi / 2:
                    continue
                for _ in range(n):
                    first, third = rng.uniform(-math.pi, math.pi, size=2)
                    rows.append([first, middle, third])
                    offsets.append(off)
    return torch.tensor(rows, dtype=torch.float64), torch.tensor(offsets, dtype=torch.float64)


def all_singular():
    """Identity, tiny angles and half turns together."""
    return torch.cat([near_identity(), half_turns()])


def singular_and_uniform(n=200):
    return torch.cat([uniform(n), all_singular()])
