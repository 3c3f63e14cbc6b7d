"""Gymnasium environments of smo_gym (MuJoCo models shipped as package data).

Importing this module registers:

==================================  ==========================================================================
``smo_gym/VariableInertia-v0``      one-DOF pendulum with configuration-dependent inertia (Coriolis transform)
``smo_gym/TwoLinkArm-v0``           two-link planar arm with an external joint-torque disturbance input
``smo_gym/FurutaPendulum-v0``       Furuta pendulum with a matched disturbance input
==================================  ==========================================================================

Without importing it first, ``gymnasium.make("smo_gym.envs:smo_gym/TwoLinkArm-v0")`` imports and registers them
(Gymnasium 1.x has no plugin entry points).
"""

from __future__ import annotations

import gymnasium as gym
from gymnasium.envs.registration import register, registry

from .base import ASSETS, SmoMujocoEnv, asset_path
from .mechanisms import FurutaPendulumEnv, TwoLinkArmEnv, VariableInertiaEnv

__all__ = ["ASSETS", "ENV_IDS", "FurutaPendulumEnv", "SmoMujocoEnv", "TwoLinkArmEnv", "VariableInertiaEnv",
           "asset_path", "make", "register_envs"]

#: id -> (entry point, max_episode_steps)
ENV_IDS = {
    "smo_gym/VariableInertia-v0": ("smo_gym.envs.mechanisms:VariableInertiaEnv", 1000),
    "smo_gym/TwoLinkArm-v0": ("smo_gym.envs.mechanisms:TwoLinkArmEnv", 1000),
    "smo_gym/FurutaPendulum-v0": ("smo_gym.envs.mechanisms:FurutaPendulumEnv", 1000),
}


def register_envs() -> None:
    """Register the environments with Gymnasium (idempotent)."""
    for env_id, (entry_point, steps) in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=entry_point, max_episode_steps=steps)


register_envs()


def make(env_id: str, **kwargs) -> gym.Env:
    """``gymnasium.make(env_id, **kwargs)`` with the namespaces smo_gym works with registered first: its own
    environments (this module) and dm_control's suite, ``dm_control/<domain>-<task>-v0``, which shimmy registers
    when imported (Gymnasium 1.x has no plugin entry points, so ``gymnasium.make`` alone does not find them)."""
    if env_id.startswith("dm_control/"):
        import shimmy  # noqa: F401 - registers the dm_control/... ids
    return gym.make(env_id, **kwargs)
