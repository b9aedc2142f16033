"""Checks and small repairs of rotations read from files, and the report of what was done.

Tolerances (stated once, quoted in messages):

* quaternions: ``|norm - 1| < 1e-3`` is accepted and normalised (counted when above 1e-6,
  which text with 6 decimals can explain); anything further is an error.
* matrices: orthogonality error ``max |R^T R - I|`` below 1e-5 is accepted as written
  (KITTI's 7 significant digits give about 1e-7); up to 1e-2 the matrix is projected onto the
  nearest rotation by SVD (``torchquat.convert(R, "rot9d", "matrix")``) and counted; beyond
  that, or ``det(R) < 0``, it is an error.
"""

from collections import Counter
from typing import List, Tuple

import numpy as np
import torch

from .. import convert
from .poses import PoseFileError

__all__ = ["Report", "normalize_quaternions", "check_matrices", "QUAT_NORM_TOLERANCE",
           "ORTHOGONALITY_TOLERANCE", "ORTHOGONALITY_ACCEPTED"]

QUAT_NORM_TOLERANCE = 1e-3
QUAT_NORM_REPORTED = 1e-6
ORTHOGONALITY_ACCEPTED = 1e-5
ORTHOGONALITY_TOLERANCE = 1e-2


class Report:
    """What a conversion assumed and repaired, for the command line to print on stderr."""

    def __init__(self):
        self.notes: List[str] = []
        self.counts: Counter = Counter()
        self.worst: dict = {}

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    def count(self, what: str, n: int, worst: float = 0.0) -> None:
        if n:
            self.counts[what] += n
            self.worst[what] = max(self.worst.get(what, 0.0), worst)

    def lines(self) -> List[str]:
        out = list(self.notes)
        for what, n in self.counts.items():
            out.append(f"{what}: {n} (largest deviation {self.worst[what]:.2g})")
        return out


def normalize_quaternions(path, q: np.ndarray, line_numbers: np.ndarray, report: Report) -> np.ndarray:
    """Divide each quaternion by its norm; raise for norms off by ``QUAT_NORM_TOLERANCE`` or more.

    Args:
        path: file name for messages.
        q: ``(n, 4)`` float64 quaternions in any component order.
        line_numbers: ``(n,)`` line of each row.
        report: collects the count of normalised rows.

    Returns:
        The unit quaternions.
    """
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    deviation = np.abs(norm - 1)
    bad = deviation >= QUAT_NORM_TOLERANCE
    if bad.any():
        row = int(np.argmax(bad))
        raise PoseFileError(path, f"quaternion norm {norm[row]:.6g} is not 1 (|norm - 1| must be below "
                            f"{QUAT_NORM_TOLERANCE:g} to be normalised)", int(line_numbers[row]))
    reported = deviation > QUAT_NORM_REPORTED
    report.count(f"quaternions normalised (|norm - 1| < {QUAT_NORM_TOLERANCE:g})", int(reported.sum()),
                 float(deviation.max(initial=0.0)))
    unit = deviation <= 4 * np.finfo(np.float64).eps  # already unit to rounding: keep the bits as written
    return np.where(unit[:, None], q, q / norm[:, None])


def _orthogonality_error_and_det(R: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """``max |R^T R - I|`` and ``det R`` of each ``(n, 3, 3)`` matrix, with one array per entry.

    (``einsum`` over the 3x3 blocks took 6x longer: 0.15 s per 1M matrices against 0.025 s.)
    """
    r = np.ascontiguousarray(R.reshape(len(R), 9).T)  # (9, n): r[3 * i + j] is R[:, i, j]
    c = [r[0::3], r[1::3], r[2::3]]  # the columns, each (3, n)
    error = np.zeros(len(R))
    for i in range(3):
        for j in range(i, 3):
            entry = c[i][0] * c[j][0] + c[i][1] * c[j][1] + c[i][2] * c[j][2]
            if i == j:
                entry -= 1.0
            np.maximum(error, np.abs(entry), out=error)
    det = (r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6])
           + r[2] * (r[3] * r[7] - r[4] * r[6]))
    return error, det


def check_matrices(path, R: np.ndarray, line_numbers: np.ndarray, report: Report) -> Tuple[np.ndarray, int]:
    """Accept, project or reject rotation matrices by their orthogonality error.

    Args:
        path: file name for messages.
        R: ``(n, 3, 3)`` float64 matrices.
        line_numbers: ``(n,)`` line of each row.
        report: collects the count of projected matrices.

    Returns:
        The matrices (projected where needed) and how many were projected.
    """
    error, det = _orthogonality_error_and_det(R)
    bad = (error >= ORTHOGONALITY_TOLERANCE) | (det <= 0)
    if bad.any():
        row = int(np.argmax(bad))
        why = "a reflection (det < 0)" if det[row] <= 0 else f"not a rotation (max |R^T R - I| = {error[row]:.3g})"
        raise PoseFileError(path, f"matrix is {why}; at most {ORTHOGONALITY_TOLERANCE:g} is projected "
                            "onto the nearest rotation", int(line_numbers[row]))
    project = np.flatnonzero(error >= ORTHOGONALITY_ACCEPTED)
    if project.size:
        R = R.copy()
        R[project] = convert(torch.from_numpy(R[project]), "rot9d", "matrix").numpy()
        report.count(f"matrices projected onto the nearest rotation ({ORTHOGONALITY_ACCEPTED:g} <= "
                     f"max |R^T R - I| < {ORTHOGONALITY_TOLERANCE:g})", int(project.size),
                     float(error[project].max()))
    return R, int(project.size)


def check_rot6d(path, x: np.ndarray, line_numbers: np.ndarray) -> np.ndarray:
    """Reject 6D rows whose two vectors are zero or collinear: they name no rotation (the
    conversion gives NaN, which would be written as numbers)."""
    finite = torch.isfinite(convert(torch.from_numpy(x), "rot6d", "matrix")).flatten(1).all(1).numpy()
    if not finite.all():
        raise PoseFileError(path, "6D rotation whose two vectors are zero or collinear: it names no rotation",
                            int(line_numbers[int(np.argmin(finite))]))
    return x

