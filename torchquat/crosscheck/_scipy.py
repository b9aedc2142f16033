"""Checks against SciPy's ``scipy.spatial.transform`` (``Rotation``, ``Slerp``).

SciPy stores quaternions scalar last; the adapters here roll them to ``(w, x, y, z)``. Its
Euler sequences follow the same rule as ours (``'ZYX'`` intrinsic, ``'xyz'`` extrinsic), so the
convention string is passed unchanged; the ``convention mapping`` row verifies that against
the definition in :mod:`torchquat.crosscheck._inputs`. SciPy computes in float64 throughout.
"""

import math
import warnings
from typing import Dict

import numpy as np
import torch
from torch import Tensor

import torchquat as tq

from ._core import Context, Once, err_abs, err_angles, err_quat, err_rotvec
from ._inputs import (
    ANGLES_MIN_LOCK_DISTANCE, F64, definition_matrix, definition_quat, euler_sets, lock_distance, near_lock_deltas,
    pair_sets, rotation_sets,
)

ORACLE = "scipy"
TIGHT = (1e-12, 1e-5)  # float64, float32
EULER_ANGLES = (1e-12, 1e-5)  # raw angles, at least ANGLES_MIN_LOCK_DISTANCE from lock
PROCRUSTES = (1e-11, 1e-5)  # rot9d: ill-conditioned when the two smallest singular values are small
LOCK_EPS = 1e-7  # SciPy's gimbal-lock threshold (rad), also torchquat's default in float64
LOCK_BAND = (3 * LOCK_EPS, 1e-5)  # the lock rule moves the rotation by up to ~2 eps


class _SciPy:
    """Thin float64 adapters from torch tensors in our layout to SciPy and back."""

    def __init__(self, transform):
        self.Rotation = transform.Rotation
        self.Slerp = transform.Slerp

    def from_quat(self, q: Tensor):
        return self.Rotation.from_quat(np.roll(q.to(F64).numpy(), -1, axis=-1))

    @staticmethod
    def quat(r) -> Tensor:
        return torch.from_numpy(np.roll(np.asarray(r.as_quat()), 1, axis=-1).copy())

    @staticmethod
    def matrix(r) -> Tensor:
        return torch.from_numpy(np.asarray(r.as_matrix()).copy())

    @staticmethod
    def rotvec(r) -> Tensor:
        return torch.from_numpy(np.asarray(r.as_rotvec()).copy())

    def from_matrix(self, R: Tensor):
        return self.Rotation.from_matrix(R.to(F64).numpy())

    def from_euler(self, convention: str, angles: Tensor):
        return self.Rotation.from_euler(convention, angles.to(F64).numpy())

    @staticmethod
    def euler(r, convention: str) -> Tensor:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "Gimbal lock detected": expected on the lock sets
            return torch.from_numpy(np.asarray(r.as_euler(convention)).copy())


ONE_ROW_ROWS = 48  # rows of each set that are also converted one at a time


def run_checks(ctx: Context, transform, n: int, generator: torch.Generator) -> None:
    """Add every SciPy row to ``ctx``."""
    sp = _SciPy(transform)
    sets = rotation_sets(n, generator)
    _conversions(ctx, sp, sets)
    # the same rows one at a time: a call on one row may take a path of its own, checked like the batch
    _conversions(ctx, sp, {f"{case}, one row at a time": {k: v[:ONE_ROW_ROWS] for k, v in s.items()}
                           for case, s in sets.items()}, wrap=one_row_each)
    _algebra(ctx, sp, n, generator)
    _algebra(ctx, sp, ONE_ROW_ROWS, torch.Generator().manual_seed(n), wrap=one_row_each, suffix=", one row at a time")
    _euler(ctx, sp, n, generator)
    _euler_one_row(ctx, sp, generator)


def one_row_each(fn):
    """``fn`` called on each row of its tensor arguments alone (other arguments passed as they are),
    the results stacked."""
    def each(*args):
        tensors = [a for a in args if isinstance(a, Tensor)]
        out = []
        for i in range(len(tensors[0])):
            rows = iter(t[i] for t in tensors)
            out.append(fn(*(next(rows) if isinstance(a, Tensor) else a for a in args)))
        return torch.stack(out)
    return each


def _same(fn):
    return fn


def _conversions(ctx: Context, sp: _SciPy, sets: Dict[str, Dict[str, Tensor]], wrap=_same) -> None:
    for case, s in sets.items():
        q, q_ref = ctx.split(s["q"])
        R, R_ref = ctx.split(s["R"])
        v, v_ref = ctx.split(s["rotvec"])
        add = lambda fn, metric, tol, compute: ctx.check(fn, case, ORACLE, metric, tol, compute)  # noqa: E731
        # rows whose input is not q: the non-unit set's R and rotvec are "random"'s, so skip them
        add_other = add if not case.startswith("non-unit q") else (lambda *args: None)  # noqa: E731
        add("quat_to_matrix", "matrix", TIGHT,
            lambda: err_abs(wrap(tq.quat_to_matrix)(q), sp.matrix(sp.from_quat(q_ref))))
        add_other("matrix_to_quat", "quat (+-)", TIGHT,
                  lambda: err_quat(wrap(tq.matrix_to_quat)(R), sp.quat(sp.from_matrix(R_ref))))
        add_other("axis_angle_to_quat", "quat (+-)", TIGHT,
                  lambda: err_quat(wrap(tq.axis_angle_to_quat)(v), sp.quat(sp.Rotation.from_rotvec(v_ref.numpy()))))
        add("quat_to_axis_angle", "rotvec", TIGHT,
            lambda: err_rotvec(wrap(tq.quat_to_axis_angle)(q), sp.rotvec(sp.from_quat(q_ref))))
        add_other("axis_angle_to_matrix", "matrix", TIGHT,
                  lambda: err_abs(wrap(tq.axis_angle_to_matrix)(v), sp.matrix(sp.Rotation.from_rotvec(v_ref.numpy()))))
        add_other("matrix_to_axis_angle", "rotvec", TIGHT,
                  lambda: err_rotvec(wrap(tq.matrix_to_axis_angle)(R), sp.rotvec(sp.from_matrix(R_ref))))
        vec = torch.randn(len(q), 3, generator=torch.Generator().manual_seed(len(q)), dtype=F64)
        x, x_ref = ctx.split(vec)
        add("quat_rotate", "vector", TIGHT,
            lambda: err_abs(wrap(tq.quat_rotate)(q, x), torch.from_numpy(sp.from_quat(q_ref).apply(x_ref.numpy()))))


def _algebra(ctx: Context, sp: _SciPy, n: int, generator: torch.Generator, wrap=_same, suffix: str = "") -> None:
    for case, (p64, q64) in pair_sets(n, generator).items():
        p, p_ref = ctx.split(p64)
        q, q_ref = ctx.split(q64)
        Rp, Rp_ref = ctx.split(definition_matrix(p64))
        Rq, Rq_ref = ctx.split(definition_matrix(q64))
        rp, rq = sp.from_quat(p_ref), sp.from_quat(q_ref)
        add = lambda fn, metric, tol, compute: ctx.check(fn, case + suffix, ORACLE, metric, tol, compute)  # noqa: E731
        add("quat_multiply", "quat (+-)", TIGHT, lambda: err_quat(wrap(tq.quat_multiply)(p, q), sp.quat(rp * rq)))
        add("quat_geodesic_distance", "radians", TIGHT,
            lambda: err_abs(wrap(tq.quat_geodesic_distance)(p, q), torch.from_numpy((rp.inv() * rq).magnitude())))
        add("matrix_geodesic_distance", "radians", TIGHT,
            lambda: err_abs(wrap(tq.matrix_geodesic_distance)(Rp, Rq),
                            torch.from_numpy((sp.from_matrix(Rp_ref).inv() * sp.from_matrix(Rq_ref)).magnitude())))
        if case in ("random", "close"):  # half a turn apart the shortest path is not unique
            # t on a 2**-20 grid: exact in float32, and 2k + t (the spline's time) exact in float64
            t = torch.randint(0, 2**20 + 1, (len(p),), generator=generator).to(F64) / 2**20
            t, t_ref = ctx.split(t)
            add("quat_slerp", "quat (+-)", TIGHT,
                lambda: err_quat(wrap(tq.quat_slerp)(p, q, t), _slerp(sp, p_ref, q_ref, t_ref)))
    if suffix:  # (rot9d has no one-row form)
        return
    # rot9d: SciPy's from_matrix maps a matrix with det > 0 to the nearest rotation (Markley 2008)
    M = torch.randn(n, 3, 3, generator=generator, dtype=F64)
    M = torch.where(torch.linalg.det(M)[:, None, None] < 0, -M, M)
    M, M_ref = ctx.split(M)
    ctx.check("rot9d_to_matrix", "random det > 0", ORACLE, "matrix", PROCRUSTES,
              lambda: err_abs(tq.rot9d_to_matrix(M), sp.matrix(sp.from_matrix(M_ref))))


def _slerp(sp: _SciPy, p: Tensor, q: Tensor, t: Tensor) -> Tensor:
    """SciPy's Slerp of each pair: one spline through p0, q0, p1, q1, ... at times 0, 1, 2, ..."""
    keys = torch.stack((p, q), 1).reshape(-1, 4)
    spline = sp.Slerp(np.arange(len(keys), dtype=np.float64), sp.from_quat(keys))
    return sp.quat(spline(2.0 * np.arange(len(p)) + t.numpy()))


def _euler(ctx: Context, sp: _SciPy, n: int, generator: torch.Generator) -> None:
    random_q = rotation_sets(n, generator)["random"]["q"]
    deltas = near_lock_deltas()
    worst = (0.0, "")
    for convention in tq.EULER_CONVENTIONS:
        sets = euler_sets(convention, n, generator)
        A64 = torch.cat(list(sets.values()))
        a, a_ref = ctx.split(A64)
        add = lambda fn, metric, tol, compute: ctx.check(fn, convention, ORACLE, metric, tol, compute)  # noqa: E731
        ref_q = sp.quat(sp.from_euler(convention, a_ref))
        worst = max(worst, (err_quat(definition_quat(a_ref, convention), ref_q), convention))
        add("euler_to_quat", "quat (+-)", TIGHT, lambda: err_quat(tq.euler_to_quat(a, convention), ref_q))
        add("euler_to_matrix", "matrix", TIGHT,
            lambda: err_abs(tq.euler_to_matrix(a, convention), sp.matrix(sp.from_euler(convention, a_ref))))
        # back: random rotations, then rotations exactly at lock and near it, each as q and -q
        lock_q, near_q = (definition_quat(sets[k], convention) for k in ("lock", "near lock"))
        parts = (random_q, lock_q, -lock_q, near_q, -near_q)
        Q64 = torch.cat(parts)
        kind = torch.cat([torch.full((len(p),), k) for k, p in zip((0, 1, 1, 2, 2), parts)])
        delta = torch.cat((torch.full((len(Q64) - 2 * len(deltas),), math.inf, dtype=F64), deltas, deltas))
        # angles are unique away from lock, and at lock by the rule (third angle 0); in float32
        # an exact-lock input rounds to up to ~1e-7 rad off lock, where the rule's eps decides
        at_lock = (kind == 1) & (ctx.dtype == F64)
        # with lock 1e-7 rad away, SciPy's test and ours (equal in exact arithmetic) may differ
        # by rounding: one sets the third angle to 0 (off by up to ~2 eps), the other does not
        band = (delta > LOCK_EPS / 3) & (delta < LOCK_EPS * 3)
        q, q_ref = ctx.split(Q64)
        R, R_ref = ctx.split(definition_matrix(Q64))
        for fn, ours_fn, x, r in (("quat_to_euler", tq.quat_to_euler, q, sp.from_quat(q_ref)),
                                  ("matrix_to_euler", tq.matrix_to_euler, R, sp.from_matrix(R_ref))):
            ref = sp.euler(r, convention)
            angles_rows = ((kind == 0) & (lock_distance(ref, convention) >= ANGLES_MIN_LOCK_DISTANCE)) | at_lock
            ours = Once(lambda: ours_fn(x, convention).to(F64))
            rot = Once(lambda: (sp.matrix(sp.from_euler(convention, ours())) -
                                sp.matrix(sp.from_euler(convention, ref))).abs().amax((-2, -1)))
            add(fn, "angles", EULER_ANGLES, lambda: err_angles(ours()[angles_rows], ref[angles_rows]))
            add(fn, "rotation", TIGHT, lambda: err_abs(rot()[~band], torch.zeros(int((~band).sum()), dtype=F64)))
            add(fn, "rotation, lock +-1e-7", LOCK_BAND,
                lambda: err_abs(rot()[band], torch.zeros(int(band.sum()), dtype=F64)))
    ctx.check("convention mapping", "from_euler vs definition (24)", ORACLE, "quat (+-)", (1e-14, 1e-14),
              lambda: worst[0], note=f"worst {worst[1]}" if worst[0] > 1e-14 else "")


def _euler_one_row(ctx: Context, sp: _SciPy, generator: torch.Generator) -> None:
    """The four Euler functions one row at a time, over all 24 conventions (one report row each):
    random angles and angles exactly at lock both ways; back from their quaternions and matrices,
    compared as rotations (at lock the angles are the rule's, checked by the batch rows above)."""
    errors = {"euler_to_quat": 0.0, "euler_to_matrix": 0.0, "quat_to_euler": 0.0, "matrix_to_euler": 0.0}
    for convention in tq.EULER_CONVENTIONS:
        sets = euler_sets(convention, ONE_ROW_ROWS // 2, generator)
        A64 = torch.cat((sets["random"], sets["lock"][::4]))
        a, a_ref = ctx.split(A64)
        each = lambda fn: one_row_each(lambda x: fn(x, convention))  # noqa: E731
        errors["euler_to_quat"] = max(errors["euler_to_quat"], err_quat(each(tq.euler_to_quat)(a),
                                                                          sp.quat(sp.from_euler(convention, a_ref))))
        errors["euler_to_matrix"] = max(errors["euler_to_matrix"], err_abs(each(tq.euler_to_matrix)(a),
                                                                            sp.matrix(sp.from_euler(convention, a_ref))))
        Q64 = definition_quat(A64, convention)
        for fn, ours_fn, x64 in (("quat_to_euler", tq.quat_to_euler, Q64), ("matrix_to_euler", tq.matrix_to_euler,
                                                                            definition_matrix(Q64))):
            x, x_ref = ctx.split(x64)
            target = sp.matrix(sp.from_quat(x_ref) if fn == "quat_to_euler" else sp.from_matrix(x_ref))
            ours = each(ours_fn)(x).to(F64)
            errors[fn] = max(errors[fn], err_abs(sp.matrix(sp.from_euler(convention, ours)), target))
    for fn, error in errors.items():
        metric = {"euler_to_quat": "quat (+-)", "euler_to_matrix": "matrix"}.get(fn, "rotation")
        ctx.check(fn, "24 conventions, one row at a time", ORACLE, metric, TIGHT, lambda e=error: e)
