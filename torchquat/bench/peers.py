"""The peers the benchmark compares: each library's call for each operation.

Every implementation gets the *same* rotations, laid out the way its library expects
(scalar-last quaternions for RoMa, PyPose and SciPy, separate tensors for kornia's Euler
functions, rows instead of columns for pytorch-kinematics' 6D). Layout changes happen once,
outside the timed region; the timed region is exactly the library call (plus, where a library
needs it, what is noted in ``Impl.note``). ``to_tq`` maps an output back to torchquat's layout
for the sanity check, also outside the timed region.
"""

import importlib
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

import torch

from .ops import Impl

__all__ = ["Peer", "PEER_SPECS", "PEER_NAMES", "load_peers"]


def _xyzw(q):
    return q[..., [1, 2, 3, 0]].contiguous()


def _wxyz(q):
    return q[..., [3, 0, 1, 2]]


def _np(t):
    return t.detach().cpu().numpy()


# each builder takes the imported module and returns {op name: Impl}


def _roma(roma) -> Dict[str, Impl]:
    q = lambda d: (_xyzw(d["q"]),)  # noqa: E731
    out_q = _wxyz
    impls = {
        "quat_to_matrix": Impl(roma.unitquat_to_rotmat, q, "roma.unitquat_to_rotmat(q_xyzw)"),
        "matrix_to_quat": Impl(roma.rotmat_to_unitquat, lambda d: (d["R"],), "roma.rotmat_to_unitquat(R)",
                               out_q),
        "quat_rotate": Impl(lambda q_, v: roma.quat_action(q_, v, is_normalized=True),
                            lambda d: (_xyzw(d["q"]), d["v"]),
                            "roma.quat_action(q_xyzw, v, is_normalized=True)"),
        "axis_angle_to_quat": Impl(roma.rotvec_to_unitquat, lambda d: (d["aa"],),
                                   "roma.rotvec_to_unitquat(v)", out_q),
        "quat_to_axis_angle": Impl(roma.unitquat_to_rotvec, q, "roma.unitquat_to_rotvec(q_xyzw)"),
        "axis_angle_to_matrix": Impl(roma.rotvec_to_rotmat, lambda d: (d["aa"],), "roma.rotvec_to_rotmat(v)"),
        "matrix_to_axis_angle": Impl(roma.rotmat_to_rotvec, lambda d: (d["R"],), "roma.rotmat_to_rotvec(R)"),
        "quat_multiply": Impl(roma.quat_product, lambda d: (_xyzw(d["q"]), _xyzw(d["q2"])),
                              "roma.quat_product(p_xyzw, q_xyzw)", out_q),
        # special_gramschmidt orthonormalises the first two *columns* of a 3 x N matrix.
        "rot6d_to_matrix": Impl(roma.special_gramschmidt,
                                lambda d: (d["x6"].unflatten(-1, (2, 3)).mT.contiguous(),),
                                "roma.special_gramschmidt(M_3x2)"),
        "quat_geodesic_distance": Impl(roma.unitquat_geodesic_distance,
                                       lambda d: (_xyzw(d["q"]), _xyzw(d["q2"])),
                                       "roma.unitquat_geodesic_distance(q1_xyzw, q2_xyzw)"),
        "matrix_geodesic_distance": Impl(roma.rotmat_geodesic_distance, lambda d: (d["R"], d["R2"]),
                                         "roma.rotmat_geodesic_distance(R1, R2)"),
    }
    for seq in ("ZYX", "ZXZ"):
        e = lambda d, s=seq: (d["e_" + s],)  # noqa: E731
        impls["euler_to_quat_" + seq] = Impl(lambda a, s=seq: roma.euler_to_unitquat(s, a), e,
                                             f'roma.euler_to_unitquat("{seq}", e)', out_q)
        impls["quat_to_euler_" + seq] = Impl(lambda a, s=seq: roma.unitquat_to_euler(s, a), q,
                                             f'roma.unitquat_to_euler("{seq}", q_xyzw)')
        impls["euler_to_matrix_" + seq] = Impl(lambda a, s=seq: roma.euler_to_rotmat(s, a), e,
                                               f'roma.euler_to_rotmat("{seq}", e)')
        impls["matrix_to_euler_" + seq] = Impl(lambda a, s=seq: roma.rotmat_to_euler(s, a),
                                               lambda d: (d["R"],), f'roma.rotmat_to_euler("{seq}", R)')
    return impls


def _kornia(kornia) -> Dict[str, Impl]:
    C = kornia.geometry.conversions
    return {
        "quat_to_matrix": Impl(C.quaternion_to_rotation_matrix, lambda d: (d["q"],),
                               "kornia...quaternion_to_rotation_matrix(q_wxyz)"),
        "matrix_to_quat": Impl(C.rotation_matrix_to_quaternion, lambda d: (d["R"],),
                               "kornia...rotation_matrix_to_quaternion(R)"),
        # kornia's Euler functions take and return separate tensors: (roll, pitch, yaw) about
        # x, y, z, i.e. intrinsic ZYX with the angles in reverse order.
        "euler_to_quat_ZYX": Impl(C.quaternion_from_euler, lambda d: tuple(d["e_ZYX"].flip(-1).unbind(-1)),
                                  "kornia...quaternion_from_euler(roll, pitch, yaw)",
                                  lambda out: torch.stack(out, -1)),
        "quat_to_euler_ZYX": Impl(C.euler_from_quaternion, lambda d: tuple(d["q"].unbind(-1)),
                                  "kornia...euler_from_quaternion(w, x, y, z)",
                                  lambda out: torch.stack(out[::-1], -1)),
        "axis_angle_to_quat": Impl(C.axis_angle_to_quaternion, lambda d: (d["aa"],),
                                   "kornia...axis_angle_to_quaternion(v)"),
        "quat_to_axis_angle": Impl(C.quaternion_to_axis_angle, lambda d: (d["q"],),
                                   "kornia...quaternion_to_axis_angle(q_wxyz)"),
        "axis_angle_to_matrix": Impl(C.axis_angle_to_rotation_matrix, lambda d: (d["aa"],),
                                     "kornia...axis_angle_to_rotation_matrix(v)"),
        "matrix_to_axis_angle": Impl(C.rotation_matrix_to_axis_angle, lambda d: (d["R"],),
                                     "kornia...rotation_matrix_to_axis_angle(R)"),
    }


def _pytorch_kinematics(pk) -> Dict[str, Impl]:
    T = pk.transforms
    impls = {
        "quat_to_matrix": Impl(T.quaternion_to_matrix, lambda d: (d["q"],), "pk.quaternion_to_matrix(q)"),
        "matrix_to_quat": Impl(T.matrix_to_quaternion, lambda d: (d["R"],), "pk.matrix_to_quaternion(R)"),
        "quat_rotate": Impl(T.quaternion_apply, lambda d: (d["q"], d["v"]), "pk.quaternion_apply(q, v)"),
        "axis_angle_to_quat": Impl(T.axis_angle_to_quaternion, lambda d: (d["aa"],),
                                   "pk.axis_angle_to_quaternion(v)"),
        "quat_to_axis_angle": Impl(T.quaternion_to_axis_angle, lambda d: (d["q"],),
                                   "pk.quaternion_to_axis_angle(q)"),
        "axis_angle_to_matrix": Impl(T.so3_exp_map, lambda d: (d["aa"],), "pk.so3_exp_map(v)"),
        "matrix_to_axis_angle": Impl(T.matrix_to_axis_angle, lambda d: (d["R"],), "pk.matrix_to_axis_angle(R)"),
        # quaternion_multiply also standardises the sign; the raw product is torchquat's operation.
        "quat_multiply": Impl(T.quaternion_raw_multiply, lambda d: (d["q"], d["q2"]),
                              "pk.quaternion_raw_multiply(p, q)"),
        # pytorch-kinematics' 6D is the first two *rows*: the same numbers give the transpose.
        "rot6d_to_matrix": Impl(T.rotation_6d_to_matrix, lambda d: (d["x6"],),
                                "pk.rotation_6d_to_matrix(x)", lambda out: out.mT),
        "quat_geodesic_distance": Impl(T.quaternion_angular_distance, lambda d: (d["q"], d["q2"]),
                                       "pk.quaternion_angular_distance(q1, q2)"),
        # angle of R1 R2^T, the same angle as R1^T R2
        "matrix_geodesic_distance": Impl(T.so3_relative_angle, lambda d: (d["R"], d["R2"]),
                                         "pk.so3_relative_angle(R1, R2)"),
    }
    for seq in ("ZYX", "ZXZ"):
        e = lambda d, s=seq: (d["e_" + s],)  # noqa: E731
        axes = "r" + seq.lower()  # transformations.py: 'r' = rotating (intrinsic) frame
        impls["euler_to_quat_" + seq] = Impl(
            lambda a, ax=axes: T.quaternion_from_euler(a.clone(), ax), e,
            f'pk.quaternion_from_euler(e.clone(), "{axes}")',
            note="clone inside the timed region: quaternion_from_euler halves its input in place")
        impls["euler_to_matrix_" + seq] = Impl(lambda a, s=seq: T.euler_angles_to_matrix(a, s), e,
                                               f'pk.euler_angles_to_matrix(e, "{seq}")')
        impls["matrix_to_euler_" + seq] = Impl(lambda R, s=seq: T.matrix_to_euler_angles(R, s),
                                               lambda d: (d["R"],), f'pk.matrix_to_euler_angles(R, "{seq}")')
    return impls


def _pypose(pp) -> Dict[str, Impl]:
    # Inputs are LieTensors built outside the timed region (pp.SO3(q_xyzw), pp.so3(v)).
    so3q = lambda d: (pp.SO3(_xyzw(d["q"])),)  # noqa: E731
    out_q = lambda out: _wxyz(out.tensor())  # noqa: E731
    rpy = lambda d: (d["e_ZYX"].flip(-1).contiguous(),)  # noqa: E731  (roll, pitch, yaw)
    return {
        "quat_to_matrix": Impl(lambda x: x.matrix(), so3q, "pp.SO3(q_xyzw).matrix()"),
        "matrix_to_quat": Impl(lambda R: pp.mat2SO3(R, check=False), lambda d: (d["R"],),
                               "pp.mat2SO3(R, check=False)", out_q),
        "euler_to_quat_ZYX": Impl(pp.euler2SO3, rpy, "pp.euler2SO3(rpy)", out_q),
        "quat_to_euler_ZYX": Impl(lambda x: x.euler(), so3q, "pp.SO3(q_xyzw).euler()",
                                  lambda out: out.flip(-1)),
        "euler_to_matrix_ZYX": Impl(lambda a: pp.euler2SO3(a).matrix(), rpy, "pp.euler2SO3(rpy).matrix()"),
        "matrix_to_euler_ZYX": Impl(lambda R: pp.mat2SO3(R, check=False).euler(), lambda d: (d["R"],),
                                    "pp.mat2SO3(R, check=False).euler()", lambda out: out.flip(-1)),
        "quat_rotate": Impl(lambda x, v: x.Act(v), lambda d: (pp.SO3(_xyzw(d["q"])), d["v"]),
                            "pp.SO3(q_xyzw).Act(v)"),
        "axis_angle_to_quat": Impl(lambda x: x.Exp(), lambda d: (pp.so3(d["aa"]),), "pp.so3(v).Exp()", out_q),
        "quat_to_axis_angle": Impl(lambda x: x.Log(), so3q, "pp.SO3(q_xyzw).Log()",
                                   lambda out: out.tensor()),
        "axis_angle_to_matrix": Impl(lambda x: x.matrix(), lambda d: (pp.so3(d["aa"]),), "pp.so3(v).matrix()"),
        "matrix_to_axis_angle": Impl(lambda R: pp.mat2SO3(R, check=False).Log(), lambda d: (d["R"],),
                                     "pp.mat2SO3(R, check=False).Log()", lambda out: out.tensor()),
        "quat_multiply": Impl(lambda a, b: a * b, lambda d: (pp.SO3(_xyzw(d["q"])), pp.SO3(_xyzw(d["q2"]))),
                              "pp.SO3(p_xyzw) * pp.SO3(q_xyzw)", out_q),
        "quat_geodesic_distance": Impl(lambda a, b: pp.geodesic_loss(a, b, reduction="none"),
                                       lambda d: (pp.SO3(_xyzw(d["q"])), pp.SO3(_xyzw(d["q2"]))),
                                       'pp.geodesic_loss(SO3(q1), SO3(q2), reduction="none")'),
    }


def _scipy(Rotation) -> Dict[str, Impl]:
    """SciPy on NumPy arrays: forward only, constructing the Rotation is part of the call."""
    R_ = Rotation
    impls = {
        "quat_to_matrix": (lambda q: R_.from_quat(q, scalar_first=True).as_matrix(), ("q",),
                           "from_quat(q, scalar_first=True).as_matrix()"),
        "matrix_to_quat": (lambda m: R_.from_matrix(m).as_quat(scalar_first=True), ("R",),
                           "from_matrix(R).as_quat(scalar_first=True)"),
        "quat_rotate": (lambda q, v: R_.from_quat(q, scalar_first=True).apply(v), ("q", "v"),
                        "from_quat(q, scalar_first=True).apply(v)"),
        "axis_angle_to_quat": (lambda v: R_.from_rotvec(v).as_quat(scalar_first=True), ("aa",),
                               "from_rotvec(v).as_quat(scalar_first=True)"),
        "quat_to_axis_angle": (lambda q: R_.from_quat(q, scalar_first=True).as_rotvec(), ("q",),
                               "from_quat(q, scalar_first=True).as_rotvec()"),
        "axis_angle_to_matrix": (lambda v: R_.from_rotvec(v).as_matrix(), ("aa",), "from_rotvec(v).as_matrix()"),
        "matrix_to_axis_angle": (lambda m: R_.from_matrix(m).as_rotvec(), ("R",), "from_matrix(R).as_rotvec()"),
        "quat_multiply": (lambda p, q: (R_.from_quat(p, scalar_first=True) * R_.from_quat(q, scalar_first=True))
                          .as_quat(scalar_first=True), ("q", "q2"), "(from_quat(p) * from_quat(q)).as_quat()"),
        "quat_geodesic_distance": (lambda a, b: (R_.from_quat(a, scalar_first=True).inv()
                                                 * R_.from_quat(b, scalar_first=True)).magnitude(),
                                   ("q", "q2"), "(from_quat(q1).inv() * from_quat(q2)).magnitude()"),
        "matrix_geodesic_distance": (lambda a, b: (R_.from_matrix(a).inv() * R_.from_matrix(b)).magnitude(),
                                     ("R", "R2"), "(from_matrix(R1).inv() * from_matrix(R2)).magnitude()"),
    }
    for seq in ("ZYX", "ZXZ"):
        impls["euler_to_quat_" + seq] = (lambda e, s=seq: R_.from_euler(s, e).as_quat(scalar_first=True),
                                         ("e_" + seq,), f'from_euler("{seq}", e).as_quat(scalar_first=True)')
        impls["quat_to_euler_" + seq] = (lambda q, s=seq: R_.from_quat(q, scalar_first=True).as_euler(s),
                                         ("q",), f'from_quat(q, scalar_first=True).as_euler("{seq}")')
        impls["euler_to_matrix_" + seq] = (lambda e, s=seq: R_.from_euler(s, e).as_matrix(), ("e_" + seq,),
                                           f'from_euler("{seq}", e).as_matrix()')
        impls["matrix_to_euler_" + seq] = (lambda m, s=seq: R_.from_matrix(m).as_euler(s), ("R",),
                                           f'from_matrix(R).as_euler("{seq}")')
    out = {}
    for name, (fn, args, call) in impls.items():
        out[name] = Impl(fn, lambda d, a=args: tuple(_np(d[k]) for k in a), "scipy Rotation." + call,
                         lambda o: torch.from_numpy(o), backward=False)
    return out


@dataclass
class Peer:
    name: str         # the --peers identifier and column heading
    module: str       # what to import
    build: Callable   # module -> {op name: Impl}
    torch_peer: bool = True  # False: SciPy, reported in its own column, not a "fastest peer"
    impls: Dict[str, Impl] = field(default_factory=dict)
    version: str = ""
    import_s: float = 0.0
    error: Optional[str] = None


def _import_pk():
    import pytorch_kinematics
    import pytorch_kinematics.transforms  # noqa: F401
    return pytorch_kinematics


def _import_kornia():
    import kornia
    import kornia.geometry.conversions  # noqa: F401
    return kornia


def _import_scipy():
    from scipy.spatial.transform import Rotation
    return Rotation


PEER_SPECS = [
    ("roma", "roma", _roma, True, None),
    ("kornia", "kornia", _kornia, True, _import_kornia),
    ("pytorch-kinematics", "pytorch_kinematics", _pytorch_kinematics, True, _import_pk),
    ("pypose", "pypose", _pypose, True, None),
    ("scipy", "scipy", _scipy, False, _import_scipy),
]
PEER_NAMES = [spec[0] for spec in PEER_SPECS]


def _version(dist: str, module: str) -> str:
    try:
        from importlib.metadata import version
        return version(dist)
    except Exception:
        return str(getattr(importlib.import_module(module), "__version__", "?"))


def load_peers(names) -> List[Peer]:
    """Import the requested peers; one that fails to import keeps its error and no impls."""
    peers = []
    for name, module, build, torch_peer, importer in PEER_SPECS:
        if name not in names:
            continue
        peer = Peer(name, module, build, torch_peer)
        start = time.perf_counter()
        try:
            mod = importer() if importer else importlib.import_module(module)
            peer.import_s = time.perf_counter() - start
            peer.version = _version(name, module)
            peer.impls = build(mod)
        except Exception as exc:  # ImportError, or a version without the functions used
            peer.error = f"{type(exc).__name__}: {exc}"
        peers.append(peer)
    return peers
