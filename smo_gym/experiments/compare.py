r"""Side-by-side comparison of velocity observers on the *same* measurements of one MuJoCo rollout.

The library behind ``smo-gym compare``. One environment is run under a seeded smooth random policy; the true
configuration is sampled at the chosen rate with the wrapper's own substep hook
(:meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.record_substeps`), measured once by a
:class:`~smo_gym.engine.measurement.JointMeasurement`, and every observer (built as the wrapper builds it,
:func:`~smo_gym.wrappers.estimated_velocity.calibrated_observer`, ``"auto"`` included) processes those same
measurements through :class:`~smo_gym.engine.measurement.VelocityEstimator`, i.e. exactly what
:class:`~smo_gym.wrappers.EstimatedVelocity` would feed it. The recording keeps the ``ctrl`` of every sample, so
the observers that take the control input (:data:`~smo_gym.observers.MODEL_BASED_OBSERVERS`, and ``"auto"`` with
a ``model``) run on it too, built as the wrapper builds them
(:func:`~smo_gym.wrappers.model_based.model_based_observer`).

Metrics (per observer) are over every estimate (:func:`estimate_errors`): every sample except the first of each
episode, where the observer is initialized, as the wrapper does, at the first measurement with zero velocity.
Transients after it are part of the errors (they are not timed separately).

``rmse``
    velocity RMSE over all dofs and estimates (rad/s for hinge and rotational dofs, m/s for slide and
    translational ones, pooled);
``max_error``
    the largest absolute velocity error of any dof and estimate (same units);
``rmse_observed``
    the RMSE over the samples the wrapper puts in the observation (:func:`observed`: at the physics rate the
    last of each environment step, the sample a policy sees);
``cost_us``
    median wall time of one online ``update`` (one sample, all dofs) in microseconds (the median leaves out the
    compilation at the first call and scheduler hiccups).

An observer whose state becomes non-finite (``DivergenceError``) is reported as diverged, with the time.
"""

from __future__ import annotations

import difflib
import time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from .. import _extras as extras
from .._validation import (
    DivergenceError,
    as_real_array,
    check_names,
    check_nonnegative,
    check_positive,
    check_real_in_range,
)
from ..engine.measurement import JointMeasurement, VelocityEstimator, angular_dofs, mean_velocity_span
from ..envs import make as make_by_id
from ..specs import make_sensor, needs_model, parse_observer_spec
from ..wrappers.adapters import make_adapter
from ..wrappers.estimated_velocity import calibrated_observer, resolve_rate
from ..wrappers.model_based import joint_candidate, model_based_observer
from ..wrappers.rollout import rollout, smooth_random_policy

__all__ = [
    "ObserverResult",
    "Recording",
    "compare_observers",
    "dof_names",
    "env_dof_names",
    "estimate_errors",
    "format_table",
    "observed",
    "parse_observer_specs",
    "plot_velocities",
    "record_rollout",
    "resolve_joints",
    "smooth_random_policy",
    "velocity_units",
]


def dof_names(model: mujoco.MjModel) -> list[str]:
    """A name per dof: the joint's name, with ``:x ... :rz`` suffixes for free and ball joints."""
    names = []
    for d in range(model.nv):
        j = model.dof_jntid[d]
        name = model.joint(j).name or f"joint{j}"
        offset = d - model.jnt_dofadr[j]
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            name += ":" + ("x", "y", "z", "rx", "ry", "rz")[offset]
        elif model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            name += ":" + ("rx", "ry", "rz")[offset]
        names.append(name)
    return names


@dataclass
class Recording:
    """One rollout's true states and measurements at the sampling rate.

    Attributes
    ----------
    env_id, sensor, rate : str
    dt : float
        Sampling step [s].
    qpos : ndarray, shape (T, nq)
        True configurations.
    qvel : ndarray, shape (T, nv)
        True velocities.
    z_measured : ndarray, shape (T, nv)
        Measured tangent coordinates (what the observers see).
    episode_starts : ndarray of int
        Sample indices where an episode (re)starts; observers are reset there.
    names : list of str
        Dof names.
    noise_std : ndarray, shape (nv,)
        The sensor's random error per dof.
    resolution : ndarray, shape (nv,)
        The sensor's quantization step per dof (0: none).
    inputs : ndarray, shape (T, nu), optional
        The ``ctrl`` that acted over the interval ending at each sample (row of an episode's first sample: after
        its reset).
    """

    env_id: str
    sensor: str
    rate: str
    dt: float
    qpos: np.ndarray
    qvel: np.ndarray
    z_measured: np.ndarray
    episode_starts: np.ndarray
    names: list[str]
    noise_std: np.ndarray
    resolution: np.ndarray
    inputs: np.ndarray | None = None
    context: dict = field(default_factory=dict, repr=False)


def record_rollout(
    env_id: str = "Hopper-v5",
    *,
    sensor: str = "encoder-12bit-noisy",
    rate="physics",
    steps: int = 1000,
    seed: int = 0,
    progress: bool = False,
    env_kwargs: dict | None = None,
    smoothing: float = 0.9,
) -> Recording:
    """Run ``env_id`` for ``steps`` environment steps under :func:`smooth_random_policy` (with ``smoothing``; 0:
    uniform random actions) and record samples.

    The environment is reset (unseeded, continuing its stream) when an episode ends; the sensor keeps one stream
    seeded from ``seed``. Samples are taken every ``rate`` physics steps inside ``frame_skip`` exactly as the
    wrapper takes them.
    """
    smoothing = check_real_in_range("smoothing", smoothing, 0.0, 1.0, high_open=True)  # a_k+1 = s a_k + (1 - s) u_k
    env = make_by_id(env_id, **(env_kwargs or {}))
    adapter = make_adapter(env)
    k = resolve_rate(rate, adapter.frame_skip)
    if k < adapter.frame_skip and not adapter.supports_substeps():
        raise ValueError(
            f"expected an environment whose substeps can be sampled for rate={rate!r}, "
            f"actual value: {env_id}; use rate='env'"
        )
    model = adapter.model
    dt = float(model.opt.timestep) * k
    episodes = rollout(
        env,
        smooth_random_policy(env.action_space, seed, smoothing),
        steps,
        sample_every=k,
        seed=seed,
        adapter=adapter,
        progress=f"{env_id} rollout" if progress else None,
    )
    # the sensor measures the recorded configurations in order, one stream across episodes
    measurement = JointMeasurement(model, make_sensor(sensor), dt)
    rng = np.random.default_rng([int(seed), 0x534D4F])
    z, starts = [], []
    for episode in episodes:
        starts.append(len(z))
        measurement.reset(episode.qpos[0], rng)
        z.append(measurement.z_measured.copy())
        if len(episode.qpos) > 1:
            z.extend(measurement.measure_block(episode.qpos[1:]))
    # the env stays open: compare_observers calibrates the default gains on it (context["unwrapped"]), and
    # dm_control's close (shimmy) frees the physics
    return Recording(
        env_id=env_id,
        sensor=sensor if isinstance(sensor, str) else repr(sensor),
        rate=str(rate),
        dt=dt,
        qpos=np.concatenate([episode.qpos for episode in episodes]),
        qvel=np.concatenate([episode.qvel for episode in episodes]),
        z_measured=np.array(z),
        episode_starts=np.array(starts),
        names=dof_names(model),
        noise_std=measurement.noise_std(),
        resolution=measurement.quantization_step(),
        inputs=np.concatenate([episode.ctrl for episode in episodes]),
        context={
            "unwrapped": env.unwrapped,
            "adapter": adapter,
            "sample_every": k,
            "angular": angular_dofs(model),
            "measurement": measurement,
        },
    )


@dataclass
class ObserverResult:
    """Estimates and metrics of one observer on a :class:`Recording` (see the module docstring)."""

    name: str
    velocity: np.ndarray
    rmse: float
    max_error: float
    cost_us: float
    rmse_per_dof: np.ndarray
    observer: object = field(repr=False, default=None)
    #: time [s] at which the observer's state became non-finite (DivergenceError), or None
    diverged_at: float | None = None
    #: velocity RMSE over the samples the wrapper returns, the last of each environment step (:func:`observed`)
    rmse_observed: float = float("nan")


def observed(rec: Recording) -> np.ndarray:
    """Mask of the samples :class:`~smo_gym.wrappers.EstimatedVelocity` puts in the observation, shape (T,): the last
    sample of each environment step (every sample at ``rate="env"``; at the physics rate every ``frame_skip``-th
    after the episode's reset), the reset's own excepted."""
    per_step = rec.context["adapter"].frame_skip // rec.context["sample_every"]
    mask = np.zeros(len(rec.qvel), dtype=bool)
    starts = [*rec.episode_starts, len(rec.qvel)]
    for a, b in zip(starts[:-1], starts[1:], strict=True):
        mask[a + per_step : b : per_step] = True
    return mask


def estimate_errors(rec: Recording, velocity: np.ndarray) -> np.ndarray:
    """Velocity errors ``velocity - qvel`` of every sample that is an estimate, shape (T - episodes, nv).

    The first sample of each episode is left out: there the observer is initialized (zero velocity by
    construction), it has not estimated anything yet.

    Raises
    ------
    ValueError
        ``velocity`` is not of the recording's shape ``(T, nv)`` (a column or a row would broadcast against the
        true velocities into errors of samples it does not hold).
    """
    velocity = as_real_array("velocity", velocity)
    if velocity.shape != rec.qvel.shape:
        raise ValueError(
            f"expected velocity of the recording's shape {rec.qvel.shape}, actual value: shape {velocity.shape}"
        )
    estimated = np.ones(len(velocity), dtype=bool)
    estimated[rec.episode_starts] = False
    return (velocity - rec.qvel)[estimated]


#: the default choice and what it chooses among (compiled once for both), with super-twisting for comparison
DEFAULT_OBSERVERS = (
    "auto",
    "super-twisting",
    "levant:discretization=implicit",
    "low-power-high-gain",
    "kalman-ca",
    "finite-difference",
)


def parse_observer_specs(observers, *, inputs: bool = False) -> dict[str, tuple[str, dict]]:
    """``{spec: (name, options)}`` of observer specs (:func:`smo_gym.specs.parse_observer_spec`); with ``inputs``
    (a recording that has its control inputs) also of those that take the input.

    Raises
    ------
    ValueError
        A spec is not valid, or, without ``inputs``, names a model-based observer (or ``auto`` with a model): those
        need the control input at every sample; they run in :class:`~smo_gym.wrappers.EstimatedVelocity` or on a
        :class:`Recording` with its ``inputs``.
    """
    specs = {spec: parse_observer_spec(spec) for spec in observers}
    for spec, (name, kw) in specs.items():
        if needs_model(name, kw) and not inputs:
            raise ValueError(
                "expected model-free observers (a recording without its inputs cannot give the control input an "
                f"observer that takes it needs; run that one in EstimatedVelocity), actual value: {spec!r}"
            )
    return specs


def _built_observer(name: str, kw: dict, ctx: dict, safety: float):
    """The observer ``name`` with options ``kw`` as :class:`~smo_gym.wrappers.EstimatedVelocity` builds it on the
    recording's environment (``ctx``: :attr:`Recording.context`)."""
    adapter, measurement, joint = ctx["adapter"], ctx["measurement"], None
    how = (2000, 0.99, safety)  # the wrapper's default calibration steps and quantile
    if name != "auto" and needs_model(name, kw):
        return model_based_observer(name, adapter, measurement, kw, *how).observer
    if needs_model(name, kw):
        joint, _, kw = joint_candidate(adapter, measurement, kw, *how)
    args = (ctx["unwrapped"], adapter, measurement, ctx["sample_every"], kw)
    return calibrated_observer(name, *args, safety=safety, joint=joint)[0]


def compare_observers(
    rec: Recording,
    observers=DEFAULT_OBSERVERS,
    *,
    observer_kwargs: dict | None = None,
    calibration_safety: float = 2.0,
    progress: bool = False,
) -> list[ObserverResult]:
    """Run every observer on the recorded measurements.

    ``observers`` are names or specs ``"name:key=value:..."`` (:func:`parse_observer_specs`: those that take the
    control input where the recording has its ``inputs``); ``observer_kwargs`` maps a spec to further overrides.
    The reported name is the spec.
    """
    if not isinstance(rec, Recording):
        raise TypeError(f"expected a Recording (record_rollout), actual value: {type(rec).__name__}")
    names = check_names("observers", observers, "specs")
    specs = parse_observer_specs(names, inputs=rec.inputs is not None)
    if observer_kwargs is not None and (
        not isinstance(observer_kwargs, dict) or not set(observer_kwargs) <= set(names)
    ):  # a misspelled spec's overrides were dropped silently
        raise ValueError(
            f"expected observer_kwargs keyed by specs among {names}, actual value: {observer_kwargs!r:.120}"
        )
    ctx = rec.context
    starts = list(rec.episode_starts) + [len(rec.z_measured)]
    results = []
    iterator = names
    if progress:
        iterator = extras.progress(names, desc="observers")
    for spec in iterator:
        name, kw = specs[spec]
        kw = {**kw, **((observer_kwargs or {}).get(spec) or {})}
        observer = _built_observer(name, kw, ctx, calibration_safety)
        estimator = VelocityEstimator(observer, mean_over=mean_velocity_span(ctx["adapter"].model))
        if observer.takes_input:  # as the wrapper's InputAwareEstimator, with the recorded ctrl

            def advance(i, estimator=estimator, observer=observer):
                return estimator.velocity_of(observer.update(rec.z_measured[i], rec.inputs[i]))
        else:

            def advance(i, estimator=estimator):
                return estimator.update(rec.z_measured[i])

        V = np.full_like(rec.qvel, np.nan)
        timings = []
        clock = time.perf_counter
        diverged = None
        for a, b in zip(starts[:-1], starts[1:], strict=True):
            V[a] = estimator.reset(rec.z_measured[a])
            try:
                for i in range(a + 1, b):
                    t0 = clock()
                    V[i] = advance(i)
                    timings.append(clock() - t0)
            except DivergenceError:
                diverged = i * rec.dt
                break
        cost = 1e6 * float(np.median(timings)) if timings else float("nan")
        if diverged is not None:
            results.append(
                ObserverResult(
                    name=spec,
                    velocity=V,
                    rmse=float("nan"),
                    max_error=float("inf"),
                    cost_us=cost,
                    rmse_per_dof=np.full(V.shape[1], np.nan),
                    observer=estimator.observer,
                    diverged_at=diverged,
                )
            )
            continue
        err = estimate_errors(rec, V)
        seen = (V - rec.qvel)[observed(rec)]
        results.append(
            ObserverResult(
                name=spec,
                velocity=V,
                rmse=float(np.sqrt(np.mean(err**2))),
                max_error=float(np.max(np.abs(err))),
                cost_us=cost,
                rmse_per_dof=np.sqrt(np.mean(err**2, axis=0)),
                observer=estimator.observer,
                rmse_observed=float(np.sqrt(np.mean(seen**2))) if seen.size else float("nan"),
            )
        )
    return results


#: what every column of :func:`format_table` means (also the help of ``smo-gym compare``)
TABLE_COLUMNS = {
    "observer": "the observer spec (name:key=value:...); gains not given are calibrated as the wrapper does",
    "RMSE": "velocity RMSE over every dof and estimate (rad/s for hinge dofs, m/s for slide dofs, pooled)",
    "max err": "largest absolute velocity error of any dof and estimate (same units)",
    "us/step": "median wall time of one observer update (one sample, all dofs) in microseconds",
}


def _table(cols, rows) -> list[str]:
    widths = [max([len(c), *(len(row[i]) for row in rows)]) for i, c in enumerate(cols)]

    def line(cells):
        return "  ".join(
            c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        )

    return [line(cols), line(["-" * w for w in widths])] + [line(row) for row in rows]


def format_table(rec: Recording, results: list[ObserverResult], *, per_joint: bool = False) -> str:
    """A plain-text table of the metrics (and, with ``per_joint``, the RMSE of every dof)."""
    head = (
        f"{rec.env_id}, sensor {rec.sensor}, rate {rec.rate} (dt = {rec.dt:g} s), {len(rec.qvel)} samples, "
        f"{len(rec.episode_starts)} episode(s); velocity RMS {np.sqrt(np.mean(rec.qvel**2)):.3g} "
        f"(rad/s for hinge dofs, m/s for slide dofs)"
    )
    rows = [
        (r.name, f"{r.rmse:.4g}", f"{r.max_error:.4g}", f"{r.cost_us:.1f}")
        if r.diverged_at is None
        else (r.name, f"diverged at {r.diverged_at:.3g} s", "-", f"{r.cost_us:.1f}")
        for r in results
    ]
    out = [head] + _table(tuple(TABLE_COLUMNS), rows)
    if per_joint:
        units = velocity_units(rec)
        out += ["", "RMSE per dof"]
        jrows = [[f"{n} [{units[d]}]"] + [f"{r.rmse_per_dof[d]:.4g}" for r in results] for d, n in enumerate(rec.names)]
        out += _table(["dof"] + [r.name for r in results], jrows)
    return "\n".join(out)


def velocity_units(rec: Recording) -> list[str]:
    """``"rad/s"`` for every rotational dof (hinge, ball, a free joint's rotations), ``"m/s"`` for translations."""
    return ["rad/s" if a else "m/s" for a in rec.context["angular"]]


def env_dof_names(env_id: str, env_kwargs: dict | None = None) -> list[str]:
    """The dof names of ``env_id`` (:func:`dof_names`), from a freshly made environment (no rollout)."""
    env = make_by_id(env_id, **(env_kwargs or {}))
    try:
        return dof_names(make_adapter(env).model)
    finally:
        env.close()


def resolve_joints(names: list[str], joints, qvel: np.ndarray | None = None, root=None) -> list[int]:
    """Dof indices of ``joints`` (names or indices into ``names``).

    Without ``joints``: the two dofs with the largest velocity RMS in ``qvel`` (T, nv), leaving out those flagged
    in ``root`` (the floating base) unless nothing else is left.
    """
    if not joints:
        if qvel is None:
            raise ValueError("expected joints or the velocities to choose them from, actual value: neither")
        qvel = as_real_array("qvel", qvel)
        if qvel.ndim != 2 or qvel.shape[1] != len(names):
            raise ValueError(f"expected qvel of shape (T, {len(names)}), actual value: shape {qvel.shape}")
        rms = np.sqrt(np.mean(qvel**2, axis=0))
        root = np.zeros(len(names), dtype=bool) if root is None else np.asarray(root, dtype=bool)
        if root.shape != (len(names),):
            raise ValueError(f"expected root of shape ({len(names)},), actual value: shape {root.shape}")
        order = [d for d in np.argsort(-rms) if not root[d]] or list(np.argsort(-rms))
        return [int(d) for d in order[:2]]
    out = []
    for j in joints:
        if isinstance(j, bool):
            raise TypeError(f"expected a dof name or an integer index, actual value: {j!r}")
        if isinstance(j, (int, np.integer)) or (
            isinstance(j, str) and j.lstrip("-").isascii() and j.lstrip("-").isdigit()
        ):
            d = int(j)
            if not 0 <= d < len(names):
                raise ValueError(f"expected a dof index in [0, {len(names) - 1}], actual value: {j!r}")
        elif j in names:
            d = names.index(j)
        else:
            match = difflib.get_close_matches(str(j), names, n=1)
            hint = f" (did you mean {match[0]!r}?)" if match else ""
            raise ValueError(f"expected a dof name in {', '.join(names)} or an index, actual value: {j!r}{hint}")
        out.append(d)
    return out


def _root_dofs(rec: Recording) -> np.ndarray:
    model = rec.context["adapter"].model
    root = model.jnt_type[model.dof_jntid] == mujoco.mjtJoint.mjJNT_FREE
    return root | (np.asarray(model.dof_jntid) == 0)


def plot_limits(true_velocity: np.ndarray, margin: float = 1.0, floor: float = 1e-3) -> tuple[float, float]:
    """y-limits of a velocity plot from the *true* velocity alone: its range widened by ``margin`` times its span
    on both sides (span at least ``floor``), so that a chattering or diverged estimate cannot rescale the axis."""
    v = as_real_array("true_velocity", true_velocity)
    margin, floor = check_nonnegative("margin", margin), check_positive("floor", floor)
    if v.size == 0 or not np.isfinite(v).all():
        raise ValueError(f"expected finite true velocities, actual value: {v.size} values, some not finite or none")
    lo, hi = float(np.min(v)), float(np.max(v))
    with np.errstate(over="ignore"):
        span = max(hi - lo, floor, 0.1 * max(abs(lo), abs(hi)))
        limits = lo - margin * span, hi + margin * span
    if not np.isfinite(limits).all():
        raise ValueError(f"expected velocities whose plot range is finite, actual value: from {lo:.3g} to {hi:.3g}")
    return limits


def velocity_figure(rec: Recording, results: list[ObserverResult], joints, *, seconds: float = 1.0):
    """A matplotlib figure of true vs estimated velocities of the dofs ``joints`` over the first ``seconds``.

    The y-axis of each dof is set by its true velocity (:func:`plot_limits`); estimates outside it are drawn
    clipped at the edge, with triangles where they leave it, and their legend entry says which fraction of the
    window was off scale and the largest value. The legend sits outside the axes, to the right.
    """
    extras.require("matplotlib", "plots").use("Agg")
    plt = extras.require("matplotlib.pyplot", "plots")

    if not seconds > 0:
        raise ValueError(f"expected seconds > 0, actual value: {seconds!r}")
    dofs = resolve_joints(rec.names, joints, rec.qvel, _root_dofs(rec))
    units = velocity_units(rec)
    n = min(len(rec.qvel), max(2, round(seconds / rec.dt) + 1))
    t = np.arange(n) * rec.dt
    fig, axes = plt.subplots(
        len(dofs), 1, figsize=(11, 2.8 * len(dofs) + 0.8), sharex=True, squeeze=False, layout="constrained"
    )
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    handles, labels = [], []
    off_scale: dict[str, list[str]] = {}
    for row, (ax, d) in enumerate(zip(axes[:, 0], dofs, strict=True)):
        lo, hi = plot_limits(rec.qvel[:n, d])
        for k, r in enumerate(results):
            v = r.velocity[:n, d]
            color = colors[k % len(colors)]
            (line,) = ax.plot(t, np.clip(v, lo, hi), lw=0.8, alpha=0.8, color=color)
            outside = np.isfinite(v) & ((v < lo) | (v > hi))
            if outside.any():
                # mark where the estimate leaves the window (first sample of each excursion)
                enter = np.flatnonzero(outside & ~np.r_[False, outside[:-1]])
                for side, edge, marker in ((v[enter] > hi, hi, "^"), (v[enter] < lo, lo, "v")):
                    ax.plot(t[enter[side]], np.full(side.sum(), edge), ls="none", color=color, ms=5, marker=marker)
                peak = float(np.max(np.abs(v[outside])))
                share = f"{outside.mean():.0%}" if outside.mean() >= 0.005 else "<1%"
                off_scale.setdefault(r.name, []).append(f"{rec.names[d]} {share} (|v| up to {peak:.3g})")
            if row == 0:
                handles.append(line)
        (true_line,) = ax.plot(t, rec.qvel[:n, d], color="k", lw=1.6, zorder=10)
        ax.set_ylim(lo, hi)
        ax.set_ylabel(f"{rec.names[d]} velocity [{units[d]}]")
        ax.grid(alpha=0.3)
    for r in results:
        if r.diverged_at is not None:
            label = f"{r.name} (diverged at {r.diverged_at:.3g} s)"
        else:
            label = f"{r.name} (RMSE {r.rmse:.3g})"
        if r.name in off_scale:
            label += "\n  clipped: " + "; ".join(off_scale[r.name])
        labels.append(label)
    handles.append(true_line)
    labels.append("true")
    fig.legend(handles, labels, loc="outside right upper", fontsize=7, frameon=False)
    axes[0, 0].set_title(
        f"{rec.env_id}: sensor {rec.sensor}, rate {rec.rate} (dt = {rec.dt:g} s)\n"
        "y-axis from the true velocity; estimates beyond it clipped (triangles)",
        fontsize=9,
    )
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def plot_velocities(rec: Recording, results: list[ObserverResult], joints, out: str, *, seconds: float = 1.0) -> str:
    """Write :func:`velocity_figure` to ``out`` (PNG or any format matplotlib knows by the suffix); its path."""
    plt = extras.require("matplotlib.pyplot", "plots")

    fig = velocity_figure(rec, results, joints, seconds=seconds)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return str(out)
