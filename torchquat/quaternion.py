"""Quaternion algebra: products, conjugates, normalisation, rotation of vectors, sampling (slerp:
:mod:`torchquat.slerp`).

Quaternions are ``(..., 4)`` tensors ``(w, x, y, z)`` with the Hamilton product (``ij = k``).
These functions keep signs as the mathematics gives them; only the conversions that *produce*
a quaternion from another representation standardise to ``w >= 0``.
"""

import math
import operator
from typing import Optional, Sequence, Tuple, Union

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule
from ._dispatch import kernel
from ._one_row import OneRow
from ._math import bilinear, bilinear_terms, constant, contract, copysign, is_small, outer_product, sum_of_squares
from ._planes import columns, planar, plane_buffer, rows, slot
from ._validation import prepare, prepare_pair, restore

__all__ = [
    "quat_multiply", "quat_conjugate", "quat_inverse", "quat_normalize", "quat_standardize",
    "quat_rotate", "quat_identity", "random_quat",
    "quat_wxyz_to_xyzw", "quat_xyzw_to_wxyz", "quat_from_jpl", "quat_to_jpl",
]


def _product_table():
    """16 x 4 table: ``(p q^T).flatten() @ T`` is the Hamilton product ``p q``."""
    basis = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))
    table = []
    for i in range(4):
        for j in range(4):
            table.append([float(c) for c in basis_product(basis[i], basis[j])])
    return table


def basis_product(a, b):
    """Hamilton product of two quaternions given as 4-tuples of Python numbers (exact for integers)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


_PRODUCT = _product_table()
_PLANAR_SHARE = 0.25  # the product and rotating vectors: contiguous columns from 8,192 rows (measured)
CONJUGATE_SIGNS = [1.0, -1.0, -1.0, -1.0]
# p conj(q) and conj(p) q, for the product's gradients
_PRODUCT_TERMS = bilinear_terms(_PRODUCT, 4)
_PRODUCT_CONJUGATE_RIGHT = bilinear_terms([[c * CONJUGATE_SIGNS[r % 4] for c in row] for r, row in enumerate(_PRODUCT)], 4)
_PRODUCT_CONJUGATE_LEFT = bilinear_terms([[c * CONJUGATE_SIGNS[r // 4] for c in row] for r, row in enumerate(_PRODUCT)], 4)


def _product_columnwise_parts(p: Tensor, q: Tensor):
    """The product column by column, and its inputs' columns (for the closed-form backward)."""
    a, b = columns(p, share=_PLANAR_SHARE), columns(q, share=_PLANAR_SHARE)
    return rows(bilinear(a, b, _PRODUCT_TERMS, out=plane_buffer(4, a + b, _PLANAR_SHARE)), share=_PLANAR_SHARE), (*a, *b)


def _product_columnwise(p: Tensor, q: Tensor) -> Tensor:
    return _product_columnwise_parts(p, q)[0]


def _product_columnwise_backward(grad: Tensor, inputs, saved):
    # d(p q) = dp q + p dq, and right (left) multiplication by q has the transpose of right (left)
    # multiplication by conj(q): 2 products of 16 terms, against autograd's ~100 nodes.
    p, q = saved[:4], saved[4:]  # (the forward's columns: no second transpose)
    g = columns(grad, share=_PLANAR_SHARE)
    return (rows(bilinear(g, q, _PRODUCT_CONJUGATE_RIGHT, out=plane_buffer(4, g, _PLANAR_SHARE)), share=_PLANAR_SHARE),
            rows(bilinear(p, g, _PRODUCT_CONJUGATE_LEFT, out=plane_buffer(4, g, _PLANAR_SHARE)), share=_PLANAR_SHARE))


_PRODUCT_COLUMNWISE = Rule(_product_columnwise, _product_columnwise_parts, _product_columnwise_backward,
                           _product_columnwise)
_PRODUCT_TRACED = closed_form.traced_rule(_PRODUCT_COLUMNWISE)


@kernel(blocked_row_dims=(1, 1), compiled_from_rows=8_192, one_row=OneRow("hamilton_product", (4, 4), (4,)),
        vector_bits=256)
def hamilton_product(p: Tensor, q: Tensor) -> Tensor:
    """Unchecked Hamilton product of prepared tensors (used internally)."""
    if is_small(p, 4, gpu_share=4) and is_small(q, 4, gpu_share=4):
        return contract(outer_product(p, q), "product", _PRODUCT)
    if torch.compiler.is_compiling():
        return _PRODUCT_TRACED(p, q)
    return closed_form.apply(_PRODUCT_COLUMNWISE, p, q)


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
    if (out := hamilton_product.at_one_row(p, q)) is not None:
        return out
    p, q, dtype = prepare_pair("quat_multiply", ("p", "q"), p, q, (4,), (4,))
    return restore(hamilton_product(p, q), dtype)


def quat_conjugate(q: Tensor) -> Tensor:
    """Conjugate ``(w, -x, -y, -z)``: the inverse rotation for a unit quaternion.

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_conjugate(torch.tensor([1., 2., 3., 4.]))
        tensor([ 1., -2., -3., -4.])
    """
    q, dtype = prepare(q, "quat_conjugate", "q", (4,))
    return restore(q * constant("conjugate", CONJUGATE_SIGNS, q), dtype)


def quat_inverse(q: Tensor) -> Tensor:
    """Multiplicative inverse ``conj(q) / |q|^2`` (NaN for the zero quaternion).

    Shape:
        ``(..., 4)`` -> ``(..., 4)``.

    Example:
        >>> quat_inverse(torch.tensor([0., 2., 0., 0.]))
        tensor([ 0.0000, -0.5000, -0.0000, -0.0000])
    """
    q, dtype = prepare(q, "quat_inverse", "q", (4,))
    inv = q * constant("conjugate", CONJUGATE_SIGNS, q) / (q * q).sum(-1, keepdim=True)
    return restore(inv, dtype)


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
    return restore(normalized(q / q.abs().amax(-1, keepdim=True)), dtype)  # (0 / 0: NaN for q = 0)


def normalized(q: Tensor) -> Tensor:
    """Unchecked ``q / |q|`` with NaN (not inf or 0) for zero vectors."""
    return q * torch.rsqrt((q * q).sum(-1, keepdim=True))


def standardize_sign(q: Tensor, magnitude: Optional[Tensor] = None) -> Tensor:
    """Unchecked: the sign (+-1, shape ``(..., 1)``) that makes ``q`` canonical, or ``magnitude``
    (broadcasting with ``(..., 1)``) with that sign.

    Canonical means ``w > 0``, or ``w == 0`` and the first non-zero of ``x, y, z`` positive,
    so that every rotation has exactly one representative (SciPy's canonical form).
    """
    # sign(8 sign(w) + 4 sign(x) + 2 sign(y) + sign(z)) is the sign of the first non-zero
    # component (each weight exceeds the sum of the later ones): 3 ops instead of nested wheres.
    key = contract(torch.sign(q), "lexicographic", [8.0, 4.0, 2.0, 1.0])
    return copysign(constant("one", 1.0, q) if magnitude is None else magnitude,
                    key.unsqueeze(-1))  # key = +0 only for q = 0


@kernel
def standardized(q: Tensor) -> Tensor:
    """Unchecked ``q * standardize_sign(q)``."""
    return q * standardize_sign(q)


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
    return restore(standardized(q), dtype)


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
    if (out := rotate_unchecked.at_one_row(q, v)) is not None:
        return out
    q, v, dtype = prepare_pair("quat_rotate", ("q", "v"), q, v, (4,), (3,))
    return restore(rotate_unchecked(q, v), dtype)


@kernel(blocked_row_dims=(1, 1), compiled_from_rows=1_024, one_row=OneRow("rotate", (4, 3), (3,)))
def rotate_unchecked(q: Tensor, v: Tensor) -> Tensor:
    if torch.compiler.is_compiling() or planar(q, 4, _PLANAR_SHARE) or planar(v, 3, _PLANAR_SHARE):  # (one fused loop under compile)
        q, (a, b, c) = columns(q, share=_PLANAR_SHARE), columns(v, share=_PLANAR_SHARE)
        w, x, y, z = q
        scale = 2.0 / sum_of_squares(q)
        tx = torch.addcmul(y * c, z, b, value=-1.0) * scale
        ty = torch.addcmul(z * a, x, c, value=-1.0) * scale
        tz = torch.addcmul(x * b, y, a, value=-1.0) * scale
        buffer = plane_buffer(3, (*q, a), _PLANAR_SHARE)  # (forward only: autograd refuses out=)
        rotated = [torch.addcmul(torch.addcmul(torch.addcmul(a, w, tx), y, tz), z, ty, value=-1.0, out=slot(buffer, 0)),
                   torch.addcmul(torch.addcmul(torch.addcmul(b, w, ty), z, tx), x, tz, value=-1.0, out=slot(buffer, 1)),
                   torch.addcmul(torch.addcmul(torch.addcmul(c, w, tz), x, ty), y, tx, value=-1.0, out=slot(buffer, 2))]
        return rows(rotated if buffer is None else buffer, share=_PLANAR_SHARE)
    w, u = q.narrow(-1, 0, 1), q.narrow(-1, 1, 3)
    u, v = torch.broadcast_tensors(u, v)  # linalg.cross wants equal ndim; these are views
    t = torch.linalg.cross(u, v, dim=-1) * (constant("two", 2.0, q) / (q * q).sum(-1, keepdim=True))
    return v + w * t + torch.linalg.cross(u, t, dim=-1)


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
    q[..., 0] = 1.0  # a fresh tensor we own: writing into it changes no input
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
    u = torch.rand(shape + (3,), generator=generator, dtype=work, device=device)
    u1, u2, u3 = u.unbind(-1)
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
    return restore(q.roll(1, dims=-1) * constant("conjugate", CONJUGATE_SIGNS, q), dtype)


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
    return restore(q.roll(-1, dims=-1) * constant("jpl_signs", [-1.0, -1.0, -1.0, 1.0], q), dtype)
