"""Exceptions raised by torchquat for bad input (never ``assert``)."""

__all__ = ["ShapeError", "ConventionError"]


class ShapeError(ValueError):
    """A tensor argument has the wrong trailing shape, or batch shapes do not broadcast."""


class ConventionError(ValueError):
    """An Euler-angle convention string is not one of the 24 valid conventions."""
