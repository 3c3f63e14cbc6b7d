r"""Output-feedback control of a MuJoCo environment: several controllers on the same seeded runs, a table, a plot.

``smo-gym control --env ID --controller NAME[,NAME...] --disturbance EXPR --sensor PRESET`` and
``scripts/bench_control.py`` call :func:`compare_controllers`: every controller is designed by
:func:`smo_gym.control.design` for the same environment, run by :func:`smo_gym.control.run_closed_loop` from the
same seeded resets with the same sensor and disturbance, and summarized by
:func:`smo_gym.control.closed_loop_metrics` (medians over the seeds).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .._validation import check_names, check_positive, check_real
from ..control.closed_loop import closed_loop_metrics, parse_disturbance, run_closed_loop, scale_body_mass

__all__ = ["BASELINES", "DEFAULT_CONTROLLERS", "compare_controllers", "plot_closed_loop", "summarize"]

#: the sliding-mode controllers and the baselines a control engineer would otherwise use
DEFAULT_CONTROLLERS = ("compensation", "ism", "lqr-luenberger", "lqr-kalman", "pid")


def compare_controllers(
    env_id: str,
    controllers: Sequence[str] = DEFAULT_CONTROLLERS,
    *,
    disturbance: str | None = None,
    sensor: str = "encoder-12bit-noisy",
    seeds: Sequence[int] = (0,),
    t_final: float = 8.0,
    t_steady: float | None = None,
    env_kwargs: dict | None = None,
    design_kwargs: dict | None = None,
    payload: tuple[float, str, float] | None = None,
    show_progress: bool = False,
) -> tuple[list[dict], dict]:
    """Design and run each controller on each seed; return ``(rows, runs)``.

    Parameters
    ----------
    env_id : str
        Gymnasium id of a MuJoCo environment with hinge and slide joints.
    controllers : sequence of str
        Names accepted by :func:`smo_gym.control.design`.
    disturbance : str, optional
        Expression(s) of ``t`` for the external force on the disturbance channels (:func:`parse_disturbance`).
    sensor : str
        Sensor preset.
    seeds : sequence of int
        One run per seed and controller (the same resets and sensor streams for every controller).
    t_final, t_steady : float
        Run length and start of the steady window (default half the run).
    env_kwargs, design_kwargs : dict, optional
        Passed to ``gymnasium.make`` and to :func:`smo_gym.control.design`.
    payload : (float, str, float), optional
        ``(time, body, factor)``: the body's mass and inertia change by ``factor`` at ``time``.
    show_progress : bool
        A progress bar over the runs on standard error.

    Returns
    -------
    rows : list of dict
        One per controller: the medians over the seeds of :func:`closed_loop_metrics` (over the runs that did not
        fall) and the number of runs that fell.
    runs : dict
        ``{controller: ClosedLoopRun}`` of the first seed, for the plot.
    """
    import gymnasium as gym

    from .. import envs as _envs  # noqa: F401 - registers smo_gym's environments
    from .._extras import progress
    from ..control.policies import design

    controllers, seeds = check_names("controllers", controllers), list(seeds)
    if not seeds or not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in seeds):
        raise ValueError(f"expected one integer seed or more, actual value: {seeds!r:.80}")
    if payload is not None and not (
        isinstance(payload, tuple) and len(payload) == 3 and isinstance(payload[1], str)
    ):  # the time and the factor are checked by run_closed_loop and scale_body_mass
        raise ValueError(f"expected payload as (time, body name, mass factor), actual value: {payload!r:.80}")
    t_final = check_positive("t_final", t_final)
    t_steady = t_final / 2 if t_steady is None else check_real("t_steady", t_steady)
    dt = gym.make(env_id, **(env_kwargs or {})).unwrapped.dt
    if not t_steady + 2 * dt <= t_final:  # the metrics are over the steady window: two control steps at least
        raise ValueError(
            f"expected a run with two control steps ({dt:g} s) in its steady window [{t_steady:g}, {t_final:g}] s, "
            f"actual value: t_final={t_final:g}"
        )
    force = None if disturbance is None else parse_disturbance(disturbance)
    events = () if payload is None else ((payload[0], scale_body_mass(payload[1], payload[2])),)
    results: dict[str, list] = {name: [] for name in controllers}
    runs = {}
    pairs = [(name, seed) for name in controllers for seed in seeds]
    for name, seed in progress(pairs, desc="closed loops", unit="run") if show_progress else pairs:
        env = gym.make(env_id, **(env_kwargs or {}))
        policy = design(env, name, sensor=sensor, **(design_kwargs or {}))
        run = run_closed_loop(env, policy, t_final=t_final, seed=seed, disturbance=force, sensor=sensor, events=events)
        runs.setdefault(name, run)
        results[name].append((run.terminated, closed_loop_metrics(run, t_steady)))
    rows = []
    keys = ("error RMS", "steady band", "effort RMS", "TV(u)/s", "ident. RMS", "converged [s]")
    for name, outcomes in results.items():
        metrics = [m for fell, m in outcomes if not fell]
        row = {"controller": name}
        for k in keys:
            row[k] = float(np.median([m[k] for m in metrics])) if metrics else np.inf
        row["fell"] = f"{len(outcomes) - len(metrics)}/{len(outcomes)}"
        rows.append(row)
    return rows, runs


#: the controllers a control engineer would otherwise use
BASELINES = ("lqr-luenberger", "lqr-kalman", "pid")


def summarize(rows: list[dict]) -> list[dict]:
    """For each controller that is not a baseline (:data:`BASELINES`): its steady band and effort divided by those of
    the best baseline (the one with the smallest steady band among those that did not fall); below 1 is better."""
    base = [r for r in rows if r["controller"] in BASELINES and np.isfinite(r["steady band"])]
    if not base:
        return []
    best = min(base, key=lambda b: b["steady band"])

    def ratio(a: float, b: float) -> float:  # a baseline that holds exactly (0) makes any other band infinitely worse
        return a / b if b != 0 else (1.0 if a == 0 else np.inf)

    return [
        {
            "controller": r["controller"],
            "best baseline": best["controller"],
            "band / best baseline": ratio(r["steady band"], best["steady band"]),
            "effort / its effort": ratio(r["effort RMS"], best["effort RMS"]),
        }
        for r in rows
        if r["controller"] not in BASELINES
    ]


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centered moving average over ``n`` samples along axis 0 (edges averaged over what exists)."""
    if n <= 1:
        return x
    kernel = np.ones(n)
    norm = np.convolve(np.ones(len(x)), kernel, mode="same")
    return np.stack([np.convolve(col, kernel, mode="same") / norm for col in np.atleast_2d(x.T)], axis=-1)


def plot_closed_loop(runs: dict, path, title: str = "", smoothing: float = 0.05) -> None:
    """Position error, command, identified vs true disturbance and velocity estimation error of each run.

    Noisy signals (command, identified disturbance) are drawn faintly as sampled and boldly as their centered moving
    average over ``smoothing`` seconds, so that the mean behaviour stays readable under sensor noise.
    """
    from .._extras import require

    require("matplotlib", "plots").use("Agg")
    plt = require("matplotlib.pyplot", "plots")
    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (name, r) in enumerate(runs.items()):
        c = colors[i % len(colors)]
        n = max(1, int(round(smoothing / max(r.t[1] - r.t[0], 1e-12)))) if r.t.size > 1 else 1
        err = np.abs(r.qpos - r.target).max(axis=1)
        axes[0].semilogy(r.t, np.maximum(err, 1e-7), color=c, lw=0.3, alpha=0.35)
        axes[0].semilogy(r.t, np.maximum(_moving_average(err[:, None], n)[:, 0], 1e-7), color=c, lw=1.2, label=name)
        axes[1].plot(r.t, r.ctrl[:, 0], color=c, lw=0.3, alpha=0.3)
        axes[1].plot(r.t, _moving_average(r.ctrl, n)[:, 0], color=c, lw=1.2, label=name)
        w_hat = r.disturbance_hat
        if w_hat.shape == r.disturbance.shape and np.any(w_hat != 0):
            axes[2].plot(r.t, w_hat[:, 0], color=c, lw=0.3, alpha=0.3)
            axes[2].plot(r.t, _moving_average(w_hat, n)[:, 0], color=c, lw=1.2, label=f"{name}: identified")
        verr = np.abs(r.qvel_hat - r.qvel[:, : r.qvel_hat.shape[1]]).max(axis=1)
        axes[3].semilogy(r.t, np.maximum(verr, 1e-7), color=c, lw=0.3, alpha=0.35)
        axes[3].semilogy(r.t, np.maximum(_moving_average(verr[:, None], n)[:, 0], 1e-7), color=c, lw=1.2, label=name)
    first = next(iter(runs.values()))
    if first.disturbance.size:
        axes[2].plot(first.t, first.disturbance[:, 0], "k", lw=1.5, label="true")
    labels = ("max |q - q*| [rad, m]", "command (first actuator)", "disturbance (first channel)", "max |v_hat - v|")
    for ax, label in zip(axes, labels, strict=True):
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axes[0].set_title(f"{title}\n(faint: as sampled; bold: {smoothing * 1e3:g} ms moving average)", fontsize=9)
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
