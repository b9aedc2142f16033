"""Checks against ``pytorch_kinematics.transforms`` (PyTorch3D's conversions plus tf's Euler).

What its functions mean, read from its source and verified by the ``convention mapping`` rows:

- Quaternions are ``(w, x, y, z)``, matrices act on column vectors, as ours.
- ``euler_angles_to_matrix(angles, "ZYX")`` multiplies ``Rz(a1) @ Ry(a2) @ Rx(a3)``: intrinsic,
  upper case only. Our extrinsic ``'xyz'`` with ``(a, b, c)`` is its ``'ZYX'`` with ``(c, b, a)``,
  which is how the 12 lower-case conventions are checked. ``matrix_to_euler_angles`` uses
  ``asin``/``acos`` of single entries, so it is compared on random rotations only (at gimbal
  lock it returns an arbitrary split).
- ``quaternion_from_euler(angles, axes)`` takes the 24 axes strings of Gohlke's
  ``transformations.py`` (ROS tf): ``'s'`` (static) is extrinsic and ``'r'`` (rotating) is
  intrinsic, and the three letters name the axes in the order the angles are given, so
  ``'sxyz' -> 'xyz'`` and ``'rzyx' -> 'ZYX'``: the mapping is the letters, upper-cased for
  ``'r'``. It halves its input in place (``ai /= 2.0`` on ``unbind`` views): it gets clones.
- ``matrix_to_rotation_6d`` keeps the first two *rows* and ``rotation_6d_to_matrix`` stacks its
  Gram-Schmidt vectors as rows; ours uses columns, so ours on ``R`` is compared with theirs on
  ``R.mT`` and ours on ``x`` with the transpose of theirs.
- Its quaternion functions assume unit norm; they are given ``q / |q|``.
- ``quaternion_to_axis_angle`` returns an angle in ``(pi, 2 pi)`` for ``w < 0``; it is given
  ``w >= 0`` quaternions, and ``matrix_to_axis_angle``'s output is wrapped to ``[0, pi]``.
- ``quaternion_slerp`` negates its second argument in place and switches to lerp for a whole
  batch that is close; ``quaternion_angular_distance`` uses ``sqrt(1 - dot^2)``: both are
  compared on random pairs only, with a tolerance for their lost digits.

pytorch-kinematics runs in float64 on the same rounded inputs torchquat gets.
"""

import math
import warnings
from typing import Dict

import torch
from torch import Tensor

import torchquat as tq

from ._core import Context, Once, err_abs, err_angles, err_quat, err_rotvec
from ._inputs import (
    ANGLES_MIN_LOCK_DISTANCE, F64, definition_matrix, definition_quat, euler_sets, lock_distance, pair_sets,
    rotation_sets,
)

ORACLE = "pk"
TIGHT = (1e-12, 1e-5)
LOOSE = (1e-9, 1e-5)  # where pytorch-kinematics' own formula loses digits (asin, acos, sqrt(1 - x^2))

#: tf/transformations.py axes string -> torchquat convention (verified by a row of the report).
TF_AXES: Dict[str, str] = {
    **{"s" + c: c for c in tq.EULER_CONVENTIONS if c.islower()},
    **{"r" + c.lower(): c for c in tq.EULER_CONVENTIONS if c.isupper()},
}


def _pk_euler_matrix(pkt, angles: Tensor, convention: str) -> Tensor:
    """pytorch-kinematics' matrix for any of our 24 conventions (extrinsic through reversal)."""
    if convention.isupper():
        return pkt.euler_angles_to_matrix(angles, convention)
    return pkt.euler_angles_to_matrix(angles.flip(-1), convention.upper()[::-1])


def _wrap_rotvec(v: Tensor) -> Tensor:
    """A rotation vector with angle in (pi, 2 pi) -> the same rotation with angle in [0, pi]."""
    angle = v.norm(dim=-1, keepdim=True)
    return torch.where(angle > math.pi, v - v / angle * (2 * math.pi), v)


def run_checks(ctx: Context, pkt, n: int, generator: torch.Generator) -> None:
    """Add every pytorch-kinematics row to ``ctx``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # its axis_angle_to_matrix warns
        _conversions(ctx, pkt, rotation_sets(n, generator))
        _algebra(ctx, pkt, n, generator)
        _rot6d(ctx, pkt, n, generator)
        _euler(ctx, pkt, n, generator)


def _conversions(ctx: Context, pkt, sets: Dict[str, Dict[str, Tensor]]) -> None:
    # not exported by pytorch_kinematics.transforms (deprecated there as slow, still correct)
    pk_axis_angle_to_matrix = pkt.rotation_conversions.axis_angle_to_matrix
    for case, s in sets.items():
        q, q_ref = ctx.split(s["q"])
        R, R_ref = ctx.split(s["R"])
        v, v_ref = ctx.split(s["rotvec"])
        q_ref = q_ref / q_ref.norm(dim=-1, keepdim=True)  # it assumes unit quaternions
        q_pos = torch.where(q_ref[..., :1] < 0, -q_ref, q_ref)
        add = lambda fn, metric, tol, compute: ctx.check(fn, case, ORACLE, metric, tol, compute)  # noqa: E731
        # rows whose input is not q: the non-unit set's R and rotvec are "random"'s, so skip them
        add_other = add if case != "non-unit q" else (lambda *args: None)  # noqa: E731
        add("quat_to_matrix", "matrix", TIGHT, lambda: err_abs(tq.quat_to_matrix(q), pkt.quaternion_to_matrix(q_ref)))
        add_other("matrix_to_quat", "quat (+-)", TIGHT,
                  lambda: err_quat(tq.matrix_to_quat(R), pkt.matrix_to_quaternion(R_ref)))
        add_other("axis_angle_to_quat", "quat (+-)", TIGHT,
                  lambda: err_quat(tq.axis_angle_to_quat(v), pkt.axis_angle_to_quaternion(v_ref)))
        add("quat_to_axis_angle", "rotvec", TIGHT,
            lambda: err_rotvec(tq.quat_to_axis_angle(q), pkt.quaternion_to_axis_angle(q_pos)))
        add_other("axis_angle_to_matrix", "matrix", TIGHT,
                  lambda: err_abs(tq.axis_angle_to_matrix(v), pk_axis_angle_to_matrix(v_ref)))
        add_other("matrix_to_axis_angle", "rotvec", TIGHT,
                  lambda: err_rotvec(tq.matrix_to_axis_angle(R), _wrap_rotvec(pkt.matrix_to_axis_angle(R_ref))))
        vec = torch.randn(len(q), 3, generator=torch.Generator().manual_seed(len(q)), dtype=F64)
        x, x_ref = ctx.split(vec)
        add("quat_rotate", "vector", TIGHT, lambda: err_abs(tq.quat_rotate(q, x), pkt.quaternion_apply(q_ref, x_ref)))


def _algebra(ctx: Context, pkt, n: int, generator: torch.Generator) -> None:
    from pytorch_kinematics.transforms.math import quaternion_angular_distance, quaternion_slerp

    for case, (p64, q64) in pair_sets(n, generator).items():
        p, p_ref = ctx.split(p64)
        q, q_ref = ctx.split(q64)
        ctx.check("quat_multiply", case, ORACLE, "quat (+-)", TIGHT,
                  lambda: err_quat(tq.quat_multiply(p, q), pkt.quaternion_multiply(p_ref, q_ref)))
        if case == "random":
            t = torch.rand(len(p), generator=generator, dtype=F64)
            t, t_ref = ctx.split(t)
            # both assume unit quaternions (float32 rounding is not); slerp negates q2 in place
            p_unit, q_unit = p_ref / p_ref.norm(dim=-1, keepdim=True), q_ref / q_ref.norm(dim=-1, keepdim=True)
            ctx.check("quat_slerp", case, ORACLE, "quat (+-)", LOOSE,
                      lambda: err_quat(tq.quat_slerp(p, q, t), quaternion_slerp(p_unit, q_unit.clone(), t_ref)))
            ctx.check("quat_geodesic_distance", case, ORACLE, "radians", LOOSE,
                      lambda: err_abs(tq.quat_geodesic_distance(p, q), quaternion_angular_distance(p_unit, q_unit)))


def _rot6d(ctx: Context, pkt, n: int, generator: torch.Generator) -> None:
    R64 = definition_matrix(tq.random_quat(n, generator=generator, dtype=F64))
    R, R_ref = ctx.split(R64)
    ctx.check("matrix_to_rot6d", "random", ORACLE, "6D", TIGHT,
              lambda: err_abs(tq.matrix_to_rot6d(R), pkt.matrix_to_rotation_6d(R_ref.mT)))
    x = torch.randn(n, 6, generator=generator, dtype=F64)
    a1, a2 = x[:, :3], x[:, 3:]
    sine = torch.linalg.cross(a1, a2, dim=-1).norm(dim=-1) / (a1.norm(dim=-1) * a2.norm(dim=-1))
    x, x_ref = ctx.split(x[sine > 0.1])  # Gram-Schmidt loses digits as 1/sin: keep it conditioned
    ctx.check("rot6d_to_matrix", "random 6-vectors", ORACLE, "matrix", TIGHT,
              lambda: err_abs(tq.rot6d_to_matrix(x), pkt.rotation_6d_to_matrix(x_ref).mT))


def _euler(ctx: Context, pkt, n: int, generator: torch.Generator) -> None:
    random_q = rotation_sets(n, generator)["random"]["q"]
    worst_tf, worst_mat = (0.0, ""), (0.0, "")
    for convention in tq.EULER_CONVENTIONS:
        axes = next(k for k, v in TF_AXES.items() if v == convention)
        A64 = torch.cat(list(euler_sets(convention, n, generator).values()))
        a, a_ref = ctx.split(A64)
        truth = definition_quat(a_ref, convention)
        tf_q = pkt.quaternion_from_euler(a_ref.clone(), axes)  # clone: it halves its input in place
        pk_R = _pk_euler_matrix(pkt, a_ref, convention)
        worst_tf = max(worst_tf, (err_quat(tf_q, truth), f"{axes} -> {convention}"))
        worst_mat = max(worst_mat, (err_abs(pk_R, definition_matrix(truth)), convention))
        ctx.check("euler_to_quat", f"{convention} ({axes})", ORACLE, "quat (+-)", TIGHT,
                  lambda: err_quat(tq.euler_to_quat(a, convention), tf_q))
        ctx.check("euler_to_matrix", convention, ORACLE, "matrix", TIGHT,
                  lambda: err_abs(tq.euler_to_matrix(a, convention), pk_R))
        if convention.isupper():
            R, R_ref = ctx.split(definition_matrix(random_q))
            ref = pkt.matrix_to_euler_angles(R_ref, convention)
            ours = Once(lambda: tq.matrix_to_euler(R, convention).to(F64))
            far = lock_distance(ref, convention) >= ANGLES_MIN_LOCK_DISTANCE
            ctx.check("matrix_to_euler", convention, ORACLE, "angles", LOOSE, lambda: err_angles(ours()[far], ref[far]))
            ctx.check("matrix_to_euler", convention, ORACLE, "rotation", TIGHT,
                      lambda: err_abs(pkt.euler_angles_to_matrix(ours(), convention),
                                      pkt.euler_angles_to_matrix(ref, convention)))
    ctx.check("convention mapping", "quaternion_from_euler tf axes (24)", ORACLE, "quat (+-)", (1e-14, 1e-14),
              lambda: worst_tf[0], note=f"worst {worst_tf[1]}" if worst_tf[0] > 1e-14 else "")
    ctx.check("convention mapping", "euler_angles_to_matrix (24)", ORACLE, "matrix", (1e-14, 1e-14),
              lambda: worst_mat[0], note=f"worst {worst_mat[1]}" if worst_mat[0] > 1e-14 else "")
