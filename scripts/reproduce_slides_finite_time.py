"""Reproduce the finite-time output-feedback stabilization of Fridman's slides, section 6 (Angulo, Fridman and
Levant 2011, 2012), with Levant's arbitrary-order sliding-mode controllers (Levant 2003, 2005).

The slides' section prints no numerical example (only the scheme and its claims), and the papers are not on disk,
so the claims compared here are the stated properties, each measured:

* :func:`reproduce_levant2005`: the sampled ``r``-sliding accuracy ``|sigma^(i)| = O(tau^(r-i))`` of the
  quasi-continuous (Levant 2005) and nested (Levant 2003) controllers on ``sigma^(r) = u + h``, ``|h| <= 1``;
* :func:`reproduce_angulo2012`: "robust finite-time stabilization of the whole state" on the slides' Furuta model
  (both angles measured, ``w = 0.4 sin 2.5t + 0.5``), the residual order in ``tau``, and the need for the
  non-homogeneous gain under ``||w|| <= W1 ||x|| + W2``;
* :func:`reproduce_angulo2012_mujoco`: the stabilizer on ``smo_gym/FurutaPendulum-v0`` (nonlinear MuJoCo model)
  from the positions measured through :class:`smo_gym.wrappers.EstimatedVelocity`, next to the compensation
  controller of the same slides.

``python scripts/reproduce_slides_finite_time.py [--fast]`` prints the claims; ``scripts/reproduce_papers.py``
loads the three runners.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from smo_gym import DivergenceError, control
from smo_gym.control import FiniteTimeStabilizer, hosm_control, settling_time, simulate_chain

GAINS = {2: 4.0, 3: 10.0, 4: 30.0}
FURUTA_ALPHA, FURUTA_SCALE = 25.0, 10.0  # physical amplitude alpha k2 / c = 2.5 > max |w| = 0.9


def _h(t):
    return 0.5 * np.sin(2 * t) + 0.5 * np.cos(7 * t)


def reproduce_levant2005(out_dir: Path | None = None, fast: bool = False) -> list[dict]:
    """Accuracy orders of the sampled r-sliding mode, fitted over three sampling steps."""
    steps = (4e-3, 2e-3, 1e-3)
    cases = [("quasi-continuous", 2), ("quasi-continuous", 3), ("quasi-continuous", 4), ("nested", 3)]
    if not fast:
        cases += [("nested", 2), ("nested", 4)]
    claims = []
    for kind, r in cases:
        acc, times = [], []
        for dt in steps:
            t, Z, _ = simulate_chain(
                lambda z, t, kind=kind, r=r: hosm_control(z, GAINS[r], kind=kind),
                0.01 * np.eye(r)[0],
                dt,
                4.0,
                disturbance=_h,
            )
            acc.append(np.abs(Z[t > 3.0]).max(axis=0))
            times.append(float(settling_time(t, np.abs(Z[:, 0]), 3.0 * acc[-1][0])))
        acc = np.array(acc)
        slopes = np.array([control.fit_order(steps, acc[:, i]) for i in range(r)])
        expected = r - np.arange(r)
        claims.append(
            dict(
                claim=f"{kind} {r}-sliding, |h| <= 1: |sigma^(i)| = O(tau^(r-i)), orders {expected.tolist()} "
                f"(Levant 2003, 2005); convergence in finite time",
                measured=f"orders {np.round(slopes, 2).tolist()}; |sigma| at tau = 1 ms {acc[-1, 0]:.2e}; "
                f"time to 3x the floor {np.round(times, 2).tolist()} s for tau = {list(steps)}",
                ok=bool(np.all(np.abs(slopes - expected) < 0.45)),
            )
        )
    return claims


def furuta_run(dt, *, true_plant=None, k1=0.0, x0=(0.0, 0.05, 0.0, 0.0), t_final=4.0, lipschitz_factor=1.0):
    """The stabilizer on the slides' Furuta model under ``w = 0.4 sin 2.5t + 0.5``; ``(result, controller)``."""
    P = control.furuta_slides()
    L = lipschitz_factor * 2.5 * control.output_error_lipschitz(P, 2, e_bound=0.1, w_bounds=(0.9, 1.0, 2.5))
    obs = control.CascadedHOSMObserver(P, dt, L)
    ctl = FiniteTimeStabilizer(obs, alpha=FURUTA_ALPHA, k1=k1, k2=1.0, output_scale=FURUTA_SCALE)
    try:
        res = control.simulate(true_plant or P, ctl, t_final=t_final, w=control.furuta_disturbance, x0=x0)
    except DivergenceError:  # the closed loop left the range of a float
        return None, ctl
    return res, ctl


def reproduce_angulo2012(out_dir: Path | None = None, fast: bool = False) -> list[dict]:
    """Slides' claims on the slides' Furuta model (noise-free samples, observer started from C^+ y0)."""
    steps = (4e-3, 2e-3, 1e-3) if fast else (4e-3, 2e-3, 1e-3, 5e-4)
    t_final = 4.0 if fast else 6.0
    resid, pos, times, zeta3 = [], [], [], []
    for dt in steps:
        res, ctl = furuta_run(dt, t_final=t_final)
        late = res.t > t_final - 1.0
        resid.append(np.linalg.norm(res.x[late], axis=1).max())
        pos.append(np.abs(res.x[late, :2]).max())
        Z = np.abs(res.x @ ctl.sliding.T.T)
        floor = Z[late].max(axis=0)
        zeta3.append(floor[3])
        times.append(float(settling_time(res.t, Z, 2.0 * floor).max()))
    o_x, o_z = control.fit_order(steps, resid), control.fit_order(steps, zeta3)
    claims = [
        dict(
            claim="robust finite-time stabilization of the whole state (slides; Angulo et al. 2012): every "
            "chain coordinate reaches its sampling floor in a time independent of tau; ||x|| = O(tau) "
            "(zeta^(3) = O(tau), Levant)",
            measured=f"time to 2x the floor {np.round(times, 2).tolist()} s; max ||x|| after "
            f"{t_final - 1:.0f} s {np.round(resid, 3).tolist()} (order {o_x:.2f}); max |theta|,|alpha| "
            f"{np.array(pos).round(5).tolist()}; zeta^(3) order {o_z:.2f}; tau = {list(steps)}",
            ok=bool(0.6 < o_x < 1.3 and 0.6 < o_z < 1.3 and max(times) - min(times) < 0.3 * min(times)),
        )
    ]
    # ||w|| <= W1 ||x|| + W2: a matched model error Delta x (W1 = 10) on top of w(t), from 0.2 rad
    P = control.furuta_slides()
    true = control.LinearPlant(P.A + P.B @ np.array([[0.0, 10.0, 0.0, 0.0]]), P.B, P.C, P.D)
    out = {}
    for k1 in (0.0, 5.0):
        res, _ = furuta_run(1e-3, true_plant=true, k1=k1, x0=(0.0, 0.2, 0.0, 0.0), lipschitz_factor=10.0)
        out[k1] = np.inf if res is None else float(np.abs(res.x[res.t > 3.0, :2]).max())
    claims.append(
        dict(
            claim="non-homogeneous gain alpha (k1 ||x|| + k2) for ||w|| <= W1 ||x|| + W2 (slides): needed when the "
            "disturbance grows with the state (W1 = 10, x0 = 0.2 rad, alpha k1 / c = 12.5)",
            measured=f"max |theta|,|alpha| over [3, 4] s: k1 = 0 -> {out[0.0]:.3g}, k1 = 5 -> {out[5.0]:.3g}",
            ok=bool(out[0.0] > 1.0 and out[5.0] < 5e-3),
        )
    )
    return claims


def furuta_mujoco(
    frame_skip: int = 1, sensor: str = "ideal", t_final: float = 8.0, t_steady: float = 5.0, scale: float = 0.1
):
    """The stabilizer and the compensation controller on ``smo_gym/FurutaPendulum-v0`` through EstimatedVelocity.

    The model is :func:`smo_gym.control.linearize` of the MJCF around upright (``D = B``); the environment applies
    ``w = scale (0.4 sin 2.5t + 0.5)`` N m on the arm. The stabilizer's physical amplitude is
    ``alpha k2 / c = 0.15`` N m (``> max |w| = 0.09``, inside the actuator's +-0.5 N m). The controllers see the
    wrapper's measured positions only. Returns one row per controller.
    """
    import gymnasium as gym

    from smo_gym.wrappers import EstimatedVelocity

    def w_env(t):
        return np.array([scale * (0.4 * np.sin(2.5 * t) + 0.5)])

    base = gym.make("smo_gym/FurutaPendulum-v0", frame_skip=frame_skip, disturbance=w_env)
    model = base.unwrapped.model
    plant = control.linearize(model, qpos0=np.zeros(model.nq))
    dt = float(base.unwrapped.dt)
    base.close()
    L = 2.5 * control.output_error_lipschitz(plant, 2, e_bound=0.1, w_bounds=(scale * 0.9, scale, scale * 2.5))
    makers = {
        "finite-time (quasi-continuous 4-sliding)": lambda: FiniteTimeStabilizer(
            control.CascadedHOSMObserver(plant, dt, L), alpha=25.0, k2=1.0, output_scale=25.0 / 0.15, t_start=0.05
        ),
        "compensation u = -K x_hat - w_hat": lambda: control.CompensationController(
            control.CascadedHOSMObserver(plant, dt, L),
            control.lqr(plant.A, plant.B, np.diag([10.0, 1.0, 1.0, 1.0]), np.eye(1) * 1e3),
            t_start=0.05,
        ),
    }
    rows = []
    for name, make in makers.items():
        env = EstimatedVelocity(
            gym.make("smo_gym/FurutaPendulum-v0", frame_skip=frame_skip, disturbance=w_env), sensor=sensor, rate="env"
        )
        lo, hi = env.action_space.low, env.action_space.high
        obs, _ = env.reset(seed=0)
        ctl = make()
        ctl.reset(obs[:2])
        X, U, T = [], [], []
        fell = False
        for k in range(int(round(t_final / dt))):
            data = env.unwrapped.data
            X.append(np.concatenate([data.qpos, data.qvel]))
            T.append(k * dt)
            U.append(np.clip(ctl.step(obs[:2], k * dt), lo, hi))
            obs, _, fell, _, _ = env.step(U[-1])
            if fell:
                break
        env.close()
        X, U, T = np.array(X), np.array(U), np.array(T)
        late = t_steady <= T
        if fell or not late.any():
            rows.append(dict(controller=name, fell=True))
            continue
        floor = np.abs(X[late, :2]).max()
        rows.append(
            dict(
                controller=name,
                fell=False,
                tau=dt,
                rms=np.sqrt((X[late] ** 2).mean(axis=0)),
                max_pos=floor,
                t_conv=float(settling_time(T, np.abs(X[:, :2]).max(axis=1), 2.0 * floor)),
                tv=control.total_variation_rate(U[late], T[late]),
                saturated=100.0 * float(np.mean(np.abs(U) >= hi - 1e-12)),
            )
        )
    return rows


def reproduce_angulo2012_mujoco(out_dir: Path | None = None, fast: bool = False) -> list[dict]:
    """The MuJoCo Furuta pendulum from measured positions (ideal sensor, and a 12-bit encoder unless fast)."""
    claims = []
    for sensor in ("ideal",) if fast else ("ideal", "encoder-12bit"):
        rows = furuta_mujoco(sensor=sensor, t_final=4.0 if fast else 8.0, t_steady=3.0 if fast else 5.0)
        ft = rows[0]
        desc = []
        for r in rows:
            if r["fell"]:
                desc.append(f"{r['controller']}: fell")
            else:
                desc.append(
                    f"{r['controller']}: RMS [theta, alpha, theta', alpha'] {np.round(r['rms'], 4).tolist()}, "
                    f"max |theta|,|alpha| {r['max_pos']:.2e} rad, within 2x that after {r['t_conv']:.2f} s, "
                    f"TV(u) {r['tv']:.3g} N m/s, saturated {r['saturated']:.1f}%"
                )
        claims.append(
            dict(
                claim=f"smo_gym/FurutaPendulum-v0 (nonlinear MuJoCo, tau = 2 ms, {sensor} sensor through "
                "EstimatedVelocity, w = 0.1 (0.4 sin 2.5t + 0.5) N m): stabilized from measured positions",
                measured="; ".join(desc),
                ok=bool(not ft["fell"] and ft["max_pos"] < 0.05),
            )
        )
    return claims


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fast", action="store_true")
    args = parser.parse_args(argv)
    for name, fn in (
        ("Levant 2003, 2005", reproduce_levant2005),
        ("Angulo, Fridman and Levant 2012 (slides' Furuta model)", reproduce_angulo2012),
        ("Angulo, Fridman and Levant 2012 (MuJoCo Furuta)", reproduce_angulo2012_mujoco),
    ):
        t0 = time.perf_counter()
        print(f"\n=== {name} ===")
        for c in fn(None, args.fast):
            print(f"[{'ok' if c['ok'] else 'DIFFERS'}] {c['claim']}\n        measured: {c['measured']}")
        print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
