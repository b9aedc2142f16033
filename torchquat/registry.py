"""The representation registry and :func:`convert`, the one entry point over all of them.

Each representation names its trailing shape and how it reaches its *hub*: the quaternion for
quaternion-like ones (Euler angles and axis-angle have closed forms there) and the matrix for
matrix-like ones (6D, 9D). ``convert``, ``torchquat.nn`` and the command line all read this
table instead of keeping if/elif chains of their own. Where a pair crosses the hubs and has a
kernel of its own (Euler angles and axis-angle to and from the matrix), ``convert`` takes that
kernel (``_TO_MATRIX``, ``_FROM_MATRIX``).
"""

import math
from typing import Callable, Dict, NamedTuple, Optional, Tuple

from torch import Tensor

from . import _euler_formulas as E
from . import _formulas as F
from ._dispatch import run
from ._validation import prepare, restore, tensor_or_as_is
from .conventions import check_degrees, gimbal_eps, gimbal_threshold, parse_convention
from .errors import ConventionError, ShapeError
from .rot6d import project, rot6d_noise

__all__ = ["Representation", "REPRESENTATIONS", "convert", "parse_representation", "parse_conversion"]


class Options(NamedTuple):
    convention: Optional[object]  # a parsed EulerConvention, for "euler" only
    degrees: bool
    eps: Optional[float]


class Representation(NamedTuple):
    """One rotation representation: its name, shape and the way to and from its hub."""

    name: str
    shape: Tuple[int, ...]  # trailing shape of a tensor in this representation
    hub: str  # "quat" or "matrix"
    to_hub: Callable[[Tensor, Options], Tensor]
    from_hub: Callable[[Tensor, Options], Tensor]
    doc: str

    @property
    def size(self) -> int:
        """How many numbers one rotation takes (the output size of a network head)."""
        return math.prod(self.shape)


def _options(o: Options, x: Tensor) -> dict:
    eps = gimbal_eps(x.dtype) if o.eps is None else float(o.eps)
    return {"name": o.convention.name, "degrees": o.degrees, "lock_sine": math.sin(eps)}


def _euler_options(o: Options) -> dict:
    return {"name": o.convention.name, "degrees": o.degrees}


def _identity(x: Tensor, _opts: Options) -> Tensor:
    return x


def _flattened(R: Tensor, _opts: Options) -> Tensor:
    return R.flatten(-2)


def _matrix_to_rot6d(R: Tensor, _opts: Options) -> Tensor:
    return R.mT.flatten(-2)[..., :6]


REPRESENTATIONS: Dict[str, Representation] = {r.name: r for r in (
    Representation("quat", (4,), "quat", _identity, _identity,
                   "quaternion (w, x, y, z), returned with w >= 0"),
    Representation("quat_xyzw", (4,), "quat", lambda x, o: x.roll(1, dims=-1), lambda q, o: q.roll(-1, dims=-1),
                   "quaternion (x, y, z, w), scalar last (SciPy, ROS), returned with w >= 0"),
    Representation("matrix", (3, 3), "matrix", _identity, _identity, "3x3 rotation matrix"),
    Representation("euler", (3,), "quat", lambda x, o: run(E.euler_to_quat, (x,), (4,), **_euler_options(o)),
                   lambda q, o: run(E.quat_to_euler, (q,), (3,), **_options(o, q)),
                   "Euler angles; needs convention= (or 'euler:ZYX')"),
    Representation("axis_angle", (3,), "quat", lambda x, o: run(F.axis_angle_to_quat, (x,), (4,)),
                   lambda q, o: run(F.quat_to_axis_angle, (q,), (3,)), "rotation vector, angle in [0, pi]"),
    Representation("rot6d", (6,), "matrix", lambda x, o: run(F.rot6d_to_matrix, (x,), (3, 3), noise=rot6d_noise(x.dtype)),
                   _matrix_to_rot6d, "first two columns of R (Zhou et al. 2019)"),
    Representation("rot9d", (9,), "matrix", lambda x, o: project(x.unflatten(-1, (3, 3))),
                   _flattened, "any 3x3 matrix row-major, projected by SVD (Levinson et al. 2020)"),
)}

_HUB_TO_HUB = {("quat", "matrix"): lambda q: run(F.quat_to_matrix, (q,), (3, 3)),
               ("matrix", "quat"): lambda R: run(F.matrix_to_quat, (R,), (4,), 2)}
_QUATERNIONS = ("quat", "quat_xyzw")
# Representations on the quaternion's side with a formula of their own to and from the matrix, which
# convert takes in place of the way through both hubs (one formula, the named function's numbers)
_TO_MATRIX = {"euler": lambda x, o: run(E.euler_to_matrix, (x,), (3, 3), **_euler_options(o)),
              "axis_angle": lambda x, o: run(F.axis_angle_to_matrix, (x,), (3, 3))}
_FROM_MATRIX = {"euler": lambda R, o: run(E.matrix_to_euler, (R,), (3,), 2, **_options(o, R)),
                "axis_angle": lambda R, o: run(F.matrix_to_axis_angle, (R,), (3,), 2)}


def parse_conversion(src: str, dst: str, fn: str, convention=None, degrees: bool = False):
    """Both entries and conventions of a conversion (see :func:`parse_representation`), refusing
    ``convention=`` or ``degrees=True`` when neither side is Euler angles (the layers' and the
    dataset transform's check: an option they would silently ignore)."""
    src_rep, src_conv = parse_representation(src, fn, convention)
    dst_rep, dst_conv = parse_representation(dst, fn, convention)
    if src_conv is None and dst_conv is None and (convention is not None or degrees):
        given = f"convention={convention!r}" if convention is not None else f"degrees={degrees!r}"
        raise ValueError(f"{fn}: {given} only applies to Euler angles, but src={src!r} and dst={dst!r}")
    return src_rep, src_conv, dst_rep, dst_conv


def parse_representation(token: str, fn: str, convention=None):
    """Split ``"euler:ZYX"`` into the registry entry and the convention; check both."""
    if not isinstance(token, str):
        raise ValueError(f"{fn}: expected a representation name, got {token!r}")
    name, colon, inline = token.partition(":")
    rep = REPRESENTATIONS.get(name)
    if rep is None:
        raise ValueError(f"{fn}: unknown representation {token!r}: use one of {', '.join(sorted(REPRESENTATIONS))}")
    if colon and not inline:
        raise ConventionError(f"{fn}: {token!r} names no convention after ':', e.g. 'euler:ZYX'")
    if inline and name != "euler":
        raise ValueError(f"{fn}: only 'euler' takes a convention after ':', got {token!r}")
    if inline and convention is not None and inline != convention:
        raise ConventionError(f"{fn}: two conventions given, {inline!r} in the name and {convention!r} as keyword")
    convention = inline or convention
    if name == "euler":
        if convention is None:
            raise ConventionError(f"{fn}: 'euler' needs a convention, e.g. convention='ZYX' or 'euler:ZYX' "
                                  "(there is no default: say which one you mean)")
        return rep, parse_convention(convention, fn)
    return rep, None


def convert(x: Tensor, src: str, dst: str, *, convention: Optional[str] = None, degrees: bool = False,
            eps: Optional[float] = None) -> Tensor:
    """Convert rotations between any two representations.

    Tokens: ``"quat"``, ``"quat_xyzw"``, ``"matrix"``, ``"euler"`` (with ``convention=`` or as
    ``"euler:ZYX"``), ``"axis_angle"``, ``"rot6d"``, ``"rot9d"``. Quaternion outputs have
    ``w >= 0``; ``"rot9d"`` output is the matrix flattened row-major and ``"rot9d"`` input is
    read row-major (``(..., 3, 3)`` is accepted too) and projected onto a rotation.

    Args:
        x: rotations in representation ``src``.
        src: input representation token.
        dst: output representation token.
        convention: Euler convention when ``src`` or ``dst`` is ``"euler"`` (both use it).
        degrees: Euler angles in degrees.
        eps: gimbal-lock threshold for Euler output (see :func:`quat_to_euler`).

    Returns:
        The same rotations in representation ``dst``.

    Shape:
        ``(..., *src_shape)`` -> ``(..., *dst_shape)``.

    Example:
        >>> convert(torch.tensor([90., 0., 0.]), "euler:ZYX", "axis_angle", degrees=True)
        tensor([0.0000, 0.0000, 1.5708])
    """
    degrees = check_degrees("convert", degrees)
    src_rep, src_conv = parse_representation(src, "convert", convention)
    dst_rep, dst_conv = parse_representation(dst, "convert", convention)
    # Options no Euler angles use are ignored (generic code may pass them to every conversion),
    # but checked: a misspelt convention or an eps out of range is an error wherever it is given.
    if convention is not None and src_conv is None and dst_conv is None:
        parse_convention(convention, "convert")
    if eps is not None:
        eps = gimbal_threshold("convert", eps, None)  # (its dtype's default is not used)
    shape = src_rep.shape
    # (the last dimension first: comparing a symbolic batch size with 3 would guard it under export)
    if src_rep.name == "rot9d":
        x = tensor_or_as_is(x)  # (a list or NumPy 3 x 3 matrix, read before its shape decides)
    if src_rep.name == "rot9d" and isinstance(x, Tensor) and x.dim() >= 2 and x.shape[-1] == 3 and x.shape[-2] == 3:
        x = x.flatten(-2)
    try:
        x, dtype = prepare(x, "convert", "x", shape)
    except ShapeError as err:
        raise ShapeError(f"{err} (for src={src!r})") from None
    src_options, dst_options = Options(src_conv, degrees, eps), Options(dst_conv, degrees, eps)
    if src_rep.hub == "matrix" and dst_rep.name in _FROM_MATRIX:  # (matrix, 6D or 9D -> Euler or axis-angle)
        return restore(_FROM_MATRIX[dst_rep.name](src_rep.to_hub(x, src_options), dst_options), dtype)
    if dst_rep.hub == "matrix" and src_rep.name in _TO_MATRIX:
        return restore(dst_rep.from_hub(_TO_MATRIX[src_rep.name](x, src_options), dst_options), dtype)
    hub = src_rep.to_hub(x, src_options)
    if src_rep.hub != dst_rep.hub:
        hub = _HUB_TO_HUB[(src_rep.hub, dst_rep.hub)](hub)
    elif src_rep.name in _QUATERNIONS and dst_rep.name in _QUATERNIONS:
        # the one way to a quaternion that no conversion has made canonical: every conversion that
        # returns one (Euler angles, axis-angle, the matrix) gives w >= 0 itself
        hub = run(F.standardize, (hub,), (4,))
    out = dst_rep.from_hub(hub, dst_options)
    if hub is x and dst_rep.from_hub in (_identity, _flattened):
        out = out.clone()  # (matrix -> matrix or rot9d: x itself or a view of it; outputs are fresh)
    return restore(out, dtype)
