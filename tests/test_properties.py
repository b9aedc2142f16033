"""Property tests (hypothesis): round trips, composition and inverses over random and
near-singular rotations, in every representation and convention."""

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import torchquat as tq
from rotation_samples import CONVENTIONS

F64 = torch.float64
finite = st.floats(-1.0, 1.0, allow_nan=False)
# angles that cluster at the singular values (0, +-pi/2, pi) as well as anywhere
special = st.sampled_from([0.0, math.pi / 2, -math.pi / 2, math.pi, -math.pi, 1e-9, math.pi - 1e-9])
angle = st.one_of(st.floats(-math.pi, math.pi), special, special.map(lambda a: a + 1e-7), special.map(lambda a: a - 1e-5))


@st.composite
def quaternions(draw):
    q = torch.tensor([draw(finite) for _ in range(4)], dtype=F64)
    if draw(st.booleans()):  # snap near the identity / a half turn / an axis
        q = torch.where(q.abs() < 0.3, q * draw(st.sampled_from([0.0, 1e-9, 1e-5])), q)
    if q.norm() < 1e-3:
        q = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64)
    return q / q.norm()


def same_rotation(a, b, tol):
    return (tq.quat_to_matrix(a) - tq.quat_to_matrix(b)).abs().max() <= tol


@settings(max_examples=150, deadline=None)
@given(q=quaternions(), convention=st.sampled_from(CONVENTIONS))
def test_euler_round_trip_reproduces_the_rotation(q, convention):
    angles = tq.quat_to_euler(q, convention)
    tol = 1e-12 if not tq.euler_gimbal_lock(q, convention) else 4e-7
    assert same_rotation(tq.euler_to_quat(angles, convention), q, tol)
    assert (tq.euler_to_matrix(angles, convention) - tq.quat_to_matrix(q)).abs().max() <= tol


@settings(max_examples=150, deadline=None)
@given(a=st.tuples(angle, angle, angle), convention=st.sampled_from(CONVENTIONS))
def test_angles_to_rotation_and_back(a, convention):
    angles = torch.tensor(a, dtype=F64)
    q = tq.euler_to_quat(angles, convention)
    back = tq.quat_to_euler(q, convention)
    assert same_rotation(tq.euler_to_quat(back, convention), q, 4e-7)
    middle = back[1]
    if convention[0].lower() == convention[2].lower():
        assert 0 <= middle <= math.pi
    else:
        assert -math.pi / 2 <= middle <= math.pi / 2
    assert back[0].abs() <= math.pi and back[2].abs() <= math.pi


@settings(max_examples=200, deadline=None)
@given(q=quaternions(), rep=st.sampled_from(["matrix", "axis_angle", "rot6d", "rot9d", "quat_xyzw", "euler:ZYX", "euler:zxz"]))
def test_every_representation_round_trips(q, rep):
    x = tq.convert(q, "quat", rep)
    back = tq.convert(x, rep, "quat")
    assert (back - tq.quat_standardize(q)).abs().max() <= 1e-12 or same_rotation(back, q, 4e-7)
    assert back[0] >= 0


@settings(max_examples=150, deadline=None)
@given(p=quaternions(), q=quaternions())
def test_composition_and_inverse(p, q):
    pq = tq.quat_multiply(p, q)
    assert (tq.quat_to_matrix(pq) - tq.quat_to_matrix(p) @ tq.quat_to_matrix(q)).abs().max() <= 1e-14
    assert (tq.quat_multiply(pq, tq.quat_inverse(q)) - p).abs().max() <= 1e-14
    d = tq.quat_geodesic_distance(p, q)
    assert 0 <= d <= math.pi
    assert abs(d - tq.matrix_geodesic_distance(tq.quat_to_matrix(p), tq.quat_to_matrix(q))) <= 1e-12
    assert abs(d - tq.quat_to_axis_angle(tq.quat_multiply(tq.quat_conjugate(p), q)).norm()) <= 1e-12


@settings(max_examples=150, deadline=None)
@given(v=st.tuples(*[st.one_of(st.floats(-4.0, 4.0), st.sampled_from([0.0, 1e-12, 1e-6, -1e-9]))] * 3))
def test_axis_angle_round_trip_is_the_shortest_arc(v):
    v = torch.tensor(v, dtype=F64)
    back = tq.quat_to_axis_angle(tq.axis_angle_to_quat(v))
    assert back.norm() <= math.pi + 1e-15
    assert (tq.axis_angle_to_matrix(back) - tq.axis_angle_to_matrix(v)).abs().max() <= 1e-13
    if v.norm() < math.pi - 1e-6:
        assert (back - v).abs().max() <= 1e-15 + 1e-15 * v.norm()
