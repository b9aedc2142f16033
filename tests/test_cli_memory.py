"""Streaming keeps peak memory flat in the file size (measured in a child process)."""

import subprocess
import sys

import numpy as np
import pytest

CHILD = """
import resource, sys
from torchquat.io import convert_file
convert_file(sys.argv[1], sys.argv[2])
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def write_kitti(path, rows: int) -> None:
    rng = np.random.default_rng(0)
    block = np.tile(np.array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0], dtype=float), (10_000, 1))
    block[:, [3, 7, 11]] = np.round(rng.standard_normal((10_000, 3)) * 100, 6)
    text = "\n".join(" ".join(f"{v:.6e}" for v in row) for row in block) + "\n"
    with open(path, "w") as stream:
        for _ in range(rows // 10_000):
            stream.write(text)


def peak_rss_kb(src, out) -> int:
    result = subprocess.run([sys.executable, "-c", CHILD, str(src), str(out)], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    return int(result.stdout.split()[-1])


@pytest.mark.slow
def test_peak_memory_is_flat_in_file_size(tmp_path):
    small, large = tmp_path / "small.kitti", tmp_path / "large.kitti"
    write_kitti(small, 50_000)
    write_kitti(large, 500_000)
    small_peak = peak_rss_kb(small, tmp_path / "small.tum")
    large_peak = peak_rss_kb(large, tmp_path / "large.tum")
    assert large.stat().st_size > 9 * small.stat().st_size
    assert sum(1 for _ in open(tmp_path / "large.tum")) == 500_001
    assert large_peak < 1.5 * small_peak, (small_peak, large_peak)
