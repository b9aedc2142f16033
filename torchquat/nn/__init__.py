"""Layers, heads and losses for rotations (``torch.nn`` style): thin modules over the core.

=========================  ===================================================================
:class:`Convert`           any representation to any other, a stateless layer
:class:`RotateVectors`     ``forward(q, v)``: rotate 3-vectors by quaternions
:class:`RotationHead`      ``nn.Linear`` + map to a valid rotation (6D, 9D, quat, axis-angle,
                           Euler)
:class:`GeodesicLoss`      rotation angle between matrices or quaternions (radians)
:class:`QuatDistanceLoss`  ``1 - |<q1, q2>|`` of unit quaternions (Huynh 2009, metric 4)
:class:`ChordalLoss`       ``||R1 - R2||_F^2`` (Hartley et al. 2013)
=========================  ===================================================================

Every module works with ``torch.compile(fullgraph=True)``, ``torch.export``, ``state_dict``
round trips and ``copy.deepcopy``; under autocast the rotation maps and losses compute in
float32.
"""

from .heads import RotationHead
from .layers import Convert, RotateVectors
from .losses import ChordalLoss, GeodesicLoss, QuatDistanceLoss

__all__ = ["Convert", "RotateVectors", "RotationHead", "GeodesicLoss", "QuatDistanceLoss", "ChordalLoss"]
