"""Many pose files on Dask's distributed scheduler: a local cluster of processes, or one by address.

:func:`torchquat.io.convert_files` and ``torchquat convert IN... OUT/`` use :func:`run_files`.
Dask and distributed come with ``pip install 'torchquat[dask]'``; they are imported when these
functions are called, never by ``import torchquat``.
"""

import importlib
import sys
from typing import Callable, Dict, List, Optional, Sequence, Tuple

__all__ = ["run_files", "local_cluster", "require"]

EXTRA = "pip install 'torchquat[dask]'"
SCHEDULER_TIMEOUT = "10s"  # how long run_files tries to reach a scheduler given by address


def require(module: str, fn: str):
    """``module`` imported, or an ``ImportError`` naming ``fn`` and the extra that brings it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"{fn}: needs {module.split('.')[0]}, which is not installed: {EXTRA}") from None


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
    dask = require("dask", "torchquat.io.local_cluster")
    distributed = require("distributed", "torchquat.io.local_cluster")
    settings = {}
    if (sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()
            and "polars" not in sys.modules):
        settings["distributed.worker.multiprocessing-method"] = "fork"
    with dask.config.set(settings):
        return distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                        dashboard_address=None, silence_logs=logging.ERROR)


def run_files(fn: Callable, pairs: Sequence[Tuple[str, str]], options: Dict, failed: Callable,
              workers: Optional[int] = None, scheduler: Optional[str] = None, retries: int = 2,
              on_result: Optional[Callable[[int, object], None]] = None) -> List:
    """Run ``fn(src, dst, options)`` for every pair on Dask's distributed scheduler.

    Args:
        fn: the one-file conversion (:func:`torchquat.io.shards.convert_one`): returns a
            ``FileResult`` and raises only on unexpected errors.
        pairs: ``(src, dst)`` absolute paths (workers of a remote cluster must see them).
        options: passed to ``fn``.
        failed: ``failed(src, dst, message)`` makes the result of a pair whose task failed.
        workers: processes of a local cluster started here (and closed at the end).
        scheduler: the address of an existing scheduler, used instead.
        retries: Dask retries of a pair whose ``fn`` raised.
        on_result: called as ``on_result(k, result)`` in this process as each pair finishes.

    Returns:
        The results, in the order of ``pairs``; a pair whose task failed (an exception, a worker
        lost too often) gets ``failed``'s, naming the exception.
    """
    distributed = require("distributed", "torchquat.io.convert_files")
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
                        results[k] = failed(pairs[k][0], pairs[k][1], f"{pairs[k][0]}: {type(err).__name__}: {err}")
                    if on_result is not None:
                        on_result(k, results[k])
            finally:
                client.cancel([f for f in futures if not f.done()])
        return results
    finally:
        if cluster is not None:
            cluster.close()
