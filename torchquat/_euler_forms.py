"""Quaternion or matrix to Euler angles: Bernardes and Viollet (2022) as quadratic forms.

Bernardes and Viollet, "Quaternion to Euler angles conversion: A direct, general and
computationally efficient method", PLoS ONE 17(11), 2022, compute every convention from a
permuted quaternion ``(a, b, c, d)``. Here each of their angles is one ``atan2`` of two quadratic
forms in ``(a, b, c, d)`` (see :func:`_build_forms_tables`). Quadratic forms of ``q`` are linear
in ``q q^T`` and, for a unit ``q``, in R's entries, so one table per convention serves both
inputs. Two evaluations give the same angles to rounding: ``torchquat._euler_small`` (few
dispatches and a closed-form backward: small batches) and :func:`angles_columnwise` (1-D
columns: large batches and ``torch.compile``), whose eager rules for quaternions and matrices
(:data:`QUAT_TO_EULER_PLANAR`, :data:`MATRIX_TO_EULER_COLUMNWISE`) live here too, with their
closed-form backward (:func:`forms_gradient`).
"""

import math
from typing import Optional

import torch
from torch import Tensor

from ._closed_form import Rule, traced_rule
from ._math import bilinear, bilinear_terms, constant, literal, safe_sqrt, sparse_columns, zero_to_inf
from ._polynomials import atan2
from ._planes import columns, combinations, plane_buffer, rows, slot
from .conventions import EULER_CONVENTIONS, EulerConvention
from .matrix import _SHEPPERD, _SHEPPERD_OFFSET, _SHEPPERD_ROWS


def abcd_table(conv: EulerConvention):
    """Bernardes and Viollet's permuted quaternion ``(a, b, c, d) = q @ P`` and the sign.

    The method works on extrinsic sequences; an intrinsic one is the reversed extrinsic one
    with its angles reversed. A Tait-Bryan sequence is rotated onto the proper-Euler form by
    the fixed 90-degree change ``a = w - q_j`` etc. and its middle angle shifted by pi/2.
    The change is linear in ``q``, so it is one 4 x 4 matrix per convention.
    """
    i, j, k = conv.axes if not conv.intrinsic else conv.axes[::-1]
    if conv.symmetric:
        k = 3 - i - j
    sign = (i - j) * (j - k) * (k - i) // 2  # +1 for an even permutation of xyz, -1 otherwise
    w, qi, qj, qk = 0, i + 1, j + 1, k + 1  # rows of P: which input component
    if conv.symmetric:
        columns = [{w: 1}, {qi: 1}, {qj: 1}, {qk: sign}]
    else:
        columns = [{w: 1, qj: -1}, {qi: 1, qk: sign}, {qj: 1, w: 1}, {qk: sign, qi: -1}]
    table = [[float(col.get(row, 0)) for col in columns] for row in range(4)]
    return table, sign


ABCD = {name: abcd_table(conv) for name, conv in EULER_CONVENTIONS.items()}

# Where each product q_i q_j sits among Shepperd's ten entries of 4 q q^T (see matrix.py).
_PAIR_SLOT = {(i, j): _SHEPPERD_ROWS[i][j] for i in range(4) for j in range(4)}


def _build_forms_tables(name: str):
    """The 14 quadratic forms in ``(a, b, c, d)`` that give the angles, as linear maps of
    ``q q^T`` (16 x 14) and of ``R`` (9 x 14 plus an offset, using ``|q| = 1``).

    Bernardes and Viollet's angles (extrinsic order) are ``t1 = atan2(b, a) - atan2(d, c)``,
    ``t3 = atan2(b, a) + atan2(d, c)`` and ``t2 = 2 atan2(|(c, d)|, |(a, b)|)``. By the
    angle-sum identities each is an ``atan2`` of two quadratic forms: ``t1 = atan2(bc - ad,
    ac + bd)``, ``t2 = atan2(2h, |ab|^2 - |cd|^2)`` with ``h = |(a, b)| |(c, d)|``, the norm of
    ``t1``'s pair, and the well-conditioned double angles ``2 atan2(b, a) = atan2(2ab, a^2 - b^2)``
    and ``2 atan2(d, c) = atan2(2cd, c^2 - d^2)``. Near lock ``t1`` and ``t3`` are each
    ill-conditioned but their sum (middle near 0) or difference (near pi) is not, so ``t3`` is
    formed as ``D -+ t1`` from the dominant double angle ``D``: the returned angles then
    reproduce the rotation to rounding right up to the lock. Quadratic forms of ``q`` are
    linear in ``R``, so a matrix needs no quaternion and no square root. The lock test (middle
    angle within ``eps`` of 0 or pi) is ``sin(t2) <= sin(eps)``, that is
    ``2h <= sin(eps) (|ab|^2 + |cd|^2)``: no cancellation near lock, so an exact lock is caught
    in float32 too.

    Columns: 0-1 ``t1`` (times 2, so the pair's norm is ``2h``); 2-3 and 4-5 the double angles
    ``2 atan2(b, a)`` and ``2 atan2(d, c)`` (times the Tait-Bryan sign); 6-7 and 8-9 ``t1`` at
    lock near 0 and near pi (extrinsic only: SciPy's rule puts the rotation in the first
    letter's angle, which is ``t1`` there and ``t3`` for intrinsic); 10-11 ``(|ab|^2, |cd|^2)``; 12 the middle angle's other argument (``Z = |ab|^2 - |cd|^2``, or ``-Z``
    for Tait-Bryan, whose middle ``atan2(2h, Z) - pi/2`` is ``atan2(-Z, 2h)``); 13 ``|abcd|^2``.
    """
    conv = EULER_CONVENTIONS[name]
    P, sign = ABCD[name]
    tb = 1 if conv.symmetric else sign  # Tait-Bryan third angle's sign
    a, b, c, d = range(4)

    def form(*terms):  # terms: (coefficient, u, v) for coefficient * u * v over (a, b, c, d)
        M = [[0.0] * 4 for _ in range(4)]
        for coef, u, v in terms:
            M[u][v] += coef / 2.0
            M[v][u] += coef / 2.0
        return M

    zero = form()
    z_sign = 1 if conv.symmetric else -1
    forms = [
        form((2, b, c), (-2, a, d)), form((2, a, c), (2, b, d)),
        form((2 * tb, a, b)), form((1, a, a), (-1, b, b)),
        form((2 * tb, c, d)), form((1, c, c), (-1, d, d)),
        zero if conv.intrinsic else form((2, a, b)), zero if conv.intrinsic else form((1, a, a), (-1, b, b)),
        zero if conv.intrinsic else form((-2, c, d)), zero if conv.intrinsic else form((1, c, c), (-1, d, d)),
        form((1, a, a), (1, b, b)), form((1, c, c), (1, d, d)),
        form((z_sign, a, a), (z_sign, b, b), (-z_sign, c, c), (-z_sign, d, d)),
        form((1, a, a), (1, b, b), (1, c, c), (1, d, d)),
    ]
    # in q: A = P M P^T; in R: q_i q_j = (R.flatten() @ S + s0)[slot(i, j)] / 4 (Shepperd)
    abcd_table = [[M[u][v] for M in forms] for u in range(4) for v in range(4)]
    quat_table = [[0.0] * len(forms) for _ in range(16)]
    matrix_table = [[0.0] * len(forms) for _ in range(9)]
    offset = [0.0] * len(forms)
    for f, M in enumerate(forms):
        for i in range(4):
            for j in range(4):
                A_ij = sum(P[i][u] * M[u][v] * P[j][v] for u in range(4) for v in range(4))
                quat_table[4 * i + j][f] = A_ij
                slot = _PAIR_SLOT[(i, j)]
                for r in range(9):
                    matrix_table[r][f] += A_ij * _SHEPPERD[r][slot] / 4.0
                offset[f] += A_ij * _SHEPPERD_OFFSET[slot] / 4.0
    return quat_table, matrix_table, offset, tb, abcd_table


_FORMS_TABLES = {name: _build_forms_tables(name) for name in EULER_CONVENTIONS}


def forms_tables(name: str):
    return _FORMS_TABLES[name]


PAIRS = tuple((i, j) for i in range(4) for j in range(i, 4))  # the 10 distinct products u v
_PI_TWO_PI = (math.pi, 2.0 * math.pi)  # (through literal: constants of a compiled loop)


ANGLE_FORMS = (0, 1, 2, 3, 4, 5, 12)
"""The forms :func:`angles_columnwise` reads: ``t1``'s pair, the two double angles' and ``Z``. The
lock pairs (6-9) are the double angles' up to sign, and ``(|ab|^2, |cd|^2)`` (10-11) tell no more
than ``Z``'s sign and ``|abcd|^2`` (13: a quaternion's, or a constant for a matrix) do: every form
left out is a column less in the transposing matmul and in its backward."""


def _columnwise_tables(name: str):
    """Sparse terms: ``(a, b, c, d)`` from q's components, and the forms :data:`ANGLE_FORMS` and
    ``|abcd|^2`` from the 10 products of ``(a, b, c, d)`` (the forms from R's entries:
    :data:`DENSE`, through ``torchquat._planes``)."""
    abcd_table = forms_tables(name)[4]
    pair_table = [[0.0] * len(abcd_table[0]) for _ in PAIRS]
    for p, (u, v) in enumerate(PAIRS):
        for k in range(len(abcd_table[0])):  # M[u][v] + M[v][u] multiplies u v (u != v)
            pair_table[p][k] = abcd_table[4 * u + v][k] * (1 if u == v else 2)
    pair_table = [[row[k] for k in ANGLE_FORMS + (13,)] for row in pair_table]
    return sparse_columns(ABCD[name][0]), sparse_columns(pair_table)


COLUMNWISE = {name: _columnwise_tables(name) for name in EULER_CONVENTIONS}


def _dense_tables(name: str):
    """The forms :data:`ANGLE_FORMS` and ``|abcd|^2`` as one matrix of q's 10 products (10 x 8), and
    the forms from R's entries (9 x 7, with the offset), for the eager path's single matmul
    (torchquat._planes); and a matrix's ``|abcd|^2``, a constant (1, or 2 for Tait-Bryan)."""
    quat_table, matrix_table, offset, _, _ = forms_tables(name)
    pairs = tuple(tuple(quat_table[4 * i + j][f] + (quat_table[4 * j + i][f] if i != j else 0.0)
                        for f in ANGLE_FORMS + (13,)) for i, j in PAIRS)
    return (pairs, tuple(tuple(row[f] for f in ANGLE_FORMS) for row in matrix_table),
            tuple(offset[f] for f in ANGLE_FORMS), offset[13])


DENSE = {name: _dense_tables(name) for name in EULER_CONVENTIONS}


def _lock_test(forms, eps: float, abcd2, values: bool = True):
    """t1's pair and ``Z`` divided by ``|abcd|^2`` when it is a tensor (a quaternion's; see
    :func:`angles_parts`), the scale (or None), ``2h``, and the gimbal-lock mask ``2h <= sin(eps)``:
    the test of the angles and, alone, of :func:`euler_gimbal_lock` (the same rows)."""
    y1, x1, z = forms[0], forms[1], forms[6]
    scale = None
    if isinstance(abcd2, Tensor):
        scale, abcd2 = abcd2, 1.0
        # (0 + y1 / scale: a -0 from strided columns' products becomes +0, so that t1 = atan2(y1, x1)
        # of an exact half turn is +pi, not -pi, as on the matmul paths)
        y1, x1, z = torch.addcdiv(constant("zero", 0.0, y1), y1, scale), x1 / scale, z / scale
    elif torch.compiler.is_compiling() or not y1.is_cpu:  # (fused there; on the CPU eager the
        y1 = y1 + 0.0  # matrices' forms come out of a matmul, which gives +0) the same for a -0
    two_h = (torch.sqrt if values else safe_sqrt)(y1 * y1 + x1 * x1)
    return y1, x1, z, scale, two_h, two_h <= abcd2 * math.sin(eps)  # sin(middle) <= sin(eps), as the small path


def angles_parts(forms, conv: EulerConvention, eps: float, abcd2, out: Optional[Tensor] = None, values: bool = False):
    """The same angles as ``torchquat._euler_small``, written column by column with the tables'
    numbers as literals: for large batches (a handful of passes over 1-D columns instead of
    strided pair tensors) and for ``torch.compile``, which fuses it into one vectorised loop.

    ``forms``: the :data:`ANGLE_FORMS` (their scale is free), ``abcd2``: ``|abcd|^2`` on the same
    scale (a number, or a quaternion's ``|abcd|^2``, a tensor). ``out``: an optional
    ``torchquat._planes.plane_buffer`` of 3 rows for the angles. Returns the three angles and what
    :func:`forms_gradient` needs.

    A quaternion's forms are of order ``|q|^2`` and ``2h`` squares them again, which underflows
    for ``|q|`` below about 1e-77 (float64) or 3e-10 (float32) and would read as gimbal lock; so
    t1's pair and ``Z`` are first divided by ``|abcd|^2`` (three passes, the angles unchanged).
    That also makes ``q = 0``, whose forms are all 0 (a plausible (0, 0, 0)), NaN throughout.

    ``values``: nothing will be differentiated, so the substitutions that keep autograd finite
    (``safe_sqrt``'s, and ``(0, 1)`` for t1's pair at lock) are left out: the same angles bit for
    bit, four passes fewer (and no parts for the backward)."""
    y_zero, x_zero, y_pi, x_pi = forms[2:6]
    y1, x1, z, scale, two_h, locked = _lock_test(forms, eps, abcd2, values)
    near_zero = z >= 0 if conv.symmetric else z <= 0  # |ab| >= |cd|: the small path's test
    tb = forms_tables(conv.name)[3]
    if torch.compiler.is_compiling():  # (inductor's where is a branch-free blend)
        weight = near_zero.to(z.dtype)  # (for a traced rule's backward; a graph that does not read it drops it)

        def pick(if_near_zero, if_near_pi):
            return torch.where(near_zero, if_near_zero, if_near_pi)
        step = torch.where(near_zero, -float(tb), float(tb))
    else:
        # Which double angle (middle near 0 or near pi) is a coin toss per row: an eager `where`
        # on it mispredicts a branch per element (4 ms per 1e6, 6x a lerp), so choose with lerp,
        # whose weights 0 and 1 return either end exactly.
        weight = near_zero.to(z.dtype)

        def pick(if_near_zero, if_near_pi):
            return torch.lerp(if_near_pi, if_near_zero, weight)
        step = weight * (-2.0 * tb) + tb
    final = (lambda i: None) if out is None else out.__getitem__  # (the last passes write into the buffer)
    if values:  # (at lock the discarded atan2 of about (0, 0) is any angle: no gradient to spoil;
        # strided columns are copied, as the wheres would: atan2's vectorised loop, the same bits)
        t1 = torch.where(locked, constant("zero", 0.0, y1), atan2(y1.contiguous(), x1.contiguous()),
                         out=final(2) if conv.intrinsic else None)
    else:
        y1_used, x1_used = torch.where(locked, 0.0, y1), torch.where(locked, 1.0, x1)  # t1 = 0 at lock
        t1 = atan2(y1_used, x1_used, out=final(2) if conv.intrinsic else None)
    if conv.symmetric:  # (2h is a square root: +0.0 or positive, which the compiled polynomial may assume)
        middle = atan2(two_h, z, out=final(1), y_nonnegative=True)
    else:
        middle = atan2(z, two_h, out=final(1), x_nonnegative=True)
    y_double, x_double = pick(y_zero, y_pi), pick(x_zero, x_pi)
    double = atan2(y_double, x_double)
    t3 = torch.addcmul(double, t1, step)  # D - tb t1 near 0, D + tb t1 near pi
    if not conv.intrinsic:  # SciPy's rule moves the rotation into the first angle at lock: there
        # t3 = D, and the lock pair (2ab, a^2 - b^2) or (-2cd, c^2 - d^2) is the double angle's up
        # to sign: -step D, wrapped by the same passes
        t3 = t3 * torch.where(locked, -step, 1.0)
    # into (-pi, pi], branch-free, exact for angles already in it; an exact half turn is +pi on
    # every path (t3 - pi is exact there, and -2 pi / 2 pi exactly -1: no rounding decides). A t3
    # an ulp or two above -pi rounds t3 - pi to -2 pi and comes out as pi plus those ulps: the
    # clamp keeps the range ([-pi, pi] in SPEC; pi is within rounding of the exact -pi + ulps)
    pi, two_pi = literal(_PI_TWO_PI)
    turns = torch.ceil((t3 - pi) / two_pi)
    t3 = torch.clamp_max(torch.sub(t3, turns, alpha=two_pi), pi, out=final(0) if conv.intrinsic else None)
    if conv.intrinsic:
        angles = (t3, middle, t1)
    else:
        zero = constant("zero", 0.0, t3)
        angles = (torch.where(locked, t3, t1, out=final(0)), middle, torch.where(locked, zero, t3, out=final(2)))
    if values:
        return angles, None
    return angles, (y1, x1, y1_used, x1_used, y_double, x_double, two_h, z, locked, weight, step, scale)


def lock_columnwise(forms, eps: float, abcd2) -> Tensor:
    """The gimbal-lock mask of :func:`angles_parts` on the same forms, without the angles."""
    return _lock_test(forms, eps, abcd2)[-1]


def angles_columnwise(forms, conv: EulerConvention, eps: float, abcd2, share: float = 1.0, values: bool = False) -> Tensor:
    """The angles of :func:`angles_parts` side by side; ``share``: as for ``torchquat._planes.rows``;
    ``values``: as for :func:`angles_parts` (where nothing will differentiate them)."""
    return rows(angles_parts(forms, conv, eps, abcd2, values=values)[0], share=share)


def forms_gradient(grad, saved, conv: EulerConvention, out: Optional[Tensor] = None):
    """The gradient of :func:`angles_parts`' angles (``grad``: three columns) with respect to the
    forms, from ``d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)``: about 30 passes where autograd's
    backward through the forward takes about 60. t1 is a constant at lock; the wrap into
    ``[-pi, pi]`` has derivative 1; a pick passes the gradient to the form it took (weight 0 or 1).
    ``out``: an optional ``torchquat._planes.plane_buffer`` of 7 rows to write them into."""
    y1, x1, y1_used, x1_used, y_double, x_double, two_h, z, locked, weight, step, scale = saved
    g_first, g_middle, g_third = grad
    zero = constant("zero", 0.0, g_first)
    if conv.intrinsic:  # (t3, middle, t1), t3 = D + step t1
        g_double = g_first
        g_t1 = torch.where(locked, zero, torch.addcmul(g_third, step, g_first))
    else:  # (t1, or -step t3 at lock; middle; t3, or 0 at lock)
        g_double = torch.where(locked, -step * g_first, g_third)
        g_t1 = torch.addcmul(g_first, step, g_double)  # (0 at lock: step^2 = 1)
    if scale is not None:  # (t1's pair and Z were divided by |abcd|^2: so are their gradients)
        g_t1, g_middle = g_t1 / scale, g_middle / scale
    r1 = g_t1 / torch.addcmul(x1_used * x1_used, y1_used, y1_used)
    r_double = g_double / torch.addcmul(x_double * x_double, y_double, y_double)
    r_middle = g_middle / torch.addcmul(z * z, two_h, two_h)
    slot = (lambda i: None) if out is None else out.__getitem__
    if conv.symmetric:  # middle = atan2(2h, z)
        g_two_h, g_z = r_middle * z, torch.addcmul(zero, r_middle, two_h, value=-1.0, out=slot(6))
    else:  # atan2(z, 2h)
        g_two_h, g_z = torch.addcmul(zero, r_middle, z, value=-1.0), torch.mul(r_middle, two_h, out=slot(6))
    s = g_two_h / zero_to_inf(two_h)  # 2h = |(y1, x1)|: 0 at 2h = 0, as safe_sqrt's gradient
    g_y_double, g_x_double = r_double * x_double, -r_double * y_double
    g_y_zero, g_x_zero = torch.mul(g_y_double, weight, out=slot(2)), torch.mul(g_x_double, weight, out=slot(3))
    return [torch.addcmul(r1 * x1_used, s, y1, out=slot(0)), torch.addcmul(-r1 * y1_used, s, x1, out=slot(1)),
            g_y_zero, g_x_zero, torch.sub(g_y_double, g_y_zero, out=slot(4)), torch.sub(g_x_double, g_x_zero, out=slot(5)), g_z]


# Contiguous columns (measured crossovers, with the closed-form backward): quat -> Euler from 65,536
# rows (its forward is 1.06-1.13x slower at 8-32k); matrix -> Euler from the large path's first
# rows (0.91-0.95 of the strided code's time at 1,100-8,192 rows, forward and forward+backward)
QUAT_TO_EULER_PLANAR_SHARE, MATRIX_TO_EULER_PLANAR_SHARE = 2.0, 1.0 / 32


def _quat_planar_forms(q: Tensor, convention: EulerConvention):
    """q's columns, and the forms and ``|abcd|^2`` from q's 10 products in one matmul."""
    share = QUAT_TO_EULER_PLANAR_SHARE
    components = columns(q, share=share)
    buffer = plane_buffer(len(PAIRS), components, share, output=False)
    products = [torch.mul(components[u], components[v], out=slot(buffer, p)) for p, (u, v) in enumerate(PAIRS)]
    *forms, abcd2 = combinations(products if buffer is None else buffer, DENSE[convention.name][0],
                                 "euler_q_" + convention.name, share=share)
    return components, forms, abcd2


def _quat_to_euler_planar_parts(q: Tensor, convention: EulerConvention, eps: float, values: bool = False):
    """Contiguous columns: the angles, and what the closed-form backward needs (``values``: the
    angles alone, see :func:`angles_parts`)."""
    components, forms, abcd2 = _quat_planar_forms(q, convention)
    # (contiguous planes: atan2 into strided columns runs a scalar loop, slower than any
    # transpose, and its last bit would differ from the differentiable forward's; see rows())
    buffer = plane_buffer(3, forms, QUAT_TO_EULER_PLANAR_SHARE, output=False)
    angles, saved = angles_parts(forms, convention, eps, abcd2, out=buffer, values=values)
    return rows(angles if buffer is None else buffer, share=QUAT_TO_EULER_PLANAR_SHARE), None if values else (*components, *saved)


def quat_lock_planar(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    """The gimbal-lock mask of :data:`QUAT_TO_EULER_PLANAR`: the same forms and test, so the same rows."""
    _, forms, abcd2 = _quat_planar_forms(q, convention)
    return lock_columnwise(forms, eps, abcd2)


def quat_to_euler_planar(q: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    return _quat_to_euler_planar_parts(q, convention, eps)[0]


def _product_gradient_terms(name: str):
    """For the backward of the forms' products: the forms' gradient to the products' (the
    transposed table, 7 x 10), and the bilinear terms of ``d(q_u q_v) = q_v dq_u + q_u dq_v``
    (row ``4 p + v``: the product p's gradient times component v, to component u)."""
    pairs_table = DENSE[name][0]
    transposed = tuple(tuple(row[f] for row in pairs_table) for f in range(len(ANGLE_FORMS)))
    table = [[0.0] * 4 for _ in range(4 * len(PAIRS))]
    for p, (u, v) in enumerate(PAIRS):
        table[4 * p + v][u] += 1.0
        table[4 * p + u][v] += 1.0
    return transposed, bilinear_terms(table, 4)


_PRODUCT_GRADIENT = {name: _product_gradient_terms(name) for name in EULER_CONVENTIONS}


def _quat_to_euler_planar_backward(grad: Tensor, inputs, saved, convention: EulerConvention, eps: float):
    share = QUAT_TO_EULER_PLANAR_SHARE
    components, saved = saved[:4], saved[4:]
    transposed, terms = _PRODUCT_GRADIENT[convention.name]
    g = columns(grad, share=share)
    buffer = plane_buffer(len(ANGLE_FORMS), g, share, output=False)
    g_forms = forms_gradient(g, saved, convention, out=buffer)
    g_products = combinations(g_forms if buffer is None else buffer, transposed, "euler_q_grad_" + convention.name, share=share)
    return (rows(bilinear(g_products, components, terms, out=plane_buffer(4, g_products, share)), share=share),)


QUAT_TO_EULER_PLANAR = Rule(quat_to_euler_planar, _quat_to_euler_planar_parts, _quat_to_euler_planar_backward,
                            lambda q, convention, eps: _quat_to_euler_planar_parts(q, convention, eps, values=True)[0])


def _matrix_columnwise_forms(R: Tensor, convention: EulerConvention):
    """The forms from R's entries (eager CPU: one matmul; else one pass per term), and ``|abcd|^2``."""
    _, table, offset, _ = DENSE[convention.name]  # (the tables: literals through columns())
    abcd2 = literal(DENSE[convention.name])[3]
    return columns(R.flatten(-2), table, "euler_R_" + convention.name, offset, share=MATRIX_TO_EULER_PLANAR_SHARE), abcd2


def matrix_lock_columnwise(R: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    """The gimbal-lock mask of :data:`MATRIX_TO_EULER_COLUMNWISE`: the same forms and test."""
    forms, abcd2 = _matrix_columnwise_forms(R, convention)
    return lock_columnwise(forms, eps, abcd2)


def _matrix_to_euler_columnwise_parts(R: Tensor, convention: EulerConvention, eps: float, values: bool = False):
    """The forms from R's entries (eager CPU: one matmul; else one pass per term); the angles, and
    what the closed-form backward needs (``values``: the angles alone, see :func:`angles_parts`)."""
    forms, abcd2 = _matrix_columnwise_forms(R, convention)
    buffer = plane_buffer(3, forms, MATRIX_TO_EULER_PLANAR_SHARE, output=False)  # (as above)
    angles, saved = angles_parts(forms, convention, eps, abcd2, out=buffer, values=values)
    return rows(angles if buffer is None else buffer, share=MATRIX_TO_EULER_PLANAR_SHARE), saved


def matrix_to_euler_columnwise(R: Tensor, convention: EulerConvention, eps: float) -> Tensor:
    return _matrix_to_euler_columnwise_parts(R, convention, eps)[0]


# the forms' gradient to R's entries: the matrix tables transposed (7 x 9)
_MATRIX_FORMS_TRANSPOSED = {name: tuple(zip(*DENSE[name][1])) for name in EULER_CONVENTIONS}


def _matrix_to_euler_columnwise_backward(grad: Tensor, inputs, saved, convention: EulerConvention, eps: float):
    share = MATRIX_TO_EULER_PLANAR_SHARE
    g = columns(grad, share=share)
    buffer = plane_buffer(len(ANGLE_FORMS), g, share, output=False)
    g_forms = forms_gradient(g, saved, convention, out=buffer)  # the forms are linear in R
    g_R = rows(g_forms if buffer is None else buffer, _MATRIX_FORMS_TRANSPOSED[convention.name],
               "euler_R_grad_" + convention.name, share=share)
    return (g_R.view(inputs[0].shape),)


MATRIX_TO_EULER_COLUMNWISE = Rule(matrix_to_euler_columnwise, _matrix_to_euler_columnwise_parts,
                                   _matrix_to_euler_columnwise_backward,
                                   lambda R, convention, eps: _matrix_to_euler_columnwise_parts(R, convention, eps, values=True)[0])
MATRIX_TO_EULER_TRACED = traced_rule(MATRIX_TO_EULER_COLUMNWISE)
