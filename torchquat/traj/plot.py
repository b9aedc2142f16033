"""The figure of ``torchquat eval --plot``: both trajectories from above, and the error along the way."""

import os

import numpy as np
import torch

__all__ = ["plot_evaluation"]


def plot_evaluation(args, reference, estimate, errors: torch.Tensor, times, relation: str) -> None:
    """Draw the reference (grey) and the estimate (aligned when asked, coloured by error) in the
    x-y plane, and the error against time (or pose index) below; written to ``args.plot``.
    matplotlib is imported here only, with the non-interactive Agg backend."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .pairs import pair_indices
    from .poses import apply_similarity, check_pair
    ref, est = check_pair("eval", reference, estimate)
    _, p_est = apply_similarity(ref, est, args.align, args.scale)
    p_ref = ref[1].numpy()
    p_est = p_est.numpy()
    e = errors.numpy()
    if args.metric == "ape":
        at = np.arange(len(e))
    else:
        t = None if times is None else torch.as_tensor(times)
        at = pair_indices(len(p_est), args.delta, args.delta_unit, positions=torch.from_numpy(p_est),
                          times=t)[1].numpy()
    x = np.asarray(times) - times[0] if times is not None else np.arange(len(p_est))
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(7, 9), gridspec_kw={"height_ratios": (3, 1)})
    top.plot(p_ref[:, 0], p_ref[:, 1], "--", color="0.5", lw=1, label="reference")
    top.plot(p_est[:, 0], p_est[:, 1], color="0.8", lw=0.5)
    points = top.scatter(p_est[at, 0], p_est[at, 1], c=e, s=4, cmap="viridis", label="estimate")
    figure.colorbar(points, ax=top, label=relation.replace("_", " "))
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_aspect("equal", adjustable="datalim")
    top.legend(loc="best")
    top.set_title(f"{args.metric.upper()}: {os.path.basename(args.estimate)} against {os.path.basename(args.reference)}", fontsize=9)
    bottom.plot(x[at], e, lw=0.8)
    bottom.set_xlabel("time (s)" if times is not None else "pose index")
    bottom.set_ylabel(relation.replace("_", " "))
    figure.tight_layout()
    try:
        figure.savefig(args.plot, dpi=120)
    finally:
        plt.close(figure)
