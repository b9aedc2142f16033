"""``torchquat.dask.convert`` against ``torchquat.convert`` on the whole array, and what ``import
torchquat`` leaves out."""

import subprocess
import sys

import numpy as np
import pytest
import torch

import torchquat

da = pytest.importorskip("dask.array")
tqdask = pytest.importorskip("torchquat.dask")

TARGETS = ["matrix", "euler:ZYX", "rot6d", "axis_angle", "quat_xyzw", "quat"]


def _quats(shape, dtype=np.float64, seed=0):
    q = np.random.default_rng(seed).normal(size=(*shape, 4)).astype(dtype)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _close(a: np.ndarray, b: np.ndarray) -> None:
    """Equal but for the last bits: the core takes other paths for small and large batches
    (``torchquat._math.SMALL_BATCH_ROWS``, ``PLANAR_ROWS``), and a block is a smaller batch."""
    assert a.shape == b.shape and a.dtype == b.dtype
    tol = 64 * np.finfo(a.dtype).eps
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol)


@pytest.mark.parametrize("dst", TARGETS)
def test_against_the_eager_result(dst):
    q = _quats((50, 7))
    x = da.from_array(q, chunks=(12, 3, 2))
    y = tqdask.convert(x, "quat", dst)
    eager = torchquat.convert(torch.from_numpy(q), "quat", dst).numpy()
    assert y.shape == eager.shape and y.dtype == eager.dtype
    assert y.chunks[:2] == ((12, 12, 12, 12, 2), (3, 3, 1))  # leading chunks kept, trailing dims whole
    assert all(len(c) == 1 for c in y.chunks[2:])
    _close(y.compute(), eager)


def test_one_block_is_bitwise_the_eager_result():
    q = _quats((40,))
    for dst in TARGETS:
        y = tqdask.convert(da.from_array(q, chunks=-1), "quat", dst).compute()
        assert np.array_equal(y, torchquat.convert(torch.from_numpy(q), "quat", dst).numpy())


def test_matrix_in_fewer_dims_out_and_options():
    m = torchquat.convert(torch.from_numpy(_quats((30,), np.float32)), "quat", "matrix").numpy()
    y = tqdask.convert(da.from_array(m, chunks=(7, 1, 3)), "matrix", "euler", convention="xyz", degrees=True)
    eager = torchquat.convert(torch.from_numpy(m), "matrix", "euler", convention="xyz", degrees=True).numpy()
    assert y.chunks == ((7, 7, 7, 7, 2), (3,)) and y.dtype == np.float32
    _close(y.compute(), eager)
    e = tqdask.convert(y, "euler:xyz", "quat", degrees=True)
    _close(e.compute(), torchquat.convert(torch.from_numpy(eager), "euler:xyz", "quat", degrees=True).numpy())


def test_on_a_distributed_cluster():
    distributed = pytest.importorskip("distributed")
    q = _quats((64,))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, host="127.0.0.1",
                                  protocol="tcp://", dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        y = client.compute(tqdask.convert(da.from_array(q, chunks=16), "quat", "rot6d")).result()
    _close(y, torchquat.convert(torch.from_numpy(q), "quat", "rot6d").numpy())


def test_errors_name_the_function_and_what_was_expected():
    with pytest.raises(TypeError, match=r"torchquat.dask.convert: x must be a dask.array.Array, got ndarray"):
        tqdask.convert(np.zeros((3, 4)), "quat", "matrix")
    with pytest.raises(ValueError, match=r"must end in the shape \(3, 3\) of one 'matrix' rotation, got shape \(5, 4\)"):
        tqdask.convert(da.zeros((5, 4)), "matrix", "quat")
    with pytest.raises(ValueError, match="must hold floats"):
        tqdask.convert(da.zeros((5, 4), dtype=int), "quat", "matrix")
    with pytest.raises(ValueError, match="unknown representation"):
        tqdask.convert(da.zeros((5, 4)), "quaternion", "matrix")


def test_import_torchquat_imports_no_dask_distributed_or_pyarrow():
    code = ("import sys, torchquat, torchquat.io, torchquat.cli\n"
            "print(sorted(m for m in ('dask', 'distributed', 'pyarrow') if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"
