r"""The bare model's random-action rollout that the wrapper's calibration falls back on.

The default gains come from a :class:`smo_gym.calibration.Calibration` of the joints at the observer's sampling
step, measured on a short rollout of the environment itself (its own resets and random actions; see
:class:`~smo_gym.wrappers.EstimatedVelocity`). Where the environment cannot be copied, the calibration rolls out the
bare MuJoCo model instead (:func:`model_rollout_velocities`): no Gymnasium here.
"""

from __future__ import annotations

import mujoco
import numpy as np

__all__ = ["model_rollout_velocities"]


def model_rollout_velocities(
    model: mujoco.MjModel,
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    frame_skip: int,
    sample_every: int,
    *,
    steps: int = 2000,
    episode: int = 500,
    seed: int = 0,
) -> list[np.ndarray]:
    r"""``qvel`` sampled every ``sample_every`` physics steps of ``model`` under a random policy, per episode.

    From ``(qpos0, qvel0)`` the model is stepped ``steps`` physics steps with actions drawn uniformly from the
    actuators' control ranges and held for ``frame_skip`` steps, restarting every ``episode`` steps (and on a
    non-finite state). The fallback of the wrapper's calibration when the environment itself cannot be copied.

    Returns
    -------
    list of ndarray, shape (T_i, nv)
    """
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(model)
    lo, hi = np.array(model.actuator_ctrlrange, dtype=float).T if model.nu else (np.zeros(0), np.zeros(0))
    limited = np.asarray(model.actuator_ctrllimited, dtype=bool) if model.nu else np.zeros(0, dtype=bool)
    lo = np.where(limited, lo, -1.0)
    hi = np.where(limited, hi, 1.0)
    samples: list[np.ndarray] = []
    episodes: list[np.ndarray] = []

    def restart():
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos0
        data.qvel[:] = qvel0
        mujoco.mj_forward(model, data)

    restart()
    for k in range(steps):
        if k % frame_skip == 0:
            data.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(model, data)
        if not np.all(np.isfinite(data.qvel)) or (k + 1) % episode == 0:
            if samples:
                episodes.append(np.array(samples))
            samples = []
            restart()
            continue
        if (k + 1) % sample_every == 0:
            samples.append(data.qvel.copy())
    if samples:
        episodes.append(np.array(samples))
    return episodes
