r"""Vectorized sensing: one batched observer call for all environments of a vector env (``rate="env"``).

The per-environment :class:`~smo_gym.wrappers.EstimatedVelocity` runs one observer per environment. With ``n``
environments stepped in lock step, the observers can run as *one* observer over a batch: its state has shape
``(n_envs, n_dofs, ...)`` (leading batch dimension, :class:`smo_gym.observers.Observer` supports any), one
compiled call updates every environment, and ``reset(y0, mask=...)`` restarts one environment alone.

The work splits in two halves:

:class:`JointSensor` (in each sub-environment, also inside a ``SubprocVecEnv`` / ``AsyncVectorEnv`` worker)
    the sensor with its own random stream (seeded like :class:`EstimatedVelocity`), the MuJoCo state and the
    environment's observation function. After every ``step``/``reset`` it measures the joint positions and puts
    the measured tangent coordinates in ``info["smo_z"]`` (so measurements travel back with the step results,
    no extra round trip); ``observe(velocity, filtered)`` rebuilds the observation from the measured positions
    and a given velocity estimate. When an episode ends, it keeps a copy of the final ``MjData`` and
    measurement, so the terminal observation can be rebuilt after the environment was already reset.
:class:`~smo_gym.wrappers.sb3.VecEstimatedVelocity` (SB3) and :class:`VectorEstimatedVelocity` (Gymnasium)
    the batched observer: stack the ``n`` measurements, one ``update``, masked restarts, then rebuild the
    observations (one parallel round trip to all workers with ``SubprocVecEnv`` / ``AsyncVectorEnv``).

In-process (``DummyVecEnv``, ``SyncVectorEnv``) the sensors keep their streams in the rows of one
:class:`~smo_gym.engine.batch.MeasurementBatch`, which measures every environment that goes on in one compiled
call (a :class:`JointSensor` measures only resets and an episode's last sample), and the observations are built
for all environments at once (a clipped selection of the state, or entries gathered from ``MjData``).

Measurements and observations are computed with exactly the arithmetic of :class:`EstimatedVelocity` (each sensor
on its own random stream), and channels of a batched observer are independent, so the vectorized wrappers
reproduce per-environment wrappers at ``rate="env"`` with the same seeds bit for bit (tested to 1e-12).

Autoreset
---------
SB3 (``DummyVecEnv``, ``SubprocVecEnv``) resets a finished environment inside the same ``step``:
``infos[i]["terminal_observation"]`` holds the finished episode's last observation and the returned observation
is the new episode's first. :class:`VecEstimatedVelocity` rewrites both: the terminal observation from the
finished episode's last measurement and its estimate after the last update, the new one from the new first
measurement, where that environment's observer restarts (``reset(mask=dones)``). Gymnasium's modes
(``metadata["autoreset_mode"]``) are handled by :class:`VectorEstimatedVelocity`: ``next-step`` (restart at the
step after the end, from the reset's measurement), ``same-step`` (as SB3, with ``infos["final_obs"]``) and
``disabled`` (restart on ``reset(options={"reset_mask": ...})``).

Cost with subprocesses
----------------------
With a ``SubprocVecEnv`` the observation rebuild must run where the MuJoCo state is, so each step costs one
extra parallel ``env_method`` round trip (pipe + pickle of the ``(n_envs, nv)`` estimates and the observations)
on top of SB3's own; ``scripts/bench_rl_throughput.py`` measures it against per-environment wrappers inside the
workers (which need no round trip). Prefer per-environment wrappers with subprocesses and ``rate="physics"``;
the batched wrapper pays off with ``DummyVecEnv`` (no process boundary).
"""

from __future__ import annotations

import copy
import inspect
import uuid

import gymnasium as gym
import mujoco
import numpy as np

from ..engine.batch import BatchedSensing, MeasurementBatch
from ..engine.measurement import check_finite_observation, check_sample_time
from ..engine.scratch import GatheredObservations, copy_observed_fields, shared_selection
from ..specs import needs_model
from .estimated_velocity import EstimatedVelocity, _reset_stream
from .sensing import check_action, check_seed

__all__ = ["JointSensor", "VectorEstimatedVelocity", "check_vector_rate", "sensing_config", "stack_samples"]


def sensing_config(sensor="encoder-12bit-noisy", observer="auto", observer_kwargs=None, **options) -> dict:
    """The sensing options (those of :class:`EstimatedVelocity` except ``rate``) as a dict: its keyword-only
    ``options``, the missing ones at its defaults."""
    parameters = inspect.signature(EstimatedVelocity).parameters
    defaults = {name: p.default for name, p in parameters.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    unknown = sorted(set(options) - set(defaults))
    if unknown:
        raise TypeError(f"expected options of EstimatedVelocity ({', '.join(defaults)}), actual value: {unknown}")
    return dict(sensor=sensor, observer=observer, observer_kwargs=observer_kwargs, **{**defaults, **options})


def check_vector_rate(rate) -> None:
    """The vector wrappers sample once per environment step: ``rate`` must be ``"env"`` (a typed error says where
    physics-rate sampling is)."""
    if isinstance(rate, str) and rate == "env":
        return
    raise ValueError(
        f"expected rate='env' for a vector wrapper (one batched observer update per vector step), actual value: "
        f"{rate!r}; to sample inside frame_skip, wrap each environment instead: "
        "gymnasium.make_vec(id, wrappers=[functools.partial(EstimatedVelocity, rate='physics')]) or "
        "make_vec_env(id, wrapper_class=EstimatedVelocity, wrapper_kwargs={'rate': 'physics'})"
    )


class JointSensor(EstimatedVelocity):
    r"""The sub-environment half of the vectorized wrappers: measure ``qpos`` once per step, rebuild observations.

    Same constructor as :class:`EstimatedVelocity` without ``rate`` (always ``"env"``). It does *not* estimate:
    it returns the environment's own observation unchanged and adds ``info["smo_z"]``, shape ``(nv,)``, the
    measured tangent coordinates of the sample (and ``info["smo"]`` with the true ``qpos``/``qvel``). The owner
    (:class:`VecEstimatedVelocity`, :class:`VectorEstimatedVelocity`) runs the observer on those measurements
    and calls :meth:`observe`.

    Attributes
    ----------
    token : str
        A random identifier; the vector wrappers map tokens to environment indices, so one broadcast call can
        carry every environment's estimate (``observe_rows``).
    batched : bool
        Set by an in-process owner that measures this environment's steps with the others'
        (:class:`~smo_gym.engine.batch.MeasurementBatch`): a step that does not end the episode then only keeps
        the environment's observation, :attr:`step_observation`.
    """

    def __init__(
        self,
        env: gym.Env,
        sensor="encoder-12bit-noisy",
        observer="auto",
        observer_kwargs=None,
        *,
        rate="env",
        **kwargs,
    ):
        check_vector_rate(rate)
        if needs_model(observer, observer_kwargs):  # one batched update per vector step has no actions
            raise ValueError(
                f"expected a model-free observer for a vector wrapper, actual value: {observer!r}"
                f"{' with a model' if observer == 'auto' else ''}; wrap each environment instead: "
                f"gymnasium.make_vec(id, wrappers=[functools.partial(EstimatedVelocity, observer={observer!r}, "
                "observer_kwargs=...)])"
            )
        super().__init__(env, sensor, observer, "env", observer_kwargs, **kwargs)
        self.config = sensing_config(sensor, observer, observer_kwargs, **kwargs)
        self.token = uuid.uuid4().hex
        #: put the measurement and the true state in ``info`` (needed across a process boundary; an in-process
        #: owner reads :attr:`z_step`, :attr:`z_reset` and :attr:`smo` instead, and saves SB3's deepcopy of infos)
        self.emit_info = True
        self.batched = False
        self.step_observation = None
        self.z_step = self.z_reset = None
        self._reset_last = False
        #: the true state, measured configuration and clean observation of the last step's and of the last
        #: reset's sample (:meth:`_record`)
        self.smo_step = self.smo_reset = None
        self._terminal = None

    #: the owner rebuilds observations from the bare environment's own function: nothing to replay beneath
    _replays_observation_wrappers = False

    # ---- measurements ---------------------------------------------------------------------------------------
    def _record(self, clean, info: dict) -> dict:
        """The sample's true state, measured configuration and the environment's own (clean) observation, for the
        owner's ``info["smo"]`` (:class:`~smo_gym.wrappers.sensing.SensingInfo`, which adds the estimate)."""
        data = self.adapter.data
        smo = {
            "qpos": data.qpos.copy(),
            "qvel": data.qvel.copy(),
            "qpos_measured": np.array(self.measurement.measured_qpos()),
            "observation": clean,
        }
        if self.emit_info:
            info["smo"] = smo
        return smo

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = check_seed(seed)
        obs, info = self.env.reset(seed=seed, options=options)
        rng, self._rng, self._unreset = _reset_stream(seed, self._rng), None, "its last reset raised"  # until done
        self.measurement.reset(self.adapter.data.qpos, rng, self.adapter.model)  # a model rebuilt, a copy's
        self._start_time = self.adapter.data.time  # the episode's first step is checked against the sampling
        if self.adapter.evaluation is not None:  # the observation's compiled shortcuts may read a goal drawn here
            self.adapter.evaluation.verify(self.adapter.model)
        self.z_reset = np.array(self.measurement.z_measured, dtype=np.float64)
        self._reset_last = True
        self.smo_reset = self._record(obs, info)
        if self.emit_info:
            info["smo_z"] = self.z_reset
        self._rng = rng
        return obs, info

    def step(self, action):
        if self._rng is None:
            raise RuntimeError(f"expected reset() before step(), actual value: {self._unreset}")
        check_action(action, self._action_shape)
        self._terminal = None  # kept across the autoreset that follows an episode's end, dropped here
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._start_time is not None:  # once an episode: a frame_skip edited since, an action repeated inside
            check_sample_time(self.adapter.data.time - self._start_time, self.sample_dt)
            self._start_time = None
        self._reset_last = False
        if self.batched and not (terminated or truncated):  # the owner measures this sample with the others'
            self.step_observation = obs
            return obs, reward, terminated, truncated, info
        data = self.adapter.data
        z = self.measurement.measure_block(data.qpos[None])[0]
        self.z_step = np.array(z, dtype=np.float64)
        self.smo_step = self._record(obs, info)
        if self.emit_info:
            info["smo_z"] = self.z_step
        if terminated or truncated:
            # the environment will be reset before the owner rebuilds the terminal observation: keep what the
            # observation reads from the live data (the controller's inputs and contact forces)
            self._terminal = (
                self._snapshot(data),
                self.measurement.measured_qpos().copy(),
                np.array(self.measurement.z_measured, dtype=np.float64),
            )
        return obs, reward, terminated, truncated, info

    def _snapshot(self, data):
        """The fields an observation reads from the live data, copied into a preallocated ``MjData``
        (:func:`~smo_gym.engine.scratch.copy_observed_fields`)."""
        if getattr(self, "_snap", None) is None:
            self._snap = mujoco.MjData(self.adapter.model)
        return copy_observed_fields(data, self._snap)

    # ---- observations ---------------------------------------------------------------------------------------
    def _positions(self, q_meas, z_meas, filtered) -> np.ndarray:
        if self.positions == "measured" or filtered is None:
            return q_meas
        return self.measurement.tangent.to_qpos(q_meas, z_meas, filtered)

    def observe(self, velocity: np.ndarray, filtered: np.ndarray | None = None, terminal: bool = False) -> np.ndarray:
        """Observation at the measured positions (or ``filtered`` ones, see ``positions``) and ``velocity``.

        Parameters
        ----------
        velocity : ndarray, shape (nv,)
            Velocity estimate.
        filtered : ndarray, shape (nv,), optional
            The observer's filtered tangent coordinates (used with ``positions="filtered"``).
        terminal : bool
            Evaluate at the last sample of the episode that just ended (the environment was reset since).
        """
        if terminal:
            if self._terminal is None:
                raise RuntimeError("expected an episode that just ended, actual value: no terminal state kept")
            data, q_meas, z_meas = self._terminal
            unwrapped = self.adapter.env
            live = unwrapped.data
            unwrapped.data = data  # the adapter copies the controller's inputs (ctrl, time, ...) from here
            try:
                obs = self.adapter.observation(self._positions(q_meas, z_meas, filtered), velocity)
            finally:
                unwrapped.data = live
        else:
            obs = self.adapter.observation(
                self._positions(self.measurement.measured_qpos(), self.measurement.z_measured, filtered), velocity
            )
        if not self.adapter.checks_observation:  # else the adapter's compiled gather has checked it
            check_finite_observation(obs)
        return obs

    def observe_rows(self, index: dict, velocity, filtered, terminal_velocity, terminal_filtered, terminal_mask):
        """Broadcast form of :meth:`observe` for vector envs: ``(observation, terminal_observation or None)`` of
        this environment's row, ``index[token]``."""
        if (i := index.get(self.token)) is None:
            raise ValueError(f"expected an index with this sensor's token {self.token!r}, actual value: {index!r:.80}")
        f = None if filtered is None else filtered[i]
        obs = self.observe(velocity[i], f)
        term = None
        if terminal_mask is not None and terminal_mask[i]:
            term = self.observe(
                terminal_velocity[i], None if terminal_filtered is None else terminal_filtered[i], terminal=True
            )
        return obs, term

    def prototype(self):
        """``(estimator, config, token)``: an un-reset copy of the velocity estimator (the observer this
        environment's sensing calibrated, and how its velocity is reported), the sensing options and :attr:`token`."""
        return copy.deepcopy(self.estimator), dict(self.config), self.token

    def __getstate__(self):
        state = super().__getstate__()
        state["batched"] = False  # a copy's sensor has a stream of its own: its owner batches it again
        return state


def _find_sensor(env) -> JointSensor | None:
    while isinstance(env, gym.Wrapper):
        if isinstance(env, JointSensor):
            return env
        env = env.env
    return None


def attach_sensors(envs: list, config: dict | None) -> list[JointSensor]:
    """The :class:`JointSensor` of every in-process sub-environment, wrapping (in place) those that lack one."""
    sensors = []
    for i, env in enumerate(envs):
        sensor = _find_sensor(env)
        if sensor is None:
            sensor = JointSensor(env, **(config or sensing_config()))
            envs[i] = sensor
        sensors.append(sensor)
    return sensors


class _Sensing:
    """The batched observer and the bookkeeping both vector wrappers share."""

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_plan_cache", None)  # compiled entry points and this process's addresses: made again when used
        state["_batch"] = state["_together"] = None  # share the sensors' arrays (pickled with them): made again
        return state

    def _check_batch(self, actions, action_shape: tuple[int, ...]) -> None:
        """Every environment's action, checked before any environment steps (a refused row would otherwise leave
        the ones before it stepped, unknown to the observer)."""
        check_action(actions, (self.n_envs, *action_shape))

    def _call_envs(self, name: str, *args) -> list:  # pragma: no cover - provided by the vector wrappers
        """``getattr(env_i, name)(*args)`` for every sub-environment, in order."""
        raise NotImplementedError

    def _all_have(self, name: str) -> bool:  # pragma: no cover - provided by the vector wrappers
        """Whether every sub-environment's wrapper stack has the attribute ``name`` (asked without raising in the
        workers, so a missing :class:`JointSensor` gives one error here, not one traceback per worker)."""
        raise NotImplementedError

    def _setup_sensing(self, config: dict, n_envs: int, sensors) -> None:
        # sensors: the in-process JointSensor objects, measured together (MeasurementBatch); or None across a
        # process boundary, and in-process where the measurements cannot share a batch: then each JointSensor
        # measures its steps and rebuilds its observation through _call_envs, as in a worker
        if sensors is not None and not (
            all(isinstance(s.observation_space, gym.spaces.Box) for s in sensors)
            and MeasurementBatch.supports([s.measurement for s in sensors])
        ):
            sensors = None
        self._local = sensors
        #: the in-process environments' MeasurementBatch and their BatchedSensing (None where it does not serve
        #: the observer), made at the first reset (:meth:`_local_batch`)
        self._batch = self._together = None
        self.__dict__.pop("_selection_cache", None)
        self.__dict__.pop("_plan_cache", None)
        if sensors is not None:
            protos = [s.prototype() for s in sensors]
            tokens = [s.token for s in sensors]
            for s in sensors:
                s.emit_info = False
        else:
            if not self._all_have("observe_rows"):
                raise TypeError(
                    "expected every sub-environment wrapped in smo_gym.wrappers.JointSensor (with a process "
                    "boundary the observation must be rebuilt where the MuJoCo state is), actual value: no "
                    "JointSensor found; build the vector env with "
                    "make_vec_env(env_id, wrapper_class=JointSensor, wrapper_kwargs=sensing_config(...)) or "
                    "gymnasium.make_vec(env_id, wrappers=[functools.partial(JointSensor, ...)])"
                )
            protos = list(self._call_envs("prototype"))
            tokens = [p[2] for p in protos]
        configs, steps = [p[1] for p in protos], [p[0].observer.dt for p in protos]  # one batched observer, one dt
        if any(c != configs[0] for c in configs) or len(set(steps)) > 1:
            raise ValueError(f"expected the same sensing and sample step in every sub-environment, actual value: "
                             f"{configs}, sample steps {steps}")  # fmt: skip
        if config is not None and config != configs[0]:
            raise ValueError(
                f"expected the sub-environments' JointSensor to have the wrapper's sensing {config}, actual value: "
                f"{configs[0]}"
            )
        self.config = configs[0]
        self.positions = self.config["positions"]
        self.estimator = protos[0][0]
        self.observer = self.estimator.observer
        self.n_envs = n_envs
        self._index = {t: i for i, t in enumerate(tokens)}

    def _observe_all(
        self, estimate, positions=None, terminal_estimate=None, terminal_mask=None
    ) -> tuple[np.ndarray, list]:
        """Every environment's observation at its measured positions (``positions`` ``(n_envs, nq)`` in-process,
        :meth:`_local_positions`) and the estimate, and the terminal observations where ``terminal_mask``."""
        vel = self.estimator.velocity_of(estimate)
        filt = estimate[..., 0] if self.positions == "filtered" else None
        tvel = None if terminal_estimate is None else self.estimator.velocity_of(terminal_estimate)
        tfilt = None if terminal_estimate is None or self.positions != "filtered" else terminal_estimate[..., 0]
        if self._local is not None:
            selection = self._selection()
            if selection is not None:  # every observation is the same clipped selection: one NumPy expression
                index, low, high = selection
                obs = np.concatenate((positions, vel), axis=1).take(index, axis=1)
                np.maximum(obs, low, out=obs)
                return np.minimum(obs, high, out=obs), self._terminal_observations(tvel, terminal_mask)
            plan = self._entries_plan()
            if plan is not None:  # every observation is gathered from MjData entries: compiled calls, no _get_obs
                return plan.observe(positions, vel), self._terminal_observations(tvel, terminal_mask)
            rows = []
            for i, s in enumerate(self._local):
                obs = s.observe(vel[i], None if filt is None else filt[i])
                term = None
                if terminal_mask is not None and terminal_mask[i]:
                    term = s.observe(tvel[i], None if tfilt is None else tfilt[i], terminal=True)
                rows.append((obs, term))
        else:
            rows = self._call_envs("observe_rows", self._index, vel, filt, tvel, tfilt, terminal_mask)
        obs = np.stack([r[0] for r in rows])
        return obs, [r[1] for r in rows]

    def _terminal_observations(self, velocity, mask) -> list:
        """The in-process environments' terminal observations where ``mask`` (else None), ``positions="measured"``."""
        terms = [None] * len(self._local)
        if mask is not None:
            for i in np.flatnonzero(mask):
                terms[i] = self._local[i].observe(velocity[i], None, terminal=True)
        return terms

    def _selection(self):
        """``(index, low, high)`` when the in-process environments' observations are all the same clipped selection
        of the measured positions and estimated velocities (:func:`~smo_gym.engine.scratch.shared_selection`,
        ``positions="measured"``), else None; decided again whenever a reset dropped or re-probed one's selection."""
        evaluations = [s.adapter.evaluation for s in self._local]
        maps = [None if e is None else e.observation_map for e in evaluations]
        cache = self.__dict__.get("_selection_cache")
        if cache is None or any(m is not seen for m, seen in zip(maps, cache[0], strict=True)):
            selection = shared_selection(evaluations) if self.positions == "measured" else None
            cache = self._selection_cache = maps, selection
            if self._together is not None:
                self._together = BatchedSensing(self._batch, self.estimator, selection)
        return cache[1]

    def _entries_plan(self) -> GatheredObservations | None:
        """The batched evaluation of the in-process environments' observations when each is gathered from MjData
        entries (:meth:`GatheredObservations.supports <smo_gym.engine.scratch.GatheredObservations.supports>`,
        ``positions="measured"``, joint coordinates equal to ``qpos``), else None; decided once, made again if an
        environment replaced its ``MjData`` or a reset dropped its gather."""
        plan = self.__dict__.get("_plan_cache", False)
        if plan is None or (plan and plan.current()):
            return plan
        evaluations = [s.adapter.evaluation for s in self._local]
        plan = None
        if (
            self.positions == "measured"
            and GatheredObservations.supports(evaluations)
            and all(s.adapter.unflatten is None and not s.measurement.tangent.manifold for s in self._local)
        ):
            plan = GatheredObservations(evaluations)
        self._plan_cache = plan
        return plan

    def _full_reset(self, Z: np.ndarray) -> np.ndarray:
        self.observer.reset(Z)
        return self.observer.estimate

    def _update(self, Z: np.ndarray) -> np.ndarray:
        return self.observer.update(Z)

    # ---- in-process: the environments measured together ------------------------------------------------------
    def _local_batch(self) -> MeasurementBatch:
        """The in-process environments' MeasurementBatch, made once their sensors have a stream (after a reset)."""
        if self._batch is None:
            self._batch = MeasurementBatch([s.measurement for s in self._local])
            for s in self._local:
                s.batched = True
            if BatchedSensing.supports(self.estimator):
                self._together = BatchedSensing(self._batch, self.estimator, self._selection())
        return self._batch

    def _step_together(self) -> tuple | None:
        """A step where every in-process environment went on: ``(block, clean, estimate, observations)`` from one
        compiled call (:class:`~smo_gym.engine.batch.BatchedSensing`), or None where it does not serve the observer."""
        together, local = self._together, self._local
        if together is None:
            return None
        block, obs = together.step([s.adapter.data for s in local])
        est = self.observer.estimate
        if obs is None:
            obs, _ = self._observe_all(est, block[:, self._batch.slices[3]])
        return block, np.array([s.step_observation for s in local]), est, obs

    def _local_block(self, stale: np.ndarray | None, terminal=None) -> tuple[np.ndarray, np.ndarray]:
        """``(block, clean)`` after a vector step: each environment's sample, a row of ``block`` (layout of
        :func:`~smo_gym.engine.batch.block_slices`, ``qvel_estimate`` zero), and its clean observation. Rows but
        the ``stale`` ones (a mask; None: no row) are measured now, in one call; the stale ones by their
        :class:`JointSensor`: the ended episode's last sample where ``terminal`` (a mask), else the reset's."""
        local = self._local
        datas, clean = [s.adapter.data for s in local], [s.step_observation for s in local]
        block = self._batch.measure_live(datas, None if stale is None else ~stale)
        if stale is not None:
            self._record_rows(block, clean, stale, terminal)
        return block, np.array(clean)

    def _record_rows(self, block: np.ndarray, clean: list, rows: np.ndarray, terminal: np.ndarray | None) -> None:
        """Write the samples the JointSensors measured into the rows ``rows`` (a mask) of ``block`` and ``clean``."""
        q, v, _, qm, _, zm = self._batch.slices
        for i in np.flatnonzero(rows):
            s = self._local[i]
            step = (terminal is not None and terminal[i]) or not s._reset_last
            sample, z = (s.smo_step, s.z_step) if step else (s.smo_reset, s.z_reset)
            row = block[i]
            row[q], row[v], row[qm], row[zm] = sample["qpos"], sample["qvel"], sample["qpos_measured"], z
            clean[i] = sample["observation"]

    def _local_positions(self, block: np.ndarray | None = None, stale: np.ndarray | None = None) -> np.ndarray:
        """The in-process environments' measured configurations at their last sample, ``(n_envs, nq)``: from
        ``block`` (:meth:`_local_block`, a view when no row is ``stale``), from each measurement where ``stale``."""
        if block is None:
            return np.array([s.measurement.measured_qpos() for s in self._local])
        if stale is None:
            return block[:, self._batch.slices[3]]
        positions = block[:, self._batch.slices[3]].copy()
        for i in np.flatnonzero(stale):
            positions[i] = self._local[i].measurement.measured_qpos()
        return positions


def stack_samples(samples: list[dict], velocity: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """``infos["smo"]`` of a Gymnasium vector env: the keys of :class:`~smo_gym.wrappers.sensing.SensingInfo`
    with a leading environment dimension (``qpos`` ``(n_envs, nq)``, ..., ``observation`` stacked like the
    vector env's observations), and Gymnasium's ``_key`` masks (``mask``, default all True), exactly the layout
    Gymnasium's info merging gives to per-environment wrappers."""
    mask = np.ones(len(samples), dtype=bool) if mask is None else np.array(mask, dtype=bool)

    def stack(values):
        if isinstance(values[0], dict):
            out = {}
            for key in values[0]:
                out[key], out[f"_{key}"] = stack([v[key] for v in values]), mask.copy()
            return out
        return np.stack([np.asarray(v) for v in values])

    merged = [{**sample, "qvel_estimate": v} for sample, v in zip(samples, velocity, strict=True)]
    keys = ("qpos", "qvel", "qvel_estimate", "qpos_measured", "observation")
    return stack([{key: sample[key] for key in keys} for sample in merged])


def _rows(stacked: dict, i: int) -> dict:
    """Row ``i`` of a dict of stacked arrays (nested dicts too, masks dropped): one environment's sample from
    Gymnasium's merged infos."""
    return {
        key: _rows(value, i) if isinstance(value, dict) else value[i]
        for key, value in stacked.items()
        if not key.startswith("_")
    }


# ----------------------------------------------------------------------------------------------------------------
# Gymnasium vector envs
# ----------------------------------------------------------------------------------------------------------------
class VectorEstimatedVelocity(_Sensing, gym.vector.VectorWrapper):
    r"""Gymnasium vector-env wrapper: the counterpart of :class:`VecEstimatedVelocity` for ``gymnasium.vector``.

    Honours ``metadata["autoreset_mode"]``:

    ``next-step`` (Gymnasium's default)
        the step that ends an episode returns its terminal observation (estimate after the last sample); at the
        next step the environment is reset and its observer restarts from the reset's measurement;
    ``same-step``
        the finished environment is reset within the step: ``infos["final_obs"][i]`` is rewritten from the
        finished episode's last measurement and estimate, the returned observation is the new episode's first;
    ``disabled``
        observers of finished environments restart when the user calls ``reset(options={"reset_mask": m})``.

    ``SyncVectorEnv``'s environments are wrapped in :class:`JointSensor` here if needed; ``AsyncVectorEnv`` must
    be built with it (``gymnasium.make_vec(id, vectorization_mode="async", wrappers=[partial(JointSensor, ...)])``).

    ``infos["smo"]`` has the keys of :class:`~smo_gym.wrappers.sensing.SensingInfo` (the per-environment
    wrapper's ``info["smo"]``) with a leading environment dimension: ``qpos`` ``(n_envs, nq)``, ``qvel``,
    ``qvel_estimate`` and ``qpos_measured``, and ``observation``, the clean observations stacked like the
    returned ones (``infos["_smo"]`` is all True, Gymnasium's convention): what per-environment wrappers inside
    a ``SyncVectorEnv`` give. So, as there, with ``same-step`` autoresets the row of a finished environment
    describes the new episode's first sample, and ``infos["final_info"]["smo"]`` (rows where
    ``infos["final_info"]["_smo"]``) the finished episode's last one.

    Sampling is once per environment step (``rate="env"``); for ``rate="physics"`` put the per-environment
    :class:`~smo_gym.wrappers.EstimatedVelocity` inside the vector env instead (``gymnasium.make_vec(id,
    wrappers=[partial(EstimatedVelocity, rate="physics")])``), which samples inside ``frame_skip`` wherever the
    environment runs.
    """

    def __init__(self, env, sensor=None, observer=None, observer_kwargs=None, *, rate="env", **kwargs):
        gym.vector.VectorWrapper.__init__(self, env)
        check_vector_rate(rate)
        requested = (
            None
            if sensor is None and observer is None and not kwargs and observer_kwargs is None
            else sensing_config(sensor or "encoder-12bit-noisy", observer or "auto", observer_kwargs, **kwargs)
        )
        from gymnasium.vector import AutoresetMode, SyncVectorEnv

        self.autoreset_mode = AutoresetMode(env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP))
        base = env.unwrapped
        sensors = attach_sensors(base.envs, requested) if isinstance(base, SyncVectorEnv) else None
        self._setup_sensing(requested, env.num_envs, sensors)
        self._autoreset = np.zeros(env.num_envs, dtype=bool)
        #: in-process with a batch: the last step's samples (:meth:`_local_block`)
        self._last_sample = None

    def _call_envs(self, name: str, *args) -> list:
        return list(self.env.call(name, *args))

    def _all_have(self, name: str) -> bool:
        return all(self.env.call("has_wrapper_attr", name))

    def _samples(self, infos: dict, terminal=None) -> list[dict]:
        """Every environment's last sample from the workers' ``infos``, or the step's (in ``final_info``) where
        ``terminal``."""
        rows = [_rows(infos["smo"], i) for i in range(self.num_envs)]
        if terminal is not None:
            for i in np.flatnonzero(terminal):
                rows[i] = _rows(infos["final_info"]["smo"], i)
        return rows

    def reset(self, *, seed=None, options=None):
        if options is not None and not isinstance(options, dict):
            raise TypeError(f"expected options to be None or a dict, actual value: {options!r:.80}")
        if isinstance(seed, (list, tuple)) and len(seed) != self.num_envs:  # all checked before any is reset
            raise ValueError(f"expected {self.num_envs} seeds, one per environment, actual value: {seed!r:.80}")
        seed = [check_seed(s) for s in seed] if isinstance(seed, (list, tuple)) else check_seed(seed)
        mask = None if options is None else options.get("reset_mask")
        _, infos = self.env.reset(seed=seed, options=options)
        Z = self._measurements(infos)
        if mask is None or self.observer.shape is None:
            est = self._full_reset(Z)
            self._autoreset[:] = False
        else:
            mask = np.asarray(mask, dtype=bool)
            self.observer.reset(np.where(mask[:, None], Z, self.observer.estimate[..., 0]), mask=mask)
            est = self.observer.estimate
            self._autoreset[mask] = False
        if self._local is None:
            obs, _ = self._observe_all(est)
            infos["smo"] = stack_samples(self._samples(infos), self.estimator.velocity_of(est))
        else:
            obs, _ = self._observe_all(est, self._local_positions())
            self._local_batch()  # the sensors have their streams now
            # the samples of the environments reset here, and the others' last ones (a masked reset)
            n = self.num_envs
            if mask is not None and self._last_sample is not None:
                rows, block, clean = mask, self._last_sample[0].copy(), list(self._last_sample[1])
            else:
                rows, block, clean = np.ones(n, bool), np.zeros((n, self._batch.slices[-1].stop)), [None] * n
            self._record_rows(block, clean, rows, None)
            self._last_sample = (block, np.array(clean))
            infos["smo"] = self._stacked_info(*self._last_sample, self.estimator.velocity_of(est))
        infos["_smo"] = np.ones(self.num_envs, bool)
        return obs, infos

    def _measurements(self, infos) -> np.ndarray:
        """This call's measurement of every environment: from the workers' ``infos``, or in-process (a reset) from
        the sensors."""
        if self._local is None:
            return np.array(infos["smo_z"], dtype=np.float64)
        return np.array([s.z_reset for s in self._local], dtype=np.float64)

    def step(self, actions):
        if self.observer.shape is None:
            raise RuntimeError("expected reset() before step(), actual value: the wrapper was never reset")
        self._check_batch(actions, self.env.single_action_space.shape)
        if self.autoreset_mode is gym.vector.AutoresetMode.DISABLED and self._autoreset.any():  # else some would step
            raise RuntimeError(
                "expected reset(options={'reset_mask': ...}) of the finished environments before step() (autoreset "
                f"mode disabled), actual value: environments {np.flatnonzero(self._autoreset).tolist()} finished"
            )
        local = self._local
        if local is not None:
            batch = self._local_batch()
        _, rewards, terminated, truncated, infos = self.env.step(actions)
        done = np.logical_or(terminated, truncated)
        restart = self._autoreset.copy()  # environments that ended at the last step (autoreset mode next-step only)
        stale = done | restart
        stale = stale if stale.any() else None
        together = self._step_together() if stale is None else None
        terminal = terminal_mask = None
        if together is not None:  # every environment went on: one compiled call
            block, clean, est, obs = together
        else:
            if local is not None:  # the environments that were stepped and go on, measured together
                block, clean = self._local_block(stale)
                Z = np.ascontiguousarray(block[:, batch.slices[5]])
            else:
                Z = self._measurements(infos)
            est, terminal, terminal_mask = self._advance(Z, done, restart, infos)
            positions = None if local is None else self._local_positions(block, stale)
            obs, terms = self._observe_all(est, positions, terminal, terminal_mask)
            if terminal_mask is not None:
                final_obs = infos["final_obs"]
                for i in np.flatnonzero(terminal_mask):
                    final_obs[i] = terms[i]
        if local is not None:
            infos["smo"] = self._stacked_info(block, clean, self.estimator.velocity_of(est))
            self._last_sample = (block, clean)  # for a masked reset (autoreset mode "disabled")
        else:
            infos["smo"] = stack_samples(self._samples(infos), self.estimator.velocity_of(est))
        infos["_smo"] = np.ones(self.num_envs, bool)
        if terminal_mask is not None:  # Gymnasium's same-step convention: the finished episodes' in final_info
            final = infos["final_info"]
            if local is not None:
                block, clean = block.copy(), list(clean)
                self._record_rows(block, clean, terminal_mask, terminal_mask)
                final["smo"] = self._stacked_info(
                    block, np.array(clean), self.estimator.velocity_of(terminal), terminal_mask
                )
            else:
                final["smo"] = stack_samples(
                    self._samples(infos, terminal_mask), self.estimator.velocity_of(terminal), terminal_mask
                )
            final["_smo"] = terminal_mask.copy()
        return obs, rewards, terminated, truncated, infos

    def _advance(self, Z: np.ndarray, done: np.ndarray, restart: np.ndarray, infos: dict) -> tuple:
        """The observer's step on ``Z`` in the autoreset mode: ``(estimate, terminal estimate, finished)`` (None, None
        but where same-step autoresets end episodes)."""
        from gymnasium.vector import AutoresetMode

        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            est = self._update(np.where(restart[:, None], self.observer.estimate[..., 0], Z))
            if restart.any():
                self.observer.reset(Z, mask=restart)
                est = self.observer.estimate
            self._autoreset = done
        elif self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            Zt = Z.copy()
            for i in np.flatnonzero(done):
                Zt[i] = self._local[i].z_step if self._local is not None else infos["final_info"]["smo_z"][i]
            terminal = self._update(Zt).copy()
            self.observer.reset(Z, mask=done)
            return self.observer.estimate, terminal, done
        else:  # disabled: finished environments wait for reset(options={"reset_mask": ...})
            est = self._update(Z)
            self._autoreset = self._autoreset | done
        return est, None, None

    def _stacked_info(self, block: np.ndarray, clean: np.ndarray, velocity: np.ndarray, mask=None) -> dict:
        """:func:`stack_samples` of the samples in ``block`` and ``clean`` (:meth:`_local_block`), with the velocity
        estimates ``velocity`` ``(n_envs, nv)``: new arrays."""
        mask = np.ones(self.num_envs, dtype=bool) if mask is None else np.array(mask, dtype=bool)
        q, v, _, qm = self._batch.slices[:4]
        values = (block[:, q], block[:, v], velocity, block[:, qm], clean)
        out = {}
        for key, value in zip(("qpos", "qvel", "qvel_estimate", "qpos_measured", "observation"), values, strict=True):
            out[key], out[f"_{key}"] = np.array(value), mask.copy()
        return out
