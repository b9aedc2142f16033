"""torchquat.traj's functions on synthetic data: SciPy and NumPy as references, batching, gradients,
degenerate input and errors."""

import math

import numpy as np
import pytest
import torch

import torchquat
import torchquat.traj as traj

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation
Slerp = pytest.importorskip("scipy.spatial.transform").Slerp


def trajectory(n, batch=(), seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    q = torchquat.random_quat((*batch, n), generator=g, dtype=dtype)
    p = torch.randn(*batch, n, 3, generator=g, dtype=dtype)
    return q, p


def test_quat_mean_equals_scipy_and_is_sign_invariant():
    q, _ = trajectory(50, batch=(3,), seed=1)
    w = torch.rand(3, 50, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    signs = torch.where(torch.rand(3, 50, 1, dtype=torch.float64) < 0.5, -1.0, 1.0)
    for weights in (None, w):
        ours = traj.quat_mean(q * signs * 3.0, weights)
        assert (ours[..., 0] >= 0).all()
        for b in range(3):
            r = Rotation.from_quat(torchquat.quat_wxyz_to_xyzw(q[b]).numpy())
            mean = r.mean(None if weights is None else weights[b].numpy()).as_quat()
            mean = torchquat.quat_xyzw_to_wxyz(torch.from_numpy(mean))
            mean = mean * (1.0 if mean[0] >= 0 else -1.0)
            torch.testing.assert_close(ours[b], mean, rtol=0, atol=1e-12)


def test_interpolate_equals_scipy_slerp_and_numpy_interp():
    q, p = trajectory(20, seed=3)
    t = torch.cumsum(torch.rand(20, dtype=torch.float64, generator=torch.Generator().manual_seed(4)) + 0.1, 0)
    query = torch.linspace(float(t[0]), float(t[-1]), 97, dtype=torch.float64)
    pos, quat = traj.interpolate(t, p, q, query)
    for k in range(3):
        np.testing.assert_allclose(pos[:, k].numpy(), np.interp(query.numpy(), t.numpy(), p[:, k].numpy()),
                                   rtol=0, atol=1e-12)
    expected = Slerp(t.numpy(), Rotation.from_quat(torchquat.quat_wxyz_to_xyzw(q).numpy()))(query.numpy())
    ours = Rotation.from_quat(torchquat.quat_wxyz_to_xyzw(quat).numpy())
    assert (ours.inv() * expected).magnitude().max() < 1e-12


def test_interpolate_is_batched_and_rejects_queries_outside():
    q, p = trajectory(10, batch=(2,), seed=5)
    t = torch.arange(10, dtype=torch.float64)
    pos, quat = traj.interpolate(t, p, q, torch.tensor([[0.5, 9.0], [3.25, 0.0]], dtype=torch.float64))
    assert pos.shape == (2, 2, 3) and quat.shape == (2, 2, 4)
    torch.testing.assert_close(pos[1, 1], p[1, 0])
    torch.testing.assert_close(pos[0, 0], (p[0, 0] + p[0, 1]) / 2)
    with pytest.raises(ValueError, match="interpolate: expected query_times within .* 9.5"):
        traj.interpolate(t, p[0], q[0], torch.tensor([9.5], dtype=torch.float64))


def test_align_recovers_a_similarity_batched_with_det_one():
    _, x = trajectory(30, batch=(4, 2), seed=6)
    R = torchquat.quat_to_matrix(torchquat.random_quat((4, 2), dtype=torch.float64))
    t = torch.randn(4, 2, 3, dtype=torch.float64)
    s = torch.rand(4, 2, dtype=torch.float64) + 0.5
    y = s[..., None, None] * x @ R.transpose(-1, -2) + t.unsqueeze(-2)
    r_hat, t_hat, s_hat = traj.align(x, y, scale=True)
    torch.testing.assert_close(r_hat, R)
    torch.testing.assert_close(t_hat, t)
    torch.testing.assert_close(s_hat, s)
    # a reflection of the target is never answered with a reflection
    r_hat, _, s1 = traj.align(x, -y)
    torch.testing.assert_close(torch.linalg.det(r_hat), torch.ones(4, 2, dtype=torch.float64))
    assert (s1 == 1).all()


def test_align_is_nan_when_undetermined():
    line = torch.linspace(0, 1, 10, dtype=torch.float64)[:, None] * torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    for source in (line, torch.ones(5, 3, dtype=torch.float64), torch.randn(2, 3, dtype=torch.float64)):
        r, t, s = traj.align(source, source + 1.0, scale=True)
        assert r.isnan().all() and t.isnan().all() and s.isnan().all()
    plane = torch.randn(6, 3, dtype=torch.float64)
    plane[:, 2] = 0  # coplanar points do determine the rotation
    r, _, _ = traj.align(plane, plane)
    torch.testing.assert_close(r, torch.eye(3, dtype=torch.float64))


def test_align_weights_zero_leave_points_out():
    _, x = trajectory(12, seed=8)
    y = x + torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    y[3] += 100.0
    w = torch.ones(12, dtype=torch.float64)
    w[3] = 0
    r, t, _ = traj.align(x, y, weights=w)
    torch.testing.assert_close(t, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))


def test_gradcheck_align_and_ape_wrt_estimate():
    q_ref, p_ref = trajectory(8, seed=9)
    q_est, p_est = trajectory(8, seed=10)
    p_est = p_est.requires_grad_()
    assert torch.autograd.gradcheck(lambda x: traj.align(x, p_ref, scale=True), (p_est,))
    for relation in traj.RELATIONS:
        for align, scale in ((False, False), (True, False), (True, True)):
            def f(q, p):
                return traj.ape((q_ref, p_ref), (q, p), relation, align=align, scale=scale)
            assert torch.autograd.gradcheck(f, (q_est.clone().requires_grad_(), p_est)), (relation, align, scale)
    g = torch.autograd.grad(traj.rpe((q_ref, p_ref), (q_est, p_est), 2, relation="rotation_angle_rad",
                                     align=True).sum(), p_est)[0]
    assert g.isfinite().all()


def test_ape_gradient_finite_at_zero_error():
    q, p = trajectory(6, seed=11)
    qe, pe = q.clone().requires_grad_(), p.clone().requires_grad_()
    for relation in traj.RELATIONS:
        grads = torch.autograd.grad(traj.ape((q, p), (qe, pe), relation).sum(), (qe, pe), allow_unused=True)
        assert all(g is None or g.isfinite().all() for g in grads), relation


def test_batch_equals_loop_and_broadcasts():
    q_ref, p_ref = trajectory(40, seed=12)
    q_est, p_est = trajectory(40, batch=(3,), seed=13)
    for fn in (lambda r, e: traj.ape(r, e, "full_transformation", align=True, scale=True),
               lambda r, e: traj.rpe(r, e, 3, relation="rotation_angle_deg", align=True)):
        batched = fn((q_ref, p_ref), (q_est, p_est))
        for b in range(3):
            torch.testing.assert_close(batched[b], fn((q_ref, p_ref), (q_est[b], p_est[b])))
    # meters: pairs chosen per trajectory, the shorter padded with NaN
    p2 = torch.stack((p_est[0], p_est[0] * 0.5))
    e = traj.rpe((q_ref, p_ref), (q_est[:2], p2), 5.0, "meters")
    assert e.shape[0] == 2 and e[1].isnan().any() and not e[0].isnan().any()


def test_nan_poses_give_nan_errors_only_there():
    q, p = trajectory(20, seed=14)
    pe = p + 0.01 * torch.randn(20, 3, dtype=torch.float64)
    pe[5, 1] = float("nan")
    errors = traj.ape((q, p), (q, pe), align=True, scale=True)
    assert errors.isnan().tolist() == [i == 5 for i in range(20)]
    stats = traj.error_statistics(errors, ignore_nan=True)
    finite = errors[~errors.isnan()].numpy()
    assert float(stats["median"]) == pytest.approx(np.median(finite))
    assert float(stats["std"]) == pytest.approx(np.std(finite))
    assert traj.error_statistics(errors)["rmse"].isnan()


def test_error_statistics_match_numpy():
    e = torch.rand(3, 7, dtype=torch.float64)
    stats = traj.error_statistics(e)
    x = e.numpy()
    expected = {"rmse": np.sqrt(np.mean(x ** 2, -1)), "mean": x.mean(-1), "median": np.median(x, -1),
                "std": x.std(-1), "min": x.min(-1), "max": x.max(-1), "sse": (x ** 2).sum(-1)}
    assert list(stats) == list(expected)
    for key, value in expected.items():
        np.testing.assert_allclose(stats[key].numpy(), value, rtol=1e-14)


def test_associate_takes_closest_pairs_first_each_once():
    a = np.array([0.0, 1.0, 1.02, 2.0, 5.0])
    b = np.array([1.011, 1.99, 3.0])
    ia, ib = traj.associate(a, b, max_difference=0.05)
    assert ia.tolist() == [2, 3] and ib.tolist() == [0, 1]  # 1.02 is closer to 1.011 than 1.0 is
    ia, ib = traj.associate(torch.tensor(a), torch.tensor(b) - 1.0, max_difference=0.05, offset=1.0)
    assert ia.tolist() == [2, 3]
    assert traj.associate(a, b + 10, 0.05)[0].numel() == 0


def test_rpe_seconds_and_errors_name_function_and_argument():
    q, p = trajectory(30, seed=15)
    times = torch.arange(30, dtype=torch.float64) * 0.1
    e = traj.rpe((q, p), (q, p), 0.5, "seconds", times=times)
    assert e.shape == (5,) and (e.abs() < 1e-12).all()
    torch.testing.assert_close(traj.rpe((q, p), (q, p * 2), 5, "frames"),
                               traj.rpe((q, p), (q, p * 2), 0.45, "seconds", times=times))
    with pytest.raises(torchquat.ShapeError, match=r"ape: .*reference \(30,\) and estimate \(29,\)"):
        traj.ape((q, p), (q[:29], p[:29]))
    with pytest.raises(ValueError, match="rpe: expected relation one of"):
        traj.rpe((q, p), (q, p), relation="rotation")
    with pytest.raises(ValueError, match="rpe: expected delta_unit"):
        traj.rpe((q, p), (q, p), delta_unit="degrees")
    with pytest.raises(ValueError, match="rpe: expected delta a positive integer for frames, got 1.5"):
        traj.rpe((q, p), (q, p), delta=1.5)
    with pytest.raises(torchquat.ShapeError, match=r"align: expected source of shape \(..., N, 3\), got \(4, 2\)"):
        traj.align(torch.zeros(4, 2), torch.zeros(4, 3))
    with pytest.raises(torchquat.ShapeError, match="quat_mean: expected q of shape"):
        traj.quat_mean(torch.zeros(4, 3))


def test_quat_mean_gradient_and_angle_units():
    q, _ = trajectory(5, seed=16)
    assert torch.autograd.gradcheck(lambda x: traj.quat_mean(x), (q.clone().requires_grad_(),))
    qz = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64).expand(3, 4)
    q90 = torchquat.axis_angle_to_quat(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64)).expand(3, 4)
    p = torch.zeros(3, 3, dtype=torch.float64)
    torch.testing.assert_close(traj.ape((qz, p), (q90, p), "rotation_angle_deg"),
                               torch.full((3,), 90.0, dtype=torch.float64))
