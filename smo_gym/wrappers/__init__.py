"""Wrappers: the only layer that knows Gymnasium (and, through adapters, simulator) conventions.

:class:`EstimatedVelocity` runs a MuJoCo environment through a joint sensor and a velocity observer;
:mod:`smo_gym.wrappers.sensing` is the simulator-agnostic core it shares with the CLI and the benchmarks, and
:mod:`smo_gym.wrappers.adapters` the small interface to a simulator's MuJoCo objects.
"""

from __future__ import annotations

from . import adapters, sensing
from .adapters import CONTACT_FORCES, GymnasiumMujocoAdapter, MujocoAdapter, make_adapter, register_adapter
from .dm_control import DmControlAdapter, make_dm_control  # registers the dm_control adapter (lazy imports)
from .estimated_velocity import EstimatedVelocity
from .monitored import Monitored
from .vec import JointSensor, VectorEstimatedVelocity, sensing_config

__all__ = [
    "CONTACT_FORCES",
    "DmControlAdapter",
    "EstimatedVelocity",
    "GymnasiumMujocoAdapter",
    "JointSensor",
    "Monitored",
    "MujocoAdapter",
    "VecEstimatedVelocity",
    "VectorEstimatedVelocity",
    "adapters",
    "make_adapter",
    "make_dm_control",
    "register_adapter",
    "sensing",
    "sensing_config",
]


def __getattr__(name):  # VecEstimatedVelocity imports Stable-Baselines3 (and torch): only when asked for
    if name == "VecEstimatedVelocity":
        from .sb3 import VecEstimatedVelocity

        return VecEstimatedVelocity
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
