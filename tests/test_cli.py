"""``smo-gym compare``: the CLI runs, and its numbers are the wrapper's numbers on the same measurements."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from smo_gym import cli
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers import compare as lib


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SMO_GYM_CACHE_DIR", str(tmp_path / "cache"))


def test_compare_prints_table_and_writes_png(tmp_path, capsys):
    out = tmp_path / "cmp.png"
    code = cli.main(["compare", "--env", "InvertedPendulum-v5", "--steps", "60", "--seed", "1", "--out", str(out),
                     "--observers", "super-twisting,finite-difference,levant:order=1:discretization=matching",
                     "--per-joint", "--joints", "hinge,0", "--sensor", "low-cost", "--rate", "1"])
    text = capsys.readouterr().out
    assert code == 0
    for word in ("observer", "RMSE", "max err", "conv. [s]", "us/step", "super-twisting",
                 "levant:order=1:discretization=matching", "RMSE per dof", "slider", "hinge"):
        assert word in text
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_finite_difference_row_is_the_backward_difference_of_the_measurements():
    rec = lib.record_rollout("Hopper-v5", sensor="encoder-12bit-noisy", steps=40, seed=2)
    (fd,) = lib.compare_observers(rec, ["finite-difference"])
    starts = set(rec.episode_starts.tolist())
    for i in range(1, len(rec.z_measured)):
        if i not in starts and i - 1 not in starts:
            np.testing.assert_allclose(fd.velocity[i], (rec.z_measured[i] - rec.z_measured[i - 1]) / rec.dt,
                                       rtol=1e-12, atol=1e-9)
    # the max error is over the samples after convergence, so it cannot exceed the max over all samples
    assert 0 < fd.max_error <= np.max(np.abs(fd.velocity - rec.qvel)) + 1e-12


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Ant-v5"])
def test_compare_uses_the_wrappers_code_path(env_id):
    """Same seed, policy and sensor: the comparison's estimates equal the wrapper's at every control period."""
    seed, steps = 3, 30
    rec = lib.record_rollout(env_id, sensor="encoder-12bit-noisy", steps=steps, seed=seed)
    (sta,) = lib.compare_observers(rec, ["super-twisting"])
    env = EstimatedVelocity(gym.make(env_id), sensor="encoder-12bit-noisy")
    policy = lib.smooth_random_policy(env.action_space, seed)
    obs, info = env.reset(seed=seed)
    fs = env.adapter.frame_skip
    for k in range(steps):
        obs, _, term, trunc, info = env.step(policy(obs))
        if term or trunc:
            break
        np.testing.assert_array_equal(info["smo"]["qvel_estimate"], sta.velocity[(k + 1) * fs])
        np.testing.assert_array_equal(info["smo"]["qvel"], rec.qvel[(k + 1) * fs])


def test_bad_input_exit_codes(capsys):
    assert cli.main(["compare", "--observers", "magic", "--steps", "5"]) == 2
    assert "super-twisting" in capsys.readouterr().err
    assert cli.main(["compare", "--env", "Hopper-v5", "--rate", "3", "--steps", "5"]) == 2
    assert "divisor of frame_skip=4" in capsys.readouterr().err
    assert cli.main(["compare", "--sensor", "nope", "--steps", "5"]) == 2
    assert "low-cost" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main([])


def test_environment_ids_of_dm_control_need_no_import_first():
    """``smo-gym compare/train/evaluate --env dm_control/...`` make their environments with ``smo_gym.envs.make``,
    which registers shimmy's ids itself: checked in a fresh interpreter (here shimmy may already be imported)."""
    import os
    import subprocess
    import sys

    code = ("import sys; from smo_gym.envs import make; assert 'shimmy' not in sys.modules; "
            "env = make('dm_control/cartpole-swingup-v0'); env.reset(seed=0); env.close()")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                            env={**os.environ, "MUJOCO_GL": "disable"})
    assert result.returncode == 0, result.stderr[-2000:]
