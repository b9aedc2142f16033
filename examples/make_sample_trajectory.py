"""Write examples/data/sample_trajectory.tum: 500 poses of a smooth, deterministic path (TUM format).

The path is a figure-eight at walking speed, 1.5 m above the floor, sampled at 20 Hz, with the
body yawing along the direction of travel and rocking gently in pitch and roll. Rotations are
built with torchquat (intrinsic 'ZYX' yaw-pitch-roll) and written with torchquat.io, so running
this script twice gives the same bytes.

    python examples/make_sample_trajectory.py
    torchquat convert examples/data/sample_trajectory.tum /tmp/out.csv --to euler:ZYX --degrees
"""

import math
from pathlib import Path

import numpy as np
import torch

from torchquat.io import Poses, fastpath, write_poses

OUT = Path(__file__).resolve().parent / "data" / "sample_trajectory.tum"


def make_trajectory(n: int = 500, rate_hz: float = 20.0) -> Poses:
    """A figure-eight: positions, yaw along the tangent, small pitch/roll oscillations."""
    t = np.arange(n) / rate_hz
    phase = 2 * math.pi * t / (n / rate_hz)
    x, y, z = 3.0 * np.sin(phase), 1.5 * np.sin(2 * phase), 1.5 + 0.1 * np.sin(3 * phase)
    yaw = np.arctan2(3.0 * np.cos(2 * phase), 3.0 * np.cos(phase))  # along d(x, y)/dt
    pitch, roll = 0.05 * np.sin(5 * phase), 0.08 * np.sin(7 * phase)
    angles = torch.from_numpy(np.stack([yaw, pitch, roll], axis=1))
    ns = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_000  # 20 Hz, exact
    return Poses(angles, "euler:ZYX", positions=torch.from_numpy(np.stack([x, y, z], axis=1)),
                 timestamps_ns=ns)


def main() -> None:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fastpath.use_polars(False)  # (polars writes the same values in its own layout: 0.0 for 0)
    rows = write_poses(OUT, make_trajectory(), format="tum")
    print(f"wrote {rows} poses to {OUT}")


if __name__ == "__main__":
    main()
