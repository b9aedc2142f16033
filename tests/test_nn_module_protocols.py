"""Every module: repr, deepcopy, state_dict round trip, torch.export, torch.compile(fullgraph)."""

import copy

import pytest
import torch

import torchquat
from torchquat.nn import ChordalLoss, Convert, GeodesicLoss, QuatDistanceLoss, RotateVectors, RotationHead

_G = torch.Generator().manual_seed(0)
_Q = torchquat.random_quat(5, generator=_G)
_R = torchquat.quat_to_matrix(_Q)
_Q2 = torchquat.random_quat(5, generator=_G)
_R2 = torchquat.quat_to_matrix(_Q2)
_F = torch.randn(5, 8, generator=_G)


def _head(rep, output="matrix"):
    return lambda: RotationHead(8, rep, output, convention="ZYX" if rep == "euler" else None)


# name: (factory, example inputs, text the repr must show)
MODULES = {
    "Convert-euler-quat": (lambda: Convert("euler", "quat", convention="ZYX"), (torch.randn(5, 3, generator=_G),),
                           "Convert(src='euler', dst='quat', convention='ZYX', degrees=False)"),
    "Convert-rot9d-rot6d": (lambda: Convert("rot9d", "rot6d"), (torch.randn(5, 9, generator=_G),),
                            "Convert(src='rot9d', dst='rot6d')"),
    # (a pair convert takes straight to its own kernel, matrix_to_euler)
    "Convert-matrix-euler": (lambda: Convert("matrix", "euler:zxz", degrees=True), (_R,),
                             "Convert(src='matrix', dst='euler', convention='zxz', degrees=True)"),
    "RotateVectors": (RotateVectors, (_Q[:, None], torch.randn(5, 7, 3, generator=_G)), "RotateVectors()"),
    "RotationHead-rot6d": (_head("rot6d"), (_F,), "in_features=8, representation='rot6d', output='matrix'"),
    "RotationHead-rot9d": (_head("rot9d"), (_F,), "representation='rot9d'"),
    "RotationHead-quat-quat": (_head("quat", "quat"), (_F,), "representation='quat', output='quat'"),
    "RotationHead-axis_angle": (_head("axis_angle"), (_F,), "representation='axis_angle'"),
    "RotationHead-euler-quat": (_head("euler", "quat"), (_F,), "output='quat', convention='ZYX'"),
    "GeodesicLoss-matrix": (GeodesicLoss, (_R, _R2), "GeodesicLoss(representation='matrix', reduction='mean')"),
    "GeodesicLoss-quat-none": (lambda: GeodesicLoss("quat", "none"), (_Q, _Q2),
                               "GeodesicLoss(representation='quat', reduction='none')"),
    "QuatDistanceLoss-sum": (lambda: QuatDistanceLoss("sum"), (_Q, _Q2), "QuatDistanceLoss(reduction='sum')"),
    "ChordalLoss": (ChordalLoss, (_R, _R2), "ChordalLoss(reduction='mean')"),
}
NAMES = list(MODULES)


@pytest.fixture
def fresh_dynamo():
    """Forget earlier compilations: configurations share code objects (``convert``), and many of
    them in one process would hit Dynamo's recompile limit, which ``fullgraph=True`` turns into an
    error that says nothing about the module under test."""
    torch._dynamo.reset()
    yield
    torch._dynamo.reset()


def _build(name, seed=0):
    torch.manual_seed(seed)
    factory, args, _ = MODULES[name]
    return factory(), args


@pytest.mark.parametrize("name", NAMES)
def test_repr_shows_configuration(name):
    module, _ = _build(name)
    assert MODULES[name][2] in repr(module)


@pytest.mark.parametrize("name", NAMES)
def test_deepcopy_is_independent_and_equal(name):
    module, args = _build(name)
    clone = copy.deepcopy(module)
    torch.testing.assert_close(clone(*args), module(*args), rtol=0, atol=0)
    for p, c in zip(module.parameters(), clone.parameters()):
        assert p.data_ptr() != c.data_ptr()
    assert repr(clone) == repr(module)


@pytest.mark.parametrize("name", NAMES)
def test_state_dict_round_trip(name):
    module, args = _build(name, seed=0)
    other, _ = _build(name, seed=1)  # different initial weights
    other.load_state_dict(module.state_dict(), strict=True)
    torch.testing.assert_close(other(*args), module(*args), rtol=0, atol=0)
    if not name.startswith("RotationHead"):
        assert module.state_dict() == {} and list(module.buffers()) == []


@pytest.mark.parametrize("name", NAMES)
def test_torch_export_matches_eager(name):
    module, args = _build(name)
    program = torch.export.export(module, args)
    torch.testing.assert_close(program.module()(*args), module(*args))


@pytest.mark.parametrize("name", NAMES)
def test_compile_fullgraph_traces_without_graph_breaks(name, fresh_dynamo):
    # aot_eager: Dynamo captures the whole graph (fullgraph=True fails on any break) and AOT
    # autograd traces the backward, without paying for Inductor's C++ code generation.
    module, args = _build(name)
    compiled = torch.compile(module, fullgraph=True, backend="aot_eager")
    args = tuple(a.clone().requires_grad_(True) for a in args)
    out = compiled(*args)
    torch.testing.assert_close(out, module(*args))
    out.sum().backward()
    assert all(torch.isfinite(a.grad).all() for a in args)


@pytest.mark.parametrize("name", ["RotationHead-rot6d"])  # Inductor is slow to compile: one representative
def test_compile_inductor_forward_and_backward(name, fresh_dynamo):
    module, args = _build(name)
    compiled = torch.compile(module, fullgraph=True)
    args = tuple(a.clone().requires_grad_(True) for a in args)
    out = compiled(*args)
    torch.testing.assert_close(out, module(*args), rtol=1e-5, atol=1e-6)
    out.sum().backward()
    assert all(torch.isfinite(a.grad).all() for a in args)


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in NAMES if n != "RotationHead-rot6d"])
def test_compile_inductor_every_module(name, fresh_dynamo):
    test_compile_inductor_forward_and_backward(name, fresh_dynamo)


@pytest.mark.parametrize("name", NAMES)
def test_torch_export_with_a_dynamic_batch_matches_eager_at_another_size(name):
    # the batch-size crossovers were tested before the tracing check: their guards made export
    # refuse a dynamic batch ("batch < 524288/9", "3*batch <= 2304") and a broadcast check hashed it
    module, args = _build(name)
    batch = torch.export.Dim("batch", min=2, max=100_000)
    program = torch.export.export(module, args, dynamic_shapes=tuple({0: batch} for _ in args))
    other = tuple(torch.cat([a, a[:4]]) for a in args)  # 9 rows
    torch.testing.assert_close(program.module()(*other), module(*other))
