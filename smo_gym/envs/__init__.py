"""Gymnasium environments of smo_gym (MuJoCo models shipped as package data).

``import smo_gym`` registers (:mod:`smo_gym._registration`):

==================================  ==========================================================================
``smo_gym/VariableInertia-v0``      one-DOF pendulum with configuration-dependent inertia (Coriolis transform)
``smo_gym/TwoLinkArm-v0``           two-link planar arm with an external joint-torque disturbance input
``smo_gym/FurutaPendulum-v0``       Furuta pendulum with a matched disturbance input
==================================  ==========================================================================

``gymnasium.make("smo_gym.envs:smo_gym/TwoLinkArm-v0")`` imports smo_gym first, and so works without an import
of one's own (Gymnasium 1.x has no plugin entry points).
"""

from __future__ import annotations

import gymnasium as gym

from .._registration import ENV_IDS, register_envs
from .base import ASSETS, SmoMujocoEnv, asset_path
from .mechanisms import FurutaPendulumEnv, TwoLinkArmEnv, VariableInertiaEnv

__all__ = [
    "ASSETS",
    "ENV_IDS",
    "FurutaPendulumEnv",
    "SmoMujocoEnv",
    "TwoLinkArmEnv",
    "VariableInertiaEnv",
    "asset_path",
    "make",
    "register_envs",
]


def make(env_id: str, **kwargs) -> gym.Env:
    """``gymnasium.make(env_id, **kwargs)`` with the namespaces smo_gym works with registered first: its own
    environments (this module) and dm_control's suite, ``dm_control/<domain>-<task>-v0``, which shimmy registers
    when imported (Gymnasium 1.x has no plugin entry points, so ``gymnasium.make`` alone does not find them)."""
    if env_id.startswith("dm_control/"):
        from .._extras import require

        require("shimmy", "dm_control")  # registers the dm_control/... ids
    return gym.make(env_id, **kwargs)
