"""The wrapper's batched update: at ``rate="physics"`` the samples of one control period go through
``Observer.run`` in one compiled call; that must give exactly what per-sample ``update`` calls give (``run`` is
documented as ``update`` row by row), for observers with very different state machines, on a model with a free
joint (tangent coordinates) and one without."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from smo_gym.engine import VelocityEstimator
from smo_gym.wrappers import EstimatedVelocity


class PerSample(VelocityEstimator):
    """A subclass: the wrapper keeps the per-sample path for it."""


@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Ant-v5"])
@pytest.mark.parametrize("observer", ["super-twisting", "kalman-ca", "switched-gain", "levant"])
def test_batched_run_equals_per_sample_updates(env_id, observer):
    batched = EstimatedVelocity(gym.make(env_id), observer=observer, rate="physics")
    single = EstimatedVelocity(gym.make(env_id), observer=observer, rate="physics")
    single.estimator = PerSample(single.estimator.observer, mean_over=single.estimator.mean_over)
    a, _ = batched.reset(seed=1)
    b, _ = single.reset(seed=1)
    batched._fused = None  # the general path, whose batched call this is (the compiled one has its own tests)
    runs = []
    run = batched.observer.run
    batched.observer.run = lambda Y, **kw: runs.append(len(Y)) or run(Y, **kw)
    rng = np.random.default_rng(0)
    for _ in range(25):
        action = rng.uniform(-1, 1, batched.action_space.shape).astype(batched.action_space.dtype)
        a, _, _, _, ia = batched.step(action)
        b, _, _, _, ib = single.step(action)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(ia["smo"]["qvel_estimate"], ib["smo"]["qvel_estimate"])
    assert batched.observer.n_updates == single.observer.n_updates == 25 * batched.adapter.frame_skip
    assert runs == [batched.adapter.frame_skip] * 25  # one batched call per control period
