"""AMASS ``.npz`` files (SMPL, SMPL-H, SMPL-X body parameters) read into a :class:`Motion`.

An AMASS file holds ``poses`` ``(T, 3 J)``: each joint's local rotation as axis-angle (52 joints
for SMPL-H, 55 for SMPL-X, 24 for plain SMPL), ``trans`` ``(T, 3)`` the root position, and the
frame rate under ``mocap_framerate`` (SMPL-H) or ``mocap_frame_rate`` (SMPL-X: the key was
renamed). The bone offsets are not in the file: they come from the body model and ``betas``, so
the skeleton's offsets are zeros; world positions need the model's joint locations.
"""

import os
from typing import List, Tuple

import numpy as np
import torch

import torchquat as _tq
from .motion import Motion, Skeleton
from .poses import PoseFileError

__all__ = ["read_amass", "smpl_skeleton", "FRAME_RATE_KEYS"]

FRAME_RATE_KEYS = ("mocap_framerate", "mocap_frame_rate")

_BODY = ["pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
         "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
         "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist"]
_BODY_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
_FINGERS = ("index", "middle", "pinky", "ring", "thumb")  # SMPL-H/SMPL-X order, three joints each


def _hand(side: str, wrist: int, first: int) -> Tuple[List[str], List[int]]:
    names, parents = [], []
    for f, finger in enumerate(_FINGERS):
        for k in range(3):
            names.append(f"{side}_{finger}{k + 1}")
            parents.append(wrist if k == 0 else first + 3 * f + k - 1)
    return names, parents


def smpl_skeleton(joints: int) -> Tuple[List[str], List[int]]:
    """Joint names and parents of the SMPL family by joint count.

    Args:
        joints: 24 (SMPL), 52 (SMPL-H) or 55 (SMPL-X).

    Returns:
        ``(names, parents)``, parents ``-1`` for the pelvis.

    Example:
        >>> names, parents = smpl_skeleton(52)
        >>> names[22], parents[22], names[51], parents[51]
        ('left_index1', 20, 'right_thumb3', 50)
    """
    if joints == 24:
        return _BODY + ["left_hand", "right_hand"], _BODY_PARENTS + [20, 21]
    if joints == 52:
        left, right = _hand("left", 20, 22), _hand("right", 21, 37)
        return _BODY + left[0] + right[0], _BODY_PARENTS + left[1] + right[1]
    if joints == 55:
        left, right = _hand("left", 20, 25), _hand("right", 21, 40)
        return (_BODY + ["jaw", "left_eye_smplhf", "right_eye_smplhf"] + left[0] + right[0],
                _BODY_PARENTS + [15, 15, 15] + left[1] + right[1])
    raise ValueError(f"smpl_skeleton: expected 24 (SMPL), 52 (SMPL-H) or 55 (SMPL-X) joints, got {joints}")


def _float_array(path, data, name: str, shape_text: str, ndim: int) -> np.ndarray:
    array = data[name]
    if array.dtype.kind not in "fiu" or array.ndim != ndim:
        raise PoseFileError(path, f"read_amass: expected array {name!r} of numbers with shape {shape_text}, "
                            f"got {array.dtype} {array.shape}")
    return array.astype(np.float64, copy=False)


def read_amass(path) -> Motion:
    """Read an AMASS ``.npz`` (SMPL-H or SMPL-X) into a :class:`Motion` of local quaternions.

    Args:
        path: the ``.npz`` file.

    Returns:
        A :class:`Motion`: ``rotations`` ``(T, J, 4)`` = :func:`torchquat.axis_angle_to_quat` of
        each joint's triple of ``poses`` (float64), ``root_positions`` = ``trans``,
        ``frame_time`` = 1 / frame rate, the SMPL-family skeleton with zero offsets, and every
        other array (``betas``, ``gender``, ``dmpls``, ...) in ``extras``.

    Raises:
        PoseFileError: no ``poses``, a ``poses`` width that is not 3 x 24, 52 or 55, a ``trans``
            of another length, or no frame rate under either key.

    Shape:
        ``poses`` ``(T, 3 J)`` -> ``rotations`` ``(T, J, 4)``; ``trans`` ``(T, 3)`` -> ``root_positions``.

    Example:
        >>> import tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "walk.npz")
        >>> np.savez(path, poses=np.zeros((2, 156)), trans=np.zeros((2, 3)), mocap_frame_rate=120.0)
        >>> m = read_amass(path)
        >>> m.rotations.shape, m.frame_time
        (torch.Size([2, 52, 4]), 0.008333333333333333)
    """
    path_text = os.fspath(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise PoseFileError(path_text, f"not a NumPy .npz archive ({err})") from None
    with data:
        if not hasattr(data, "files") or "poses" not in data.files:
            raise PoseFileError(path_text, "an AMASS file needs an array 'poses' (T, 3 J) of axis-angle triples")
        poses = _float_array(path_text, data, "poses", "(T, 3 J)", 2)
        frames, width = poses.shape
        if width % 3:
            raise PoseFileError(path_text, f"array 'poses' has {width} columns, not a multiple of 3: each joint "
                                "is an axis-angle triple")
        try:
            names, parents = smpl_skeleton(width // 3)
        except ValueError:
            raise PoseFileError(path_text, f"array 'poses' holds {width // 3} joints (width {width}): expected 24 "
                                "(SMPL), 52 (SMPL-H) or 55 (SMPL-X)") from None
        if "trans" in data.files:
            trans = _float_array(path_text, data, "trans", f"({frames}, 3)", 2)
            if trans.shape != (frames, 3):
                raise PoseFileError(path_text, f"array 'trans' has shape {trans.shape}; {frames} frames of poses "
                                    f"need ({frames}, 3)")
        else:
            trans = np.zeros((frames, 3))
        key = next((k for k in FRAME_RATE_KEYS if k in data.files), None)
        if key is None:
            raise PoseFileError(path_text, "no frame rate: expected 'mocap_framerate' (SMPL-H) or "
                                "'mocap_frame_rate' (SMPL-X)")
        rate = float(np.asarray(data[key]).reshape(-1)[0])
        if not rate > 0:
            raise PoseFileError(path_text, f"{key} = {rate}: a frame rate must be positive")
        extras = {}
        for name in data.files:
            if name not in ("poses", "trans", key):
                try:
                    extras[name] = data[name]
                except ValueError:  # (a pickled object array: skipped rather than unpickled)
                    continue
    rotations = _tq.axis_angle_to_quat(torch.from_numpy(poses.reshape(frames, -1, 3)))
    skeleton = Skeleton(names, parents, torch.zeros(len(names), 3, dtype=torch.float64))
    return Motion(skeleton, rotations, "quat", torch.from_numpy(trans.copy()), 1.0 / rate, extras=extras)
