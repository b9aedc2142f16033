"""BOP ``scene_gt.json``: object poses per image, read and written.

The file maps each image id (a JSON key) to a list of objects, each with ``obj_id``,
``cam_R_m2c`` (9 numbers, the row-major rotation) and ``cam_t_m2c`` (millimetres): the transform
from the object's model frame to the camera, OpenCV camera axes. One pose per (image, object),
in the file's order; other keys of an object are ignored, a missing one is named.
"""

import json
from typing import BinaryIO, Iterator

import numpy as np
import torch

from .cameras import FORMAT_MAPS
from .checks import Report, check_matrices
from .nerf import load_json
from .poses import PoseFileError, Poses
from .textwrite import positions_of

__all__ = ["read_bop", "BopWriter", "REQUIRED"]

REQUIRED = ("obj_id", "cam_R_m2c", "cam_t_m2c")


def _entry(path, image: str, index: int, entry) -> tuple:
    """(obj_id, 9 rotation numbers, 3 translation numbers) of one object, or an error naming it."""
    where = f"image {image}, object {index}"
    if not isinstance(entry, dict):
        raise PoseFileError(path, f"{where}: expected an object with {', '.join(REQUIRED)}, got "
                            f"{type(entry).__name__}")
    missing = [k for k in REQUIRED if k not in entry]
    if missing:
        raise PoseFileError(path, f"{where}: missing {', '.join(missing)} (a BOP pose needs {', '.join(REQUIRED)})")
    obj = entry["obj_id"]
    if not isinstance(obj, int) or isinstance(obj, bool):
        raise PoseFileError(path, f"{where}: obj_id must be an integer, got {obj!r}")
    numbers = []
    for key, count in (("cam_R_m2c", 9), ("cam_t_m2c", 3)):
        value = entry[key]
        try:
            array = np.array(value, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            array = None
        if array is None or array.size != count or not np.isfinite(array).all():
            raise PoseFileError(path, f"{where}: {key} must be {count} finite numbers, got {json.dumps(value)[:80]}")
        numbers.append(array)
    return obj, numbers[0], numbers[1]


def read_bop(path, stream: BinaryIO, chunk_lines: int, report: Report, **_) -> Iterator[Poses]:
    """Yield the object poses of a BOP ``scene_gt.json`` in chunks of ``chunk_lines``.

    Args:
        path: the file.
        stream: it, open in binary mode.
        chunk_lines: poses per chunk.
        report: counts rotations projected onto the nearest rotation.

    Returns:
        :class:`Poses` in ``"matrix"``, ``positions`` ``cam_t_m2c`` in millimetres, ``meta``
        ``image_id`` and ``obj_id`` (int64), ``maps`` model -> camera (OpenCV, mm).
    """
    data = load_json(path, stream)
    if not isinstance(data, dict):
        raise PoseFileError(path, f"a scene_gt.json is an object of image ids, got {type(data).__name__}")
    images, objects, rotations, translations, where = [], [], [], [], []
    for image, entries in data.items():
        try:
            image_id = int(image)
        except ValueError:
            raise PoseFileError(path, f"image key {image!r} is not an integer image id") from None
        if not isinstance(entries, list):
            raise PoseFileError(path, f"image {image}: expected a list of objects, got {type(entries).__name__}")
        for index, entry in enumerate(entries):
            obj, R, t = _entry(path, image, index, entry)
            images.append(image_id)
            objects.append(obj)
            rotations.append(R)
            translations.append(t)
            where.append(f"image {image}, object {index}")
    R = np.array(rotations, dtype=np.float64).reshape(-1, 3, 3)
    try:
        R, _ = check_matrices(path, R, np.arange(len(R)), report)
    except PoseFileError as err:
        raise PoseFileError(path, f"{where[err.line]}: cam_R_m2c {err.problem}") from None
    t = np.array(translations, dtype=np.float64).reshape(-1, 3)
    ids, objs = np.array(images, dtype=np.int64), np.array(objects, dtype=np.int64)
    for start in range(0, len(R), chunk_lines):
        cut = slice(start, start + chunk_lines)
        yield Poses(torch.from_numpy(R[cut]), "matrix", positions=torch.from_numpy(t[cut]),
                    meta={"image_id": ids[cut], "obj_id": objs[cut]}, maps=FORMAT_MAPS["bop"])


class BopWriter:
    """Writes a ``scene_gt.json``: one line per image, its objects in order.

    Poses of one image must come one after another (as read); ids missing from ``meta`` become
    the pose's index (``image_id``) and 1 (``obj_id``), with a note.
    """

    def __init__(self, stream: BinaryIO, report: Report, dtype=np.float64, path="scene_gt.json"):
        self.stream, self.report, self.dtype, self.rows = stream, report, dtype, 0
        self.current, self.entries, self.seen = None, [], set()
        self.stream.write(b"{")

    def _ids(self, poses: Poses):
        meta = poses.meta or {}
        n = len(poses)
        if "image_id" in meta:
            images = np.asarray(meta["image_id"], dtype=np.int64)
        else:
            self.report.note("BOP output: image_id is the pose's 0-based index")
            images = np.arange(self.rows, self.rows + n)
        if "obj_id" in meta:
            objects = np.asarray(meta["obj_id"], dtype=np.int64)
        else:
            self.report.note("BOP output: obj_id 1 for every pose")
            objects = np.ones(n, dtype=np.int64)
        return images.tolist(), objects.tolist()

    def _flush(self) -> None:
        if self.current is None:
            return
        self.stream.write(f'{"," if self.seen else ""}\n  "{self.current}": [{", ".join(self.entries)}]'
                          .encode("utf-8"))
        self.seen.add(self.current)
        self.current, self.entries = None, []

    def write(self, poses: Poses) -> None:
        if not len(poses):
            return
        images, objects = self._ids(poses)
        R = poses.to("matrix").rotations.numpy().astype(self.dtype).reshape(len(poses), 9).tolist()
        t = positions_of(poses, self.dtype, self.report).tolist()
        for image, obj, r, x in zip(images, objects, R, t):
            if image != self.current:
                self._flush()
                if image in self.seen:
                    raise ValueError(f"BOP output: the poses of image {image} are not one after another "
                                     "(scene_gt.json lists each image once)")
                self.current = image
            self.entries.append(json.dumps({"cam_R_m2c": r, "cam_t_m2c": x, "obj_id": obj}))
        self.rows += len(poses)

    def close(self) -> None:
        self._flush()
        self.stream.write(b"\n}\n")
