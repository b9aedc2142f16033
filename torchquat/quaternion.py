"""Quaternion algebra: products, conjugates, rotation of vectors, layouts and sampling."""

import math
import operator
from typing import Sequence, Tuple, Union

import torch
from torch import Tensor

from . import _formulas as F
from ._dispatch import run
from ._validation import prepare, prepare_pair, restore

__all__ = ["quat_multiply", "quat_conjugate", "quat_inverse", "quat_normalize", "quat_standardize",
           "quat_rotate", "quat_identity", "random_quat", "quat_wxyz_to_xyzw", "quat_xyzw_to_wxyz",
           "quat_from_jpl", "quat_to_jpl"]

_CONJUGATE = (1.0, -1.0, -1.0, -1.0)

def quat_multiply(p: Tensor, q: Tensor) -> Tensor:
    """Hamilton product ``p * q`` (apply ``q`` first, then ``p``).

    Args:
        p: quaternions ``(w, x, y, z)``.
        q: quaternions ``(w, x, y, z)``; batch dims broadcast with ``p``'s.

    Returns:
        The product, unnormalised, with signs as the algebra gives them.

    Shape:
        ``(..., 4)`` and ``(..., 4)`` -> ``(..., 4)`` (broadcast batch).

    Example:
        >>> i = torch.tensor([0., 1., 0., 0.]); j = torch.tensor([0., 0., 1., 0.])
        >>> quat_multiply(i, j)  # ij = k
        tensor([0., 0., 0., 1.])
    """
    p, q, dtype = prepare_pair("quat_multiply", ("p", "q"), p, q, (4,), (4,))
    return restore(run(F.multiply, (p, q), (4,)), dtype)


def quat_conjugate(q: Tensor) -> Tensor:
    """Conjugate ``(w, -x, -y, -z)``: the inverse rotation for a unit quaternion.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_conjugate(torch.tensor([1., 2., 3., 4.]))
        tensor([ 1., -2., -3., -4.])
    """
    q, dtype = prepare(q, "quat_conjugate", "q", (4,))
    return restore(q * q.new_tensor(_CONJUGATE), dtype)


def quat_inverse(q: Tensor) -> Tensor:
    """Multiplicative inverse ``conj(q) / |q|^2`` (NaN for the zero quaternion).

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_inverse(torch.tensor([0., 2., 0., 0.]))
        tensor([ 0.0000, -0.5000, -0.0000, -0.0000])
    """
    q, dtype = prepare(q, "quat_inverse", "q", (4,))
    return restore(q * q.new_tensor(_CONJUGATE) / (q * q).sum(-1, keepdim=True), dtype)


def quat_normalize(q: Tensor) -> Tensor:
    """Scale to unit norm; the zero quaternion gives NaN (no rotation is plausible for it).

    Any finite norm works, even where ``|q|^2`` would overflow or underflow (1e20 or 1e-20 in
    float32): ``q`` is first divided by its largest ``|component|``. So this is the cure for
    quaternions whose norm the other functions' squares cannot take.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_normalize(torch.tensor([2., 0., 0., 0.]))
        tensor([1., 0., 0., 0.])
    """
    q, dtype = prepare(q, "quat_normalize", "q", (4,))
    q = q / q.abs().amax(-1, keepdim=True)  # (0 / 0: NaN for q = 0)
    return restore(q * torch.rsqrt((q * q).sum(-1, keepdim=True)), dtype)


def quat_standardize(q: Tensor) -> Tensor:
    """Pick the representative with ``w >= 0`` (``q`` and ``-q`` are the same rotation).

    When ``w == 0`` (a half turn) the first non-zero of ``x, y, z`` is made positive, so the
    result is unique for every rotation.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_standardize(torch.tensor([-1., 0., 0., 0.]))
        tensor([1., -0., -0., -0.])
    """
    q, dtype = prepare(q, "quat_standardize", "q", (4,))
    return restore(run(F.standardize, (q,), (4,)), dtype)


def quat_rotate(q: Tensor, v: Tensor) -> Tensor:
    """Rotate 3-vectors: ``q (0, v) q*`` for unit ``q``, computed as ``t = 2 q_vec x v``,
    ``v' = v + w t + q_vec x t``.

    A non-unit ``q`` rotates by ``q / |q|`` (``t`` is divided by ``|q|^2``), matching
    :func:`quat_to_matrix`; the zero quaternion gives NaN. ``|q|^2`` must neither overflow nor
    underflow: norms from about 1e-19 to 1e19 in float32 (1e-153 to 1e154 in float64); beyond, a
    large ``q`` leaves ``v`` unrotated and a tiny one gives NaN, so normalise such inputs first
    (:func:`quat_normalize` takes any finite norm).

    Args:
        q: quaternions ``(w, x, y, z)``.
        v: vectors; batch dims broadcast with ``q``'s (one rotation for many points or one each).

    Returns:
        The rotated vectors.

    Shape:
        ``(..., 4)`` and ``(..., 3)`` -> ``(..., 3)`` (broadcast batch).

    Example:
        >>> q = torch.tensor([math.cos(math.pi / 4), 0., 0., math.sin(math.pi / 4)])  # 90 deg about z
        >>> quat_rotate(q, torch.tensor([1., 0., 0.])).round(decimals=6) + 0.0  # + 0.0 turns -0. into 0.
        tensor([0., 1., 0.])
    """
    q, v, dtype = prepare_pair("quat_rotate", ("q", "v"), q, v, (4,), (3,))
    return restore(run(F.rotate, (q, v), (3,)), dtype)


def _factory_arguments(fn: str, shape, dtype) -> Tuple[Tuple[int, ...], torch.dtype]:
    """``shape`` as a tuple (an integer of any kind, NumPy's included, or a sequence of them) and
    ``dtype`` (the default dtype for ``None``), a floating-point one, else ``TypeError`` naming ``fn``."""
    try:
        shape = (operator.index(shape),)
    except TypeError:
        try:
            shape = tuple(operator.index(n) for n in shape)
        except TypeError:
            raise TypeError(f"{fn}: expected shape to be an int or a sequence of ints, got {shape!r}") from None
    if any(n < 0 for n in shape):
        raise ValueError(f"{fn}: expected a shape of non-negative sizes, got {shape}")
    dtype = torch.get_default_dtype() if dtype is None else dtype
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(f"{fn}: expected a floating-point dtype, got {dtype!r}")
    return shape, dtype


def quat_identity(shape: Union[int, Sequence[int]] = (), *, dtype=None, device=None) -> Tensor:
    """Identity quaternions ``(1, 0, 0, 0)``.

    Shape:
        ``shape`` -> ``(*shape, 4)``.

    Example:
        >>> quat_identity(2)
        tensor([[1., 0., 0., 0.],
                [1., 0., 0., 0.]])
    """
    shape, dtype = _factory_arguments("quat_identity", shape, dtype)
    q = torch.zeros(shape + (4,), dtype=dtype, device=device)
    q[..., 0] = 1.0  # (a fresh tensor of our own)
    return q


def random_quat(shape: Union[int, Sequence[int]] = (), *, generator=None, dtype=None,
                device=None) -> Tensor:
    """Rotations drawn uniformly from SO(3) (Shoemake 1992, "Uniform random rotations").

    Args:
        shape: batch shape.
        generator: a ``torch.Generator`` for reproducible draws.
        dtype: defaults to ``torch.get_default_dtype()``.
        device: where to create the tensor.

    Returns:
        Unit quaternions; signs are as drawn (both hemispheres occur).

    Shape:
        ``shape`` -> ``(*shape, 4)``.

    Example:
        >>> q = random_quat(1000, generator=torch.Generator().manual_seed(0))
        >>> bool(torch.allclose(q.norm(dim=-1), torch.ones(1000)))
        True
    """
    shape, dtype = _factory_arguments("random_quat", shape, dtype)
    work = torch.float32 if dtype in (torch.float16, torch.bfloat16) else dtype
    u1, u2, u3 = torch.rand(shape + (3,), generator=generator, dtype=work, device=device).unbind(-1)
    r1, r2 = torch.sqrt(1.0 - u1), torch.sqrt(u1)
    a2, a3 = 2.0 * math.pi * u2, 2.0 * math.pi * u3
    q = torch.stack((r2 * torch.cos(a3), r1 * torch.sin(a2), r1 * torch.cos(a2), r2 * torch.sin(a3)), -1)
    return q.to(dtype)


def quat_wxyz_to_xyzw(q: Tensor) -> Tensor:
    """Reorder scalar-first ``(w, x, y, z)`` to scalar-last ``(x, y, z, w)`` (SciPy, ROS, RoMa).

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_wxyz_to_xyzw(torch.tensor([1., 2., 3., 4.]))
        tensor([2., 3., 4., 1.])
    """
    q, dtype = prepare(q, "quat_wxyz_to_xyzw", "q", (4,))
    return restore(q.roll(-1, dims=-1), dtype)


def quat_xyzw_to_wxyz(q: Tensor) -> Tensor:
    """Reorder scalar-last ``(x, y, z, w)`` to scalar-first ``(w, x, y, z)``.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_xyzw_to_wxyz(torch.tensor([2., 3., 4., 1.]))
        tensor([1., 2., 3., 4.])
    """
    q, dtype = prepare(q, "quat_xyzw_to_wxyz", "q", (4,))
    return restore(q.roll(1, dims=-1), dtype)


def quat_from_jpl(q: Tensor) -> Tensor:
    """JPL quaternion ``(x, y, z, w)`` (scalar last, ``ij = -k``) to the Hamilton quaternion with
    the same rotation matrix.

    Trawny and Roumeliotis (2005) give ``C(q) = (2w^2 - 1) I - 2w [q_vec x] + 2 q_vec q_vec^T``,
    which is ``quat_to_matrix((w, -x, -y, -z))``.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_from_jpl(torch.tensor([1., 2., 3., 4.]))
        tensor([ 4., -1., -2., -3.])
    """
    q, dtype = prepare(q, "quat_from_jpl", "q", (4,))
    return restore(q.roll(1, dims=-1) * q.new_tensor(_CONJUGATE), dtype)


def quat_to_jpl(q: Tensor) -> Tensor:
    """Hamilton quaternion ``(w, x, y, z)`` to the JPL quaternion ``(-x, -y, -z, w)``; inverse of
    :func:`quat_from_jpl`.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_to_jpl(torch.tensor([4., -1., -2., -3.]))
        tensor([1., 2., 3., 4.])
    """
    q, dtype = prepare(q, "quat_to_jpl", "q", (4,))
    return restore((q * q.new_tensor(_CONJUGATE)).roll(-1, dims=-1), dtype)
