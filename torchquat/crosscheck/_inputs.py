"""Inputs for the cross-check and the definitions it verifies the oracles against.

Everything here is float64 and written from first principles (elementary rotations about the
coordinate axes, the Hamilton product), independent of torchquat and of both oracles, so that
the convention mappings can be verified rather than assumed.
"""

import math
from typing import Dict, Tuple

import torch
from torch import Tensor

import torchquat as tq

F64 = torch.float64
#: Raw first and third angles are compared only this far (rad) from gimbal lock: closer, their
#: rounding error grows as 1 / distance (float32: ~1e-7 / distance) and only the rotation they
#: make is well-conditioned, so there the report compares rotations.
ANGLES_MIN_LOCK_DISTANCE = 0.05
SMALL_ANGLES = (1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3)  # radians: distances to 0, pi or lock
N_AXES = 16  # random axes per singular set


def hamilton(p: Tensor, q: Tensor) -> Tensor:
    """Hamilton product of ``(w, x, y, z)`` quaternions (``ij = k``)."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - (pv * qv).sum(-1, keepdim=True)
    v = pw * qv + qw * pv + torch.linalg.cross(pv, qv, dim=-1)
    return torch.cat((w, v), dim=-1)


def elementary_quat(axis: int, angle: Tensor) -> Tensor:
    """Quaternion of a rotation by ``angle`` about coordinate axis ``axis`` (0, 1, 2)."""
    q = torch.zeros(angle.shape + (4,), dtype=angle.dtype)
    q[..., 0] = torch.cos(angle / 2)
    q[..., axis + 1] = torch.sin(angle / 2)
    return q


def definition_quat(angles: Tensor, convention: str) -> Tensor:
    """Euler angles to a quaternion by the definition of the convention.

    Intrinsic ``'ABC'`` (upper case) turns about A, then the moved B, then the moved C:
    ``q = q_A(a1) q_B(a2) q_C(a3)``. Extrinsic ``'abc'`` turns about the fixed a, b, c in that
    order: ``q = q_c(a3) q_b(a2) q_a(a1)``.
    """
    axes = ["xyz".index(c) for c in convention.lower()]
    factors = [elementary_quat(ax, angles[..., n]) for n, ax in enumerate(axes)]
    if convention.islower():
        factors.reverse()
    return hamilton(hamilton(factors[0], factors[1]), factors[2])


def definition_matrix(q: Tensor) -> Tensor:
    """Rotation matrix (acting on column vectors) of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = q.unbind(-1)
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def _axis_angle_quat(axes: Tensor, angles: Tensor) -> Tensor:
    half = angles[..., None] / 2
    return torch.cat((torch.cos(half), torch.sin(half) * axes), dim=-1)


def _random_axes(count: int, generator: torch.Generator) -> Tensor:
    v = torch.randn(count, 3, generator=generator, dtype=F64)
    return v / v.norm(dim=-1, keepdim=True)


def _rotation_set(axes: Tensor, angles: Tensor) -> Dict[str, Tensor]:
    """q (and -q), rotation vector and matrix of rotations given by axis and angle."""
    q = _axis_angle_quat(axes, angles)
    rotvec = axes * angles[..., None]
    return {"q": torch.cat((q, -q)), "rotvec": torch.cat((rotvec, rotvec)),
            "R": torch.cat((definition_matrix(q),) * 2)}


def rotation_sets(n: int, generator: torch.Generator) -> Dict[str, Dict[str, Tensor]]:
    """Named sets of rotations, each as ``q``, ``rotvec`` and ``R`` (float64).

    ``random``: ``n`` uniform rotations (both quaternion hemispheres). ``small angle``: the
    identity and 1e-9..1e-3 rad about random axes. ``half turn``: pi about x, y, z and random
    axes. ``near half turn``: pi - (1e-9..1e-3). Singular sets hold both ``q`` and ``-q``.
    """
    q = tq.random_quat(n, generator=generator, dtype=F64)
    qs = torch.where(q[..., :1] < 0, -q, q)
    vnorm = qs[..., 1:].norm(dim=-1, keepdim=True)
    rotvec = qs[..., 1:] * (2 * torch.atan2(vnorm, qs[..., :1]) / vnorm)
    sets = {"random": {"q": q, "rotvec": rotvec, "R": definition_matrix(q)}}
    scale = torch.exp((2 * torch.rand(n, 1, generator=generator, dtype=F64) - 1) * math.log(100.0))
    sets["non-unit q"] = {"q": q * scale, "rotvec": rotvec, "R": definition_matrix(q)}
    axes = _random_axes(N_AXES, generator)
    small = torch.tensor(SMALL_ANGLES, dtype=F64)
    grid_axes = axes.repeat(len(SMALL_ANGLES), 1)
    grid_small = small.repeat_interleave(N_AXES)
    sets["small angle"] = _rotation_set(torch.cat((axes[:1], grid_axes)),
                                        torch.cat((torch.zeros(1, dtype=F64), grid_small)))
    half_axes = torch.cat((torch.eye(3, dtype=F64), axes))
    sets["half turn"] = _rotation_set(half_axes, torch.full((len(half_axes),), math.pi, dtype=F64))
    sets["near half turn"] = _rotation_set(grid_axes, math.pi - grid_small)
    return sets


def pair_sets(n: int, generator: torch.Generator) -> Dict[str, Tuple[Tensor, Tensor]]:
    """Pairs of quaternions ``(q1, q2)``: random, close (1e-9..1e-3 rad apart), half a turn
    apart and near half a turn apart."""
    q1 = tq.random_quat(n, generator=generator, dtype=F64)
    q2 = tq.random_quat(n, generator=generator, dtype=F64)
    out = {"random": (q1, q2)}
    for name in ("small angle", "half turn", "near half turn"):
        rel = rotation_sets(1, generator)[name]["q"]
        base = tq.random_quat(len(rel), generator=generator, dtype=F64)
        out[{"small angle": "close"}.get(name, name + " apart")] = (base, hamilton(base, rel))
    return out


def lock_middles(convention: str) -> Tuple[float, ...]:
    """Middle angles at gimbal lock: +-pi/2 (Tait-Bryan) or 0 and pi (proper Euler)."""
    symmetric = convention[0].lower() == convention[2].lower()
    return (0.0, math.pi) if symmetric else (-math.pi / 2, math.pi / 2)


def lock_distance(angles: Tensor, convention: str) -> Tensor:
    """Distance (rad) of the middle angle from gimbal lock."""
    middle = angles[..., 1]
    if convention[0].lower() == convention[2].lower():
        return torch.minimum(middle.abs(), (math.pi - middle).abs())
    return math.pi / 2 - middle.abs()


def euler_sets(convention: str, n: int, generator: torch.Generator) -> Dict[str, Tensor]:
    """Euler angles for one convention: ``random`` (first and third uniform in [-pi, pi], the
    middle uniform over its range), ``lock`` (the middle exactly at each singular value) and
    ``near lock`` (1e-9..1e-3 rad inside the range from each singular value)."""
    lo, hi = lock_middles(convention)
    u = torch.rand(n, 3, generator=generator, dtype=F64)
    random = torch.stack(((2 * u[:, 0] - 1) * math.pi, lo + (hi - lo) * u[:, 1],
                          (2 * u[:, 2] - 1) * math.pi), -1)
    m = 2 * N_AXES

    def with_middle(middle: Tensor) -> Tensor:
        outer = (2 * torch.rand(len(middle), 2, generator=generator, dtype=F64) - 1) * math.pi
        return torch.stack((outer[:, 0], middle, outer[:, 1]), -1)

    lock = with_middle(torch.tensor((lo, hi), dtype=F64).repeat_interleave(m))
    lock = torch.cat((lock, torch.zeros(1, 3, dtype=F64)))  # all zero: at lock for proper Euler
    deltas = near_lock_deltas()
    half = len(deltas) // 2
    near = with_middle(torch.cat((lo + deltas[:half], hi - deltas[half:])))
    return {"random": random, "lock": lock, "near lock": near}


def near_lock_deltas() -> Tensor:
    """Distance to lock of each row of :func:`euler_sets`' ``near lock`` set, in order."""
    return torch.tensor(SMALL_ANGLES, dtype=F64).repeat_interleave(8).repeat(2)
