"""NeRF ``transforms.json`` (instant-ngp, nerfstudio): ``frames[].transform_matrix``, read and written.

A pose is camera -> world with OpenGL camera axes (x right, y up, z backward), a 4 x 4 (or 3 x 4)
``transform_matrix`` per frame. Every other field is kept through a read and a write: the
top-level ones (intrinsics, ``aabb_scale``, ``applied_transform`` ...) in ``Poses.document``,
the per-frame ones (``file_path``, ``sharpness``, per-frame intrinsics ...) in ``Poses.meta``
under their own names. Numbers are written as Python writes floats (shortest text that reads
back to the same float64), so a file read and written back keeps every number.

The file is read whole (JSON has no lines to stream), and written frame by frame, one a line.
"""

import json
from typing import BinaryIO, Iterator, List

import numpy as np
import torch

from .cameras import FORMAT_MAPS
from .checks import Report, check_matrices
from .poses import PoseFileError, Poses
from .textwrite import positions_of

__all__ = ["read_nerf", "NerfWriter", "MISSING", "load_json", "meta_array"]

_RIGID_ROW_TOLERANCE = 1e-6  # the last row of a 4 x 4 must be (0, 0, 0, 1) to this


class _Missing:
    """A per-frame field that this frame does not have (others do): left out when written."""

    def __repr__(self) -> str:
        return "MISSING"


MISSING = _Missing()


def load_json(path, stream: BinaryIO):
    """The parsed JSON document; a syntax error becomes a :class:`PoseFileError` at its line."""
    try:
        return json.loads(stream.read().decode("utf-8"))
    except UnicodeDecodeError as err:
        raise PoseFileError(path, f"not UTF-8 text ({err})") from None
    except json.JSONDecodeError as err:
        raise PoseFileError(path, f"not valid JSON: {err.msg} (column {err.colno})", err.lineno) from None


def meta_array(values: list) -> np.ndarray:
    """One field's per-pose values as an array: str, int64 or float64 when all are, else objects.

    Example:
        >>> meta_array(["a", "b"]).dtype.kind, meta_array([1, 2]).dtype, meta_array([1, 2.5]).dtype
        ('U', dtype('int64'), dtype('O'))
    """
    kinds = {type(v) for v in values}
    if kinds == {str}:
        return np.array(values, dtype=str)
    if kinds == {int} and all(-2 ** 63 <= v < 2 ** 63 for v in values):
        return np.array(values, dtype=np.int64)
    if kinds == {float}:
        return np.array(values, dtype=np.float64)
    array = np.empty(len(values), dtype=object)
    array[:] = values
    return array


def _matrix(path, index: int, frame) -> np.ndarray:
    """A frame's transform as a 4 x 4 float64 array, or an error naming the frame."""
    where = f"frames[{index}]"
    if not isinstance(frame, dict):
        raise PoseFileError(path, f"{where} is a {type(frame).__name__}, expected an object with a transform_matrix")
    if "transform_matrix" not in frame:
        raise PoseFileError(path, f"{where} has no transform_matrix (fields: {', '.join(frame) or 'none'})")
    try:
        matrix = np.array(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        matrix = None
    if matrix is None or matrix.shape not in ((4, 4), (3, 4)) or not np.isfinite(matrix).all():
        got = "not a table of numbers" if matrix is None else \
            f"shape {matrix.shape}" if matrix.shape not in ((4, 4), (3, 4)) else "values that are not finite"
        raise PoseFileError(path, f"{where}: transform_matrix is neither a rigid 4x4 nor a rigid 3x4 transform "
                            f"(got {got})")
    if matrix.shape == (3, 4):
        return np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
    if np.abs(matrix[3] - [0.0, 0.0, 0.0, 1.0]).max() > _RIGID_ROW_TOLERANCE:
        raise PoseFileError(path, f"{where}: transform_matrix is neither a rigid 4x4 nor a rigid 3x4 transform "
                            f"(last row {matrix[3].tolist()}, expected [0, 0, 0, 1])")
    return matrix


def read_nerf(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield the frames of a ``transforms.json`` as :class:`Poses` chunks.

    Args:
        path: the file.
        stream: it, open in binary mode.
        chunk_lines: frames per chunk.
        report: counts rotations projected onto the nearest rotation.

    Returns:
        :class:`Poses` in ``"matrix"``, ``positions`` the camera centres, ``meta`` the per-frame
        fields, ``document`` the top-level ones, ``maps`` camera -> world (OpenGL).
    """
    data = load_json(path, stream)
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        got = f"fields {', '.join(data) or 'none'}" if isinstance(data, dict) else type(data).__name__
        raise PoseFileError(path, f"a transforms.json needs a top-level object with a list 'frames', got {got}")
    frames = data["frames"]
    document = {k: v for k, v in data.items() if k != "frames"}
    matrices = np.stack([_matrix(path, i, f) for i, f in enumerate(frames)]) if frames else np.zeros((0, 4, 4))
    try:
        R, _ = check_matrices(path, np.ascontiguousarray(matrices[:, :3, :3]), np.arange(len(frames)), report)
    except PoseFileError as err:
        raise PoseFileError(path, f"frames[{err.line}]: transform_matrix is neither a rigid 4x4 nor a rigid 3x4 "
                            f"transform: its rotation part {err.problem.partition('; ')[0]}") from None
    keys: List[str] = []
    for frame in frames:
        keys.extend(k for k in frame if k != "transform_matrix" and k not in keys)
    meta = {k: meta_array([f.get(k, MISSING) for f in frames]) for k in keys}
    translations = matrices[:, :3, 3].copy()
    for start in range(0, len(frames), chunk_lines):
        cut = slice(start, start + chunk_lines)
        yield Poses(torch.from_numpy(R[cut]), "matrix", positions=torch.from_numpy(translations[cut]),
                    meta={k: v[cut] for k, v in meta.items()}, maps=FORMAT_MAPS["nerf"], document=document)


def _plain(value):
    """A JSON-ready Python value (numpy scalars become Python numbers)."""
    return value.item() if isinstance(value, np.generic) else value


class NerfWriter:
    """Writes a ``transforms.json``: the document's fields, then ``frames``, one frame a line.

    Frames keep every ``meta`` field when the poses came from a ``transforms.json`` (they have
    a ``document``); otherwise ``file_path`` is COLMAP's ``name`` (or the pose's index) and
    ``colmap_im_id`` COLMAP's ``IMAGE_ID``, as nerfstudio writes them.
    """

    def __init__(self, stream: BinaryIO, report: Report, dtype=np.float64, path="transforms.json"):
        self.stream, self.report, self.dtype, self.rows = stream, report, dtype, 0
        self.started = False

    def _start(self, poses: Poses) -> None:
        document = poses.document
        if document is None:
            self.report.note("NeRF output: frames only (no intrinsics: COLMAP's cameras and BOP's scene_camera "
                             "are not read)")
        head = "".join(f"    {json.dumps(k)}: {json.dumps(_plain(v))},\n"
                       for k, v in (document or {}).items())
        self.stream.write(("{\n" + head + '    "frames": [\n').encode("utf-8"))

    def _fields(self, poses: Poses, row: int) -> List[dict]:
        meta = poses.meta or {}
        n = len(poses)
        if poses.document is not None:
            columns = dict(meta)
        elif "name" in meta or "file_path" in meta:
            if "file_path" not in meta:
                self.report.note("NeRF output: file_path is COLMAP's image name, unchanged (relative to COLMAP's "
                                 "image folder)")
            columns = {"file_path": meta.get("file_path", meta.get("name"))}
            if "image_id" in meta and "name" in meta:  # (nerfstudio's field for COLMAP's IMAGE_ID)
                columns["colmap_im_id"] = meta["image_id"]
        else:
            self.report.note("NeRF output: file_path is the pose's 0-based index")
            columns = {"file_path": np.array([str(i) for i in range(row, row + n)])}
        return [{k: _plain(v[i]) for k, v in columns.items() if v[i] is not MISSING} for i in range(n)]

    def write(self, poses: Poses) -> None:
        if not self.started:
            self._start(poses)
            self.started = True
        if not len(poses):
            return
        matrices = np.zeros((len(poses), 4, 4))
        matrices[:, :3, :3] = poses.to("matrix").rotations.numpy().astype(self.dtype)
        matrices[:, :3, 3] = positions_of(poses, self.dtype, self.report)
        matrices[:, 3, 3] = 1.0
        lines = []
        for frame, matrix in zip(self._fields(poses, self.rows), matrices.tolist()):
            frame = dict(frame)
            frame["transform_matrix"] = matrix
            lines.append("        " + json.dumps(frame))
        self.stream.write(((",\n" if self.rows else "") + ",\n".join(lines)).encode("utf-8"))
        self.rows += len(poses)

    def close(self) -> None:
        self.stream.write(b"\n    ]\n}\n")
