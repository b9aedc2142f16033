"""Benchmark of torchquat.traj against evo (not a test).

1. ``torchquat eval`` against ``evo_ape`` on N KITTI poses (KITTI 00 repeated with a growing offset)
   and a perturbed copy, by index, both as subprocesses: wall time and peak RSS (of the child).
2. APE of a batch of B trajectories x T poses in one ``torchquat.traj.ape`` call against
   ``evo.main_ape.ape`` in a loop over the batch (translation part, SE(3) alignment).

Usage: python tools/bench_traj.py [--poses 1000000] [--batch 256] [--length 1000] [--data ../shared/data]
"""

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def kitti_files(data: Path, poses: int, folder: Path):
    given = np.loadtxt(data / "KITTI_00_gt.txt").reshape(-1, 3, 4)
    reps = -(-poses // len(given))
    shift = np.arange(reps).repeat(len(given))[:poses, None] * (given[-1, :, 3] - given[0, :, 3] + 10.0)
    ref = np.tile(given, (reps, 1, 1))[:poses]
    ref[:, :, 3] += shift
    rng = np.random.default_rng(0)
    est = ref.copy()
    est[:, :, 3] += rng.normal(scale=0.2, size=(poses, 3))
    paths = folder / "ref.txt", folder / "est.txt"
    for path, values in zip(paths, (ref, est)):
        np.savetxt(path, values.reshape(-1, 12), fmt="%.9g")
    return paths


def bench_files(args, folder: Path) -> None:
    ref, est = kitti_files(Path(args.data), args.poses, folder)
    ours = [sys.executable, "-m", "torchquat", "eval", str(ref), str(est), "--align"]
    theirs = ["evo_ape", "kitti", str(ref), str(est), "-a"]
    # peak RSS: each in its own child of a fresh interpreter, so the maxima are not mixed
    probe = ("import resource, subprocess, sys, time; s = time.perf_counter(); "
             "r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
             "print(time.perf_counter() - s, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, "
             "r.returncode); sys.stderr.write(r.stdout[-600:] + r.stderr[-600:])")
    rows = []
    for name, command in (("torchquat eval", ours), ("evo_ape", theirs)):
        result = subprocess.run([sys.executable, "-c", probe, *command], capture_output=True, text=True)
        wall, rss, rc = result.stdout.split()
        print(f"--- {name} output (tail) ---\n{result.stderr.strip()[-600:]}")
        rows.append((name, float(wall), float(rss), rc))
    print(f"\nAPE of {args.poses:,} KITTI poses against a perturbed copy, SE(3) aligned, by index:")
    for name, wall, rss, rc in rows:
        print(f"  {name:15s} {wall:8.2f} s   peak RSS {rss:8.0f} MiB   exit {rc}")
    print(f"  speed-up {rows[1][1] / rows[0][1]:.1f}x")


def bench_batch(args) -> None:
    import torch

    import torchquat
    import torchquat.traj as traj
    from evo import main_ape
    from evo.core import metrics
    from evo.core.trajectory import PosePath3D
    torch.manual_seed(0)
    b, n = args.batch, args.length
    q_ref = torchquat.random_quat((b, n), dtype=torch.float64)
    p_ref = torch.cumsum(torch.randn(b, n, 3, dtype=torch.float64), 1)
    q_est = torchquat.quat_normalize(q_ref + 0.01 * torch.randn(b, n, 4, dtype=torch.float64))
    p_est = p_ref + 0.1 * torch.randn(b, n, 3, dtype=torch.float64)
    traj.ape((q_ref[:2], p_ref[:2]), (q_est[:2], p_est[:2]), align=True)  # warm-up
    start = time.perf_counter()
    ours = traj.ape((q_ref, p_ref), (q_est, p_est), align=True)
    t_ours = time.perf_counter() - start
    paths = [(PosePath3D(p_ref[i].numpy(), q_ref[i].numpy()), PosePath3D(p_est[i].numpy(), q_est[i].numpy()))
             for i in range(b)]
    start = time.perf_counter()
    theirs = [main_ape.ape(r, e, metrics.PoseRelation.translation_part, align=True).np_arrays["error_array"]
              for r, e in paths]
    t_evo = time.perf_counter() - start
    diff = np.max(np.abs(ours.numpy() - np.stack(theirs)) / np.abs(np.stack(theirs)))
    print(f"\nAPE (translation part, SE(3) aligned) of {b} x {n} poses, threads {torch.get_num_threads()}:")
    print(f"  torchquat.traj.ape, one call  {t_ours * 1e3:9.1f} ms")
    print(f"  evo main_ape.ape, in a loop   {t_evo * 1e3:9.1f} ms   (poses built outside the timing)")
    print(f"  speed-up {t_evo / t_ours:.1f}x; largest relative difference {diff:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--poses", type=int, default=1_000_000)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--length", type=int, default=1000)
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    parser.add_argument("--skip-files", action="store_true")
    args = parser.parse_args()
    if not args.skip_files:
        with tempfile.TemporaryDirectory() as folder:
            bench_files(args, Path(folder))
    bench_batch(args)


if __name__ == "__main__":
    main()
