"""Dataset transforms: convert the rotation of each sample (``torch.utils.data`` friendly)."""

from typing import Any, Optional

from torch import Tensor

from .. import convert
from .representations import parse_token

__all__ = ["ConvertRotation"]


class ConvertRotation:
    """Convert a sample's rotation between representations; picklable, so it works in workers.

    A tensor sample is converted as a whole; for a dict (or any mapping) sample only ``key`` is
    converted and the other entries are passed through in a new dict.

    Args:
        src: source representation token (``"quat"``, ``"matrix"``, ``"euler:ZYX"``, ...).
        dst: target representation token.
        key: the entry of a dict sample holding the rotation.
        convention: Euler convention, if not given in the token.
        degrees: Euler angles in degrees.

    Example:
        >>> import torch
        >>> t = ConvertRotation("quat", "euler:ZYX", degrees=True)
        >>> sample = t({"rotation": torch.tensor([1.0, 0.0, 0.0, 1.0]) / 2 ** 0.5, "id": 3})
        >>> torch.allclose(sample["rotation"], torch.tensor([90.0, 0.0, 0.0]), atol=1e-4), sample["id"]
        (True, 3)
    """

    def __init__(self, src: str, dst: str, key: str = "rotation", convention: Optional[str] = None,
                 degrees: bool = False):
        _check_conversion(src, dst, convention, degrees)  # fail early, in the main process
        self.src, self.dst, self.key, self.convention, self.degrees = src, dst, key, convention, degrees

    def __call__(self, sample: Any) -> Any:
        if isinstance(sample, Tensor):
            return self._convert(sample)
        if hasattr(sample, "keys"):
            if self.key not in sample:
                raise KeyError(f"ConvertRotation: sample has no key {self.key!r} (keys: {list(sample.keys())})")
            out = dict(sample)
            out[self.key] = self._convert(sample[self.key])
            return out
        raise TypeError(f"ConvertRotation: expected a tensor or a dict sample, got {type(sample).__name__}")

    def _convert(self, x: Tensor) -> Tensor:
        return convert(x, self.src, self.dst, convention=self.convention, degrees=self.degrees)

    def __repr__(self) -> str:
        extra = f", convention={self.convention!r}" if self.convention else ""
        extra += ", degrees=True" if self.degrees else ""
        return f"ConvertRotation({self.src!r}, {self.dst!r}, key={self.key!r}{extra})"


def _check_conversion(src: str, dst: str, convention: Optional[str], degrees: bool) -> None:
    """Check both tokens, and refuse options neither side uses (they would be silently ignored)."""
    euler = [parse_token(token, "ConvertRotation", convention).convention for token in (src, dst)]
    if euler == [None, None] and (convention is not None or degrees):
        given = f"convention={convention!r}" if convention is not None else f"degrees={degrees!r}"
        raise ValueError(f"ConvertRotation: {given} only applies to Euler angles, but src={src!r} and dst={dst!r}")
