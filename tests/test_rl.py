"""smo_gym.rl: sensings, velocity masking, training and cross-sensing evaluation, and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

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
    summary = rl.train(
        "InvertedDoublePendulum-v5",
        sensing="true",
        steps=128,
        seed=0,
        out=out,
        hyperparams=TINY_PPO,
        evaluate_at=[64, 128],
        eval_sensings=["true", "estimated"],
        eval_episodes=2,
        checkpoint_every=64,
    )
    assert {(e["steps"], e["sensing"]) for e in summary["evaluations"]} == {
        (64, "true"),
        (64, "estimated"),
        (128, "true"),
        (128, "estimated"),
    }
    assert all(e["trained_steps"] >= e["steps"] for e in summary["evaluations"])
    assert (out / "model.zip").exists() and (out / "vecnormalize.pkl").exists()
    assert (out / "progress.csv").exists() and list((out / "checkpoints").glob("*.zip"))
    assert json.loads((out / "run.json").read_text())["sensing"] == "true"
    true = rl.evaluate(out, episodes=2)["returns"]
    for sensing in ("estimated", "finite-difference", "no-velocity"):
        res = rl.evaluate(out, sensing=sensing, episodes=2)
        assert res["sensing"] == sensing and len(res["returns"]) == 2
        assert np.all(np.isfinite(res["returns"])) and min(res["returns"]) > 0
        assert res["returns"] != true  # played under that sensing (same seeds, other observations)
    # stacked positions are another observation, even where the shapes agree (InvertedPendulum: both (4,))
    with pytest.raises(ValueError, match="interchangeable with 'true'"):
        rl.evaluate(out, sensing="stacked-positions", episodes=1)
    with pytest.raises(ValueError, match="observation shape"):
        rl.evaluate(out, env_id="InvertedPendulum-v5", episodes=1)
    # checked before the model is loaded: "" fell back on the run's setting, "no" played deterministically, a
    # count beyond SB3's int64 failed after the environments were made (and left them open)
    for bad, error in (
        (dict(sensing=""), ValueError),
        (dict(env_id="NoSuchEnv-v0"), ValueError),
        (dict(deterministic="no"), TypeError),
        (dict(episodes=2**63), ValueError),
    ):
        with pytest.raises(error, match="expected"):
            rl.evaluate(out, **({"episodes": 1} | bad))


def test_vectorized_sensing_in_training(tmp_path):
    from smo_gym.wrappers import VecEstimatedVelocity

    venv = rl.make_vec("InvertedDoublePendulum-v5", "estimated", n_envs=2, rate="env")
    assert not isinstance(venv, VecEstimatedVelocity)  # per-environment wrappers cost less with few environments
    venv.close()
    venv = rl.make_vec("InvertedDoublePendulum-v5", "estimated", n_envs=2, rate="env", vectorized=True)
    assert isinstance(venv, VecEstimatedVelocity)
    venv.close()
    venv = rl.make_vec("InvertedDoublePendulum-v5", "estimated", n_envs=rl.VECTORIZE_FROM, rate="env")
    assert isinstance(venv, VecEstimatedVelocity)
    venv.close()
    summary = rl.train(
        "InvertedDoublePendulum-v5",
        sensing="estimated",
        rate="env",
        steps=128,
        n_envs=2,
        out=tmp_path / "v",
        hyperparams=TINY_PPO,
    )
    assert summary["trained_steps"] >= 128


def test_training_time_evaluation_is_what_evaluate_gives(tmp_path):
    """The evaluation at the last budget plays the saved model with the saved statistics, seeded as ``evaluate``
    seeds: the same returns. The frozen copy of the statistics lost VecNormalize's ``epsilon`` (returns
    30, 20, 34 against 31, 21, 26 with ``epsilon=10``)."""
    out = tmp_path / "run"
    summary = rl.train(IP, sensing="true", steps=128, out=out, hyperparams=TINY_PPO, normalize={"epsilon": 10.0},
                       evaluate_at=[128], eval_episodes=3)  # fmt: skip
    assert summary["evaluations"][0]["returns"] == rl.evaluate(out, episodes=3)["returns"]


def test_sac_learns_briefly(tmp_path):
    summary = rl.train(
        "InvertedDoublePendulum-v5",
        sensing="estimated",
        algo="SAC",
        steps=80,
        out=tmp_path / "s",
        hyperparams=dict(learning_starts=40, batch_size=16),
    )
    assert summary["algo"] == "SAC" and summary["trained_steps"] >= 80 and not summary["normalize"]
    assert np.isfinite(rl.evaluate(tmp_path / "s", sensing="true", episodes=1)["mean"])


def test_cli_train_and_evaluate(tmp_path, capsys):
    from smo_gym.cli import main

    out = tmp_path / "cli"
    assert (
        main(
            [
                "train",
                "--env",
                "InvertedDoublePendulum-v5",
                "--steps",
                "64",
                "--out",
                str(out),
                "--no-progress",
                "--checkpoint-every",
                "0",
                "--eval-episodes",
                "1",
            ]
        )
        == 0
    )
    assert "steps/s" in capsys.readouterr().out
    assert main(["evaluate", str(out), "--sensing", "true", "--episodes", "1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["sensing"] == "true" and len(res["returns"]) == 1
    with pytest.raises(SystemExit):
        main(["train", "--algo", "DQN"])
    assert main(["evaluate", str(tmp_path / "missing"), "--episodes", "1"]) == 2


# ----------------------------------------------------------------------------------------------------------------
# evaluation of checkpoints, run folders, hyperparameter files, dm_control
# ----------------------------------------------------------------------------------------------------------------
IP = "InvertedPendulum-v5"


@pytest.fixture(autouse=True)
def _one_thread(tmp_path, monkeypatch):
    import torch

    torch.set_num_threads(1)
    monkeypatch.setenv("SMO_GYM_CACHE_DIR", str(tmp_path / "cache"))


def _by_hand(model_zip, norm_pkl, sensing, seed, episodes=2):
    """Returns of a saved model under a sensing, with its statistics, computed without smo_gym.rl.evaluate."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize.load(str(norm_pkl), rl.make_vec(IP, sensing, n_envs=1, seed=seed))
    venv.training, venv.norm_reward = False, False
    rewards, _ = evaluate_policy(
        PPO.load(model_zip, device="cpu"),
        venv,
        n_eval_episodes=episodes,
        deterministic=True,
        return_episode_rewards=True,
        warn=False,
    )
    venv.close()
    return rewards


def test_evaluating_a_checkpoint_uses_the_runs_sensing_and_that_checkpoints_statistics(tmp_path, capsys):
    from smo_gym.cli import main

    out = tmp_path / "run"
    rl.train(IP, sensing="finite-difference", steps=128, out=out, hyperparams=TINY_PPO, checkpoint_every=64)
    ckpt = out / "checkpoints" / "model_64_steps.zip"
    norm = out / "checkpoints" / "model_vecnormalize_64_steps.pkl"
    assert ckpt.exists() and norm.exists()
    res = rl.evaluate(ckpt, episodes=2, seed=7)
    assert res["sensing"] == "finite-difference" and res["vecnormalize"] == str(norm)
    assert res["returns"] == _by_hand(ckpt, norm, "finite-difference", seed=7)
    # only the settings that act under the sensing are printed: finite differences have no observer
    assert main(["evaluate", str(ckpt), "--episodes", "1"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "under finite-difference (sensor encoder-12bit-noisy, rate physics)" in line and "observer" not in line
    assert main(["evaluate", str(ckpt), "--episodes", "1", "--sensing", "true"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert f"{IP} under true: return" in line and "sensor" not in line
    # (the override itself is told apart by returns in test_train_evaluate_cross_sensing: here they coincide)
    assert rl.evaluate(ckpt, sensing="true", episodes=2, seed=7)["returns"] == _by_hand(ckpt, norm, "true", seed=7)
    # statistics that cannot be read say which file, not pickle's own message
    saved = norm.read_bytes()
    norm.write_bytes(b"garbage\n")
    with pytest.raises(ValueError, match="normalization statistics SB3's VecNormalize"):
        rl.evaluate(ckpt, episodes=1)
    norm.write_bytes(saved)
    # a checkpoint whose statistics are gone is refused, not played unnormalized
    norm.unlink()
    with pytest.raises(ValueError, match="normalization statistics"):
        rl.evaluate(ckpt, episodes=1)
    # a run.json that is not the run's object, or one without the names, is refused with what was expected
    for broken in ("[1, 2]", '{"algo": "PPO"}', '{"env": 3}', "{not json"):
        (out / "run.json").write_text(broken)
        with pytest.raises(ValueError, match=r"run.json"):
            rl.evaluate(out / "model.zip", episodes=1)
    # a model without a run.json needs its environment and sensing
    (out / "run.json").unlink()
    with pytest.raises(ValueError, match=r"run.json"):
        rl.evaluate(out / "model.zip", episodes=1)
    assert rl.evaluate(out / "model.zip", env_id=IP, sensing="true", episodes=1)["vecnormalize"] == str(
        out / "vecnormalize.pkl"
    )


def test_default_run_folders_name_observer_sensor_and_rate(tmp_path, capsys, monkeypatch):
    from smo_gym.cli import main

    a = rl.default_run_folder(IP, "estimated", "PPO", 0, sensor="low-cost", observer="levant:order=1", rate="env")
    b = rl.default_run_folder(IP, "estimated", "PPO", 0, sensor="low-cost", observer="high-gain", rate="env")
    c = rl.default_run_folder(IP, "estimated", "PPO", 0, sensor="ideal", observer="high-gain", rate="env")
    d = rl.default_run_folder(IP, "estimated", "PPO", 0, sensor="ideal", observer="high-gain", rate=2)
    assert len({a, b, c, d}) == 4
    assert a.name == "InvertedPendulum-v5-estimated-levant_order=1-low-cost-rate-env-PPO-s0"
    # settings that do not act under the sensing are not in the name
    assert rl.default_run_folder(IP, "true", "PPO", 0, sensor="ideal").name == "InvertedPendulum-v5-true-PPO-s0"
    assert rl.default_run_folder("dm_control/cartpole-swingup-v0", "true", "SAC", 1).parent == Path("outputs/runs")
    monkeypatch.chdir(tmp_path)
    common = [
        "train",
        "--env",
        IP,
        "--steps",
        "64",
        "--no-progress",
        "--checkpoint-every",
        "0",
        "--eval-episodes",
        "0",
        "--rate",
        "env",
        "--sensor",
        "ideal",
    ]
    assert main(common + ["--observer", "high-gain"]) == 0
    assert main(common + ["--observer", "finite-difference"]) == 0
    runs = sorted(p.name for p in (tmp_path / "outputs" / "runs").iterdir())
    assert runs == [
        "InvertedPendulum-v5-estimated-finite-difference-ideal-rate-env-PPO-s0",
        "InvertedPendulum-v5-estimated-high-gain-ideal-rate-env-PPO-s0",
    ]
    run = json.loads((tmp_path / "outputs" / "runs" / runs[1] / "run.json").read_text())
    assert (run["observer"], run["sensor"], run["rate"]) == ("high-gain", "ideal", "env")  # trained as named


def test_an_existing_run_is_refused_unless_forced(tmp_path, capsys):
    from smo_gym.cli import main

    out = tmp_path / "run"
    args = [
        "train",
        "--env",
        IP,
        "--sensing",
        "true",
        "--steps",
        "64",
        "--no-progress",
        "--checkpoint-every",
        "0",
        "--eval-episodes",
        "0",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    first = (out / "model.zip").read_bytes()
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main(args + ["--seed", "1"]) == 2
    assert "holds a run already" in capsys.readouterr().err
    assert (out / "model.zip").read_bytes() == first
    assert main(args + ["--seed", "1", "--force"]) == 0
    assert json.loads((out / "run.json").read_text())["seed"] == 1
    assert (out / "notes.txt").read_text() == "mine"  # only the run's own files are replaced
    with pytest.raises(ValueError, match="holds a run already"):
        rl.train(IP, sensing="true", steps=64, out=out, hyperparams=TINY_PPO)


def test_a_failed_start_removes_what_it_created(tmp_path, monkeypatch):
    out = tmp_path / "new" / "deeper" / "run"
    with pytest.raises(ValueError, match="divisor"):  # Hopper's frame_skip is 4: rate 3 fails building the env
        rl.train("Hopper-v5", sensing="estimated", rate=3, steps=64, out=out, hyperparams=TINY_PPO)
    assert not (tmp_path / "new").exists()

    def broken(*args, **kwargs):
        raise RuntimeError("an evaluation failed")

    # a failure during training (in the evaluation at a budget), before any checkpoint
    monkeypatch.setattr(rl, "_returns", broken)
    with pytest.raises(RuntimeError, match="evaluation failed"):
        rl.train(IP, sensing="true", steps=128, out=out, hyperparams=TINY_PPO, evaluate_at=[64])
    assert not (tmp_path / "new").exists()
    # an existing (empty) folder stays, without the files of the failed run
    out.mkdir(parents=True)
    with pytest.raises(RuntimeError, match="evaluation failed"):
        rl.train(IP, sensing="true", steps=128, out=out, hyperparams=TINY_PPO, evaluate_at=[64])
    assert out.is_dir() and not any(out.iterdir())


def test_a_failed_forced_retrain_keeps_the_old_run(tmp_path, capsys):
    """``overwrite=True`` replaces a run once the new model exists; a retrain that failed before (an unknown env,
    arguments SB3 refuses) deleted the old run's files all the same."""
    from smo_gym.cli import main

    out = tmp_path / "run"
    rl.train(IP, sensing="true", steps=64, out=out, hyperparams=TINY_PPO)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    with pytest.raises(ValueError, match="registered Gymnasium environment id"):
        rl.train("NoSuchEnv-v1", sensing="true", steps=64, out=out, hyperparams=TINY_PPO, overwrite=True)
    with pytest.raises(ValueError, match=r"SB3 accepts.*batch_size"):  # PPO asserts batch_size > 1
        rl.train(IP, sensing="true", steps=64, out=out, hyperparams=TINY_PPO | {"batch_size": 1}, overwrite=True)
    zoo = tmp_path / "zoo.yml"
    zoo.write_text(f"{IP}:\n  n_steps: 64\n  batch_size: 1\n")
    assert main(["train", "--env", IP, "--sensing", "true", "--steps", "64", "--no-progress", "--force",
                 "--hyperparams", str(zoo), "--out", str(out)]) == 2  # fmt: skip
    assert "batch_size" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


@pytest.mark.parametrize(
    "change, error, message",
    [
        (dict(eval_sensings=["psychic"]), ValueError, "expected sensing"),
        (dict(eval_sensings=["stacked-positions"]), ValueError, "interchangeable"),
        (dict(eval_sensings="true"), TypeError, "sequence of sensings"),
        (dict(evaluate_at=[10**9]), ValueError, r"evaluate_at in \[1, 128\]"),
        (dict(evaluate_at=[-5]), ValueError, "evaluate_at"),
        (dict(evaluate_at=100), TypeError, "sequence of budgets"),
        (dict(eval_episodes=0), ValueError, r"eval_episodes in \[1, "),
        (dict(eval_episodes=10**400), ValueError, r"eval_episodes in \[1, "),
        (dict(checkpoint_every=-3), ValueError, "checkpoint_every >= 0"),
        (dict(steps=True), TypeError, "steps"),
        (dict(n_envs=2.5), TypeError, "n_envs"),
        (dict(seed=2**32), ValueError, "seed in"),
        (dict(policy=5), TypeError, "policy"),
        (dict(hyperparams={"n_timesteps": 100}), ValueError, "train's own argument steps="),
        (dict(out=""), TypeError, "folder path"),
        (dict(overwrite="False"), TypeError, "overwrite to be True or False"),
        (dict(verbose=-3), ValueError, "verbose in"),
        (dict(observer_kwargs="abc"), TypeError, "observer_kwargs to be a dict"),
        (dict(env_kwargs=[1]), TypeError, "env_kwargs to be a dict"),
        (dict(hyperparams=TINY_PPO | {"clip_range": float("nan")}), ValueError, "clip_range to be finite"),
        (dict(hyperparams=TINY_PPO | {"clip_range": "lin_nan"}), ValueError, "lin_<number>"),
        (dict(hyperparams=TINY_PPO | {"n_epochs": 0}), ValueError, "n_epochs >= 1"),
        (dict(hyperparams={1: 2}), TypeError, "hyperparameter names"),
        (dict(hyperparams=TINY_PPO | {"policy_kwargs": "dict(net_arch=[-64])"}), ValueError, "SB3 accepts"),
    ],
)
def test_bad_training_arguments_are_refused_before_training(change, error, message, tmp_path):
    """Each was found late (after the training it was to evaluate: the run then deleted), ignored (a budget
    beyond ``steps``), or taken as something else (``steps=True`` trained 64 steps; ``eval_sensings="true"``
    was read letter by letter)."""
    args = dict(sensing="true", steps=128, out=tmp_path / "run", hyperparams=TINY_PPO, evaluate_at=[64]) | change
    with pytest.raises(error, match=message):
        rl.train(IP, **args)
    assert not (tmp_path / "run").exists()


ZOO_YAML = """
InvertedPendulum-v5:
  n_timesteps: !!float 128
  policy: 'MlpPolicy'
  n_envs: 2
  normalize: "{'norm_obs': True, 'norm_reward': False}"
  learning_rate: lin_1e-3
  policy_kwargs: "dict(net_arch=[16, 8], activation_fn=nn.Tanh)"
  n_steps: 32
  batch_size: 32
  n_epochs: 1
Hopper-v5:
  n_timesteps: !!float 1e6
"""


def test_train_reads_rl_zoo3_hyperparameters(tmp_path, capsys):
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from smo_gym.cli import main

    file = tmp_path / "ppo.yml"
    file.write_text(ZOO_YAML)
    out = tmp_path / "zoo"
    assert (
        main(
            [
                "train",
                "--env",
                IP,
                "--sensing",
                "true",
                "--hyperparams",
                str(file),
                "--out",
                str(out),
                "--no-progress",
                "--checkpoint-every",
                "0",
                "--eval-episodes",
                "1",
            ]
        )
        == 0
    )
    run = json.loads((out / "run.json").read_text())
    assert run["n_envs"] == 2 and run["steps"] == 128 and run["trained_steps"] == 128
    assert run["hyperparams"]["learning_rate"] == "lin_1e-3"
    model = PPO.load(out / "model.zip", device="cpu")
    assert model.n_envs == 2 and model.n_steps == 32
    assert model.lr_schedule(1.0) == pytest.approx(1e-3) and model.lr_schedule(0.25) == pytest.approx(2.5e-4)
    linears = [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linears] == [16, 8]
    assert any(isinstance(m, torch.nn.Tanh) for m in model.policy.mlp_extractor.policy_net)
    norm = VecNormalize.load(str(out / "vecnormalize.pkl"), rl.make_vec(IP, "true"))
    assert norm.norm_obs and not norm.norm_reward
    # command-line flags win over the file
    assert (
        main(
            [
                "train",
                "--env",
                IP,
                "--sensing",
                "true",
                "--hyperparams",
                str(file),
                "--out",
                str(tmp_path / "z2"),
                "--no-progress",
                "--checkpoint-every",
                "0",
                "--eval-episodes",
                "0",
                "--n-envs",
                "1",
                "--steps",
                "64",
            ]
        )
        == 0
    )
    run = json.loads((tmp_path / "z2" / "run.json").read_text())
    assert run["n_envs"] == 1 and run["steps"] == 64


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("learning_rat: 0.001", "did you mean 'learning_rate'?"),
        ("env_wrapper: smo_gym.wrappers.EstimatedVelocity", "README"),
        ("learning_rate: cos_1e-3", "lin_<number>"),
        ("policy_kwargs: \"dict(net_arch=__import__('os').system('echo hi'))\"", "expected policy_kwargs made of"),
        ("normalize: \"{'norm_ob': True}\"", "expected normalize options"),
        ("n_timesteps: -3", "positive integer"),
        ("n_timesteps: .inf", "positive integer"),
        ("n_timesteps: .nan", "positive integer"),
        ("policy: null", "expected policy to be an SB3 policy name"),
        ("1: 2", "to map hyperparameter names to values"),
    ],
)
def test_bad_hyperparameter_files_are_refused_before_training(entry, message, tmp_path, capsys, monkeypatch):
    from smo_gym.cli import main

    monkeypatch.setattr(rl, "make_vec", lambda *a, **k: pytest.fail("training started"))
    file = tmp_path / "bad.yml"
    file.write_text(f"{IP}:\n  {entry}\n")
    assert main(["train", "--env", IP, "--hyperparams", str(file), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()
    file.write_text("Hopper-v5:\n  n_envs: 2\n")
    assert main(["train", "--env", "Hopper-v4", "--hyperparams", str(file), "--out", str(tmp_path / "r")]) == 2
    assert "did you mean 'Hopper-v5'?" in capsys.readouterr().err


def test_what_was_read_as_something_else_is_refused(tmp_path):
    """Each gave a result: ``vectorized=True`` batched at the environment rate whatever ``rate`` said (and the run
    recorded ``"physics"``); bools and floats were indices (``[False, False, True, True]`` masked entries 0, 0, 1,
    1); no trial found no velocity entry; an unknown id or an empty name fell through to Gymnasium's own errors or
    to the run's settings; SB3 wrote into the caller's ``policy_kwargs``."""
    with pytest.raises(ValueError, match="rate='env' for a vector wrapper"):
        rl.make_vec(IP, "estimated", vectorized=True, rate="physics")
    with pytest.raises(TypeError, match="vectorized to be True or False"):
        rl.make_vec(IP, "estimated", vectorized="no")
    with pytest.raises(ValueError, match="seed in"):
        rl.make_vec(IP, "true", seed=-1)
    with pytest.raises(ValueError, match="did you mean 'InvertedPendulum-v5'"):
        rl.make_env("InvertedPendulm-v5", "true")
    env = gym.make(IP)
    for indices, error in (([False, False, True, True], TypeError), ([2.7], TypeError), ([7], ValueError)):
        for wrapper in (rl.MaskEntries, rl.SelectEntries):
            with pytest.raises(error, match="indices"):
                wrapper(env, indices)
    np.testing.assert_array_equal(rl.MaskEntries(env, [2, -1]).observation(np.arange(1.0, 5.0)), [1, 2, 0, 0])
    env.reset(seed=0)
    with pytest.raises(ValueError, match="trials >= 1"):
        rl.velocity_entries(env, trials=0)
    kwargs = {"net_arch": [8]}
    assert rl.algo_kwargs("SAC", {"policy_kwargs": kwargs, "buffer_size": 1e3})["buffer_size"] == 1000
    rl.algo_kwargs("SAC", {"policy_kwargs": kwargs})["policy_kwargs"]["use_sde"] = False  # what SB3 does
    assert kwargs == {"net_arch": [8]}


def test_entries_and_paths_of_the_wrong_type_are_named(tmp_path):
    """Python's own messages ('int' object is not iterable, unhashable type: 'list', expected str, bytes or
    os.PathLike object) named nothing the caller wrote."""
    file = tmp_path / "h.yml"
    for text in (f"{IP}: 5", f"{IP}:\n  - a"):
        file.write_text(text)
        with pytest.raises(ValueError, match="to map hyperparameter names to values"):
            rl.load_hyperparams(file, IP)
    with pytest.raises(TypeError, match="expected env_id"):
        rl.load_hyperparams(file, None)
    with pytest.raises(ValueError, match="a key that is not a string"):
        rl.parse_policy_kwargs("{[1]: 2}")
    for call in (rl.run_files, rl.evaluate, rl.check_run_folder):
        with pytest.raises(TypeError, match="expected"):
            call(5)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "model.zip").write_bytes(b"")
    (tmp_path / "run" / "run.json").write_bytes(b"\xff\xfe")
    with pytest.raises(ValueError, match=r"expected run\.json to be JSON"):
        rl.load_run(tmp_path / "run")


def test_hyperparameter_paths_that_are_not_yaml_text(tmp_path):
    with pytest.raises(ValueError, match="is not a file"):
        rl.load_hyperparams(tmp_path, IP)  # a folder: it exists
    (tmp_path / "binary.yml").write_bytes(b"\xff\xfe\x00 not text")
    with pytest.raises(ValueError, match="is not text"):
        rl.load_hyperparams(tmp_path / "binary.yml", IP)


def test_policy_kwargs_are_evaluated_safely():
    import torch

    kwargs = rl.parse_policy_kwargs(
        "dict(log_std_init=-2, ortho_init=False, activation_fn=nn.ReLU, "
        "net_arch=dict(pi=[256, 256], vf=[256, 256]), optimizer_class=th.optim.AdamW)"
    )
    assert kwargs == dict(
        log_std_init=-2,
        ortho_init=False,
        activation_fn=torch.nn.ReLU,
        net_arch=dict(pi=[256, 256], vf=[256, 256]),
        optimizer_class=torch.optim.AdamW,
    )
    assert rl.parse_policy_kwargs("{'net_arch': (64, 64)}") == {"net_arch": (64, 64)}
    for text in ("dict(a=os.system)", "dict(**x)", "[1, 2]", "dict(a=1 + 2)", "dict(a=nn.Module)", "open('f')"):
        with pytest.raises(ValueError, match="policy_kwargs"):
            rl.parse_policy_kwargs(text)


def test_dm_control_observations_are_flattened_for_training(tmp_path, capsys):
    """The dm_control suite's Dict observation is flattened (position, then velocity) so that an MLP policy can be
    trained on it; the velocity entries are found in the flattened vector."""
    from smo_gym.cli import main

    env_id = "dm_control/cartpole-swingup-v0"
    env = rl.make_env(env_id, "no-velocity", sensor="ideal")
    assert env.observation_space.shape == (5,)
    o, _ = env.reset(seed=0)
    np.testing.assert_array_equal(o[3:], 0.0)  # cartpole: position (3: x, cos, sin), velocity (2)
    out = tmp_path / "dmc"
    assert (
        main(
            [
                "train",
                "--env",
                env_id,
                "--sensing",
                "estimated",
                "--steps",
                "64",
                "--out",
                str(out),
                "--no-progress",
                "--checkpoint-every",
                "0",
                "--eval-episodes",
                "0",
            ]
        )
        == 0
    )
    assert main(["evaluate", str(out), "--episodes", "1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["env"] == env_id and res["sensing"] == "estimated" and np.isfinite(res["mean"])
