r"""An environment's own observation function evaluated on scratch ``MjData`` at a sensed state.

The sensed observation is the environment's observation at the measured ``qpos`` and estimated ``qvel``, with
everything derived from them (Humanoid's ``cinert``/``cvel``/``qfrc_actuator``, Pusher's body positions,
InvertedDoublePendulum's constraint force) recomputed: :class:`ScratchObservation` copies into a scratch ``MjData``
the inputs a real controller knows (``ctrl``, ``act``, ``time``, mocap poses, applied forces, ``userdata``, which
equality constraints are on) and the sensed state, runs the forward-pass stages the observation needs and calls the
observation function on it. The live simulation is never changed. The function must read the data it is given: one
check at construction sets every floating-point field of the live data to NaN for one evaluation (then restores it
bit for bit) and refuses a function whose result moved, since it would return the true state (a view of
``data.qpos`` kept since ``__init__``).

What the observation needs is *probed* once at construction, with no per-environment table: the observation is
evaluated on scratch data whose other fields are all NaN, after no computation, then after the kinematic stages only
(no collision detection or constraint solver); the first that comes out finite and equal to the ``mj_forward``
result at random states is used (Hopper, HalfCheetah, Ant: none; Humanoid: kinematics; InvertedDoublePendulum, whose
observation has a constraint force: the full forward pass). What collision detection makes (``ncon``, ``contact``:
counts and structures no NaN marks, empty where no geoms touch) is probed with a copy of the model whose contact
margin makes the geoms touch, then with the contacts' numbers moved and the contacts dropped: an observation that
follows takes the full forward pass. The same NaN probe finds whether the observation reads ``cfrc_ext``. Which of
the inputs (``ctrl``, applied forces, ``time``, ...) it reads is probed at random nonzero inputs, each replaced in
turn by other random values and by NaN (MuJoCo zeroes a NaN ``ctrl``, and the live ``ctrl`` is zero at construction:
Humanoid's ``qfrc_actuator`` reads ``ctrl`` only through the actuation); with the full forward pass every input is
copied (constraint forces depend on the inputs only while a constraint is active, which a probe at a few states need
not see). Last, whether the function returns a fresh array. Only what is read is copied at every step, and fresh
arrays are not copied again (:meth:`ScratchObservation.observe_scratch`, the per-step path). Observations that are
clipped selections of the state (:attr:`ScratchObservation.observation_map`) or of ``MjData`` entries and their
sines and cosines (:attr:`ScratchObservation.observation_entries`) are built by compiled code instead of the Python
function, with the same numbers; ``tests/test_wrapper.py`` checks the result against a full forward pass at run-time
inputs and active joint limits on every v5 environment, and :meth:`ScratchObservation.verify` checks the shortcut
again at every reset.

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

import mujoco
import numpy as np

from .._validation import as_real_array
from .fused import (
    ENTRY_COS,
    ENTRY_IDENTITY,
    ENTRY_SIN,
    EntryGather,
    InputCopy,
    entry_functions_match_numpy,
)

__all__ = [
    "CONTACT_FORCES",
    "INPUT_FIELDS",
    "OBSERVED_FIELDS",
    "GatheredObservations",
    "ScratchObservation",
    "copy_observed_fields",
    "shared_selection",
]

#: sources of the contact forces (``cfrc_ext``) in a sensed observation: see :class:`ScratchObservation`
CONTACT_FORCES = ("sensor", "estimated", "zero")
#: the controller's inputs that ``observation`` copies from the live data (those the observation reads, probed)
INPUT_FIELDS = ("time", "ctrl", "act", "mocap_pos", "mocap_quat", "qfrc_applied", "xfrc_applied", "userdata")
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


@contextlib.contextmanager
def _quiet_mujoco():
    """Within the block, MuJoCo's warnings (``Nan, Inf or huge value in CTRL``, ...) are dropped instead of printed
    and appended to ``MUJOCO_LOG.TXT`` in the working directory: the probes provoke them on purpose."""
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_ignore_warning)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def _ignore_warning(message: str) -> None:
    pass


def _float_fields(data: mujoco.MjData):
    """``(name, array)`` of every nonempty float64 array field of ``data`` (the probes poison, mark or save them)."""
    for name in dir(data):
        if name.startswith("_"):
            continue
        try:
            value = getattr(data, name)
        except Exception:
            continue
        if isinstance(value, np.ndarray) and value.dtype == np.float64 and value.size:
            yield name, value


def _same(a, b: np.ndarray) -> bool:
    """``np.array_equal(a, b)`` for an observation ``a`` (any array-like) and an ndarray ``b``, at a third of its
    cost (it runs at every reset: :meth:`ScratchObservation.verify`)."""
    a = np.asarray(a)
    return a.shape == b.shape and bool((a == b).all())


def _select(x: np.ndarray, index: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """``np.clip(x[index], bounds[0], bounds[1])`` in NumPy: an :attr:`ScratchObservation.observation_map`."""
    return np.minimum(np.maximum(x[index], bounds[0]), bounds[1])


class ScratchObservation:
    """An observation function evaluated on a scratch ``MjData`` at a given state (see the module docstring).

    Parameters
    ----------
    model : mujoco.MjModel
    live : callable
        ``live() -> MjData``: the simulation's live data (read for the controller inputs and ``cfrc_ext``).
    function : callable
        ``function(data) -> ndarray``: the environment's observation computed from ``data`` as it is.
    contact_forces : {"sensor", "estimated", "zero"}
    name : str
        The environment's name, for error messages.

    Attributes
    ----------
    model : mujoco.MjModel
        The model the observation is evaluated on (:meth:`follow` moves it to another).
    pipeline : {"none", "kinematics", "forward"}
        The forward-pass stages the observation needs (probed).
    input_fields : tuple of str
        The controller inputs it reads (probed).
    copies_inputs, reads_contacts, fresh_observation : bool
        Whether it reads controller inputs, ``cfrc_ext``; whether ``function`` returns a fresh array (probed).
    observation_map : tuple of ndarray or None
        ``(index, bounds)`` when the observation is a clipped selection of ``[qpos, qvel]``.
    observation_entries : tuple or None
        ``(fields, flat_index, bounds, functions)`` when it is a clipped selection of ``MjData`` entries, or of
        their sines and cosines, after the forward-pass stages.
    checks_observation : bool
        :meth:`observe_scratch` raises ``ValueError`` on a non-finite observation itself.

    Raises
    ------
    ValueError
        ``contact_forces`` unknown, or other than ``"sensor"`` for an observation without contact forces; a
        ``function`` that reads the live simulation instead of the data it is given.
    """

    def __init__(self, model: mujoco.MjModel, live: Callable, function: Callable, contact_forces: str, name: str):
        if contact_forces not in CONTACT_FORCES:
            raise ValueError(
                f"expected contact_forces in {', '.join(map(repr, CONTACT_FORCES))}, actual value: {contact_forces!r}"
            )
        self.live, self.function, self.contact_forces, self.name = live, function, contact_forces, name
        self._probe(model)

    def follow(self, model: mujoco.MjModel) -> bool:
        """Evaluate the observation on ``model`` from now on, if it is not :attr:`model` already; returns whether it
        was another.

        An environment may rebuild its model at reset (a procedurally generated world), and a copy of a wrapper
        (pickled, deep-copied) holds a copy of the model it was built on while Gymnasium rebuilds the copied
        environment, with a model of its own, from its constructor: evaluated on any other model than the live one,
        the observation would miss what differs (a link's length; a mass randomised in place). Everything probed on
        the first model is probed again on this one, at the cost of the construction (17 ms for InvertedPendulum, 50 ms
        for Humanoid).
        """
        if model is self.model:
            return False
        self._probe(model)
        return True

    def _probe(self, model: mujoco.MjModel) -> None:
        """Make the scratch data of ``model`` and probe what the observation reads there (see the attributes)."""
        name, contact_forces = self.name, self.contact_forces
        self.model = model
        self.fresh_observation = False
        self.observation_map = self.observation_entries = None
        self._scratch = mujoco.MjData(model)
        self.pipeline, self.copies_inputs, self.reads_contacts = "forward", True, True
        self.input_fields = INPUT_FIELDS
        self.copies_equality = False
        with _quiet_mujoco():  # the probes feed MuJoCo NaN and huge inputs on purpose
            self._check_reads_given_data(name)
            self.pipeline, self.copies_inputs = self._probe_pipeline()
            #: which equality constraints are on (``eq_active``, which an environment may switch: a weld for a
            #: grasp) is copied at every evaluation where the constraint solver runs or the observation reads it (a
            #: uint8 array, outside the compiled copies)
            self.copies_equality = model.neq > 0 and (self.pipeline == "forward" or self._reads_equality())
            self.reads_contacts = self._probe_contacts()
            if contact_forces != "sensor" and not self.reads_contacts:
                raise ValueError(
                    f"expected contact_forces='sensor' for {name}, whose observation has no contact "
                    f"forces (cfrc_ext), actual value: {contact_forces!r}"
                )
            if self.copies_inputs and self.pipeline != "forward":
                # the constraint forces of a full forward pass depend on every applied input whenever a constraint
                # is active, which a probe at a few states need not see (InvertedDoublePendulum's rail limit):
                # with the forward pass, every input is copied
                self.input_fields = self._probe_input_fields()
                self.copies_inputs = bool(self.input_fields)
            self.fresh_observation = self._probe_fresh()
            #: the observation needs nothing but the sensed qpos/qvel on the scratch data (Hopper, HalfCheetah, ...)
            self._bare = (
                self.pipeline == "none"
                and not self.copies_inputs
                and not self.reads_contacts
                and not self.copies_equality
            )
            self.observation_map = self._probe_observation_map() if self._bare else None
            self.observation_entries = None if self._bare else self._probe_observation_entries()
        self._views()

    def _views(self) -> None:
        # cached views of the scratch arrays written at every observation (MjData builds a view per access)
        self._scratch_qpos, self._scratch_qvel = self._scratch.qpos, self._scratch.qvel
        self._inputs = None
        self._inputs_cache = {}
        self._gather = None
        self._verification = None  # made by the first verify()
        entries = self.observation_entries
        if entries is not None:  # the observation's entries in this scratch data, gathered by one compiled call
            names, flat, bounds, functions = entries
            fields = {name: getattr(self._scratch, name) for name in set(names)}
            self._gather = EntryGather(fields, names, flat, functions, bounds)
        self.checks_observation = self._gather is not None

    def compute(self) -> None:
        """The forward-pass stages the observation needs, on the scratch data as it is."""
        self._compute(self._scratch, self.pipeline)

    @property
    def gather(self) -> EntryGather | None:
        """The compiled gather of :attr:`observation_entries` from the scratch data, or None."""
        return self._gather

    @property
    def scratch(self) -> mujoco.MjData:
        """The scratch ``MjData`` (never the live one)."""
        return self._scratch

    def __getstate__(self):
        state = dict(self.__dict__)
        for name in ("_scratch_qpos", "_scratch_qvel", "_inputs", "_inputs_cache", "_gather", "_verification"):
            state.pop(name, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._views()

    def _fill(self, scratch: mujoco.MjData, qpos, qvel, inputs: bool = True, source: mujoco.MjData | None = None):
        scratch.qpos[:] = qpos
        scratch.qvel[:] = qvel
        if inputs:
            self._fill_inputs(scratch, source)

    def _fill_inputs(self, scratch: mujoco.MjData, source: mujoco.MjData | None = None) -> None:
        """Copy the controller inputs the observation reads from ``source`` (default: the live data)."""
        source = self.live() if source is None else source
        for name in self.input_fields:
            if name == "time":
                scratch.time = source.time
            else:
                getattr(scratch, name)[:] = getattr(source, name)

    def _random_inputs(self, rng: np.random.Generator) -> mujoco.MjData:
        """Data whose controller inputs (:data:`INPUT_FIELDS`) are random, finite and nonzero, for the probes.

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
        source.userdata[:] = rng.standard_normal(model.nuserdata)
        return source

    def _near_live(self, rng: np.random.Generator, scale: float = 0.1) -> np.ndarray:
        """A configuration of the probes: the live ``qpos`` moved by a random tangent step of size ``scale``."""
        qpos = np.array(self.live().qpos)
        mujoco.mj_integratePos(self.model, qpos, scale * rng.standard_normal(self.model.nv), 1.0)
        return qpos

    def _check_reads_given_data(self, name: str) -> None:
        """Refuse an observation function that reads the live simulation instead of the data it is given.

        Its result on scratch data must not change when every floating-point field of the live data does (set to
        NaN for one evaluation, then restored bit for bit); for an observation with noise of its own, which
        changes from call to call, no entry may turn non-finite. One that does, e.g. from a view of
        ``data.qpos`` kept since ``__init__``, would return the true state where the sensed one is asked for,
        silently.
        """
        model, live = self.model, self.live()
        rng = np.random.default_rng(97531)
        qpos = self._near_live(rng)
        scratch = mujoco.MjData(model)
        self._fill(scratch, qpos, rng.standard_normal(model.nv), source=self._random_inputs(rng))
        mujoco.mj_forward(model, scratch)
        scratch.cfrc_ext[:] = live.cfrc_ext
        want = np.array(self.function(scratch), copy=True)
        # an observation with noise of its own differs from call to call: then only NaN coming through tells
        deterministic = np.array_equal(np.array(self.function(scratch)), want, equal_nan=True)
        saved = {field: value.copy() for field, value in _float_fields(live)}
        try:
            for field in saved:
                getattr(live, field)[...] = np.nan
            try:
                got = np.array(self.function(scratch), copy=True)
            except Exception:
                got = None
        finally:
            for field, value in saved.items():
                getattr(live, field)[...] = value
        if got is None or got.shape != want.shape:
            moved = True
        elif deterministic:
            moved = not np.array_equal(got, want, equal_nan=True)
        else:
            moved = bool(np.any(np.isfinite(want) & ~np.isfinite(got)))
        if moved:
            raise ValueError(
                f"expected an observation function of {name} that reads the state from the data it is given "
                "(env.data, which the wrapper points at scratch data holding the sensed state), actual value: one "
                "whose result follows the live simulation; a view of data.qpos or data.qvel kept from __init__ "
                "reads the true state"
            )

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
                ("userdata", model.nuserdata),
            )
            if size
        ]
        rng = np.random.default_rng(2468)
        cases = []
        for _ in range(2):
            qpos = self._near_live(rng)
            cases.append((qpos, rng.standard_normal(model.nv), self._random_inputs(rng), self._random_inputs(rng)))
        self.input_fields = tuple(fields)
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
                    self.input_fields = tuple(fields)
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
        self.input_fields = tuple(fields)
        return tuple(needed)

    def _evaluate(self, scratch: mujoco.MjData, pipeline: str) -> np.ndarray:
        self._compute(scratch, pipeline)
        return self._call_observation(scratch)

    def _call_observation(self, scratch: mujoco.MjData) -> np.ndarray:
        """The environment's ``_get_obs`` on ``scratch`` as it is (nothing computed)."""
        obs = self.function(scratch)
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
                scratch.cfrc_ext[:] = self.live().cfrc_ext
            elif self.contact_forces == "zero":
                scratch.cfrc_ext[:] = 0.0

    def observation(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """The environment's observation at ``(qpos, qvel)``, evaluated on scratch data (see module docstring)."""
        qpos, qvel = as_real_array("qpos", qpos), as_real_array("qvel", qvel)
        if qpos.shape != self._scratch_qpos.shape or qvel.shape != self._scratch_qvel.shape:
            raise ValueError(
                f"expected qpos of shape {self._scratch_qpos.shape} and qvel of shape {self._scratch_qvel.shape}, "
                f"actual value: shapes {qpos.shape} and {qvel.shape}"
            )
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
            obs = self.function(self._scratch)
            return obs if self.fresh_observation else np.array(obs, copy=True)
        if self.copies_inputs:
            if not inputs_copied:
                self._copy_inputs()
            elif self._inputs.reads_time:
                self._scratch.time = self.live().time
        if self.copies_equality:
            self._scratch.eq_active[:] = self.live().eq_active
        if self._gather is None:
            return self._evaluate(self._scratch, self.pipeline)
        self._compute(self._scratch, self.pipeline)  # then the entries, compiled, instead of _get_obs
        obs = np.empty(len(self._gather))
        bad = self._gather(obs)
        if bad != -1:
            raise ValueError(f"expected a finite sensed observation, actual value: {obs[bad]!r} at entry {bad}")
        return obs

    def verify(self, model: mujoco.MjModel | None = None) -> bool:
        """Check the compiled shortcuts (:attr:`observation_map`, :attr:`observation_entries`) against the observation
        function; drop them if they differ. Returns whether they hold (True without any).

        ``model``: the environment's model now, followed first (:meth:`follow`).

        The shortcuts are probed at construction as functions of ``MjData`` alone. An observation that also reads
        the environment's own attributes may be such a function then and not later: ``qpos - self.goal`` with a
        goal still zero at construction and drawn at every reset is a selection of the state only until the first
        reset. The wrappers call this at every reset: the function and the shortcut must agree on the live data as
        the environment left it (an offset, a scale or another selection shows there), then on data of the check's
        own with every field the shortcut reads at -1e300 and at +1e300 (the clip bounds; sines and cosines
        excepted), else the function computes the observation from then on (the cost of :meth:`observe_scratch`
        without a shortcut). Both sides read the same fields, so nothing is recomputed: the data need not hold a
        consistent state, and the probes found the observation a function of these fields alone. An attribute
        changed in the middle of an episode is seen at the next reset only. Cost: three evaluations of the
        function and of the shortcut, 37-88 us (InvertedPendulum to Hopper, on a 2-core machine).
        """
        if model is not None:
            self.follow(model)
        if self.observation_map is None and self.observation_entries is None:
            return True
        if self._verification is None:
            self._verification = self._verification_plan()
        data, fields, identity, shortcut = self._verification
        live = self.live()
        try:
            for name, value in fields.items():
                value[...] = getattr(live, name)
            holds = _same(self.function(live), shortcut())
            with _quiet_mujoco():  # a function that calls MuJoCo on its data would warn of the huge values
                for huge in (-1e300, 1e300):
                    for value in fields.values():
                        value[...] = huge
                    holds = holds and _same(np.asarray(self.function(data))[identity], shortcut()[identity])
        except Exception:
            holds = False
        if not holds:
            self.observation_map = self.observation_entries = None
            self._views()
        return holds

    def _verification_plan(self) -> tuple:
        """``(data, fields, identity, shortcut)`` for :meth:`verify`: its own ``MjData``, the fields the shortcut
        reads there (by name), the entries whose clip bounds it checks, and ``shortcut()``, the shortcut's
        observation of ``data``."""
        data = mujoco.MjData(self.model)
        if self.observation_entries is None:
            index, bounds = self.observation_map
            nq = self.model.nq
            x = np.empty(nq + self.model.nv)
            fields = {"qpos": data.qpos, "qvel": data.qvel}

            def shortcut():
                x[:nq] = fields["qpos"]
                x[nq:] = fields["qvel"]
                return _select(x, index, bounds)

            return data, fields, slice(None), shortcut
        names, flat, bounds, functions = self.observation_entries
        fields = {name: getattr(data, name) for name in set(names)}
        gather = EntryGather(fields, names, flat, functions, bounds)

        def shortcut():
            obs = np.empty(len(gather))
            gather(obs)
            return obs

        return data, fields, functions == ENTRY_IDENTITY, shortcut

    def input_views(self) -> tuple[tuple[tuple[np.ndarray, np.ndarray], ...], bool]:
        """``(pairs, time)``: the ``(scratch, live)`` array views of the inputs the observation reads (each a
        C-contiguous float64 array of the same size), and whether it reads ``time``; made once per live data."""
        inputs = self.inputs_of(self.live())
        return inputs.pairs, inputs.reads_time

    def inputs_of(self, live: mujoco.MjData) -> InputCopy:
        """The compiled copy of the inputs the observation reads from ``live`` into the scratch data, cached per
        data: the live data, and the snapshot a vector env's sensor swaps in for a terminal observation
        (rebuilding it at every swap would cost more than the copies)."""
        inputs = self._inputs
        if inputs is not None and inputs.source is live:
            return inputs
        inputs = self._inputs_cache.get(id(live))
        if inputs is None or inputs.source is not live:
            pairs = tuple(
                (getattr(self._scratch, name), getattr(live, name)) for name in self.input_fields if name != "time"
            )
            inputs = InputCopy(pairs, source=live, reads_time="time" in self.input_fields)
            if len(self._inputs_cache) >= 4:
                self._inputs_cache.clear()
            self._inputs_cache[id(live)] = inputs
        self._inputs = inputs
        return inputs

    def _copy_inputs(self) -> None:
        """The inputs the observation reads, from the live data into the scratch data: one compiled call (a
        NumPy copy per field costs ~2 us right after the physics)."""
        inputs = self.inputs_of(self.live())
        inputs()
        if inputs.reads_time:
            self._scratch.time = inputs.source.time

    def _probe_fresh(self) -> bool:
        """Whether ``_get_obs`` returns a new array at every call, sharing no memory with the data it reads: two
        evaluations at different states (each through the forward-pass stages the observation needs, so that what
        it reads changes), the first result must be an ndarray, share no memory with the second and be unchanged
        by it. Then the defensive copy of every observation is skipped."""
        rng = np.random.default_rng(777)
        first = None
        for _ in range(2):
            qpos = self._near_live(rng)
            self._fill(self._scratch, qpos, rng.standard_normal(self.model.nv), source=self._random_inputs(rng))
            self._compute(self._scratch, self.pipeline)
            obs = self.function(self._scratch)
            if first is None:
                if type(obs) is not np.ndarray:
                    return False
                first, kept = obs, np.array(obs, copy=True)
        return obs is not first and not np.may_share_memory(obs, first) and np.array_equal(first, kept, equal_nan=True)

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
                    if not np.array_equal(evaluate(x), _select(x, index, bounds)):
                        return None
        except Exception:
            return None
        return index, np.ascontiguousarray(bounds)

    def _probe_observation_entries(self) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray] | None:
        """``(fields, flat_index, bounds, functions)`` such that, after the forward-pass stages, the observation is
        ``obs[i] = min(max(f_i(getattr(data, fields[i]).flat[flat_index[i]]), bounds[0, i]), bounds[1, i])`` with
        ``f_i`` the identity, ``sin`` or ``cos`` (``functions[i]``, codes of
        :func:`~smo_gym.engine.fused.gather_entries`), or None.

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
        model = self.model
        rng = np.random.default_rng(8642)

        def computed(scale):
            scratch = mujoco.MjData(model)
            qpos = self._near_live(rng, scale)
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
            fields = [(name, value) for name, value in _float_fields(scratch) if value.flags.c_contiguous]
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
                    fields = {name: getattr(scratch, name) for name in set(names)}
                    EntryGather(fields, names, flat, functions, bounds)(got)  # the run-time gather itself
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
        model = self.model
        keep = {"qpos", "qvel"} | ({"cfrc_ext"} if self.contact_forces != "estimated" else set())
        states = []
        for _ in range(2):
            qpos = self._near_live(rng)
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
                for name, value in _float_fields(poisoned):
                    if name not in skip:
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
                return ("forward", True) if self._reads_collisions(*states[0]) else (pipeline, inputs)
        return "forward", True

    def _reads_collisions(self, qpos: np.ndarray, qvel: np.ndarray, source: mujoco.MjData) -> bool:
        """Whether the observation reads what collision detection makes: ``ncon``, the ``contact`` structures, the
        constraint rows. The NaN probes cannot mark those (counts and structures, empty where no geoms touch: a
        foot-contact flag read at probe states in the air). Here the full forward pass runs at one state with a
        copy of the model whose contact margin (``o_margin`` override) makes the geoms touch (the largest margin
        whose contacts fit MuJoCo's arena), then the contacts' and constraint rows' numbers are moved and the
        contacts dropped (``ncon = 0``): an observation that follows either reads them."""
        wide = copy.deepcopy(self.model)
        wide.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_OVERRIDE
        for margin in (2.0, 0.2, 0.02):
            wide.opt.o_margin = margin * max(float(self.model.stat.extent), 0.5)
            data = mujoco.MjData(wide)
            self._fill(data, qpos, qvel, source=source)
            try:
                mujoco.mj_forward(wide, data)
                break
            except Exception:  # mujoco.FatalError: the contacts overflow the arena
                continue
        else:
            return True
        if data.ncon == 0:
            return False
        try:
            before = np.array(self.function(data), copy=True)
            contacts = data.contact
            for name in ("dist", "pos", "frame", "includemargin"):
                getattr(contacts, name)[...] = -1.5 * getattr(contacts, name) - 0.25
            for name, value in _float_fields(data):
                if name.startswith("efc_"):
                    value[...] = -1.5 * value - 0.25
            moved = np.array(self.function(data), copy=True)
            data.ncon = 0
            dropped = np.array(self.function(data), copy=True)
        except Exception:
            return True
        return not (_same(moved, before) and _same(dropped, before))

    def _reads_equality(self) -> bool:
        """Whether the observation reads ``eq_active`` itself (a grasp flag): evaluated at a random state with every
        equality constraint switched, does it change? (Through the constraint solver it matters only to the full
        forward pass, which copies it anyway.)"""
        rng = np.random.default_rng(13579)
        data = mujoco.MjData(self.model)
        self._fill(data, self._near_live(rng), rng.standard_normal(self.model.nv), source=self._random_inputs(rng))
        try:
            self._compute(data, "forward")
            before = np.array(self.function(data), copy=True)
            data.eq_active[:] = 1 - data.eq_active
            return not _same(self.function(data), before)
        except Exception:
            return True

    def _probe_contacts(self) -> bool:
        """Whether the observation reads ``cfrc_ext`` (Ant, Humanoid): evaluated at a random state with
        ``cfrc_ext`` NaN (not recomputed), does it come out non-finite? If not, the per-step copy of the contact
        forces is skipped, and a ``contact_forces`` mode other than ``"sensor"`` is refused."""
        mode, self.contact_forces = self.contact_forces, "sensor"  # no recomputation during the probe
        rng = np.random.default_rng(54321)
        qpos = self._near_live(rng)
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


#: MjData fields an observation may read from the live data: the state, the controller inputs the scratch evaluation
#: copies (:data:`INPUT_FIELDS`, but ``time``, a scalar) and the contact forces (``contact_forces="sensor"``)
OBSERVED_FIELDS = ("qpos", "qvel", *(name for name in INPUT_FIELDS if name != "time"), "cfrc_ext")


def copy_observed_fields(data: mujoco.MjData, into: mujoco.MjData) -> mujoco.MjData:
    """Copy ``time``, ``eq_active`` and the :data:`OBSERVED_FIELDS` of ``data`` into ``into`` (an ``MjData`` of the
    same model) and return it: what an observation of the state needs after the live data moved on (a vector env's
    terminal observation, rebuilt after the autoreset); a full ``copy.copy(MjData)`` costs ~100x more."""
    into.time = data.time
    into.eq_active[:] = data.eq_active
    for name in OBSERVED_FIELDS:
        dst = getattr(into, name, None)
        if isinstance(dst, np.ndarray) and dst.size:
            dst[...] = getattr(data, name)
    return into


def shared_selection(evaluations) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(index, low, high)`` when the observations of ``evaluations`` (one :class:`ScratchObservation` or None per
    environment) are all the same clipped selection ``np.clip(x[index], low, high)`` of the sensed state ``x = [qpos,
    qvel]`` (:attr:`ScratchObservation.observation_map`, models of one size), else None."""
    maps = [None if e is None else e.observation_map for e in evaluations]
    if not maps or any(m is None for m in maps) or len({e.model.nq for e in evaluations}) != 1:
        return None
    index, bounds = maps[0]
    if not all(np.array_equal(m[0], index) and np.array_equal(m[1], bounds) for m in maps):
        return None
    return index, *np.array(bounds)


class GatheredObservations:
    """Several environments' observations at given states, when each is gathered from ``MjData`` entries
    (:attr:`ScratchObservation.observation_entries`): what :meth:`ScratchObservation.observation` does
    environment by environment, in three moves.

    One compiled copy writes every environment's state and controller inputs into its scratch data, the
    forward-pass stages run on each scratch data, and one compiled gather fills the ``(n_envs, obs_dim)``
    observations and checks them. Same numbers as ``observation`` (the same copies, stages and gather); about a
    third of its cost for InvertedDoublePendulum with four environments (the in-process vector wrappers).

    Parameters
    ----------
    evaluations : sequence of ScratchObservation
        One per environment, all with a :attr:`~ScratchObservation.gather` and models of one size.

    Raises
    ------
    ValueError
        Observations of different sizes.
    """

    @staticmethod
    def supports(evaluations) -> bool:
        """Whether every one of ``evaluations`` (a :class:`ScratchObservation` or None per environment) is gathered
        from ``MjData`` entries (:attr:`~ScratchObservation.gather`), on models of one size."""
        return (
            bool(evaluations)
            and all(e is not None and e.gather is not None for e in evaluations)
            and len({(e.model.nq, e.model.nv) for e in evaluations}) == 1
        )

    def __init__(self, evaluations):
        self.evaluations = evaluations = tuple(evaluations)
        n, nq, nv = len(evaluations), evaluations[0].model.nq, evaluations[0].model.nv
        self.positions, self.velocities = np.zeros((n, nq)), np.zeros((n, nv))
        pairs = []
        #: the live data each input copy reads (checked at every call: a new MjData needs a new plan)
        self.live = []
        for i, evaluation in enumerate(evaluations):
            qpos, qvel = evaluation.scratch_state()
            pairs += [(qpos, self.positions[i]), (qvel, self.velocities[i])]
            live = evaluation.live()
            if evaluation.copies_inputs:
                pairs += evaluation.inputs_of(live).pairs
            self.live.append(live)
        self.copy = InputCopy(pairs)
        self.times = [e for e in evaluations if e.copies_inputs and e.inputs_of(e.live()).reads_time]
        self.equalities = [e for e in evaluations if e.copies_equality]
        sizes = [len(e.gather) for e in evaluations]
        if len(set(sizes)) != 1:
            raise ValueError(f"expected observations of one size, actual value: {sizes}")
        self.gathers = [e.gather for e in evaluations]
        self.gather = EntryGather.concatenate(self.gathers)
        self.shape = (n, sizes[0])
        #: one full forward pass on every scratch data, or None when the stages differ (then each runs its own)
        forward_only = all(e.pipeline == "forward" and not e.reads_contacts for e in evaluations)
        self.forward = [(e.model, e.scratch) for e in evaluations] if forward_only else None

    def current(self) -> bool:
        """Whether every environment still has the ``MjData`` the input copies read, and its gather (which
        :meth:`ScratchObservation.verify` drops at a reset where the observation is no longer one)."""
        return all(
            e.live() is live and e.gather is gather
            for e, live, gather in zip(self.evaluations, self.live, self.gathers, strict=True)
        )

    def observe(self, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """Observations ``(n_envs, obs_dim)`` at ``qpos = positions[i]`` ``(n_envs, nq)`` and ``qvel =
        velocities[i]`` ``(n_envs, nv)`` (the plan must be :meth:`current`)."""
        self.positions[:] = positions
        self.velocities[:] = velocities
        self.copy()
        for evaluation in self.times:
            evaluation.scratch.time = evaluation.live().time
        for evaluation in self.equalities:
            evaluation.scratch.eq_active[:] = evaluation.live().eq_active
        if self.forward is not None:
            forward = mujoco.mj_forward
            for model, scratch in self.forward:
                forward(model, scratch)
        else:
            for evaluation in self.evaluations:
                evaluation.compute()
        obs = np.empty(self.shape)
        bad = self.gather(obs.reshape(-1))
        if bad != -1:
            i, k = divmod(bad, self.shape[1])
            raise ValueError(
                f"expected a finite sensed observation, actual value: {obs[i, k]!r} at entry {k} of environment {i}"
            )
        return obs
