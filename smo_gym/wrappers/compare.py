r"""Side-by-side comparison of velocity observers on the *same* measurements of one MuJoCo rollout.

The library behind ``smo-gym compare``. One environment is run under a seeded smooth random policy; the true
configuration is sampled at the chosen rate with the wrapper's own substep hook
(:meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.substeps`), measured once by a
:class:`~smo_gym.wrappers.sensing.JointMeasurement`, and every observer (built with the wrapper's default gains,
:func:`~smo_gym.wrappers.sensing.default_observer`) processes those same measurements through
:class:`~smo_gym.wrappers.sensing.VelocityEstimator`, i.e. exactly what
:class:`~smo_gym.wrappers.EstimatedVelocity` would feed it.

Metrics (per observer; samples after a reset restart the observer, as the wrapper does):

An observer whose state becomes non-finite (``DivergenceError``) is reported as diverged, with the time.

``rmse``
    velocity RMSE over all dofs and the samples after convergence;
``max_error``
    the largest absolute velocity error after convergence;
``convergence_time``
    time until the per-sample error (RMS over dofs) first falls inside three times its steady level (the median
    over the second half of the episode), averaged over episodes;
``cost_us``
    median wall time of one online ``update`` (one sample, all dofs) in microseconds (the median leaves out the
    compilation at the first call and scheduler hiccups).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

from .._validation import DivergenceError
from ..envs import make as make_by_id
from ..observers import OBSERVERS, make_observer
from ..sensors import make_sensor
from .adapters import make_adapter
from .estimated_velocity import calibrated_bounds, resolve_rate
from .sensing import JointMeasurement, VelocityEstimator, angular_dofs, bound_order, default_observer

__all__ = [
    "ObserverResult",
    "Recording",
    "compare_observers",
    "dof_names",
    "format_table",
    "parse_observer_spec",
    "plot_velocities",
    "record_rollout",
    "smooth_random_policy",
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


def smooth_random_policy(action_space: gym.spaces.Box, seed: int, smoothing: float = 0.9):
    r"""A seeded low-pass random policy :math:`a_{k+1} = s a_k + (1 - s) u_k`, :math:`u_k` uniform in the box.

    Returns a function ``policy(obs) -> action`` (the observation is ignored).
    """
    rng = np.random.default_rng(seed)
    low, high = action_space.low, action_space.high
    state = {"a": np.zeros(action_space.shape)}

    def policy(_obs):
        state["a"] = smoothing * state["a"] + (1.0 - smoothing) * rng.uniform(low, high)
        return state["a"].astype(action_space.dtype)

    return policy


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
    context: dict = field(default_factory=dict, repr=False)


def record_rollout(env_id: str = "Hopper-v5", *, sensor: str = "encoder-12bit-noisy", rate="physics",
                   steps: int = 1000, seed: int = 0, progress: bool = False, env_kwargs: dict | None = None
                   ) -> Recording:
    """Run ``env_id`` for ``steps`` environment steps under :func:`smooth_random_policy` and record samples.

    The environment is reset (unseeded, continuing its stream) when an episode ends; the sensor keeps one stream
    seeded from ``seed``. Samples are taken every ``rate`` physics steps inside ``frame_skip`` exactly as the
    wrapper takes them.
    """
    env = make_by_id(env_id, **(env_kwargs or {}))
    adapter = make_adapter(env)
    k = resolve_rate(rate, adapter.frame_skip)
    if k < adapter.frame_skip and not adapter.supports_substeps():
        raise ValueError(f"expected an environment whose substeps can be sampled for rate={rate!r}, "
                         f"actual value: {env_id}; use rate='env'")
    model = adapter.model
    dt = float(model.opt.timestep) * k
    measurement = JointMeasurement(model, make_sensor(sensor), dt)
    rng = np.random.default_rng([int(seed), 0x534D4F])
    policy = smooth_random_policy(env.action_space, seed)
    qpos, qvel, z, starts = [], [], [], []
    counter = [0]

    def sample():
        counter[0] += 1
        if counter[0] % k == 0:
            q = np.array(adapter.data.qpos)
            qpos.append(q)
            qvel.append(np.array(adapter.data.qvel))
            z.append(measurement.measure(q))

    def start():
        starts.append(len(qpos))
        q = np.array(adapter.data.qpos)
        measurement.reset(q, rng)
        qpos.append(q)
        qvel.append(np.array(adapter.data.qvel))
        z.append(measurement.z_measured.copy())

    obs, _ = env.reset(seed=seed)
    start()
    iterator = range(steps)
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(iterator, desc=f"{env_id} rollout", unit="step", leave=False)
    hook = adapter.supports_substeps()
    for step in iterator:
        if hook:
            with adapter.substeps(sample):
                obs, _, terminated, truncated, _ = env.step(policy(obs))
        else:  # rate == frame_skip: one sample at the end of the step, as the wrapper takes it
            obs, _, terminated, truncated, _ = env.step(policy(obs))
            counter[0] = k - 1
            sample()
        if (terminated or truncated) and step < steps - 1:
            obs, _ = env.reset()
            counter[0] = 0
            start()
    # the env stays open: compare_observers calibrates the default gains on it (context["unwrapped"]), and
    # dm_control's close (shimmy) frees the physics
    return Recording(env_id=env_id, sensor=sensor if isinstance(sensor, str) else repr(sensor), rate=str(rate),
                     dt=dt, qpos=np.array(qpos), qvel=np.array(qvel), z_measured=np.array(z),
                     episode_starts=np.array(starts), names=dof_names(model),
                     noise_std=measurement.noise_std(),
                     context={"unwrapped": env.unwrapped, "adapter": adapter, "sample_every": k,
                              "angular": angular_dofs(model)})


@dataclass
class ObserverResult:
    """Estimates and metrics of one observer on a :class:`Recording` (see the module docstring)."""

    name: str
    velocity: np.ndarray
    rmse: float
    max_error: float
    convergence_time: float
    cost_us: float
    rmse_per_dof: np.ndarray
    observer: object = field(repr=False, default=None)
    #: time [s] at which the observer's state became non-finite (DivergenceError), or None
    diverged_at: float | None = None


def _convergence_index(err: np.ndarray) -> int:
    """First sample at which the per-sample error ``err`` (T,) enters three times its steady (median) level."""
    steady = np.median(err[len(err) // 2:])
    inside = np.flatnonzero(err <= 3.0 * steady + 1e-12)
    return int(inside[0]) if inside.size else len(err)


def parse_observer_spec(spec: str) -> tuple[str, dict]:
    """``"levant:order=1:discretization=matching"`` -> ``("levant", {"order": 1, "discretization": "matching"})``.

    Values are read as int, then float, then kept as strings.
    """
    name, *items = spec.split(":")
    kwargs: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"expected observer options as key=value, actual value: {item!r} in {spec!r}")
        for cast in (int, float):
            try:
                kwargs[key] = cast(value)
                break
            except ValueError:
                continue
        else:
            kwargs[key] = value
    if name not in OBSERVERS:
        make_observer(name)  # raises the ValueError listing the valid names
    return name, kwargs


def compare_observers(rec: Recording, observers=("super-twisting", "levant", "levant:discretization=matching",
                                                 "high-gain", "kalman-ca", "finite-difference"), *, observer_kwargs: dict | None = None,
                      calibration_safety: float = 2.0, progress: bool = False) -> list[ObserverResult]:
    """Run every observer on the recorded measurements.

    ``observers`` are names or specs ``"name:key=value:..."`` (:func:`parse_observer_spec`); ``observer_kwargs``
    maps a spec to further overrides. The reported name is the spec.
    """
    names = list(observers)
    specs = {spec: parse_observer_spec(spec) for spec in names}
    ctx = rec.context
    bounds_by_order: dict[int, np.ndarray] = {}
    starts = list(rec.episode_starts) + [len(rec.z_measured)]
    results = []
    iterator = names
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(names, desc="observers", leave=False)
    for spec in iterator:
        name, kw = specs[spec]
        kw = {**kw, **((observer_kwargs or {}).get(spec) or {})}
        order = bound_order(name, kw)
        if order not in bounds_by_order:
            bounds_by_order[order] = calibrated_bounds(ctx["unwrapped"], ctx["adapter"], ctx["sample_every"], order,
                                                       safety=calibration_safety)
        estimator = VelocityEstimator(default_observer(name, rec.dt, bounds_by_order[order], rec.noise_std, kw))
        V = np.full_like(rec.qvel, np.nan)
        timings = []
        clock = time.perf_counter
        diverged = None
        for a, b in zip(starts[:-1], starts[1:], strict=True):
            V[a] = estimator.reset(rec.z_measured[a])
            try:
                for i in range(a + 1, b):
                    t0 = clock()
                    V[i] = estimator.update(rec.z_measured[i])
                    timings.append(clock() - t0)
            except DivergenceError:
                diverged = i * rec.dt
                break
        if diverged is not None:
            results.append(ObserverResult(
                name=spec, velocity=V, rmse=float("nan"), max_error=float("inf"), convergence_time=float("nan"),
                cost_us=1e6 * float(np.median(timings)) if timings else float("nan"),
                rmse_per_dof=np.full(V.shape[1], np.nan), observer=estimator.observer, diverged_at=diverged,
            ))
            continue
        err = V - rec.qvel
        per_sample = np.sqrt(np.mean(err**2, axis=1))
        keep = np.zeros(len(err), dtype=bool)
        conv_times = []
        for a, b in zip(starts[:-1], starts[1:], strict=True):
            c = _convergence_index(per_sample[a:b])
            keep[a + c:b] = True
            conv_times.append(c * rec.dt)
        kept = err[keep] if keep.any() else err
        results.append(ObserverResult(
            name=spec, velocity=V, rmse=float(np.sqrt(np.mean(kept**2))), max_error=float(np.max(np.abs(kept))),
            convergence_time=float(np.mean(conv_times)),
            cost_us=1e6 * float(np.median(timings)) if timings else float("nan"),
            rmse_per_dof=np.sqrt(np.mean(kept**2, axis=0)), observer=estimator.observer,
        ))
    return results


def format_table(rec: Recording, results: list[ObserverResult], *, per_joint: bool = False) -> str:
    """A plain-text table of the metrics (and, with ``per_joint``, the RMSE of every dof)."""
    head = (f"{rec.env_id}, sensor {rec.sensor}, rate {rec.rate} (dt = {rec.dt:g} s), {len(rec.qvel)} samples, "
            f"{len(rec.episode_starts)} episode(s); velocity RMS {np.sqrt(np.mean(rec.qvel**2)):.3g}")
    cols = ("observer", "RMSE", "max err", "conv. [s]", "us/step")
    rows = [(r.name, f"{r.rmse:.4g}", f"{r.max_error:.4g}", f"{r.convergence_time:.3g}", f"{r.cost_us:.1f}")
            if r.diverged_at is None else (r.name, "diverged", "-", f"at {r.diverged_at:.3g}", f"{r.cost_us:.1f}")
            for r in results]
    widths = [max(len(c), *(len(row[i]) for row in rows)) for i, c in enumerate(cols)]
    line = lambda cells: "  ".join(c.ljust(w) if i == 0 else c.rjust(w)  # noqa: E731
                                   for i, (c, w) in enumerate(zip(cells, widths, strict=True)))
    out = [head, line(cols), line(["-" * w for w in widths])] + [line(row) for row in rows]
    if per_joint:
        out += ["", "RMSE per dof"]
        jcols = ["dof"] + [r.name for r in results]
        jrows = [[n] + [f"{r.rmse_per_dof[d]:.4g}" for r in results] for d, n in enumerate(rec.names)]
        jw = [max(len(c), *(len(row[i]) for row in jrows)) for i, c in enumerate(jcols)]
        fmt = lambda cells: "  ".join(c.ljust(w) if i == 0 else c.rjust(w)  # noqa: E731
                                      for i, (c, w) in enumerate(zip(cells, jw, strict=True)))
        out += [fmt(jcols), fmt(["-" * w for w in jw])] + [fmt(row) for row in jrows]
    return "\n".join(out)


def resolve_joints(rec: Recording, joints) -> list[int]:
    """Dof indices from names or indices; default: the two non-root dofs with the largest velocity RMS."""
    if not joints:
        rms = np.sqrt(np.mean(rec.qvel**2, axis=0))
        model = rec.context["adapter"].model
        root = model.jnt_type[model.dof_jntid] == mujoco.mjtJoint.mjJNT_FREE
        root |= np.asarray(model.dof_jntid) == 0
        order = [d for d in np.argsort(-rms) if not root[d]] or list(np.argsort(-rms))
        return [int(d) for d in order[:2]]
    out = []
    for j in joints:
        if isinstance(j, (int, np.integer)) or (isinstance(j, str) and j.lstrip("-").isdigit()):
            d = int(j)
            if not 0 <= d < len(rec.names):
                raise ValueError(f"expected a dof index in [0, {len(rec.names) - 1}], actual value: {j!r}")
        elif j in rec.names:
            d = rec.names.index(j)
        else:
            raise ValueError(f"expected a dof name in {', '.join(rec.names)}, actual value: {j!r}")
        out.append(d)
    return out


def plot_velocities(rec: Recording, results: list[ObserverResult], joints, out: str, *, seconds: float = 1.0) -> str:
    """Write a PNG of true vs estimated velocities of the dofs ``joints`` over the first ``seconds``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dofs = resolve_joints(rec, joints)
    n = min(len(rec.qvel), max(2, int(round(seconds / rec.dt)) + 1))
    t = np.arange(n) * rec.dt
    fig, axes = plt.subplots(len(dofs), 1, figsize=(9, 2.8 * len(dofs)), sharex=True, squeeze=False)
    for ax, d in zip(axes[:, 0], dofs, strict=True):
        for r in results:
            ax.plot(t, r.velocity[:n, d], lw=0.8, alpha=0.8, label=f"{r.name} (RMSE {r.rmse:.3g})")
        ax.plot(t, rec.qvel[:n, d], color="k", lw=1.6, label="true", zorder=10)
        ax.set_ylabel(f"{rec.names[d]} velocity")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(ncol=2, fontsize=7, loc="upper right")
    axes[0, 0].set_title(f"{rec.env_id}: sensor {rec.sensor}, rate {rec.rate} (dt = {rec.dt:g} s)")
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
