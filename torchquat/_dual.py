"""Forward-mode dual numbers: the gradient of one rotation's formula, from the formula itself.

A :class:`Dual` carries a value and its derivatives with respect to every input component. Run
through a formula of :mod:`torchquat._formulas` with the namespace :data:`DUALS`, it yields the
outputs and their Jacobian in Python floats, which a one-row call that records a graph hands to
autograd (:func:`torchquat._dispatch._one_row`). No derivative is written by hand: each rule below
is the textbook derivative of one elementary function.
"""

import math
from operator import add, sub

from ._backends import _float_sign, _float_where


class Dual:
    """``value + sum_i d[i] eps_i`` with ``eps_i eps_j = 0``."""

    __slots__ = ("v", "d")

    def __init__(self, v: float, d: tuple):
        self.v, self.d = v, d

    def _scaled(self, k):
        return tuple(k * x for x in self.d)

    def __add__(self, o):
        if type(o) is Dual:
            return Dual(self.v + o.v, tuple(map(add, self.d, o.d)))
        return Dual(self.v + o, self.d)

    __radd__ = __add__

    def __sub__(self, o):
        if type(o) is Dual:
            return Dual(self.v - o.v, tuple(map(sub, self.d, o.d)))
        return Dual(self.v - o, self.d)

    def __rsub__(self, o):
        return Dual(o - self.v, self._scaled(-1.0))

    def __neg__(self):
        return Dual(-self.v, self._scaled(-1.0))

    def __mul__(self, o):
        if type(o) is Dual:
            a, b = self.v, o.v
            return Dual(a * b, tuple(b * x + a * y for x, y in zip(self.d, o.d)))
        return Dual(self.v * o, self._scaled(o))

    __rmul__ = __mul__

    def __truediv__(self, o):
        if type(o) is Dual:
            q = self.v / o.v
            return Dual(q, tuple((x - q * y) / o.v for x, y in zip(self.d, o.d)))
        return Dual(self.v / o, self._scaled(1.0 / o))

    def __rtruediv__(self, o):
        q = o / self.v
        return Dual(q, self._scaled(-q / self.v))

    def __lt__(self, o):
        return self.v < (o.v if type(o) is Dual else o)

    def __le__(self, o):
        return self.v <= (o.v if type(o) is Dual else o)

    def __gt__(self, o):
        return self.v > (o.v if type(o) is Dual else o)

    def __ge__(self, o):
        return self.v >= (o.v if type(o) is Dual else o)


def _value(x):
    return x.v if type(x) is Dual else x


def _chain(x, value, derivative):
    """``f(x)`` with ``f(x.v) = value`` and ``f'(x.v) = derivative``."""
    return Dual(value, x._scaled(derivative)) if type(x) is Dual else value


class _Duals:
    """The namespace of :mod:`torchquat._backends` for :class:`Dual` (and plain floats)."""

    pi = math.pi
    where = staticmethod(_float_where)

    @staticmethod
    def sqrt(x):
        r = math.sqrt(_value(x))
        return _chain(x, r, 0.5 / r if r > 0 else math.inf)

    @staticmethod
    def sin(x):
        return _chain(x, math.sin(_value(x)), math.cos(_value(x)))

    @staticmethod
    def cos(x):
        return _chain(x, math.cos(_value(x)), -math.sin(_value(x)))

    @staticmethod
    def abs(x):
        return x if _value(x) >= 0 else -x

    @staticmethod
    def sign(x):
        return _float_sign(_value(x))

    @staticmethod
    def fmod(x, y: float):
        r = math.fmod(_value(x), y)
        return Dual(r, x.d) if type(x) is Dual else r

    @staticmethod
    def copysign(x, y):
        return x if (math.copysign(1.0, _value(x)) == math.copysign(1.0, _value(y))) else -x

    @staticmethod
    def atan2(y, x):
        yv, xv = _value(y), _value(x)
        r2 = xv * xv + yv * yv
        value = math.atan2(yv, xv)
        if type(y) is not Dual and type(x) is not Dual:
            return value
        dy = y.d if type(y) is Dual else None
        dx = x.d if type(x) is Dual else None
        n = len(dy if dy is not None else dx)
        dy = dy or (0.0,) * n
        dx = dx or (0.0,) * n
        return Dual(value, tuple((xv * a - yv * b) / r2 for a, b in zip(dy, dx)))


DUALS = _Duals()


def jacobian(formula, values, static):
    """The formula's outputs and Jacobian (a list of rows, one per output) at ``values``."""
    n = len(values)
    seeds = [Dual(v, tuple(1.0 if i == j else 0.0 for j in range(n))) for i, v in enumerate(values)]
    out = formula(DUALS, *seeds, **static)
    zero = (0.0,) * n
    return [_value(o) for o in out], [o.d if type(o) is Dual else zero for o in out]
