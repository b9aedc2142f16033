"""Time torchquat.io.read_bvh against bvhio.readAsBvh on a BVH file tiled to many frames.

The issue's figure (SPEC section 8): reading at least 10x faster than bvhio's ``readAsBvh`` on
``../shared/data/mocapbank_walk.bvh`` tiled to 18,200 frames, memory proportional to the frames.
Both readers run in this process, in turns, best of ``--rounds``; ``read_bvh`` times include the
Euler-to-quaternion conversion (bvhio's ``readAsBvh`` builds its per-frame quaternions too).
Peak memory of each reader is traced with ``tracemalloc`` (Python and NumPy allocations; torch's
own buffers are not seen by it, so the quaternion tensor's size is added).

Run::

    python tools/bench_bvh.py [--frames 18200] [--rounds 3] [--source ../shared/data/mocapbank_walk.bvh]
"""

import argparse
import os
import tempfile
import time
import tracemalloc
from pathlib import Path

import torch

from torchquat.io import read_bvh

DEFAULT_SOURCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mocapbank_walk.bvh"


def tiled(source: Path, frames: int, folder: str) -> str:
    """The source file with its frame lines repeated to ``frames`` lines, written to ``folder``."""
    text = source.read_bytes()
    head, _, rest = text.partition(b"MOTION")
    lines = [line for line in rest.split(b"\n") if line.strip()]
    motion = lines[2:]
    body = [motion[i % len(motion)] for i in range(frames)]
    path = os.path.join(folder, f"tiled_{frames}.bvh")
    with open(path, "wb") as out:
        out.write(head + b"MOTION\n" + f"Frames: {frames}\n".encode() + lines[1] + b"\n" + b"\n".join(body) + b"\n")
    return path


def best(fn, rounds: int):
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return min(times), result


def peak(fn) -> float:
    tracemalloc.start()
    result = fn()
    _, top = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    extra = result.rotations.numel() * result.rotations.element_size() if hasattr(result, "rotations") else 0
    return (top + extra) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", type=Path, default=DEFAULT_SOURCE)
    parser.add_argument("--frames", type=int, default=18_200)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as folder:
        path = tiled(args.source, args.frames, folder)
        size = os.path.getsize(path) / 1e6
        print(f"{path}: {args.frames} frames, {size:.1f} MB")
        read_bvh(path)  # (first call: imports and warm-up)
        ours, motion = best(lambda: read_bvh(path), args.rounds)
        print(f"torchquat.io.read_bvh   {ours * 1e3:8.1f} ms  -> rotations {tuple(motion.rotations.shape)}, "
              f"peak {peak(lambda: read_bvh(path)):.0f} MB")
        try:
            import bvhio
        except ImportError:
            print("bvhio is not installed: pip install bvhio")
            return
        theirs, _ = best(lambda: bvhio.readAsBvh(path), args.rounds)
        print(f"bvhio.readAsBvh         {theirs * 1e3:8.1f} ms  peak {peak(lambda: bvhio.readAsBvh(path)):.0f} MB")
        print(f"speed-up: {theirs / ours:.1f}x")


if __name__ == "__main__":
    main()
