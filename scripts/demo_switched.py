#!/usr/bin/env python
r"""Mode estimation on the MuJoCo two-link arm whose actuator gears switch mid-episode.

The arm (``smo_gym/TwoLinkArm-v0``, physics and sampling at 2 ms, ``frame_skip=1``) tracks a slow random
reference around the hanging configuration under PD control (the controller reads the simulator's state; the
observers only the encoder). The *simulation's* ``actuator_gear`` switches between three modes,

* ``nominal``: gears (1, 1),
* ``shoulder-low``: the shoulder gear drops to 0.4,
* ``elbow-low``: the elbow gear drops to 0.4,

at random instants with dwell times of 0.6-1.2 s (exogenous switching, unknown to the observer). Each mode is
linearized at the hanging configuration with :func:`smo_gym.control.linearize` (unknown input ``D = B``, the
positions measured: every mode is strongly observable, relative degrees (2, 2)), and a
:class:`smo_gym.control.SwitchedObserverBank` of three cascaded HOSM observers estimates the continuous state and
the mode from the ``"encoder-12bit-noisy"`` positions (12-bit quantization and 1e-3 rad Gaussian noise).

The band is *calibrated*: ``MARGIN`` times the largest residual of the right mode over runs with the mode known
(seeds 1000, 1001, ..., disjoint from the evaluation seeds 0, 1, ...). Reported per seed: mode accuracy (fraction of
samples after the settle time with the right mode), switch-detection delay (true switch to decision), missed and
false switches, and the velocity RMSE of the bank's estimate.

Run ``MUJOCO_GL=disable python scripts/demo_switched.py`` (``--seeds 10``; ``--quick`` for 3 seeds); writes
``outputs/switched/modes.png`` and prints a markdown table.
"""

from __future__ import annotations

import argparse
import copy
import os
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")

import gymnasium as gym

import smo_gym  # noqa: F401  (registers the environments)
from smo_gym import control
from smo_gym.sensors import make_sensor

ENV_ID = "smo_gym/TwoLinkArm-v0"
CENTRE = np.array([np.pi / 2, 0.0])  # hanging (the joint axis is +y): the linearization point
#: mode name -> actuator gears
GEARS = {"nominal": (1.0, 1.0), "shoulder-low": (0.4, 1.0), "elbow-low": (1.0, 0.4)}
LIPSCHITZ = 1000.0  # rad/s^3: the last derivative slews at ~L, so a mismatch jump of J is followed in ~J / L
TAU = 0.05  # s, residual (mean-square) filter: averages the differentiator's noise
DWELL = 0.01  # s, the new mode must fit this long (the residual filter already averages over TAU)
SETTLE = 0.3  # s
MARGIN = 1.5


def modes_of(model) -> control.SwitchedLinearSystem:
    """One linearization per gear setting, at the hanging configuration with zero control."""
    plants = []
    for gear in GEARS.values():
        m = copy.deepcopy(model)
        m.actuator_gear[:, 0] = gear
        plants.append(control.linearize(m, qpos0=CENTRE))
    return control.SwitchedLinearSystem(plants, names=list(GEARS))


def schedule(rng, steps: int, h: float) -> np.ndarray:
    """Random mode sequence: dwell 0.6-1.2 s, never the same mode twice in a row, starting nominal."""
    sigma = np.zeros(steps, dtype=int)
    k, mode = round(rng.uniform(0.6, 1.2) / h), 0
    while k < steps:
        mode = int(rng.choice([j for j in range(len(GEARS)) if j != mode]))
        n = round(rng.uniform(0.6, 1.2) / h)
        sigma[k : k + n] = mode
        k += n
    return sigma


def run_episode(seed: int, *, duration: float, threshold: float | None = None, known: bool = False, sigma=None):
    """One episode; returns ``(estimate, sigma (T + 1,), qvel (T + 1, 2))``. Without ``threshold`` (calibration)
    the bank never decides (unit band, dwell longer than the episode); with ``known`` the mode never switches;
    ``sigma`` (one mode index per step) replaces the random schedule."""
    env = gym.make(ENV_ID, frame_skip=1, reset_noise_scale=0.0)
    obs, _ = env.reset(seed=seed)
    sim = env.unwrapped.model
    h = float(sim.opt.timestep)
    system = modes_of(sim)
    rng = np.random.default_rng(seed + 7919)
    steps = round(duration / h)
    if sigma is None:
        sigma = np.zeros(steps, dtype=int) if known else schedule(rng, steps, h)
    sigma = np.asarray(sigma, dtype=int)
    amp, freq, phase = rng.uniform(0.15, 0.3, 2), rng.uniform(1.0, 3.0, 2), rng.uniform(0, 2 * np.pi, 2)
    env.unwrapped.data.qpos[:] = CENTRE
    env.unwrapped.data.qvel[:] = 0.0
    obs = np.concatenate([CENTRE, [0.0, 0.0]])
    bank = control.SwitchedObserverBank(
        system,
        h,
        LIPSCHITZ,
        threshold=1.0 if threshold is None else threshold,
        dwell=DWELL if threshold is not None else 2 * duration,
        settle_time=SETTLE,
        residual_time_constant=TAU,
    )
    sensor = make_sensor("encoder-12bit-noisy")
    bank.reset(sensor.reset(obs[:2], seed=seed, dt=h) - CENTRE, x_hat0=np.zeros(4))
    lo, hi = sim.actuator_ctrlrange[:, 0], sim.actuator_ctrlrange[:, 1]
    qvel = np.zeros((steps + 1, 2))
    for k in range(steps):
        t = k * h
        sim.actuator_gear[:, 0] = list(GEARS.values())[sigma[k]]  # the plant switches, the bank is not told
        ref = CENTRE + amp * np.sin(freq * t + phase)
        dref = amp * freq * np.cos(freq * t + phase)
        u = np.clip(np.array([40.0, 15.0]) * (ref - obs[:2]) + np.array([4.0, 1.5]) * (dref - obs[2:]), lo, hi)
        bank.advance(u)
        obs, *_ = env.step(u)
        bank.update(sensor.measure(obs[:2]) - CENTRE)
        qvel[k + 1] = obs[2:]
    env.close()
    return bank.result(), np.r_[sigma, sigma[-1]], qvel


def calibrate(n: int, duration: float) -> float:
    """``MARGIN`` times the largest residual of the right (nominal) mode over runs with the mode known."""
    peaks = []
    for s in range(n):
        est, _, _ = run_episode(1000 + s, duration=duration, known=True)
        k0 = round(SETTLE / est.dt)
        peaks.append(est.residual_norms[k0:, 0].max())
    return MARGIN * float(max(peaks))


def evaluate(seeds: int, duration: float, threshold: float) -> list[dict]:
    rows = []
    for s in range(seeds):
        est, sigma, qvel = run_episode(s, duration=duration, threshold=threshold)
        m = control.mode_metrics(est, sigma, start=SETTLE)
        k0 = round(SETTLE / est.dt)
        rmse = float(np.sqrt(np.mean((est.x_hat[k0:, 2:] - qvel[k0:]) ** 2)))
        n_true = int(np.sum(sigma[1:] != sigma[:-1]))
        rows.append(dict(seed=s, metrics=m, switches=n_true, rmse=rmse))
    return rows


def table(rows: list[dict]) -> str:
    out = [
        "| seed | true switches | detected | missed | false switches | mode accuracy | delay [ms] median / max "
        "| velocity RMSE [rad/s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m = r["metrics"]
        d = f"{1e3 * np.median(m.delays):.0f} / {1e3 * np.max(m.delays):.0f}" if m.delays.size else "-"
        out.append(
            f"| {r['seed']} | {r['switches']} | {m.delays.size} | {m.missed} | {m.false_switches} | "
            f"{100 * m.accuracy:.1f} % | {d} | {r['rmse']:.3f} |"
        )
    delays = np.concatenate([r["metrics"].delays for r in rows])
    acc = np.mean([r["metrics"].accuracy for r in rows])
    missed: dict[str, int] = {}
    names = list(GEARS)
    for r in rows:
        for _, a, b in r["metrics"].missed_switches:
            key = f"{names[a]} -> {names[b]}"
            missed[key] = missed.get(key, 0) + 1
    out.append("")
    out.append(
        "Missed switches by transition: "
        + (", ".join(f"{k}: {v}" for k, v in sorted(missed.items(), key=lambda kv: -kv[1])) or "none")
        + "."
    )
    out.append(
        f"All seeds: {delays.size}/{sum(r['switches'] for r in rows)} switches detected, "
        f"{sum(r['metrics'].false_switches for r in rows)} false switches, mean mode accuracy {100 * acc:.1f} %, "
        f"detection delay median {1e3 * np.median(delays):.0f} ms, max {1e3 * np.max(delays):.0f} ms."
    )
    return "\n".join(out)


def plot(path: Path, threshold: float, duration: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    est, sigma, qvel = run_episode(0, duration=duration, threshold=threshold)
    t = np.arange(est.modes.shape[0]) * est.dt
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    axes[0].step(t, sigma, where="post", label="true mode", lw=2, color="0.7")
    axes[0].step(t, est.modes, where="post", label="estimated mode", lw=1, color="C3")
    axes[0].set_yticks(range(len(GEARS)), list(GEARS))
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title("two-link arm, actuator gears switching; bank of cascaded HOSM observers, 12-bit noisy encoder")
    for j, name in enumerate(GEARS):
        axes[1].semilogy(t, np.maximum(est.residual_norms[:, j], 1e-3), label=name, lw=1)
    axes[1].axhline(1.0, color="k", ls="--", lw=0.8)
    axes[1].set_ylabel("residual / band")
    axes[1].legend(loc="upper right", fontsize=8, ncol=3)
    axes[2].plot(t, qvel[:, 0], color="0.6", lw=2, label="true shoulder velocity")
    axes[2].plot(t, est.x_hat[:, 2], color="C0", lw=0.8, label="estimate")
    axes[2].set_ylabel("rad/s")
    axes[2].set_xlabel("time [s]")
    axes[2].legend(loc="upper right", fontsize=8)
    for ax in axes:
        for ts in t[1:][sigma[1:] != sigma[:-1]]:
            ax.axvline(ts, color="r", ls=":", lw=0.8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--calibration-seeds", type=int, default=5)
    p.add_argument("--duration", type=float, default=6.0)
    p.add_argument("--quick", action="store_true", help="3 seeds, 2 calibration seeds")
    p.add_argument("--out", type=Path, default=Path("outputs/switched"))
    a = p.parse_args(argv)
    if a.quick:
        a.seeds, a.calibration_seeds = 3, 2
    t0 = time.perf_counter()
    threshold = calibrate(a.calibration_seeds, a.duration)
    print(f"band (calibrated on {a.calibration_seeds} seeds with the mode known, x{MARGIN}): {threshold:.2f} rad/s^2")
    print(table(evaluate(a.seeds, a.duration, threshold)))
    plot(a.out / "modes.png", threshold, a.duration)
    print(f"plot: {a.out / 'modes.png'}; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
