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
    "check_env_id",
    "make",
    "register_envs",
]


def check_env_id(env_id: str) -> str:
    """``env_id`` after checking that Gymnasium knows it, with the namespaces smo_gym works with registered first
    (its own environments and dm_control's suite, which shimmy registers when imported). An id that names a module
    to import first (``"module:Env-v0"``) is left to ``gymnasium.make``.

    Raises
    ------
    TypeError
        ``env_id`` is not a string.
    ValueError
        An unknown id, with the closest registered one.
    """
    import difflib

    if not isinstance(env_id, str):
        raise TypeError(f"expected env_id to be a Gymnasium environment id (a str), actual value: {env_id!r:.80}")
    if env_id.startswith("dm_control/"):
        from .._extras import require

        require("shimmy", "dm_control")  # registers the dm_control/... ids
    if ":" in env_id or env_id in gym.registry:
        return env_id
    match = difflib.get_close_matches(env_id, list(gym.registry), n=1, cutoff=0.6)
    hint = f" (did you mean {match[0]!r}?)" if match else ""
    raise ValueError(f"expected a registered Gymnasium environment id, actual value: {env_id!r}{hint}")


def make(env_id: str, **kwargs) -> gym.Env:
    """``gymnasium.make(env_id, **kwargs)`` after :func:`check_env_id`, which registers the namespaces smo_gym works
    with first: its own environments (this module) and dm_control's suite, ``dm_control/<domain>-<task>-v0``
    (Gymnasium 1.x has no plugin entry points, so ``gymnasium.make`` alone does not find them)."""
    return gym.make(check_env_id(env_id), **kwargs)
