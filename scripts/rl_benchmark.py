"""RL benchmark: what estimated velocities do to PPO on InvertedDoublePendulum-v5 and Hopper-v5.

Every run trains PPO (Stable-Baselines3, same hyperparameters for all) under one sensing of
:mod:`smo_gym.rl`, all with the same noisy encoder (``encoder-12bit-noisy``) except the true state:

    true               the environment's observation (true positions and velocities)
    estimated          EstimatedVelocity's default: measured positions, super-twisting velocities, rate="physics"
    finite-difference  measured positions, backward differences of consecutive samples (same rate)
    no-velocity        measured positions, velocity-dependent entries zeroed (rl_zoo3's MaskVelocityWrapper)
    stacked-positions  measured positions only, two frames stacked

and is evaluated (deterministic policy, true return, training normalization frozen) at half and all of the
budget under its own sensing; the policies trained on the true state are also evaluated under ``estimated``
and ``finite-difference`` (cross-evaluation: trained on true velocities, deployed on estimates).

Runs go in parallel processes (``--jobs``, default 2: one per core), one environment after the other
(InvertedDoublePendulum first); each finished run is appended to ``runs.csv`` at once, and ``--resume`` skips
runs already there, so the benchmark can be stopped and continued. ``summary.csv`` (mean and standard deviation
over seeds of each run's mean return) and ``rl_benchmark.png`` are rebuilt from ``runs.csv`` (in ``--out``,
default ``results/rl_benchmark``; the models and training logs go in ``--models``).

    MUJOCO_GL=disable .venv/bin/python scripts/rl_benchmark.py --steps 100000 --seeds 3 --jobs 2
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import csv
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import numpy as np

ENVS = ("InvertedDoublePendulum-v5", "Hopper-v5")
SENSINGS = ("true", "estimated", "finite-difference", "no-velocity", "stacked-positions")
CROSS = ("estimated", "finite-difference")
SENSOR = "encoder-12bit-noisy"
#: the same for every run: SB3's PPO defaults except 4 environments x 512 steps per rollout and minibatches of 256
#: (2048 samples per update as the default; fewer, larger minibatches fit the time budget on 2 cores)
HYPERPARAMS = dict(n_steps=512, batch_size=256)
N_ENVS = 4
FIELDS = (
    "env",
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
    "hyperparams",
)


def run_one(env_id: str, sensing: str, seed: int, steps: int, models: str, episodes: int) -> list[dict]:
    os.environ.setdefault("MUJOCO_GL", "disable")
    from smo_gym import rl

    evals = [sensing] + (list(CROSS) if sensing == "true" else [])
    folder = Path(models) / f"{env_id}-{sensing}-s{seed}"
    summary = rl.train(
        env_id,
        sensing=sensing,
        sensor=SENSOR,
        steps=steps,
        seed=seed,
        n_envs=N_ENVS,
        out=folder,
        hyperparams=HYPERPARAMS,
        evaluate_at=[steps // 2, steps],
        eval_sensings=evals,
        eval_episodes=episodes,
        overwrite=True,
    )  # a rerun of the benchmark replaces its runs
    rows = []
    for ev in summary["evaluations"]:
        rows.append(
            dict(
                env=env_id,
                train_sensing=sensing,
                eval_sensing=ev["sensing"],
                steps=ev["steps"],
                seed=seed,
                mean_return=ev["mean"],
                std_return=ev["std"],
                episodes=len(ev["returns"]),
                budget=steps,
                train_seconds=round(summary["seconds"], 1),
                steps_per_second=round(summary["steps_per_second"], 1),
                sensor=SENSOR,
                observer=summary["observer"],
                rate=summary["rate"],
                n_envs=N_ENVS,
                hyperparams=str(HYPERPARAMS),
            )
        )
    return rows


def read_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path) as fh:
        return list(csv.DictReader(fh))


def summarize(rows: list[dict]) -> list[dict]:
    groups: dict[tuple, list[float]] = {}
    for r in rows:
        key = (r["env"], r["train_sensing"], r["eval_sensing"], int(r["steps"]))
        groups.setdefault(key, []).append(float(r["mean_return"]))
    out = []
    for (env, tr, ev, steps), vals in sorted(
        groups.items(),
        key=lambda kv: (
            ENVS.index(kv[0][0]) if kv[0][0] in ENVS else 9,
            kv[0][3],
            SENSINGS.index(kv[0][1]),
            SENSINGS.index(kv[0][2]),
        ),
    ):
        out.append(
            dict(
                env=env,
                train_sensing=tr,
                eval_sensing=ev,
                steps=steps,
                seeds=len(vals),
                mean=round(float(np.mean(vals)), 1),
                std=round(float(np.std(vals)), 1),
            )
        )
    return out


def plot(summary: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = [e for e in ENVS if any(s["env"] == e for s in summary)]
    if not envs:
        return
    fig, axes = plt.subplots(1, len(envs), figsize=(6.5 * len(envs), 4.2), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        rows = [s for s in summary if s["env"] == env]
        budgets = sorted({s["steps"] for s in rows})
        labels = [
            f"{tr}" if tr == ev else f"{tr} -> {ev}"
            for tr, ev in [(t, t) for t in SENSINGS] + [("true", c) for c in CROSS]
        ]
        pairs = [(t, t) for t in SENSINGS] + [("true", c) for c in CROSS]
        width = 0.8 / max(len(budgets), 1)
        for b_i, b in enumerate(budgets):
            means, stds = [], []
            for tr, ev in pairs:
                m = [s for s in rows if s["steps"] == b and s["train_sensing"] == tr and s["eval_sensing"] == ev]
                means.append(m[0]["mean"] if m else np.nan)
                stds.append(m[0]["std"] if m else 0.0)
            x = np.arange(len(pairs)) + (b_i - (len(budgets) - 1) / 2) * width
            ax.bar(x, means, width, yerr=stds, capsize=3, label=f"{b // 1000}k steps")
        ax.set_xticks(np.arange(len(pairs)), labels, rotation=35, ha="right", fontsize=8)
        ax.set_title(f"{env}, PPO, {SENSOR} (mean +- std over seeds)", fontsize=9)
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
        w = csv.DictWriter(fh, fieldnames=("env", "train_sensing", "eval_sensing", "steps", "seeds", "mean", "std"))
        w.writeheader()
        w.writerows(summary)
    plot(summary, out / "rl_benchmark.png")
    return summary


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", default=",".join(ENVS))
    p.add_argument("--sensings", default=",".join(SENSINGS))
    p.add_argument("--steps", type=int, default=100_000, help="budget per run (evaluated at half and all of it)")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--jobs", type=int, default=2, help="parallel training processes (one per core)")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes per checkpoint")
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
    if not args.resume and runs_csv.exists():
        runs_csv.unlink()
    done = {(r["env"], r["train_sensing"], int(r["seed"]), int(r["budget"])) for r in read_rows(runs_csv)}
    tasks = [
        (e, s, seed)
        for e in args.envs.split(",")
        for seed in range(args.seeds)
        for s in args.sensings.split(",")
        if (e, s, seed, args.steps) not in done
    ]
    print(f"{len(tasks)} runs of {args.steps} steps, {args.jobs} at a time", flush=True)
    t0 = time.perf_counter()
    ctx = mp.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=args.jobs, mp_context=ctx, max_tasks_per_child=1) as pool:
        futures = {
            pool.submit(run_one, e, s, seed, args.steps, args.models, args.episodes): (e, s, seed)
            for e, s, seed in tasks
        }
        for fut in cf.as_completed(futures):
            e, s, seed = futures[fut]
            try:
                rows = fut.result()
            except Exception as exc:  # a failed run is reported, the others go on
                print(f"FAILED {e} {s} seed {seed}: {exc!r}", flush=True)
                continue
            new = not runs_csv.exists()
            with open(runs_csv, "a", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=FIELDS)
                if new:
                    w.writeheader()
                w.writerows(rows)
            final = [r for r in rows if r["steps"] == args.steps]
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
