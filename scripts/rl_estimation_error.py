#!/usr/bin/env python
r"""Velocity estimates along a trained policy's own trajectories, observers side by side.

The policy of a trained run (a folder of :func:`smo_gym.rl.train`, e.g. one of ``scripts/rl_benchmark.py``'s
true-state runs) plays its environment from the *true* observation, deterministically. Beside it, one
:class:`~smo_gym.wrappers.EstimatedVelocity` per observer spec, each over its own copy of the environment with the
same sensor, steps the same actions from the same seed: the wrappers never perturb the simulation, so every copy
follows the same trajectory (checked at every step), the one the policy makes when it sees perfectly, and each
records its velocity estimate. Per observer and joint, over every step of every episode:

* the RMSE and the largest error of the estimate, beside the RMS of the true velocity;
* the lag :math:`\delta` that best explains the error as a delay, :math:`e \approx -\delta a` (least squares,
  ``a`` the true acceleration by central differences of the policy-step velocities): a filter that trades noise
  for delay shows it here;
* the error's autocorrelation one policy step apart: errors that persist over steps act on a policy like a bias,
  white ones average out.

This is what a policy trained on an estimate has to cope with, on the states a good policy visits (a random
policy's states differ: ``scripts/bench_accuracy.py``).

    MUJOCO_GL=disable .venv/bin/python scripts/rl_estimation_error.py RUN_FOLDER \
        --observers auto,finite-difference,high-gain,auto:model=true:mass_scale=1.1
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")

DEFAULT_OBSERVERS = "auto,finite-difference,high-gain,auto:model=true:mass_scale=1.1"


def play(run: str, observers: list[str], episodes: int, seed: int, sensor: str, rate: str):
    """``(truth, estimates, step)``: per episode the true velocity ``(T, nv)`` at every policy step and each
    observer's estimate at the same steps; ``step`` is the policy's step in seconds."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from smo_gym import rl
    from smo_gym.envs import make

    files = rl.run_files(run)
    model, info = rl.load_run(run)
    env_id = info["env"]
    envs = {spec: rl.make_env(env_id, "estimated", sensor=sensor, observer=spec, rate=rate) for spec in observers}
    first = envs[observers[0]]
    if first.observation_space.shape != model.observation_space.shape:
        raise SystemExit(
            f"expected a run trained on {env_id}'s observation {first.observation_space.shape}, actual value: "
            f"{model.observation_space.shape} (stacked positions cannot play from the true observation)"
        )
    normalize = None
    if files["vecnormalize"] is not None:
        normalize = VecNormalize.load(str(files["vecnormalize"]), DummyVecEnv([lambda: make(env_id)]))
    truth, estimates = [], {spec: [] for spec in observers}
    for episode in range(episodes):
        infos = {spec: env.reset(seed=seed + episode)[1] for spec, env in envs.items()}
        true_v, est = [], {spec: [] for spec in observers}
        done = False
        while not done:
            obs = np.asarray(infos[observers[0]]["smo"]["observation"])
            action, _ = model.predict(obs if normalize is None else normalize.normalize_obs(obs), deterministic=True)
            reference = None
            for spec, env in envs.items():
                _, _, terminated, truncated, infos[spec] = env.step(action)
                sample = infos[spec]["smo"]
                if reference is None:
                    reference = sample["qpos"]
                elif not np.array_equal(sample["qpos"], reference):
                    raise RuntimeError(f"expected every copy on the same trajectory, actual value: {spec} left it")
                est[spec].append(sample["qvel_estimate"])
                done = terminated or truncated
            true_v.append(infos[observers[0]]["smo"]["qvel"])
        truth.append(np.array(true_v))
        for spec in observers:
            estimates[spec].append(np.array(est[spec]))
        print(f"  episode {episode}: {len(true_v)} steps", file=sys.stderr, flush=True)
    step = first.unwrapped.dt
    for env in envs.values():
        env.close()
    return truth, estimates, step


def summary(truth: list, estimate: list, step: float) -> dict:
    """RMSE, max, lag [s] and lag-one autocorrelation of the error, per joint."""
    errors = [e - v for e, v in zip(estimate, truth, strict=True)]
    accel = [np.gradient(v, step, axis=0) if len(v) > 1 else np.zeros_like(v) for v in truth]
    e, a = np.concatenate(errors), np.concatenate(accel)
    lagged = np.concatenate([x[1:] * x[:-1] for x in errors])
    return dict(
        rmse=np.sqrt(np.mean(e**2, axis=0)),
        max=np.max(np.abs(e), axis=0),
        lag=-np.sum(e * a, axis=0) / np.maximum(np.sum(a * a, axis=0), 1e-300),
        autocorrelation=np.sum(lagged, axis=0) / np.maximum(np.sum(e**2, axis=0), 1e-300),
    )


def table(truth: list, estimates: dict, step: float) -> str:
    v = np.concatenate(truth)
    nv = v.shape[1]
    joints = " | ".join(f"dof {j}" for j in range(nv))
    lines = [
        f"| observer | quantity | {joints} |",
        "|---|---|" + "---:|" * nv,
        "| (true velocity) | RMS | " + " | ".join(f"{x:.3g}" for x in np.sqrt(np.mean(v**2, axis=0))) + " |",
    ]
    for spec, est in estimates.items():
        s = summary(truth, est, step)
        lines += [
            f"| {spec} | RMSE | " + " | ".join(f"{x:.3g}" for x in s["rmse"]) + " |",
            f"| {spec} | max | " + " | ".join(f"{x:.3g}" for x in s["max"]) + " |",
            f"| {spec} | lag [ms] | " + " | ".join(f"{1e3 * x:.1f}" for x in s["lag"]) + " |",
            f"| {spec} | autocorr. at 1 step | " + " | ".join(f"{x:.2f}" for x in s["autocorrelation"]) + " |",
        ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run", help="a run folder (model.zip, run.json, vecnormalize.pkl), its model or a checkpoint")
    parser.add_argument("--observers", default=DEFAULT_OBSERVERS, help="comma-separated observer specs")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=10_000, help="seed of the first episode (then +1 each)")
    parser.add_argument("--sensor", default="encoder-12bit-noisy")
    parser.add_argument("--rate", default="physics", choices=("physics", "env"))
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"expected --episodes >= 1, actual value: {args.episodes}")
    observers = [s for s in args.observers.split(",") if s]
    if not observers:
        parser.error("expected at least one observer spec, actual value: none")
    truth, estimates, step = play(args.run, observers, args.episodes, args.seed, args.sensor, args.rate)
    steps = sum(len(v) for v in truth)
    print(
        f"Velocity error along the policy's trajectories: {args.run}, {args.episodes} episodes ({steps} policy "
        f"steps of {step * 1e3:g} ms) from seed {args.seed}, sensor {args.sensor}, rate {args.rate!r}\n"
    )
    print(table(truth, estimates, step))
    return 0


if __name__ == "__main__":
    sys.exit(main())
