"""Pose files (TUM, KITTI, EuRoC, plain CSV/NPZ/NPY), streaming conversion and dataset transforms.

Example:
    >>> from torchquat.io import ConvertRotation, Poses, read_poses, write_poses  # doctest: +SKIP
    >>> poses = read_poses("KITTI_00_gt.txt")                                   # doctest: +SKIP
    >>> write_poses("out.csv", poses, representation="euler:ZYX", degrees=True)  # doctest: +SKIP
"""

from .checks import Report
from .poses import PoseFileError, Poses
from .streaming import (
    DEFAULT_CHUNK_SIZE, FORMATS, POSE_FORMATS, atomic_output, output_folder_problem, convert_file, detect_format, iter_poses, output_plan,
    read_poses, read_times, write_poses,
)
from .transforms import ConvertRotation

__all__ = ["Poses", "PoseFileError", "Report", "read_poses", "write_poses", "iter_poses", "convert_file",
           "detect_format", "output_plan", "read_times", "atomic_output", "output_folder_problem", "ConvertRotation", "FORMATS",
           "POSE_FORMATS", "DEFAULT_CHUNK_SIZE"]
