"""The calibrations shipped with the package: looked up after the user's cache, equal to what the wrapper computes,
and what spares a new process the calibration of Gymnasium's MuJoCo environments with the wrapper's defaults."""

from __future__ import annotations

import json
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
import shimmy  # noqa: F401  (registers the dm_control/... ids)
from conftest import load_script

from smo_gym import _cache
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers import estimated_velocity as ev_module

ship = load_script("ship_calibrations")


@pytest.fixture
def fresh_process(monkeypatch, tmp_path):
    """An empty user cache and an empty memory: what a new process on a new machine starts from."""
    monkeypatch.setenv("SMO_GYM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_cache, "_MEMORY_CACHE", {})
    return tmp_path


def test_the_shipped_file_covers_every_environment_at_both_rates():
    shipped = json.loads(_cache.SHIPPED_FILE.read_text())
    entries = Counter(key.split(":", 1)[1] for key in shipped)
    assert set(entries) == set(ship.ENVS)
    # per environment and rate: the calibration levels and the trial errors of "auto"; the dm_control tasks that
    # step the physics once per environment step sample the same at both rates, under the same keys
    for env_id in ship.ENVS:
        expected = (2, 2 * len(ship.RATES)) if env_id.startswith("dm_control/") else (2 * len(ship.RATES),)
        assert entries[env_id] in expected, (env_id, entries[env_id])
    for key, value in shipped.items():
        assert len(key.split(":", 1)[0]) == 16
        value = np.asarray(value, dtype=float)
        assert value.ndim == 2 and np.isfinite(value).all(), key


@pytest.mark.parametrize(
    "env_id, rate",
    # the default environment of the demo and the benchmarks at the default rate, and a small one at both
    [("InvertedPendulum-v5", "physics"), ("InvertedPendulum-v5", "env"), ("Hopper-v5", "physics")],
)
def test_shipped_calibration_is_what_the_wrapper_computes(fresh_process, env_id, rate):
    """Recomputed here (``disk_cache=False`` reads neither the user's file nor the shipped one): the same keys and
    the same numbers, up to rounding (another CPU may round the rollouts differently in the last bits). A change to
    the calibration, the trials or the candidates of ``"auto"`` fails here until ``scripts/ship_calibrations.py``
    is rerun."""
    EstimatedVelocity(gym.make(env_id), rate=rate, disk_cache=False)
    computed = _cache.memory_entries()
    shipped = json.loads(_cache.SHIPPED_FILE.read_text())
    assert len(computed) == 2
    for key, value in computed.items():
        assert key in shipped, f"{key} is not shipped: rerun scripts/ship_calibrations.py"
        np.testing.assert_allclose(shipped[key], value, rtol=1e-9, atol=1e-12)
    assert not (fresh_process / "calibration.json").exists()


@pytest.mark.parametrize("env_id", ["Hopper-v5", "dm_control/cheetah-run-v0"])
def test_a_shipped_environment_is_not_calibrated_again(fresh_process, monkeypatch, env_id):
    def fail(*args, **kwargs):
        raise AssertionError("calibrated instead of reading the shipped calibration")

    for name in ("rollout_velocities", "model_rollout_velocities", "sensed_trials"):
        monkeypatch.setattr(ev_module, name, fail)
    env = EstimatedVelocity(gym.make(env_id))
    assert env.observer.selection.source == "trials"
    env.reset(seed=0)
    env.step(env.action_space.sample())
    # a shipped calibration is not copied into the user's cache
    assert not (fresh_process / "calibration.json").exists()
    # a setting of one's own misses the shipped file and is calibrated
    with pytest.raises(AssertionError, match="calibrated instead"):
        EstimatedVelocity(gym.make(env_id), calibration_quantile=0.95)


def test_lookup_order_is_memory_then_the_users_file_then_the_shipped_file(fresh_process, monkeypatch):
    shipped_file = fresh_process / "shipped.json"
    shipped_file.write_text(json.dumps({"k:shipped": [1.0], "k:both": [2.0]}))
    (fresh_process / "calibration.json").write_text(json.dumps({"k:both": [3.0]}))
    monkeypatch.setattr(_cache, "SHIPPED_FILE", shipped_file)
    _cache._shipped.cache_clear()
    try:

        def compute():
            return [4.0]

        assert _cache.cached_bounds("k:shipped", compute).tolist() == [1.0]
        assert _cache.cached_bounds("k:both", compute).tolist() == [3.0]  # the user's file first
        assert _cache.cached_bounds("k:new", compute).tolist() == [4.0]
        assert _cache.cached_bounds("k:other", compute, disk=False).tolist() == [4.0]
        monkeypatch.setattr(_cache, "_MEMORY_CACHE", {})
        assert _cache.cached_bounds("k:shipped", compute, disk=False).tolist() == [4.0]  # no disk: not shipped
        stored = json.loads((fresh_process / "calibration.json").read_text())
        assert stored == {"k:both": [3.0], "k:new": [4.0]}  # computed values go to the user's file, shipped do not
    finally:
        _cache._shipped.cache_clear()
