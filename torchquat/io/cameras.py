"""What a pose maps, and the two exact operations between camera conventions: inverse and axes.

A camera pose file stores one of two transforms, with one of two sets of camera axes:

========  ======================  ==================================================
format    a pose maps             camera axes
========  ======================  ==================================================
colmap    world -> camera         OpenCV: x right, y down, z forward
nerf      camera -> world         OpenGL: x right, y up, z backward
bop       model -> camera (mm)    OpenCV
tum ...   camera -> world         as the source's (TUM, KITTI, EuRoC, plain files)
========  ======================  ==================================================

A transform ``(R, t)`` maps a point ``x`` of its source frame to ``R x + t`` in its target
frame. The two camera axes differ by ``D = diag(1, -1, -1)``, a half turn about x, so changing
axes only negates and swaps numbers (exact in floating point). This module works on tensors;
:class:`~torchquat.io.Poses` wraps it as ``Poses.inverse()`` and ``Poses.to_camera_axes()``.
"""

from typing import NamedTuple, Optional, Tuple

import numpy as np
import torch
from torch import Tensor

from .. import convert, quat_rotate

__all__ = ["PoseMap", "AXES", "FORMAT_MAPS", "WORLD_POSE", "ID_FIELDS", "invert_transform", "change_camera_axes",
           "to_convention", "in_convention", "IdColumns", "CAMERA_FORMATS", "camera_format_of",
           "camera_extension_problem"]

AXES = {"opencv": "x right, y down, z forward", "opengl": "x right, y up, z backward"}


class PoseMap(NamedTuple):
    """What a batch of poses maps: ``source`` frame to ``target`` frame, and the camera's axes.

    Attributes:
        source: the frame whose points the transform takes (``"world"``, ``"camera"``, ``"model"``).
        target: the frame it takes them to.
        camera_axes: ``"opencv"``, ``"opengl"`` or None (not stated by the source).
        translation_unit: ``"mm"`` for BOP, None where the file's own unit (COLMAP's is arbitrary).

    Example:
        >>> print(PoseMap("world", "camera", "opencv"))
        world -> camera, OpenCV camera axes (x right, y down, z forward)
    """

    source: str
    target: str
    camera_axes: Optional[str] = None
    translation_unit: Optional[str] = None

    def __str__(self) -> str:
        axes = "camera axes not stated" if self.camera_axes is None else \
            f"{'OpenCV' if self.camera_axes == 'opencv' else 'OpenGL'} camera axes ({AXES[self.camera_axes]})"
        unit = f", translations in {self.translation_unit}" if self.translation_unit else ""
        return f"{self.source} -> {self.target}, {axes}{unit}"

    def inverse(self) -> "PoseMap":
        """The map the other way round."""
        return self._replace(source=self.target, target=self.source)


FORMAT_MAPS = {"colmap": PoseMap("world", "camera", "opencv"), "nerf": PoseMap("camera", "world", "opengl"),
               "bop": PoseMap("model", "camera", "opencv", "mm")}
CAMERA_FORMATS = tuple(FORMAT_MAPS)
_EXTENSIONS = {"colmap": (".txt", ".bin"), "nerf": (".json",), "bop": (".json",)}
WORLD_POSE = PoseMap("camera", "world")  # TUM, KITTI, EuRoC and plain files: the camera's pose in the world


def camera_format_of(path, sniff: bool = False) -> Optional[str]:
    """The camera format a file's name gives (``images.txt``/``.bin``: colmap, ``transforms*.json``:
    nerf, ``scene_gt*.json``: bop), or with ``sniff`` that of another ``.json``'s content
    (``frames``: nerf, image-id keys: bop); else None.

    Example:
        >>> camera_format_of("sparse/0/images.bin"), camera_format_of("transforms_train.json")
        ('colmap', 'nerf')
    """
    import os
    name = os.path.basename(os.fspath(path)).lower()
    if name in ("images.txt", "images.bin"):
        return "colmap"
    if name.endswith(".json"):
        if name.startswith("transforms"):
            return "nerf"
        if name.startswith("scene_gt") and "info" not in name:
            return "bop"
        if sniff and os.path.isfile(path):
            import json
            try:
                with open(path, "rb") as stream:
                    data = json.load(stream)
            except (OSError, ValueError):
                return None
            if isinstance(data, dict) and "frames" in data:
                return "nerf"
            if isinstance(data, dict) and data and all(k.isdigit() for k in data):
                return "bop"
    return None


def camera_extension_problem(path, format: str) -> Optional[str]:
    """Why a camera format should not be written under ``path``'s extension, or None."""
    import os
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if suffix in _EXTENSIONS[format]:
        return None
    return f"{format} output is written to a {' or '.join(_EXTENSIONS[format])} file, got {suffix or 'no extension'}"


def _as_matrix(rotations: Tensor, representation: str) -> Tensor:
    return rotations if representation == "matrix" else convert(rotations, representation, "matrix")


def invert_transform(rotations: Tensor, representation: str,
                     translations: Optional[Tensor]) -> Tuple[Tensor, Optional[Tensor]]:
    """The inverse transforms ``(R^T, -R^T t)``.

    The rotation is inverted exactly (a conjugate or a transpose) for ``quat``, ``quat_xyzw`` and
    ``matrix``; other representations go through matrices. The translation carries one rounding.

    Args:
        rotations: ``(n, ...)`` rotations in ``representation``.
        representation: a :func:`torchquat.convert` token.
        translations: ``(n, 3)`` or None (then None is returned for it).

    Returns:
        ``(rotations, translations)`` of the inverses, in the same representation.

    Example:
        >>> q = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)  # half turn about z
        >>> invert_transform(q, "quat", torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64))
        (tensor([[ 0., -0., -0., -1.]], dtype=torch.float64), tensor([[ 1.,  2., -3.]], dtype=torch.float64))
    """
    if representation == "quat":
        inverse = rotations * rotations.new_tensor([1.0, -1.0, -1.0, -1.0])
    elif representation == "quat_xyzw":
        inverse = rotations * rotations.new_tensor([-1.0, -1.0, -1.0, 1.0])
    else:
        inverse = _as_matrix(rotations, representation).transpose(-1, -2)
    if translations is not None:
        if representation in ("quat", "quat_xyzw"):
            q = inverse if representation == "quat" else inverse[:, [3, 0, 1, 2]]
            translations = -quat_rotate(q, translations)
        else:
            translations = -(inverse @ translations.unsqueeze(-1)).squeeze(-1)
    if representation not in ("quat", "quat_xyzw", "matrix"):
        inverse = convert(inverse, "matrix", representation)
    return inverse, translations


# p = (0, 1, 0, 0), the half turn D about x; left and right products by +p or -p as index moves and
# signs, so that OpenCV -> OpenGL (by p) and back (by -p = p^-1) return the very same numbers.
_QUAT_MOVES = {  # (camera is the target, towards OpenGL) -> (order of w, x, y, z, signs)
    (True, True): ([1, 0, 3, 2], [-1.0, 1.0, -1.0, 1.0]),    # p q
    (True, False): ([1, 0, 3, 2], [1.0, -1.0, 1.0, -1.0]),   # -p q
    (False, True): ([1, 0, 3, 2], [-1.0, 1.0, 1.0, -1.0]),   # q p
    (False, False): ([1, 0, 3, 2], [1.0, -1.0, -1.0, 1.0]),  # q (-p)
}


def change_camera_axes(rotations: Tensor, representation: str, translations: Optional[Tensor],
                       camera_is_target: bool, to_opengl: bool) -> Tuple[Tensor, Optional[Tensor]]:
    """Turn OpenCV camera axes into OpenGL ones or back: ``D = diag(1, -1, -1)`` on the camera side.

    Camera as target (world -> camera): ``R' = D R``, ``t' = D t``. Camera as source
    (camera -> world): ``R' = R D``, ``t' = t``. Exact: only signs and places change, and the
    way back undoes them bit for bit (quaternions ``q p`` then ``q p (-p)``) for ``quat``,
    ``quat_xyzw`` and ``matrix``; other representations go through matrices.

    Args:
        rotations: ``(n, ...)`` rotations in ``representation``.
        representation: a :func:`torchquat.convert` token.
        translations: ``(n, 3)`` or None.
        camera_is_target: the pose maps into the camera frame (COLMAP, BOP) rather than out of it.
        to_opengl: towards OpenGL axes (else towards OpenCV).

    Returns:
        ``(rotations, translations)`` with the other camera axes.

    Example:
        >>> R = torch.eye(3, dtype=torch.float64)[None]
        >>> change_camera_axes(R, "matrix", None, camera_is_target=False, to_opengl=True)[0]
        tensor([[[ 1., -0., -0.],
                 [ 0., -1., -0.],
                 [ 0., -0., -1.]]], dtype=torch.float64)
    """
    if representation in ("quat", "quat_xyzw"):
        order, signs = _QUAT_MOVES[(camera_is_target, to_opengl)]
        q = rotations if representation == "quat" else rotations[:, [3, 0, 1, 2]]
        q = q[:, order] * q.new_tensor(signs)
        turned = q if representation == "quat" else q[:, [1, 2, 3, 0]]
    else:
        R = _as_matrix(rotations, representation)
        flip = R.new_tensor([1.0, -1.0, -1.0])
        turned = R * flip[:, None] if camera_is_target else R * flip
        if representation != "matrix":
            turned = convert(turned, "matrix", representation)
    if translations is not None and camera_is_target:
        translations = translations * translations.new_tensor([1.0, -1.0, -1.0])
    return turned, translations


ID_FIELDS = ("image_id", "camera_id", "name", "file_path", "obj_id")  # kept as columns of plain outputs
_SHORT = {"world": "w", "camera": "c", "model": "m", "body": "b"}


def _camera_first(maps: PoseMap) -> bool:
    """The pose maps out of the camera (or body) frame, rather than into it."""
    return maps.source in ("camera", "body")


def _formula(before: PoseMap, after: PoseMap, inverted: bool, turned: bool) -> str:
    """``c2w = inv(w2c) @ diag(1, -1, -1, 1)`` and the like, in the maps' own frame letters."""
    old = f"{_SHORT.get(before.source, before.source)}2{_SHORT.get(before.target, before.target)}"
    new = f"{_SHORT.get(after.source, after.source)}2{_SHORT.get(after.target, after.target)}"
    flip = "diag(1, -1, -1, 1)"
    if not inverted:
        return f"{new} = {flip} @ {old}" if not _camera_first(after) else f"{new} = {old} @ {flip}"
    if not turned:
        return f"{new} = inv({old})"
    return f"{new} = inv({old}) @ {flip}" if _camera_first(after) else f"{new} = {flip} @ inv({old})"


def to_convention(poses, format: str, report=None):
    """The poses in the convention of an output format (:data:`FORMAT_MAPS`, else :data:`WORLD_POSE`).

    Inverts the poses when they map the other way, turns the camera axes when both sides name
    them, and notes on ``report`` what was done; the world (or model) frame is never moved,
    recentred or rescaled, and translations keep their unit (BOP's are millimetres).
    Poses without ``maps`` (TUM, KITTI, EuRoC) are taken as the camera's pose in the world.

    Args:
        poses: a :class:`~torchquat.io.Poses`.
        format: the output format's name (``colmap``, ``nerf``, ``bop``, ``tum``, ``csv`` ...).
        report: a :class:`~torchquat.io.Report` for the notes, or None.

    Returns:
        The converted :class:`~torchquat.io.Poses` (the same object when nothing changes).

    Example:
        >>> from torchquat.io import Poses
        >>> w2c = Poses(torch.tensor([[1.0, 0.0, 0.0, 0.0]]), "quat", positions=torch.tensor([[0.0, 0.0, 2.0]]),
        ...             maps=FORMAT_MAPS["colmap"])
        >>> c2w = to_convention(w2c, "nerf")
        >>> c2w.rotations + 0.0, c2w.positions + 0.0  # (a half turn about x; + 0.0 shows -0.0 as 0.0)
        (tensor([[0., 1., 0., 0.]]), tensor([[ 0.,  0., -2.]]))
        >>> print(c2w.maps)
        camera -> world, OpenGL camera axes (x right, y up, z backward)
    """
    want = FORMAT_MAPS.get(format, WORLD_POSE)
    note = (lambda text: None) if report is None else report.note
    have = poses.maps
    if have is None:
        if want == WORLD_POSE:
            return poses
        note(f"the input's poses are taken as the camera's pose in the world (camera -> world), with "
             f"{format}'s camera axes")
        have = PoseMap("camera", "world", want.camera_axes)
        poses = _with_maps(poses, have)
    inverted = _camera_first(have) != _camera_first(want)
    if inverted:
        poses = poses.inverse()
    turned = want.camera_axes is not None and poses.maps.camera_axes not in (None, want.camera_axes)
    if turned:
        poses = poses.to_camera_axes(want.camera_axes)
    if inverted or turned:
        note(f"{format} output: poses changed from {have} to {poses.maps}: "
             f"{_formula(have, poses.maps, inverted, turned)}; the world frame is kept as it is "
             "(not moved, recentred or rescaled)")
    other = {poses.maps.source, poses.maps.target} - {"camera", "body"}
    wanted = {want.source, want.target} - {"camera"}
    if other != wanted:
        note(f"{format} output: the {'/'.join(sorted(other))} frame stands for {format}'s "
             f"{'/'.join(sorted(wanted))} frame")
    if have.translation_unit != want.translation_unit:
        unit = have.translation_unit or "the input's unit"
        note(f"{format} output: translations are written in {unit}, not rescaled"
             + (" (BOP's cam_t_m2c is in millimetres)" if format == "bop" else ""))
    return poses


def _with_maps(poses, maps: PoseMap):
    from dataclasses import replace
    return replace(poses, maps=maps)


def in_convention(chunks, format: str, report=None):
    """:func:`to_convention` over a stream of :class:`~torchquat.io.Poses` chunks."""
    for chunk in chunks:
        yield to_convention(chunk, format, report)


class IdColumns:
    """Wraps a plain writer (CSV, NPZ) so that the poses' identifiers (:data:`ID_FIELDS` found in
    ``meta``) are kept: leading CSV columns, or arrays of an ``.npz`` under their own names.

    Args:
        writer: a ``CsvWriter`` or ``NpzWriter`` (any writer with ``stream``, ``write``, ``close``).
        kind: ``"csv"`` or ``"npz"``.
    """

    def __init__(self, writer, kind: str):
        self.writer, self.kind, self.columns, self.kept = writer, kind, None, {}
        self.stream = writer.stream

    def write(self, poses) -> None:
        if self.columns is None:
            self.columns = [k for k in ID_FIELDS if k in (poses.meta or {})]
        if not self.columns:
            return self.writer.write(poses)
        if self.kind == "npz":
            for k in self.columns:
                self.kept.setdefault(k, []).append(np.asarray(poses.meta[k]))
            return self.writer.write(poses)
        import csv
        import io
        self.writer.stream = io.BytesIO()
        self.writer.write(poses)
        lines = self.writer.stream.getvalue().splitlines(keepends=True)
        self.writer.stream = self.stream
        text = io.StringIO()
        fields = csv.writer(text, lineterminator="\n")
        if len(lines) > len(poses):  # the header, written with the first chunk
            fields.writerow(self.columns)
            self.stream.write(text.getvalue().rstrip("\n").encode("utf-8") + b"," + lines.pop(0))
            text.seek(0)
            text.truncate()
        values = [poses.meta[k].tolist() for k in self.columns]
        for row in zip(*values):
            fields.writerow(row)
        prefixes = text.getvalue().splitlines()
        self.stream.write(b"".join(p.encode("utf-8") + b"," + line for p, line in zip(prefixes, lines)))

    def close(self) -> None:
        if self.kind != "npz" or not self.kept:
            return self.writer.close()
        import io
        self.writer.stream = io.BytesIO()
        self.writer.close()
        with np.load(io.BytesIO(self.writer.stream.getvalue()), allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        arrays.update({k: np.concatenate(v) for k, v in self.kept.items() if k not in arrays})
        np.savez(self.stream, **arrays)
