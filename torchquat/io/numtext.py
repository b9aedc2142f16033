"""Fast, vectorised number-to-text for pose files, with a round-trip guarantee.

``numpy.savetxt`` and Python's ``repr`` format one value at a time (measured here: 3.3-4.6 s
for a million 8-column rows). Here a whole chunk is formatted with array arithmetic: each
float64 is scaled to 17 significant digits as an exact double-double product (Dekker's
two-product with a table of 10**k as double-doubles; float32 values need only float64), the
shortest of 15, 16 or 17 digits whose decimal lies inside the value's rounding interval (with a
margin far above the arithmetic error) is kept, and the digits are laid into a byte matrix that
is compacted once. 17 digits always round-trip float64 and 9 float32 (IEEE 754, 5.12.2), so
every value written parses back to the same float; for decimals of 15 digits or fewer the text
is the one ``repr`` gives. Non-finite, subnormal and beyond-1e290 values go through ``repr``.

Layout follows ``repr``: positional for ``1e-5 <= |x| < 1e16``, scientific (``1e-05``) outside,
integers without ``.0``.
"""

from typing import List, NamedTuple, Sequence

import numpy as np

__all__ = ["format_rows", "format_floats", "format_nanoseconds", "format_integers", "format_columns", "Floats",
           "Integers", "Nanoseconds"]

_MARGIN = 1e-6  # in units of the last of P digits; the arithmetic error is about 1e-7 of a unit
_SPLIT = 134217729.0  # 2**27 + 1, Dekker's splitter for float64
_ZERO = ord("0")


def _split(x: np.ndarray):
    """Dekker split: ``x == hi + lo`` with each half fitting in 26 bits."""
    t = x * _SPLIT
    hi = t - (t - x)
    return hi, x - hi


def _power_table():
    """10**k for k in [-310, 308] as double-double (hi + lo), computed exactly once."""
    from fractions import Fraction
    ks = range(-_POW_OFFSET, 309)
    exact = [Fraction(10) ** k for k in ks]
    hi = np.array([float(e) for e in exact])
    lo = np.array([float(e - Fraction(h)) if h != 0 else 0.0 for e, h in zip(exact, hi)])
    return hi, lo


_POW_OFFSET = 310
_POW_HI, _POW_LO = _power_table()


def _scaled(a: np.ndarray, k: np.ndarray):
    """``a * 10**k`` as double-double ``(hi, lo)`` (error near 1e-32 relative)."""
    p_hi, p_lo = _POW_HI[k + _POW_OFFSET], _POW_LO[k + _POW_OFFSET]
    product = a * p_hi
    a_hi, a_lo = _split(a)
    b_hi, b_lo = _split(p_hi)
    error = ((a_hi * b_hi - product) + a_hi * b_lo + a_lo * b_hi) + a_lo * b_lo
    return product, error + a * p_lo


def _floor_dd(hi: np.ndarray, lo: np.ndarray):
    """Floor of the double-double ``hi + lo`` and the (non-negative) rest, both float64."""
    whole = np.floor(hi)
    rest = (hi - whole) + lo
    below = rest < 0
    return np.where(below, whole - 1, whole), np.where(below, rest + 1, rest)


def _digit_matrix(x: np.ndarray, count: int) -> np.ndarray:
    """Decimal digits of integer-valued float64 ``0 <= x < 1e15``: ``(count, n)``, most significant first.

    Arrays here are digit-major (one row per digit position) so that numpy's inner loops run
    along the long axis.
    """
    powers = 10.0 ** np.arange(count, -1, -1)
    quotients = np.floor(x[None, :] / powers[:, None])
    return (quotients[1:] - 10 * quotients[:-1]).astype(np.uint8)


def _significant(a: np.ndarray, single: bool):
    """Digits of positive finite ``a``: (``(P, n)`` uint8 digits, exponent, significant count).

    The value is ``0.d1 d2 ... dP * 10**(exponent + 1)``; the digits are the shortest of ``P-2``,
    ``P-1`` or ``P`` significant digits that read back to ``a`` (``P`` = 9 or 17).
    """
    exp10 = np.floor(np.log10(a)).astype(np.int64)
    if single:  # float64 holds a float32 times a power of ten to far better than the margin
        precision, high_digits = 9, 0
        for _ in range(2):
            scaled = a * _POW_HI[8 - exp10 + _POW_OFFSET]
            exp10 = exp10 + (scaled >= 1e9) - (scaled < 1e8)
        high, rest = np.zeros_like(scaled), scaled
    else:  # 8 high digits from floor(a * 10**(7 - e)), 9 low digits from the exact remainder
        precision, high_digits = 17, 8
        for _ in range(2):
            hi, lo = _scaled(a, 7 - exp10)
            # hi + lo against the bounds (hi may round onto or past one the exact product is
            # below); near a bound hi - bound is exact (Sterbenz), and elsewhere lo cannot flip it
            exp10 = exp10 + ((hi - 1e8) + lo >= 0) - ((hi - 1e7) + lo < 0)
        high, fraction = _floor_dd(hi, lo)
        rest = fraction * 1e9
    low_digits = precision - high_digits
    unit_scale = _POW_HI[precision - 1 - exp10 + _POW_OFFSET]
    # (a float32's rounding interval, not its float64 copy's: else 0.6305f needs 9 digits)
    radius = _rounding_half_width(a.astype(np.float32) if single else a) * unit_scale - _MARGIN
    low = np.rint(rest)
    chosen = np.zeros(a.shape, dtype=bool)
    for shorter in (100.0, 10.0):
        candidate = np.rint(rest / shorter) * shorter
        fits = ~chosen & (np.abs(rest - candidate) < radius)
        low = np.where(fits, candidate, low)
        chosen |= fits
    carry = low >= 10.0 ** low_digits  # rounding up spilled into the next digit
    if high_digits:
        low = np.where(carry, 0.0, low)
        high = high + carry
        spill = high >= 10.0 ** high_digits  # 99999999|99999999.9 rounded up to 10**17
        high = np.where(spill, high / 10, high)
    else:
        spill = carry
        low = np.where(spill, low / 10, low)
    exp10 = exp10 + spill
    digits = np.empty((precision, a.size), dtype=np.uint8)
    if high_digits:
        digits[:high_digits] = _digit_matrix(high, high_digits)
    digits[high_digits:] = _digit_matrix(low, low_digits)
    nonzero = digits != 0
    count = precision - np.argmax(nonzero[::-1], axis=0)
    return digits, exp10, count


def _rounding_half_width(a: np.ndarray) -> np.ndarray:
    """Half the gap to the nearer neighbour of each positive finite value (its rounding radius)."""
    with np.errstate(over="ignore"):
        below = a - np.nextafter(a, 0)
        above = np.nextafter(a, np.inf) - a
    return np.minimum(below, above).astype(np.float64) / 2


def format_floats(values: np.ndarray) -> np.ndarray:
    """Format a 2-D float array into a byte matrix, one NUL-padded field per value.

    Args:
        values: ``(n, k)`` float64 or float32 array.

    Returns:
        ``(n, k, width)`` uint8 array; dropping the zero bytes of a field gives its text.

    Example:
        >>> m = format_floats(np.array([[0.1, -2.5e-7, 1e16, 123.0, 0.0]]))
        >>> [bytes(f[f != 0]).decode() for f in m[0]]
        ['0.1', '-2.5e-07', '1e+16', '123', '0']
    """
    single = values.dtype == np.float32
    flat = np.ascontiguousarray(values).reshape(-1)
    negative = np.signbit(flat)
    magnitude = np.abs(flat).astype(np.float64)
    zero = magnitude == 0
    odd = ~np.isfinite(magnitude) | (~zero & ((magnitude < 1e-290) | (magnitude > 1e290)))
    if single:
        odd |= ~zero & (magnitude < np.finfo(np.float32).tiny)
    safe = np.where(zero | odd, 1.0, magnitude)
    digits, exp10, count = _significant(safe, single)
    precision = digits.shape[0]
    digits[:, zero] = 0
    exp10 = np.where(zero, 0, exp10)
    count = np.where(zero, 1, count)

    positional = (exp10 >= -5) & (exp10 < min(16, precision))
    small = positional & (exp10 < 0)
    big = positional & ~small
    science = ~positional
    exp10 = exp10.astype(np.int16)
    count = count.astype(np.int16)
    dot_at = np.where(big & (count > exp10 + 1), exp10 + 1, np.where(science & (count > 1), 1, precision + 1))
    dot_at = dot_at.astype(np.int16)
    last_int = np.where(big, exp10, -1).astype(np.int16)  # integer digits always shown
    shown = np.maximum(count, last_int + 1)  # digits written, the point not counted
    n = flat.size
    body = np.zeros((precision + 1, n), dtype=np.uint8)
    for column in range(precision + 1):  # digit ``column``, or the point, or digit ``column - 1``
        after = column > dot_at
        if column == 0:
            body[0] = digits[0] + _ZERO
            continue
        digit = digits[column - 1] if column == precision else np.where(after, digits[column - 1], digits[column])
        visible = np.where(after, column - 1 < shown, column < shown)
        text = np.where(visible, digit + _ZERO, 0).astype(np.uint8)
        body[column] = np.where(column == dot_at, np.uint8(ord(".")), text)

    head = np.zeros((7, n), dtype=np.uint8)
    head[0] = np.where(negative & ~zero, ord("-"), 0)
    head[1] = np.where(small, _ZERO, 0)
    head[2] = np.where(small, ord("."), 0)
    leading_zeros = np.where(small, -exp10 - 1, 0)
    for i in range(4):
        head[3 + i] = np.where(i < leading_zeros, _ZERO, 0)
    power = np.abs(exp10)
    tail = np.zeros((5, n), dtype=np.uint8)
    tail[0] = np.where(science, ord("e"), 0)
    tail[1] = np.where(science, np.where(exp10 < 0, ord("-"), ord("+")), 0)
    tail[2] = np.where(science & (power >= 100), power // 100 + _ZERO, 0)
    tail[3] = np.where(science, (power // 10) % 10 + _ZERO, 0)
    tail[4] = np.where(science, power % 10 + _ZERO, 0)
    fields = np.concatenate([head, body, tail], axis=0).T
    if odd.any():
        _patch_with_repr(fields, flat, np.flatnonzero(odd))
    return fields.reshape(values.shape[0], values.shape[1], -1)


def _patch_with_repr(fields: np.ndarray, flat: np.ndarray, where: np.ndarray) -> None:
    """Rare values (non-finite, subnormal, beyond 1e+-290): Python's shortest ``repr``."""
    for i in where:
        text = repr(float(flat[i])) if flat.dtype == np.float64 else str(np.float32(flat[i]))
        raw = np.frombuffer(text.encode()[: fields.shape[1]], dtype=np.uint8)
        fields[i] = 0
        fields[i, : raw.size] = raw


def format_nanoseconds(ns: np.ndarray) -> np.ndarray:
    """Format int64 nanoseconds as seconds (``%d.%09d``, trailing zeros of the fraction dropped).

    Args:
        ns: ``(n,)`` int64 array of nanoseconds.

    Returns:
        ``(n, 1, width)`` uint8 array, NUL padded like :func:`format_floats`.

    Example:
        >>> m = format_nanoseconds(np.array([1403715524907143168, 5_000_000_000, -1]))
        >>> [bytes(f[0][f[0] != 0]).decode() for f in m]
        ['1403715524.907143168', '5.0', '-0.000000001']
    """
    ns = np.asarray(ns, dtype=np.int64)
    negative = ns < 0
    magnitude = np.abs(ns)
    seconds, fraction = magnitude // 1_000_000_000, magnitude % 1_000_000_000
    int_places = 10 ** np.arange(9, -1, -1, dtype=np.int64)
    int_digits = (seconds[:, None] // int_places) % 10
    first = np.where(int_digits.any(axis=1), np.argmax(int_digits != 0, axis=1), 9)
    frac_digits = (fraction[:, None] // 10 ** np.arange(8, -1, -1, dtype=np.int64)) % 10
    nonzero = frac_digits != 0
    frac_count = np.where(nonzero.any(axis=1), 9 - np.argmax(nonzero[:, ::-1], axis=1), 1)
    n = ns.size
    out = np.zeros((n, 1 + 10 + 1 + 9), dtype=np.uint8)
    out[:, 0] = np.where(negative, ord("-"), 0)
    out[:, 1:11] = np.where(np.arange(10)[None, :] >= first[:, None], int_digits + _ZERO, 0)
    out[:, 11] = ord(".")
    out[:, 12:] = np.where(np.arange(9)[None, :] < frac_count[:, None], frac_digits + _ZERO, 0)
    return out.reshape(n, 1, -1)


def format_integers(values: np.ndarray) -> np.ndarray:
    """Format int64 values in decimal.

    Args:
        values: ``(n,)`` integer array.

    Returns:
        ``(n, 1, w)`` uint8 array (``w <= 20``), NUL padded like :func:`format_floats`.

    Example:
        >>> m = format_integers(np.array([0, -42, 1403715524907143168]))
        >>> [bytes(f[0][f[0] != 0]).decode() for f in m]
        ['0', '-42', '1403715524907143168']
    """
    values = np.asarray(values, dtype=np.int64)
    magnitude = np.abs(values).astype(np.uint64)
    largest = int(magnitude.max(initial=0))
    width = max(1, min(19, len(str(largest))))  # only as many digit columns as the largest value needs
    places = (10 ** np.arange(width - 1, -1, -1, dtype=np.int64)).astype(np.uint64)
    digits = ((magnitude[None, :] // places[:, None]) % np.uint64(10)).astype(np.uint8)  # (width, n)
    first = np.where(digits.any(axis=0), np.argmax(digits != 0, axis=0), width - 1)
    out = np.zeros((width + 1, values.size), dtype=np.uint8)
    out[0] = np.where(values < 0, ord("-"), 0)
    out[1:] = np.where(np.arange(width)[:, None] >= first[None, :], digits + _ZERO, 0)
    return np.ascontiguousarray(out.T).reshape(values.size, 1, width + 1)


def format_rows(fields: Sequence[np.ndarray], separator: str = " ") -> bytes:
    """Join NUL-padded field matrices into text lines.

    Args:
        fields: arrays of shape ``(n, k_i, width_i)`` from :func:`format_floats` and
            :func:`format_nanoseconds`, in column order.
        separator: the byte put between fields; each row ends with a newline.

    Returns:
        The encoded lines.

    Example:
        >>> format_rows([format_nanoseconds(np.array([1])), format_floats(np.array([[1.5, -2.0]]))])
        b'0.000000001 1.5 -2\\n'
    """
    parts: List[np.ndarray] = []
    n = fields[0].shape[0]
    for block in fields:
        width = block.shape[2]
        padded = np.zeros((n, block.shape[1], width + 1), dtype=np.uint8)
        padded[:, :, :width] = block
        padded[:, :, width] = ord(separator)
        parts.append(padded.reshape(n, -1))
    table = np.concatenate(parts, axis=1)
    last = table.shape[1] - 1
    table[:, last] = ord("\n")
    return table[table != 0].tobytes()


class Floats(NamedTuple):
    """Columns of floats for :func:`format_columns`: an ``(n, k)`` float64 or float32 array."""
    values: np.ndarray


class Integers(NamedTuple):
    """A column of integers for :func:`format_columns`: an ``(n,)`` int64 array."""
    values: np.ndarray


class Nanoseconds(NamedTuple):
    """A column of int64 nanoseconds written as exact decimal seconds (see :func:`format_nanoseconds`)."""
    values: np.ndarray


_FORMATTERS = {Floats: format_floats, Integers: format_integers, Nanoseconds: format_nanoseconds}


def format_columns(columns: Sequence, separator: str = " ") -> bytes:
    """Format columns into text lines with numpy alone.

    Args:
        columns: :class:`Floats`, :class:`Integers` and :class:`Nanoseconds`, in column order.
        separator: the byte put between fields; each row ends with a newline.

    Returns:
        The encoded lines; every value reads back to the same float (or integer).

    Example:
        >>> text = format_columns([Integers(np.array([7])), Floats(np.array([[0.5, -2.0]]))])
        >>> [float(v) for v in text.split()]
        [7.0, 0.5, -2.0]
    """
    fields = []
    for column in columns:
        formatter = _FORMATTERS.get(type(column))
        if formatter is None:
            raise TypeError(f"format_columns: unknown column {type(column).__name__}")
        fields.append(formatter(column.values))
    return format_rows(fields, separator)
