"""A :class:`Motion` as Parquet: one row per frame, the skeleton in the schema's metadata.

Columns: ``root_x, root_y, root_z``, then each joint's rotation columns named
``<joint name>:<column>`` with the plain CSV's column names (``Hips:qw``, ``Hips:r6_1``,
``Hips:ZXY_1_deg``, ...; :func:`~torchquat.io.plain.rotation_columns`), then, when joints other
than the root move, ``<joint name>:tx, :ty, :tz`` (``Motion.translations``). The schema's key-value
metadata holds, under ``torchquat.motion``, JSON with the representation, ``degrees``,
``frame_time``, the skeleton (``names``, ``parents``, ``offsets``, ``channels``, ``end_sites``)
and the source's other arrays (``extras``: dtype, shape and values). Reading the file back gives
the same :class:`Motion`; a Parquet without that key is a plain pose file.

pyarrow is imported on first use (``pip install 'torchquat[dask]'``).
"""

import json
from typing import Optional

import numpy as np
import torch

from .motion import Motion, Skeleton
from .parquet import ROW_GROUP_ROWS, pyarrow_modules
from .plain import rotation_columns
from .poses import PoseFileError
from .representations import SHAPES

__all__ = ["MOTION_KEY", "is_motion_parquet", "read_motion_parquet", "write_motion_parquet"]

MOTION_KEY = b"torchquat.motion"
ROOT_COLUMNS = ["root_x", "root_y", "root_z"]
_TRANSLATION = ["tx", "ty", "tz"]


def _columns(names, representation: str, degrees: bool, translations: bool) -> list:
    own = rotation_columns(representation, degrees)
    columns = ROOT_COLUMNS + [f"{name}:{c}" for name in names for c in own]
    return columns + ([f"{name}:{c}" for name in names for c in _TRANSLATION] if translations else [])


def _metadata(path) -> Optional[dict]:
    """The motion JSON of a Parquet file's schema, or None (not Parquet, no such key, no pyarrow)."""
    try:
        import pyarrow.parquet as parquet
    except ImportError:
        return None
    try:
        meta = parquet.read_schema(path).metadata or {}
        return json.loads(meta[MOTION_KEY]) if MOTION_KEY in meta else None
    except Exception:  # (not Parquet, damaged, not JSON: not a motion)
        return None


def is_motion_parquet(path) -> bool:
    """Whether ``path`` is a Parquet file whose schema metadata says it holds a :class:`Motion`."""
    return _metadata(path) is not None


def _extra(value: np.ndarray) -> dict:
    value = np.asarray(value)
    items = np.char.decode(value, "latin-1") if value.dtype.kind == "S" else value
    return {"dtype": value.dtype.str, "shape": list(value.shape), "values": items.reshape(-1).tolist()}


def _from_extra(spec: dict) -> np.ndarray:
    dtype = np.dtype(spec["dtype"])
    values = spec["values"]
    if dtype.kind == "S":
        values = [v.encode("latin-1") for v in values]
    return np.array(values, dtype=dtype).reshape(spec["shape"])


def write_motion_parquet(path, motion: Motion, dtype=np.float64) -> int:
    """Write ``motion`` (in its own representation) to a Parquet file, atomically.

    Args:
        path: the output file.
        motion: the :class:`Motion`.
        dtype: ``numpy.float64`` or ``numpy.float32`` values.

    Returns:
        The number of frames written.
    """
    from .files import atomic_output
    pyarrow, parquet = pyarrow_modules(path)
    s, frames = motion.skeleton, motion.num_frames
    try:
        columns = _columns(s.names, motion.representation, motion.degrees, motion.translations is not None)
    except KeyError:
        raise PoseFileError(path, f"no Parquet columns for the representation {motion.representation!r}") from None
    if len(set(columns)) != len(columns):
        raise PoseFileError(path, "joint names must be unique to name Parquet columns")
    parts = [motion.root_positions, motion.rotations.reshape(frames, -1)]
    if motion.translations is not None:
        parts.append(motion.translations.reshape(frames, -1))
    values = np.concatenate([p.detach().cpu().numpy().astype(dtype, copy=False) for p in parts], axis=1)
    meta = {"representation": motion.representation, "degrees": bool(motion.degrees),
            "frame_time": motion.frame_time, "translations": motion.translations is not None,
            "names": list(s.names), "parents": list(s.parents),
            "offsets": s.offsets.detach().cpu().double().tolist(), "channels": [list(c) for c in s.channels],
            "end_sites": [None if e is None else [float(v) for v in e] for e in s.end_sites],
            "extras": {k: _extra(v) for k, v in motion.extras.items()}}
    arrays = [pyarrow.array(np.ascontiguousarray(values[:, i])) for i in range(values.shape[1])]
    table = pyarrow.table(arrays, names=columns).replace_schema_metadata({MOTION_KEY: json.dumps(meta)})
    with atomic_output(path) as stream:
        parquet.write_table(table, stream, row_group_size=ROW_GROUP_ROWS)
    return frames


def read_motion_parquet(path) -> Motion:
    """Read a :class:`Motion` written by :func:`write_motion_parquet`.

    Raises:
        PoseFileError: not Parquet, no motion metadata, or columns that do not match it.
    """
    pyarrow, parquet = pyarrow_modules(path)
    try:
        table = parquet.read_table(path)
    except (pyarrow.ArrowException, OSError, ValueError) as err:
        raise PoseFileError(path, f"not a readable Parquet file ({err})") from None
    raw = (table.schema.metadata or {}).get(MOTION_KEY)
    if raw is None:
        raise PoseFileError(path, f"a Parquet file without {MOTION_KEY.decode()!r} metadata is poses, not a motion")
    try:
        meta = json.loads(raw)
        names, representation, degrees = meta["names"], meta["representation"], bool(meta["degrees"])
        shape = SHAPES[representation.partition(":")[0]]
        moving = bool(meta.get("translations", False))
        expected = _columns(names, representation, degrees, moving)
        if table.column_names != expected:
            raise ValueError(f"columns {table.column_names[:6]}... do not match the motion metadata "
                             f"(expected {expected[:6]}...)")
        values = np.stack([np.asarray(table.column(i).to_numpy()) for i in range(table.num_columns)], axis=1)
        if values.dtype.kind != "f":
            raise ValueError(f"values of type {values.dtype}, not floating point")
        frames, joints = table.num_rows, len(names)
        size = int(np.prod(shape)) * joints
        rotations = values[:, 3:3 + size].reshape(frames, joints, *shape)
        translations = values[:, 3 + size:].reshape(frames, joints, 3).copy() if moving else None
        skeleton = Skeleton(names, meta["parents"], torch.tensor(meta["offsets"], dtype=torch.float64).reshape(-1, 3),
                            [tuple(c) for c in meta["channels"]],
                            [None if e is None else tuple(e) for e in meta["end_sites"]])
        return Motion(skeleton, torch.from_numpy(np.ascontiguousarray(rotations)), representation,
                      torch.from_numpy(np.ascontiguousarray(values[:, :3])), float(meta["frame_time"]),
                      degrees=degrees,
                      translations=None if translations is None else torch.from_numpy(translations),
                      extras={k: _from_extra(v) for k, v in meta.get("extras", {}).items()})
    except (ValueError, KeyError, IndexError, TypeError) as err:
        raise PoseFileError(path, f"not a readable motion Parquet file: {err}") from None
