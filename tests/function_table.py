"""Every public function with a way to make generic and singular inputs for it.

Tests that must hold for *every* function (gradcheck, finite gradients, compile, vmap, purity,
row independence, dtypes) parametrize over this table, so a failure names its function.
"""

import math

import torch
from torch.utils._python_dispatch import TorchDispatchMode

import torchquat as tq
from rotation_samples import CONVENTIONS, all_singular, cube_rotations, lock_angles

F64 = torch.float64


def _gen(seed):
    return torch.Generator().manual_seed(seed)


def quats(n=6, seed=0):
    return torch.randn(n, 4, generator=_gen(seed), dtype=F64)


def unit_quats(n=6, seed=0):
    q = quats(n, seed)
    return q / q.norm(dim=-1, keepdim=True)


def matrices(n=6, seed=0):
    return tq.quat_to_matrix(unit_quats(n, seed))


def vectors(n=6, seed=0):
    return torch.randn(n, 3, generator=_gen(seed), dtype=F64)


def singular_quats():
    return torch.cat([all_singular(), tq.matrix_to_quat(cube_rotations())])


def singular_axis_angles():
    axes = torch.eye(3, dtype=F64)
    return torch.cat([torch.zeros(1, 3, dtype=F64), axes * 1e-9, axes * math.pi, -axes * math.pi,
                      axes * 2 * math.pi, tq.quat_to_axis_angle(singular_quats())])


# name -> (function of a tuple of tensors, generic inputs, singular inputs)
UNARY = {
    "quat_to_matrix": (tq.quat_to_matrix, quats, singular_quats),
    "matrix_to_quat": (tq.matrix_to_quat, matrices, lambda: tq.quat_to_matrix(singular_quats())),
    "axis_angle_to_quat": (tq.axis_angle_to_quat, vectors, singular_axis_angles),
    "quat_to_axis_angle": (tq.quat_to_axis_angle, quats, singular_quats),
    "axis_angle_to_matrix": (tq.axis_angle_to_matrix, vectors, singular_axis_angles),
    "matrix_to_axis_angle": (tq.matrix_to_axis_angle, matrices, lambda: tq.quat_to_matrix(singular_quats())),
    "rot6d_to_matrix": (tq.rot6d_to_matrix, lambda n=6, seed=0: torch.randn(n, 6, generator=_gen(seed), dtype=F64),
                        lambda: tq.matrix_to_rot6d(tq.quat_to_matrix(singular_quats()))),
    "matrix_to_rot6d": (tq.matrix_to_rot6d, matrices, lambda: tq.quat_to_matrix(singular_quats())),
    "rot9d_to_matrix": (tq.rot9d_to_matrix, lambda n=6, seed=0: torch.randn(n, 9, generator=_gen(seed), dtype=F64),
                        lambda: tq.quat_to_matrix(singular_quats()).flatten(-2)),
    "quat_conjugate": (tq.quat_conjugate, quats, singular_quats),
    "quat_inverse": (tq.quat_inverse, quats, singular_quats),
    "quat_normalize": (tq.quat_normalize, quats, singular_quats),
    "quat_standardize": (tq.quat_standardize, quats, singular_quats),
    "quat_wxyz_to_xyzw": (tq.quat_wxyz_to_xyzw, quats, singular_quats),
    "quat_xyzw_to_wxyz": (tq.quat_xyzw_to_wxyz, quats, singular_quats),
    "quat_from_jpl": (tq.quat_from_jpl, quats, singular_quats),
    "quat_to_jpl": (tq.quat_to_jpl, quats, singular_quats),
}

for _c in CONVENTIONS:
    _locks = lambda c=_c: lock_angles(c, n=2)[0]
    _lock_quats = lambda c=_c: torch.cat([tq.euler_to_quat(lock_angles(c, n=2)[0], c), singular_quats()])
    UNARY[f"euler_to_quat[{_c}]"] = (lambda a, c=_c: tq.euler_to_quat(a, c), vectors, _locks)
    UNARY[f"euler_to_matrix[{_c}]"] = (lambda a, c=_c: tq.euler_to_matrix(a, c), vectors, _locks)
    UNARY[f"quat_to_euler[{_c}]"] = (lambda q, c=_c: tq.quat_to_euler(q, c), unit_quats, _lock_quats)
    UNARY[f"matrix_to_euler[{_c}]"] = (lambda R, c=_c: tq.matrix_to_euler(R, c), matrices,
                                       lambda q=_lock_quats: tq.quat_to_matrix(q()))


def _distance_pairs_q():
    q = singular_quats()
    half = tq.quat_multiply(q, torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=F64))  # exactly pi apart
    return (torch.cat([q, q, q]), torch.cat([q, -q, half]))


BINARY = {
    "quat_multiply": (tq.quat_multiply, lambda: (quats(seed=1), quats(seed=2)), lambda: (singular_quats(), singular_quats().flip(0))),
    "quat_rotate": (tq.quat_rotate, lambda: (quats(seed=1), vectors(seed=2)), lambda: (singular_quats(), vectors(len(singular_quats())))),
    "quat_slerp": (lambda a, b: tq.quat_slerp(a, b, 0.3), lambda: (unit_quats(seed=1), unit_quats(seed=2)),
                   lambda: (torch.cat([singular_quats()] * 2), torch.cat([singular_quats(), -singular_quats()]))),
    "quat_geodesic_distance": (tq.quat_geodesic_distance, lambda: (unit_quats(seed=1), unit_quats(seed=2)), _distance_pairs_q),
    "matrix_geodesic_distance": (tq.matrix_geodesic_distance, lambda: (matrices(seed=1), matrices(seed=2)),
                                 lambda: tuple(tq.quat_to_matrix(x) for x in _distance_pairs_q())),
}

ALL = {**{k: (lambda *xs, f=f: f(*xs), lambda g=g: (g(),), lambda s=s: (s(),)) for k, (f, g, s) in UNARY.items()},
       **BINARY}


def same_output(name, a, b, atol):
    """Equal to ``atol``; Euler angles modulo 2 pi (a half turn may come out as pi or -pi)."""
    difference = a - b
    if "to_euler" in name:
        difference = torch.remainder(difference + torch.pi, 2 * torch.pi) - torch.pi
    return bool((difference.abs() <= atol).all())


def off_kink(name, value, grads, other_grads):
    """Gradients of both paths restricted to rows where they are defined: a distance of pi is a
    maximum with a kink, and which one-sided gradient (or 0) comes out there follows rounding."""
    if "distance" not in name:
        return grads, other_grads
    keep = (value < torch.pi - 1e-6).detach()
    assert keep.sum() > 0.5 * keep.numel()
    return [g[keep] for g in grads], [g[keep] for g in other_grads]


def assert_paths_agree(name, singular_inputs, out, ref, grads, ref_grads, atol, grad_atol, grad_rtol=0.0):
    """Two evaluation paths of one function (small/large batch, compiled/eager) agree.

    Gradients must be finite on both. Euler angles are compared as the rotations they make: next
    to lock single angles are ill-conditioned (rounding moves them, not the rotation), and exactly
    at lock the middle angle has a kink whose one-sided gradient follows the rounding, so their
    gradients are compared on generic inputs only; distances off their maximum (see off_kink).
    """
    assert all(torch.isfinite(g).all() for g in (*grads, *ref_grads))
    if "to_euler" in name:
        convention = name[-4:-1]
        assert torch.allclose(tq.euler_to_matrix(out, convention), tq.euler_to_matrix(ref, convention), atol=1e-13)
        if singular_inputs:
            return
    else:
        assert same_output(name, out.nan_to_num(7.0), ref.nan_to_num(7.0), atol)
    grads, ref_grads = off_kink(name, ref, grads, ref_grads)
    assert all(torch.allclose(g, r, atol=grad_atol, rtol=grad_rtol) for g, r in zip(grads, ref_grads))


def compiled_against_eager(fn, inputs):
    """``fn``'s output and input gradients of ``out.sum()`` with the compiled kernels on (the
    caller switches them on), then off: ``(out, grads, eager_out, eager_grads)``."""
    leaves = tuple(x.detach().clone().requires_grad_() for x in inputs)
    out = fn(*leaves)
    grads = torch.autograd.grad(out.sum(), leaves)
    tq.use_compiled_kernels(False)
    try:
        eager_leaves = tuple(x.detach().clone().requires_grad_() for x in inputs)
        ref = fn(*eager_leaves)
        ref_grads = torch.autograd.grad(ref.sum(), eager_leaves)
    finally:
        tq.use_compiled_kernels(True)
    return out.detach(), grads, ref.detach(), ref_grads


class DispatchRecorder(TorchDispatchMode):
    """Inside ``with DispatchRecorder() as recorder:``, ``recorder.names`` lists the ATen operations
    dispatched, in order (``func.overloadpacket`` names: "mm", "stack", ...)."""

    def __init__(self):
        super().__init__()
        self.names = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.names.append(func.overloadpacket.__name__)
        return func(*args, **(kwargs or {}))
