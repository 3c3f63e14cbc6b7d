r"""``EstimatedVelocity``: a Gymnasium MuJoCo environment seen through joint sensors and a velocity observer."""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np

from ..observers import OBSERVERS, Observer, make_observer
from ..sensors import Sensor, make_sensor
from .adapters import make_adapter
from .sensing import (
    FusedSensing,
    JointMeasurement,
    SensingInfo,
    VelocityEstimator,
    bound_order,
    bounds_from_velocities,
    cached_bounds,
    calibrate_bounds,
    calibration_key,
    check_finite_observation,
    default_observer,
)

__all__ = ["EstimatedVelocity", "calibrated_bounds", "environment_key", "observation_independent_reset",
           "observation_independent_step", "resolve_rate", "rollout_velocities"]

#: mixed into the user's seed so the sensor stream differs from the environment's own ``np_random``
_SEED_SALT = 0x534D4F


def resolve_rate(rate, frame_skip: int) -> int:
    """Physics steps per sample: ``"physics"`` -> 1, ``"env"`` -> ``frame_skip``, an int ``k`` dividing it -> k."""
    if isinstance(rate, str):
        if rate == "physics":
            return 1
        if rate == "env":
            return int(frame_skip)
        raise ValueError(f"expected rate 'physics', 'env' or an int dividing frame_skip, actual value: {rate!r}")
    if isinstance(rate, bool) or not isinstance(rate, (int, np.integer)):
        raise TypeError(f"expected rate 'physics', 'env' or an int dividing frame_skip, actual value: {rate!r}")
    k = int(rate)
    if k < 1 or frame_skip % k != 0:
        raise ValueError(
            f"expected rate to be a positive divisor of frame_skip={frame_skip} (physics steps per sample), "
            f"actual value: {rate!r}"
        )
    return k


def environment_key(unwrapped) -> str:
    """Identity of an environment for the calibration cache: its registered id and kwargs, or its class/model."""
    spec = getattr(unwrapped, "spec", None)
    if spec is not None and spec.id:
        kwargs = {k: v for k, v in sorted((spec.kwargs or {}).items()) if k != "render_mode"}
        return f"{spec.id}{kwargs}" if kwargs else spec.id
    return f"{type(unwrapped).__module__}.{type(unwrapped).__qualname__}:{getattr(unwrapped, 'fullpath', '')}"


def rollout_velocities(unwrapped, sample_every: int, steps: int, seed: int = 0) -> list[np.ndarray] | None:
    """``qvel`` sampled every ``sample_every`` physics steps on a *copy* of the environment under uniform random
    actions, with the environment's own (seeded) resets at episode ends: its reset distribution, actions and
    terminations, for about ``steps`` physics steps. Returns one array ``(T_i, nv)`` per episode, or None if the
    environment cannot be copied."""
    try:
        sim = copy.deepcopy(unwrapped)  # MujocoEnv pickles (and copies) by its constructor arguments
        sim.render_mode = None  # never open a window for the calibration
        adapter = make_adapter(sim)
    except Exception:  # noqa: BLE001 - any failure: the caller falls back to a rollout of the bare model
        return None
    space = sim.action_space
    space.seed(seed)
    hook = adapter.supports_substeps()
    frame_skip = adapter.frame_skip
    episodes: list[np.ndarray] = []
    samples: list[np.ndarray] = []
    counter = [0]

    def record():
        counter[0] += 1
        if counter[0] % sample_every == 0:
            samples.append(np.array(adapter.data.qvel))

    sim.reset(seed=seed)
    samples.append(np.array(adapter.data.qvel))
    for k in range(max(1, int(steps) // frame_skip)):
        if hook:
            with adapter.substeps(record):
                _, _, terminated, truncated, _ = sim.step(space.sample())
        else:
            _, _, terminated, truncated, _ = sim.step(space.sample())
            samples.append(np.array(adapter.data.qvel))
        if terminated or truncated or not np.all(np.isfinite(adapter.data.qvel)):
            episodes.append(np.array(samples))
            sim.reset()
            samples, counter[0] = [np.array(adapter.data.qvel)], 0
    episodes.append(np.array(samples))
    sim.close()
    if not hook and sample_every < frame_skip:  # only end-of-step samples: rescale at the caller's step
        return None
    return [V for V in episodes if np.all(np.isfinite(V))]


#: wrappers that pass ``step``'s observation through unchanged (``gym.make``'s stack): with only these between
#: ``EstimatedVelocity`` and the MuJoCo environment, the sensed observation may be returned by the env's own step
_TRANSPARENT_WRAPPERS = (gym.wrappers.TimeLimit, gym.wrappers.OrderEnforcing, gym.wrappers.PassiveEnvChecker,
                         gym.wrappers.RecordEpisodeStatistics)
#: the same, named by module and class (not imported here: importing Stable-Baselines3 imports torch); SB3's
#: ``make_vec_env`` puts its ``Monitor`` between the environment and ``wrapper_class``
_TRANSPARENT_BY_NAME = {("stable_baselines3.common.monitor", "Monitor")}


def _transparent(wrapper) -> bool:
    """Whether ``wrapper`` (exactly one of the classes above, not a subclass) passes observations through."""
    cls = type(wrapper)
    return cls in _TRANSPARENT_WRAPPERS or (cls.__module__, cls.__qualname__) in _TRANSPARENT_BY_NAME


#: environment id -> (step, reset) observation independence (:func:`observation_independent_step`)
_OBSERVATION_INDEPENDENT: dict[str, tuple[bool, bool]] = {}


def _same(a, b) -> bool:
    """Equal results of two steps: numbers and arrays exactly (NaN equal to NaN), dicts key by key."""
    if isinstance(a, dict) or isinstance(b, dict):
        return (isinstance(a, dict) and isinstance(b, dict) and a.keys() == b.keys()
                and all(_same(a[k], b[k]) for k in a))
    if isinstance(a, (tuple, list)) or isinstance(b, (tuple, list)):
        return (isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)) and len(a) == len(b)
                and all(_same(x, y) for x, y in zip(a, b, strict=True)))
    try:
        return bool(np.array_equal(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64), equal_nan=True))
    except (TypeError, ValueError):  # not numeric (a string, an object): plain equality
        return bool(np.all(a == b))


def observation_independent_step(unwrapped, steps: int = 150, seed: int = 0) -> bool:
    r"""Whether the environment's ``step`` uses its observation only to return it.

    Then the wrapper can have ``step`` return the *sensed* observation (``_get_obs`` replaced for the duration of
    the step) instead of evaluating the environment's observation twice, once at the true state (discarded) and
    once at the sensed state. Checked on copies of the environment (its own seeded resets, random actions, about
    ``steps`` steps): one as is, one whose ``_get_obs`` returns NaN, one whose ``_get_obs`` returns the observation
    plus 1000. Rewards, terminations, truncations and infos must be identical in all three (InvertedPendulum-v5
    terminates on its observation: not independent), and ``_get_obs`` must be called exactly once per step,
    after the physics. Cached per environment id in memory; False if the environment cannot be copied.
    """
    return _observation_independence(unwrapped, steps, seed)[0]


def observation_independent_reset(unwrapped, steps: int = 150, seed: int = 0) -> bool:
    r"""Whether the environment's ``reset`` uses its observation only to return it (and its ``step`` too).

    Then a wrapper that rebuilds the first observation of an episode at the sensed state need not have the
    environment evaluate its own (10-20 us of NumPy calls for InvertedDoublePendulum, paid at every episode end
    of a short-episode environment). The probe of :func:`observation_independent_step`, at each of its resets:
    the reset infos of the three copies must be identical, ``_get_obs`` called exactly once per reset, and the
    steps that follow identical as well.
    """
    return all(_observation_independence(unwrapped, steps, seed))


def _observation_independence(unwrapped, steps: int, seed: int) -> tuple[bool, bool]:
    key = environment_key(unwrapped)
    if key not in _OBSERVATION_INDEPENDENT:
        _OBSERVATION_INDEPENDENT[key] = _probe_observation_independence(unwrapped, steps, seed)
    return _OBSERVATION_INDEPENDENT[key]


def _probe_observation_independence(unwrapped, steps: int, seed: int) -> tuple[bool, bool]:
    """``(step, reset)`` independence (see :func:`observation_independent_step`); ``(False, False)`` if the
    environment cannot be copied or anything unexpected happens."""
    try:
        sims = [copy.deepcopy(unwrapped) for _ in range(3)]
    except Exception:  # noqa: BLE001 - an environment that cannot be copied is not probed, nor intercepted
        return False, False
    calls = []  # (physics done before the call?) per _get_obs call of the unchanged copy
    physics = [False]
    base = sims[0]
    original_obs = type(base)._get_obs
    original_step = type(base)._step_mujoco_simulation

    def counted_obs():
        calls.append(physics[0])
        return original_obs(base)

    def flagged_step(ctrl, n_frames):
        physics[0] = True
        original_step(base, ctrl, n_frames)

    def reset_all(**kwargs) -> bool:
        """Reset the three copies; whether their infos agree and the unchanged one observed exactly once."""
        calls.clear()
        infos = [sim.reset(**kwargs)[1] for sim in sims]
        return len(calls) == 1 and all(_same(infos[0], info) for info in infos[1:])

    base._get_obs, base._step_mujoco_simulation = counted_obs, flagged_step
    sims[1]._get_obs = lambda sim=sims[1]: np.full(np.shape(original_obs(sim)), np.nan)
    sims[2]._get_obs = lambda sim=sims[2]: np.asarray(original_obs(sim), dtype=np.float64) + 1000.0
    try:
        for sim in sims:
            sim.render_mode = None
        reset_independent = reset_all(seed=seed)
        space = base.action_space
        space.seed(seed)
        for _ in range(steps):
            action = space.sample()
            physics[0] = False
            calls.clear()
            results = [sim.step(action)[1:] for sim in sims]
            if calls != [True]:
                return False, False
            if not all(_same(results[0], r) for r in results[1:]):
                return False, False
            if results[0][1] or results[0][2]:
                reset_independent &= reset_all()
        return True, reset_independent
    except Exception:  # noqa: BLE001 - anything unexpected: do not intercept
        return False, False
    finally:
        for sim in sims:
            sim.close()


def calibrated_bounds(unwrapped, adapter, sample_every: int, derivative: int, *, safety: float = 2.0,
                      quantile: float = 0.99, steps: int = 2000, disk: bool = True) -> np.ndarray:
    """Per-dof bounds on the ``derivative``-th derivative of the joint coordinates, sampled every ``sample_every``
    physics steps, cached per environment id (:func:`environment_key`) in memory and, with ``disk``, on disk.

    The velocities come from :func:`rollout_velocities` (a copy of the environment itself: its resets, random
    actions, terminations), or, if the environment cannot be copied, from
    :func:`~smo_gym.wrappers.sensing.calibrate_bounds` on the bare model from its initial state; the bound is
    :func:`~smo_gym.wrappers.sensing.bounds_from_velocities`.
    """
    model = adapter.model
    settings = dict(derivative=int(derivative), every=int(sample_every), frame_skip=adapter.frame_skip,
                    safety=float(safety), quantile=float(quantile), steps=int(steps), v=3)
    key = calibration_key(getattr(adapter, "environment_key", None) or environment_key(unwrapped), model, **settings)
    dt = float(model.opt.timestep) * int(sample_every)

    def compute():
        episodes = rollout_velocities(unwrapped, int(sample_every), int(steps))
        if episodes:
            try:
                return bounds_from_velocities(episodes, dt, derivative=int(derivative), quantile=float(quantile),
                                              safety=float(safety))
            except ValueError:
                pass
        qpos0 = np.array(getattr(unwrapped, "init_qpos", adapter.data.qpos), dtype=float)
        qvel0 = np.array(getattr(unwrapped, "init_qvel", adapter.data.qvel), dtype=float)
        return calibrate_bounds(model, qpos0, qvel0, adapter.frame_skip, int(sample_every),
                                derivative=int(derivative), steps=int(steps), quantile=float(quantile),
                                safety=float(safety))

    return cached_bounds(key, compute, disk=disk)


class SubstepSampler:
    """Collects the live ``qpos`` inside ``frame_skip`` for the fused hot path (``each`` or ``every_k`` is the
    substep callback: one of them runs after every physics step, so they do as little as possible)."""

    __slots__ = ("samples", "n", "count", "every", "qpos")

    def __init__(self, capacity: int, nq: int, every: int):
        self.samples = np.zeros((max(1, capacity), nq))
        self.n = self.count = 0
        self.every = int(every)
        self.qpos = None

    def start(self, qpos: np.ndarray) -> None:
        """A new control period; ``qpos`` is the live configuration's view."""
        self.n = self.count = 0
        self.qpos = qpos

    def each(self) -> None:
        n = self.n
        if n == self.samples.shape[0]:  # an env that steps more than frame_skip frames
            self.samples = np.concatenate([self.samples, np.zeros_like(self.samples)])
        self.samples[n] = self.qpos
        self.n = n + 1

    def every_k(self) -> None:
        self.count += 1
        if self.count % self.every == 0:
            self.each()

    def __getstate__(self):
        return {"samples": self.samples, "n": 0, "count": 0, "every": self.every, "qpos": None}

    def __setstate__(self, state):
        for key, value in state.items():
            setattr(self, key, value)


class EstimatedVelocity(gym.Wrapper, gym.utils.RecordConstructorArgs):
    r"""Replace a MuJoCo environment's true state by measured positions and estimated velocities.

    At every sample (every physics step with ``rate="physics"``) the sensor measures the joint positions; an
    observer estimates the joint velocities from those measurements only. Every observation is then rebuilt by
    the environment's *own* observation function evaluated at the measured ``qpos`` and estimated ``qvel`` on a
    scratch ``MjData`` after ``mj_forward`` (see :mod:`smo_gym.wrappers.adapters`): positions, velocities and
    everything derived from them (Humanoid's ``cinert``/``cvel``/``qfrc_actuator``, Pusher's body positions,
    InvertedDoublePendulum's constraint force) come from the sensed state; the simulation itself, its rewards and
    terminations are untouched. Works for every ``gymnasium.envs.mujoco`` v5 environment and user ``MujocoEnv``
    subclasses, with no per-environment table.

    Parameters
    ----------
    env : gymnasium.Env
        A MuJoCo environment (possibly wrapped).
    sensor : str or smo_gym.sensors.Sensor
        Preset name (:data:`smo_gym.sensors.PRESETS`) or a sensor (copied: each wrapper has its own).
    observer : str or smo_gym.observers.Observer
        Observer name (:data:`smo_gym.observers.OBSERVERS`), with gains from a calibration rollout unless
        ``observer_kwargs`` sets them, or an observer object whose ``dt`` is the sampling step (copied).
    rate : "physics", "env" or int
        Sample every physics step, once per environment step, or every ``k`` physics steps (``k`` divides
        ``frame_skip``).
    observer_kwargs : dict, optional
        Constructor arguments overriding the calibrated defaults (e.g. ``{"lipschitz": 200.0}``).
    positions : {"measured", "filtered"}
        Positions in the observation: the raw measurement or the observer's filtered value.
    contact_forces : {"sensor", "estimated", "zero"}
        Where ``cfrc_ext`` entries come from (see :mod:`smo_gym.wrappers.adapters`; default: separate force
        sensors, i.e. the simulator's values).
    calibration_safety, calibration_quantile, calibration_steps : float, float, int
        Default gains: ``safety * quantile(|z^(r)|)`` per dof over about ``calibration_steps`` physics steps of a
        copy of the environment under random actions, with its own resets (:func:`calibrated_bounds`), cached
        per environment id.
    disk_cache : bool
        Also cache calibrations on disk (``$SMO_GYM_CACHE_DIR`` or ``~/.cache/smo_gym``).

    Attributes
    ----------
    sample_every : int
        Physics steps per sample.
    sample_dt : float
        Sampling step of sensor and observer [s].
    bounds : ndarray, shape (nv,) or None
        Calibrated derivative bounds (None when an observer object was given).

    Notes
    -----
    ``info["smo"]`` holds ``qpos`` and ``qvel`` (true), ``qvel_estimate`` and ``qpos_measured`` at the last
    sample. Observers start from the first measurement at ``reset()`` with zero velocity. The sensor's random
    stream is seeded from ``reset(seed=...)`` (so a vector env's environments, seeded ``seed + i``, get
    different noise); without a seed it continues, or starts from fresh entropy.

    Sampling inside ``frame_skip``: during ``step`` the environment's ``_step_mujoco_simulation`` is replaced
    (on the instance, for the duration of the call) by an identical loop of single ``mj_step`` calls that records
    ``qpos`` after each (:meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.record_substeps`); the
    trajectory, rewards and terminations are bit-identical to the unwrapped environment's (tested on every v5
    environment). The samples of one control period then go through sensor, tangent coordinates and observer in
    one compiled call (:class:`~smo_gym.wrappers.sensing.FusedSensing`, for the observers with a fused driver;
    the others take the general path with the same numbers), which also writes the sensed state into the scratch
    data the observation is evaluated on. Observer parameters are derived at the first reset and kept for later
    episodes (:meth:`~smo_gym.observers.Observer.restart`).

    Pickling follows Gymnasium's MuJoCo environments, which pickle by their constructor arguments (``EzPickle``):
    an unpickled copy is a freshly constructed simulation with this wrapper's configuration, sensor and observer;
    ``reset(seed=...)`` on both gives identical observations.

    Raises
    ------
    TypeError
        ``env`` is not a MuJoCo environment (the message says what is missing); ``rate`` of a wrong type.
    ValueError
        Unknown sensor preset or observer name (the valid ones are listed), ``rate`` not dividing
        ``frame_skip``, bad option values; at run time a non-finite measurement or observation.
    """

    def __init__(self, env: gym.Env, sensor: str | Sensor = "encoder-12bit-noisy",
                 observer: str | Observer = "super-twisting", rate: str | int = "physics",
                 observer_kwargs: dict | None = None, *, positions: str = "measured", contact_forces: str = "sensor",
                 calibration_safety: float = 2.0, calibration_quantile: float = 0.99, calibration_steps: int = 2000,
                 disk_cache: bool = True):
        gym.utils.RecordConstructorArgs.__init__(
            self, sensor=sensor, observer=observer, rate=rate, observer_kwargs=observer_kwargs, positions=positions,
            contact_forces=contact_forces, calibration_safety=calibration_safety,
            calibration_quantile=calibration_quantile, calibration_steps=calibration_steps, disk_cache=disk_cache,
        )
        gym.Wrapper.__init__(self, env)
        if positions not in ("measured", "filtered"):
            raise ValueError(f"expected positions 'measured' or 'filtered', actual value: {positions!r}")
        self.adapter = make_adapter(env, contact_forces=contact_forces)
        model = self.adapter.model
        self.sample_every = resolve_rate(rate, self.adapter.frame_skip)
        if self.sample_every < self.adapter.frame_skip and not self.adapter.supports_substeps():
            raise ValueError(
                f"expected an environment stepping through MujocoEnv._step_mujoco_simulation for rate={rate!r} "
                f"(samples inside frame_skip), actual value: {type(env.unwrapped).__name__} overrides it; "
                "use rate='env'"
            )
        self.sample_dt = float(model.opt.timestep) * self.sample_every
        self.positions = positions
        self.measurement = JointMeasurement(model, copy.deepcopy(make_sensor(sensor)), self.sample_dt)
        self.bounds = None
        if isinstance(observer, Observer):
            if not np.isclose(observer.dt, self.sample_dt, rtol=1e-9, atol=0.0):
                raise ValueError(
                    f"expected an observer with dt equal to the sampling step {self.sample_dt}, "
                    f"actual value: {observer.dt}"
                )
            obs_object = copy.deepcopy(observer)
        else:
            if observer not in OBSERVERS:
                make_observer(observer)  # raises ValueError listing the valid names
            self.bounds = calibrated_bounds(env.unwrapped, self.adapter, self.sample_every,
                                            bound_order(observer, observer_kwargs), safety=calibration_safety,
                                            quantile=calibration_quantile, steps=calibration_steps, disk=disk_cache)
            obs_object = default_observer(observer, self.sample_dt, self.bounds, self.measurement.noise_std(),
                                          observer_kwargs)
        self.estimator = VelocityEstimator(obs_object)
        self._rng: np.random.Generator | None = None
        n_samples = max(1, self.adapter.frame_skip // self.sample_every)
        self._substep_hook = None
        self._live = None
        self._info_slices = SensingInfo.slices(model.nq, model.nv)
        self._sampler = SubstepSampler(n_samples, model.nq, self.sample_every)
        #: the one-compiled-call hot path where it computes exactly what the general path would (decided at
        #: reset, after a subclass has set its estimator)
        self._fused: FusedSensing | None = None
        #: hook making the env's own step return the sensed observation (None: not decided yet; False: not used)
        self._intercept = None
        #: the same for reset, with a zero placeholder (:func:`observation_independent_reset`)
        self._reset_hook = None
        self._pending_smo = None

    @property
    def sensor(self) -> Sensor:
        return self.measurement.sensor

    @property
    def observer(self) -> Observer:
        return self.estimator.observer

    # ---- the sensed observation -----------------------------------------------------------------------------
    def _observation_qpos(self) -> np.ndarray:
        q_meas = self.measurement.measured_qpos()
        if self.positions == "measured":
            return q_meas
        return self.measurement.tangent.to_qpos(q_meas, self.measurement.z_measured, self.estimator.filtered)

    def _observe(self, info: dict) -> np.ndarray:
        qvel_hat = self.estimator.velocity
        q_meas = self.measurement.measured_qpos()
        obs = self.adapter.observation(q_meas if self.positions == "measured" else self._observation_qpos(),
                                       qvel_hat)
        check_finite_observation(obs)
        if self.adapter.unflatten is not None:  # Dict observation spaces (dm_control): the env's own structure
            obs = self.adapter.unflatten(obs)
        data = self.adapter.data
        info["smo"] = SensingInfo.of(data.qpos, data.qvel, qvel_hat, q_meas)
        return obs

    def _observe_fused(self, block: np.ndarray, info: dict):
        """The observation at the sensed state FusedSensing wrote into the scratch data, and ``info["smo"]``."""
        fused = self._fused
        if fused.maps_observation:  # built by the compiled call from the finite sensed state
            obs = fused.observation
        else:
            adapter = self.adapter
            obs = adapter.observe_scratch(fused.copies_inputs)
            if not adapter.checks_observation:
                check_finite_observation(obs)
        if self.adapter.unflatten is not None:  # Dict observation spaces (dm_control)
            obs = self.adapter.unflatten(obs)
        info["smo"] = SensingInfo.from_block(block, self._info_slices)
        return obs

    def _substep_hook_for(self, sampler: SubstepSampler):
        """The adapter's hook that fills ``sampler`` during ``env.step`` (made once per reset)."""
        recorder = getattr(self.adapter, "record_substeps", None)
        if self.sample_every == 1 and recorder is not None:
            return recorder(sampler)  # the recording loop itself: no callback per physics step
        return self.adapter.substeps(sampler.each if self.sample_every == 1 else sampler.every_k)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_substep_hook"] = None  # holds closures over the live simulation; made again on first use
        state["_live"] = None
        state["_fused"] = None  # bound to this instance's arrays; chosen again at the next reset
        state["_intercept"] = None  # a closure over this instance; made again at the next reset
        state["_reset_hook"] = None
        return state

    # ---- Gymnasium API --------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _, info = self._reset_env(seed, options)  # the first observation is rebuilt below, at the sensed state
        if seed is not None:
            self._rng = np.random.default_rng([int(seed) & 0xFFFFFFFFFFFFFFFF, _SEED_SALT])
        elif self._rng is None:
            self._rng = np.random.default_rng()
        self.measurement.reset(self.adapter.data.qpos, self._rng)
        self.estimator.reset(self.measurement.z_measured)
        self._substep_hook = None  # a reset may rebuild the simulation's objects (dm_control's physics)
        data = self.adapter.data
        self._live = (data, data.qpos[None], data.qvel, data.qpos)
        fused = self._fused
        if fused is None or fused.observer is not self.estimator.observer or fused.sensor is not self.sensor:
            self._fused = (FusedSensing(self.measurement, self.estimator, self.adapter, self.positions == "filtered")
                           if FusedSensing.supports(self.measurement, self.estimator, self.adapter) else None)
        if self._fused is not None:
            self._fused.prepare()
            if self._intercept is None:
                self._intercept = self._interception_hook() or False
        return self._observe(info), info

    def _reset_env(self, seed, options, placeholder: bool = True):
        """``self.env.reset(seed=seed, options=options)``; with ``placeholder``, from the second reset on, the
        environment's own first observation is a zero placeholder (:meth:`_zero_observation_hook`) where its reset
        only returns it. The first reset runs as is: environment checkers see its real output."""
        hook = self._reset_hook
        if hook and placeholder:
            with hook:
                result = self.env.reset(seed=seed, options=options)
        else:
            result = self.env.reset(seed=seed, options=options)
        if hook is None:
            self._reset_hook = self._zero_observation_hook("reset") or False
        return result

    def _interception_hook(self, function=None, during: str = "step"):
        """The hook that makes the environment's own ``step`` return the sensed observation (or ``function()``),
        or None: needs an adapter that can replace ``_get_obs``, only observation-preserving wrappers in between,
        and an environment whose step does not use its observation (:func:`observation_independent_step`).
        ``during="reset"``: the hook for ``reset``, which must not use its observation either
        (:func:`observation_independent_reset`)."""
        intercept = getattr(self.adapter, "intercept_observation", None)
        if intercept is None:
            return None
        env, unwrapped = self.env, self.env.unwrapped
        while env is not unwrapped:
            if not _transparent(env):
                return None
            env = env.env
        independent = observation_independent_reset if during == "reset" else observation_independent_step
        if not independent(unwrapped):
            return None
        return intercept(function or self._sensed_observation)

    def _zero_observation_hook(self, during: str):
        """:meth:`_interception_hook` with a zero observation of the observation space's shape and dtype, for an
        observation that is rebuilt at the sensed state anyway (None without a ``Box`` space)."""
        space = self.observation_space
        if not isinstance(space, gym.spaces.Box):
            return None
        shape, dtype = space.shape, space.dtype
        return self._interception_hook(lambda: np.zeros(shape, dtype), during)

    def _sensed_observation(self):
        """``_get_obs`` of the environment during an intercepted step: sense the control period that just ended
        and return the observation at the sensed state (``info["smo"]`` is kept for ``step``)."""
        live = self._live
        sampler = self._sampler
        samples = sampler.samples[:sampler.n] if self.sample_every < self.adapter.frame_skip else live[1]
        block = self._fused.sample(samples, live[2])
        info = {}
        if block is None:  # the samples straddle the sensor's random block: the general path splits them
            self.estimator.observer.run(self.measurement.measure_block(samples))
            obs = self._observe(info)
        else:
            obs = self._observe_fused(block, info)
        self._pending_smo = info["smo"]
        return obs

    def step(self, action):
        """Step the environment, sample its joints (inside ``frame_skip`` if ``rate`` asks), update the observer and
        return the observation at the sensed state.

        Written flat on purpose: every Python operation here costs two to three times its micro-benchmark time
        right after the physics step, and a small model's whole step is ~30 us.
        """
        if self._rng is None:
            raise RuntimeError("expected reset() before step(), actual value: the wrapper was never reset")
        data = self.adapter.data
        live = self._live
        if live is None or live[0] is not data:  # cached views of the live qpos/qvel (a field access makes one)
            live = self._live = (data, data.qpos[None], data.qvel, data.qpos)
            if self._fused is not None:  # its input copies read the live data
                self._fused.prepare()
        intercept = self._intercept
        if intercept and self._fused is not None:  # the env's own step returns the sensed observation
            self._pending_smo = None
            if self.sample_every < self.adapter.frame_skip:
                self._sampler.start(live[3])
                hook = self._substep_hook
                if hook is None:
                    hook = self._substep_hook = self._substep_hook_for(self._sampler)
                with hook, intercept:
                    obs, reward, terminated, truncated, info = self.env.step(action)
            else:
                with intercept:
                    obs, reward, terminated, truncated, info = self.env.step(action)
            if self._pending_smo is None:
                raise RuntimeError("expected the environment's step to call _get_obs after its physics, actual "
                                   "value: it did not (the probe of observation_independent_step said it would)")
            info["smo"] = self._pending_smo
            return obs, reward, terminated, truncated, info
        if self.sample_every < self.adapter.frame_skip:
            sampler = self._sampler
            sampler.start(live[3])
            hook = self._substep_hook
            if hook is None:
                hook = self._substep_hook = self._substep_hook_for(sampler)
            with hook:
                _, reward, terminated, truncated, info = self.env.step(action)
            if sampler.count == 0 and sampler.n == 0:
                raise RuntimeError(
                    "expected the environment to step its physics through MujocoEnv._step_mujoco_simulation, "
                    "actual value: no physics step was observed during step(); use rate='env'"
                )
            samples = sampler.samples[:sampler.n]
        else:
            _, reward, terminated, truncated, info = self.env.step(action)
            samples = live[1]
        fused = self._fused
        if fused is not None:
            block = fused.sample(samples, live[2])
            if block is not None:
                return self._observe_fused(block, info), reward, terminated, truncated, info
            # None: the samples straddle the sensor's random block; the general path splits them
        Z = self.measurement.measure_block(samples)
        if len(Z) == 1:
            self.estimator.update(Z[0])
        elif type(self.estimator) is VelocityEstimator:
            # a control period's samples in one compiled call: Observer.run is update row by row (same kernel,
            # same numbers); subclassed estimators (e.g. with the control input) keep their per-sample update
            self.estimator.observer.run(Z)
        else:
            for z in Z:
                self.estimator.update(z)
        return self._observe(info), reward, terminated, truncated, info
