"""Two claims of the source material, measured: prints the tables of the documentation's claims page.

(a) Rotating a vector by a unit quaternion as ``t = 2 q_vec x v; v' = v + w t + q_vec x t``
    against the sandwich ``q (0, v) q*`` (two Hamilton products): speed (eager PyTorch, float32,
    one thread, median of interleaved runs) and accuracy (largest error against the rotation of
    ``q / |q|`` computed in extended precision, NumPy's ``longdouble``).
(b) Euler angles (heading, attitude, bank = intrinsic ``'YZX'``) to a quaternion by the half-angle
    products (the first method) and by the square-root method (w from the matrix trace, then
    x, y, z divided by ``4 w``; euclideanspace.com's alternative), near the second method's
    singular set ``w = 0`` (rotations by 180 degrees): largest error against the extended-precision
    quaternion of the same (rounded) angles, by distance to that set, in float32 and float64.

A developer's tool (not installed)::

    python tools/claims.py [--n 1000000] [--repeats 9] [--seed 0]
"""

import argparse
import math
import statistics
import sys
import time

import numpy as np
import torch

import torchquat as tq

LD = np.longdouble


# ---- (a) vector rotation ------------------------------------------------------------------------

def rotate_t(q, v):
    """``t = 2 q_vec x v; v + w t + q_vec x t`` on columns."""
    w, x, y, z = q.unbind(-1)
    a, b, c = v.unbind(-1)
    tx, ty, tz = 2 * (y * c - z * b), 2 * (z * a - x * c), 2 * (x * b - y * a)
    return torch.stack((a + w * tx + (y * tz - z * ty),
                        b + w * ty + (z * tx - x * tz),
                        c + w * tz + (x * ty - y * tx)), -1)


def rotate_t_cross(q, v):
    """The same formula on ``(N, 3)`` rows with ``torch.linalg.cross``."""
    u, w = q[..., 1:], q[..., :1]
    t = 2 * torch.linalg.cross(u, v, dim=-1)
    return v + w * t + torch.linalg.cross(u, t, dim=-1)


def _product(p, q):
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


def rotate_sandwich(q, v):
    """``q (0, v) q*``: two full Hamilton products on columns, the vector part kept."""
    w, x, y, z = q.unbind(-1)
    a, b, c = v.unbind(-1)
    zero = torch.zeros_like(a)
    out = _product(_product((w, x, y, z), (zero, a, b, c)), (w, -x, -y, -z))
    return torch.stack(out[1:], -1)


ROTATIONS = {"t = 2 q_vec x v (columns)": rotate_t,
             "t = 2 q_vec x v (torch.linalg.cross)": rotate_t_cross,
             "q (0, v) q* (two products, columns)": rotate_sandwich}


def rotate_reference(q, v):
    """The rotation of ``q / |q|`` applied to ``v``, in ``longdouble`` (rows of NumPy arrays)."""
    q = q.astype(LD)
    v = v.astype(LD)
    q = q / np.sqrt((q * q).sum(-1, keepdims=True))
    w, u = q[:, :1], q[:, 1:]
    t = 2 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def claim_a(n, repeats, seed):
    g = torch.Generator().manual_seed(seed)
    torch.set_num_threads(1)
    rows = []
    q32 = tq.random_quat(n, generator=g, dtype=torch.float32)
    q32 = q32 / q32.norm(dim=-1, keepdim=True)
    v32 = torch.randn(n, 3, generator=g, dtype=torch.float32)
    times = {name: [] for name in ROTATIONS}
    for f in ROTATIONS.values():  # warm-up
        f(q32, v32)
    for _ in range(repeats):  # interleaved, so a slow spell of the machine hits every variant
        for name, f in ROTATIONS.items():
            start = time.perf_counter()
            f(q32, v32)
            times[name].append(time.perf_counter() - start)
    errors = {}
    for dtype in (torch.float32, torch.float64):
        q, v = q32.to(dtype), v32.to(dtype)
        if dtype == torch.float64:  # unit to float64 rounding
            q = q / q.norm(dim=-1, keepdim=True)
        ref = rotate_reference(q.numpy(), v.numpy())
        norm = np.sqrt((ref * ref).sum(-1))
        for name, f in ROTATIONS.items():
            err = np.abs(f(q, v).numpy().astype(LD) - ref).max(-1)
            errors[name, dtype] = (float(err.max()), float((err / norm).max()))
    fastest = min(statistics.median(t) for t in times.values())
    for name in ROTATIONS:
        t = statistics.median(times[name])
        rows.append((name, t * 1e3, t / fastest, *errors[name, torch.float32], *errors[name, torch.float64]))
    return rows


# ---- (b) Euler YZX -> quaternion near w = 0 ---------------------------------------------------

def yzx_half_angles(m, h, a, b):
    """The first method: half-angle products (SPEC's heading/attitude/bank case)."""
    c1, s1 = m.cos(h / 2), m.sin(h / 2)
    c2, s2 = m.cos(a / 2), m.sin(a / 2)
    c3, s3 = m.cos(b / 2), m.sin(b / 2)
    return (c1 * c2 * c3 - s1 * s2 * s3, s1 * s2 * c3 + c1 * c2 * s3,
            s1 * c2 * c3 + c1 * s2 * s3, c1 * s2 * c3 - s1 * c2 * s3)


def yzx_square_root(m, h, a, b):
    """The second method: ``w = sqrt(1 + trace R) / 2`` and the skew part of R over ``4 w``, R's
    entries written in the full angles (heading h about y, attitude a about z, bank b about x)."""
    C1, S1, C2, S2, C3, S3 = m.cos(h), m.sin(h), m.cos(a), m.sin(a), m.cos(b), m.sin(b)
    w = m.sqrt(1 + C1 * C2 + C1 * C3 - S1 * S2 * S3 + C2 * C3) / 2
    w4 = 4 * w
    return (w, (C2 * S3 + C1 * S3 + S1 * S2 * C3) / w4,
            (S1 * C2 + S1 * C3 + C1 * S2 * S3) / w4,
            (-S1 * S3 + C1 * S2 * C3 + S2) / w4)


class _NumpyLD:
    sqrt, sin, cos = staticmethod(np.sqrt), staticmethod(np.sin), staticmethod(np.cos)


def _stack(components):
    return torch.stack(components, -1)


def _sign_free_error(q, ref):
    """Largest component error of ``q`` against ``ref`` or ``-ref`` (one rotation), per row."""
    q = q.astype(LD)
    return np.minimum(np.abs(q - ref).max(-1), np.abs(q + ref).max(-1))


def check_formulas():
    """Both methods equal torchquat's intrinsic 'YZX' at generic angles and SPEC's worked case."""
    angles = torch.rand(1000, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * 2 - 1
    expected = tq.euler_to_quat(angles, "YZX").numpy()
    for method in (yzx_half_angles, yzx_square_root):
        got = _stack(method(torch, *angles.unbind(-1))).numpy()
        assert _sign_free_error(got, expected.astype(LD)).max() < 1e-12, method.__name__
        bank = _stack(method(torch, *torch.tensor([[0.0, 0.0, math.pi / 2]], dtype=torch.float64).unbind(-1)))
        assert torch.allclose(bank, torch.tensor([[math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0]], dtype=torch.float64))


def claim_b(n, seed):
    """Rows of (distance range, then per dtype: the first method's max error, the second's over its finite
    results, how many of its results are NaN or inf, how many rows)."""
    g = torch.Generator().manual_seed(seed)
    axis = torch.randn(n, 3, dtype=torch.float64, generator=g)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    delta = 10.0 ** (-9 * torch.rand(n, dtype=torch.float64, generator=g))  # log-uniform in (1e-9, 1]
    delta[: n // 20] = 0.0  # exactly 180 degrees
    angles = tq.quat_to_euler(tq.axis_angle_to_quat(axis * (math.pi - delta)[:, None]), "YZX")
    edges = [1.0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 0.0]
    per_dtype = {}
    for dtype in (torch.float32, torch.float64):
        a = angles.to(dtype)
        ref = np.stack(yzx_half_angles(_NumpyLD, *a.numpy().astype(LD).T), -1)
        distance = 2 * np.arcsin(np.minimum(np.abs(ref[:, 0]), 1)).astype(np.float64)  # pi - rotation angle
        first = _stack(yzx_half_angles(torch, *a.unbind(-1))).numpy()
        second = _stack(yzx_square_root(torch, *a.unbind(-1))).numpy()
        per_dtype[dtype] = (distance, _sign_free_error(first, ref), _sign_free_error(second, ref))
    rows = []
    for hi, lo in zip(edges, edges[1:]):
        row = [hi, lo]
        for dtype in (torch.float32, torch.float64):
            distance, e1, e2 = per_dtype[dtype]
            inside = (distance < hi) & (distance >= lo) if lo > 0 else distance < hi
            if not inside.any():
                row += [None, None, 0, 0]
                continue
            bad = ~np.isfinite(e2[inside])  # (sqrt of a negative: NaN; w = 0: a division by zero)
            assert np.isfinite(e1[inside]).all()
            row += [float(e1[inside].max()), float(e2[inside][~bad].max()) if not bad.all() else math.nan,
                    int(bad.sum()), int(inside.sum())]
        rows.append(row)
    return rows


def _e(x):
    return "-" if x is None else ("NaN" if math.isnan(x) else f"{x:.1e}")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=1_000_000, help="rows (default 1e6)")
    p.add_argument("--repeats", type=int, default=9, help="timed runs per variant (default 9)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.n < 1 or args.repeats < 1:
        p.error("--n and --repeats must be at least 1")
    check_formulas()
    print(f"torch {torch.__version__}, {args.n} rows, seed {args.seed}\n")
    print("(a) rotating vectors: eager, float32, 1 thread, median of", args.repeats, "interleaved runs;")
    print("    error: largest |v' - reference| component, absolute and relative to |v|\n")
    print("| formula | time (ms) | x fastest | float32 error | float32 rel. | float64 error | float64 rel. |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, ms, ratio, e32, r32, e64, r64 in claim_a(args.n, args.repeats, args.seed):
        print(f"| `{name}` | {ms:.2f} | {ratio:.2f} | {_e(e32)} | {_e(r32)} | {_e(e64)} | {_e(r64)} |")
    print("\n(b) Euler 'YZX' -> quaternion near 180 degrees: largest component error (up to sign);")
    print("    distance = pi - rotation angle of the angles as rounded to the dtype; the square root's")
    print("    error over its finite results, then how many were NaN or inf\n")
    print("| distance to 180 deg | rows f32 | half angles f32 | square root f32 | not finite f32 "
          "| rows f64 | half angles f64 | square root f64 | not finite f64 |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for hi, lo, a1, a2, anan, an, b1, b2, bnan, bn in claim_b(args.n, args.seed):
        band = f"[{lo:.0e}, {hi:.0e})" if lo > 0 else f"[0, {hi:.0e})"
        print(f"| {band} | {an} | {_e(a1)} | {_e(a2)} | {anan} | {bn} | {_e(b1)} | {_e(b2)} | {bnan} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
