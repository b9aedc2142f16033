"""The conventions table: stated once here, read everywhere else.

=====================  ==========================================================================
quaternion             ``(..., 4)``, scalar first ``(w, x, y, z)``, Hamilton product (``ij = k``)
rotation               active: ``quat_rotate(q, v) == q (0, v) q* == quat_to_matrix(q) @ v``
rotation matrix        ``(..., 3, 3)`` acting on column vectors (``R @ v``)
Euler angles           ``(..., 3)`` in the order the convention's letters name them, radians
Euler convention       SciPy's rule: ``'ZYX'`` (upper case) intrinsic, ``'xyz'`` (lower) extrinsic
axis-angle             ``(..., 3)``: unit axis times angle (rotation vector)
6D                     ``(..., 6)``: first two *columns* of R (Zhou et al. 2019)
9D                     ``(..., 9)`` row-major or ``(..., 3, 3)``, projected by SVD (Levinson 2020)
=====================  ==========================================================================
"""

import math
from itertools import permutations
from typing import Dict, NamedTuple

import torch

from .errors import ConventionError

__all__ = ["EulerConvention", "EULER_CONVENTIONS", "parse_convention", "gimbal_eps", "gimbal_threshold", "check_degrees"]

QUAT_LAYOUT = "wxyz"
AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


class EulerConvention(NamedTuple):
    """One of the 24 Euler conventions, parsed once.

    ``axes`` are the 0-based axis indices in the order the letters name them;
    ``intrinsic`` is True for upper case (rotations about the moving body's axes);
    ``symmetric`` is True for proper Euler sequences (first axis == third axis).
    """

    name: str
    axes: tuple
    intrinsic: bool
    symmetric: bool


def _build_table() -> Dict[str, EulerConvention]:
    sequences = ["".join(p) for p in permutations("xyz")]  # Tait-Bryan: 6
    sequences += [a + b + a for a in "xyz" for b in "xyz" if a != b]  # proper Euler: 6
    table = {}
    for seq in sequences:
        axes = tuple(AXIS_INDEX[c] for c in seq)
        for name, intrinsic in ((seq, False), (seq.upper(), True)):
            table[name] = EulerConvention(name, axes, intrinsic, axes[0] == axes[2])
    return table


EULER_CONVENTIONS: Dict[str, EulerConvention] = _build_table()


def parse_convention(convention, fn: str) -> EulerConvention:
    """Look ``convention`` up in the table; raise ``ConventionError`` naming ``fn`` if invalid."""
    found = EULER_CONVENTIONS.get(convention) if isinstance(convention, str) else None
    if found is None:
        raise ConventionError(
            f"{fn}: invalid convention {convention!r}: use 3 letters all from 'xyz' (extrinsic) "
            "or all from 'XYZ' (intrinsic), adjacent letters different, e.g. 'ZYX' or 'zxz'"
        )
    return found


def gimbal_eps(dtype: torch.dtype) -> float:
    """Default gimbal-lock threshold (radians): 1e-7 in float64, 1e-6 in float32 and below."""
    return 1e-7 if dtype == torch.float64 else 1e-6


def check_degrees(fn: str, degrees) -> bool:
    """``degrees`` as a bool: ``True`` or ``False`` (or 1, 0, NumPy's bools), else ``ValueError``
    naming ``fn`` (the string ``"False"`` would be true)."""
    if isinstance(degrees, (str, bytes)) or degrees not in (True, False):
        raise ValueError(f"{fn}: expected degrees to be True or False, got {degrees!r}")
    return bool(degrees)


def gimbal_threshold(fn: str, eps, dtype: torch.dtype) -> float:
    """``eps`` as a float of radians (the default for ``dtype`` when ``None``), checked: a number
    from 0 to pi/2 (the lock test compares sines, which grow only that far), else ``TypeError`` or
    ``ValueError`` naming ``fn``."""
    if eps is None:
        return gimbal_eps(dtype)
    try:
        value = float(eps)
    except (TypeError, ValueError):
        raise TypeError(f"{fn}: expected eps to be a number of radians, got {eps!r}") from None
    if not 0.0 <= value <= math.pi / 2:  # (NaN fails too)
        raise ValueError(f"{fn}: expected eps between 0 and pi/2 radians, got {eps!r}")
    return value
