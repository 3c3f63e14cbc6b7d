#!/usr/bin/env python
r"""Fault detection and isolation on the MuJoCo two-link arm with a bank of super-twisting observers.

The arm (``smo_gym/TwoLinkArm-v0``, physics and sampling at 2 ms, ``frame_skip=1``) tracks a slow random
reference under PD control (the controller reads the simulator's state; the fault detector only the encoder).
Half-way through the episode the *simulation's* model changes (``env.unwrapped.model``), one of

* ``shoulder-gain``: the shoulder motor loses half its gain (``actuator_gear`` x 0.5),
* ``elbow-gain``: the elbow motor loses half its gain,
* ``elbow-damping``: the elbow joint's viscous damping grows from 0.05 to 1.0 N m s/rad,

or, outside the bank, ``shoulder-damping`` (0.05 to 1.0 N m s/rad at the shoulder). The positions are measured by the
``"encoder-12bit-noisy"`` sensor (12-bit quantization and 1e-3 rad Gaussian noise). The bank
(:class:`smo_gym.fault_detection.FaultObserverBank`) has the nominal model and the three known faulty models, each a
:class:`smo_gym.mechanics.MujocoDynamics` of a modified copy of the model.

The threshold is *calibrated*: 1.5 times the largest nominal residual per joint over fault-free runs of
calibration seeds (1000, 1001, ...), disjoint from the evaluation seeds (0, 1, ...). Each evaluation seed runs
every fault once and one fault-free episode (for the false-alarm rate).

Run ``MUJOCO_GL=disable python scripts/demo_fault_detection.py`` (``--seeds 20``, ``--quick`` for fewer seeds
and shorter episodes); writes ``outputs/fault_detection/residuals.png`` and prints a markdown table.
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
from smo_gym.fault_detection import FaultObserverBank, calibrate_threshold
from smo_gym.mechanics import MujocoDynamics
from smo_gym.sensors import make_sensor

ENV_ID = "smo_gym/TwoLinkArm-v0"
#: fault name -> modification of an MjModel in place (the same function faults the plant and builds the bank)
FAULTS = {
    "shoulder-gain": lambda m: m.actuator_gear.__setitem__((0, 0), 0.5 * m.actuator_gear[0, 0]),
    "elbow-gain": lambda m: m.actuator_gear.__setitem__((1, 0), 0.5 * m.actuator_gear[1, 0]),
    "elbow-damping": lambda m: m.dof_damping.__setitem__(1, 1.0),
}
UNKNOWN = {"shoulder-damping": lambda m: m.dof_damping.__setitem__(0, 1.0)}
SETTLE = 0.3  # s, observer convergence from the zero initial velocity estimate
LIPSCHITZ = 100.0  # rad/s^2: k2 = 1.1 L must exceed what a model misses under any fault of the bank
TAU = 0.1  # s, residual filter (averages the injection chattering caused by the encoder noise)
DWELL = 0.2  # s, isolation dwell
MARGIN = 1.5
ACCEL_BOUND = 300.0  # rad/s^2, saturates the model term: a wrong model's observer must not escape (Coriolis)


def make_bank(model, threshold, dt: float) -> FaultObserverBank:
    """Nominal model plus one faulty ``MujocoDynamics`` per known fault."""
    faulty = []
    for modify in FAULTS.values():
        m = copy.deepcopy(model)
        modify(m)
        faulty.append(MujocoDynamics(m))
    return FaultObserverBank(
        dt,
        MujocoDynamics(model),
        faulty,
        threshold,
        lipschitz=LIPSCHITZ,
        dwell=DWELL,
        settle_time=SETTLE,
        disturbance_time_constant=TAU,
        names=list(FAULTS),
        accel_bound=ACCEL_BOUND,
    )


def run_episode(seed: int, fault: str | None, *, duration: float, fault_time: float, threshold=None):
    """One episode; returns ``(diagnosis, nominal residual history (T, 2))``. Without ``threshold`` the bank uses a
    unit threshold (for calibration, only the residuals matter)."""
    env = gym.make(ENV_ID, frame_skip=1)
    obs, _ = env.reset(seed=seed)
    sim = env.unwrapped.model
    h = float(sim.opt.timestep)
    rng = np.random.default_rng(seed + 7919)
    amp, freq, phase = rng.uniform(0.2, 0.6, 2), rng.uniform(0.8, 2.5, 2), rng.uniform(0, 2 * np.pi, 2)
    centre = np.array([-np.pi / 2, 0.0]) + rng.uniform(-0.3, 0.3, 2)
    bank = make_bank(copy.deepcopy(sim), 1.0 if threshold is None else threshold, h)
    sensor = make_sensor("encoder-12bit-noisy")
    y = sensor.reset(obs[:2], seed=seed, dt=h)
    bank.reset(y)
    modify = {**FAULTS, **UNKNOWN}.get(fault)
    lo, hi = sim.actuator_ctrlrange[:, 0], sim.actuator_ctrlrange[:, 1]
    steps = round(duration / h)
    residual = np.zeros((steps + 1, 2))
    for k in range(steps):
        t = k * h
        if modify is not None and k == round(fault_time / h):
            modify(sim)  # the plant changes, the observers' models do not
        ref = centre + amp * np.sin(freq * t + phase)
        dref = amp * freq * np.cos(freq * t + phase)
        u = np.clip(np.array([40.0, 15.0]) * (ref - obs[:2]) + np.array([4.0, 1.5]) * (dref - obs[2:]), lo, hi)
        obs, *_ = env.step(u)
        bank.update(sensor.measure(obs[:2]), u)
        residual[k + 1] = bank.residuals[0]
    env.close()
    return bank.diagnose(), residual


def calibrate(n: int, duration: float) -> np.ndarray:
    res = [run_episode(1000 + s, None, duration=duration, fault_time=duration)[1] for s in range(n)]
    h = 0.002
    return calibrate_threshold(np.stack(res, axis=1), h, settle_time=SETTLE, margin=MARGIN)


def evaluate(seeds: int, duration: float, fault_time: float, threshold) -> dict:
    """Detection delays, isolation verdicts and false alarms over ``seeds`` seeds (every fault once per seed)."""
    rows = {}
    for name in [*FAULTS, *UNKNOWN, None]:
        delays, iso_delays, verdicts, detected, early = [], [], [], 0, 0
        for s in range(seeds):
            d, _ = run_episode(s, name, duration=duration, fault_time=fault_time, threshold=threshold)
            if d.detected and d.detection_time < fault_time:
                early += 1  # an alarm before the fault: a false alarm, not a detection
            elif d.detected:
                detected += 1
                delays.append(float(d.detection_time) - fault_time)
            verdicts.append(d.label())
            if d.label() == name:
                iso_delays.append(float(d.isolation_time) - fault_time)
        rows[name or "fault-free"] = dict(
            detected=detected, early=early, delays=delays, iso=iso_delays, verdicts=verdicts
        )
    return rows


def _median_max(values) -> str:
    return f"{1e3 * np.median(values):.0f} / {1e3 * np.max(values):.0f}" if values else "-"


def table(rows: dict, seeds: int) -> str:
    out = [
        "| plant | detected | detection delay [ms] median / max | verdict | isolation delay [ms] median / max |",
        "|---|---|---|---|---|",
    ]
    known_correct = 0
    for name, r in rows.items():
        expected = "unknown" if name in UNKNOWN else ("no fault" if name == "fault-free" else name)
        correct = sum(v == expected for v in r["verdicts"])
        if name in FAULTS:
            known_correct += correct
        others = sorted({v for v in r["verdicts"] if v != expected})
        verdict = f"{correct}/{seeds} {expected}" + (f" (else: {', '.join(others)})" if others else "")
        detected = f"{r['detected'] + r['early']}/{seeds} (false alarms)" if name == "fault-free" else None
        detected = detected or f"{r['detected']}/{seeds}" + (f" ({r['early']} before the fault)" if r["early"] else "")
        out.append(f"| {name} | {detected} | {_median_max(r['delays'])} | {verdict} | {_median_max(r['iso'])} |")
    out.append("")
    out.append(
        f"Isolation accuracy over the known faults: {known_correct}/{len(FAULTS) * seeds}; "
        f"false-alarm rate: {rows['fault-free']['detected'] + rows['fault-free']['early']}/{seeds} fault-free runs; "
        f"alarms before the fault in faulty runs: {sum(r['early'] for r in rows.values())}."
    )
    return "\n".join(out)


def plot(path: Path, threshold, duration: float, fault_time: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [*FAULTS, *UNKNOWN]
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 2.4 * len(names)), sharex=True)
    for ax, name in zip(axes, names, strict=True):
        d, _ = run_episode(0, name, duration=duration, fault_time=fault_time, threshold=threshold)
        t = np.arange(d.residual_norms.shape[0]) * 0.002
        for i, label in enumerate(d.names):
            ax.semilogy(t, np.maximum(d.residual_norms[:, i], 1e-3), label=label, lw=1)
        ax.axhline(1.0, color="k", ls="--", lw=0.8)
        ax.axvline(fault_time, color="r", ls=":", lw=0.8)
        ax.set_ylabel("residual / threshold")
        ax.set_title(f"plant fault: {name}; verdict: {d.label()} (detected at {float(d.detection_time):.3f} s)")
    axes[0].legend(ncol=4, fontsize=8)
    axes[-1].set_xlabel("time [s] (fault at the dotted line, band below the dashed line)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--calibration-seeds", type=int, default=10)
    p.add_argument("--duration", type=float, default=2.0)
    p.add_argument("--quick", action="store_true", help="3 seeds, 2 calibration seeds")
    p.add_argument("--out", type=Path, default=Path("outputs/fault_detection"))
    a = p.parse_args(argv)
    if a.quick:
        a.seeds, a.calibration_seeds = 3, 2
    fault_time = a.duration / 2
    t0 = time.perf_counter()
    threshold = calibrate(a.calibration_seeds, a.duration)
    print(f"threshold (calibrated on {a.calibration_seeds} fault-free seeds, x{MARGIN}): {threshold} rad/s^2")
    rows = evaluate(a.seeds, a.duration, fault_time, threshold)
    print(table(rows, a.seeds))
    plot(a.out / "residuals.png", threshold, a.duration, fault_time)
    print(f"plot: {a.out / 'residuals.png'}; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
