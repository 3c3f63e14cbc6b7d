"""scripts/rl_benchmark.py: its summary statistics, its CSV reading and its rl-zoo3 hyperparameter table."""

from __future__ import annotations

import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def bench():
    return load_script("rl_benchmark")


def _row(seed, value, train="true", ev="true", steps=1000, env="Hopper-v5"):
    return dict(env=env, algo="PPO", train_sensing=train, eval_sensing=ev, steps=str(steps), seed=str(seed),
                mean_return=str(value))  # fmt: skip


def test_summary_is_mean_sample_std_and_range_over_seeds(bench):
    rows = [_row(0, 1.0), _row(1, 2.0), _row(2, 6.0), _row(0, 5.0, ev="auto"), _row(0, 7.0, train="auto", ev="auto")]
    rows.append(_row(0, 9.0, env="InvertedDoublePendulum-v5"))
    summary = bench.summarize(rows)
    # environments in ENVS order, own sensing before cross-evaluation
    assert [(s["env"], s["train_sensing"], s["eval_sensing"]) for s in summary] == [
        ("InvertedDoublePendulum-v5", "true", "true"),
        ("Hopper-v5", "true", "true"),
        ("Hopper-v5", "auto", "auto"),
        ("Hopper-v5", "true", "auto"),
    ]
    first = summary[1]
    # 1, 2, 6: mean 3, sample variance ((-2)^2 + (-1)^2 + 3^2) / 2 = 7
    assert (first["seeds"], first["mean"], first["min"], first["max"]) == (3, 3.0, 1.0, 6.0)
    assert first["std"] == pytest.approx(7**0.5, abs=0.05)
    assert summary[2]["std"] == 0.0  # one seed


def test_csv_comment_lines_are_skipped_and_kept_for_the_summary(bench, tmp_path):
    (tmp_path / "runs.csv").write_text(
        "# scripts/rl_benchmark.py --seeds 2\n"
        + ",".join(bench.FIELDS)
        + "\n"
        + ",".join("Hopper-v5" if f == "env" else "1" for f in bench.FIELDS)
        + "\n# scripts/rl_benchmark.py --resume\n"
    )
    rows = bench.read_rows(tmp_path / "runs.csv")
    assert len(rows) == 1 and rows[0]["env"] == "Hopper-v5"
    bench.write_summary(tmp_path)
    lines = (tmp_path / "summary.csv").read_text().splitlines()
    assert lines[:2] == ["# scripts/rl_benchmark.py --seeds 2", "# scripts/rl_benchmark.py --resume"]
    assert lines[2] == ",".join(bench.SUMMARY_FIELDS)


def test_steps_per_environment(bench):
    envs = ["InvertedDoublePendulum-v5", "Hopper-v5"]
    assert bench.parse_steps("5000", envs) == dict.fromkeys(envs, 5000)
    assert bench.parse_steps("Hopper-v5=7000", envs) == {envs[0]: bench.BUDGETS[envs[0]], "Hopper-v5": 7000}
    with pytest.raises(ValueError, match="Walker2d-v5=1"):
        bench.parse_steps("Walker2d-v5=1", envs)


def test_every_sensing_is_one_of_smo_gym_rl(bench):
    rl = pytest.importorskip("smo_gym.rl")
    assert set(bench.RL_SENSING) == set(bench.SENSINGS)
    assert {s for s, _ in bench.RL_SENSING.values()} <= set(rl.SENSINGS)
    from smo_gym.specs import parse_observer_spec

    for _sensing, observer in bench.RL_SENSING.values():  # auto-model's spec names auto's model options
        parse_observer_spec(observer)


def test_zoo_hyperparameters_are_arguments_of_the_algorithms(bench):
    pytest.importorskip("stable_baselines3")
    from smo_gym import rl

    for (_env, algo), zoo in bench.ZOO.items():
        kwargs = rl.algo_kwargs(algo, zoo["hyperparams"])
        assert set(kwargs) == set(zoo["hyperparams"])
    hopper = rl.algo_kwargs("PPO", bench.ZOO[("Hopper-v5", "PPO")]["hyperparams"])["policy_kwargs"]
    assert hopper["net_arch"] == dict(pi=[256, 256], vf=[256, 256]) and hopper["log_std_init"] == -2
