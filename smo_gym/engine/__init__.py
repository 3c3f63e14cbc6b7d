r"""The sensing engine: joint measurements, tangent coordinates and observer state, one compiled path.

Below the wrappers (nothing here knows Gymnasium): :mod:`~smo_gym.engine.measurement` measures a MuJoCo model's
configuration through a sensor on the configuration manifold and feeds an observer;
:mod:`~smo_gym.engine.fused` runs a control period of samples through sensor, tangent coordinates and observer in
one compiled call; :mod:`~smo_gym.engine.batch` measures the environments of an in-process vector env in one
compiled call; :mod:`~smo_gym.engine.tangent` is the compiled tangent-coordinate arithmetic (MuJoCo's, bit for
bit) they share; :mod:`~smo_gym.engine.rollout` rolls out a bare model for the calibration.
"""

from __future__ import annotations

from .batch import MeasurementBatch
from .fused import FusedSensing
from .measurement import JointMeasurement, TangentCoordinates, VelocityEstimator, angular_dofs

__all__ = [
    "FusedSensing",
    "JointMeasurement",
    "MeasurementBatch",
    "TangentCoordinates",
    "VelocityEstimator",
    "angular_dofs",
]
