"""Quaternion <-> rotation matrix."""

import torch
from torch import Tensor

from ._dispatch import kernel
from ._math import constant, is_small
from ._validation import prepare, restore
from .quaternion import standardize_sign

__all__ = ["quat_to_matrix", "matrix_to_quat"]


def _homogeneous_table():
    """16 x 10 table: ``(q q^T).flatten() @ T`` gives the 9 entries of ``|q|^2 R`` and ``|q|^2``."""
    w, x, y, z = range(4)
    entries = [
        {(w, w): 1, (x, x): 1, (y, y): -1, (z, z): -1}, {(x, y): 2, (w, z): -2}, {(x, z): 2, (w, y): 2},
        {(x, y): 2, (w, z): 2}, {(w, w): 1, (x, x): -1, (y, y): 1, (z, z): -1}, {(y, z): 2, (w, x): -2},
        {(x, z): 2, (w, y): -2}, {(y, z): 2, (w, x): 2}, {(w, w): 1, (x, x): -1, (y, y): -1, (z, z): 1},
        {(w, w): 1, (x, x): 1, (y, y): 1, (z, z): 1},
    ]
    table = [[0.0] * 10 for _ in range(16)]
    for col, entry in enumerate(entries):
        for (i, j), coefficient in entry.items():
            table[4 * i + j][col] = float(coefficient)
    return table


_HOMOGENEOUS = _homogeneous_table()


@kernel
def quat_to_matrix_unchecked(q: Tensor) -> Tensor:
    """Homogeneous form divided by ``|q|^2``: the rotation of ``q / |q|``, NaN for ``q = 0``."""
    if is_small(q, 4):
        # Few rotations: cost is per-operation dispatch, so use 4 ops: the outer product, one
        # small matmul against the constant table, a division (NOTES: 5-10 us an op at N = 1).
        h = (q.unsqueeze(-1) * q.unsqueeze(-2)).flatten(-2) @ constant("homogeneous", _HOMOGENEOUS, q)
        return (h[..., :9] / h[..., 9:]).unflatten(-1, (3, 3))
    # Many: the skinny matmul is slower than elementwise passes (NOTES), so spell it out.
    w, x, y, z = q.unbind(-1)
    s = 2.0 / (w * w + x * x + y * y + z * z)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    R = torch.stack((
        1.0 - (yy + zz), xy - wz, xz + wy,
        xy + wz, 1.0 - (xx + zz), yz - wx,
        xz - wy, yz + wx, 1.0 - (xx + yy),
    ), dim=-1)
    return R.unflatten(-1, (3, 3))


def quat_to_matrix(q: Tensor) -> Tensor:
    """Rotation matrix of a quaternion.

    Non-unit quaternions are accepted: the result is the rotation of ``q / |q|`` (the homogeneous
    form divided by ``|q|^2``, which stays orthogonal); the zero quaternion gives NaN.

    Args:
        q: quaternions ``(w, x, y, z)``.

    Returns:
        Rotation matrices acting on column vectors, ``R @ v``.

    Shape:
        ``(..., 4)`` -> ``(..., 3, 3)``.

    Example:
        >>> quat_to_matrix(torch.tensor([0., 0., 0., 1.]))  # 180 degrees about z
        tensor([[-1.,  0.,  0.],
                [ 0., -1.,  0.],
                [ 0.,  0.,  1.]])
    """
    q, dtype = prepare(q, "quat_to_matrix", "q", (4,))
    return restore(quat_to_matrix_unchecked(q), dtype)


@kernel
def matrix_to_quat_unchecked(R: Tensor) -> Tensor:
    """Shepperd's method (1978), branch-free, returning ``w >= 0``.

    Each of ``4w^2, 4x^2, 4y^2, 4z^2`` is a linear function of R's diagonal; the largest of them
    is at least 1, so dividing the matching row of the symmetric matrix ``4 q q^T`` by its norm
    never loses precision (unlike the trace formula near 180 degrees). The choice is made with
    ``argmax`` and ``gather``, so there is no data-dependent branch and no device sync.
    """
    m = R.flatten(-2)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = m.unbind(-1)
    d0 = 1.0 + r00 + r11 + r22
    d1 = 1.0 + r00 - r11 - r22
    d2 = 1.0 - r00 + r11 - r22
    d3 = 1.0 - r00 - r11 + r22
    a, b, c = r21 - r12, r02 - r20, r10 - r01  # 4w(x, y, z)
    e, f, g = r10 + r01, r02 + r20, r21 + r12  # 4xy, 4xz, 4yz
    rows = torch.stack((
        d0, a, b, c,
        a, d1, e, f,
        b, e, d2, g,
        c, f, g, d3,
    ), dim=-1).unflatten(-1, (4, 4))
    best = torch.stack((d0, d1, d2, d3), dim=-1).argmax(dim=-1)
    index = best[..., None, None].expand(*best.shape, 1, 4)
    row = rows.gather(-2, index).squeeze(-2)
    q = row * torch.rsqrt((row * row).sum(-1, keepdim=True))
    return q * standardize_sign(q)


def matrix_to_quat(R: Tensor) -> Tensor:
    """Quaternion of a rotation matrix (Shepperd 1978), with ``w >= 0``.

    ``R`` is assumed orthogonal with det +1; project noisy matrices with
    :func:`rot9d_to_matrix` first. Accurate at every angle including 180 degrees, and its
    gradient is finite at the identity (where square-root formulas give NaN).

    Args:
        R: rotation matrices acting on column vectors.

    Returns:
        Unit quaternions ``(w, x, y, z)``, standardised (``w >= 0``, see :func:`quat_standardize`).

    Shape:
        ``(..., 3, 3)`` -> ``(..., 4)``.

    Example:
        >>> matrix_to_quat(torch.eye(3))
        tensor([1., 0., 0., 0.])
    """
    R, dtype = prepare(R, "matrix_to_quat", "R", (3, 3))
    return restore(matrix_to_quat_unchecked(R), dtype)
