"""Rotation representation tokens as pose files name them: ``"quat"``, ``"euler:ZYX"``, ...

The tokens are :func:`torchquat.convert`'s (SPEC section 2). They are checked here, before any
file is opened, so that a misspelt ``--to`` fails at once with a message naming the caller.
"""

from typing import NamedTuple, Optional, Tuple

from .. import ConventionError

__all__ = ["SHAPES", "Token", "parse_token", "EULER_CONVENTIONS"]

# trailing shape of one rotation in each representation
SHAPES = {"quat": (4,), "quat_xyzw": (4,), "matrix": (3, 3), "euler": (3,), "axis_angle": (3,), "rot6d": (6,),
          "rot9d": (9,)}
# SciPy's rule: three axes, adjacent ones different; lower case extrinsic, upper case intrinsic
EULER_CONVENTIONS = frozenset(a + b + c for axes in ("xyz", "XYZ") for a in axes for b in axes for c in axes
                              if a != b and b != c)


class Token(NamedTuple):
    """A checked token: its representation name, Euler convention (or None) and trailing shape."""

    name: str
    convention: Optional[str]
    shape: Tuple[int, ...]


def parse_token(token: str, fn: str, convention: Optional[str] = None) -> Token:
    """Split ``"euler:ZYX"`` into name and convention and check both.

    Args:
        token: a representation token, e.g. ``"quat"`` or ``"euler:ZYX"``.
        fn: the caller's name, which starts every message.
        convention: an Euler convention given apart from the token.

    Returns:
        The :class:`Token`.

    Raises:
        ValueError: an unknown name, or a convention after a name other than ``euler``.
        ConventionError: a missing, malformed or conflicting Euler convention.
    """
    if not isinstance(token, str):
        raise ValueError(f"{fn}: expected a representation name, got {token!r}")
    name, colon, inline = token.partition(":")
    if name not in SHAPES:
        raise ValueError(f"{fn}: unknown representation {token!r}: use one of {', '.join(sorted(SHAPES))}")
    if colon and name != "euler":
        raise ValueError(f"{fn}: only 'euler' takes a convention after ':', got {token!r}")
    if name != "euler":
        return Token(name, None, SHAPES[name])
    if inline and convention is not None and inline != convention:
        raise ConventionError(f"{fn}: two conventions given, {inline!r} in the name and {convention!r} as keyword")
    chosen = inline if colon else convention
    if chosen is None:
        raise ConventionError(f"{fn}: 'euler' needs a convention, e.g. convention='ZYX' or 'euler:ZYX' "
                              "(there is no default: say which one you mean)")
    if chosen not in EULER_CONVENTIONS:
        raise ConventionError(f"{fn}: invalid convention {chosen!r}: use 3 letters all from 'xyz' (extrinsic) or "
                              "all from 'XYZ' (intrinsic), adjacent letters different, e.g. 'ZYX' or 'zxz'")
    return Token(name, chosen, SHAPES[name])
