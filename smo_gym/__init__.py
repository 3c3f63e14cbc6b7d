"""smo_gym: realistic sensing for Gymnasium and MuJoCo.

Joint positions come from a sensor model; velocities are estimated online by sliding-mode, higher-order
sliding-mode and high-gain observers, the way a real controller would have to.

``smo_gym.wrappers`` (Gymnasium/MuJoCo) is imported on demand: ``from smo_gym import wrappers``.
"""

from . import design, observers, sensors
from ._validation import DivergenceError
from .offline import differentiate

__version__ = "0.1.0"
__all__ = ["DivergenceError", "__version__", "design", "differentiate", "observers", "sensors"]
