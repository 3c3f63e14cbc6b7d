"""MuJoCo-backed model terms (inertia, bias, passive and actuator forces) for the model-based observers.

This layer may import MuJoCo but not Gymnasium. It implements the dynamics protocol of
:mod:`smo_gym.observers.mechanical` so that the observers themselves stay free of MuJoCo.
"""

from .design import default_transform, dissipative_gains
from .dynamics import MASS_SCALE_RANGE, MujocoDynamics, calibrate_model_miss
from .regressor import MujocoParameterRegressor

__all__ = [
    "MASS_SCALE_RANGE",
    "MujocoDynamics",
    "MujocoParameterRegressor",
    "calibrate_model_miss",
    "default_transform",
    "dissipative_gains",
]
