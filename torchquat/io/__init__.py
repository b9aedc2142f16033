"""Pose files (TUM, KITTI, EuRoC, plain CSV/NPZ/NPY, COLMAP, NeRF, BOP), streaming conversion and dataset
transforms.

Example:
    >>> from torchquat.io import ConvertRotation, Poses, read_poses, write_poses  # doctest: +SKIP
    >>> poses = read_poses("KITTI_00_gt.txt")                                   # doctest: +SKIP
    >>> write_poses("out.csv", poses, representation="euler:ZYX", degrees=True)  # doctest: +SKIP
"""

from .checks import Report
from .detect import FORMATS, POSE_FORMATS, detect_format, output_plan
from .files import atomic_output, output_folder_problem, write_json
from .poses import PoseFileError, Poses
from .streaming import DEFAULT_CHUNK_SIZE, convert_file, iter_poses, read_poses, read_times, write_poses
from .transforms import ConvertRotation
from .motion import Motion, Skeleton  # motion capture (SPEC section 8)
from .bvh import read_bvh
from .bvh_write import write_bvh
from .amass import read_amass
from .mocap import MOTION_FORMATS, convert_motion, read_motion, write_motion
from .shards import ConvertSummary, FileResult, convert_files  # many files, on Dask (SPEC section 9)
from .cameras import CAMERA_FORMATS, FORMAT_MAPS, PoseMap, to_convention  # COLMAP, NeRF, BOP (SPEC section 7)

__all__ = ["Poses", "PoseFileError", "Report", "read_poses", "write_poses", "iter_poses", "convert_file",
           "convert_files", "ConvertSummary", "FileResult",
           "detect_format", "output_plan", "read_times", "atomic_output", "output_folder_problem", "write_json",
           "ConvertRotation", "FORMATS",
           "POSE_FORMATS", "DEFAULT_CHUNK_SIZE",
           "Motion", "Skeleton", "read_bvh", "write_bvh", "read_amass", "read_motion", "write_motion",
           "convert_motion", "MOTION_FORMATS", "PoseMap", "FORMAT_MAPS", "CAMERA_FORMATS", "to_convention"]
