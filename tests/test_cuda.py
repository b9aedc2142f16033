"""CUDA tensors: every public function runs on the GPU, never waits on the host, and gives the
CPU's answers and gradients. Skipped where no CUDA device is present (CI has none); on a GPU
machine: ``python -m pytest tests/test_cuda.py``.

``torch.cuda.set_sync_debug_mode("error")`` makes any host synchronization (``.item()``, a
boolean-mask write, ``nonzero``, a data-dependent shape) raise, so these tests also hold the
branch-free rule of the core on the device where it matters.
"""

import pytest
import torch

import torchquat as tq
from function_table import ALL, assert_paths_agree, compiled_against_eager

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")

# SVD on CUDA checks its convergence on the host (torch.linalg.svd synchronizes), so the 9D
# projection is checked for its answers but not for being sync-free.
SYNCS_BY_DESIGN = {"rot9d_to_matrix"}


def without_host_sync(call, name=""):
    """``call()``, raising if it synchronizes with the host (after a first call, unchecked)."""
    call()
    if name in SYNCS_BY_DESIGN:
        return call()
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        return call()
    finally:
        torch.cuda.set_sync_debug_mode("default")


@pytest.mark.parametrize("name", sorted(ALL))
def test_cuda_matches_cpu_without_a_host_sync(name):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        cpu = tuple(x.clone().requires_grad_() for x in make())
        ref = fn(*cpu)
        ref_grads = torch.autograd.grad(ref.sum(), cpu)
        gpu = tuple(x.detach().cuda().requires_grad_() for x in cpu)

        def forward_backward():
            out = fn(*gpu)
            return out, torch.autograd.grad(out.sum(), gpu)

        out, grads = without_host_sync(forward_backward, name)
        with torch.no_grad():
            plain = without_host_sync(lambda: fn(*(x.detach() for x in gpu)), name)
        assert out.device == plain.device == gpu[0].device
        assert torch.allclose(plain, out.detach(), atol=1e-14, rtol=0, equal_nan=True)
        assert all(g.device == gpu[0].device for g in grads)
        assert_paths_agree(name, make is singular, out.detach().cpu(), ref.detach(), [g.cpu() for g in grads],
                           ref_grads, atol=1e-12, grad_atol=1e-9, grad_rtol=1e-9)


@pytest.mark.parametrize("name", ["quat_to_euler[ZYX]", "matrix_to_euler[zxz]", "euler_to_quat[XYZ]",
                                  "euler_to_matrix[ZYZ]", "matrix_to_quat", "axis_angle_to_quat",
                                  "quat_to_axis_angle", "rot6d_to_matrix", "quat_geodesic_distance"])
def test_cuda_second_derivatives_are_exact(name):
    # (the tolerance for nondeterminism: CUDA's backward of a broadcast sums with atomic adds)
    fn, generic, singular = ALL[name]
    inputs = tuple(x[:3].cuda().requires_grad_() for x in generic())
    assert torch.autograd.gradgradcheck(lambda *xs: fn(*xs), inputs, nondet_tol=1e-12)


@pytest.mark.parametrize("n", [1, 7, 20_000])
def test_float32_on_cuda_matches_float64_on_cpu(n):
    g = torch.Generator().manual_seed(3)
    q = tq.random_quat(n, generator=g, dtype=torch.float64)
    R = tq.quat_to_matrix(q)
    # (function, input, its output as a rotation matrix): Euler angles next to lock are
    # ill-conditioned, so those are compared as the rotations they make
    cases = [(tq.quat_to_matrix, q, None), (tq.matrix_to_quat, R, tq.quat_to_matrix),
             (lambda t: tq.quat_to_euler(t, "ZYX"), q, lambda e: tq.euler_to_matrix(e, "ZYX")),
             (lambda t: tq.matrix_to_euler(t, "XZX"), R, lambda e: tq.euler_to_matrix(e, "XZX")),
             (tq.quat_to_axis_angle, q, tq.axis_angle_to_matrix),
             (lambda t: tq.euler_to_matrix(t, "zyx"), tq.quat_to_euler(q, "zyx"), None),
             (tq.matrix_to_rot6d, R, None), (tq.rot6d_to_matrix, tq.matrix_to_rot6d(R), None)]
    for f, x, as_matrix in cases:
        as_matrix = as_matrix or (lambda y: y)
        x32 = x.float().cuda()
        out = without_host_sync(lambda: f(x32))
        assert out.dtype == torch.float32 and out.device.type == "cuda"
        assert (as_matrix(out.double().cpu()) - as_matrix(f(x))).abs().max() < 1e-5


def test_random_quat_and_convert_on_cuda():
    q = tq.random_quat((5, 7), generator=torch.Generator("cuda").manual_seed(0), device="cuda")
    assert q.device.type == "cuda" and q.shape == (5, 7, 4)
    assert torch.allclose(q.norm(dim=-1), torch.ones(5, 7, device="cuda"), atol=1e-6)
    q = q.double()
    for dst in sorted(tq.REPRESENTATIONS):
        dst = "euler:YXZ" if dst == "euler" else dst
        there, back = without_host_sync(lambda: (tq.convert(q, "quat", dst), tq.convert(tq.convert(q, "quat", dst), dst, "quat")),
                                        dst.replace("rot9d", "rot9d_to_matrix"))
        assert there.device.type == "cuda"
        assert torch.allclose(there.cpu(), tq.convert(q.cpu(), "quat", dst), atol=1e-12)
        assert torch.allclose(tq.quat_to_matrix(back), tq.quat_to_matrix(q), atol=1e-12)


def test_nn_modules_train_on_cuda():
    from torchquat.nn import Convert, GeodesicLoss, QuatDistanceLoss, RotationHead

    torch.manual_seed(0)
    head = RotationHead(8, "rot6d", "matrix").cuda()
    quat_head = RotationHead(8, "euler", "quat", convention="ZYX").cuda()
    x = torch.randn(64, 8, device="cuda")
    target = tq.random_quat(64, generator=torch.Generator("cuda").manual_seed(1), device="cuda")

    def step():
        loss = (GeodesicLoss("matrix")(head(x), tq.quat_to_matrix(target))
                + QuatDistanceLoss()(quat_head(x), target)
                + Convert("quat", "rot6d")(target).sum() * 0)
        loss.backward()

    without_host_sync(step)
    parameters = list(head.parameters()) + list(quat_head.parameters())
    assert all(p.grad is not None and p.grad.device.type == "cuda" and torch.isfinite(p.grad).all()
               for p in parameters)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["quat_to_matrix", "matrix_to_quat", "quat_to_euler[ZYX]", "matrix_to_euler[xzx]",
                                  "euler_to_quat[ZYZ]", "axis_angle_to_quat", "quat_to_axis_angle", "rot6d_to_matrix",
                                  "quat_geodesic_distance", "matrix_geodesic_distance", "quat_rotate"])
def test_compiled_kernels_on_cuda_match_eager(name, compiled):
    fn, generic, singular = ALL[name]
    for make in (generic, singular):
        out, grads, ref, ref_grads = compiled_against_eager(fn, tuple(x.cuda() for x in make()))
        assert_paths_agree(name, make is singular, out.cpu(), ref.cpu(), [g.cpu() for g in grads],
                           [g.cpu() for g in ref_grads], atol=1e-12, grad_atol=1e-9, grad_rtol=1e-9)


def test_bench_times_cuda_tensors(tmp_path, capsys):
    import json

    from torchquat import bench

    path = tmp_path / "bench.json"
    assert bench.main(["--device", "cuda", "--n", "1", "1000", "--ops", "quat_to_matrix", "quat_to_euler_ZYX",
                       "--peers", "scipy", "--rounds", "1", "--min-run-time", "0.01", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "cuda device" in out and "caching allocator" in out and "scipy" not in out.split("Calls timed")[0]
    data = json.loads(path.read_text())
    assert data["meta"]["device"].startswith("cuda")
    assert all(r["median_s"] > 0 for r in data["results"] if r["impl"] in ("torchquat", "floor"))
