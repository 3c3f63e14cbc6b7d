#!/usr/bin/env python
r"""Step-time cost of :class:`smo_gym.wrappers.EstimatedVelocity`, as a ratio to the raw environment.

For each environment (InvertedPendulum-v5, Hopper-v5, HalfCheetah-v5, Humanoid-v5 by default) four copies run the
*same* action sequence from the same seed (the wrapper never perturbs the simulation, so all four do the same
physics work and terminate at the same steps):

``raw``
    ``gym.make(env_id)``;
``physics``
    ``EstimatedVelocity(..., observer="super-twisting", rate="physics")`` with the default sensor (noisy 12-bit
    encoder): the sensor and the observer run at every MuJoCo step inside ``frame_skip``;
``env``
    the same with ``rate="env"``: one sample per environment step;
``NormalizeObservation``
    Gymnasium's running-mean observation normalizer, the reference cost of a light observation wrapper.

Timing is interleaved: every repeat times a block of ``--steps`` ``env.step`` calls of each variant, in an order
shuffled per repeat, with the garbage collector off and the thread's CPU time (``time.thread_time``: the machine is
shared, wall time would count other jobs); resets at episode ends happen outside the timed calls. The ratio of a
variant is taken against the raw block of the *same* repeat, and the table reports the median over repeats (and
the inter-quartile range of the ratio), so slow drifts of the machine cancel.

Targets, each also required to be below ``NormalizeObservation``'s ratio on the same environment:

================== ============== ==================
environment         ``rate="env"``  ``rate="physics"``
================== ============== ==================
InvertedPendulum    1.40            1.80
Hopper              1.10            1.20
HalfCheetah         1.20            1.40
Humanoid            1.10            1.20
================== ============== ==================

``--tables resets`` times the same blocks with the resets at episode ends (no seed, as a vector env's autoreset
does) counted too: what a training loop pays per environment step, where a short-episode environment resets every
few steps; then the wrapper's reset against the raw one, with its parts timed in situ (the environment's own reset,
the sensor's and the observer's, the check of the compiled observation, the first observation). No targets: those
are the steps'.

``--profile ENV`` prints a cProfile of the wrapped step (``rate="physics"`` and ``"env"``) on that environment,
sorted by internal time, to show where the wrapper's time goes.

Run: ``MUJOCO_GL=disable .venv/bin/python scripts/bench_wrapper.py`` (``--quick`` for a short run;
``--tables resets --observer auto`` for the resets with the wrapper's default observer).
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

import gymnasium as gym

from smo_gym.wrappers import EstimatedVelocity

ENVS = ("InvertedPendulum-v5", "Hopper-v5", "HalfCheetah-v5", "Humanoid-v5")
#: env id -> (target at rate="env", target at rate="physics")
TARGETS = {
    "InvertedPendulum-v5": (1.40, 1.80),
    "Hopper-v5": (1.10, 1.20),
    "HalfCheetah-v5": (1.20, 1.40),
    "Humanoid-v5": (1.10, 1.20),
}
VARIANTS = ("raw", "physics", "env", "NormalizeObservation")
CLOCK = time.thread_time


def make_variant(env_id: str, variant: str, observer: str = "super-twisting") -> gym.Env:
    """One of :data:`VARIANTS` for ``env_id``."""
    env = gym.make(env_id)
    if variant == "raw":
        return env
    if variant == "NormalizeObservation":
        return gym.wrappers.NormalizeObservation(env)
    return EstimatedVelocity(env, observer=observer, rate=variant)


def smooth_actions(space: gym.spaces.Box, n: int, seed: int) -> list[np.ndarray]:
    """A seeded low-pass random policy, so that episodes last (the same sequence for every variant)."""
    rng = np.random.default_rng(seed)
    a = np.zeros(space.shape)
    out = []
    for _ in range(n):
        a = 0.9 * a + 0.1 * rng.uniform(space.low, space.high)
        out.append(a.astype(space.dtype))
    return out


def timed_block(env: gym.Env, actions: list[np.ndarray], seed: int, resets: bool = False) -> float:
    """CPU seconds spent in ``env.step`` over ``actions``, reset at episode ends (without a seed, as an autoreset):
    those resets untimed, or timed too with ``resets``. The reset at the start is never timed."""
    env.reset(seed=seed)
    step, clock = env.step, CLOCK
    total = 0.0
    t0 = clock()  # one clock read per episode segment (a thread-CPU clock read costs about 1 us here)
    for a in actions:
        _, _, terminated, truncated, _ = step(a)
        if terminated or truncated:
            if resets:
                env.reset()
                continue
            total += clock() - t0
            env.reset()
            t0 = clock()
    return total + (clock() - t0)


def episode_ends(env_id: str, actions: list[np.ndarray], seed: int) -> int:
    """How many episodes end within ``actions`` from ``reset(seed=seed)`` (the same for every variant)."""
    env = gym.make(env_id)
    env.reset(seed=seed)
    ends = 0
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            ends += 1
            env.reset()
    env.close()
    return ends


def bench_env(
    env_id: str,
    repeats: int,
    steps: int,
    seed: int = 0,
    observer: str = "super-twisting",
    envs: dict | None = None,
    resets: bool = False,
) -> dict:
    """Median step-time ratios against ``raw`` (interleaved, see the module docstring); ``envs`` maps variant
    names to environments (default: :data:`VARIANTS`), one of them ``"raw"``; ``resets``: the resets at episode
    ends are timed too (:func:`timed_block`)."""
    envs = envs or {v: make_variant(env_id, v, observer) for v in VARIANTS}
    variants = tuple(envs)
    actions = smooth_actions(envs["raw"].action_space, steps, seed)
    for env in envs.values():  # warm-up: compilation, caches, first-touch allocations
        timed_block(env, actions[: min(50, steps)], seed)
    order_rng = np.random.default_rng(seed)
    times = {v: [] for v in variants}
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for r in range(repeats):
            for idx in order_rng.permutation(len(variants)):
                v = variants[idx]
                times[v].append(timed_block(envs[v], actions, seed + r, resets))
            gc.collect()
    finally:
        if gc_was_enabled:
            gc.enable()
    raw = np.array(times["raw"])
    out = {"env_id": env_id, "raw_us": 1e6 * float(np.median(raw)) / steps, "times": times, "steps": steps}
    for v in variants:
        if v == "raw":
            continue
        ratios = np.array(times[v]) / raw
        q1, med, q3 = np.percentile(ratios, [25, 50, 75])
        out[v] = {"ratio": float(med), "iqr": (float(q1), float(q3)), "us": 1e6 * float(np.median(times[v])) / steps}
    for env in envs.values():
        env.close()
    return out


def format_table(results: list[dict]) -> str:
    """Markdown table: raw cost, ratio of each variant (median [IQR]), targets and pass/fail."""
    head = (
        '| environment | raw us/step | NormalizeObservation | rate="env" | target | pass | '
        'rate="physics" | target | pass |'
    )
    lines = [head, "|---|---:|---:|---:|---:|:-:|---:|---:|:-:|"]

    def cell(res):
        q1, q3 = res["iqr"]
        return f"{res['ratio']:.3f} [{q1:.2f}-{q3:.2f}]"

    def verdict(ratio, target, norm):  # environments without a target (not in TARGETS): "-"
        if target is None:
            return "-", "-"
        return f"{target:.2f}", "pass" if ratio <= target and ratio < norm else "FAIL"

    for res in results:
        norm = res["NormalizeObservation"]["ratio"]
        t_env, t_phys = TARGETS.get(res["env_id"], (None, None))
        target_env, ok_env = verdict(res["env"]["ratio"], t_env, norm)
        target_phys, ok_phys = verdict(res["physics"]["ratio"], t_phys, norm)
        lines.append(
            f"| {res['env_id']} | {res['raw_us']:.1f} | {cell(res['NormalizeObservation'])} | {cell(res['env'])} | "
            f"{target_env} | {ok_env} | {cell(res['physics'])} | {target_phys} | {ok_phys} |"
        )
    return "\n".join(lines)


def ablations(env_id: str, rate: str, observer: str = "super-twisting") -> dict:
    """The wrapped env with its parts switched off one after the other (instance attributes replaced), to measure
    each part's marginal cost *in situ* (interleaved with the physics, caches as in real use): ``full``;
    ``-scratch obs`` (the scratch evaluation of ``_get_obs`` returns a constant); ``-observe`` (no observation
    at all: also no finiteness check and no ``info["smo"]``); ``-sensing`` (also no sensor and no observer
    update: what remains is the wrapper's skeleton and, at ``rate="physics"``, the substep hook that copies
    ``qpos`` after every physics step). The wrapper's hot path (``FusedSensing``) is what is switched off."""

    def wrapped():
        env = make_variant(env_id, rate, observer)
        env.reset(seed=0)
        if env._fused is None:
            raise SystemExit(f"{env_id}: the wrapper does not take the fused hot path; no ablation")
        return env

    full, no_scratch, no_observe, no_sensing = wrapped(), wrapped(), wrapped(), wrapped()
    const = np.array(full.observation_space.sample(), dtype=np.float64)
    for env in (no_scratch, no_observe, no_sensing):
        if env._fused.maps_observation:  # the full path runs no Python finiteness check: nor do the ablations
            env._fused.evaluation.checks_observation = True
        env._fused.evaluation.observe_scratch = lambda *args, c=const: c  # what _observe_fused calls
        env._fused.maps_observation = False  # a selection built by the compiled call is switched off here too

    def no_observation(block, info, clean, c=const):
        info["smo"] = {}
        return c

    for env in (no_observe, no_sensing):
        env._observe_fused = no_observation
    block = np.zeros(2 * full.adapter.model.nq + 4 * full.adapter.model.nv)
    no_sensing._fused.sample = lambda samples, qvel, b=block: b
    return {
        "raw": make_variant(env_id, "raw"),
        "full": full,
        "-scratch obs": no_scratch,
        "-observe": no_observe,
        "-sensing": no_sensing,
    }


def format_ablation(env_id: str, rate: str, res: dict) -> str:
    """Marginal cost of each part in microseconds per env step: median over repeats of the paired difference of
    consecutive ablations timed in the same repeat (absolute times drift on a shared machine; pairs cancel it)."""
    raw_us = res["raw_us"]
    times, steps = res["times"], res["steps"]

    def diff(a, b):
        return 1e6 * float(np.median(np.array(times[a]) - np.array(times[b]))) / steps

    parts = [
        (
            "observation at the sensed state (ScratchObservation.observe_scratch, or built by the compiled call)",
            diff("full", "-scratch obs"),
        ),
        ("finiteness check and info['smo']", diff("-scratch obs", "-observe")),
        ("sensor + observer + outputs (FusedSensing.sample, one compiled call)", diff("-observe", "-sensing")),
        (
            "skeleton (Wrapper.step, bookkeeping" + (", substep hook and sampling)" if rate != "env" else ")"),
            diff("-sensing", "raw"),
        ),
    ]
    lines = [
        f"{env_id}, rate={rate!r}: raw {raw_us:.1f} us/step, wrapped {res['full']['us']:.1f} us/step "
        f"(ratio {res['full']['ratio']:.3f}; total overhead, paired: {diff('full', 'raw'):.1f} us)",
        "| part | us/step | share of the raw step |",
        "|---|---:|---:|",
    ]
    lines += [f"| {name} | {v:.1f} | {v / raw_us:.1%} |" for name, v in parts]
    return "\n".join(lines)


def format_with_resets(results: list[dict], ends: dict) -> str:
    """Markdown table of :func:`bench_env` results timed with the resets (no targets: those are for the steps)."""
    lines = [
        "| environment | episode ends (block of seed 0) | raw us/step | NormalizeObservation | "
        'rate="env" | rate="physics" |',
        "|---|---:|---:|---:|---:|---:|",
    ]
    for res in results:
        cells = []
        for v in ("NormalizeObservation", "env", "physics"):
            q1, q3 = res[v]["iqr"]
            cells.append(f"{res[v]['ratio']:.3f} [{q1:.2f}-{q3:.2f}]")
        lines.append(f"| {res['env_id']} | {ends[res['env_id']]} | {res['raw_us']:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: the calls of ``EstimatedVelocity.reset`` timed by :func:`reset_parts`: (label, the object, the attribute)
RESET_PARTS = (
    ("the environment's own reset", lambda env: (env.env, "reset")),
    ("sensor (JointMeasurement.reset)", lambda env: (env.measurement, "reset")),
    ("observer (VelocityEstimator.reset: a restart)", lambda env: (env.estimator, "reset")),
    ("check of the compiled observation (ScratchObservation.verify)", lambda env: (env.adapter.evaluation, "verify")),
    ("observation and info['smo'] (general path)", lambda env: (env, "_observe")),
)


def reset_parts(env_id: str, observer: str, resets: int = 2000, rates=("env", "physics")) -> dict:
    """Median wall time (us) of ``resets`` resets without a seed of the raw environment and of the wrapper at each
    of ``rates``, and of each part of the wrapper's reset (:data:`RESET_PARTS`) timed in situ by wrapping the calls
    with a clock read before and after (instance attributes; ~0.1 us each). Interleaved in blocks of 100 resets
    (raw, then each rate), so that the machine's drift hits every column alike. Returns ``{rate: {part: us}}``,
    each with ``"raw"`` and ``"wrapped"``."""
    raw = make_variant(env_id, "raw")
    wrapped = {rate: make_variant(env_id, rate, observer) for rate in rates}
    clock = time.perf_counter_ns

    def timed(call, into: list):
        def call_timed(*args, **kwargs):
            t0 = clock()
            out = call(*args, **kwargs)
            into.append(clock() - t0)
            return out

        return call_timed

    parts = {rate: {} for rate in rates}
    for e in (raw, *wrapped.values()):
        e.reset(seed=0)
        e.step(e.action_space.sample())
    for rate, env in wrapped.items():
        for name, where in RESET_PARTS:
            obj, attr = where(env)
            setattr(obj, attr, timed(getattr(obj, attr), parts[rate].setdefault(name, [])))
    totals = {key: [] for key in ("raw", *rates)}
    for _ in range(resets // 100):
        for key, e in (("raw", raw), *wrapped.items()):
            for _ in range(100):
                t0 = clock()
                e.reset()
                totals[key].append(clock() - t0)
    out = {}
    for rate in rates:
        times = {"raw": totals["raw"], "wrapped": totals[rate], **parts[rate]}
        out[rate] = {key: 1e-3 * float(np.median(v)) for key, v in times.items()}
    for e in (raw, *wrapped.values()):
        e.close()
    return out


def format_resets(env_id: str, res: dict) -> str:
    """Markdown table of :func:`reset_parts` (``res`` maps each rate to its result)."""
    rates = tuple(res)
    lines = [
        f"{env_id}: reset without a seed, median us (parts timed in situ)",
        "| part | " + " | ".join(f"rate={r!r}" for r in rates) + " |",
        "|---|" + "---:|" * len(rates),
        "| raw environment's reset | " + " | ".join(f"{res[r]['raw']:.1f}" for r in rates) + " |",
        "| EstimatedVelocity's reset | " + " | ".join(f"{res[r]['wrapped']:.1f}" for r in rates) + " |",
    ]
    for name, _ in RESET_PARTS:
        lines.append(f"| - {name} | " + " | ".join(f"{res[r][name]:.1f}" for r in rates) + " |")
    rest = [res[r]["wrapped"] - sum(res[r][name] for name, _ in RESET_PARTS) for r in rates]
    lines.append("| - the rest (streams, bookkeeping, the fused path's preparation) | "
                 + " | ".join(f"{v:.1f}" for v in rest) + " |")  # fmt: skip
    return "\n".join(lines)


def cold_path(env_id: str, n: int = 3000, repeats: int = 5) -> str:
    """Why the wrapper costs more inside a step than its parts cost in a loop: after ``env.step`` the first
    (sensor measure + observer update) pair of a step is timed against a second identical pair and against the
    pair alone in a hot loop (wall time, best of ``repeats``). A large first-pair excess is a cold-path cost
    (instruction/data caches and branch predictors refilled after the physics step): it scales with the number of
    distinct Python/numba code paths a step touches, not with their arithmetic."""
    env = EstimatedVelocity(gym.make(env_id), rate="env")
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, env.action_space.dtype)
    qpos, measure, update, inner = env.adapter.data.qpos, env.measurement.measure, env.estimator.update, env.env.step

    def run(k: int, with_step: bool = True) -> float:
        best = float("inf")
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(n):
                if with_step:
                    inner(action)
                for _ in range(k):
                    update(measure(qpos))
            best = min(best, (time.perf_counter() - t0) / n * 1e6)
        return best

    step0, step1, step2, alone = run(0), run(1), run(2), run(1, with_step=False)
    return (
        f"{env_id}: env.step {step0:.1f} us; first sensor+observer pair after it +{step1 - step0:.1f} us, "
        f"second pair +{step2 - step1:.1f} us, the pair alone in a hot loop {alone:.1f} us"
    )


def profile(env_id: str, steps: int, rate: str, observer: str = "super-twisting", top: int = 25) -> str:
    """cProfile of ``steps`` wrapped steps, sorted by internal time; returns the printed statistics."""
    import cProfile
    import io
    import pstats

    env = make_variant(env_id, rate, observer)
    actions = smooth_actions(env.action_space, steps, 0)
    timed_block(env, actions[:50], 0)
    prof = cProfile.Profile()
    prof.enable()
    timed_block(env, actions, 0)
    prof.disable()
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(top)
    return buf.getvalue()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", default=",".join(ENVS), help="comma-separated environment ids")
    parser.add_argument("--repeats", type=int, default=21, help="timed blocks per variant (median over them)")
    parser.add_argument("--steps", type=int, default=400, help="env steps per timed block")
    parser.add_argument("--observer", default="super-twisting")
    parser.add_argument("--quick", action="store_true", help="7 repeats of 200 steps")
    parser.add_argument("--profile", metavar="ENV", help="print a cProfile of the wrapped step on ENV and exit")
    parser.add_argument(
        "--cold-path",
        action="store_true",
        help="also print the first-call (cold path) cost of sensor+observer after env.step",
    )
    parser.add_argument(
        "--ablate",
        action="store_true",
        help="also print the marginal cost of each part of the wrapper (see ablations())",
    )
    parser.add_argument(
        "--tables",
        default="steps",
        help="comma-separated among: steps (the step-time table, the default), resets (the steps timed with the "
        "resets at episode ends, and the parts of a reset)",
    )
    args = parser.parse_args(argv)
    tables = {t.strip() for t in args.tables.split(",") if t.strip()}
    if not tables or tables - {"steps", "resets"}:
        parser.error(f"expected --tables among steps, resets, actual value: {args.tables!r}")
    if args.quick:
        args.repeats, args.steps = 7, 200
    warnings.filterwarnings("ignore")
    if args.profile:
        for rate in ("physics", "env"):
            print(f"## {args.profile}, rate={rate!r}, {args.observer}: cProfile of {args.steps * 5} steps")
            print(profile(args.profile, args.steps * 5, rate, args.observer))
        return 0
    envs = [e.strip() for e in args.envs.split(",") if e.strip()]
    if "steps" in tables:
        print(
            f"EstimatedVelocity step time / raw step time ({args.observer}, default sensor), medians over "
            f"{args.repeats} interleaved blocks of {args.steps} steps (thread CPU time); [IQR of the ratio]; "
            f"pass = ratio <= target and < NormalizeObservation's ratio\n",
            flush=True,
        )
        results = []
        for env_id in envs:
            t0 = time.perf_counter()
            results.append(bench_env(env_id, args.repeats, args.steps, observer=args.observer))
            print(f"  {env_id}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        print(format_table(results))
    if "resets" in tables:
        print(
            f"\nWith the resets: the same blocks ({args.observer}, default sensor, {args.repeats} interleaved blocks "
            f"of {args.steps} steps, thread CPU time), the resets at episode ends (no seed, as an autoreset) timed "
            "too: what a training loop pays per environment step; [IQR of the ratio]\n",
            flush=True,
        )
        results, ends = [], {}
        for env_id in envs:
            ends[env_id] = episode_ends(env_id, smooth_actions(gym.make(env_id).action_space, args.steps, 0), 0)
            results.append(bench_env(env_id, args.repeats, args.steps, observer=args.observer, resets=True))
        print(format_with_resets(results, ends))
        print("\nWhere a reset's time goes: the wrapper's reset and its parts, in situ\n")
        for env_id in envs:
            print(format_resets(env_id, reset_parts(env_id, args.observer)) + "\n", flush=True)
    if args.cold_path:
        print("\nCold path: the same sensor+observer calls cost more right after the physics step\n")
        for env_id in envs:
            print("- " + cold_path(env_id), flush=True)
    if args.ablate:
        print(
            "\nWhere the wrapper's time goes: marginal cost of each part, measured in situ by switching the parts "
            "off one after the other (interleaved medians)\n"
        )
        for env_id in envs:
            for rate in ("env", "physics"):
                res = bench_env(
                    env_id,
                    args.repeats,
                    args.steps,
                    observer=args.observer,
                    envs=ablations(env_id, rate, args.observer),
                )
                print(format_ablation(env_id, rate, res) + "\n", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
