"""Dask for torchquat: rotations in a ``dask.array``, and many pose files on a cluster.

* :func:`convert` is :func:`torchquat.convert` for a ``dask.array`` chunked along its leading
  (batch) dims: block by block, the same numbers as on the whole array.
* :func:`run_files` runs one-file conversions on Dask's distributed scheduler, a local cluster of
  processes or an existing one by address; :func:`torchquat.io.convert_files` and
  ``torchquat convert IN... OUT/`` use it.

Dask, distributed and pyarrow come with ``pip install 'torchquat[dask]'``; they are imported when
these functions are called, never by ``import torchquat``.
"""

import sys
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch

import torchquat

__all__ = ["convert", "run_files", "local_cluster"]

_EXTRA = "pip install 'torchquat[dask]'"
SCHEDULER_TIMEOUT = "10s"  # how long run_files tries to reach a scheduler given by address


def _require(module: str, fn: str):
    import importlib
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"{fn}: needs {module.split('.')[0]}, which is not installed: {_EXTRA}") from None


def _rotation_dims(shape: Tuple[int, ...], src: str, convention: Optional[str]) -> int:
    """How many trailing dims of ``shape`` hold one rotation in ``src``."""
    from .io.representations import parse_token
    token = parse_token(src, "torchquat.dask.convert: src", convention)
    k = len(token.shape)
    if token.name == "rot9d" and tuple(shape[-2:]) == (3, 3):
        k = 2
    elif tuple(shape[len(shape) - k:]) != token.shape or len(shape) < k:
        raise ValueError(f"torchquat.dask.convert: x must end in the shape {token.shape} of one {src!r} rotation, "
                         f"got shape {tuple(shape)}")
    return k


def convert(x, src: str, dst: str, **options):
    """:func:`torchquat.convert` on a ``dask.array``, lazily, block by block.

    The trailing dims (one rotation) are rechunked whole; the leading dims keep their chunks.

    Args:
        x: a ``dask.array.Array`` of shape ``(..., *shape of src)``, float32 or float64.
        src: the source representation (``"quat"``, ``"matrix"``, ``"euler:ZYX"``, ...).
        dst: the target representation.
        **options: :func:`torchquat.convert`'s keywords (``convention``, ``degrees``, ``eps``).

    Returns:
        A ``dask.array.Array`` of shape ``(..., *shape of dst)`` with the leading chunks of ``x``;
        computed, it equals ``torchquat.convert`` on the whole array.

    Raises:
        TypeError: ``x`` is not a dask array.
        ValueError: ``x``'s trailing shape is not one ``src`` rotation, or a bad representation.

    Example:
        >>> import dask.array as da
        >>> import torchquat.dask
        >>> q = da.from_array(np.array([[1.0, 0.0, 0.0, 0.0]] * 6), chunks=(2, 4))
        >>> m = torchquat.dask.convert(q, "quat", "matrix")
        >>> m.shape, m.chunks[0], bool((m.compute() == np.eye(3)).all())
        ((6, 3, 3), (2, 2, 2), True)
    """
    da = _require("dask.array", "torchquat.dask.convert")
    if not isinstance(x, da.Array):
        raise TypeError(f"torchquat.dask.convert: x must be a dask.array.Array, got {type(x).__name__} "
                        "(use torchquat.convert for tensors)")
    k = _rotation_dims(tuple(x.shape), src, options.get("convention"))
    lead = x.ndim - k
    if not np.issubdtype(x.dtype, np.floating):
        raise ValueError(f"torchquat.dask.convert: x must hold floats (float32 or float64), got dtype {x.dtype}")
    sample = torchquat.convert(torch.zeros((0, *x.shape[lead:]), dtype=torch.from_numpy(np.zeros(0, x.dtype)).dtype),
                               src, dst, **options)
    dst_shape = tuple(sample.shape[1:])
    dtype = sample.numpy().dtype
    x = x.rechunk({axis: -1 for axis in range(lead, x.ndim)})
    extra = {}
    if len(dst_shape) > k:
        extra["new_axis"] = list(range(x.ndim, lead + len(dst_shape)))
    elif len(dst_shape) < k:
        extra["drop_axis"] = list(range(lead + len(dst_shape), x.ndim))
    return x.map_blocks(_convert_block, src, dst, options, dtype=dtype,
                        chunks=x.chunks[:lead] + tuple((d,) for d in dst_shape),
                        meta=np.empty((0,) * (lead + len(dst_shape)), dtype=dtype), **extra)


def _convert_block(block: np.ndarray, src: str, dst: str, options: Dict) -> np.ndarray:
    tensor = torch.from_numpy(np.ascontiguousarray(block))
    return torchquat.convert(tensor, src, dst, **options).numpy()


def local_cluster(workers: int):
    """A ``distributed.LocalCluster`` of ``workers`` one-thread processes on 127.0.0.1, no dashboard.

    On Linux the workers are forked (started in a fraction of a second with torch already imported,
    against seconds each when spawned), unless this process has imported polars, whose thread pool
    can deadlock a forked child; then, and elsewhere, Dask's default start method (spawn) is kept.

    Args:
        workers: the number of worker processes.

    Returns:
        The cluster (close it, or use it in a ``with`` block).
    """
    import logging
    import multiprocessing
    dask = _require("dask", "torchquat.dask.local_cluster")
    distributed = _require("distributed", "torchquat.dask.local_cluster")
    settings = {}
    if (sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()
            and "polars" not in sys.modules):
        settings["distributed.worker.multiprocessing-method"] = "fork"
    with dask.config.set(settings):
        return distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                        dashboard_address=None, silence_logs=logging.ERROR)


def run_files(fn: Callable, pairs: Sequence[Tuple[str, str]], options: Dict, workers: Optional[int] = None,
              scheduler: Optional[str] = None, retries: int = 2,
              on_result: Optional[Callable[[int, object], None]] = None) -> List:
    """Run ``fn(src, dst, options)`` for every pair on Dask's distributed scheduler.

    Args:
        fn: the one-file conversion (:func:`torchquat.io.shards.convert_one`): returns a
            ``FileResult`` and raises only on unexpected errors.
        pairs: ``(src, dst)`` absolute paths (workers of a remote cluster must see them).
        options: passed to ``fn``.
        workers: processes of a local cluster started here (and closed at the end).
        scheduler: the address of an existing scheduler, used instead.
        retries: Dask retries of a pair whose ``fn`` raised.
        on_result: called as ``on_result(k, result)`` in this process as each pair finishes.

    Returns:
        The results, in the order of ``pairs``; a pair whose task failed (an exception, a worker
        lost too often) gets a failed ``FileResult`` naming the exception.
    """
    from .io.shards import FileResult
    distributed = _require("distributed", "torchquat.io.convert_files")
    cluster = None
    try:
        if scheduler is None:
            cluster = local_cluster(workers or 1)
            client = distributed.Client(cluster, set_as_default=False)
        else:
            try:
                client = distributed.Client(scheduler, timeout=SCHEDULER_TIMEOUT, set_as_default=False)
            except (OSError, TimeoutError) as err:
                raise ValueError(f"convert_files: cannot reach the Dask scheduler at {scheduler!r}: {err}") from None
        results: List = [None] * len(pairs)
        with client:
            futures = client.map(fn, [s for s, _ in pairs], [d for _, d in pairs], [options] * len(pairs),
                                 retries=retries, pure=False)
            index = {future.key: k for k, future in enumerate(futures)}
            try:
                for future in distributed.as_completed(futures, loop=client.loop):
                    k = index[future.key]
                    if future.status == "finished":
                        results[k] = future.result()
                    else:
                        err = future.exception()
                        results[k] = FileResult(pairs[k][0], pairs[k][1], "failed",
                                                message=f"{pairs[k][0]}: {type(err).__name__}: {err}")
                    if on_result is not None:
                        on_result(k, results[k])
            finally:
                client.cancel([f for f in futures if not f.done()])
        return results
    finally:
        if cluster is not None:
            cluster.close()
