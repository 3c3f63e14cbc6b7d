"""Training throughput with and without the sensing wrappers, side by side (interleaved rounds, medians).

For each environment and PPO setting (:data:`SETTINGS`, all with VecNormalize), PPO models are built once per
configuration, the wrappers with the observer ``--observer`` (default ``auto``, the wrappers' own default):

    unwrapped          the environment's true observation
    NormalizeObservation  Gymnasium's running normalization of the observation in every environment: the cost
                       of a standard one-line observation wrapper, for scale (not sensing; the PPO models also
                       have SB3's VecNormalize)
    per-env physics    EstimatedVelocity(rate="physics") in every environment (the default sensing)
    per-env env        EstimatedVelocity(rate="env")
    vec env            VecEstimatedVelocity (one batched observer call for all environments, rate="env")

then trained in interleaved rounds of rollouts + updates of at least 2048 environment steps each (``--rounds``),
so that load changes on a shared machine hit every configuration alike; the table gives the median env steps/s
and its ratio to the unwrapped median (acceptance: >= 0.90 for the sensing configurations). A second table times
bare vector-env steps (no learning) with ``SubprocVecEnv``: per-environment wrappers inside the workers against
``VecEstimatedVelocity`` on top of the workers (which costs one extra parallel round trip per step to rebuild the
observations where the MuJoCo state is).

A third table (``--tables in-process``) times bare in-process vector-env steps (no learning) for both vector
APIs, ``gymnasium.vector.SyncVectorEnv`` and SB3's ``DummyVecEnv``, with ``--n-envs`` environments each:

    unwrapped          the vector env of the bare environments
    per-env env        EstimatedVelocity(rate="env") in every environment
    vec env            VectorEstimatedVelocity / VecEstimatedVelocity on top (one batched sensing step)

All three run the same actions from the same seeds (the wrappers never perturb the simulation, so they do the
same physics and autoresets), interleaved in chunks of 10 steps, each chunk timed by the thread's CPU time with
the garbage collector off; the table gives the median time per vector step and the median over chunks of its
ratio to the unwrapped chunk of the same steps (``--rounds`` rounds of ``--steps`` steps, each round from its own
seed).

    MUJOCO_GL=disable .venv/bin/python scripts/bench_rl_throughput.py --rounds 9
    MUJOCO_GL=disable .venv/bin/python scripts/bench_rl_throughput.py --tables in-process --envs Hopper-v5 --rounds 5
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
import warnings

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")


def _venv(env_id: str, kind: str, n_envs: int, subproc: bool = False, observer: str = "auto"):
    import gymnasium as gym
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    from smo_gym.wrappers import EstimatedVelocity, JointSensor, VecEstimatedVelocity

    cls = SubprocVecEnv if subproc else None
    if kind == "unwrapped":
        return make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=cls)
    if kind == "NormalizeObservation":
        return make_vec_env(
            env_id, n_envs=n_envs, seed=0, vec_env_cls=cls, wrapper_class=gym.wrappers.NormalizeObservation
        )
    if kind == "per-env physics":
        return make_vec_env(
            env_id,
            n_envs=n_envs,
            seed=0,
            vec_env_cls=cls,
            wrapper_class=EstimatedVelocity,
            wrapper_kwargs=dict(rate="physics", observer=observer),
        )
    if kind == "per-env env":
        return make_vec_env(
            env_id,
            n_envs=n_envs,
            seed=0,
            vec_env_cls=cls,
            wrapper_class=EstimatedVelocity,
            wrapper_kwargs=dict(rate="env", observer=observer),
        )
    if kind == "vec env":
        if subproc:
            return VecEstimatedVelocity(
                make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=cls, wrapper_class=JointSensor),
                observer=observer,
            )
        return VecEstimatedVelocity(make_vec_env(lambda: gym.make(env_id), n_envs=n_envs, seed=0), observer=observer)
    raise ValueError(kind)


KINDS = ("unwrapped", "NormalizeObservation", "per-env physics", "per-env env", "vec env")
#: the configurations that sense (the acceptance's): the others are references
SENSING = KINDS[2:]


#: PPO settings: ``large-batch`` (4 envs, minibatches of 256: little learning cost per environment step, so the
#: environment and the wrapper weigh the most), SB3's defaults (1 env, 2048 steps, minibatches of 64, 10 epochs)
#: and ``rl-zoo3``, the tuned hyperparameters ``scripts/rl_benchmark.py`` trains with (its ``ZOO``, per environment)
SETTINGS = {
    "large-batch": dict(n_envs=4, n_steps=512, batch_size=256),
    "sb3-default": dict(n_envs=1, n_steps=2048, batch_size=64),
    "rl-zoo3": None,
}
#: what the script can measure (``--tables``)
TABLES = ("ppo", "subproc", "in-process")
#: environment steps per timed round, at least (whole rollouts)
ROUND_STEPS = 2048


def _setting(env_id: str, setting: str) -> tuple[int, dict]:
    """``(n_envs, PPO keyword arguments)`` of a :data:`SETTINGS` entry for ``env_id``."""
    if SETTINGS[setting] is not None:
        cfg = dict(SETTINGS[setting])
        return cfg.pop("n_envs"), cfg
    from rl_benchmark import ZOO  # the sibling script (this script's folder is first on sys.path)

    from smo_gym.rl import algo_kwargs

    zoo = ZOO[(env_id, "PPO")]
    return zoo["n_envs"], algo_kwargs("PPO", zoo["hyperparams"])


def training(
    env_id: str, rounds: int, setting: str, observer: str = "auto"
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Steps per wall-clock second and per CPU second of this process, per configuration and round."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(1)
    n_envs, cfg = _setting(env_id, setting)
    with warnings.catch_warnings():  # rl-zoo3's InvertedDoublePendulum minibatch is larger than its rollout
        warnings.filterwarnings("ignore", message=".*mini-batch size.*")
        models = {
            k: PPO("MlpPolicy", VecNormalize(_venv(env_id, k, n_envs, observer=observer)), seed=0, device="cpu", **cfg)
            for k in KINDS
        }
    rollout = cfg["n_steps"] * n_envs
    per_round = rollout * -(-ROUND_STEPS // rollout)
    for m in models.values():  # without a logger of its own every learn() makes a new empty /tmp/SB3-<time> folder
        m.set_logger(Logger(folder=None, output_formats=[]))
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


#: the configurations of the in-process table
IN_PROCESS = ("unwrapped", "per-env env", "vec env")


def _in_process_venv(api: str, env_id: str, kind: str, n_envs: int):
    """An in-process vector env of ``n_envs`` copies of ``env_id``: ``api`` ``"gymnasium"`` (``SyncVectorEnv``)
    or ``"sb3"`` (``DummyVecEnv``), ``kind`` one of :data:`IN_PROCESS`."""
    import gymnasium as gym

    from smo_gym.wrappers import EstimatedVelocity

    if kind == "per-env env":
        fns = [lambda: EstimatedVelocity(gym.make(env_id), rate="env")] * n_envs
    else:
        fns = [lambda: gym.make(env_id)] * n_envs
    if api == "gymnasium":
        from gymnasium.vector import SyncVectorEnv

        from smo_gym.wrappers import VectorEstimatedVelocity as wrapper

        venv = SyncVectorEnv(fns)
    else:
        from stable_baselines3.common.vec_env import DummyVecEnv

        from smo_gym.wrappers import VecEstimatedVelocity as wrapper

        venv = DummyVecEnv(fns)
    return wrapper(venv, "encoder-12bit-noisy", "super-twisting") if kind == "vec env" else venv


def in_process_steps(
    api: str, env_id: str, n_envs: int, rounds: int, steps: int = 200, kinds=IN_PROCESS, chunk: int = 10
) -> dict[str, list[float]]:
    """Microseconds per vector step of each configuration ``kinds``, one entry per chunk of ``chunk`` steps.

    Every round resets all vector envs with the round's seed, then steps them with the same actions, ``chunk``
    steps of each configuration after the other in a shuffled order, each chunk timed (thread CPU time, the
    garbage collector off): the configurations are interleaved chunk by chunk, so a load change of a shared
    machine hits them alike, and chunk ``k`` of every configuration did the same physics (the same episodes and
    autoresets).
    """
    venvs = {k: _in_process_venv(api, env_id, k, n_envs) for k in kinds}
    space = venvs["unwrapped"].action_space  # SyncVectorEnv: the batched space; DummyVecEnv: one environment's
    shape = space.shape if api == "gymnasium" else (n_envs, *space.shape)
    n_chunks = steps // chunk
    actions = np.random.default_rng(0).uniform(-1, 1, (n_chunks, chunk, *shape)).astype(np.float32)

    def reset(v, seed: int) -> None:
        if api == "gymnasium":
            v.reset(seed=seed)
        else:
            v.seed(seed)
            v.reset()

    for v in venvs.values():  # warm-up: compilation, first allocations
        reset(v, 0)
        for a in actions[0]:
            v.step(a)
    order = np.random.default_rng(1)
    clock = time.thread_time
    times: dict[str, list[float]] = {k: [] for k in kinds}
    enabled = gc.isenabled()
    gc.disable()
    try:
        for r in range(rounds):
            for v in venvs.values():
                reset(v, r)
            for block in actions:
                for i in order.permutation(len(kinds)):
                    step = venvs[kinds[i]].step
                    t0 = clock()
                    for a in block:
                        step(a)
                    times[kinds[i]].append((clock() - t0) / chunk * 1e6)
            gc.collect()
    finally:
        if enabled:
            gc.enable()
        for v in venvs.values():
            v.close()
    return times


def format_in_process(rows: list[tuple[str, str, int, dict[str, list[float]]]]) -> str:
    """Table of :func:`in_process_steps` results: us per vector step, its ratio to unwrapped and the sensing's cost
    per environment step (the difference to unwrapped over the number of environments), each the median over
    chunks of the value paired with the unwrapped chunk of the same steps, and the interquartile range of the
    ratio."""
    head = (
        f"{'env':12s} {'vector env':14s} {'n':>3s} {'configuration':14s} {'us/step':>8s} {'ratio':>6s} "
        f"{'IQR':>11s} {'+us/env-step':>12s}"
    )
    lines = [head]
    for api, env_id, n_envs, t in rows:
        base = np.array(t["unwrapped"])
        vector = "SyncVectorEnv" if api == "gymnasium" else "DummyVecEnv"
        for k, v in t.items():
            v = np.array(v)
            q1, q3 = np.percentile(v / base, [25, 75])
            lines.append(
                f"{env_id:12s} {vector:14s} {n_envs:3d} {k:14s} {np.median(v):8.0f} {np.median(v / base):6.3f} "
                f"{q1:5.3f}-{q3:5.3f} {np.median(v - base) / n_envs:12.1f}"
            )
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", default="InvertedDoublePendulum-v5,Hopper-v5")
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--settings", default=",".join(SETTINGS), help=f"PPO settings among {', '.join(SETTINGS)}")
    p.add_argument("--no-subproc", action="store_true", help="the same as leaving subproc out of --tables")
    p.add_argument("--tables", default="ppo,subproc", help=f"among {', '.join(TABLES)}")
    p.add_argument("--n-envs", default="8,32", help="environments per vector env of the in-process table")
    p.add_argument("--steps", type=int, default=200, help="vector steps per round of the in-process table")
    p.add_argument("--observer", default="auto", help="the wrappers' observer in the PPO table (default: auto)")
    args = p.parse_args(argv)
    tables = set(args.tables.split(","))
    for option, given, known in (("--tables", tables, TABLES), ("--settings", args.settings.split(","), SETTINGS)):
        if not set(given) <= set(known):
            p.error(f"{option}: expected names among {', '.join(known)}, actual value: {','.join(given)}")
    if args.no_subproc:
        tables.discard("subproc")
    if "in-process" in tables:
        print(
            f"In-process vector envs, {args.rounds} rounds of {args.steps} steps interleaved in chunks of 10: CPU time "
            "per vector step (us), ratio to unwrapped and the sensing's cost per environment step, medians over "
            "chunks of 10 steps paired with the unwrapped chunk of the same steps, and the IQR of the ratio"
        )
        rows = []
        for env_id in args.envs.split(","):
            for n_envs in (int(n) for n in args.n_envs.split(",")):
                for api in ("gymnasium", "sb3"):
                    rows.append((api, env_id, n_envs, in_process_steps(api, env_id, n_envs, args.rounds, args.steps)))
        print(format_in_process(rows), flush=True)
    if "ppo" not in tables and "subproc" not in tables:
        return 0
    if "ppo" not in tables:
        return _subproc_table(args)
    print(
        f"PPO training throughput (observer={args.observer!r}): env steps per second of wall clock and of process "
        "CPU time (median of interleaved rounds) and their ratio to unwrapped"
    )
    print(
        f"{'env':26s} {'PPO setting':13s} {'configuration':20s} {'wall/s':>7s} {'ratio':>6s} {'cpu/s':>7s} "
        f"{'ratio':>6s}"
    )
    worst = {"wall": np.inf, "cpu": np.inf, "reference": np.inf}
    for env_id in args.envs.split(","):
        for setting in args.settings.split(","):
            wall, cpu = training(env_id, args.rounds, setting, args.observer)
            bw, bc = float(np.median(wall["unwrapped"])), float(np.median(cpu["unwrapped"]))
            for k in KINDS:
                mw, mc = float(np.median(wall[k])), float(np.median(cpu[k]))
                if k in SENSING:
                    worst["wall"] = min(worst["wall"], mw / bw)
                    worst["cpu"] = min(worst["cpu"], mc / bc)
                elif k != "unwrapped":
                    worst["reference"] = min(worst["reference"], mw / bw)
                print(
                    f"{env_id:26s} {setting:13s} {k:20s} {mw:7.0f} {mw / bw:6.2f} {mc:7.0f} {mc / bc:6.2f}", flush=True
                )
    print(
        f"worst ratio of the sensing configurations: wall {worst['wall']:.2f}, cpu {worst['cpu']:.2f} (target >= "
        f"0.90); of NormalizeObservation: wall {worst['reference']:.2f}"
    )
    if "subproc" in tables:
        return _subproc_table(args)
    return 0


def _subproc_table(args) -> int:
    print("\nSubprocVecEnv, 2 workers: time per vector step (us, median), no learning")
    for env_id in args.envs.split(","):
        t = subproc_steps(env_id, args.rounds)
        base = float(np.median(t["unwrapped"]))
        for k, v in t.items():
            print(f"{env_id:28s} {k:16s} {np.median(v):9.0f} {np.median(v) / base:6.2f}x", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
