r"""The experiments of Fridman's slides, section 6, on the slides' linear models: tables (lists of dicts) and plots.

Called by ``scripts/control_experiments.py`` and ``smo-gym control``; every number comes from
:func:`smo_gym.control.simulate` with the library's observers and controllers.

- :func:`identification_orders`: cascaded-observer errors against the sampling step for several ``alpha``,
  with fitted orders against the theoretical ``alpha`` (identification) and ``alpha + 1`` (state).
- :func:`noise_growth`: identification/state errors against the measurement noise level.
- :func:`furuta_sweep`: LQR with a Luenberger observer vs compensation vs output ISM (unit vector and
  super-twisting) on the slides' Furuta pendulum under ``w(t) = 0.4 sin(2.5 t) + 0.5``, noise-free and with
  12-bit encoders, over a sweep of sampling steps: steady-state error, control total variation per second,
  fitted orders.
- :func:`actuator_sweep`: the execution error ``O(mu)`` of an actuator lag, compensation vs ISM.
- :func:`helicopter_experiment`: the unmatched case on the slides' 3-DOF helicopter: exact compensation through
  the sliding surface vs an LQR baseline.

Gains are not tuned per run: the differentiator bound is :func:`output_error_lipschitz` with a fixed safety
factor, the LQR weights are shared by all controllers of one plant.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import DivergenceError
from ..control import (
    CascadedHOSMObserver,
    CompensationController,
    IntegralSlidingModeController,
    LuenbergerObserver,
    StateFeedback,
    UnmatchedCompensationController,
    fit_order,
    furuta_disturbance,
    furuta_slides,
    helicopter_slides,
    linearize,
    lqr,
    output_error_lipschitz,
    simulate,
    steady_state_error,
    total_variation_rate,
)
from .closed_loop import DEFAULT_CONTROLLERS

__all__ = [
    "ENCODER_12BIT",
    "FURUTA_Q",
    "actuator_sweep",
    "add_subcommand",
    "cli",
    "format_table",
    "furuta_mujoco_experiment",
    "furuta_sweep",
    "helicopter_disturbance",
    "helicopter_experiment",
    "identification_orders",
    "injection_ablation",
    "noise_growth",
    "run_all",
]

#: LQR weights shared by every Furuta controller (arm angle weighted so the baseline settles in ~2 s)
FURUTA_Q = np.diag([10.0, 1.0, 1.0, 1.0])
#: 4096 counts per revolution
ENCODER_12BIT = 2 * np.pi / 4096
#: bounds of |w^(i)| for w = 0.4 sin(2.5 t) + 0.5
FURUTA_W_BOUNDS = tuple([0.9] + [0.4 * 2.5**i for i in range(1, 6)])
#: safety factor on the differentiator bound of :func:`output_error_lipschitz`
SAFETY = 2.5
#: assumed bound on the Luenberger error after its transient (checked a posteriori in the tables)
E_BOUND = 0.1
X0 = (0.0, 0.05, 0.0, 0.0)


def helicopter_disturbance(t):
    r"""Unknown inputs of the helicopter experiment (the slides do not print theirs).

    :math:`f_1 = 0.2\sin t + 0.1,\ f_2 = 0.15\cos 1.3t` (matched, rotor thrust errors) and
    :math:`\nu = 0.1 + 0.05\sin 0.5t` (unmatched travel torque). Shape ``(len(t), 3)``.
    """
    t = np.asarray(t, dtype=float)
    return np.stack([0.2 * np.sin(t) + 0.1, 0.15 * np.cos(1.3 * t), 0.1 + 0.05 * np.sin(0.5 * t)], axis=-1)


HELI_W_BOUNDS = (0.3,)


def _furuta_lipschitz(plant, alpha, n_w=0):
    order = plant.strong_observability().molinari.n_derivatives + n_w + alpha
    return SAFETY * output_error_lipschitz(plant, order, e_bound=E_BOUND, w_bounds=FURUTA_W_BOUNDS)


def identification_orders(alphas=(1, 2, 3), steps=(5e-4, 1e-3, 2e-3, 4e-3), t_final: float = 4.0):
    """Cascaded observer on the slides' Furuta model (LQR on its estimate), noise-free: errors vs ``tau``.

    Returns ``(rows, fits)``: one row per (alpha, tau) with the max errors over ``t >= 2 s``; one fit per alpha.
    """
    plant = furuta_slides()
    rows, fits = [], []
    for alpha in alphas:
        L = _furuta_lipschitz(plant, alpha)
        ew, ex, ev = [], [], []
        for dt in steps:
            obs = CascadedHOSMObserver(plant, dt, L, alpha=alpha)
            res = simulate(plant, StateFeedback(obs, Q=FURUTA_Q), t_final=t_final, w=furuta_disturbance, x0=X0)
            sel = res.after(2.0)
            ew.append(np.abs(res.w_hat - res.w)[sel].max())
            ex.append(np.abs(res.x_hat - res.x)[sel][:, :2].max())
            ev.append(np.abs(res.x_hat - res.x)[sel][:, 2:].max())
            rows.append(
                {
                    "alpha": alpha,
                    "order k": obs.order,
                    "tau [ms]": dt * 1e3,
                    "|w_hat - w|": ew[-1],
                    "|pos err|": ex[-1],
                    "|vel err|": ev[-1],
                }
            )
        fits.append(
            {
                "alpha": alpha,
                "identification order": fit_order(steps, ew),
                "theory (alpha)": alpha,
                "velocity order": fit_order(steps, ev),
                "theory (alpha+1)": alpha + 1,
                "position order": fit_order(steps, ex),
            }
        )
    return rows, fits


def injection_ablation(alphas=(1, 2), steps=(1e-3, 2e-3, 4e-3), t_final: float = 4.0):
    """Sampled (default) vs held Luenberger injection in the cascade: fitted orders in ``tau`` (noise-free).

    The held injection (the slides' continuous observer with ``y_k`` held) adds ``L C (x(t) - x(t_k))`` to the
    error dynamics; see :mod:`smo_gym.control.estimators`.
    """
    plant = furuta_slides()
    fits = []
    for injection in ("sampled", "held"):
        for alpha in alphas:
            L = _furuta_lipschitz(plant, alpha)
            ew, ev = [], []
            for dt in steps:
                obs = CascadedHOSMObserver(plant, dt, L, alpha=alpha, injection=injection)
                res = simulate(plant, StateFeedback(obs, Q=FURUTA_Q), t_final=t_final, w=furuta_disturbance, x0=X0)
                sel = res.after(2.0)
                ew.append(np.abs(res.w_hat - res.w)[sel].max())
                ev.append(np.abs(res.x_hat - res.x)[sel][:, 2:].max())
            fits.append(
                {
                    "injection": injection,
                    "alpha": alpha,
                    "|w_hat - w| at tau min": ew[0],
                    "identification order": fit_order(steps, ew),
                    "|vel err| at tau min": ev[0],
                    "velocity order": fit_order(steps, ev),
                }
            )
    return fits


def noise_growth(etas=(1e-5, 1e-4, 1e-3, 1e-2), dt: float = 1e-3, alphas=(1, 2), t_final: float = 4.0):
    """Identification and velocity errors against Gaussian measurement noise ``eta`` at a fixed ``tau``.

    Theory (Fridman's slides, section 6, after Angulo et al. 2011): ``O(eta^(alpha/(k+1)))`` for the identification,
    ``O(eta^(alpha/(k+1) + 1/(k+1)))`` for the velocities, ``k`` the differentiator order, once the noise
    dominates the sampling error.

    Notes
    -----
    Measured (tau = 1 ms, eta = 1e-4 .. 1e-2): identification exponents 0.19 (alpha = 1, theory 1/3) and 0.37
    (alpha = 2, theory 1/2), velocity exponents 0.54 and 0.62 (theory 2/3 and 3/4): the growth is sub-linear as
    predicted but slower than the asymptotic exponents. The theory bounds the error for *bounded* noise of
    amplitude ``eta`` with the gains fixed; here the noise is Gaussian (the max over 2000 samples is ~3.5
    ``eta``), the sampling error is not negligible at the low end, and the Luenberger stage feeds the noise back
    into the differentiated signal, so a three-point fit over two decades sits between the sampling-dominated
    (flat) and the noise-dominated regime.
    """
    plant = furuta_slides()
    rows, fits = [], []
    for alpha in alphas:
        L = _furuta_lipschitz(plant, alpha)
        ew, ev = [], []
        for eta in etas:
            obs = CascadedHOSMObserver(plant, dt, L, alpha=alpha)
            res = simulate(
                plant, StateFeedback(obs, Q=FURUTA_Q), t_final=t_final, w=furuta_disturbance, x0=X0, noise_std=eta
            )
            sel = res.after(2.0)
            ew.append(np.abs(res.w_hat - res.w)[sel].max())
            ev.append(np.abs(res.x_hat - res.x)[sel][:, 2:].max())
            rows.append({"alpha": alpha, "eta": eta, "|w_hat - w|": ew[-1], "|vel err|": ev[-1]})
        k = obs.order
        fits.append(
            {
                "alpha": alpha,
                "order k": k,
                "identification exponent (top 3)": fit_order(etas[-3:], ew[-3:]),
                "theory alpha/(k+1)": alpha / (k + 1),
                "velocity exponent (top 3)": fit_order(etas[-3:], ev[-3:]),
                "theory (alpha+1)/(k+1)": (alpha + 1) / (k + 1),
            }
        )
    return rows, fits


def _furuta_controllers(plant, dt):
    L = _furuta_lipschitz(plant, 1)
    return {
        "LQR + Luenberger": lambda: StateFeedback(LuenbergerObserver(plant, dt), Q=FURUTA_Q),
        "compensation": lambda: CompensationController(CascadedHOSMObserver(plant, dt, L), Q=FURUTA_Q, t_start=0.05),
        "ISM (unit vector)": lambda: IntegralSlidingModeController(
            CascadedHOSMObserver(plant, dt, L), Q=FURUTA_Q, rho=1.2, t_start=0.05
        ),
        "ISM (super-twisting)": lambda: IntegralSlidingModeController(
            CascadedHOSMObserver(plant, dt, L),
            Q=FURUTA_Q,
            discontinuity="super-twisting",
            k1=1.5 * np.sqrt(5.0),
            k2=1.1 * 5.0,
            t_start=0.05,
        ),
    }


def furuta_sweep(
    steps=(5e-4, 1e-3, 2e-3, 4e-3),
    resolutions=(0.0, ENCODER_12BIT),
    t_final: float = 10.0,
    t_steady: float = 6.0,
    keep_runs_at: float | None = 1e-3,
):
    """The slides' Furuta experiment over sampling steps and encoder resolutions.

    Returns ``(rows, fits, runs)``: rows with the steady-state error ``max |theta|, |alpha|`` over
    ``t >= t_steady``, the total variation of ``u`` per second there, and the identification error; fits of the
    steady-state error against ``tau`` per controller and resolution; the runs at ``tau = keep_runs_at`` for the
    plots.
    """
    plant = furuta_slides()
    rows, fits, runs = [], [], {}
    for res_ in resolutions:
        per = {}
        for dt in steps:
            for name, make in _furuta_controllers(plant, dt).items():
                r = simulate(plant, make(), t_final=t_final, w=furuta_disturbance, x0=X0, resolution=res_)
                sel = r.after(t_steady)
                sse = steady_state_error(r, t_steady, [0, 1])
                tv = total_variation_rate(r.u[sel], r.t[sel])
                rows.append(
                    {
                        "encoder": "12-bit" if res_ else "exact",
                        "tau [ms]": dt * 1e3,
                        "controller": name,
                        "max |theta|,|alpha|": sse,
                        "max |alpha| (all t)": np.abs(r.x[:, 1]).max(),
                        "TV(u) per s": tv,
                        "|w_hat - w|": np.abs(r.w_hat - r.w)[sel].max(),
                    }
                )
                per.setdefault(name, []).append(sse)
                if keep_runs_at is not None and abs(dt - keep_runs_at) < 1e-12:
                    runs[(res_, name)] = r
        for name, errs in per.items():
            fits.append(
                {
                    "encoder": "12-bit" if res_ else "exact",
                    "controller": name,
                    "fitted order of steady-state error in tau": fit_order(steps, errs),
                }
            )
    return rows, fits, runs


def actuator_sweep(mus=(1e-3, 2e-3, 5e-3, 1e-2), dt: float = 1e-3, t_final: float = 10.0, t_steady: float = 6.0):
    r"""Execution error: an actuator lag ``mu`` the controllers do not know, compensation vs ISM (noise-free).

    Notes
    -----
    Measured (tau = 1 ms): the ISM error grows with ``mu`` from the start (unit vector 4.4e-4, 5.6e-3, 1.6e-2,
    9.0e-2 rad for mu = 0, 2, 5, 10 ms), the execution error ``O(mu)`` of the slides. The compensation controller
    is insensitive up to 5 ms (9.3e-4 .. 9.7e-4 rad) and degrades abruptly at 10 ms (8.1e-2): with ``D = B`` the
    cascade identifies the actuator mismatch ``B (u_a - u)`` as part of the matched unknown input, so
    :math:`\hat w` compensates the lag as well -- until the loop through the identification loses its margin. A
    single power law in ``mu`` therefore fits neither controller well; the fitted orders are reported as such.
    """
    plant = furuta_slides()
    rows, fits = [], []
    per = {}
    for mu in (0.0,) + tuple(mus):
        for name, make in _furuta_controllers(plant, dt).items():
            if name == "LQR + Luenberger":
                continue
            try:
                r = simulate(plant, make(), t_final=t_final, w=furuta_disturbance, x0=X0, actuator_tau=mu)
                sse = steady_state_error(r, t_steady, [0, 1])
                tv = total_variation_rate(r.u[r.after(t_steady)], r.t[r.after(t_steady)])
            except DivergenceError:  # the closed loop left the range of a float
                sse, tv = np.inf, np.nan
            rows.append({"mu [ms]": mu * 1e3, "controller": name, "max |theta|,|alpha|": sse, "TV(u) per s": tv})
            if mu > 0:
                per.setdefault(name, []).append(sse)
    for name, errs in per.items():
        ok = np.isfinite(errs)
        fits.append(
            {
                "controller": name,
                "fitted order in mu": fit_order(np.array(mus)[ok], np.array(errs)[ok]) if ok.sum() >= 2 else np.nan,
            }
        )
    return rows, fits


def helicopter_experiment(dt: float = 1e-3, t_final: float = 20.0, t_steady: float = 12.0):
    """Unmatched case: LQR + Luenberger vs compensation through the sliding surface (unit vector and STA).

    Regulated output: elevation and travel (``E B = 0``); the pitch is the pseudo-control that cancels the travel
    disturbance (on the surface ``0.49 pitch = nu``).
    """
    plant = helicopter_slides()
    E = np.eye(6)[[0, 2]]
    order = plant.strong_observability().molinari.n_derivatives + 1 + 1
    L = SAFETY * output_error_lipschitz(plant, order, w_bounds=HELI_W_BOUNDS)
    Q = np.diag([10.0, 10.0, 10.0, 1.0, 1.0, 1.0])
    makers = {
        "LQR + Luenberger": lambda: StateFeedback(LuenbergerObserver(plant, dt), Q=Q),
        "surface compensation (unit)": lambda: UnmatchedCompensationController(
            CascadedHOSMObserver(plant, dt, L, n_w_derivatives=1), rho=0.5, regulated=E, Qr=10 * np.eye(4), t_start=0.05
        ),
        "surface compensation (STA)": lambda: UnmatchedCompensationController(
            CascadedHOSMObserver(plant, dt, L, n_w_derivatives=1),
            discontinuity="super-twisting",
            k1=1.5,
            k2=1.1,
            regulated=E,
            Qr=10 * np.eye(4),
            t_start=0.05,
        ),
    }
    rows, runs = [], {}
    for name, make in makers.items():
        r = simulate(plant, make(), t_final=t_final, w=helicopter_disturbance)
        sel = r.after(t_steady)
        rows.append(
            {
                "controller": name,
                "band |travel|": np.abs(r.x[sel, 2]).max(),
                "band |elevation|": np.abs(r.x[sel, 0]).max(),
                "max |0.49 pitch - nu|": np.abs(0.49 * r.x[sel, 1] - r.w[sel, 2]).max(),
                "TV(u) per s": total_variation_rate(r.u[sel], r.t[sel]),
                "|w_hat - w|": np.abs(r.w_hat - r.w)[sel].max(),
            }
        )
        runs[name] = r
    base = rows[0]["band |travel|"]
    for row in rows:
        row["travel band / LQR"] = row["band |travel|"] / base
    return rows, runs


def furuta_mujoco_experiment(
    frame_skips=(1, 2, 5),
    t_final: float = 10.0,
    t_steady: float = 6.0,
    sensor: str = "encoder-12bit",
    scale: float = 0.1,
    seed: int = 0,
):
    r"""The Furuta experiment on the MuJoCo environment ``smo_gym/FurutaPendulum-v0`` (nonlinear, RK4).

    The plant model is :func:`linearize` of the environment's MJCF around upright (``D = B``: the disturbance
    torque enters the arm joint like the motor). The environment applies the torque
    :math:`w(t) = s\,(0.4\sin 2.5t + 0.5)` N m with ``s = scale`` (0.1 gives about the slides' acceleration,
    ``B`` being ~11x the slides'). The loop runs through :class:`smo_gym.wrappers.EstimatedVelocity` (sensor
    ``sensor``, its own super-twisting velocity observer, sampled once per environment step): the controllers see
    the wrapper's observation only -- measured positions for the cascade/Luenberger controllers, measured positions
    and the wrapper's estimated velocities for the "LQR on the wrapper's state" baseline. The sampling step is
    ``frame_skip * 2 ms``. The commanded torque is clipped to the actuator range ``+-0.5`` N m (the observers are
    told the commanded value; a clipped difference is a matched input the cascade identifies as part of ``w``).

    Returns ``(rows, runs)``.
    """
    import gymnasium as gym

    from ..wrappers import EstimatedVelocity

    def w_env(t):
        return np.array([scale * (0.4 * np.sin(2.5 * t) + 0.5)])

    rows, runs = [], {}
    for fs in frame_skips:
        base_env = gym.make("smo_gym/FurutaPendulum-v0", frame_skip=fs, disturbance=w_env)
        model = base_env.unwrapped.model
        plant = linearize(model, qpos0=np.zeros(model.nq))
        dt = float(base_env.unwrapped.dt)
        w_bounds = tuple(scale * b for b in FURUTA_W_BOUNDS)
        L = SAFETY * output_error_lipschitz(plant, 2, e_bound=E_BOUND, w_bounds=w_bounds)
        K = lqr(plant.A, plant.B, FURUTA_Q, np.eye(1) * 1e3)
        makers = {
            "LQR on wrapper state": None,
            "LQR + Luenberger": lambda: StateFeedback(LuenbergerObserver(plant, dt), K),
            "compensation": lambda: CompensationController(CascadedHOSMObserver(plant, dt, L), K, t_start=0.05),
            "ISM (unit vector)": lambda: IntegralSlidingModeController(
                CascadedHOSMObserver(plant, dt, L), K, rho=1.5 * scale, t_start=0.05
            ),
            "ISM (super-twisting)": lambda: IntegralSlidingModeController(
                CascadedHOSMObserver(plant, dt, L),
                K,
                discontinuity="super-twisting",
                k1=1.5 * np.sqrt(5.0 * scale),
                k2=1.1 * 5.0 * scale,
                t_start=0.05,
            ),
        }
        for name, make in makers.items():
            env = EstimatedVelocity(
                gym.make("smo_gym/FurutaPendulum-v0", frame_skip=fs, disturbance=w_env), sensor=sensor, rate="env"
            )
            lo, hi = env.action_space.low, env.action_space.high
            obs, _ = env.reset(seed=seed)
            ctl = None if make is None else make()
            if ctl is not None:
                ctl.reset(obs[:2])
            n = int(round(t_final / dt))
            X, U, W, WH, T = [], [], [], [], []
            terminated = False
            for k in range(n):
                t = k * dt
                data = env.unwrapped.data
                X.append(np.concatenate([data.qpos, data.qvel]))
                u = -K @ obs if ctl is None else ctl.step(obs[:2], t)
                U.append(np.clip(u, lo, hi))
                W.append(w_env(t))
                WH.append(np.zeros(1) if ctl is None else ctl.observer.w_hat.copy())
                T.append(t)
                obs, _, terminated, _, _info = env.step(U[-1])
                if terminated:
                    break
            env.close()
            X, U, W, WH, T = map(np.array, (X, U, W, WH, T))
            sel = t_steady <= T
            ok = (not terminated) and sel.any()
            rows.append(
                {
                    "tau [ms]": dt * 1e3,
                    "controller": name,
                    "max |theta|,|alpha|": np.abs(X[sel][:, :2]).max() if ok else np.inf,
                    "fell": terminated,
                    "TV(u) per s": total_variation_rate(U[sel], T[sel]) if ok else np.nan,
                    "saturated %": 100.0 * np.mean(np.abs(U) >= hi - 1e-12),
                    "|w_hat - w| [N m]": np.abs(WH - W)[sel].max() if ok and ctl is not None else np.nan,
                }
            )
            runs[(fs, name)] = {"t": T, "x": X, "u": U, "w": W, "w_hat": WH}
        base_env.close()
    return rows, runs


def format_table(rows, title: str = "") -> str:
    """Plain-text table of a list of dicts (floats in 4 significant digits)."""
    if not rows:
        return title
    cols = list(rows[0])

    def fmt(v):
        if isinstance(v, (float, np.floating)):
            return f"{v:.4g}"
        return str(v)

    cells = [[fmt(r.get(c, "")) for c in cols] for r in rows]
    width = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    lines = [title] if title else []
    lines.append("  ".join(c.ljust(w) for c, w in zip(cols, width, strict=False)))
    lines.append("  ".join("-" * w for w in width))
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, width, strict=False)) for row in cells]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------------------
# plots (matplotlib imported lazily)
# ---------------------------------------------------------------------------------------------------------------
def _plt():
    from .._extras import require

    require("matplotlib", "plots").use("Agg")
    return require("matplotlib.pyplot", "plots")


def plot_identification(rows, path):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for alpha in sorted({r["alpha"] for r in rows}):
        rr = [r for r in rows if r["alpha"] == alpha]
        tau = np.array([r["tau [ms]"] for r in rr]) * 1e-3
        axes[0].loglog(tau, [r["|w_hat - w|"] for r in rr], "o-", label=f"alpha={alpha}")
        axes[1].loglog(tau, [r["|vel err|"] for r in rr], "o-", label=f"alpha={alpha}")
    axes[0].set(xlabel="tau [s]", ylabel="max |w_hat - w|", title="identification, O(tau^alpha)")
    axes[1].set(xlabel="tau [s]", ylabel="max velocity error", title="observation, O(tau^(alpha+1))")
    for ax in axes:
        ax.legend()
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_furuta_sweep(rows, path):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for enc, style in (("exact", "-"), ("12-bit", "--")):
        for name in dict.fromkeys(r["controller"] for r in rows):
            rr = [r for r in rows if r["controller"] == name and r["encoder"] == enc]
            if not rr:
                continue
            tau = np.array([r["tau [ms]"] for r in rr]) * 1e-3
            axes[0].loglog(tau, [r["max |theta|,|alpha|"] for r in rr], "o" + style, label=f"{name} ({enc})")
            axes[1].loglog(tau, [r["TV(u) per s"] for r in rr], "o" + style, label=f"{name} ({enc})")
    axes[0].set(xlabel="tau [s]", ylabel="steady-state max |theta|, |alpha| [rad]", title="Furuta (slides' model)")
    axes[1].set(xlabel="tau [s]", ylabel="total variation of u per second", title="chattering")
    axes[0].legend(fontsize=7)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_furuta_runs(runs, path):
    plt = _plt()
    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    for (res_, name), r in runs.items():
        if res_ == 0.0:
            continue
        axes[0].plot(r.t, r.x[:, 0], label=name)
        axes[1].plot(r.t, r.x[:, 1], label=name)
        axes[2].plot(r.t, r.u[:, 0], label=name, lw=0.6)
        if name == "compensation":
            axes[3].plot(r.t, r.w[:, 0], "k", label="w")
            axes[3].plot(r.t, r.w_hat[:, 0], label="w_hat (compensation)", lw=0.6)
    axes[0].set_ylabel("theta [rad]")
    axes[1].set_ylabel("alpha [rad]")
    axes[2].set_ylabel("u")
    axes[3].set_ylabel("w")
    axes[3].set_xlabel("t [s]")
    axes[0].set_title("Furuta (slides' model), tau = 1 ms, 12-bit encoders")
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_helicopter(runs, path):
    plt = _plt()
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for name, r in runs.items():
        axes[0].plot(r.t, r.x[:, 2], label=name)
        axes[1].plot(r.t, r.x[:, 0], label=name)
        axes[2].plot(r.t, r.x[:, 1], label=name)
    r = next(iter(runs.values()))
    axes[2].plot(r.t, r.w[:, 2] / 0.49, "k:", label="nu / 0.49")
    for ax, lab in zip(axes, ("travel [rad]", "elevation [rad]", "pitch [rad]"), strict=False):
        ax.set_ylabel(lab)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    axes[0].set_title("3-DOF helicopter (slides' model): unmatched compensation vs LQR")
    axes[2].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_mujoco(runs, path):
    plt = _plt()
    fs0 = min(fs for fs, _ in runs)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for (fs, name), r in runs.items():
        if fs != fs0:
            continue
        axes[0].plot(r["t"], r["x"][:, 0], label=name)
        axes[1].plot(r["t"], r["x"][:, 1], label=name)
        axes[2].plot(r["t"], r["u"][:, 0], label=name, lw=0.6)
    for ax, lab in zip(axes, ("arm [rad]", "pendulum [rad]", "torque [N m]"), strict=False):
        ax.set_ylabel(lab)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"smo_gym/FurutaPendulum-v0, frame_skip={fs0}, through EstimatedVelocity")
    axes[2].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_all(out_dir="outputs/control", quick: bool = False, plots: bool = True, echo=print) -> dict:
    """Run every experiment, print the tables through ``echo`` and write the plots to ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    steps = (1e-3, 2e-3, 4e-3) if quick else (5e-4, 1e-3, 2e-3, 4e-3)
    tf = 8.0 if quick else 10.0
    results = {}

    rows, fits = identification_orders(alphas=(1, 2) if quick else (1, 2, 3), steps=steps)
    echo(format_table(rows, "Identification on the slides' Furuta model (noise-free, LQR on the estimate)"))
    echo(format_table(fits, "\nFitted orders in tau (theory: identification alpha, velocities alpha + 1)"))
    results["identification"] = (rows, fits)
    if plots:
        plot_identification(rows, out / "identification_orders.png")

    fits = injection_ablation(steps=steps[-3:])
    echo(format_table(fits, "\nAblation: Luenberger injection applied at the samples (default) vs held between them"))
    results["injection"] = fits

    rows, fits = noise_growth(etas=(1e-4, 1e-3, 1e-2) if quick else (1e-5, 1e-4, 1e-3, 1e-2))
    echo(format_table(rows, "\nIdentification against Gaussian measurement noise (tau = 1 ms)"))
    echo(format_table(fits, "\nFitted exponents in eta (largest three levels)"))
    results["noise"] = (rows, fits)

    rows, fits, runs = furuta_sweep(steps=steps, t_final=tf, t_steady=tf - 4.0)
    echo(format_table(rows, "\nFuruta pendulum (slides' model) under w(t) = 0.4 sin(2.5 t) + 0.5"))
    echo(format_table(fits, "\nFitted orders of the steady-state error in tau"))
    results["furuta"] = (rows, fits)
    if plots:
        plot_furuta_sweep(rows, out / "furuta_sweep.png")
        plot_furuta_runs(runs, out / "furuta_time.png")

    rows, fits = actuator_sweep(
        mus=(2e-3, 5e-3, 1e-2) if quick else (1e-3, 2e-3, 5e-3, 1e-2), t_final=tf, t_steady=tf - 4.0
    )
    echo(format_table(rows, "\nActuator lag mu (unknown to the controller), tau = 1 ms, noise-free"))
    echo(format_table(fits, "\nFitted orders in mu (theory: execution error O(mu))"))
    results["actuator"] = (rows, fits)

    rows, runs = helicopter_experiment(t_final=16.0 if quick else 20.0, t_steady=10.0 if quick else 12.0)
    echo(format_table(rows, "\nThree-DOF helicopter (slides' model): unmatched compensation vs LQR"))
    results["helicopter"] = rows
    if plots:
        plot_helicopter(runs, out / "helicopter.png")

    try:
        rows, runs = furuta_mujoco_experiment(frame_skips=(1, 5) if quick else (1, 2, 5), t_final=tf, t_steady=tf - 4.0)
    except ImportError as exc:  # environments or wrappers not installed
        echo(f"\nMuJoCo Furuta experiment skipped: {exc}")
    else:
        echo(
            format_table(
                rows,
                "\nFuruta pendulum in MuJoCo (smo_gym/FurutaPendulum-v0, linearized model, "
                "12-bit encoders through EstimatedVelocity)",
            )
        )
        results["mujoco"] = rows
        if plots:
            plot_mujoco(runs, out / "furuta_mujoco.png")
    if plots:
        echo(f"\nplots written to {out}/")
    return results


# ---------------------------------------------------------------------------------------------------------------
# command line (``smo-gym control`` and ``scripts/control_experiments.py`` share it)
# ---------------------------------------------------------------------------------------------------------------
def add_arguments(parser) -> None:
    """Options of the ``control`` command: a closed loop on ``--env``, or the slides' experiments (``--reproduce``)."""
    parser.add_argument("--env", default="smo_gym/TwoLinkArm-v0", help="MuJoCo environment id (default %(default)s)")
    parser.add_argument(
        "--controller",
        default=",".join(DEFAULT_CONTROLLERS),
        help="comma-separated controllers of smo_gym.control.design: compensation, ism, unmatched, lqr, "
        "lqr-luenberger, lqr-kalman, pid, computed-torque (default %(default)s)",
    )
    parser.add_argument(
        "--disturbance",
        default="0.5*sin(2*t) + 0.2",
        help="external force on the actuated joints, expressions of t separated by commas, or 'none' "
        "(default %(default)s)",
    )
    parser.add_argument("--sensor", default="encoder-12bit-noisy", help="sensor preset (default %(default)s)")
    parser.add_argument(
        "--frame-skip", type=int, default=None, help="physics steps per control step (default: the env's)"
    )
    parser.add_argument("--seconds", type=float, default=8.0, help="run length (default %(default)s)")
    parser.add_argument("--seeds", type=int, default=1, help="seeded runs per controller (default %(default)s)")
    parser.add_argument(
        "--target", default=None, help="comma-separated qpos to regulate to (default the model's qpos0)"
    )
    parser.add_argument(
        "--reproduce", action="store_true", help="run the experiments of Fridman's slides, section 6, instead"
    )
    parser.add_argument("--out", default="outputs/control", help="directory for the plots (default %(default)s)")
    parser.add_argument("--quick", action="store_true", help="with --reproduce: fewer sampling steps, shorter runs")
    parser.add_argument("--no-plots", action="store_true", help="tables only")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar over the runs")


def add_subcommand(subparsers):
    """Register ``control`` on an ``argparse`` sub-parser collection (used by ``smo-gym``)."""
    parser = subparsers.add_parser(
        "control",
        help="output-feedback control of a MuJoCo environment from measured positions (or --reproduce the slides')",
        description="Designs each controller for the environment (smo_gym.control.design: linearization, strong "
        "observability, LQR, cascaded HOSM observer gains from the sensor), runs them in closed loop from measured "
        "positions under the sensor and the disturbance, and prints state error, control effort, disturbance "
        "identification and observer convergence (medians over the seeds), with a plot. --reproduce runs the "
        "experiments of Fridman's slides, section 6, instead (Furuta pendulum, 3-DOF helicopter).",
    )
    add_arguments(parser)
    return parser


def cli(args) -> int:
    """Run the command for parsed ``args`` (see :func:`add_arguments`)."""
    if args.reproduce:
        run_all(args.out, quick=args.quick, plots=not args.no_plots)
        return 0
    from ..cli import check_env_id
    from .closed_loop import compare_controllers, plot_closed_loop, summarize

    # every argument checked before the runs
    check_env_id(args.env)
    names = [c.strip() for c in args.controller.split(",") if c.strip()]
    if not names:
        raise ValueError(f"expected at least one controller in --controller, actual value: {args.controller!r}")
    if args.seeds < 1:
        raise ValueError(f"expected --seeds >= 1, actual value: {args.seeds}")
    if args.frame_skip is not None and args.frame_skip < 1:
        raise ValueError(f"expected --frame-skip >= 1, actual value: {args.frame_skip}")
    if not args.seconds > 0:
        raise ValueError(f"expected --seconds > 0, actual value: {args.seconds}")
    if not args.no_plots and Path(args.out).exists() and not Path(args.out).is_dir():
        raise ValueError(f"expected --out to be a folder for the plots, actual value: {args.out!r} is a file")
    disturbance = None if args.disturbance.strip().lower() == "none" else args.disturbance
    env_kwargs = {} if args.frame_skip is None else {"frame_skip": args.frame_skip}
    design_kwargs = {}
    if args.target:
        design_kwargs["operating_point"] = np.array([float(v) for v in args.target.split(",")])
    rows, runs = compare_controllers(
        args.env,
        names,
        disturbance=disturbance,
        sensor=args.sensor,
        seeds=range(args.seeds),
        t_final=args.seconds,
        env_kwargs=env_kwargs,
        design_kwargs=design_kwargs,
        show_progress=not args.no_progress,
    )
    title = f"{args.env}, sensor {args.sensor}, disturbance {disturbance or 'none'}"
    print(format_table(rows, f"{title}; medians over {args.seeds} seed(s), steady window t >= {args.seconds / 2:g} s"))
    ratios = summarize(rows)
    if ratios:
        print(format_table(ratios, "\nSliding-mode controllers against the best baseline (steady band)"))
    if not args.no_plots:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{args.env.replace('/', '_')}.png"
        plot_closed_loop(runs, path, title)
        print(f"\nplot written to {path}")
    return 0
