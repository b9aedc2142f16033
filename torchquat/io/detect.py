"""Which format a pose file is in, and which one an output will be written in.

Input: the extension, else the content (``.txt``: 8 numbers a line is TUM, 12 KITTI; ``.csv``:
EuRoC's header or 8+ numbers a line is EuRoC, named columns a plain CSV). Output: ``--to`` (or
``format=``), else the extension.
"""

import os
from pathlib import Path
from typing import BinaryIO, Optional, Tuple, Union

from .cameras import CAMERA_FORMATS, camera_extension_problem, camera_format_of
from .formats import euroc_header_problem
from .poses import PoseFileError
from .representations import parse_token
from .textparse import read_header

__all__ = ["FORMATS", "POSE_FORMATS", "PLAIN_TARGETS", "POSE_REPRESENTATIONS", "detect_format", "output_plan",
           "check_pose_extension", "skip_byte_order_mark"]

FORMATS = ("tum", "kitti", "euroc", "csv", "npz", "npy", "parquet", *CAMERA_FORMATS)
POSE_FORMATS = ("tum", "kitti", "euroc")
POSE_REPRESENTATIONS = {"tum": "quat_xyzw", "kitti": "matrix", "euroc": "quat",  # what each format stores
                        "colmap": "quat", "nerf": "matrix", "bop": "matrix"}
PLAIN_TARGETS = ("quat", "quat_xyzw", "matrix", "euler:SEQ", "axis_angle", "rot6d")
_BY_EXTENSION = {".tum": "tum", ".kitti": "kitti", ".npz": "npz", ".npy": "npy", ".parquet": "parquet"}
_SNIFFED = (".txt", ".csv")
_NAME_IT = "--from on the command line, format= in Python"  # (the messages serve both)
# The extensions each pose format may be written under; the others named here (and in
# _BY_EXTENSION) are another format's, and a file under one would be misread: text in an .npz.
_POSE_EXTENSIONS = {"tum": (".tum", ".txt"), "kitti": (".kitti", ".txt"), "euroc": (".csv",)}
_KNOWN_EXTENSIONS = (*_BY_EXTENSION, *_SNIFFED)
PathLike = Union[str, os.PathLike]


_BOM = b"\xef\xbb\xbf"


def skip_byte_order_mark(stream: BinaryIO) -> None:
    """Step over a UTF-8 byte order mark (spreadsheets write one before a CSV header)."""
    if stream.read(3) != _BOM:
        stream.seek(0)


def _first_lines(path: PathLike, limit: int = 50):
    with open(path, "rb") as stream:
        skip_byte_order_mark(stream)
        for _, line in zip(range(limit), stream):
            if line.strip():
                yield line.strip()


def detect_format(path: PathLike, format: Optional[str] = None) -> str:
    """The format of an input file: ``format`` if given, else from its extension and content.

    ``.txt`` is TUM with 8 numbers a line and KITTI with 12; ``.csv`` is EuRoC when its header
    names EuRoC's columns in EuRoC's order (``timestamp``, ``p_`` x y z, ``q_`` w x y z), or a line
    has 8+ numbers and no header; else a plain CSV with named columns.

    Args:
        path: the input file.
        format: one of ``tum, kitti, euroc, csv, npz, npy, parquet, colmap, nerf, bop`` to skip
            detection (``images.txt``, ``images.bin``, ``transforms*.json`` and ``scene_gt*.json``
            are known by name).

    Returns:
        The format name.
    """
    if format is not None:
        if format not in FORMATS:
            raise PoseFileError(path, f"unknown format {format!r}: use one of {', '.join(FORMATS)}")
        return format
    camera = camera_format_of(path, sniff=True)  # (images.txt, images.bin, transforms.json, scene_gt.json)
    if camera is not None:
        return camera
    suffix = Path(path).suffix.lower()
    if suffix in _BY_EXTENSION:
        return _BY_EXTENSION[suffix]
    if suffix not in _SNIFFED:
        raise PoseFileError(path, f"cannot tell the format from the extension {suffix or '(none)'!r}: name it "
                            f"({_NAME_IT}: {', '.join(FORMATS)})")
    found = _sniff_csv(path) if suffix == ".csv" else _sniff_txt(path)
    if found is None:
        raise PoseFileError(path, "the file holds no poses (empty, or comments only)")
    return found


def _sniff_csv(path: PathLike) -> Optional[str]:
    """``euroc`` for EuRoC's header (its column order, whatever its units) or 8+ numbers a line
    without a header, else ``csv``; None for a file without a header or data."""
    with open(path, "rb") as stream:
        skip_byte_order_mark(stream)
        header, _, _ = read_header(stream)
        data = next((line for _, line in zip(range(50), stream) if line.strip()
                     and not line.lstrip().startswith(b"#")), b"")
    if header:
        return "euroc" if euroc_header_problem(header) is None else "csv"
    if data:
        return "euroc" if _numbers(data.decode("utf-8", "replace").split(",")) >= 8 else "csv"
    return None


def _sniff_txt(path: PathLike) -> Optional[str]:
    """``tum`` for 8 numbers on the first data line, ``kitti`` for 12; None for no data line."""
    for line in _first_lines(path):
        text = line.decode("utf-8", "replace")
        if text.startswith("#"):
            continue
        count = _numbers(text.split())
        if count in (8, 12):
            return "tum" if count == 8 else "kitti"
        raise PoseFileError(path, f"a .txt pose file has 8 numbers a line (TUM) or 12 (KITTI); the first data "
                            f"line has {len(text.split())} fields: name the format ({_NAME_IT}"
                            f"{'; a COLMAP images.txt is colmap' if len(text.split()) >= 10 else ''})")
    return None


def _numbers(fields) -> int:
    try:
        return len([float(f) for f in fields])
    except ValueError:
        return -1


def output_plan(path: PathLike, to: Optional[str] = None, degrees: bool = False) -> Tuple[str, str]:
    """Decide the output format and the rotation representation it holds.

    Args:
        path: the output file; its extension decides when ``to`` is None.
        to: ``tum``, ``kitti``, ``euroc`` or, for ``.csv``/``.npz``/``.npy`` outputs, a rotation
            representation (``quat``, ``quat_xyzw``, ``matrix``, ``euler:SEQ``, ``axis_angle``, ``rot6d``).
        degrees: Euler angles in degrees.

    Returns:
        ``(format, representation)``.
    """
    suffix = Path(path).suffix.lower()
    if to in POSE_FORMATS:
        check_pose_extension(path, to)
        return to, POSE_REPRESENTATIONS[to]
    if to in CAMERA_FORMATS or to is None and camera_format_of(path) is not None:
        to = to or camera_format_of(path)
        problem = camera_extension_problem(path, to)
        if problem is not None:
            raise PoseFileError(path, problem)
        return to, POSE_REPRESENTATIONS[to]
    plain = {".csv": "csv", ".npz": "npz", ".npy": "npy", ".parquet": "parquet"}.get(suffix)
    if to is None:
        if suffix in (".tum", ".kitti"):
            return suffix[1:], "quat_xyzw" if suffix == ".tum" else "matrix"
        if plain is None:
            raise PoseFileError(path, f"cannot tell the output format from the extension {suffix or '(none)'!r}: "
                                "use .tum, .kitti, .csv, .npz, .npy or .parquet, or name a pose format "
                                "(--to or format=: tum, kitti, euroc)")
        return plain, "quat"
    try:
        token = parse_token(to, "output rotations")
    except ValueError as err:
        raise PoseFileError(path, f"{err}; pose formats: {', '.join(POSE_FORMATS)}") from None
    if token.name == "rot9d":
        to = "matrix"
    if plain is None:
        raise PoseFileError(path, f"rotations as {to} are written to a plain file: its name must end in .csv, "
                            ".npz, .npy or .parquet")
    return plain, to


_READ_BACK_AS = {".tum": "TUM", ".kitti": "KITTI", ".txt": "TUM or KITTI text", ".csv": "a CSV",
                 ".npz": "a NumPy archive", ".npy": "a NumPy array", ".parquet": "Parquet"}


def check_pose_extension(path: PathLike, format: str) -> None:
    """Refuse a pose format's text under another format's extension (TUM text named ``.npz``, say),
    which every reader, ours included, would take for that other format."""
    suffix = Path(path).suffix.lower()
    if suffix in _KNOWN_EXTENSIONS and suffix not in _POSE_EXTENSIONS[format]:
        raise PoseFileError(path, f"{format} output under the extension {suffix} would be read back as "
                            f"{_READ_BACK_AS[suffix]}: name it {' or '.join(_POSE_EXTENSIONS[format])}")
