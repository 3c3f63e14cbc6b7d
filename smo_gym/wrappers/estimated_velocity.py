r"""``EstimatedVelocity``: a Gymnasium MuJoCo environment seen through joint sensors and a velocity observer."""

from __future__ import annotations

import copy
from typing import NamedTuple

import gymnasium as gym
import numpy as np

from .._cache import cached_bounds, calibration_key, stable_repr
from .._validation import check_int_in_range, check_positive, check_real_in_range
from ..calibration import Calibration, bound_order, calibration_from_velocities, default_observer
from ..engine.fused import FusedSensing
from ..engine.measurement import (
    JointMeasurement,
    VelocityEstimator,
    check_finite_observation,
    check_sample_time,
    mean_velocity_span,
    resolve_rate,
)
from ..engine.rollout import model_rollout_velocities
from ..observers import MODEL_BASED_OBSERVERS, OBSERVERS, Observer, make_observer
from ..selection import CANDIDATES, Selection, Trials, auto_observer, candidate_orders, estimates_jointly, select
from ..sensors import Sensor, make_sensor
from ..specs import parse_observer_spec
from .adapters import SubstepRecording, make_adapter
from .rollout import rollout, smooth_random_policy
from .sensing import SensingInfo, check_action, check_seed

__all__ = [
    "EstimatedVelocity",
    "calibrate_environment",
    "calibrated_observer",
    "observation_wrappers",
    "random_episodes",
    "resolve_rate",
    "rollout_velocities",
    "sensed_trials",
]

#: mixed into the user's seed so the sensor stream differs from the environment's own ``np_random``
_SEED_SALT = 0x534D4F


def _reset_stream(seed: int | None, rng: np.random.Generator | None, *salt: int) -> np.random.Generator:
    """A wrapper's random stream after ``reset(seed=seed)``: made from the salted seed, else ``rng`` going on."""
    if seed is not None:
        return np.random.default_rng([int(seed) & 0xFFFFFFFFFFFFFFFF, _SEED_SALT, *salt])
    return np.random.default_rng() if rng is None else rng


#: the seed of the episodes of the calibration, ``"auto"``'s trials and the told filters' fit: a stream of its own,
#: so that evaluations on the seeds users pick (0, 1, 2, ...) never replay them (seed 0 did, sensor noise included)
CALIBRATION_SEED = 0x534D4F43
#: the trials of ``observer="auto"`` run this many times the calibration's physics steps, per scenario: a choice
#: per joint needs more samples than a level does (on Ant and Walker2d, 1x chose 8-9 % worse than 4x)
TRIAL_STEPS = 4


def rollout_velocities(adapter, sample_every: int, steps: int, seed: int = CALIBRATION_SEED) -> list[np.ndarray] | None:
    """``qvel`` of :func:`random_episodes`, one array ``(T_i, nv)`` per finite episode, or None."""
    episodes = random_episodes(adapter, sample_every, steps, seed)
    return None if episodes is None else [episode.qvel for episode in episodes if np.all(np.isfinite(episode.qvel))]


def random_episodes(
    adapter, sample_every: int, steps: int, seed: int = CALIBRATION_SEED, smoothing: float = 0.0
) -> list | None:
    """The :class:`~smo_gym.wrappers.rollout.Episode` list of a copy of the environment under uniform random
    actions (low-passed with ``smoothing``, :func:`~smo_gym.wrappers.rollout.smooth_random_policy`), sampled every
    ``sample_every`` physics steps, with the environment's own (seeded) resets at episode ends: its reset
    distribution, actions and terminations, on the live model
    (:meth:`~smo_gym.wrappers.adapters.MujocoAdapter.copy_environment`: masses or a timestep edited in place
    count), for about ``steps`` physics steps; None if the environment cannot be copied or sampled so often."""
    try:
        sim = adapter.copy_environment()
        sim.render_mode = None  # never open a window for the calibration
        adapter = make_adapter(sim)
    except Exception:
        return None
    if sample_every < adapter.frame_skip and not adapter.supports_substeps():
        sim.close()
        return None  # only end-of-step samples: the caller rescales at its step
    space = sim.action_space
    space.seed(seed)
    policy = (lambda _: space.sample()) if smoothing == 0.0 else smooth_random_policy(space, seed, smoothing)
    env_steps = max(1, int(steps) // adapter.frame_skip)
    episodes = rollout(sim, policy, env_steps, sample_every=sample_every, seed=seed, adapter=adapter)
    sim.close()
    return episodes


#: wrappers that return the observation of the environment beneath them unchanged (exactly these classes)
_PASS_THROUGH = (
    gym.wrappers.TimeLimit, gym.wrappers.OrderEnforcing, gym.wrappers.PassiveEnvChecker,
    gym.wrappers.RecordEpisodeStatistics, gym.wrappers.NormalizeReward, gym.wrappers.StickyAction,
    gym.wrappers.RecordVideo, gym.wrappers.RenderCollection, gym.wrappers.HumanRendering,
)  # fmt: skip
#: the same, named by module and class (not imported here: importing Stable-Baselines3 imports torch); SB3's
#: ``make_vec_env`` puts its ``Monitor`` between the environment and ``wrapper_class``
_PASS_THROUGH_BY_NAME = {("stable_baselines3.common.monitor", "Monitor")}
#: observation wrappers whose observation depends on earlier ones (running statistics, stacks, delays) or on the
#: true simulation (rendered frames): replaying them on the sensed observation would mix true and sensed data
_STATEFUL_OBSERVATIONS = (
    gym.wrappers.NormalizeObservation,
    gym.wrappers.FrameStackObservation,
    gym.wrappers.DelayObservation,
    gym.wrappers.MaxAndSkipObservation,
    gym.wrappers.AddRenderObservation,
)


def _passes_observations_through(wrapper: gym.Wrapper) -> bool:
    """Whether ``wrapper`` cannot change the observations of the environment beneath it: a known pass-through
    class, a reward or action wrapper that keeps its base class's ``step``, or a wrapper that overrides neither
    ``step`` nor ``reset``."""
    cls = type(wrapper)
    if cls in _PASS_THROUGH or (cls.__module__, cls.__qualname__) in _PASS_THROUGH_BY_NAME:
        return True
    for base in (gym.RewardWrapper, gym.ActionWrapper):
        if isinstance(wrapper, base):
            return cls.step is base.step
    if isinstance(wrapper, gym.ObservationWrapper):
        return False
    return cls.step is gym.Wrapper.step and cls.reset is gym.Wrapper.reset


def observation_wrappers(env: gym.Env, *, replay: bool = True) -> tuple[gym.ObservationWrapper, ...]:
    r"""The observation wrappers between a sensing wrapper and the MuJoCo environment, innermost first.

    The sensed observation is built by the MuJoCo environment's own observation function (at the measured
    positions and estimated velocities), so every wrapper of the stack beneath that changes observations must
    be applied to it again: the wrapper's observation is then ``w_k.observation(...w_1.observation(sensed))``,
    exactly what the stack would return at the sensed state. That holds for observation wrappers that are
    functions of the current observation (``TimeAwareObservation``, ``DtypeObservation``, ``FlattenObservation``,
    ``TransformObservation``, ...), which this returns. Wrappers that pass observations through (``TimeLimit``,
    ``RecordEpisodeStatistics``, SB3's ``Monitor``, reward and action wrappers) are skipped.

    Parameters
    ----------
    env : gymnasium.Env
        The environment a sensing wrapper is about to wrap.
    replay : bool
        Whether observation wrappers may be replayed (``False``: the caller needs the bare environment's
        observation, as the vector wrappers' :class:`~smo_gym.wrappers.JointSensor` does).

    Raises
    ------
    TypeError
        ``env`` is already wrapped in a sensing wrapper; or a wrapper beneath keeps state across observations
        (``NormalizeObservation``, ``FrameStackObservation``, ``DelayObservation``, ...) or may change them in a
        way that cannot be replayed (any other wrapper that overrides ``step`` or ``reset``): such a wrapper
        belongs on top of the sensing wrapper, where it sees the sensed observations. The message names it.
    """
    chain = []
    inner = env
    while isinstance(inner, gym.Wrapper):
        name = type(inner).__name__
        if isinstance(inner, EstimatedVelocity):
            raise TypeError(
                f"expected an environment without a sensing wrapper, actual value: {name} is already in the stack; "
                "wrap the environment once"
            )
        if not _passes_observations_through(inner):
            if not replay or not isinstance(inner, gym.ObservationWrapper) or isinstance(inner, _STATEFUL_OBSERVATIONS):
                why = (
                    "keeps state across observations or reads the true simulation"
                    if isinstance(inner, _STATEFUL_OBSERVATIONS)
                    else "changes observations"
                    if isinstance(inner, gym.ObservationWrapper)
                    else "overrides step() or reset()"
                )
                raise TypeError(
                    f"expected only wrappers that pass observations through "
                    f"{'or are functions of the observation ' if replay else ''}beneath the sensing wrapper, "
                    f"actual value: {name} {why}; put it on top instead, e.g. {name}(EstimatedVelocity(env, ...)), "
                    "so that it sees the sensed observations"
                )
            chain.append(inner)
        inner = inner.env
    return tuple(reversed(chain))


def calibrate_environment(
    unwrapped,
    adapter,
    sample_every: int,
    derivative,
    *,
    noise,
    resolution=0.0,
    safety: float = 2.0,
    quantile: float = 0.99,
    steps: int = 2000,
    disk: bool = True,
) -> Calibration:
    """The :class:`~smo_gym.calibration.Calibration` of the joints for the ``derivative``-th derivative (an int or
    a tuple), sampled every ``sample_every`` physics steps: :func:`~smo_gym.calibration.calibration_from_velocities`
    of the velocities of :func:`rollout_velocities` (a copy of the environment itself: its resets, random actions,
    terminations), or, if the environment cannot be copied, of
    :func:`~smo_gym.engine.rollout.model_rollout_velocities` on the bare model from its initial state. The
    levels are cached per environment id (the adapter's ``environment_key``) in memory and, with ``disk``, on disk;
    ``noise`` and ``resolution`` are the sensor's, per dof.
    """
    model = adapter.model
    orders, every = tuple(sorted({int(r) for r in np.atleast_1d(derivative)})), int(sample_every)
    settings = dict(derivative=orders, every=every, frame_skip=adapter.frame_skip, safety=float(safety))
    settings.update(quantile=float(quantile), steps=int(steps), v=8)
    key = calibration_key(adapter.environment_key, model, **settings)
    dt = float(model.opt.timestep) * every

    def levels(episodes):
        found = calibration_from_velocities(episodes, dt, orders, noise=0.0, quantile=quantile, safety=safety)
        return found.as_rows(orders)

    def compute():
        episodes = rollout_velocities(adapter, every, int(steps))
        if episodes:
            try:
                return levels(episodes)
            except ValueError:
                pass
        qpos0 = np.array(getattr(unwrapped, "init_qpos", adapter.data.qpos), dtype=float)
        qvel0 = np.array(getattr(unwrapped, "init_qvel", adapter.data.qvel), dtype=float)
        return levels(model_rollout_velocities(model, qpos0, qvel0, adapter.frame_skip, every, steps=int(steps)))

    return Calibration.from_rows(cached_bounds(key, compute, disk=disk), orders, dt, noise, resolution)


def sensed_trials(adapter, measurement, sample_every: int, steps: int, smoothing: float = 0.0, seed=CALIBRATION_SEED):
    """The episodes of :func:`random_episodes` (``seed``: theirs and the sensor noise's) measured by a copy of the
    :class:`JointMeasurement` ``measurement``'s sensor: :class:`~smo_gym.selection.Trials` for ``"auto"``, or None."""
    sensed = JointMeasurement(adapter.model, copy.deepcopy(measurement.sensor), measurement.dt)
    rng, measured, velocity, inputs = np.random.default_rng([seed, _SEED_SALT]), [], [], []
    for episode in random_episodes(adapter, sample_every, steps, seed, smoothing) or ():
        if len(episode.qpos) > 1 and np.isfinite(episode.qvel).all():
            sensed.reset(episode.qpos[0], rng)
            measured.append(np.vstack([sensed.z_measured, sensed.measure_block(episode.qpos[1:])]))
            velocity.append(episode.qvel)
            inputs.append(episode.ctrl)
    return Trials(tuple(measured), tuple(velocity), tuple(inputs)) if measured else None


#: the action smoothing of the two scenarios ``"auto"`` compares in: the policies of an untrained agent (uniform
#: random actions) and of a trained one (low-passed, ``a = 0.9 a + 0.1 u``)
TRIAL_SMOOTHING = (0.0, 0.9)


class JointCandidate(NamedTuple):
    """A model-based candidate of ``"auto"`` for all joints together, and the model settings it was built with."""

    observer: Observer
    settings: tuple


def calibrated_observer(
    name: str, unwrapped, adapter, measurement: JointMeasurement, sample_every: int, kwargs, joint=None, **how
):
    """The observer ``name`` (or ``"auto"``, :func:`~smo_gym.selection.auto_observer` on :func:`sensed_trials`) with
    gains from :func:`calibrate_environment` (``how``: its ``safety``, ``quantile``, ``steps``, ``disk``), and that
    calibration. The errors ``"auto"`` compares are cached like the calibration. ``joint``: a
    :class:`JointCandidate`, returned (with the selection) where :attr:`~smo_gym.selection.Selection.choice` takes
    it."""
    orders = candidate_orders() if name == "auto" else bound_order(name, kwargs)
    noise, resolution = measurement.noise_std(), measurement.quantization_step()
    calibration = calibrate_environment(
        unwrapped, adapter, sample_every, orders, noise=noise, resolution=resolution, **how
    )
    if name != "auto":
        return default_observer(name, calibration, kwargs), calibration
    span = mean_velocity_span(adapter.model)
    candidates = CANDIDATES + (() if joint is None else (joint.observer.name,))
    settings = {k: v for k, v in how.items() if k != "disk"}  # where the result is kept is not what it depends on
    key = calibration_key(
        adapter.environment_key,
        adapter.model,
        auto=candidates,
        joint=stable_repr(None if joint is None else (joint.settings, vars(joint.observer))),
        sensor=stable_repr(measurement.sensor),
        every=sample_every,
        kwargs=stable_repr(kwargs),
        trial_steps=TRIAL_STEPS,
        calibration=stable_repr(vars(calibration)),  # the errors depend on the gains; v on the candidates' code
        **settings,
        v=9,
    )

    observer = None if joint is None else joint.observer  # compared as the last candidate

    def compute():
        steps = TRIAL_STEPS * how.get("steps", 2000)
        scenes = [sensed_trials(adapter, measurement, sample_every, steps, s) for s in TRIAL_SMOOTHING]
        scenes = [trials for trials in scenes if trials is not None]
        found = select(calibration, scenes or None, mean_over=span, observer_kwargs=kwargs, joint=observer)
        rows = np.concatenate([found.errors, found.bound]).reshape(-1, found.errors.shape[-1])
        return np.vstack([rows, np.full(rows.shape[-1], len(scenes))])

    stored = cached_bounds(key, compute, disk=how.get("disk", True))
    errors, bound = stored[:-1].reshape(2, -1, len(candidates), stored.shape[1])  # the last row: scenarios
    source = "trials" if stored[-1, 0] else "prediction"
    found = Selection(candidates, errors, source, joint=estimates_jointly(observer), bound=bound)
    observer = auto_observer(calibration, mean_over=span, observer_kwargs=kwargs, selection=found, joint=observer)
    return observer, calibration


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
        ``"auto"`` (the default: per joint the candidate of :mod:`smo_gym.selection` that does best on this
        wrapper's own trials, :func:`calibrated_observer`; the choice is ``observer.selection``), an observer name
        (:data:`smo_gym.observers.OBSERVERS`), with gains from a calibration rollout unless
        ``observer_kwargs`` sets them, or a spec of one with options (``"kalman-imm:huber=3"``,
        :func:`smo_gym.specs.parse_observer_spec`; ``observer_kwargs`` override them), or an observer object whose
        ``dt`` is the sampling step (copied). A model-based name (:data:`smo_gym.observers.MODEL_BASED_OBSERVERS`)
        gets a model of the environment's own ``MjModel`` and the action as its input
        (:func:`smo_gym.wrappers.model_based.model_based_observer`).
    rate : "physics", "env" or int
        Sample every physics step, once per environment step, or every ``k`` physics steps (``k`` divides
        ``frame_skip``).
    observer_kwargs : dict, optional
        Constructor arguments overriding the calibrated defaults (e.g. ``{"lipschitz": 200.0}``). For a
        model-based observer also its model's settings: ``mass_scale``, a number (every mass and inertia of the
        observer's model scaled: a model mismatch) or a pair ``(low, high)`` (a scale drawn uniformly at each
        reset, from a stream seeded by ``reset(seed=...)``; the current one is ``observer.dynamics.mass_scale``),
        and ``contact``, ``"unknown"`` or ``"measured"`` (:mod:`smo_gym.mechanics.dynamics`). With
        ``observer="auto"``, ``model=True`` (or a model-based name) makes that observer, with these model
        settings, one more candidate for all joints together (:func:`calibrated_observer`,
        :attr:`smo_gym.selection.Selection.joint`), a filter told the input (``"kalman-imm-input"``) per joint.
    positions : {"measured", "filtered"}
        Positions in the observation: the raw measurement or the observer's filtered value.
    contact_forces : {"sensor", "estimated", "zero"}
        Where ``cfrc_ext`` entries come from (see :mod:`smo_gym.wrappers.adapters`; default: separate force
        sensors, i.e. the simulator's values).
    calibration_safety, calibration_quantile, calibration_steps : float, float, int
        Default gains: worst case ``safety * quantile(|z^(r)|)`` and typical (RMS) level per dof over about
        ``calibration_steps`` physics steps of a copy of the environment under random actions, with its own
        resets (:func:`calibrate_environment`), cached per environment id.
    disk_cache : bool
        Also cache calibrations on disk (``$SMO_GYM_CACHE_DIR`` or ``~/.cache/smo_gym``).

    Attributes
    ----------
    sample_every : int
        Physics steps per sample.
    sample_dt : float
        Sampling step of sensor and observer [s].
    calibration : smo_gym.calibration.Calibration or None
        What the default gains came from (None for an observer object or a model-based observer).
    model_miss_bound, mass_scale_range : ndarray of shape (nv,), tuple or None
        A model-based observer's calibrated bound of its model miss, and the range its mass scale is drawn from.

    Notes
    -----
    ``info["smo"]`` holds ``qpos`` and ``qvel`` (true), ``qvel_estimate`` and ``qpos_measured`` at the last
    sample. Observers start from the first measurement at ``reset()`` with zero velocity. The sensor's random
    stream is seeded from ``reset(seed=...)`` (so a vector env's environments, seeded ``seed + i``, get
    different noise); without a seed it continues, or starts from fresh entropy.

    Sampling inside ``frame_skip``: during ``step`` the environment's ``_step_mujoco_simulation`` is replaced
    (on the instance, for the duration of the call) by an identical loop of single ``mj_step`` calls that records
    ``qpos`` after each (:meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.record_substeps`, the one hook
    into the environment's step); the
    trajectory, rewards and terminations are bit-identical to the unwrapped environment's (tested on every v5
    environment). The samples of one control period then go through sensor, tangent coordinates and observer in
    one compiled call (:class:`~smo_gym.engine.fused.FusedSensing`, for the observers with a fused driver;
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

    def __init__(
        self,
        env: gym.Env,
        sensor: str | Sensor = "encoder-12bit-noisy",
        observer: str | Observer = "auto",
        rate: str | int = "physics",
        observer_kwargs: dict | None = None,
        *,
        positions: str = "measured",
        contact_forces: str = "sensor",
        calibration_safety: float = 2.0,
        calibration_quantile: float = 0.99,
        calibration_steps: int = 2000,
        disk_cache: bool = True,
    ):
        gym.utils.RecordConstructorArgs.__init__(
            self,
            sensor=sensor,
            observer=observer,
            rate=rate,
            observer_kwargs=observer_kwargs,
            positions=positions,
            contact_forces=contact_forces,
            calibration_safety=calibration_safety,
            calibration_quantile=calibration_quantile,
            calibration_steps=calibration_steps,
            disk_cache=disk_cache,
        )
        gym.Wrapper.__init__(self, env)
        check_positive("calibration_safety", calibration_safety)
        check_real_in_range("calibration_quantile", calibration_quantile, 0.0, 1.0, low_open=True)
        check_int_in_range("calibration_steps", calibration_steps, 1, 10**9)
        if not isinstance(disk_cache, (bool, np.bool_)):
            raise TypeError(f"expected disk_cache to be True or False, actual value: {disk_cache!r}")
        if observer_kwargs is not None and not isinstance(observer_kwargs, dict):
            raise TypeError(f"expected observer_kwargs to be a dict or None, actual value: {observer_kwargs!r}")
        self._action_shape = tuple(env.action_space.shape)
        #: the observation wrappers beneath, innermost first, applied to every sensed observation
        self._observation_wrappers = observation_wrappers(env, replay=self._replays_observation_wrappers)
        if positions not in ("measured", "filtered"):
            raise ValueError(f"expected positions 'measured' or 'filtered', actual value: {positions!r}")
        if isinstance(observer, str) and ":" in observer:  # a spec: the name, and its options under observer_kwargs
            observer, options = parse_observer_spec(observer)
            observer_kwargs = {**options, **(observer_kwargs or {})}
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
        #: the :class:`~smo_gym.calibration.Calibration` the default gains came from (None for a given observer)
        self.calibration: Calibration | None = None
        self.model_miss_bound = self.mass_scale_range = None
        model_based = isinstance(observer, str) and observer in MODEL_BASED_OBSERVERS
        joint = None  # observer="auto" with a model: the model-based candidate for all joints together
        how = (calibration_steps, calibration_quantile, calibration_safety)
        if isinstance(observer, str) and observer == "auto" and (observer_kwargs or {}).get("model"):
            from .model_based import joint_candidate  # it imports this module

            joint, built, observer_kwargs = joint_candidate(self.adapter, self.measurement, observer_kwargs, *how)
        if model_based:
            from .model_based import model_based_observer  # it imports this module

            built = model_based_observer(observer, self.adapter, self.measurement, observer_kwargs, *how)
            observer, self.model_miss_bound, self.mass_scale_range = built
        if isinstance(observer, Observer):
            if self.measurement.wraps and not np.array_equal(
                np.broadcast_to(np.asarray(observer.wrap, dtype=bool), self.measurement.angular.shape),
                self.measurement.angular,
            ):
                raise ValueError(
                    "expected an observer with wrap on the angular channels for a sensor that reports single-turn "
                    f"angles (wrap={self.measurement.angular.tolist()}), actual value: wrap={observer.wrap!r}"
                )
            if not np.isclose(observer.dt, self.sample_dt, rtol=1e-9, atol=0.0):
                raise ValueError(
                    f"expected an observer with dt equal to the sampling step {self.sample_dt}, "
                    f"actual value: {observer.dt}"
                )
            obs_object = observer if model_based else copy.deepcopy(observer)
        else:
            if not (isinstance(observer, str) and observer == "auto") and observer not in OBSERVERS:
                make_observer(observer)  # raises ValueError listing the valid names
            if self.measurement.wraps:  # single-turn angles: the innovation takes the shortest angular difference
                observer_kwargs = {"wrap": self.measurement.angular, **(observer_kwargs or {})}
            obs_object, self.calibration = calibrated_observer(
                observer,
                env.unwrapped,
                self.adapter,
                self.measurement,
                self.sample_every,
                observer_kwargs,
                safety=calibration_safety,
                quantile=calibration_quantile,
                steps=calibration_steps,
                disk=disk_cache,
                joint=joint,
            )
        if joint is not None and obs_object is joint.observer:
            self.model_miss_bound, self.mass_scale_range = built.model_miss_bound, built.mass_scale_range
        if obs_object.takes_input:  # given the action that acted over the sample interval (order 1: as it is)
            from .model_based import InputAwareEstimator  # it imports this module

            self.estimator = InputAwareEstimator(obs_object, self.adapter)
        else:  # MuJoCo's qvel is the mean velocity over the last physics step unless it integrates with RK4
            self.estimator = VelocityEstimator(obs_object, mean_over=mean_velocity_span(model))
        self._rng: np.random.Generator | None = None
        self._model_rng: np.random.Generator | None = None
        n_samples = max(1, self.adapter.frame_skip // self.sample_every)
        self._substep_hook = self._live = None
        self._info_slices = SensingInfo.slices(model.nq, model.nv)
        self._recording = SubstepRecording(self.sample_every, {"qpos": model.nq}, n_samples)
        #: the one-compiled-call hot path where it computes exactly what the general path would (decided at
        #: reset, after a subclass has set its estimator)
        self._fused: FusedSensing | None = None

    #: whether observation wrappers beneath are replayed on the sensed observation (:func:`observation_wrappers`)
    _replays_observation_wrappers = True
    #: why step() needs a reset first (a copy says it is one)
    _unreset = "the wrapper was never reset"
    #: whether the last step ended the episode
    _ended = False
    #: ``data.time`` at the reset, until the episode's first step (at ``rate="env"``) is checked against the sampling
    _start_time = None

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

    def _wrap(self, obs):
        """The bare environment's observation through the observation wrappers beneath, innermost first."""
        if self.adapter.unflatten is not None:  # Dict observation spaces (dm_control): the env's own structure
            obs = self.adapter.unflatten(obs)
        for wrapper in self._observation_wrappers:
            obs = wrapper.observation(obs)
        return obs

    def _observe(self, info: dict, clean) -> np.ndarray:
        """The observation at the sensed state (general path), and ``info["smo"]`` with the ``clean`` one."""
        qvel_hat = self.estimator.velocity
        q_meas = self.measurement.measured_qpos()
        obs = self.adapter.observation(q_meas if self.positions == "measured" else self._observation_qpos(), qvel_hat)
        check_finite_observation(obs)
        data = self.adapter.data
        info["smo"] = SensingInfo.of(data.qpos, data.qvel, qvel_hat, q_meas, clean)
        return self._wrap(obs)

    def _observe_fused(self, block: np.ndarray, info: dict, clean):
        """The observation at the sensed state FusedSensing wrote into the scratch data, and ``info["smo"]``."""
        fused = self._fused
        if fused.maps_observation:  # built by the compiled call from the finite sensed state
            obs = fused.observation
        else:
            evaluation = fused.evaluation
            obs = evaluation.observe_scratch(fused.copies_inputs)
            if not evaluation.checks_observation:
                check_finite_observation(obs)
        info["smo"] = SensingInfo.from_block(block, self._info_slices, clean)
        return self._wrap(obs)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_substep_hook"] = None  # holds closures over the live simulation; made again on first use
        state["_live"] = None
        state["_fused"] = None  # bound to this instance's arrays; chosen again at the next reset
        if self._rng is not None:  # mid-episode: the state the copy's simulation must be in to go on
            data = self.adapter.data
            state["_simulation"] = (data.qpos.copy(), data.qvel.copy())
        return state

    def __setstate__(self, state):
        simulation = state.pop("_simulation", None)
        self.__dict__.update(state)
        data = self.adapter.data
        if simulation is not None and not (
            np.array_equal(simulation[0], data.qpos) and np.array_equal(simulation[1], data.qvel)
        ):  # Gymnasium's MuJoCo envs copy by their constructor arguments: a fresh simulation, which the sensor's
            # and the observer's state do not describe; going on would estimate a jump that never happened
            self._rng = None
            self._unreset = "a copy whose environment was rebuilt from its constructor (its simulation is new)"

    # ---- Gymnasium API --------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = check_seed(seed)
        clean, info = self.env.reset(seed=seed, options=options)
        rng, self._rng, self._unreset = _reset_stream(seed, self._rng), None, "its last reset raised"  # until done
        if self.mass_scale_range is not None:  # a new model mismatch per episode, on a stream of its own
            self._model_rng = _reset_stream(seed, self._model_rng, 1)
            self.observer.dynamics.set_mass_scale(self._model_rng.uniform(*self.mass_scale_range))
        self.measurement.reset(self.adapter.data.qpos, rng, self.adapter.model)  # a model rebuilt, a copy's
        self._ended = False
        self.estimator.reset(self.measurement.z_measured)
        if self.adapter.evaluation is not None:  # the observation's compiled shortcuts may read a goal drawn here
            self.adapter.evaluation.verify(self.adapter.model)
        self._substep_hook = None  # a reset may rebuild the simulation's objects (dm_control's physics)
        data = self.adapter.data
        self._live = (data, data.qpos[None], data.qvel, data.qpos)
        self._start_time = data.time  # rate="env": the first step's physics steps are checked against the sampling
        fused = self._fused
        if fused is None or fused.observer is not self.estimator.observer or fused.sensor is not self.sensor:
            self._fused = (
                FusedSensing(self.measurement, self.estimator, self.adapter, self.positions == "filtered")
                if FusedSensing.supports(self.measurement, self.estimator, self.adapter)
                else None
            )
        if self._fused is not None:
            self._fused.prepare()
        self._rng = rng
        return self._observe(info, clean), info

    def step(self, action):
        """Step the environment, sample its joints (inside ``frame_skip`` if ``rate`` asks), update the observer and
        return the observation at the sensed state (``info["smo"]["observation"]`` is the environment's own).

        Written flat on purpose: every Python operation here costs two to three times its micro-benchmark time
        right after the physics step, and a small model's whole step is ~30 us.
        """
        if self._rng is None:
            raise RuntimeError(f"expected reset() before step(), actual value: {self._unreset}")
        if self._ended and self.adapter.restarts_when_stepped_after_end:
            raise RuntimeError("expected reset() after the episode ended, actual value: step() (the environment would "
                               "start a new episode the observer takes for a jump)")  # fmt: skip
        check_action(action, self._action_shape)
        data = self.adapter.data
        live = self._live
        if live is None or live[0] is not data:  # cached views of the live qpos/qvel (a field access makes one)
            if self._fused is not None:  # its input copies read the live data (and it checks the data's size)
                self._fused.prepare()
            live = self._live = (data, data.qpos[None], data.qvel, data.qpos)
        if self.sample_every < self.adapter.frame_skip:
            recording = self._recording
            recording.start()
            hook = self._substep_hook
            if hook is None:
                hook = self._substep_hook = self.adapter.record_substeps(recording)
            with hook:
                clean, reward, terminated, truncated, info = self.env.step(action)
            if recording.n == 0:
                raise RuntimeError(
                    f"expected {self.sample_every} or more physics steps per step() through "
                    f"MujocoEnv._step_mujoco_simulation, actual value: {recording.count}; use rate='env'"
                )
            samples = recording.rows["qpos"][: recording.n]
            samples[-1] = live[3]  # the step's end: what the environment did after its physics counts (a re-centring)
        else:
            clean, reward, terminated, truncated, info = self.env.step(action)
            samples = live[1]
            if self._start_time is not None:  # once an episode: a frame_skip edited since, an action repeated inside
                check_sample_time(data.time - self._start_time, self.sample_dt)
                self._start_time = None
        self._ended = terminated or truncated
        fused = self._fused
        if fused is not None:
            block = fused.sample(samples, live[2])
            if block is not None:
                return self._observe_fused(block, info, clean), reward, terminated, truncated, info
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
        return self._observe(info, clean), reward, terminated, truncated, info
