"""The rollout helper samples where the wrapper samples: every ``sample_every`` physics steps, episode by episode."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.mujoco.inverted_pendulum_v5 import InvertedPendulumEnv

from smo_gym.wrappers.adapters import make_adapter
from smo_gym.wrappers.rollout import Episode, rollout


def _random_policy(space: gym.spaces.Box, seed: int):
    rng = np.random.default_rng(seed)
    return lambda _obs: rng.uniform(space.low, space.high).astype(space.dtype)


class _OwnStepping(InvertedPendulumEnv):
    """Steps its physics through its own ``_step_mujoco_simulation``: the substeps cannot be sampled."""

    def _step_mujoco_simulation(self, ctrl, n_frames):
        super()._step_mujoco_simulation(ctrl, n_frames)


def test_physics_rate_samples_are_consecutive_physics_steps():
    """HalfCheetah has hinge and slide joints only, and MuJoCo's semi-implicit Euler step makes
    ``qpos[k + 1] - qpos[k] = h qvel[k + 1]``: every pair of samples must be one physics step apart."""
    env = gym.make("HalfCheetah-v5")
    h, frame_skip = env.unwrapped.model.opt.timestep, env.unwrapped.frame_skip
    (episode,) = rollout(env, _random_policy(env.action_space, 0), 20, sample_every=1, seed=0)
    assert isinstance(episode, Episode)
    assert episode.qpos.shape == (1 + 20 * frame_skip, 9) and episode.qvel.shape == (1 + 20 * frame_skip, 9)
    np.testing.assert_allclose(np.diff(episode.qpos, axis=0), h * episode.qvel[1:], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(episode.qpos[-1], env.unwrapped.data.qpos)  # the last sample is the live state


def test_environment_rate_samples_are_the_states_after_each_step():
    env = gym.make("HalfCheetah-v5")
    frame_skip = env.unwrapped.frame_skip
    (fine,) = rollout(env, _random_policy(env.action_space, 1), 15, sample_every=1, seed=3)
    states = []
    policy = _random_policy(env.action_space, 1)
    env.reset(seed=3)
    states.append(env.unwrapped.data.qpos.copy())
    for _ in range(15):
        env.step(policy(None))
        states.append(env.unwrapped.data.qpos.copy())
    (coarse,) = rollout(env, _random_policy(env.action_space, 1), 15, seed=3)  # default: once per env step
    np.testing.assert_array_equal(coarse.qpos, np.array(states))
    np.testing.assert_array_equal(fine.qpos[::frame_skip], coarse.qpos)


def test_episodes_end_with_the_environment_and_restart_from_a_reset():
    """InvertedPendulum terminates when the pole passes 0.2 rad and resets within 0.01 rad of upright."""
    env = gym.make("InvertedPendulum-v5")
    steps = 60
    episodes = rollout(env, lambda _obs: np.array([3.0], dtype=np.float32), steps, seed=0)
    assert len(episodes) >= 3
    for episode in episodes:
        assert np.all(np.abs(episode.qpos[0]) <= 0.01)
    for episode in episodes[:-1]:
        assert abs(episode.qpos[-1, 1]) > 0.2  # ended by the termination
        assert np.all(np.abs(episode.qpos[:-1, 1]) <= 0.2)
    assert sum(len(e.qpos) - 1 for e in episodes) == steps  # every step sampled once, resets in addition


def test_environments_that_step_their_own_physics_are_sampled_at_the_end_of_each_step():
    own = gym.wrappers.TimeLimit(_OwnStepping(), 1000)
    assert not make_adapter(own).supports_substeps()
    with pytest.raises(ValueError, match=r"expected sample_every = frame_skip \(2\) on an environment whose"):
        rollout(own, _random_policy(own.action_space, 0), 5, sample_every=1)
    hooked = gym.wrappers.TimeLimit(InvertedPendulumEnv(), 1000)
    zero = lambda _obs: np.zeros(1, dtype=np.float32)
    ours = rollout(own, zero, 8, seed=5)
    reference = rollout(hooked, zero, 8, seed=5)
    assert len(ours) == len(reference)
    for a, b in zip(ours, reference, strict=True):
        np.testing.assert_array_equal(a.qpos, b.qpos)
        np.testing.assert_array_equal(a.qvel, b.qvel)


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"steps": 0}, ValueError, "expected steps >= 1, actual value: 0"),
        ({"steps": 2.5}, TypeError, "expected steps to be an integer >= 1, actual value: 2.5"),
        ({"steps": 3, "sample_every": 0}, ValueError, r"expected sample_every in \[1, 2\], actual value: 0"),
        ({"steps": 3, "sample_every": 3}, ValueError, r"expected sample_every in \[1, 2\], actual value: 3"),
    ],
)
def test_bad_arguments_are_named(kwargs, error, message):
    env = gym.make("InvertedPendulum-v5")
    with pytest.raises(error, match=message):
        rollout(env, _random_policy(env.action_space, 0), **kwargs)
