"""Quaternion <-> rotation matrix."""

import torch
from torch import Tensor

from . import _closed_form as closed_form
from ._closed_form import Rule, _transformed, jacobian_rule
from ._dispatch import kernel
from ._one_row import OneRow
from ._math import bilinear, bilinear_terms, constant, contract, is_small, outer_product, sum_of_squares
from ._planes import columns, planar, plane_buffer, rows, slot
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


HOMOGENEOUS = _homogeneous_table()
# contiguous columns from 8,192 rows (quat -> matrix) and 16,384 (matrix -> quat): measured crossovers
_PLANAR_SHARE, _SHEPPERD_PLANAR_SHARE = 0.25, 0.5
_PAIRS = tuple((i, j) for i in range(4) for j in range(i, 4))
# 10 x 9: the products q_i q_j (i <= j) -> the 9 entries of |q|^2 R
_HOMOGENEOUS_PAIRS = tuple(tuple(HOMOGENEOUS[4 * i + j][c] + (HOMOGENEOUS[4 * j + i][c] if i != j else 0.0)
                                 for c in range(9)) for i, j in _PAIRS)
_HOMOGENEOUS_PAIRS_T = tuple(zip(*_HOMOGENEOUS_PAIRS))  # 9 x 10: R's gradient to the products'


def _quat_to_matrix_planar_parts(q: Tensor):
    """Many rows, eager: the 10 distinct products q_i q_j / |q|^2 as contiguous columns (written into
    one buffer where nothing records a graph); one matmul with the table sums them into R's entries
    and interleaves them (torchquat._planes). Returns R and what the closed-form backward needs."""
    q = columns(q, share=_PLANAR_SHARE)
    inverse = torch.reciprocal(sum_of_squares(q))
    scaled = [c * inverse for c in q]
    buffer = plane_buffer(len(_PAIRS), q, _PLANAR_SHARE, output=False)
    products = [torch.mul(q[i], scaled[j], out=slot(buffer, p)) for p, (i, j) in enumerate(_PAIRS)]
    R = rows(products if buffer is None else buffer, _HOMOGENEOUS_PAIRS, "homogeneous_pairs", _PLANAR_SHARE)
    return R.unflatten(-1, (3, 3)), (*q, *scaled)


def _quat_to_matrix_planar(q: Tensor) -> Tensor:
    return _quat_to_matrix_planar_parts(q)[0]


# d(q_i q_j) = q_j dq_i + q_i dq_j over the pairs: row 4 p + v, the pair's gradient times q_v, to q_u
_PAIRS_GRADIENT = bilinear_terms([[float((u == i and v == j) + (u == j and v == i)) for u in range(4)]
                                  for i, j in _PAIRS for v in range(4)], 4)


def _quat_to_matrix_planar_backward(grad: Tensor, inputs, saved):
    # R = P(q) / s, s = |q|^2, P quadratic: with A = dP^T g_P (g_P: the 10 products' gradient, from
    # the table transposed), A(q) / s = A(q / s), and d s = 2 q.dq, the gradient is
    # A(q / s) - q <q / s, A(q / s)> (Euler's theorem: <q, A(q)> = 2 <P, g_P>)
    q, scaled = saved[:4], saved[4:]
    g_pairs = columns(grad.flatten(-2), _HOMOGENEOUS_PAIRS_T, "homogeneous_pairs_T", share=_PLANAR_SHARE)
    a = bilinear(g_pairs, scaled, _PAIRS_GRADIENT)
    along = scaled[0] * a[0]
    for x, y in zip(scaled[1:], a[1:]):
        along = torch.addcmul(along, x, y)
    buffer = plane_buffer(4, q, _PLANAR_SHARE)
    g_q = [torch.addcmul(y, x, along, value=-1.0, out=slot(buffer, i)) for i, (x, y) in enumerate(zip(q, a))]
    return (rows(g_q if buffer is None else buffer, share=_PLANAR_SHARE),)


_QUAT_TO_MATRIX_PLANAR = Rule(_quat_to_matrix_planar, _quat_to_matrix_planar_parts, _quat_to_matrix_planar_backward,
                              _quat_to_matrix_planar)


@kernel(blocked_row_dims=(1,), compiled_from_rows=2_048, one_row=OneRow("quat_to_matrix", (4,), (3, 3)))
def quat_to_matrix_unchecked(q: Tensor) -> Tensor:
    """Homogeneous form divided by ``|q|^2``: the rotation of ``q / |q|``, NaN for ``q = 0``."""
    if is_small(q, 4, gpu_share=4):
        # Few rotations: cost is per-operation dispatch, so use 4 ops: the outer product, one
        # small matmul against the constant table, a division (NOTES: 5-10 us an op at N = 1).
        h = contract(outer_product(q, q), "homogeneous", HOMOGENEOUS)
        return (h[..., :9] / h[..., 9:]).unflatten(-1, (3, 3))
    if planar(q, 4, _PLANAR_SHARE):
        return closed_form.apply(_QUAT_TO_MATRIX_PLANAR, q)
    # Many (compiled: one fused loop): the outer product's (N, 16) buffer costs more than it saves.
    return quat_columns_to_matrix(q.unbind(-1))


def quat_columns_to_matrix(q) -> Tensor:
    """:func:`quat_to_matrix_unchecked` of a quaternion's four columns ``(w, x, y, z)``: what a
    compiled kernel that computes a quaternion first passes on, so that inductor fuses both into one
    loop (a stack of the quaternion between them is an ``(N, 4)`` buffer written and read back)."""
    w, x, y, z = q
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
    if (out := quat_to_matrix_unchecked.at_one_row(q)) is not None:
        return out
    q, dtype = prepare(q, "quat_to_matrix", "q", (4,))
    return restore(quat_to_matrix_unchecked(q), dtype)


def _shepperd_tables():
    """``vals = R.flatten() @ T + c`` holds ``(4w^2, 4x^2, 4y^2, 4z^2, 4wx, 4wy, 4wz, 4xy, 4xz, 4yz)``;
    row ``k`` of ``ROWS`` indexes the entries of ``4 q_k q`` in it."""
    names = ["r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22"]
    columns = [
        {"r00": 1, "r11": 1, "r22": 1}, {"r00": 1, "r11": -1, "r22": -1},
        {"r00": -1, "r11": 1, "r22": -1}, {"r00": -1, "r11": -1, "r22": 1},
        {"r21": 1, "r12": -1}, {"r02": 1, "r20": -1}, {"r10": 1, "r01": -1},
        {"r10": 1, "r01": 1}, {"r02": 1, "r20": 1}, {"r21": 1, "r12": 1},
    ]
    table = [[float(col.get(name, 0)) for col in columns] for name in names]
    offset = [1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    rows = [[0, 4, 5, 6], [4, 1, 7, 8], [5, 7, 2, 9], [6, 8, 9, 3]]
    return table, offset, rows


_SHEPPERD, _SHEPPERD_OFFSET, _SHEPPERD_ROWS = _shepperd_tables()


def _lookup(table: Tensor, index: Tensor) -> Tensor:
    """``table[index]``; under ``torch.func`` as ``index_select``, which ``vmap(jacrev)`` batches
    (advanced indexing by a batched index it does not; elsewhere indexing is 2 dispatches fewer)."""
    if _transformed():
        return table.index_select(0, index.reshape(-1)).view(index.shape + table.shape[1:])
    return table[index]


def _shepperd_parts(R: Tensor):
    vals = contract(R.flatten(-2), "shepperd", _SHEPPERD) + constant("shepperd_offset", _SHEPPERD_OFFSET, R)
    best = vals[..., :4].argmax(-1)
    row = vals.gather(-1, _lookup(constant("shepperd_rows", _SHEPPERD_ROWS, best), best))
    # Normalise and make it canonical (w >= 0; see standardize_sign) with one multiplication.
    scale = standardize_sign(row, torch.rsqrt((row * row).sum(-1, keepdim=True)))
    return row * scale, best, scale


def _matrix_to_quat_small(R: Tensor) -> Tensor:
    return _shepperd_parts(R)[0]


# d row / d R for each of Shepperd's four choices: the table's columns that row gathers, (4, 9, 4)
_SHEPPERD_ROW_JACOBIANS = [[[_SHEPPERD[m][k] for k in rows] for m in range(9)] for rows in _SHEPPERD_ROWS]


def _matrix_to_quat_with_jacobian(R: Tensor):
    q, best, scale = _shepperd_parts(R)
    # q = row s with s = sign / |row|: dq = s (I - q q^T) d row, and d row / dR is a table lookup
    d_row = _lookup(constant("shepperd_row_jacobians", _SHEPPERD_ROW_JACOBIANS, R), best)  # (..., 9, 4)
    along_q = (d_row * q.unsqueeze(-2)).sum(-1, keepdim=True)
    return q, torch.addcmul(d_row, along_q, q.unsqueeze(-2), value=-1.0) * scale.unsqueeze(-1)


_MATRIX_TO_QUAT = jacobian_rule(_matrix_to_quat_small, _matrix_to_quat_with_jacobian)


@kernel(blocked_row_dims=(2,), compiled_from_rows=512, one_row=OneRow("matrix_to_quat", (9,), (4,)), vector_bits=256)
def matrix_to_quat_unchecked(R: Tensor) -> Tensor:
    """Shepperd's method (1978), branch-free, returning ``w >= 0``.

    Each of ``4w^2, 4x^2, 4y^2, 4z^2`` is a linear function of R's diagonal; the largest of them
    is at least 1, so dividing the matching row of the symmetric matrix ``4 q q^T`` by its norm
    never loses precision (unlike the trace formula near 180 degrees). The choice is made with
    ``argmax`` and ``gather``, so there is no data-dependent branch and no device sync; all ten
    distinct entries of ``4 q q^T`` come from one small matmul.
    """
    if torch.compiler.is_compiling() or planar(R, 9, _SHEPPERD_PLANAR_SHARE):
        return _shepperd_columnwise(R)
    if is_small(R, 9, share=1 / 64, gpu_share=0.25):  # the looked-up (..., 9, 4) Jacobians pay up to ~100 rows
        return closed_form.apply(_MATRIX_TO_QUAT, R)
    return _matrix_to_quat_small(R)


def _shepperd_columnwise(R: Tensor, raw_columns: bool = False):
    """:func:`matrix_to_quat_unchecked` column by column: for ``torch.compile``, which fuses it
    into one vectorised loop (a ``gather`` from a computed buffer would not fuse), and for large
    eager CPU batches (contiguous columns, the 10 sums in one matmul; 2.5x fewer passes than the
    table path's argmax and gather). ``raw_columns``: the four columns of the chosen row ``4 q_k q``
    itself, neither normalised nor sign-standardised, for a next formula that depends on neither
    (matrix -> axis-angle's traces, :func:`torchquat._dispatch.compiled_without_gradient`)."""
    vals = columns(R.flatten(-2), _SHEPPERD, "shepperd", _SHEPPERD_OFFSET, _SHEPPERD_PLANAR_SHARE)
    compiling = torch.compiler.is_compiling()
    best, row = vals[0], [vals[i] for i in _SHEPPERD_ROWS[0]]
    for k in range(1, 4):  # the first largest wins, as argmax's
        if compiling:  # (inductor's where is a branch-free blend)
            take = vals[k] > best
            best = torch.where(take, vals[k], best)
            row = [torch.where(take, vals[i], r) for i, r in zip(_SHEPPERD_ROWS[k], row)]
        else:  # an eager where on a coin toss mispredicts a branch per element; lerp's weights 0 and 1 return either end exactly
            take = (vals[k] > best).to(best.dtype)
            best = torch.maximum(best, vals[k])
            row = [torch.lerp(r, vals[i], take) for i, r in zip(_SHEPPERD_ROWS[k], row)]
    if raw_columns:  # (|row| = 4 |q_k| lies in [2, 4]: nothing to fear from its scale)
        return row
    w, x, y, z = row
    key = torch.add(torch.add(torch.add(torch.sign(z), torch.sign(y), alpha=2.0), torch.sign(x), alpha=4.0),
                    torch.sign(w), alpha=8.0)  # standardize_sign's key: w >= 0, then the first non-zero
    scale = torch.rsqrt(sum_of_squares(row))
    scale = scale * (torch.where(key < 0, -1.0, 1.0) if compiling else torch.copysign(constant("one", 1.0, key), key))
    buffer = plane_buffer(4, row, _SHEPPERD_PLANAR_SHARE)  # (forward only: autograd refuses out=)
    q = [torch.mul(c, scale, out=slot(buffer, i)) for i, c in enumerate(row)]
    return rows(q if buffer is None else buffer, share=_SHEPPERD_PLANAR_SHARE)


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
    if (out := matrix_to_quat_unchecked.at_one_row(R)) is not None:
        return out
    R, dtype = prepare(R, "matrix_to_quat", "R", (3, 3))
    return restore(matrix_to_quat_unchecked(R), dtype)
