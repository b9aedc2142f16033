"""Motion files in the conversion plumbing: detection, ``.npz``/``.npy`` of a :class:`Motion`, and
``torchquat convert`` for BVH and AMASS inputs and BVH outputs.

A motion ``.npz`` holds ``rotation`` ``(T, J, *k)`` in ``representation`` (``degrees`` for Euler),
``joint_names``, ``parents``, ``offsets`` ``(J, 3)``, ``channels`` (space-separated, one string a
joint), ``end_sites`` ``(J, 3)`` (NaN where none), ``root_position`` ``(T, 3)``, ``frame_time``,
``timestamp`` ``(T,)``, ``translations`` ``(T, J, 3)`` when joints other than the root move, and
the source's other arrays (AMASS ``betas``, ...) under their own names. A motion ``.parquet``
(one row per frame, the skeleton in the schema's metadata) is :mod:`torchquat.io.mocap_parquet`'s.
"""

import os
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from .mocap_parquet import is_motion_parquet, read_motion_parquet, write_motion_parquet
from .motion import Motion, Skeleton
from .poses import PoseFileError

__all__ = ["MOTION_FORMATS", "motion_format", "read_motion", "write_motion", "convert_motion",
           "is_motion_conversion"]

MOTION_FORMATS = ("bvh", "amass")
_OWN = ("rotation", "representation", "degrees", "joint_names", "parents", "offsets", "channels", "end_sites",
        "root_position", "frame_time", "timestamp", "translations")


def _npz_keys(path) -> Optional[set]:
    try:
        with np.load(path, allow_pickle=False) as data:
            return set(getattr(data, "files", ()))
    except (OSError, ValueError):
        return None


def motion_format(path, format: Optional[str] = None) -> Optional[str]:
    """``"bvh"``, ``"amass"`` or ``"motion"`` (a motion ``.npz`` or ``.parquet``) for a motion file, else None.

    Found from ``format`` (``bvh``, ``amass``; ``npz`` or ``parquet`` when the file is a motion's), the
    extension (``.bvh``) or the content: a file whose first word is ``HIERARCHY`` is BVH, an
    ``.npz`` with ``poses`` is AMASS, one with ``joint_names`` and ``parents`` a motion, and a
    Parquet file whose schema metadata has ``torchquat.motion`` a motion.

    Example:
        >>> motion_format("walk.bvh"), motion_format("walk.tum")
        ('bvh', None)
    """
    if format in MOTION_FORMATS or format == "motion":
        return format
    if format not in (None, "npz", "parquet"):
        return None
    suffix = Path(path).suffix.lower()
    if suffix == ".bvh":
        return "bvh"
    if suffix == ".parquet" or format == "parquet" or _is_parquet(path):
        return "motion" if is_motion_parquet(path) else None
    if suffix == ".npz" or format == "npz":
        keys = _npz_keys(path) if os.path.isfile(path) else None
        if keys and "poses" in keys:
            return "amass"
        if keys and {"joint_names", "parents", "rotation"} <= keys:
            return "motion"
        return None
    try:
        with open(path, "rb") as stream:
            head = stream.read(64)
    except OSError:
        return None
    return "bvh" if head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"HIERARCHY") else None


def _is_parquet(path) -> bool:
    try:
        with open(path, "rb") as stream:
            return stream.read(4) == b"PAR1"
    except OSError:
        return False


def _read_motion_file(path) -> Motion:
    return read_motion_parquet(path) if _is_parquet(path) else _read_motion_npz(path)


def _read_motion_npz(path) -> Motion:
    with np.load(path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    names = [str(n) for n in arrays["joint_names"]]
    joints = len(names)
    channels = [tuple(str(c).split()) for c in arrays.get("channels", [""] * joints)]
    sites = arrays.get("end_sites", np.full((joints, 3), np.nan))
    try:
        skeleton = Skeleton(names, arrays["parents"].tolist(), torch.from_numpy(
            arrays.get("offsets", np.zeros((joints, 3))).astype(np.float64)), channels,
            [None if np.isnan(s).any() else tuple(float(v) for v in s) for s in sites])
        rotation = torch.from_numpy(np.asarray(arrays["rotation"]))
        frames = rotation.shape[0]
        translations = arrays.get("translations")
        return Motion(skeleton, rotation, str(arrays.get("representation", "quat")),
                      torch.from_numpy(np.asarray(arrays.get("root_position", np.zeros((frames, 3))))),
                      float(arrays.get("frame_time", 1.0)), degrees=bool(arrays.get("degrees", False)),
                      translations=None if translations is None else torch.from_numpy(translations),
                      extras={k: v for k, v in arrays.items() if k not in _OWN})
    except (ValueError, KeyError, IndexError) as err:
        raise PoseFileError(path, f"not a readable motion archive: {err}") from None


def read_motion(path, format: Optional[str] = None) -> Motion:
    """Read any motion file: BVH, AMASS ``.npz`` or a motion ``.npz``/``.parquet`` written by torchquat.

    Args:
        path: the file.
        format: ``bvh`` or ``amass`` when extension and content do not tell.

    Returns:
        A :class:`Motion`.
    """
    from .amass import read_amass
    from .bvh import read_bvh
    found = motion_format(path, format)
    if found is None:
        raise PoseFileError(path, "not a motion file: expected BVH (.bvh, or a file starting with HIERARCHY), "
                            "an AMASS .npz (with 'poses'), a motion .npz (with 'joint_names' and 'parents') "
                            "or a motion .parquet (written by torchquat)")
    return {"bvh": read_bvh, "amass": read_amass, "motion": _read_motion_file}[found](path)


def _motion_arrays(motion: Motion, dtype) -> dict:
    s = motion.skeleton
    sites = np.array([site if site is not None else (np.nan,) * 3 for site in s.end_sites], dtype=np.float64)
    arrays = {k: v for k, v in motion.extras.items() if k not in _OWN}
    arrays.update(rotation=motion.rotations.detach().cpu().numpy().astype(dtype),
                  representation=np.array(motion.representation), degrees=np.array(motion.degrees),
                  joint_names=np.array(s.names), parents=np.array(s.parents, dtype=np.int64),
                  offsets=s.offsets.detach().cpu().numpy().astype(dtype),
                  channels=np.array([" ".join(c) for c in s.channels]), end_sites=sites.reshape(len(s), 3),
                  root_position=motion.root_positions.detach().cpu().numpy().astype(dtype),
                  frame_time=np.array(motion.frame_time),
                  timestamp=np.arange(motion.num_frames) * motion.frame_time)
    if motion.translations is not None:
        arrays["translations"] = motion.translations.detach().cpu().numpy().astype(dtype)
    return arrays


def write_motion(path, motion: Motion, representation: Optional[str] = None, degrees: bool = False,
                 order: Optional[str] = None, dtype=np.float64) -> int:
    """Write a motion to ``.bvh``, ``.npz`` (everything, see the module), ``.parquet`` (everything, one row
    per frame: :func:`~torchquat.io.mocap_parquet.write_motion_parquet`) or ``.npy`` (rotations alone).

    Args:
        path: the output file, written atomically; its extension picks the format.
        motion: the :class:`Motion`.
        representation: rotations in ``.npz``/``.parquet``/``.npy`` (default: the motion's own).
        degrees: Euler angles in degrees.
        order: BVH only: one rotation order for every joint (see :func:`write_bvh`).
        dtype: ``numpy.float64`` or ``numpy.float32`` values.

    Returns:
        The number of frames written.
    """
    from .files import atomic_output
    from .bvh_write import write_bvh
    suffix = Path(path).suffix.lower()
    if suffix == ".bvh":
        return write_bvh(path, motion, order=order, dtype=dtype)
    if suffix not in (".npz", ".npy", ".parquet"):
        raise PoseFileError(path, f"a motion is written as .bvh, .npz, .npy or .parquet, "
                            f"not {suffix or '(no extension)'!r}")
    if representation is not None:
        motion = motion.to(representation, degrees=degrees)
    if suffix == ".parquet":
        return write_motion_parquet(path, motion, dtype=dtype)
    with atomic_output(path) as stream:
        if suffix == ".npy":
            np.save(stream, motion.rotations.detach().cpu().numpy().astype(dtype))
        else:
            np.savez(stream, **_motion_arrays(motion, dtype))
    return motion.num_frames


def is_motion_conversion(src, dst, to: Optional[str] = None, from_format: Optional[str] = None) -> bool:
    """Whether ``torchquat convert SRC DST`` is a motion's (BVH or AMASS in, or BVH out)."""
    return (to == "bvh" or Path(dst).suffix.lower() == ".bvh"
            or (os.path.isfile(src) and motion_format(src, from_format) is not None))


def convert_motion(src, dst, to: Optional[str] = None, from_format: Optional[str] = None, degrees: bool = False,
                   dtype=np.float64, report=None) -> int:
    """Convert a motion file: BVH, AMASS or motion ``.npz``/``.parquet`` in; ``.npz``, ``.parquet``, ``.npy`` or
    BVH out.

    Args:
        src: the input file.
        dst: the output file (atomically written; untouched on any error).
        to: ``bvh``, or for ``.npz``/``.parquet``/``.npy`` a representation (``rot6d``, ``quat``,
            ``euler:ZXY``, ...; default ``quat``); ``(T, J, k)`` rotations with the joint names.
        from_format: ``bvh`` or ``amass`` when the input's extension and content do not tell.
        degrees: Euler angles in degrees.
        dtype: ``numpy.float64`` or ``numpy.float32`` values.
        report: a :class:`torchquat.io.Report` told what was assumed.

    Returns:
        The number of frames written.
    """
    if not os.path.isfile(src):
        raise PoseFileError(src, "no such file" if not os.path.exists(src) else "not a regular file")
    if os.path.exists(dst) and os.path.samefile(src, dst):
        raise PoseFileError(dst, "the output is the same file as the input: choose another output name")
    found = motion_format(src, from_format)
    if found is None:
        raise PoseFileError(src, "BVH output needs a motion: a BVH, AMASS or motion .npz input "
                            "(--from bvh|amass), not a pose file")
    suffix = Path(dst).suffix.lower()
    if to == "bvh" and suffix != ".bvh":
        raise PoseFileError(dst, "BVH output is written to a file named .bvh")
    representation = None if suffix == ".bvh" else (to or "quat")
    motion = read_motion(src, found)
    if report is not None:
        what = {".bvh": "BVH", ".parquet": f"parquet, one row per frame, rotations as {representation}"}.get(
            suffix, f"{suffix[1:]} with rotations (T, J, k) as {representation}")
        report.note(f"reading {src} as {found} ({motion.num_frames} frames, {len(motion.skeleton)} joints); "
                    f"writing {dst} as {what}" + (" in degrees" if degrees and "euler" in (to or "") else ""))
    try:
        return write_motion(dst, motion, representation, degrees, dtype=dtype)
    except ValueError as err:
        if isinstance(err, PoseFileError):
            raise
        raise PoseFileError(dst, str(err)) from None
