"""Dask for torchquat: rotations in a ``dask.array``, and many pose files on a cluster.

* :func:`convert` is :func:`torchquat.convert` for a ``dask.array`` chunked along its leading
  (batch) dims: block by block, the same numbers as on the whole array.
* Many pose files on a cluster: :func:`torchquat.io.convert_files` (``torchquat.io.cluster``).

Dask, distributed and pyarrow come with ``pip install 'torchquat[dask]'``; they are imported when
these functions are called, never by ``import torchquat``.
"""

from typing import Dict, Optional, Tuple

import numpy as np
import torch

import torchquat
from torchquat.io.cluster import require as _require

__all__ = ["convert"]

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
