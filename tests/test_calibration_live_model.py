"""The calibration of the default gains runs on the live model, and its on-disk cache key is stable."""

from __future__ import annotations

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

from smo_gym._cache import calibration_key, stable_repr
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers.adapters import make_adapter
from smo_gym.wrappers.estimated_velocity import rollout_velocities


def _edited_hopper():
    env = gym.make("Hopper-v5")
    model = env.unwrapped.model
    model.opt.timestep = 5e-4  # a quarter of the XML's
    model.body_mass[1:] *= 1.7
    return env


def test_calibration_rollout_runs_the_live_model():
    """The rollout's velocities are those of the edited environment itself (same seed, same actions): the
    regression rolled out a copy rebuilt from the XML, with the old timestep and masses, and then divided by the
    live timestep (bounds off by the ratio of the steps)."""
    env = _edited_hopper()
    unwrapped = env.unwrapped
    frame_skip = unwrapped.frame_skip
    episodes = rollout_velocities(make_adapter(unwrapped), frame_skip, 40 * frame_skip, seed=0)
    reference = _edited_hopper().unwrapped
    reference.reset(seed=0)
    space = reference.action_space
    space.seed(0)
    expected = [reference.data.qvel.copy()]
    for _ in range(len(episodes[0]) - 1):
        reference.step(space.sample())
        expected.append(reference.data.qvel.copy())
    np.testing.assert_array_equal(episodes[0], np.array(expected))
    assert unwrapped.model.opt.timestep == 5e-4  # the live environment is not touched


def test_calibrated_bounds_scale_with_the_live_timestep():
    """Acceleration bounds sampled every physics step at a quarter of the step: of the order of those at the
    original step (the accelerations are physical), not four times larger (the regression: divided by the live
    step, rolled out at the XML's)."""
    plain = EstimatedVelocity(gym.make("Hopper-v5"), disk_cache=False, calibration_steps=2000)
    edited_env = gym.make("Hopper-v5")
    edited_env.unwrapped.model.opt.timestep = 5e-4
    edited = EstimatedVelocity(edited_env, disk_cache=False, calibration_steps=8000)
    assert edited.sample_dt == 5e-4
    edited_bounds, plain_bounds = edited.calibration.bound(2), plain.calibration.bound(2)
    ratio = np.median(edited_bounds / plain_bounds)
    assert 0.3 < ratio < 2.5, (edited_bounds, plain_bounds)


def test_cache_key_changes_with_the_model():
    env = gym.make("Hopper-v5")
    key = calibration_key(make_adapter(env).environment_key, env.unwrapped.model, derivative=2)
    assert key == calibration_key(make_adapter(env).environment_key, env.unwrapped.model, derivative=2)
    env.unwrapped.model.body_mass[2] *= 2
    assert key != calibration_key(make_adapter(env).environment_key, env.unwrapped.model, derivative=2)


_KEY_SCRIPT = """
import numpy as np, gymnasium as gym, smo_gym
from smo_gym.wrappers.adapters import make_adapter
from smo_gym._cache import calibration_key
scale = {scale}
env = gym.make("smo_gym/TwoLinkArm-v0", disturbance=lambda t: [scale * np.sin(t), 0.0])
print(calibration_key(make_adapter(env).environment_key, env.unwrapped.model, derivative=2))
"""


def _key_in_new_process(scale: float) -> str:
    out = subprocess.run(
        [sys.executable, "-c", _KEY_SCRIPT.format(scale=scale)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "MUJOCO_GL": "disable"},
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_cache_key_is_the_same_in_every_process():
    """The regression: a callable constructor argument entered the key by its repr, with its memory address, so
    every process made a new cache entry. The same function gives the same key; a different one another key."""
    first, second, other = _key_in_new_process(0.5), _key_in_new_process(0.5), _key_in_new_process(0.7)
    assert first == second
    assert first != other
    assert "0x" not in first


@pytest.mark.parametrize(
    "value, expected",
    [
        ({"b": 1, "a": [1.5, "x"]}, "{'a': list(1.5, 'x'), 'b': 1}"),
        (object(), "<object object>"),
    ],
)
def test_stable_repr(value, expected):
    assert stable_repr(value) == expected
