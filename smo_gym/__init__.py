"""smo_gym: realistic sensing for Gymnasium and MuJoCo.

Joint positions come from a sensor model; velocities are estimated online by sliding-mode, higher-order
sliding-mode and high-gain observers, the way a real controller would have to.

``smo_gym.wrappers``, ``smo_gym.control``, ``smo_gym.mechanics`` and ``smo_gym.envs`` import Gymnasium and/or
MuJoCo, so they load on first access (``from smo_gym import wrappers`` or ``smo_gym.wrappers``), keeping
``import smo_gym`` light for pure signal processing. ``import smo_gym`` registers the project's environments with
Gymnasium (``smo_gym/TwoLinkArm-v0``, ...; their MuJoCo code loads when one is made).
"""

from . import design, observers, sensors
from ._registration import register_envs
from ._validation import DivergenceError
from .offline import differentiate

_LAZY_SUBMODULES = (
    "control",
    "engine",
    "envs",
    "experiments",
    "fault_detection",
    "identification",
    "mechanics",
    "monitors",
    "nonlinear_observers",
    "wrappers",
)


def __getattr__(name: str):
    """Load the heavy submodules on first attribute access (PEP 562)."""
    if name in _LAZY_SUBMODULES:
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


register_envs()  # gymnasium.make("smo_gym/...") works after a plain ``import smo_gym``

#: the version of the package (as in ``pyproject.toml``)
__version__ = "0.1.0"
__all__ = ["DivergenceError", "__version__", "design", "differentiate", "observers", "sensors"]
