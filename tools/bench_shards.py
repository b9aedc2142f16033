"""Benchmark of many-files conversion (SPEC section 9) and of one file against evo.

    python tools/bench_shards.py [--shards 48] [--rows 50000] [--single 1000000] [--skip-evo]

1. ``torchquat convert SHARDS/ OUT/ --to tum --workers N`` for N = 1 and 2, end to end in a fresh
   process (import, cluster start and close included): the wall time of each and the speed-up;
   and, as the machine's ceiling, two independent ``--workers 1`` processes on half the files each.
2. Memory per worker, flat in the file size: a local cluster of 2 processes converts shards of
   ``rows`` and of ``4 * rows`` poses; each worker's peak RSS (VmHWM) is read after each run.
3. One file, one process: ``rows`` KITTI poses to TUM with ``torchquat convert`` (wall time, peak
   RSS of the child from GNU time) against evo
   (``read_kitti_poses_file``, ``orientations_quat_wxyz``, ``numpy.savetxt``).

The shards are KITTI_00_gt.txt (../shared/data) tiled to the size asked for.
"""

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "KITTI_00_gt.txt"


def tiled(path: Path, rows: int) -> None:
    lines = DATA.read_text().splitlines()
    path.write_text("\n".join((lines * (rows // len(lines) + 1))[:rows]) + "\n")


def run(command, **kwargs):
    """Wall time and peak RSS (MB) of a child process. The RSS comes from GNU time where there is
    one: a child's own ``ru_maxrss`` starts from this process's pages at the fork."""
    timed = ["/usr/bin/time", "-f", "peak-rss-kb %M"] + list(command) if os.path.exists("/usr/bin/time") else command
    start = time.perf_counter()
    child = subprocess.Popen(timed, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **kwargs)
    stderr = child.stderr.read()
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(map(str, command))} failed:\n{stderr}")
    reported = [line for line in stderr.splitlines() if line.startswith("peak-rss-kb ")]
    peak_kb = int(reported[-1].split()[1]) if reported else usage.ru_maxrss
    return wall, peak_kb / 1024, "\n".join(line for line in stderr.splitlines() if not line.startswith("peak-rss-kb "))


def shards(folder: Path, count: int, rows: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    first = folder / "shard000.txt"
    tiled(first, rows)
    for i in range(1, count):
        target = folder / f"shard{i:03d}.txt"
        if not target.exists():
            os.link(first, target)
    return folder


def speedup(root: Path, count: int, rows: int) -> None:
    folder = shards(root / f"shards_{rows}", count, rows)
    times = {}
    for workers in (1, 2, 1, 2):  # (twice each, interleaved: the best of two)
        out = root / f"out_{workers}"
        wall, _, err = run([sys.executable, "-m", "torchquat", "convert", str(folder), str(out), "--to", "tum",
                            "--workers", str(workers), "--overwrite"])
        times[workers] = min(times.get(workers, wall), wall)
        print(f"  --workers {workers}: {wall:.2f} s  ({err.strip().splitlines()[-1]})", flush=True)
    print(f"{count} shards x {rows} poses to TUM: --workers 1 {times[1]:.2f} s, --workers 2 {times[2]:.2f} s, "
          f"speed-up {times[1] / times[2]:.2f}x (target >= 1.7x)", flush=True)
    # The machine's own ceiling, without Dask: the same files in two halves, converted by two
    # independent `--workers 1` processes at once, against one process converting all of them.
    halves = [root / f"half_{k}" for k in (0, 1)]
    for k, half in enumerate(halves):
        half.mkdir(exist_ok=True)
        for i in range(k, count, 2):
            target = half / f"shard{i:03d}.txt"
            if not target.exists():
                os.link(folder / f"shard{i:03d}.txt", target)
    command = [sys.executable, "-m", "torchquat", "convert", "IN", "OUT", "--to", "tum", "--workers", "1", "--overwrite"]
    best = None
    for _ in range(2):
        start = time.perf_counter()
        children = [subprocess.Popen([str(half) if c == "IN" else str(root / f"out_{half.name}") if c == "OUT" else c
                                      for c in command], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                    for half in halves]
        if any(child.wait() for child in children):
            raise SystemExit("a half's conversion failed")
        best = min(best or math.inf, time.perf_counter() - start)
    print(f"  no Dask, two processes on a half each: {best:.2f} s, speed-up {times[1] / best:.2f}x "
          "(what two processes gain on this machine)", flush=True)


def worker_memory(root: Path, rows: int) -> None:
    import distributed

    from torchquat.io.cluster import local_cluster
    from torchquat.io import convert_files

    def peak_kb():
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM"):
                return int(line.split()[1])
    with local_cluster(2) as cluster, distributed.Client(cluster) as client:
        for size in (rows, 4 * rows):
            folder = shards(root / f"mem_{size}", 8, size)
            summary = convert_files([folder], root / f"mem_out_{size}", to="tum", overwrite=True,
                                    scheduler=cluster.scheduler_address)
            peaks = client.run(peak_kb)
            print(f"  shards of {size} poses: {summary}; worker peak RSS "
                  + ", ".join(f"{kb / 1024:.0f} MB" for kb in peaks.values()), flush=True)


def single(root: Path, rows: int, evo: bool) -> None:
    path = root / f"kitti_{rows}.txt"
    if not path.exists():
        tiled(path, rows)
    wall, rss, _ = run([sys.executable, "-m", "torchquat", "convert", str(path), str(root / "one.tum")])
    print(f"one file, {rows} KITTI poses to TUM: torchquat {wall:.2f} s, peak RSS {rss:.0f} MB", flush=True)
    if not evo:
        return
    code = ("import numpy as np, sys\nfrom evo.tools import file_interface\n"
            "t = file_interface.read_kitti_poses_file(sys.argv[1])\n"
            "q = t.orientations_quat_wxyz\n"
            "stamps = np.arange(len(q), dtype=float)\n"
            "np.savetxt(sys.argv[2], np.column_stack([stamps, t.positions_xyz, q[:, 1:], q[:, :1]]))\n")
    evo_wall, evo_rss, _ = run([sys.executable, "-c", code, str(path), str(root / "evo.tum")])
    print(f"  evo {evo_wall:.2f} s (peak RSS {evo_rss:.0f} MB): torchquat {evo_wall / wall:.1f}x faster "
          "(target >= 10x, RSS < 500 MB)", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shards", type=int, default=48)
    parser.add_argument("--rows", type=int, default=50_000)
    parser.add_argument("--single", type=int, default=1_000_000)
    parser.add_argument("--skip-evo", action="store_true")
    parser.add_argument("--only", choices=("speedup", "memory", "single"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_shards_") as tmp:
        root = Path(tmp)
        if args.only in (None, "speedup"):
            speedup(root, args.shards, args.rows)
        if args.only in (None, "memory"):
            worker_memory(root, args.rows)
        if args.only in (None, "single"):
            single(root, args.single, not args.skip_evo)


if __name__ == "__main__":
    main()
