r"""Small adapters between the sensing engine and a simulator's MuJoCo objects.

The wrapper needs these things from an environment (the :class:`MujocoAdapter` protocol), and nothing else:

``model``, ``data``
    the ``mujoco.MjModel`` and the *live* ``mujoco.MjData`` of the simulation;
``frame_skip``
    physics steps per environment step;
``observation(qpos, qvel)``
    the environment's own observation function evaluated at a given configuration and velocity, on a scratch
    ``MjData`` (never the live one): :class:`~smo_gym.engine.scratch.ScratchObservation`, the adapter's
    ``evaluation``, which the engine's compiled path also writes into;
``record_substeps(recording)``
    a context manager under which the environment's ``step`` fills a :class:`SubstepRecording` with rows of the
    live data every few physics steps (the one hook into an environment's step);
``copy_environment()``, ``environment_key``
    a copy on the live model for calibration rollouts, and the environment's identity for the calibration cache.

:class:`GymnasiumMujocoAdapter` implements them for ``gymnasium.envs.mujoco.MujocoEnv`` (every v5 environment and
user subclasses): its observation function is the class's ``_get_obs``, called with ``env.data`` pointing at the
data to read for the duration of the call. The dm_control adapter (:mod:`smo_gym.wrappers.dm_control`) presents a
suite task as such an environment and hooks ``Physics.step`` instead. Everything else (tangent coordinates,
sensor, observer, default gains, ``info["smo"]``) is the same code.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any, Protocol, runtime_checkable

import mujoco
import numpy as np

from ..engine.scratch import CONTACT_FORCES, ScratchObservation

__all__ = [
    "ADAPTERS",
    "CONTACT_FORCES",
    "GymnasiumMujocoAdapter",
    "MujocoAdapter",
    "SubstepHook",
    "SubstepRecording",
    "make_adapter",
    "register_adapter",
]


@runtime_checkable
class MujocoAdapter(Protocol):
    """What the sensing wrapper needs from a simulator (see the module docstring), as a protocol: an adapter is
    any object with these members (:class:`GymnasiumMujocoAdapter`; the dm_control one subclasses it)."""

    model: mujoco.MjModel
    """The simulation's model."""
    frame_skip: int
    """Physics steps per environment step."""
    unflatten: Callable[[np.ndarray], Any] | None
    """``unflatten(flat) -> observation`` for structured (``Dict``) observation spaces (dm_control), else None:
    :meth:`observation` always returns a flat float array, which the wrapper checks and then unflattens."""
    checks_observation: bool
    """:meth:`observation` raises ``ValueError`` on a non-finite result itself (the wrapper does not check again)."""
    restarts_when_stepped_after_end: bool
    """A step after the episode's end starts a new one (dm_env; Gymnasium's MuJoCo envs simulate on): reset first."""

    @property
    def data(self) -> mujoco.MjData:
        """The live ``MjData`` of the simulation."""

    def observation(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """The environment's own observation at ``(qpos, qvel)``, evaluated on scratch data (flat float array)."""

    def supports_substeps(self) -> bool:
        """Whether :meth:`record_substeps` can sample inside the environment's step."""

    def record_substeps(self, recording: SubstepRecording) -> AbstractContextManager:
        """A reusable context manager under which the environment's step fills ``recording``."""

    def copy_environment(self):
        """A separate copy of the (unwrapped) environment on the live model, for calibration rollouts."""

    @property
    def environment_key(self) -> str:
        """Identity of the environment for the calibration cache, the same in every process."""

    @property
    def evaluation(self) -> ScratchObservation | None:
        """The observation evaluated on scratch data that the engine's compiled path writes into, or None."""


def _missing_mujoco_parts(env) -> list[str]:
    missing = []
    if not isinstance(getattr(env, "model", None), mujoco.MjModel):
        missing.append("model (a mujoco.MjModel)")
    if not isinstance(getattr(env, "data", None), mujoco.MjData):
        missing.append("data (a mujoco.MjData)")
    if not isinstance(getattr(env, "frame_skip", None), (int, np.integer)):
        missing.append("frame_skip (an int)")
    if not callable(getattr(env, "_get_obs", None)):
        missing.append("_get_obs() (the observation function)")
    return missing


class GymnasiumMujocoAdapter:
    """Adapter for ``gymnasium.envs.mujoco.MujocoEnv`` and its subclasses.

    Parameters
    ----------
    env : gymnasium.Env
        The *unwrapped* environment.
    contact_forces : {"sensor", "estimated", "zero"}
        Where the contact forces of a sensed observation come from (:mod:`smo_gym.engine.scratch`).

    Attributes
    ----------
    evaluation : smo_gym.engine.scratch.ScratchObservation
        The environment's ``_get_obs`` evaluated on scratch data.

    Raises
    ------
    TypeError
        If ``env`` lacks ``model``, ``data``, ``frame_skip`` or ``_get_obs`` (the message lists what is missing).
    """

    #: Gymnasium observations are flat arrays already
    unflatten = None
    #: Gymnasium's MuJoCo envs simulate on when stepped after an episode's end
    restarts_when_stepped_after_end = False

    def __init__(self, env, contact_forces: str = "sensor"):
        missing = _missing_mujoco_parts(env)
        if missing:
            raise TypeError(
                "expected a Gymnasium MuJoCo environment (gymnasium.envs.mujoco.MujocoEnv or an env with "
                "model, data, frame_skip and _get_obs), actual value: "
                f"{type(env).__name__} has no {', '.join(missing)}"
            )
        self.env = env
        self.frame_skip = int(env.frame_skip)
        self.contact_forces = contact_forces
        #: the class's observation function, called as ``_obs_function(env)`` with ``env.data`` set to the data
        #: it should read
        self._obs_function = type(env)._get_obs
        self.evaluation = ScratchObservation(
            self.model, self._live_data, self._observation_on, contact_forces, type(env).__name__
        )

    def _live_data(self) -> mujoco.MjData:
        return self.env.data

    def _observation_on(self, data: mujoco.MjData) -> np.ndarray:
        """The environment's ``_get_obs()`` computed from ``data`` (``env.data`` points to it for the call)."""
        env = self.env
        live = env.data
        env.data = data
        try:
            return self._obs_function(env)
        finally:
            env.data = live

    @property
    def model(self) -> mujoco.MjModel:  # read through: a copied environment is rebuilt with a model of its own
        return self.env.model

    @property
    def data(self) -> mujoco.MjData:
        return self.env.data

    @property
    def checks_observation(self) -> bool:
        return self.evaluation.checks_observation

    def observation(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """The environment's observation at ``(qpos, qvel)``, evaluated on scratch data (see module docstring)."""
        return self.evaluation.observation(qpos, qvel)

    @property
    def environment_key(self) -> str:
        """Identity of the environment for the calibration cache: its registered id and constructor arguments (in
        a form that is the same in every process, :func:`~smo_gym._cache.stable_repr`), or its class."""
        from .._cache import stable_repr

        env = self.env
        spec = getattr(env, "spec", None)
        if spec is not None and spec.id:
            kwargs = {k: v for k, v in (spec.kwargs or {}).items() if k != "render_mode"}
            return f"{spec.id}{stable_repr(kwargs)}" if kwargs else spec.id
        return f"{type(env).__module__}.{type(env).__qualname__}:{getattr(env, 'fullpath', '')}"

    def copy_environment(self):
        """A separate copy of the environment on the live model, for calibration rollouts.

        ``copy.deepcopy`` of a Gymnasium ``MujocoEnv`` rebuilds it from its constructor arguments (``EzPickle``),
        with the model its XML file describes: edits of the live model (masses, ``opt.timestep``) would be lost.
        The copy gets a copy of the live ``MjModel``, fresh ``MjData`` of it, the live initial state and action
        space, and keeps the rest (reset distribution, rewards, terminations) from its own construction.
        """
        env = self.env
        sim = copy.deepcopy(env)
        sim.model = copy.copy(self.model)
        sim.data = mujoco.MjData(sim.model)
        for name in ("init_qpos", "init_qvel"):
            if hasattr(env, name):
                setattr(sim, name, np.array(getattr(env, name)))
        sim.action_space = copy.deepcopy(env.action_space)
        return sim

    # ---- sampling inside frame_skip -------------------------------------------------------------------------
    def supports_substeps(self) -> bool:
        """Whether the env steps through ``MujocoEnv._step_mujoco_simulation`` (so substeps can be sampled)."""
        from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

        method = getattr(type(self.env), "_step_mujoco_simulation", None)
        return method is MujocoEnv._step_mujoco_simulation

    def record_substeps(self, recording: SubstepRecording) -> SubstepHook:
        """Within the block, the environment's physics steps run one at a time and ``recording`` takes its rows
        every ``recording.every`` of them (:meth:`SubstepRecording.take`).

        The one hook into an environment's step: ``MujocoEnv._step_mujoco_simulation`` (set ``ctrl``, ``mj_step``
        ``n_frames`` times, ``mj_rnePostConstraint``) is replicated as an *instance* attribute that is removed on
        exit (also on an exception), so nothing of the environment changes outside the block, the trajectory is
        bit-identical, and every wrapper around the environment sees its step as before. The returned context
        manager can be entered again and again (a generator-based one would cost more than a small model's physics
        step).
        """
        env, mj_step = self.env, mujoco.mj_step

        def step_recording(ctrl, n_frames):
            model, data = env.model, env.data  # as MujocoEnv's own step reads them
            data.ctrl[:] = ctrl
            # the recording loop written out: a Python call per physics step costs what a small model's step does
            pairs = recording.destinations(data, n_frames)
            every, count, n = recording.every, recording.count, recording.n
            for _ in range(n_frames):
                mj_step(model, data)
                count += 1
                if count == every:
                    count = 0
                    for buffer, field in pairs:
                        buffer[n] = field
                    n += 1
            recording.count, recording.n = count, n
            mujoco.mj_rnePostConstraint(model, data)

        return SubstepHook(env, "_step_mujoco_simulation", step_recording)


class SubstepRecording:
    """Rows of live ``MjData`` fields taken every ``every`` physics steps inside an environment's step.

    Filled by an adapter's :meth:`~GymnasiumMujocoAdapter.record_substeps` hook; :meth:`start` begins a control
    period, after which ``rows[name][:n]`` hold the samples taken (the arrays grow if an environment steps more
    frames than expected).

    Parameters
    ----------
    every : int
        Physics steps per sample.
    sizes : dict of str to int
        The ``MjData`` fields to record (``"qpos"``, ``"qvel"``, ...) and their sizes.
    capacity : int
        Rows allocated up front (samples per control period).
    """

    __slots__ = ("_capacity", "_data", "_pairs", "count", "every", "fields", "n", "rows")

    def __init__(self, every: int, sizes: dict[str, int], capacity: int):
        self.every = int(every)
        self.fields = tuple(sizes)
        self.rows = {name: np.zeros((max(1, int(capacity)), size)) for name, size in sizes.items()}
        self.n = self.count = 0
        self._data, self._pairs, self._capacity = None, (), 0  # bound to the live MjData at first use

    def start(self) -> None:
        """Begin a control period: no rows taken, the step counter at zero."""
        self.n = self.count = 0

    def destinations(self, data: mujoco.MjData, n_steps: int) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """``(buffer, field)`` pairs, ``field`` the live view of ``data``, with room in every buffer for the rows
        of ``n_steps`` more physics steps: the hook writes row ``n`` as ``buffer[n] = field``."""
        need = self.n + (self.count + n_steps) // self.every
        if data is not self._data or need > self._capacity:
            for name in self.fields:  # the buffers grow together: one capacity for all
                buffer = self.rows[name]
                if buffer.shape[0] < need:
                    grown = np.zeros((max(need, 2 * buffer.shape[0]), buffer.shape[1]))
                    grown[: self.n] = buffer[: self.n]
                    self.rows[name] = grown
            self._pairs = tuple((self.rows[name], getattr(data, name)) for name in self.fields)
            self._capacity = min(buffer.shape[0] for buffer, _ in self._pairs)
            self._data = data
        return self._pairs

    def take(self, data: mujoco.MjData) -> None:
        """Take a row of each field now (the sample at the end of a step, when substeps are not recorded)."""
        for buffer, field in self.destinations(data, self.every - self.count):
            buffer[self.n] = field
        self.n += 1
        self.count = 0

    def __getstate__(self):
        return {"every": self.every, "fields": self.fields, "rows": self.rows}

    def __setstate__(self, state):
        self.every, self.fields, self.rows = state["every"], state["fields"], state["rows"]
        self.n = self.count = 0
        self._data, self._pairs, self._capacity = None, (), 0


class SubstepHook:
    """Reusable context manager: set ``owner.<name> = function`` on entry, delete the instance attribute on exit.

    Used to route an environment's physics stepping through a recording loop for the duration of one ``step``
    (:meth:`GymnasiumMujocoAdapter.record_substeps`).
    """

    __slots__ = ("function", "name", "owner")

    def __init__(self, owner, name: str, function):
        self.owner, self.name, self.function = owner, name, function

    def __enter__(self):
        setattr(self.owner, self.name, self.function)
        return self

    def __exit__(self, *exc) -> None:
        delattr(self.owner, self.name)


#: ``(predicate(unwrapped_env) -> bool, factory(unwrapped_env, contact_forces) -> MujocoAdapter)``, tried in order
#: before the Gymnasium adapter (which raises the ``TypeError`` listing what is missing)
ADAPTERS: list = []


def register_adapter(predicate, factory) -> None:
    """Teach :func:`make_adapter` (hence ``EstimatedVelocity``) a new simulator, e.g. dm_control via shimmy."""
    ADAPTERS.append((predicate, factory))


def make_adapter(env, contact_forces: str = "sensor") -> MujocoAdapter:
    """The adapter of the first registered simulator that recognises ``env.unwrapped``, else the Gymnasium one."""
    unwrapped = getattr(env, "unwrapped", env)
    for predicate, factory in ADAPTERS:
        if predicate(unwrapped):
            return factory(unwrapped, contact_forces)
    return GymnasiumMujocoAdapter(unwrapped, contact_forces=contact_forces)
