"""Large eager CPU batches with nothing to differentiate, run block by block into one output, so that
each pass over a block's columns stays in cache (``_math.BLOCK_ROWS``)."""

from typing import Callable, Optional, Tuple

import torch
from torch import Tensor

from . import _math, _planes

# A first test, cheap enough for one rotation (0.1 us): no batch below one thread's default bound
# is blocked; run_blocked reads the live settings.
BLOCKED_FROM = _math.BLOCK_ROWS * _math.BLOCK_MIN_BLOCKS


def run_blocked(fn: Callable, tensors: Tuple[Tensor, ...], row_dims: Tuple[int, ...], static) -> Optional[Tensor]:
    """``fn(*tensors, **static)`` computed ``_math.block_rows()`` rows at a time into one output, or
    ``None`` where blocks do not apply: off the CPU, with a gradient to record (autograd would
    keep one graph per block), for non-contiguous inputs or batch shapes that broadcast other than
    one row against many, or for fewer than ``_math.BLOCK_MIN_BLOCKS`` blocks. ``row_dims``: each
    input's number of row dimensions."""
    if not tensors[0].is_cpu or (torch.is_grad_enabled() and any(t.requires_grad for t in tensors)):
        return None
    batches = [t.shape[:t.dim() - r] for t, r in zip(tensors, row_dims)]
    batch = batches[0] if all(b == batches[0] for b in batches) else torch.broadcast_shapes(*batches)
    n_rows = batch.numel()
    if any(not t.is_contiguous() or b.numel() not in (n_rows, 1) for t, b in zip(tensors, batches)):
        return None
    n_blocks = n_rows // _math.block_rows()
    if n_blocks < _math.BLOCK_MIN_BLOCKS:
        return None
    # Equal blocks (1 to 2 block_rows()) of a multiple of 64 rows: vectorised loops
    # leave a ragged end to scalar code (atan2 can differ there by an ulp), so only the last
    # block has one, on the whole batch's rows. (The results agree with the whole batch's to an
    # ulp, as any two batch sizes' do.)
    size = -(-n_rows // (n_blocks * 64)) * 64
    # (a single row, e.g. one rotation applied to many vectors, goes whole to every block)
    blocks = zip(*(t.view((n_rows,) + t.shape[t.dim() - r:]).split(size) if b.numel() == n_rows
                   else [t.view((1,) + t.shape[t.dim() - r:])] * -(-n_rows // size) for t, b, r in zip(tensors, batches, row_dims)))
    first = fn(*next(blocks), **static)
    out = first.new_empty((n_rows,) + first.shape[1:])  # (a fresh output of ours: no input is written)
    out.narrow(0, 0, first.shape[0]).copy_(first)
    start = first.shape[0]
    for block in blocks:
        # The block's slice of the output is lent to the kernel's final transposing matmul
        # (_planes.rows), which writes it in place: one pass over the output less per block.
        target = out.narrow(0, start, min(size, n_rows - start))
        _planes.lend(target.view(target.shape[0], -1))
        try:
            y = fn(*block, **static)
        finally:
            _planes.lend(None)
        if not (y.data_ptr() == target.data_ptr() and y.is_contiguous() and y.numel() == target.numel()):
            # not written in place (a lent slice holding an intermediate is read before it is overwritten)
            target.copy_(y.clone() if y.untyped_storage().data_ptr() == out.untyped_storage().data_ptr() else y)
        start += target.shape[0]
    return out.view(batch + out.shape[1:])
