"""smo_gym.rl: sensings, velocity masking, training and cross-sensing evaluation, and the CLI."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from smo_gym import rl

TINY_PPO = dict(n_steps=64, batch_size=32, n_epochs=1)


def test_velocity_entries_found_generically():
    # Hopper-v5's observation is qpos[1:] (5 entries) then clip(qvel, -10, 10) (6 entries), per Gymnasium's docs
    env = gym.make("Hopper-v5")
    env.reset(seed=0)
    np.testing.assert_array_equal(rl.velocity_entries(env), np.arange(5, 11))
    # InvertedDoublePendulum-v5: [x, sin q, cos q] (5), qvel (3), constraint force (1, zero without contact)
    env = gym.make("InvertedDoublePendulum-v5")
    env.reset(seed=0)
    assert set(rl.velocity_entries(env)) >= {5, 6, 7}
    assert not set(rl.velocity_entries(env)) & {0, 1, 2, 3, 4}


def test_sensings_shapes_and_masking():
    true = rl.make_env("Hopper-v5", "true")
    masked = rl.make_env("Hopper-v5", "no-velocity")
    stacked = rl.make_env("Hopper-v5", "stacked-positions")
    assert masked.observation_space.shape == true.observation_space.shape == (11,)
    assert stacked.observation_space.shape == (10,)  # two frames of the 5 position entries
    o, _ = masked.reset(seed=1)
    np.testing.assert_array_equal(o[5:], 0.0)
    s0, _ = stacked.reset(seed=1)
    np.testing.assert_array_equal(s0[:5], s0[5:])  # first frame repeated at reset
    s1, *_ = stacked.step(np.ones(3))
    np.testing.assert_array_equal(s1[:5], s0[5:])  # the previous frame moved down
    with pytest.raises(ValueError, match="expected sensing in"):
        rl.make_env("Hopper-v5", "psychic")


def test_train_evaluate_cross_sensing(tmp_path):
    out = tmp_path / "run"
    summary = rl.train("InvertedDoublePendulum-v5", sensing="true", steps=128, seed=0, out=out,
                       hyperparams=TINY_PPO, evaluate_at=[64, 128], eval_sensings=["true", "estimated"],
                       eval_episodes=2, checkpoint_every=64)
    assert {(e["steps"], e["sensing"]) for e in summary["evaluations"]} == {
        (64, "true"), (64, "estimated"), (128, "true"), (128, "estimated")}
    assert all(e["trained_steps"] >= e["steps"] for e in summary["evaluations"])
    assert (out / "model.zip").exists() and (out / "vecnormalize.pkl").exists()
    assert (out / "progress.csv").exists() and list((out / "checkpoints").glob("*.zip"))
    assert json.loads((out / "run.json").read_text())["sensing"] == "true"
    for sensing in ("estimated", "finite-difference", "no-velocity"):
        res = rl.evaluate(out, sensing=sensing, episodes=2)
        assert res["sensing"] == sensing and len(res["returns"]) == 2
        assert np.all(np.isfinite(res["returns"])) and min(res["returns"]) > 0
    with pytest.raises(ValueError, match="observation shape"):
        rl.evaluate(out, sensing="stacked-positions", episodes=1)


def test_vectorized_sensing_in_training(tmp_path):
    from smo_gym.wrappers import VecEstimatedVelocity

    venv = rl.make_vec("InvertedDoublePendulum-v5", "estimated", n_envs=2, rate="env")
    assert isinstance(venv, VecEstimatedVelocity)
    venv.close()
    summary = rl.train("InvertedDoublePendulum-v5", sensing="estimated", rate="env", steps=128, n_envs=2,
                       out=tmp_path / "v", hyperparams=TINY_PPO)
    assert summary["trained_steps"] >= 128


def test_sac_learns_briefly(tmp_path):
    summary = rl.train("InvertedDoublePendulum-v5", sensing="estimated", algo="SAC", steps=80, out=tmp_path / "s",
                       hyperparams=dict(learning_starts=40, batch_size=16))
    assert summary["algo"] == "SAC" and summary["trained_steps"] >= 80 and not summary["normalize"]
    assert np.isfinite(rl.evaluate(tmp_path / "s", sensing="true", episodes=1)["mean"])


def test_cli_train_and_evaluate(tmp_path, capsys):
    from smo_gym.cli import main

    out = tmp_path / "cli"
    assert main(["train", "--env", "InvertedDoublePendulum-v5", "--steps", "64", "--out", str(out),
                 "--no-progress", "--checkpoint-every", "0", "--eval-episodes", "1"]) == 0
    assert "steps/s" in capsys.readouterr().out
    assert main(["evaluate", str(out), "--sensing", "true", "--episodes", "1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["sensing"] == "true" and len(res["returns"]) == 1
    with pytest.raises(SystemExit):
        main(["train", "--algo", "DQN"])
    assert main(["evaluate", str(tmp_path / "missing"), "--episodes", "1"]) == 2
