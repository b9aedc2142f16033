"""Trajectories: association, resampling, alignment and evaluation (APE, RPE), batched in torch.

Functions on tensors with any leading batch dims (a batch of equal-length trajectories),
differentiable where the math is, with evo's definitions and numbers (``evo.main_ape.ape``,
``evo.main_rpe.rpe``). Quaternions are ``(w, x, y, z)``; poses are the body's pose in the world.

Example:
    >>> q = torch.tensor([[1., 0., 0., 0.]]).expand(3, 4)
    >>> p = torch.tensor([[0., 0., 0.], [1., 0., 0.], [2., 1., 0.]])
    >>> errors = torchquat.traj.ape((q, p), (q, p + 0.1))
    >>> round(float(torchquat.traj.error_statistics(errors)["rmse"]), 4)
    0.1732
"""

from .align import align
from .associate import associate
from .interpolate import interpolate
from .mean import quat_mean
from .metrics import RELATIONS, ape, rpe
from .pairs import DELTA_UNITS
from .stats import STATISTICS, error_statistics

__all__ = ["associate", "interpolate", "align", "ape", "rpe", "error_statistics", "quat_mean", "RELATIONS",
           "DELTA_UNITS", "STATISTICS"]
