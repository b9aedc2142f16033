"""torchquat: batched, differentiable 3D rotations for PyTorch.

Quaternions are ``(w, x, y, z)`` (Hamilton), matrices act on column vectors, Euler conventions
follow SciPy's rule (``'ZYX'`` intrinsic, ``'xyz'`` extrinsic); see :mod:`torchquat.conventions`.
"""

from ._dispatch import compiled_kernels_enabled, use_compiled_kernels
from .axis_angle import axis_angle_to_matrix, axis_angle_to_quat, matrix_to_axis_angle, quat_to_axis_angle
from .conventions import EULER_CONVENTIONS
from .distance import matrix_geodesic_distance, quat_geodesic_distance
from .errors import ConventionError, ShapeError
from .euler import euler_gimbal_lock, euler_to_matrix, euler_to_quat, matrix_to_euler, quat_to_euler
from .kinematics import forward_kinematics
from .matrix import matrix_to_quat, quat_to_matrix
from .quaternion import (
    quat_conjugate, quat_from_jpl, quat_identity, quat_inverse, quat_multiply, quat_normalize, quat_rotate,
    quat_standardize, quat_to_jpl, quat_wxyz_to_xyzw, quat_xyzw_to_wxyz, random_quat,
)
from .registry import REPRESENTATIONS, convert
from .rot6d import matrix_to_rot6d, rot6d_to_matrix, rot9d_to_matrix
from .slerp import quat_slerp

from . import nn  # noqa: E402  (torchquat.nn: layers, heads, losses)

__version__ = "0.1.0"

__all__ = [
    "ShapeError", "ConventionError", "EULER_CONVENTIONS", "REPRESENTATIONS",
    "quat_to_matrix", "matrix_to_quat",
    "euler_to_quat", "quat_to_euler", "euler_to_matrix", "matrix_to_euler", "euler_gimbal_lock",
    "axis_angle_to_quat", "quat_to_axis_angle", "axis_angle_to_matrix", "matrix_to_axis_angle",
    "rot6d_to_matrix", "matrix_to_rot6d", "rot9d_to_matrix", "convert",
    "quat_multiply", "quat_conjugate", "quat_inverse", "quat_normalize", "quat_standardize",
    "quat_rotate", "quat_slerp", "quat_identity", "random_quat",
    "quat_wxyz_to_xyzw", "quat_xyzw_to_wxyz", "quat_from_jpl", "quat_to_jpl",
    "quat_geodesic_distance", "matrix_geodesic_distance",
    "use_compiled_kernels", "compiled_kernels_enabled", "forward_kinematics",
]


def __getattr__(name: str):
    """``torchquat.io``, ``torchquat.traj`` and ``torchquat.dask`` on first use, so that ``import
    torchquat`` loads neither file formats nor NumPy-side code it does not need."""
    if name in ("io", "traj", "dask"):
        import importlib
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
