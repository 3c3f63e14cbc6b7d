"""Reproduce Section 6 of Efimov, Polyakov, Levant and Perruquetti, IFAC World Congress 2017.

Differentiation of ``f(t) = 1 + sin(t) + sin(pi t)`` measured with the noise ``v(t) = V sin(omega t)``, ``V = 0.1``,
for ``(h, omega) = (0.01, 25)`` (Fig. 1) and ``(0.001, 250)`` (Fig. 2), by

* the switched-gain observer (4) with the supervisor (7), (9): ``q = 2``, ``alpha = 1``, ``mu0 = 10``,
  ``T_min = 3h``, ``mu_max = 108.69`` and the reset to ``mu_min = 10.42`` (Remark 9), implicit Euler (11);
* the same observer with the fixed gain ``mu = 30``;
* the super-twisting differentiator with ``D = 1 + pi^2``, gains ``1.5 D^(1/2)`` (the paper prints ``1.5 D^1.5``,
  a typo) and ``1.1 D``, explicit Euler.

The paper says "continue switching while T_i <= T_min = 3h and mu_i <= mu_max"; the first inequality is
reversed (Section 5.2 stops when T_(i*+1) <= T_min), and with these values only mu_max stops the schedule.
All observers start from zero. :func:`reproduce_efimov2017` returns one dict per printed claim with what was measured;
``python scripts/reproduce_efimov2017.py [out_dir]`` prints them and writes the figures.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from smo_gym.design import switched_gain_lmi
from smo_gym.observers import SuperTwisting, SwitchedGain

V = 0.1
D = 1.0 + np.pi**2
T_END = 10.0
CASES = ((0.01, 25.0), (0.001, 250.0))
PRINTED_L = np.array([2.6, 2.1])
PRINTED_P = np.array([[0.76, -0.48], [-0.48, 0.6]])
PRINTED_MU_MIN, PRINTED_MU_MAX, PRINTED_T0 = 10.42, 108.69, 9.11
FIXED_MU = 30.0
TRANSIENT = 2.0  # s: the schedule ends at t = 1.65 s
STEADY = 5.0  # s: steady-state window [5, 10] s


def signal(t: np.ndarray, omega: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(y, f, f')`` of Section 6."""
    f = 1.0 + np.sin(t) + np.sin(np.pi * t)
    df = np.cos(t) + np.pi * np.cos(np.pi * t)
    return f + V * np.sin(omega * t), f, df


def simulate(h: float, omega: float) -> dict[str, np.ndarray]:
    """Run the three observers from zero initial conditions; returns time, truth, estimates and the gain trace."""
    t = np.arange(0.0, T_END + 0.5 * h, h)
    y, f, df = signal(t, omega)
    switched = SwitchedGain(dt=h, order=1, q=2.0, alpha=1.0, mu0=10.0, disturbance=D, noise=V)
    fixed = SwitchedGain(dt=h, order=1, gain=switched.gain, P=switched.P, mu0=FIXED_MU, supervise=False)
    sta = SuperTwisting(dt=h, lipschitz=D, discretization="euler")
    zero = np.zeros(1)
    out = {"t": t, "y": y, "f": f, "df": df}
    est = np.empty((t.size, 2))
    mu = np.empty(t.size)
    est[0] = switched.reset(zero)[0]
    mu[0] = switched.mu[0]
    for k in range(1, t.size):
        est[k] = switched.update(y[k : k + 1])[0]
        mu[k] = switched.mu[0]
    out["switched"], out["mu"] = est, mu
    for name, obs in (("fixed", fixed), ("sta", sta)):
        first = obs.reset(zero)
        out[name] = np.concatenate([first, obs.run(y[1:, None])[:, 0]], axis=0)
    out["observer"] = switched
    return out


def noise_free_errors(h: float) -> dict[str, float]:
    """Steady-state RMS derivative errors on [5, 10] s without noise, switched gain and super-twisting."""
    t = np.arange(0.0, T_END + 0.5 * h, h)
    _, f, df = signal(t, 0.0)
    out = {}
    for name, obs in (
        ("switched", SwitchedGain(dt=h, order=1, q=2.0, alpha=1.0, mu0=10.0, disturbance=D, noise=V)),
        ("sta", SuperTwisting(dt=h, lipschitz=D, discretization="euler")),
    ):
        first = obs.reset(np.zeros(1))
        z = np.concatenate([first, obs.run(f[1:, None])[:, 0]], axis=0)
        ss = t >= STEADY
        out[name] = _rms(z[ss, 1] - df[ss])
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def reproduce_efimov2017(out_dir, fast: bool = False) -> list[dict]:
    """Rerun Section 6 of Efimov et al. 2017; write the figures into ``out_dir``; return the claims with measurements.

    Returns
    -------
    list of dict
        ``{"claim": str, "measured": str, "ok": bool}``; ``ok`` says whether the measurement supports the claim.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results: list[dict] = []

    l, P, cert = switched_gain_lmi(2, kappa=1.0, rho_d=1.0, rho_v=1.0)
    results.append(
        {
            "claim": "LMI of Remark 2 (kappa = rho_d = rho_v = 1) is satisfied for l = [2.6 2.1], "
            "P = [[0.76 -0.48] [-0.48 0.6]]",
            "measured": f"l = {np.round(l, 3).tolist()}, P = {np.round(P, 3).tolist()} (max lambda_min(P)); "
            f"max eig of the LMI at the solution {cert.max_eig_lmi:.1e}",
            "ok": bool(np.max(np.abs(l - PRINTED_L)) < 0.05 and np.max(np.abs(P - PRINTED_P)) < 0.02),
        }
    )

    runs = {case: simulate(*case) for case in CASES}
    obs = runs[CASES[0]]["observer"]
    results.append(
        {
            "claim": f"mu_min = {PRINTED_MU_MIN}, mu_max = {PRINTED_MU_MAX} (D = 1 + pi^2, V = 0.1)",
            "measured": f"mu_min = {obs.mu_min:.4f}, mu_max = {obs.mu_max:.4f}",
            "ok": bool(abs(obs.mu_min - PRINTED_MU_MIN) < 0.01 and abs(obs.mu_max - PRINTED_MU_MAX) < 0.02),
        }
    )
    T0 = obs.convergence_time_bound()
    results.append(
        {
            "claim": f"uniform global convergence time estimate T0 = {PRINTED_T0}",
            "measured": f"T0 = {T0:.4f} (Theorem 6 with the LMI solution, q = 2, alpha = 1)",
            "ok": bool(abs(T0 - PRINTED_T0) < 0.01),
        }
    )

    plan = obs.schedule()
    for (h, omega), run in runs.items():
        mu = run["mu"]
        t = run["t"]
        idx = np.flatnonzero(np.diff(mu) != 0.0) + 1
        # mu[k] is the gain after the update at t_k (used from t_k on): the switch happened at t[k]
        measured = [(float(t[0]), float(mu[0]))] + [(float(t[k]), float(mu[k])) for k in idx]
        pairs = list(zip(measured, plan, strict=False))
        same_gains = len(measured) == len(plan) and all(abs(a[1] - b[1]) < 1e-9 for a, b in pairs)
        timing = max((abs(a[0] - b[0]) for a, b in pairs), default=np.inf) if same_gains else np.inf
        results.append(
            {
                "claim": f"h = {h}: switching while T_i > T_min = 3h and mu_i <= mu_max, mu_0 = 10, q = 2, then reset "
                "to mu_min (schedule (7), (9), Remark 9)",
                "measured": "switches (t, mu): "
                + ", ".join(f"({a:.3f}, {b:.2f})" for a, b in measured)
                + "; planned "
                + ", ".join(f"({a:.3f}, {b:.2f})" for a, b in plan)
                + f"; max timing difference {timing:.4f} s",
                "ok": bool(same_gains and timing <= h + 1e-9),
            }
        )

    for (h, omega), run in runs.items():
        tr = run["t"] <= TRANSIENT
        peak_sw = float(np.max(np.abs(run["switched"][tr, 1])))
        peak_fx = float(np.max(np.abs(run["fixed"][tr, 1])))
        err_sw = float(np.max(np.abs(run["switched"][tr, 1] - run["df"][tr])))
        err_fx = float(np.max(np.abs(run["fixed"][tr, 1] - run["df"][tr])))
        results.append(
            {
                "claim": f"h = {h}, omega = {omega}: gain switching reduces peaking compared with the fixed gain "
                "mu = 30",
                "measured": f"transient peak |xhat_2|: switched {peak_sw:.2f}, fixed {peak_fx:.2f} (ratio "
                f"{peak_fx / peak_sw:.2f}); peak |xhat_2 - f'|: switched {err_sw:.2f}, fixed {err_fx:.2f}; "
                f"max |f'| = {1 + np.pi:.2f}",
                "ok": bool(peak_sw < peak_fx and err_sw < err_fx),
            }
        )

    steady = {}
    for (h, omega), run in runs.items():
        ss = run["t"] >= STEADY
        steady[h] = {name: _rms(run[name][ss, 1] - run["df"][ss]) for name in ("switched", "fixed", "sta")}
    # the step's own effect, without the noise (whose frequency also changes between the two cases)
    clean = {h: noise_free_errors(h) for h, _ in CASES}
    (h1, _), (h2, _) = CASES
    change = {name: clean[h1][name] / clean[h2][name] for name in ("switched", "sta")}
    results.append(
        {
            "claim": "the switched-gain differentiator (implicit Euler) is less sensitive to the step h than the "
            "super-twisting differentiator (explicit Euler)",
            "measured": "noise-free steady-state RMS of xhat_2 - f' on [5, 10] s: "
            + "; ".join(
                f"h = {h}: switched {v['switched']:.4f}, super-twisting {v['sta']:.4f}" for h, v in clean.items()
            )
            + f"; ratio h={h1} / h={h2}: switched {change['switched']:.2f}, super-twisting "
            f"{change['sta']:.2f}. With the noise of Figs. 1-2: "
            + "; ".join(
                f"h = {h}: switched {v['switched']:.3f}, fixed mu=30 {v['fixed']:.3f}, super-twisting {v['sta']:.3f}"
                for h, v in steady.items()
            )
            + ". The relative sensitivity claim holds; in absolute terms the super-twisting error is "
            "smaller noise-free (the linear observer at mu_min = 10.4 keeps a lag error of order "
            "D/mu_min) and all three are comparable with the noise.",
            "ok": bool(abs(np.log(change["switched"])) < abs(np.log(change["sta"]))),
        }
    )

    ratios, times, t_fixed = fixed_time_contraction()
    results.append(
        {
            "claim": f"noise-free, the switched gain converges globally in a fixed time bounded by T0 = {PRINTED_T0} "
            "(Theorem 6, mu0 = 1); not simulated in the paper",
            "measured": "||e(T0)|| / ||e(0)|| for initial errors 1, 1e3, 1e6 (f = 1, D = 0, h = 1e-3, T_min = 3h): "
            + ", ".join(f"{r:.1e}" for r in ratios)
            + " (the absolute error reaches the rounding floor); "
            "contraction by 1e-6 reached at t = "
            + ", ".join(f"{x:.2f}" for x in times)
            + f" s, against {t_fixed:.2f} s for the fixed gain mu = 1",
            "ok": bool(
                max(ratios) < 1e-6 and max(times) - min(times) <= 1e-9 and max(times) < min(PRINTED_T0, t_fixed)
            ),
        }
    )

    _figures(runs, out_dir)
    return results


def fixed_time_contraction(h: float = 1e-3) -> tuple[list[float], list[float], float]:
    """Contraction ``||e(T0)|| / ||e(0)||`` of the supervised observer (mu0 = 1, (8)) for three initial errors,
    the times at which it first contracts the error by 1e-6, and the same time for the fixed gain mu = 1
    (noise-free, D = 0).

    The observer is linear in the error between switches and the schedule is open loop, so the contraction is the
    same for every initial error: convergence "in a time independent of the initial condition" is a contraction
    factor reached by T0 (zero in continuous time with infinitely many switches; finite here since the switching
    stops once T_i <= T_min = 3h).
    """
    T0 = SwitchedGain(dt=h, order=1, q=2.0, alpha=1.0, mu0=1.0).convergence_time_bound()
    t = np.arange(0.0, 3 * T0, h)
    f = np.ones(t.shape)  # D = 0 (a ramp would add its own error in the derivative)
    k0 = int(np.ceil(T0 / h))
    ratios, times = [], []
    for e0 in (1.0, 1e3, 1e6):
        obs = SwitchedGain(dt=h, order=1, q=2.0, alpha=1.0, mu0=1.0)
        first = obs.reset(np.array([f[0] + e0]))
        z = np.concatenate([first, obs.run(f[1:, None])[:, 0]], axis=0)
        err = np.hypot(z[:, 0] - f, z[:, 1]) / e0
        ratios.append(float(err[k0]))
        times.append(float(t[np.flatnonzero(err <= 1e-6)[0]]))
    fixed = SwitchedGain(dt=h, order=1, gain=obs.gain, P=obs.P, mu0=1.0, supervise=False)
    first = fixed.reset(np.array([f[0] + 1.0]))
    z = np.concatenate([first, fixed.run(f[1:, None])[:, 0]], axis=0)
    below = np.flatnonzero(np.hypot(z[:, 0] - f, z[:, 1]) <= 1e-6)
    return ratios, times, float(t[below[0]]) if below.size else np.inf


def _figures(runs, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for i, ((h, omega), run) in enumerate(runs.items(), start=1):
        fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
        t = run["t"]
        axes[0].plot(t, run["f"], "k", lw=1.5, label="f")
        axes[1].plot(t, run["df"], "k", lw=1.5, label="f'")
        for name, style in (("switched", "C0"), ("fixed", "C1"), ("sta", "C2")):
            label = {
                "switched": "switched gain (4), (7), (9)",
                "fixed": "fixed mu = 30",
                "sta": "super-twisting (explicit Euler)",
            }[name]
            axes[0].plot(t, run[name][:, 0], style, lw=0.8, label=label)
            axes[1].plot(t, run[name][:, 1], style, lw=0.8, label=label)
        axes[1].set_ylim(-25, 25)
        axes[2].plot(t, run["mu"], "C0")
        axes[2].set_ylabel("mu_i")
        axes[2].set_xlabel("t [s]")
        axes[0].legend(fontsize=7, loc="upper right")
        axes[1].legend(fontsize=7, loc="upper right")
        fig.suptitle(f"Efimov et al. 2017, Fig. {i}: h = {h}, omega = {omega}")
        fig.tight_layout()
        fig.savefig(out_dir / f"efimov2017_fig{i}_h{h}_omega{omega:g}.png", dpi=100)
        plt.close(fig)


if __name__ == "__main__":
    target = sys.argv[1] if len(sys.argv) > 1 else "figures/efimov2017"
    for r in reproduce_efimov2017(target):
        print(("OK   " if r["ok"] else "DIFF ") + r["claim"] + "\n       " + r["measured"])
