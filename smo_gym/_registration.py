"""Gymnasium registration of smo_gym's environments, run by ``import smo_gym``.

Only the ids and entry points live here (strings: nothing of MuJoCo is imported until ``gymnasium.make`` builds
an environment), so that registering costs no more than importing Gymnasium's registry.
"""

from __future__ import annotations

__all__ = ["ENV_IDS", "register_envs"]

#: id -> (entry point, max_episode_steps)
ENV_IDS = {
    "smo_gym/VariableInertia-v0": ("smo_gym.envs.mechanisms:VariableInertiaEnv", 1000),
    "smo_gym/TwoLinkArm-v0": ("smo_gym.envs.mechanisms:TwoLinkArmEnv", 1000),
    "smo_gym/FurutaPendulum-v0": ("smo_gym.envs.mechanisms:FurutaPendulumEnv", 1000),
}


def register_envs() -> None:
    """Register the environments with Gymnasium (idempotent)."""
    from gymnasium.envs.registration import register, registry

    for env_id, (entry_point, steps) in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=entry_point, max_episode_steps=steps)
