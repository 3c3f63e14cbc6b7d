r"""One rollout loop: an environment stepped by a policy, its true joint state sampled at the observer's rate.

Every tool that needs true trajectories of a MuJoCo environment (the observer comparison of
:mod:`smo_gym.experiments.compare`, the benchmarks, the calibration of default gains) records them here, so that
they sample exactly where :class:`~smo_gym.wrappers.EstimatedVelocity` samples: every ``sample_every`` physics
steps inside ``frame_skip``, through the adapter's substep hook
(:meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.record_substeps`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import _extras as extras
from .._validation import check_int_at_least, check_int_in_range
from .adapters import MujocoAdapter, SubstepRecording, make_adapter

__all__ = ["Episode", "rollout", "smooth_random_policy"]


@dataclass(frozen=True)
class Episode:
    """The sampled true joint state of one episode.

    Attributes
    ----------
    qpos : ndarray, shape (T, nq)
        Configurations; row 0 is the state after the reset, row ``i`` the state ``i * sample_every`` physics steps
        later.
    qvel : ndarray, shape (T, nv)
        Velocities at the same samples.
    ctrl : ndarray, shape (T, nu)
        The ``ctrl`` of the physics step that ended at each sample (row 0: after the reset).
    """

    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray


def rollout(
    env,
    policy: Callable[[object], object],
    steps: int,
    *,
    sample_every: int | None = None,
    seed: int | None = None,
    adapter: MujocoAdapter | None = None,
    progress: str | None = None,
) -> list[Episode]:
    r"""Step ``env`` ``steps`` times with ``policy`` and sample ``qpos`` and ``qvel`` every ``sample_every``
    physics steps.

    The environment is reset with ``seed`` first; an episode ends when the environment reports ``terminated`` or
    ``truncated`` or its velocity is no longer finite, and the environment is then reset without a seed
    (continuing its random stream) unless that was the last step. Samples are taken after the reset and then
    after every ``sample_every``-th physics step of the episode, counted across environment steps, so that with
    ``frame_skip`` physics steps per environment step and ``sample_every = frame_skip`` the samples are the
    states after every environment step.

    Parameters
    ----------
    env : gymnasium.Env
        A MuJoCo environment that :func:`~smo_gym.wrappers.adapters.make_adapter` recognises (any wrappers on
        top), or its unwrapped environment.
    policy : callable
        ``policy(observation) -> action``, called once per environment step with the latest observation.
    steps : int
        Environment steps, ``>= 1``.
    sample_every : int, optional
        Physics steps between samples, in ``[1, frame_skip]`` (default ``frame_skip``: once per environment
        step). Below ``frame_skip`` the environment must support sampling inside ``frame_skip``
        (:meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.supports_substeps`).
    seed : int, optional
        Seed of the first reset.
    adapter : MujocoAdapter, optional
        The adapter of ``env`` (default: :func:`~smo_gym.wrappers.adapters.make_adapter` of ``env``).
    progress : str, optional
        Show a progress bar with this description (``tqdm``, when installed).

    Returns
    -------
    list of Episode
        The episodes in order; the last one ends with the last step.

    Raises
    ------
    ValueError
        ``steps < 1``, ``sample_every`` out of range, or ``sample_every < frame_skip`` on an environment whose
        physics steps cannot be sampled.

    Examples
    --------
    >>> import gymnasium as gym
    >>> env = gym.make("HalfCheetah-v5")  # frame_skip = 5, never terminates
    >>> (episode,) = rollout(env, lambda obs: env.action_space.sample(), 10, sample_every=1, seed=0)
    >>> episode.qpos.shape  # the reset state and five physics steps per environment step
    (51, 9)
    """
    steps = check_int_at_least("steps", steps, 1)
    adapter = make_adapter(env) if adapter is None else adapter
    frame_skip = adapter.frame_skip
    every = frame_skip if sample_every is None else check_int_in_range("sample_every", sample_every, 1, frame_skip)
    hook = adapter.supports_substeps()
    if every < frame_skip and not hook:
        raise ValueError(
            f"expected sample_every = frame_skip ({frame_skip}) on an environment whose physics steps cannot be "
            f"sampled, actual value: {every}"
        )
    episodes: list[Episode] = []
    model = adapter.model
    sizes = {"qpos": model.nq, "qvel": model.nv, "ctrl": model.nu}  # the fields of an Episode, in order
    recording = SubstepRecording(every, sizes, frame_skip // every)
    recorder = adapter.record_substeps(recording) if hook else contextlib.nullcontext()
    obs, _ = env.reset(seed=seed)
    rows = {name: [np.array(getattr(adapter.data, name))] for name in sizes}
    recording.start()  # samples are counted in physics steps across environment steps, from the reset
    iterator = range(steps)
    if progress:
        iterator = extras.progress(iterator, desc=progress, unit="step")
    for step in iterator:
        recording.n = 0
        with recorder:
            obs, _, terminated, truncated, _ = env.step(policy(obs))
        if not hook:  # sample_every == frame_skip: one sample at the end of the step
            recording.take(adapter.data)
        for name, taken in rows.items():
            taken.extend(recording.rows[name][: recording.n].copy())
        if terminated or truncated or not np.all(np.isfinite(adapter.data.qvel)):
            episodes.append(Episode(*map(np.array, rows.values())))
            rows = {name: [] for name in sizes}
            recording.start()
            if step < steps - 1:
                obs, _ = env.reset()
                rows = {name: [np.array(getattr(adapter.data, name))] for name in sizes}
    if rows["qpos"]:
        episodes.append(Episode(*map(np.array, rows.values())))
    return episodes


def smooth_random_policy(action_space, seed: int, smoothing: float = 0.9):
    r"""A seeded low-pass random policy :math:`a_{k+1} = s a_k + (1 - s) u_k`, :math:`u_k` uniform in the box.

    Returns a function ``policy(obs) -> action`` (the observation is ignored).
    """
    rng = np.random.default_rng(seed)
    low, high = action_space.low, action_space.high
    state = {"a": np.zeros(action_space.shape)}

    def policy(_obs):
        state["a"] = smoothing * state["a"] + (1.0 - smoothing) * rng.uniform(low, high)
        return state["a"].astype(action_space.dtype)

    return policy
