"""Identify the payload mass of a MuJoCo arm online, from noisy encoders only.

The forearm (body ``lower``) of ``smo_gym/TwoLinkArm-v0`` carries a payload: its mass is 1.2 kg in the simulation
while the identifier's model says 0.8 kg. Only the encoder readings (:mod:`smo_gym.sensors` presets) and the applied
torques reach the identifier (:class:`smo_gym.identification.EquivalentInjectionIdentifier`): a super-twisting
observer with the nominal model (:class:`smo_gym.mechanics.MujocoDynamics`), its filtered equivalent output
injection and least squares on the regressor :math:`\\Phi = -\\bar M^{-1}\\partial(M\\ddot q + c)/\\partial m`
from MuJoCo's own inverse dynamics (:class:`smo_gym.mechanics.MujocoParameterRegressor`). The arm tracks a
sum-of-sines reference under a PD law computed from the true state (it only provides the excitation).

Table 1: dynamic least squares, constant payload, 3 sensors x 2 sampling steps: the error of the estimate
(mean over the last 5 s) and the settling time (to within 5 % for good). Table 2: the payload changes from 1.2 kg
to 0.6 kg at half time (``model.body_mass`` of the simulation; the identifier's copy is untouched), identified
with the matrix forgetting factor ``R = exp(-rate)``: settling times (10 % and 5 % of the new mass, counted
from the change) and the error over the last 2 s.

``python scripts/demo_identification.py [out_dir] [--fast]`` prints both tables and writes
``identification.png`` (default ``outputs/identification``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import gymnasium as gym
import mujoco

import smo_gym  # noqa: F401  (registers the environments)
from smo_gym import sensors
from smo_gym.identification import EquivalentInjectionIdentifier
from smo_gym.mechanics import MujocoDynamics, MujocoParameterRegressor

PHYSICS_DT = 0.002
TRUE_MASS = 1.2
CHANGED_MASS = 0.6
LIPSCHITZ = 150.0
SENSORS = ("ideal", "encoder-12bit", "encoder-12bit-noisy")


def excitation(t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """PD tracking of a sum of sines (true state: the excitation is not the identifier's business)."""
    ref = np.array([0.6 * np.sin(1.1 * t) + 0.3 * np.sin(2.9 * t), -1.0 + 0.8 * np.sin(1.7 * t + 0.5)])
    dref = np.array([0.66 * np.cos(1.1 * t) + 0.87 * np.cos(2.9 * t), 1.36 * np.cos(1.7 * t + 0.5)])
    u = 40.0 * (ref - q) + 4.0 * (dref - v) + np.array([1.0 * np.sin(5.3 * t), 0.5 * np.sin(7.1 * t)])
    return np.clip(u, [-10.0, -5.0], [10.0, 5.0])


def run(sensor: str, frame_skip: int, T: float, change_at: float | None = None, rate: float | None = None, seed=0):
    """One episode; returns times, true mass and estimate (arrays) and the wall time per sample [s]."""
    env = gym.make("smo_gym/TwoLinkArm-v0", frame_skip=frame_skip)
    obs, _ = env.reset(seed=seed)
    sim = env.unwrapped.model
    lower = mujoco.mj_name2id(sim, mujoco.mjtObj.mjOBJ_BODY, "lower")
    nominal_model = MujocoDynamics(sim)  # private copies of the nominal model (0.8 kg), made before the change
    regressor = MujocoParameterRegressor(sim, [("body_mass", "lower")])
    sim.body_mass[lower] = TRUE_MASS  # the payload: the simulation only
    h = PHYSICS_DT * frame_skip
    ident = EquivalentInjectionIdentifier(
        h,
        lambda t, q, v, u: nominal_model.acceleration(q, v, u),
        regressor,
        regressor.theta_bar,
        n=2,
        lipschitz=LIPSCHITZ,
        forgetting=None if rate is None else np.exp(-rate),
        uses_acceleration=True,
        observer_options={"accel_bound": 200.0},
    )
    enc = sensors.make_sensor(sensor)
    ident.reset(enc.reset(obs[:2], seed=seed))
    N = int(round(T / h))
    t = h * np.arange(1, N + 1)
    m_true = np.empty(N)
    m_hat = np.empty(N)
    start = time.perf_counter()
    for k in range(N):
        if change_at is not None and abs(k * h - change_at) < 0.5 * h:
            sim.body_mass[lower] = CHANGED_MASS
        u = excitation(k * h, obs[:2], obs[2:])
        obs, *_ = env.step(u)
        m_hat[k] = ident.update(enc.measure(obs[:2]), u)[0]
        m_true[k] = sim.body_mass[lower]
    wall = (time.perf_counter() - start) / N
    env.close()
    return t, m_true, m_hat, wall


def settling(t, err, tol, after=0.0):
    """Time (from ``after``) after which ``|err| <= tol`` for good; inf if it never settles."""
    sel = t >= after
    bad = np.nonzero(np.abs(err[sel]) > tol)[0]
    if bad.size == 0:
        return 0.0
    return np.inf if bad[-1] == sel.sum() - 1 else t[sel][bad[-1] + 1] - after


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out_dir", nargs="?", type=Path, default=ROOT / "outputs" / "identification")
    parser.add_argument("--fast", action="store_true")
    args = parser.parse_args(argv)
    fast, out_dir = args.fast, args.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    T = 10.0 if fast else 20.0
    steps = (5,) if fast else (1, 5)

    print(f"Payload mass of TwoLinkArm-v0's forearm: true {TRUE_MASS} kg, nominal (identifier) 0.8 kg, T = {T} s")
    print("\nTable 1. Dynamic least squares, constant payload")
    print(f"{'sensor':<22}{'h [ms]':>7}{'mean |err| [kg]':>17}{'rel. err':>10}{'settle 5% [s]':>15}{'us/sample':>11}")
    traces = {}
    for sensor in SENSORS:
        for fs in steps:
            t, mt, mh, wall = run(sensor, fs, T)
            err = mh - mt
            tail = t > T - 5.0
            e = float(np.mean(np.abs(err[tail])))
            ts = settling(t, err, 0.05 * TRUE_MASS)
            print(
                f"{sensor:<22}{1e3 * PHYSICS_DT * fs:>7.0f}{e:>17.4f}{e / TRUE_MASS:>10.2%}{ts:>15.2f}"
                f"{1e6 * wall:>11.0f}"
            )
            traces[(sensor, fs)] = (t, mt, mh)

    print(f"\nTable 2. Payload {TRUE_MASS} -> {CHANGED_MASS} kg at t = {T / 2:g} s, matrix forgetting factor")
    print(
        f"{'sensor':<22}{'h [ms]':>7}{'rate [1/s]':>11}{'settle 10% [s]':>15}{'settle 5% [s]':>14}"
        f"{'mean |err| last 2 s':>21}"
    )
    change = {}
    for sensor in ("encoder-12bit-noisy",):
        for fs in steps:
            for rate in (1.0, 3.0):
                t, mt, mh, _ = run(sensor, fs, T, change_at=T / 2, rate=rate)
                err = mh - mt
                ts10 = settling(t, err, 0.10 * CHANGED_MASS, after=T / 2)
                ts5 = settling(t, err, 0.05 * CHANGED_MASS, after=T / 2)
                e = float(np.mean(np.abs(err[t > T - 2.0])))
                print(f"{sensor:<22}{1e3 * PHYSICS_DT * fs:>7.0f}{rate:>11.1f}{ts10:>15.2f}{ts5:>14.2f}{e:>21.4f}")
                change[(fs, rate)] = (t, mt, mh)

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - matplotlib is a dev dependency
        print("matplotlib not installed: no plot")
        return 0
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), constrained_layout=True)
    ax = axes[0]
    fs = steps[-1]
    for sensor in SENSORS:
        t, mt, mh = traces[(sensor, fs)]
        ax.plot(t, mh, label=f"{sensor}")
    ax.plot(t, mt, "k--", label="true mass")
    ax.set(
        title=f"Dynamic least squares, h = {1e3 * PHYSICS_DT * fs:.0f} ms",
        xlabel="time [s]",
        ylabel="payload mass [kg]",
        ylim=(0.5, 1.6),
    )
    ax.legend()
    ax = axes[1]
    for (fsc, rate), (t, mt, mh) in change.items():
        if fsc == fs:
            ax.plot(t, mh, label=f"forgetting rate {rate:g} /s")
    ax.plot(t, mt, "k--", label="true mass")
    ax.set(
        title=f"Payload change, encoder-12bit-noisy, h = {1e3 * PHYSICS_DT * fs:.0f} ms",
        xlabel="time [s]",
        ylabel="payload mass [kg]",
        ylim=(0.3, 1.6),
    )
    ax.legend()
    path = out_dir / "identification.png"
    fig.savefig(path, dpi=110)
    print(f"\nplot: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
