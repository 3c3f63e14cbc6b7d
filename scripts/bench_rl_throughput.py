"""Training throughput with and without the sensing wrappers, side by side (interleaved rounds, medians).

For each environment, PPO models are built once per configuration (same hyperparameters as
``scripts/rl_benchmark.py``: 4 environments, 512 steps each per rollout, minibatches of 256, VecNormalize):

    unwrapped          the environment's true observation
    per-env physics    EstimatedVelocity(rate="physics") in every environment (the default sensing)
    per-env env        EstimatedVelocity(rate="env")
    vec env            VecEstimatedVelocity (one batched observer call for the 4 environments, rate="env")

then trained in interleaved rounds of one rollout + update each (``--rounds``), so that load changes on a shared
machine hit every configuration alike; the table gives the median env steps/s and its ratio to the unwrapped
median (acceptance: >= 0.90). A second table times bare vector-env steps (no learning) with ``SubprocVecEnv``:
per-environment wrappers inside the workers against ``VecEstimatedVelocity`` on top of the workers (which costs
one extra parallel round trip per step to rebuild the observations where the MuJoCo state is).

    MUJOCO_GL=disable .venv/bin/python scripts/bench_rl_throughput.py --rounds 9
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")


def _venv(env_id: str, kind: str, n_envs: int, subproc: bool = False):
    import gymnasium as gym
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    from smo_gym.wrappers import EstimatedVelocity, JointSensor, VecEstimatedVelocity

    cls = SubprocVecEnv if subproc else None
    if kind == "unwrapped":
        return make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=cls)
    if kind == "per-env physics":
        return make_vec_env(
            env_id,
            n_envs=n_envs,
            seed=0,
            vec_env_cls=cls,
            wrapper_class=EstimatedVelocity,
            wrapper_kwargs=dict(rate="physics"),
        )
    if kind == "per-env env":
        return make_vec_env(
            env_id,
            n_envs=n_envs,
            seed=0,
            vec_env_cls=cls,
            wrapper_class=EstimatedVelocity,
            wrapper_kwargs=dict(rate="env"),
        )
    if kind == "vec env":
        if subproc:
            return VecEstimatedVelocity(
                make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=cls, wrapper_class=JointSensor)
            )
        return VecEstimatedVelocity(make_vec_env(lambda: gym.make(env_id), n_envs=n_envs, seed=0))
    raise ValueError(kind)


KINDS = ("unwrapped", "per-env physics", "per-env env", "vec env")


#: PPO settings: the RL benchmark's (4 envs, large minibatches: little learning cost per step, so the environment
#: and the wrapper weigh the most) and SB3's defaults (1 env, 2048 steps, minibatches of 64, 10 epochs)
SETTINGS = {
    "rl_benchmark": dict(n_envs=4, n_steps=512, batch_size=256),
    "sb3-default": dict(n_envs=1, n_steps=2048, batch_size=64),
}


def training(env_id: str, rounds: int, setting: str) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Steps per wall-clock second and per CPU second of this process, per configuration and round."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(1)
    cfg = dict(SETTINGS[setting])
    n_envs = cfg.pop("n_envs")
    models = {k: PPO("MlpPolicy", VecNormalize(_venv(env_id, k, n_envs)), seed=0, device="cpu", **cfg) for k in KINDS}
    per_round = cfg["n_steps"] * n_envs
    for m in models.values():  # warm-up: compilation, calibration caches, first allocations
        m.learn(per_round)
    wall: dict[str, list[float]] = {k: [] for k in KINDS}
    cpu: dict[str, list[float]] = {k: [] for k in KINDS}
    for r in range(rounds):
        order = KINDS if r % 2 == 0 else KINDS[::-1]
        for k in order:
            t0, c0 = time.perf_counter(), time.process_time()
            models[k].learn(per_round, reset_num_timesteps=False)
            wall[k].append(per_round / (time.perf_counter() - t0))
            cpu[k].append(per_round / (time.process_time() - c0))
    for m in models.values():
        m.get_env().close()
    return wall, cpu


def subproc_steps(env_id: str, rounds: int, n_envs: int = 2, steps: int = 300) -> dict[str, list[float]]:
    venvs = {k: _venv(env_id, k, n_envs, subproc=True) for k in ("unwrapped", "per-env env", "vec env")}
    rng = np.random.default_rng(0)
    times: dict[str, list[float]] = {k: [] for k in venvs}
    try:
        for v in venvs.values():
            v.reset()
        shape = (n_envs,) + venvs["unwrapped"].action_space.shape
        for _ in range(rounds):
            for k, v in venvs.items():
                acts = rng.uniform(-1, 1, (steps,) + shape)
                t0 = time.perf_counter()
                for a in acts:
                    v.step(a)
                times[k].append((time.perf_counter() - t0) / steps * 1e6)
    finally:
        for v in venvs.values():
            v.close()
    return times


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", default="InvertedDoublePendulum-v5,Hopper-v5")
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--settings", default=",".join(SETTINGS), help=f"PPO settings among {', '.join(SETTINGS)}")
    p.add_argument("--no-subproc", action="store_true")
    args = p.parse_args(argv)
    print(
        "PPO training throughput: env steps per second of wall clock and of process CPU time (median of "
        "interleaved rounds) and their ratio to unwrapped"
    )
    print(
        f"{'env':26s} {'PPO setting':13s} {'configuration':16s} {'wall/s':>7s} {'ratio':>6s} {'cpu/s':>7s} "
        f"{'ratio':>6s}"
    )
    worst = {"wall": np.inf, "cpu": np.inf}
    for env_id in args.envs.split(","):
        for setting in args.settings.split(","):
            wall, cpu = training(env_id, args.rounds, setting)
            bw, bc = float(np.median(wall["unwrapped"])), float(np.median(cpu["unwrapped"]))
            for k in KINDS:
                mw, mc = float(np.median(wall[k])), float(np.median(cpu[k]))
                if k != "unwrapped":
                    worst["wall"] = min(worst["wall"], mw / bw)
                    worst["cpu"] = min(worst["cpu"], mc / bc)
                print(
                    f"{env_id:26s} {setting:13s} {k:16s} {mw:7.0f} {mw / bw:6.2f} {mc:7.0f} {mc / bc:6.2f}", flush=True
                )
    print(f"worst ratio: wall {worst['wall']:.2f}, cpu {worst['cpu']:.2f} (target >= 0.90)")
    if not args.no_subproc:
        print("\nSubprocVecEnv, 2 workers: time per vector step (us, median), no learning")
        for env_id in args.envs.split(","):
            t = subproc_steps(env_id, args.rounds)
            base = float(np.median(t["unwrapped"]))
            for k, v in t.items():
                print(f"{env_id:28s} {k:16s} {np.median(v):9.0f} {np.median(v) / base:6.2f}x", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
