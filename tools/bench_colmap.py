"""Benchmark: a large COLMAP images.bin converted to TUM, streaming, against pycolmap loading it.

    python tools/bench_colmap.py [--sizes 10000,100000,300000] [--points 50] [--folder /tmp/bench_colmap]

Writes a model (cameras.bin and points3D.bin by pycolmap, images.bin with ``--points`` 2D points
per image in COLMAP's layout), then runs each step in a fresh process and prints its wall time
and peak memory (ru_maxrss) above the memory after imports:

* ``pycolmap``: ``pycolmap.Reconstruction().read_binary(folder)``;
* ``torchquat``: ``torchquat.io.convert_file(images.bin, cameras.tum)`` (single thread, as the CLI);
for each number of images in ``--sizes``: torchquat's peak memory stays flat as the count grows
(it holds a few chunks of 10,000 images), pycolmap's grows with it (it holds the whole model).

Not a test: it takes tens of seconds and a few hundred MB of disk.
"""

import argparse
import json
import os
import struct
import subprocess
import sys
import time

import numpy as np

_STEP = r"""
import json, resource, sys, time
kind, folder, out = sys.argv[1:4]
if kind == "pycolmap":
    import pycolmap
else:
    import torch
    from torchquat.io import convert_file
    torch.set_num_threads(1)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
start = time.perf_counter()
if kind == "pycolmap":
    model = pycolmap.Reconstruction()
    model.read_binary(folder)
    count = model.num_images()
else:
    count = convert_file(folder + "/images.bin", out)
seconds = time.perf_counter() - start
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"images": count, "seconds": seconds, "peak_mb": (peak - base) / 1024}))
"""


def write_model(folder: str, images: int, points: int, seed: int = 0) -> None:
    """cameras.bin and points3D.bin from pycolmap, images.bin written here in COLMAP's layout."""
    import pycolmap
    os.makedirs(folder, exist_ok=True)
    model = pycolmap.Reconstruction()
    model.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=640, height=480,
                                                      params=[500.0, 500.0, 320.0, 240.0], camera_id=1))
    model.write_binary(folder)
    for name in ("images.bin", "frames.bin", "rigs.bin"):  # (pycolmap makes trivial rigs and frames from images)
        path = os.path.join(folder, name)
        if os.path.exists(path):
            os.remove(path)
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(images, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    t = rng.normal(size=(images, 3)) * 10
    point = struct.pack("<ddQ", 1.0, 2.0, 2 ** 64 - 1)  # (no 3D point: COLMAP's invalid id)
    with open(os.path.join(folder, "images.bin"), "wb") as stream:
        stream.write(struct.pack("<Q", images))
        for k in range(images):
            stream.write(struct.pack("<I7dI", k + 1, *q[k], *t[k], 1) + f"frame_{k:06d}.jpg\0".encode()
                         + struct.pack("<Q", points) + point * points)


def run_step(kind: str, folder: str, out: str) -> dict:
    result = subprocess.run([sys.executable, "-c", _STEP, kind, folder, out], capture_output=True, text=True,
                            check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,100000,300000", help="numbers of images, comma separated")
    parser.add_argument("--points", type=int, default=50, help="2D points per image (24 bytes each)")
    parser.add_argument("--folder", default="/tmp/bench_colmap")
    args = parser.parse_args(argv)
    rows = []
    for images in (int(n) for n in args.sizes.split(",")):
        folder = os.path.join(args.folder, str(images))
        start = time.perf_counter()
        write_model(folder, images, args.points)
        size = os.path.getsize(os.path.join(folder, "images.bin")) / 2 ** 20
        print(f"wrote {folder}/images.bin: {images} images, {size:.0f} MB ({time.perf_counter() - start:.1f} s)",
              file=sys.stderr)
        for kind in ("pycolmap", "torchquat"):
            step = run_step(kind, folder, os.path.join(folder, "cameras.tum"))
            rows.append((images, kind, step["seconds"], step["peak_mb"]))
    print(f"{'images':>8} {'reader':<10} {'seconds':>8} {'peak MB':>8}")
    for images, kind, seconds, peak in rows:
        label = "pycolmap" if kind == "pycolmap" else "torchquat"
        print(f"{images:>8} {label:<10} {seconds:>8.2f} {peak:>8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
