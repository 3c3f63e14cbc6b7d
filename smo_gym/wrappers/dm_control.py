r"""dm_control suite tasks with the same sensing as the Gymnasium MuJoCo environments.

dm_control tasks reach Gymnasium through shimmy's ``DmControlCompatibilityV0`` (``gym.make("dm_control/...-v0")``
after ``import shimmy``), the maintained converter; it works with the pinned versions (shimmy 2.0.1,
dm_control 1.0.50, mujoco 3.17: checked by ``tests/test_dm_control.py``), so no converter of our own is needed.
This module adds only what the sensing core needs from it, as an adapter registered with
:func:`smo_gym.wrappers.adapters.register_adapter`, so that :class:`~smo_gym.wrappers.EstimatedVelocity`,
:mod:`smo_gym.experiments.compare` and the calibration use it unchanged.

How the five parts of an adapter (:mod:`smo_gym.wrappers.adapters`) map onto dm_control, with
``dm = env.unwrapped._env`` (a ``dm_control.rl.control.Environment``) and ``physics = dm.physics``:

``model``, ``data``
    ``physics.model.ptr`` and ``physics.data.ptr`` (the ``mujoco`` objects under dm_control's wrappers).
``frame_skip``
    ``dm._n_sub_steps``: physics steps per control step (1 for cartpole, acrobot, cheetah, whose control step is
    the physics step; 10 for walker at 2.5 ms).
``observation(qpos, qvel)``
    the task's own ``get_observation(physics)`` evaluated on a *scratch* ``Physics`` (sharing the model) that
    holds the measured ``qpos`` and estimated ``qvel`` after the part of the forward pass the observation needs.
    The evaluation is :class:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter`'s own (scratch ``MjData``, the
    probed ``none``/``kinematics``/``forward`` pipeline, the controller's inputs ``ctrl``/``act``/``time``
    copied): :class:`DmControlTaskView` presents the task with the ``model``/``data``/``frame_skip``/
    ``_get_obs`` of a Gymnasium ``MujocoEnv``, its ``_get_obs`` reading the task's observation through a
    dm_control ``Physics`` around whatever ``MjData`` it is given, flattened in the task's key order. Dict
    observations are restored by :meth:`DmControlAdapter.unflatten`, so the wrapped observation space is kept
    exactly (shimmy's ``Dict`` of float64 ``Box`` es, including walker's scalar ``height``).
    Entries from other sensors (touch, force/torque in ``sensordata``) are recomputed from the sensed state by
    the forward pass, like everything else the task computes from ``physics.data``.
``record_substeps(recording)``
    ``physics.step`` is replaced on the instance, for the duration of the block, by a loop of
    ``step(1)`` calls that fill the recording; dm_control's legacy step (``mj_step2``, then ``mj_step``
    ``n - 1`` times, then ``mj_step1``) becomes ``(mj_step2, mj_step1)`` ``n`` times: the same sequence of MuJoCo
    calls, so the trajectory is bit-identical (tested), and ``qpos`` is current after each call. So
    ``rate="physics"`` samples inside the control step, as on the Gymnasium environments.

Composer environments (``dm_control.composer``: locomotion, manipulation) build observations through observables,
not ``task.get_observation(physics)``; they are refused with a ``TypeError``.

dm_control resets an episode inside ``step`` when called after the last step; the wrapper's observer would not
see that reset, so, as with any Gymnasium environment, call ``reset()`` after ``terminated or truncated``.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from .._cache import stable_repr
from .._extras import require
from .adapters import GymnasiumMujocoAdapter, SubstepHook, SubstepRecording, register_adapter

__all__ = ["DmControlAdapter", "DmControlTaskView", "is_dm_control_env", "make_dm_control"]


def is_dm_control_env(unwrapped) -> bool:
    """Whether ``unwrapped`` is shimmy's ``DmControlCompatibilityV0`` (checked without importing shimmy)."""
    cls = type(unwrapped)
    return cls.__name__ == "DmControlCompatibilityV0" and cls.__module__.startswith("shimmy")


class DmControlTaskView:
    """A dm_control suite task seen as a Gymnasium ``MujocoEnv``: ``model``, ``data``, ``frame_skip``, ``_get_obs``.

    ``data`` is the live ``MjData`` unless assigned (the Gymnasium adapter assigns a scratch ``MjData`` for the
    duration of one observation); ``_get_obs()`` evaluates ``task.get_observation`` on a dm_control ``Physics``
    around the current ``data`` and returns it flattened (float64, keys in the task's order).

    Parameters
    ----------
    environment : dm_control.rl.control.Environment
    """

    def __init__(self, environment):
        self.environment = environment
        self.frame_skip = int(environment._n_sub_steps)
        self._override = None
        # (MjData, Physics around it), the last four: the scratch data's and the reset check's alternate (~5 ms each)
        self._physics: list[tuple] = []
        self.keys: list[str] | None = None
        self.shapes: list[tuple] = []

    @property
    def physics(self):
        return self.environment.physics

    @property
    def model(self):  # read through: a copy's physics has a model of its own (a task may edit it: reacher's target)
        return self.environment.physics.model.ptr

    @property
    def data(self):
        return self._override if self._override is not None else self.environment.physics.data.ptr

    @data.setter
    def data(self, value) -> None:
        self._override = None if value is self.environment.physics.data.ptr else value

    def _physics_for(self, data):
        live = self.environment.physics
        if data is live.data.ptr:
            return live
        for held, physics in self._physics:
            if held is data:
                return physics
        from dm_control.mujoco import wrapper

        # a Physics runs a forward pass on construction: restore every field afterwards (the adapter's probe
        # poisons the fields it does not set, and must see them untouched)
        snapshot = copy.copy(data)
        physics = type(live)(wrapper.MjData(data))
        mujoco.mj_copyData(data, self.model, snapshot)
        self._physics = [(data, physics), *self._physics[:3]]
        return physics

    def task_observation(self, physics) -> dict:
        """The task's observation dict at ``physics`` (flattened as dm_control does if the env is flat)."""
        from dm_control.rl import control

        obs = self.environment.task.get_observation(physics)
        if getattr(self.environment, "_flat_observation", False):
            obs = control.flatten_observation(obs)
        return obs

    def _get_obs(self) -> np.ndarray:
        obs = self.task_observation(self._physics_for(self.data))
        if self.keys is None:
            self.keys = list(obs)
            self.shapes = [np.shape(obs[k]) for k in self.keys]
        return np.concatenate([np.ravel(np.asarray(obs[k], dtype=np.float64)) for k in self.keys])

    def __getstate__(self):
        return {**self.__dict__, "_override": None, "_physics": []}


class DmControlAdapter(GymnasiumMujocoAdapter):
    """Adapter for dm_control suite tasks behind shimmy's ``DmControlCompatibilityV0`` (see the module docstring).

    Parameters
    ----------
    env : shimmy.DmControlCompatibilityV0
        The *unwrapped* environment (a ``dm_control.rl.control.Environment`` inside).
    contact_forces : {"sensor", "estimated", "zero"}
        As for the Gymnasium adapter (``cfrc_ext``; no suite task reads it).

    Attributes
    ----------
    environment_key : str
        Identity of the task for the calibration cache: the registered id, or the task's class and its scalar
        settings (e.g. ``cartpole.Balance{_swing_up: True, ...}``) when the env was built without ``gym.make``.

    Raises
    ------
    TypeError
        A composer environment (observations through observables, not ``task.get_observation``).
    """

    #: dm_env starts a new episode when stepped after the last time step
    restarts_when_stepped_after_end = True

    def __init__(self, env, contact_forces: str = "sensor"):
        control = require("dm_control.rl.control", "dm_control")

        dm = getattr(env, "_env", None)
        if not isinstance(dm, control.Environment):
            raise TypeError(
                "expected shimmy's DmControlCompatibilityV0 around a dm_control.rl.control.Environment (a suite "
                f"task, whose observation is task.get_observation(physics)), actual value: {type(dm).__name__}"
            )
        self.gym_env = env
        self.view = DmControlTaskView(dm)
        super().__init__(self.view, contact_forces=contact_forces)
        self.keys, self.shapes = list(self.view.keys or []), list(self.view.shapes)
        sizes = [int(np.prod(s)) for s in self.shapes]
        self._slices = [
            (k, a, a + n, s)
            for k, a, n, s in zip(self.keys, np.cumsum([0] + sizes[:-1]), sizes, self.shapes, strict=True)
        ]
        spec = getattr(env, "spec", None)
        if spec is not None and spec.id:
            self._environment_key = spec.id + (stable_repr(spec.kwargs) if spec.kwargs else "")
        else:
            task = dm.task
            settings = {
                k: v
                for k, v in sorted(vars(task).items())
                if isinstance(v, (bool, int, float, str)) and not k.startswith("__")
            }
            self._environment_key = f"{type(task).__module__}.{type(task).__qualname__}{settings}"

    @property
    def environment_key(self) -> str:
        return self._environment_key

    def copy_environment(self):
        """A deep copy of shimmy's environment: dm_control's ``Physics`` copies by value, so edits of the live
        model are kept."""
        return copy.deepcopy(self.gym_env)

    # ---- observation structure ------------------------------------------------------------------------------
    def unflatten(self, flat: np.ndarray) -> dict[str, np.ndarray]:
        """The task's observation dict (shimmy's ``dm_obs2gym_obs`` layout) from the flat array of ``observation``."""
        return {key: flat[a:b].reshape(shape).copy() for key, a, b, shape in self._slices}

    # ---- sampling inside the control step -------------------------------------------------------------------
    def supports_substeps(self) -> bool:
        """dm_control steps its physics through ``Physics.step``, which can be replaced on the instance."""
        return True

    def record_substeps(self, recording: SubstepRecording) -> SubstepHook:
        """Within the block, ``physics.step(n)`` runs as ``n`` calls ``step(1)``, filling ``recording`` (the
        Gymnasium adapter's hook, on dm_control's step); the returned context manager is reusable."""
        physics = self.view.physics
        original = physics.step

        def step_recording(nstep: int = 1) -> None:
            data = physics.data.ptr
            pairs = recording.destinations(data, int(nstep))
            for _ in range(int(nstep)):
                original(1)
                recording.count += 1
                if recording.count == recording.every:
                    recording.count = 0
                    for buffer, field in pairs:
                        buffer[recording.n] = field
                    recording.n += 1

        return SubstepHook(physics, "step", step_recording)


register_adapter(is_dm_control_env, DmControlAdapter)


def make_dm_control(
    domain: str,
    task: str,
    sensor="encoder-12bit-noisy",
    observer="auto",
    rate="physics",
    observer_kwargs: dict | None = None,
    *,
    env_kwargs: dict | None = None,
    **wrapper_kwargs,
):
    """A dm_control suite task as a Gymnasium env seen through a joint sensor and a velocity observer.

    ``gym.make(f"dm_control/{domain}-{task}-v0", **env_kwargs)`` (shimmy's converter) wrapped by
    :class:`~smo_gym.wrappers.EstimatedVelocity` with ``sensor``, ``observer``, ``rate``, ``observer_kwargs`` and
    the other keyword arguments of the wrapper.

    Examples
    --------
    >>> env = make_dm_control("walker", "walk", sensor="encoder-12bit", rate="physics")  # doctest: +SKIP
    >>> obs, info = env.reset(seed=0)  # doctest: +SKIP
    >>> info["smo"]["qvel_estimate"].shape  # doctest: +SKIP
    (9,)

    Raises
    ------
    ValueError
        Unknown domain/task (the message lists the suite's tasks), and everything ``EstimatedVelocity`` raises.
    """
    import gymnasium as gym

    require("shimmy", "dm_control")  # registers the dm_control/... ids
    suite = require("dm_control.suite", "dm_control")

    from .estimated_velocity import EstimatedVelocity

    if (domain, task) not in suite.ALL_TASKS:
        raise ValueError(
            f"expected a dm_control suite (domain, task) in {', '.join(f'{d}-{t}' for d, t in suite.ALL_TASKS)}, "
            f"actual value: {domain!r}, {task!r}"
        )
    env = gym.make(f"dm_control/{domain}-{task}-v0", **(env_kwargs or {}))
    return EstimatedVelocity(
        env, sensor=sensor, observer=observer, rate=rate, observer_kwargs=observer_kwargs, **wrapper_kwargs
    )
