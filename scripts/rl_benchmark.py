"""RL benchmark: what estimated velocities do to PPO on InvertedDoublePendulum-v5 and Hopper-v5.

Every run trains an agent with rl-zoo3's tuned hyperparameters for its environment (:data:`ZOO`, values copied
from DLR-RM/rl-baselines3-zoo, ``hyperparams/ppo.yml`` and ``sac.yml``) under one sensing, all with the same
noisy encoder (``encoder-12bit-noisy``) except the true state:

    true               the environment's observation (true positions and velocities)
    auto               measured positions, velocities of EstimatedVelocity(observer="auto"), rate="physics"
    auto-model         as auto, with a model-based observer as one more candidate, its model 10 % heavier than
                       the environment's (observer "auto:model=true:mass_scale=1.1"; run on request)
    auto-told          as auto, with the IMM estimator told the actions as one more candidate (observer
                       "auto:model=kalman-imm-input"; run on request)
    estimated          measured positions, velocities of the super-twisting observer (smo_gym.rl's "estimated"
                       default), rate="physics"
    finite-difference  measured positions, backward differences of consecutive samples (same rate)
    no-velocity        measured positions, velocity-dependent entries zeroed (rl_zoo3's MaskVelocityWrapper)
    stacked-positions  measured positions only, two frames stacked

and is evaluated (deterministic policy, true return, training normalization frozen) at half and all of its
environment's budget under its own sensing; with ``--cross``, the policies trained on the true state are also
evaluated under those sensings (trained on true velocities, deployed on estimates).

Runs go one after the other by default (``--jobs``), environment by environment; each finished run is appended
to ``runs.csv`` at once, and ``--resume`` skips runs already there, so the benchmark can be stopped and continued
(every invocation is recorded as a ``#`` line in ``runs.csv``). ``summary.csv`` (mean, sample standard deviation,
minimum and maximum over seeds of each run's mean return) and ``rl_benchmark.png`` are rebuilt from ``runs.csv``
(in ``--out``, default ``results/rl_benchmark``; the models and training logs go in ``--models``).

    MUJOCO_GL=disable .venv/bin/python scripts/rl_benchmark.py --jobs 1 \\
        --steps InvertedDoublePendulum-v5=100000,Hopper-v5=100000 --seeds 3
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import csv
import datetime
import multiprocessing as mp
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np

ENVS = ("InvertedDoublePendulum-v5", "Hopper-v5")
SENSINGS = (
    "true", "auto", "auto-model", "auto-told", "estimated", "finite-difference", "no-velocity", "stacked-positions"
)  # fmt: skip
#: sensings run by default ("estimated", super-twisting, the former default, "auto-model" and "auto-told" are run on
#: request)
DEFAULT_SENSINGS = ("true", "auto", "finite-difference", "no-velocity", "stacked-positions")
#: benchmark sensing -> (smo_gym.rl sensing, observer spec)
RL_SENSING = {
    "true": ("true", "super-twisting"),
    "auto": ("estimated", "auto"),
    "auto-model": ("estimated", "auto:model=true:mass_scale=1.1"),
    "auto-told": ("estimated", "auto:model=kalman-imm-input"),
    "estimated": ("estimated", "super-twisting"),
    "finite-difference": ("finite-difference", "super-twisting"),
    "no-velocity": ("no-velocity", "super-twisting"),
    "stacked-positions": ("stacked-positions", "super-twisting"),
}
SENSOR = "encoder-12bit-noisy"

#: rl-zoo3's tuned hyperparameters (DLR-RM/rl-baselines3-zoo at commit 22e3ff2, 2026-04-23), values copied as
#: written there. rl-zoo3 has no v5 MuJoCo entries: the v4 / v2 ones are used for the v5 environments.
ZOO = {
    # hyperparams/ppo.yml, entry "InvertedDoublePendulum-v2" (there is no v4 or v5 entry). batch_size 512 is
    # larger than the rollout (n_steps * n_envs = 128): SB3 warns and trains on one minibatch of 128 per epoch.
    ("InvertedDoublePendulum-v5", "PPO"): dict(
        n_timesteps=1_000_000,
        policy="MlpPolicy",
        n_envs=1,
        normalize=True,
        hyperparams=dict(
            batch_size=512,
            n_steps=128,
            gamma=0.98,
            learning_rate=0.000155454,
            ent_coef=1.05057e-06,
            clip_range=0.4,
            n_epochs=10,
            gae_lambda=0.8,
            max_grad_norm=0.5,
            vf_coef=0.695929,
        ),
    ),
    # hyperparams/ppo.yml, entry "Hopper-v4" (the tuned one; there is no v5 entry)
    ("Hopper-v5", "PPO"): dict(
        n_timesteps=1_000_000,
        policy="MlpPolicy",
        n_envs=1,
        normalize=True,
        hyperparams=dict(
            batch_size=32,
            n_steps=512,
            gamma=0.999,
            learning_rate=9.80828e-05,
            ent_coef=0.00229519,
            clip_range=0.2,
            n_epochs=5,
            gae_lambda=0.99,
            max_grad_norm=0.7,
            vf_coef=0.835671,
            policy_kwargs="dict(log_std_init=-2, ortho_init=False, activation_fn=nn.ReLU, "
            "net_arch=dict(pi=[256, 256], vf=[256, 256]))",
        ),
    ),
    # hyperparams/sac.yml, entry "Hopper-v4" (<<: *mujoco-defaults of "HalfCheetah-v4"; no v5 entry): SB3's SAC
    # defaults with learning_starts 10000. About 55 steps/s on this benchmark's machine (one thread), against
    # 550 for the PPO entry: not run by default (--algo SAC).
    ("Hopper-v5", "SAC"): dict(
        n_timesteps=1_000_000,
        policy="MlpPolicy",
        n_envs=1,
        normalize=False,
        hyperparams=dict(learning_starts=10000),
    ),
}
#: default budget per environment (environment steps; evaluated at half and all of it), chosen for the time a
#: shared 2-core machine had (see docs/benchmarks/rl.md)
BUDGETS = {"InvertedDoublePendulum-v5": 100_000, "Hopper-v5": 100_000}
FIELDS = (
    "env",
    "algo",
    "train_sensing",
    "eval_sensing",
    "steps",
    "seed",
    "mean_return",
    "std_return",
    "episodes",
    "budget",
    "train_seconds",
    "steps_per_second",
    "sensor",
    "observer",
    "rate",
    "n_envs",
    "normalize",
    "hyperparams",
)
SUMMARY_FIELDS = ("env", "algo", "train_sensing", "eval_sensing", "steps", "seeds", "mean", "std", "min", "max")


def run_one(
    env_id: str, algo: str, sensing: str, seed: int, steps: int, models: str, episodes: int, cross: tuple[str, ...]
) -> list[dict]:
    os.environ.setdefault("MUJOCO_GL", "disable")
    from smo_gym import rl

    zoo = ZOO[(env_id, algo)]
    rl_sensing, observer = RL_SENSING[sensing]
    evals = [sensing] + (list(cross) if sensing == "true" else [])
    observers = {RL_SENSING[s][1] for s in evals if RL_SENSING[s][0] == "estimated"}
    if len(observers) > 1:
        raise ValueError(f"expected one estimating observer among the evaluations, actual value: {evals}")
    if sensing == "true" and observers:
        observer = observers.pop()  # what the "estimated" cross-evaluation runs
    folder = Path(models) / f"{env_id}-{algo}-{sensing}-s{seed}"
    summary = rl.train(
        env_id,
        sensing=rl_sensing,
        sensor=SENSOR,
        observer=observer,
        algo=algo,
        steps=steps,
        seed=seed,
        n_envs=zoo["n_envs"],
        normalize=zoo["normalize"],
        policy=zoo["policy"],
        out=folder,
        hyperparams=zoo["hyperparams"],
        evaluate_at=[steps // 2, steps],
        eval_sensings=[RL_SENSING[s][0] for s in evals],
        eval_episodes=episodes,
        overwrite=True,
    )  # a rerun of the benchmark replaces its runs
    label = {RL_SENSING[s][0]: s for s in evals}
    rows = []
    for ev in summary["evaluations"]:
        name = label[ev["sensing"]]
        measured = name != "true"
        rows.append(
            dict(
                env=env_id,
                algo=algo,
                train_sensing=sensing,
                eval_sensing=name,
                steps=ev["steps"],
                seed=seed,
                mean_return=ev["mean"],
                std_return=ev["std"],
                episodes=len(ev["returns"]),
                budget=steps,
                train_seconds=round(summary["seconds"], 1),
                steps_per_second=round(summary["steps_per_second"], 1),
                sensor=SENSOR if measured else "",
                observer=RL_SENSING[name][1] if RL_SENSING[name][0] == "estimated" else "",
                rate=summary["rate"] if measured else "",
                n_envs=zoo["n_envs"],
                normalize=zoo["normalize"],
                hyperparams=str(zoo["hyperparams"]),
            )
        )
    return rows


def read_rows(path: Path) -> list[dict]:
    """The rows of a CSV file of this script, without its ``#`` lines."""
    if not path.exists():
        return []
    with open(path) as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def read_comments(path: Path) -> list[str]:
    if not path.exists():
        return []
    with open(path) as fh:
        return [line.rstrip("\n") for line in fh if line.startswith("#")]


def _order(name: str, names: tuple[str, ...]) -> int:
    return names.index(name) if name in names else len(names)


def summarize(rows: list[dict]) -> list[dict]:
    """Mean, sample standard deviation (ddof=1; 0 for one seed), minimum and maximum over seeds of each run's
    mean return, one row per environment, algorithm, training sensing, evaluation sensing and budget."""
    groups: dict[tuple, list[float]] = {}
    for r in rows:
        key = (r["env"], r["algo"], r["train_sensing"], r["eval_sensing"], int(r["steps"]))
        groups.setdefault(key, []).append(float(r["mean_return"]))
    out = []
    for (env, algo, tr, ev, steps), vals in sorted(
        groups.items(),
        key=lambda kv: (
            _order(kv[0][0], ENVS),
            kv[0][1],
            kv[0][4],
            kv[0][2] != kv[0][3],
            _order(kv[0][2], SENSINGS),
            _order(kv[0][3], SENSINGS),
        ),
    ):
        out.append(
            dict(
                env=env,
                algo=algo,
                train_sensing=tr,
                eval_sensing=ev,
                steps=steps,
                seeds=len(vals),
                mean=round(float(np.mean(vals)), 1),
                std=round(float(np.std(vals, ddof=1)) if len(vals) > 1 else 0.0, 1),
                min=round(float(np.min(vals)), 1),
                max=round(float(np.max(vals)), 1),
            )
        )
    return out


def plot(summary: list[dict], rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(e, a) for e in ENVS for a in ("PPO", "SAC") if any(s["env"] == e and s["algo"] == a for s in summary)]
    if not panels:
        return
    fig, axes = plt.subplots(1, len(panels), figsize=(6.5 * len(panels), 4.4), squeeze=False)
    for ax, (env, algo) in zip(axes[0], panels, strict=True):
        sub = [s for s in summary if s["env"] == env and s["algo"] == algo]
        budgets = sorted({s["steps"] for s in sub})
        pairs = list(dict.fromkeys((s["train_sensing"], s["eval_sensing"]) for s in sub))
        pairs.sort(key=lambda p: (p[0] != p[1], _order(p[0], SENSINGS), _order(p[1], SENSINGS)))
        labels = [tr if tr == ev else f"{tr} -> {ev}" for tr, ev in pairs]
        width = 0.8 / max(len(budgets), 1)
        for b_i, b in enumerate(budgets):
            x = np.arange(len(pairs)) + (b_i - (len(budgets) - 1) / 2) * width
            means, stds = [], []
            for k, (tr, ev) in enumerate(pairs):
                m = [s for s in sub if s["steps"] == b and s["train_sensing"] == tr and s["eval_sensing"] == ev]
                means.append(m[0]["mean"] if m else np.nan)
                stds.append(m[0]["std"] if m else 0.0)
                seeds = [
                    float(r["mean_return"])
                    for r in rows
                    if (r["env"], r["algo"], int(r["steps"])) == (env, algo, b)
                    and (r["train_sensing"], r["eval_sensing"]) == (tr, ev)
                ]
                ax.plot([x[k]] * len(seeds), seeds, "k.", ms=3)
            ax.bar(x, means, width, yerr=stds, capsize=3, label=f"{b // 1000}k steps")
        ax.set_xticks(np.arange(len(pairs)), labels, rotation=35, ha="right", fontsize=8)
        ax.set_title(f"{env}, {algo} (rl-zoo3), {SENSOR}: mean +- std, dots: seeds", fontsize=9)
        ax.set_ylabel("return (true reward)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_summary(out: Path) -> list[dict]:
    rows = read_rows(out / "runs.csv")
    summary = summarize(rows)
    with open(out / "summary.csv", "w", newline="") as fh:
        for line in read_comments(out / "runs.csv"):
            fh.write(line + "\n")
        w = csv.DictWriter(fh, fieldnames=SUMMARY_FIELDS)
        w.writeheader()
        w.writerows(summary)
    plot(summary, rows, out / "rl_benchmark.png")
    return summary


def parse_steps(text: str, envs: list[str]) -> dict[str, int]:
    """``--steps``: one budget for every environment (``200000``) or per environment
    (``InvertedDoublePendulum-v5=200000,Hopper-v5=100000``; the others keep :data:`BUDGETS`)."""
    budgets = {e: BUDGETS.get(e, 100_000) for e in envs}
    if not text:
        return budgets
    if "=" not in text:
        return dict.fromkeys(envs, int(text))
    for item in text.split(","):
        env, _, value = item.partition("=")
        if env not in budgets:
            raise ValueError(f"expected --steps ENV=N with ENV in {', '.join(envs)}, actual value: {item!r}")
        budgets[env] = int(value)
    return budgets


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", default=",".join(ENVS))
    p.add_argument("--sensings", default=",".join(DEFAULT_SENSINGS), help=f"of {', '.join(SENSINGS)}")
    p.add_argument("--algo", default="PPO", help="PPO (both environments) or SAC (Hopper-v5 only)")
    p.add_argument("--steps", default="", help=f"budget per run: N or ENV=N,... (default {BUDGETS})")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--jobs", type=int, default=1, help="parallel training processes")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes per checkpoint")
    p.add_argument("--cross", default="", help="sensings the true-state policies are also evaluated under (auto,...)")
    p.add_argument("--out", default="results/rl_benchmark", help="CSV files and plot (default %(default)s)")
    p.add_argument("--models", default="outputs/rl_benchmark/runs", help="run folders (models, logs)")
    p.add_argument("--resume", action="store_true", help="skip runs already in runs.csv")
    p.add_argument("--summary-only", action="store_true", help="rebuild summary.csv and the plot from runs.csv")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs_csv = out / "runs.csv"
    if args.summary_only:
        for s in write_summary(out):
            print(s)
        return 0
    envs = args.envs.split(",")
    sensings = args.sensings.split(",")
    cross = tuple(c for c in args.cross.split(",") if c)
    for name in sensings + list(cross):
        if name not in SENSINGS:
            raise ValueError(f"expected sensings in {', '.join(SENSINGS)}, actual value: {name!r}")
    for env in envs:
        if (env, args.algo) not in ZOO:
            raise ValueError(f"expected ENV/algo in {sorted(ZOO)}, actual value: {(env, args.algo)!r}")
    budgets = parse_steps(args.steps, envs)
    if not args.resume and runs_csv.exists():
        runs_csv.unlink()
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    command = "scripts/rl_benchmark.py " + " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    with open(runs_csv, "a", newline="") as fh:
        fh.write(f"# {command} ({stamp})\n")
    done = {
        (r["env"], r["algo"], r["train_sensing"], int(r["seed"]), int(r["budget"]))
        for r in read_rows(runs_csv)
        if r["train_sensing"] == r["eval_sensing"]
    }
    tasks = [
        (e, s, seed)
        for e in envs
        for seed in range(args.seeds)
        for s in sensings
        if (e, args.algo, s, seed, budgets[e]) not in done
    ]
    print(f"{len(tasks)} runs ({budgets}), {args.jobs} at a time", flush=True)
    t0 = time.perf_counter()
    ctx = mp.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=args.jobs, mp_context=ctx, max_tasks_per_child=1) as pool:
        futures = {
            pool.submit(run_one, e, args.algo, s, seed, budgets[e], args.models, args.episodes, cross): (e, s, seed)
            for e, s, seed in tasks
        }
        for fut in cf.as_completed(futures):
            e, s, seed = futures[fut]
            try:
                rows = fut.result()
            except Exception as exc:  # a failed run is reported, the others go on
                print(f"FAILED {e} {s} seed {seed}: {exc!r}", flush=True)
                continue
            header = not read_rows(runs_csv)
            with open(runs_csv, "a", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=FIELDS)
                if header:
                    w.writeheader()
                w.writerows(rows)
            final = [r for r in rows if r["steps"] == budgets[e]]
            print(
                f"[{time.perf_counter() - t0:6.0f} s] {e} {s} seed {seed}: "
                + ", ".join(f"{r['eval_sensing']} {r['mean_return']:.0f}" for r in final)
                + f" ({rows[0]['train_seconds']:.0f} s, {rows[0]['steps_per_second']:.0f} steps/s)",
                flush=True,
            )
    for s in write_summary(out):
        print(s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
