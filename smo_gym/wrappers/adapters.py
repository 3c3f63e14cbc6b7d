r"""Small adapters between the sensing core and a simulator's MuJoCo objects.

The wrapper needs these things from an environment (:class:`MujocoAdapter`), and nothing else:

``model``, ``data``
    the ``mujoco.MjModel`` and the *live* ``mujoco.MjData`` of the simulation;
``frame_skip``
    physics steps per environment step;
``observation(qpos, qvel)``
    the environment's own observation function evaluated at a given configuration and velocity, on a scratch
    ``MjData`` (never the live one);
``record_substeps(recording)``
    a context manager under which the environment's ``step`` fills a :class:`SubstepRecording` with rows of the
    live data every few physics steps (the one hook into an environment's step).

:class:`GymnasiumMujocoAdapter` implements them for ``gymnasium.envs.mujoco.MujocoEnv`` (every v5 environment and
user subclasses). What a dm_control adapter (behind ``shimmy.DmControlCompatibilityV0``) needs, with
``dm = env.unwrapped._env`` (the ``dm_control.rl.control.Environment``) and ``physics = dm.physics``:

- ``model``/``data``: ``physics.model.ptr`` / ``physics.data.ptr`` (shimmy itself reads them so);
- ``frame_skip``: ``dm._n_sub_steps`` (control step / physics step);
- ``observation(qpos, qvel)``: a scratch ``physics.copy(share_model=True)``; inside its ``reset_context()`` set
  ``qpos``/``qvel`` (the context runs ``mj_forward`` on exit), copy ``ctrl``/``act``; then
  ``shimmy.utils.dm_env.dm_obs2gym_obs(dm.task.get_observation(scratch))`` (tasks read ``physics.named.data``,
  so the scratch physics is the whole swap; no ``_get_obs`` trick needed);
- ``record_substeps(recording)``: replace ``physics.step`` on the instance by ``n`` calls ``step(1)`` that fill
  the recording, inside the context (dm_control's own step keeps its mj_step2/mj_step1 split), then delete the
  attribute;
- ``supports_substeps()`` True, and the calibration key: the domain/task names.

Everything else (tangent coordinates, sensor, observer, default gains, ``info["smo"]``) is the same code.

Scratch evaluation
------------------
``observation`` copies into a scratch ``MjData`` the inputs a real controller knows (``ctrl``, ``act``, ``time``,
mocap poses, applied forces) and the *measured/estimated* ``qpos``/``qvel``, runs ``mj_forward`` (so ``cinert``,
``cvel``, ``qfrc_actuator``, ``site_xpos``, ``xpos`` of ``get_body_com``, ... are recomputed from that state) and
calls ``_get_obs()`` with ``env.data`` temporarily pointing at the scratch data. How much of the forward pass is
needed is *probed* once at construction, with no per-environment table: the observation is evaluated on scratch
data whose other fields are all NaN, after no computation, then after the kinematic stages only (no collision
detection or constraint solver); the first that comes out finite and equal to the ``mj_forward`` result at
random states is used (Hopper, HalfCheetah, Ant: none; Humanoid: kinematics; InvertedDoublePendulum, whose
observation has a constraint force: the full forward pass). The same NaN probe finds whether the observation
reads ``cfrc_ext``. Which of the inputs (``ctrl``, applied forces, ``time``, ...) it reads is probed at random
nonzero inputs, each replaced in turn by other random values and by NaN (MuJoCo zeroes a NaN ``ctrl``, and the
live ``ctrl`` is zero at construction: Humanoid's ``qfrc_actuator`` reads ``ctrl`` only through the actuation);
with the full forward pass every input is copied (constraint forces depend on the inputs only while a constraint
is active, which a probe at a few states need not see). Last, whether ``_get_obs`` returns a fresh array. Only
what is read is copied at every step, and fresh arrays are not copied again (``observe_scratch``, the per-step
path); ``tests/test_wrapper.py`` checks the result against a full forward pass at run-time inputs and active
joint limits on every v5 environment.

Contact forces
--------------
``cfrc_ext`` (Ant's and Humanoid's observations) is not a function of the joint sensors: a real robot measures
contact forces with force/torque sensors or foot switches. ``contact_forces`` decides:

``"sensor"`` (default)
    take them from the simulation, as from separate force sensors (the only true-state entries; documented);
``"estimated"``
    recompute them from the measured/estimated state (``mj_forward`` + ``mj_rnePostConstraint`` on the scratch
    data): no true state at all, but contacts from a noisy configuration are noisy;
``"zero"``
    no contact sensing (the entries are 0).
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any, Protocol, runtime_checkable

import mujoco
import numpy as np

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

#: sources of the contact forces (``cfrc_ext``) in a sensed observation: see :class:`EstimatedVelocity`
CONTACT_FORCES = ("sensor", "estimated", "zero")
#: the controller's inputs that ``observation`` copies from the live data (those the observation reads, probed)
_INPUT_FIELDS = ("time", "ctrl", "act", "mocap_pos", "mocap_quat", "qfrc_applied", "xfrc_applied")
#: MjData fields that are inputs of the simulation (known to a controller), not functions of the state
_INPUTS = (
    "qpos",
    "qvel",
    "act",
    "ctrl",
    "qfrc_applied",
    "xfrc_applied",
    "mocap_pos",
    "mocap_quat",
    "userdata",
    "plugin_state",
    "qacc_warmstart",
    "eq_active",
    "history",
)


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


def _entry_addresses(fields: dict, names, flat) -> np.ndarray:
    """Addresses of the float64 entries ``fields[names[i]].flat[flat[i]]`` (C-contiguous arrays), shape ``(n,)``."""
    from ..engine.fused import address

    base = {name: address(array) for name, array in fields.items()}
    return np.array([base[name] + 8 * int(k) for name, k in zip(names, flat, strict=True)], dtype=np.int64)


@contextlib.contextmanager
def _quiet_mujoco():
    """Within the block, MuJoCo's warnings (``Nan, Inf or huge value in CTRL``, ...) are dropped instead of printed
    and appended to ``MUJOCO_LOG.TXT`` in the working directory: the adapter's probes provoke them on purpose."""
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_ignore_warning)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def _ignore_warning(message: str) -> None:
    pass


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

    Raises
    ------
    TypeError
        If ``env`` lacks ``model``, ``data``, ``frame_skip`` or ``_get_obs`` (the message lists what is missing).
    """

    #: whether the observation reads ``cfrc_ext``, and whether ``_get_obs`` returns a fresh array (both probed at
    #: construction; these defaults are the safe choice)
    reads_contacts = True
    fresh_observation = False
    #: Gymnasium observations are flat arrays already
    unflatten = None
    _bare = False
    #: ``(index, bounds)`` when the observation is a selection of the state (:meth:`_probe_observation_map`)
    observation_map = None
    #: ``(fields, flat_index, bounds, functions)`` when it is a clipped selection of MjData entries, or of their
    #: sines and cosines, after the forward-pass stages (:meth:`_probe_observation_entries`)
    observation_entries = None
    _input_fields = _INPUT_FIELDS

    def __init__(self, env, contact_forces: str = "sensor"):
        missing = _missing_mujoco_parts(env)
        if missing:
            raise TypeError(
                "expected a Gymnasium MuJoCo environment (gymnasium.envs.mujoco.MujocoEnv or an env with "
                "model, data, frame_skip and _get_obs), actual value: "
                f"{type(env).__name__} has no {', '.join(missing)}"
            )
        if contact_forces not in CONTACT_FORCES:
            raise ValueError(
                f"expected contact_forces in {', '.join(map(repr, CONTACT_FORCES))}, actual value: {contact_forces!r}"
            )
        self.env = env
        self.model = env.model
        self.frame_skip = int(env.frame_skip)
        #: the class's observation function, called as ``_obs_function(env)``: an instance attribute that
        #: replaces ``_get_obs`` during a step (:meth:`intercept_observation`) must not call itself
        self._obs_function = type(env)._get_obs
        self.contact_forces = contact_forces
        self._scratch = mujoco.MjData(self.model)
        self.pipeline, self.copies_inputs, self.reads_contacts = "forward", True, True
        self._input_fields = _INPUT_FIELDS
        with _quiet_mujoco():  # the probes feed MuJoCo NaN and huge inputs on purpose
            self.pipeline, self.copies_inputs = self._probe_pipeline()
            self.reads_contacts = self._probe_contacts()
            if contact_forces != "sensor" and not self.reads_contacts:
                raise ValueError(
                    f"expected contact_forces='sensor' for {type(env).__name__}, whose observation has no contact "
                    f"forces (cfrc_ext), actual value: {contact_forces!r}"
                )
            if self.copies_inputs and self.pipeline != "forward":
                # the constraint forces of a full forward pass depend on every applied input whenever a constraint
                # is active, which a probe at a few states need not see (InvertedDoublePendulum's rail limit):
                # with the forward pass, every input is copied
                self._input_fields = self._probe_input_fields()
                self.copies_inputs = bool(self._input_fields)
            self.fresh_observation = self._probe_fresh()
            #: the observation needs nothing but the sensed qpos/qvel on the scratch data (Hopper, HalfCheetah, ...)
            self._bare = self.pipeline == "none" and not self.copies_inputs and not self.reads_contacts
            self.observation_map = self._probe_observation_map() if self._bare else None
            self.observation_entries = None if self._bare else self._probe_observation_entries()
        self._views()

    def _views(self) -> None:
        # cached views of the scratch arrays written at every observation (MjData builds a view per access)
        self._scratch_qpos, self._scratch_qvel = self._scratch.qpos, self._scratch.qvel
        self._input_views = None
        self._views_cache = {}
        self._gather = self._entry_addresses = None
        entries = self.observation_entries
        if entries is not None:  # the addresses of the observation's entries in this scratch data
            from ..engine.fused import gather_entries
            from ..observers.base import _compiled_entry

            names, flat, bounds, functions = entries
            fields = {name: getattr(self._scratch, name) for name in set(names)}
            self._entry_addresses = _entry_addresses(fields, names, flat)
            # kept alive with the scratch data (the addresses point into its buffers)
            self._entry_fields = fields
            self._gather = _compiled_entry(
                gather_entries, (self._entry_addresses, functions, bounds, np.empty(len(names)))
            )
        #: :meth:`observe_scratch` raises on a non-finite observation itself (the caller need not check)
        self.checks_observation = self._gather is not None

    def __getstate__(self):
        state = dict(self.__dict__)
        for name in (
            "_scratch_qpos",
            "_scratch_qvel",
            "_input_views",
            "_views_cache",
            "_gather",
            "_entry_addresses",
            "_entry_fields",
        ):
            state.pop(name, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._views()

    @property
    def data(self) -> mujoco.MjData:
        return self.env.data

    @property
    def scratch(self) -> mujoco.MjData:
        """The scratch ``MjData`` the observation is evaluated on (never the live one)."""
        return self._scratch

    @property
    def environment_key(self) -> str:
        """Identity of the environment for the calibration cache: its registered id and constructor arguments (in
        a form that is the same in every process, :func:`~smo_gym.wrappers.sensing.stable_repr`), or its class."""
        from .sensing import stable_repr

        env = self.env
        spec = getattr(env, "spec", None)
        if spec is not None and spec.id:
            kwargs = {k: v for k, v in (spec.kwargs or {}).items() if k != "render_mode"}
            return f"{spec.id}{stable_repr(kwargs)}" if kwargs else spec.id
        return f"{type(env).__module__}.{type(env).__qualname__}:{getattr(env, 'fullpath', '')}"

    # ---- observation at a given state -----------------------------------------------------------------------
    def _fill(self, scratch: mujoco.MjData, qpos, qvel, inputs: bool = True, source: mujoco.MjData | None = None):
        scratch.qpos[:] = qpos
        scratch.qvel[:] = qvel
        if inputs:
            self._fill_inputs(scratch, source)

    def _fill_inputs(self, scratch: mujoco.MjData, source: mujoco.MjData | None = None) -> None:
        """Copy the controller inputs the observation reads from ``source`` (default: the live data)."""
        source = self.env.data if source is None else source
        for name in self._input_fields:
            if name == "time":
                scratch.time = source.time
            else:
                getattr(scratch, name)[:] = getattr(source, name)

    def _random_inputs(self, rng: np.random.Generator) -> mujoco.MjData:
        """Data whose controller inputs (:data:`_INPUT_FIELDS`) are random, finite and nonzero, for the probes.

        The probes compare evaluations at such inputs, never at the live ones: at construction the live ``ctrl``
        is zero, and MuJoCo replaces a non-finite ``ctrl`` by zero, so an observation that reads ``ctrl`` only
        through the actuation (Humanoid's ``qfrc_actuator``) looks the same with zero, NaN or no ``ctrl``.
        """
        model = self.model
        source = mujoco.MjData(model)
        source.time = rng.uniform(1.0, 10.0)
        ctrl = rng.uniform(-1.0, 1.0, model.nu)
        limited = model.actuator_ctrllimited.astype(bool)
        low, high = model.actuator_ctrlrange[limited].T
        ctrl[limited] = low + (high - low) * rng.uniform(0.1, 0.9, int(limited.sum()))
        source.ctrl[:] = ctrl
        source.act[:] = rng.uniform(0.1, 0.9, model.na)
        source.mocap_pos[:] = rng.standard_normal((model.nmocap, 3))
        quat = rng.standard_normal((model.nmocap, 4))
        source.mocap_quat[:] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        source.qfrc_applied[:] = rng.standard_normal(model.nv)
        source.xfrc_applied[1:] = rng.standard_normal((model.nbody - 1, 6))
        return source

    def _probe_input_fields(self) -> tuple[str, ...]:
        """The controller inputs the observation actually reads (Humanoid's actuator force reads ``ctrl``, nothing
        reads the applied forces; not used with a full forward pass, which copies every input). At random states
        with random inputs (:meth:`_random_inputs`), each field copied by ``_fill_inputs`` is in turn set to other
        random values, then to NaN; if the observation equals the reference both times, the field is not copied
        at every step."""
        model = self.model
        fields = ["time"] + [
            name
            for name, size in (
                ("ctrl", model.nu),
                ("act", model.na),
                ("mocap_pos", model.nmocap),
                ("mocap_quat", model.nmocap),
                ("qfrc_applied", model.nv),
                ("xfrc_applied", model.nbody),
            )
            if size
        ]
        rng = np.random.default_rng(2468)
        cases = []
        for _ in range(2):
            qpos = np.array(self.env.data.qpos)
            mujoco.mj_integratePos(model, qpos, 0.1 * rng.standard_normal(model.nv), 1.0)
            cases.append((qpos, rng.standard_normal(model.nv), self._random_inputs(rng), self._random_inputs(rng)))
        self._input_fields = tuple(fields)
        expected = []
        for qpos, qvel, source, _ in cases:
            reference = mujoco.MjData(model)
            self._fill(reference, qpos, qvel, source=source)
            expected.append(self._evaluate(reference, self.pipeline))
        needed = []
        for name in fields:
            for (qpos, qvel, source, other), want in zip(cases, expected, strict=True):
                changed = []
                for replace in ("other", "nan"):
                    scratch = mujoco.MjData(model)
                    self._input_fields = tuple(fields)
                    self._fill(scratch, qpos, qvel, source=source)
                    if name == "time":
                        scratch.time = other.time if replace == "other" else np.nan
                    elif replace == "other":
                        getattr(scratch, name)[...] = getattr(other, name)
                    else:
                        getattr(scratch, name)[...] = np.nan
                    try:
                        got = self._evaluate(scratch, self.pipeline)
                    except Exception:
                        got = None
                    changed.append(got is None or got.shape != want.shape or not np.array_equal(got, want))
                if any(changed):
                    needed.append(name)
                    break
        self._input_fields = tuple(fields)
        return tuple(needed)

    def _evaluate(self, scratch: mujoco.MjData, pipeline: str) -> np.ndarray:
        self._compute(scratch, pipeline)
        return self._call_observation(scratch)

    def _call_observation(self, scratch: mujoco.MjData) -> np.ndarray:
        """The environment's ``_get_obs`` on ``scratch`` as it is (nothing computed)."""
        live = self.env.data
        self.env.data = scratch
        try:
            obs = self._obs_function(self.env)
        finally:
            self.env.data = live
        return obs if self.fresh_observation else np.array(obs, copy=True)

    def _compute(self, scratch: mujoco.MjData, pipeline: str) -> None:
        """The forward-pass stages of ``pipeline`` on ``scratch``, and its contact forces."""
        model = self.model
        if pipeline == "forward":
            mujoco.mj_forward(model, scratch)
            if self.contact_forces == "estimated":
                mujoco.mj_rnePostConstraint(model, scratch)
        elif pipeline == "kinematics":  # positions, com frames, tendons, transmissions, com velocities, actuation
            mujoco.mj_kinematics(model, scratch)
            mujoco.mj_comPos(model, scratch)
            mujoco.mj_tendon(model, scratch)
            mujoco.mj_transmission(model, scratch)
            mujoco.mj_comVel(model, scratch)
            mujoco.mj_fwdActuation(model, scratch)
        if self.reads_contacts:
            if self.contact_forces == "sensor":
                scratch.cfrc_ext[:] = self.env.data.cfrc_ext
            elif self.contact_forces == "zero":
                scratch.cfrc_ext[:] = 0.0

    def observation(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """The environment's observation at ``(qpos, qvel)``, evaluated on scratch data (see module docstring)."""
        self._scratch_qpos[:] = qpos
        self._scratch_qvel[:] = qvel
        return self.observe_scratch()

    def scratch_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The scratch ``qpos`` (nq,) and ``qvel`` (nv,) arrays: write a state there, then :meth:`observe_scratch`."""
        return self._scratch_qpos, self._scratch_qvel

    def observe_scratch(self, inputs_copied: bool = False) -> np.ndarray:
        """The environment's observation at the state already written into :meth:`scratch_state`.

        ``inputs_copied``: the caller has already copied the input arrays of :meth:`input_views` (the wrapper's
        compiled call does); ``time``, a scalar, is still copied here if read.
        """
        if self._bare:  # the common case, spelled out: this runs once per environment step
            env = self.env
            live = env.data
            env.data = self._scratch
            try:
                obs = self._obs_function(env)
            finally:
                env.data = live
            return obs if self.fresh_observation else np.array(obs, copy=True)
        if self.copies_inputs:
            if not inputs_copied:
                self._copy_inputs()
            elif self._input_views[2]:
                self._scratch.time = self.env.data.time
        if self._gather is None:
            return self._evaluate(self._scratch, self.pipeline)
        self._compute(self._scratch, self.pipeline)  # then the entries, compiled, instead of _get_obs
        _, _, bounds, functions = self.observation_entries
        obs = np.empty(len(bounds[0]))
        bad = self._gather(self._entry_addresses, functions, bounds, obs)
        if bad != -1:
            raise ValueError(f"expected a finite sensed observation, actual value: {obs[bad]!r} at entry {bad}")
        return obs

    def input_views(self) -> tuple[tuple[tuple[np.ndarray, np.ndarray], ...], bool]:
        """``(pairs, time)``: the ``(scratch, live)`` array views of the inputs the observation reads (each a
        C-contiguous float64 array of the same size), and whether it reads ``time``; made once per live data."""
        return self._views_of(self.env.data)[1:3]

    def _views_of(self, live: mujoco.MjData) -> tuple:
        """``(live, pairs, time, copy table, compiled copy)`` for the data ``env.data`` points to, cached: the live
        data, and the snapshot a vector env's sensor swaps in for a terminal observation (rebuilding them at
        every swap would cost more than the copies)."""
        views = self._input_views
        if views is not None and views[0] is live:
            return views
        cache = self.__dict__.setdefault("_views_cache", {})
        views = cache.get(id(live))
        if views is None or views[0] is not live:
            from ..engine.fused import address, copy_entries
            from ..observers.base import _compiled_entry

            pairs = tuple(
                (getattr(self._scratch, name), getattr(live, name)) for name in self._input_fields if name != "time"
            )
            # [to, from, size] of each pair (the views in ``pairs`` keep the buffers alive)
            table = np.array([(address(to), address(source), to.size) for to, source in pairs], dtype=np.int64).reshape(
                -1, 3
            )
            views = (live, pairs, "time" in self._input_fields, table, _compiled_entry(copy_entries, (table,)))
            if len(cache) >= 4:
                cache.clear()
            cache[id(live)] = views
        self._input_views = views
        return views

    def _copy_inputs(self) -> None:
        """``_fill_inputs`` of the scratch data from the live data, per step: one compiled call over the views of
        :meth:`input_views` (a NumPy copy per field costs ~2 us right after the physics)."""
        views = self._views_of(self.env.data)
        views[4](views[3])
        if views[2]:
            self._scratch.time = views[0].time

    def _probe_fresh(self) -> bool:
        """Whether ``_get_obs`` returns a new array at every call, sharing no memory with the data it reads: two
        evaluations at different states, the first result must be an ndarray and unchanged by the second. Then
        the defensive copy of every observation is skipped."""
        rng = np.random.default_rng(777)
        first = None
        for _ in range(2):
            qpos = np.array(self.env.data.qpos)
            mujoco.mj_integratePos(self.model, qpos, 0.1 * rng.standard_normal(self.model.nv), 1.0)
            self._fill(self._scratch, qpos, rng.standard_normal(self.model.nv), source=self._random_inputs(rng))
            live = self.env.data
            self.env.data = self._scratch
            try:
                obs = self._obs_function(self.env)
            finally:
                self.env.data = live
            if first is None:
                if type(obs) is not np.ndarray:
                    return False
                first, kept = obs, np.array(obs, copy=True)
        return obs is not first and np.array_equal(first, kept, equal_nan=True)

    def _probe_observation_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(index, bounds)`` such that the observation is ``obs[i] = min(max(x[index[i]], bounds[0, i]),
        bounds[1, i])`` with ``x = [qpos, qvel]``, or None if it is not such a selection of the state.

        Only for an observation of ``qpos``/``qvel`` alone (``_bare``): Hopper's ``(qpos[1:], clip(qvel, -10,
        10))``, HalfCheetah's, InvertedPendulum's... Then the wrapper's compiled call builds it (no Python
        ``_get_obs``, no finiteness check: a clipped selection of a finite state is finite). Found by
        perturbing each entry of ``x`` in turn (every observation entry must follow exactly one, with unit slope,
        and equal it), the bounds from ``x = +-1e300``; accepted only if it reproduces ``_get_obs`` bit for bit
        at random states of magnitudes 1e-6 to 1e8 (``float64`` one-dimensional observations only).
        """
        model = self.model
        nq, nv = model.nq, model.nv
        scratch = mujoco.MjData(model)

        def evaluate(x):
            self._fill(scratch, x[:nq], x[nq:], inputs=False)
            return self._evaluate(scratch, "none")

        def select(x, index, bounds):
            return np.minimum(np.maximum(x[index], bounds[0]), bounds[1])

        rng = np.random.default_rng(97531)
        x0 = 1e-3 * rng.standard_normal(nq + nv)
        try:
            obs0 = evaluate(x0)
            if type(obs0) is not np.ndarray or obs0.dtype != np.float64 or obs0.ndim != 1:
                return None
            index = np.full(obs0.size, -1, dtype=np.int64)
            for j in range(nq + nv):
                x = x0.copy()
                x[j] += 1e-3
                obs = evaluate(x)
                if obs.shape != obs0.shape:
                    return None
                changed = np.flatnonzero(obs != obs0)
                if np.any(index[changed] >= 0):  # an entry that follows two state entries: not a selection
                    return None
                index[changed] = j
            if np.any(index < 0) or not np.array_equal(obs0, x0[index]):  # constants, or not the entry itself
                return None
            huge = 1e300
            high, low = evaluate(np.full(nq + nv, huge)), evaluate(np.full(nq + nv, -huge))
            bounds = np.stack([np.where(low == -huge, -np.inf, low), np.where(high == huge, np.inf, high)])
            for scale in (1e-6, 1e-2, 1.0, 10.0, 1e2, 1e4, 1e8):
                for _ in range(2):
                    x = scale * rng.standard_normal(nq + nv)
                    if not np.array_equal(evaluate(x), select(x, index, bounds)):
                        return None
        except Exception:
            return None
        return index, np.ascontiguousarray(bounds)

    def _probe_observation_entries(self) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray] | None:
        """``(fields, flat_index, bounds, functions)`` such that, after the forward-pass stages, the observation is
        ``obs[i] = min(max(f_i(getattr(data, fields[i]).flat[flat_index[i]]), bounds[0, i]), bounds[1, i])`` with
        ``f_i`` the identity, ``sin`` or ``cos`` (``functions[i]``, codes of :func:`~._fused.gather_entries`), or
        None.

        Humanoid's ``(qpos[2:], qvel, cinert[1:], cvel[1:], qfrc_actuator[6:], cfrc_ext[1:])``, Ant's clipped
        contact forces, InvertedDoublePendulum's ``(qpos[:1], sin(qpos[1:]), cos(qpos[1:]), clip(qvel),
        clip(qfrc_constraint[:1]))``: the scratch evaluation then gathers the entries in one compiled call (with
        the finiteness check) instead of the environment's ``_get_obs`` (10-20 us of NumPy calls right after the
        physics). Found by writing distinct values into every float64 field of computed scratch data and calling
        ``_get_obs`` on it as it is (each observation entry must be one of those values, or the sine or cosine of
        one: the values are distinct in magnitude and below 1/2, where both are one-to-one), the bounds from all
        fields at +-1e300 (none for sines and cosines); accepted only if the compiled gather reproduces
        ``_get_obs`` bit for bit at random states and random inputs through the forward-pass stages, and, with
        sines or cosines, if the compiled ones equal NumPy's (:func:`~._fused.entry_functions_match_numpy`)
        (``float64`` one-dimensional observations only).
        """
        from ..engine.fused import ENTRY_COS, ENTRY_IDENTITY, ENTRY_SIN, entry_functions_match_numpy, gather_entries

        model = self.model
        rng = np.random.default_rng(8642)

        def computed(scale):
            scratch = mujoco.MjData(model)
            qpos = np.array(self.env.data.qpos)
            mujoco.mj_integratePos(model, qpos, scale * rng.standard_normal(model.nv), 1.0)
            self._fill(
                scratch,
                qpos,
                scale * rng.standard_normal(model.nv),
                inputs=self.copies_inputs,
                source=self._random_inputs(rng),
            )
            self._compute(scratch, self.pipeline)
            return scratch

        try:
            scratch = computed(0.1)
            obs0 = self._call_observation(scratch)
            if type(obs0) is not np.ndarray or obs0.dtype != np.float64 or obs0.ndim != 1 or not obs0.size:
                return None
            fields = []
            for name in dir(scratch):
                if name.startswith("_"):
                    continue
                try:
                    value = getattr(scratch, name)
                except Exception:
                    continue
                if (
                    isinstance(value, np.ndarray)
                    and value.dtype == np.float64
                    and value.size
                    and value.flags.c_contiguous
                ):
                    fields.append((name, value))
            total = sum(value.size for _, value in fields)
            # distinct magnitudes in (0, 0.5) (inside any plausible clip), random signs, in random order
            values = rng.permutation((np.arange(total) + 1.0) / (2.0 * (total + 1)) * rng.choice([-1.0, 1.0], total))
            position, start = {}, 0
            for name, value in fields:
                value.reshape(-1)[:] = values[start : start + value.size]
                for k in range(value.size):
                    position[values[start + k]] = (name, k, ENTRY_IDENTITY)
                start += value.size
            for code, function in ((ENTRY_SIN, np.sin), (ENTRY_COS, np.cos)):
                for v, out in zip(values, function(values), strict=True):
                    position.setdefault(out, position[v][:2] + (code,))
            marked = self._call_observation(scratch)
            if marked.shape != obs0.shape or not all(v in position for v in marked):
                return None
            names = tuple(position[v][0] for v in marked)
            flat = np.array([position[v][1] for v in marked], dtype=np.int64)
            functions = np.array([position[v][2] for v in marked], dtype=np.int64)
            if np.any(functions != ENTRY_IDENTITY) and not entry_functions_match_numpy():
                return None
            extremes = []
            for huge in (-1e300, 1e300):
                for _, value in fields:
                    value[...] = huge
                out = self._call_observation(scratch)
                extremes.append(np.where((out == huge) | (functions != ENTRY_IDENTITY), np.copysign(np.inf, huge), out))
            bounds = np.ascontiguousarray(np.stack(extremes))
            for scale in (0.01, 0.1, 0.5, 1.0, 3.0):
                for _ in range(2):
                    scratch = computed(scale)
                    want = self._call_observation(scratch)
                    got = np.empty(len(names))
                    addresses = _entry_addresses({name: getattr(scratch, name) for name in set(names)}, names, flat)
                    gather_entries(addresses, functions, bounds, got)  # the run-time gather itself
                    if not np.array_equal(want, got, equal_nan=True):
                        return None
        except Exception:
            return None
        return names, flat, bounds, functions

    def _probe_pipeline(self) -> tuple[str, bool]:
        """``(pipeline, copies_inputs)``: the cheapest evaluation that reproduces the forward-computed observation
        at random states (see module docstring): ``"none"`` (qpos/qvel only, with or without the inputs),
        ``"kinematics"`` (kinematics, com frames and velocities, tendons, actuation: no collision or constraint
        solver) or ``"forward"``. Fields not copied or computed are NaN in the probe, so any read of them shows."""
        rng = np.random.default_rng(12345)
        model, live = self.model, self.env.data
        keep = {"qpos", "qvel"} | ({"cfrc_ext"} if self.contact_forces != "estimated" else set())
        states = []
        for _ in range(2):
            qpos = np.array(live.qpos)
            mujoco.mj_integratePos(model, qpos, 0.1 * rng.standard_normal(model.nv), 1.0)
            states.append((qpos, rng.standard_normal(model.nv), self._random_inputs(rng)))
        expected = []
        for qpos, qvel, source in states:
            reference = mujoco.MjData(model)
            self._fill(reference, qpos, qvel, source=source)
            expected.append(self._evaluate(reference, "forward"))
        for pipeline, inputs in (("none", False), ("none", True), ("kinematics", True)):
            ok = True
            for (qpos, qvel, source), want in zip(states, expected, strict=True):
                poisoned = mujoco.MjData(model)
                skip = keep | (set(_INPUTS) if inputs else set())
                for name in dir(poisoned):
                    if name.startswith("_") or name in skip:
                        continue
                    try:
                        value = getattr(poisoned, name)
                    except Exception:
                        continue
                    if isinstance(value, np.ndarray) and value.dtype == np.float64 and value.size:
                        value[...] = np.nan
                self._fill(poisoned, qpos, qvel, inputs=inputs, source=source)
                try:
                    got = self._evaluate(poisoned, pipeline)
                except Exception:
                    ok = False
                    break
                if got.shape != want.shape or not np.all(np.isfinite(got)) or not np.array_equal(got, want):
                    ok = False
                    break
            if ok:
                return pipeline, inputs
        return "forward", True

    def _probe_contacts(self) -> bool:
        """Whether the observation reads ``cfrc_ext`` (Ant, Humanoid): evaluated at a random state with
        ``cfrc_ext`` NaN (not recomputed), does it come out non-finite? If not, the per-step copy of the contact
        forces is skipped, and a ``contact_forces`` mode other than ``"sensor"`` is refused."""
        mode, self.contact_forces = self.contact_forces, "sensor"  # no recomputation during the probe
        rng = np.random.default_rng(54321)
        qpos = np.array(self.env.data.qpos)
        mujoco.mj_integratePos(self.model, qpos, 0.1 * rng.standard_normal(self.model.nv), 1.0)
        scratch = mujoco.MjData(self.model)
        self._fill(scratch, qpos, rng.standard_normal(self.model.nv), source=self._random_inputs(rng))
        self.reads_contacts = False
        try:
            scratch.cfrc_ext[:] = np.nan
            obs = self._evaluate(scratch, self.pipeline)
            return not bool(np.all(np.isfinite(obs)))
        except Exception:
            return True
        finally:
            self.reads_contacts = True
            self.contact_forces = mode

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
        env, model = self.env, self.model
        mj_step = mujoco.mj_step

        def step_recording(ctrl, n_frames):
            data = env.data
            data.ctrl[:] = ctrl
            # the recording loop written out: a Python call per physics step costs about as much as a small
            # model's physics step
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

    __slots__ = ("_pairs", "count", "every", "fields", "n", "rows")

    def __init__(self, every: int, sizes: dict[str, int], capacity: int):
        self.every = int(every)
        self.fields = tuple(sizes)
        self.rows = {name: np.zeros((max(1, int(capacity)), size)) for name, size in sizes.items()}
        self.n = self.count = 0
        self._pairs = (None, ())

    def start(self) -> None:
        """Begin a control period: no rows taken, the step counter at zero."""
        self.n = self.count = 0

    def destinations(self, data: mujoco.MjData, n_steps: int) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """``(buffer, field)`` pairs, ``field`` the live view of ``data``, with room in every buffer for the rows
        of ``n_steps`` more physics steps: the hook writes row ``n`` as ``buffer[n] = field``."""
        need = self.n + (self.count + n_steps) // self.every
        data_of, pairs = self._pairs
        if data_of is not data or any(buffer.shape[0] < need for buffer, _ in pairs):
            for name in self.fields:
                buffer = self.rows[name]
                if buffer.shape[0] < need:
                    grown = np.zeros((max(need, 2 * buffer.shape[0]), buffer.shape[1]))
                    grown[: self.n] = buffer[: self.n]
                    self.rows[name] = grown
            pairs = tuple((self.rows[name], getattr(data, name)) for name in self.fields)
            self._pairs = (data, pairs)
        return pairs

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
        self._pairs = (None, ())


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
