r"""The sensing core shared by the wrappers, the CLI and the benchmarks: measure ``qpos``, estimate ``qvel``.

Nothing here knows Gymnasium or dm_control; it needs a ``mujoco.MjModel`` (joint types, for the manifold) and
works on arrays of ``qpos``.

Tangent coordinates
-------------------
A velocity observer differentiates a real-valued signal. Hinge and slide joints give one directly (``qpos``).
Free and ball joints store orientations as unit quaternions (``nq != nv``), whose derivative is not ``qvel``.
:class:`TangentCoordinates` turns a stream of configurations into a continuous signal ``z`` of size ``nv``:

.. math:: z_k = z_{k-1} + \ominus(q_{k-1}, q_k),

with :math:`\ominus` MuJoCo's ``mj_differentiatePos`` (for hinge/slide dofs a plain difference, for a free/ball
rotation the body-frame rotation vector :math:`\log(q_{k-1}^{-1} q_k)`). Then :math:`\dot z = ` ``qvel`` exactly
in the limit of small steps (MuJoCo's angular velocity of a free/ball joint is in the local frame, like the
increment), so any observer of :math:`\dot z` estimates ``qvel``. Hinge/slide coordinates are taken from ``qpos``
directly (no accumulated round-off); ``z`` of a rotation is unwrapped, so it never jumps.

Sensor on the manifold
----------------------
:class:`JointMeasurement` applies a :class:`smo_gym.sensors.Sensor` to the *true* tangent coordinates and maps the
result back: :math:`q^{meas} = q \oplus (z^{meas} - z)` (``mj_integratePos``), i.e. the orientation error is a
rotation vector, noise on the manifold, and a measured quaternion is always a unit quaternion.

Default gains
-------------
An order-``r`` differentiator needs a bound on :math:`|z^{(r+1)}|` (acceleration for super-twisting, jerk for
the second-order Levant differentiator). :func:`calibrate_bounds` measures it on a short rollout of the model
itself (the environment's own resets and random actions, as a random policy explores; see
``EstimatedVelocity``) at the observer's sampling step,
takes a high quantile per dof (contacts produce rare impulsive peaks that a global maximum would turn into a
huge, noise-amplifying gain) and multiplies by a safety factor. Results are cached per environment in memory and
on disk (``$SMO_GYM_CACHE_DIR`` or ``~/.cache/smo_gym``).
"""

from __future__ import annotations

import hashlib
import json
import operator
import os
import re
import tempfile
from pathlib import Path

import mujoco
import numpy as np
from numba import njit

from ..calibration import bound_order, default_observer
from ..observers import Observer
from ..sensors import BLOCK, Sensor, Wrap, make_sensor
from ._tangent import integrate_pos, joint_table, tangent_advance

__all__ = [
    "FusedSensing",
    "JointMeasurement",
    "SensingInfo",
    "TangentCoordinates",
    "VelocityEstimator",
    "angular_dofs",
    "bound_order",
    "bounds_from_velocities",
    "cached_bounds",
    "calibrate_bounds",
    "check_action",
    "check_finite_observation",
    "check_seed",
    "default_observer",
    "stable_repr",
]

_FREE, _BALL, _SLIDE, _HINGE = (
    int(mujoco.mjtJoint.mjJNT_FREE),
    int(mujoco.mjtJoint.mjJNT_BALL),
    int(mujoco.mjtJoint.mjJNT_SLIDE),
    int(mujoco.mjtJoint.mjJNT_HINGE),
)


def angular_dofs(model: mujoco.MjModel) -> np.ndarray:
    """Boolean mask ``(nv,)``: True for rotational dofs (hinge, ball, free rotation), False for translations."""
    mask = np.ones(model.nv, dtype=bool)
    for j in range(model.njnt):
        adr = model.jnt_dofadr[j]
        if model.jnt_type[j] == _SLIDE:
            mask[adr] = False
        elif model.jnt_type[j] == _FREE:
            mask[adr : adr + 3] = False
    return mask


class TangentCoordinates:
    r"""Continuous tangent coordinates ``z`` (size ``nv``) of a stream of configurations ``q`` (size ``nq``).

    See the module docstring: :math:`z_k = z_{k-1} + \ominus(q_{k-1}, q_k)`, hinge/slide dofs copied from
    ``qpos``; the arithmetic is the compiled :mod:`smo_gym.wrappers._tangent` (MuJoCo's, bit for bit), which the
    wrapper's fused hot path shares. Models without free or ball joints take a fast path (``z = qpos``).
    """

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.nq, self.nv = model.nq, model.nv
        types = np.asarray(model.jnt_type)
        self.manifold = bool(np.any((types == _FREE) | (types == _BALL)))
        #: (type, qpos address, dof address) per joint; empty without free/ball joints (then z = qpos)
        self.joints = joint_table(model) if self.manifold else np.zeros((0, 3), dtype=np.int64)
        # the last configuration and its coordinates, updated in place (the fused hot path holds them)
        self._prev = np.zeros(self.nq)
        self._z = np.zeros(self.nv)

    def reset(self, q0: np.ndarray) -> np.ndarray:
        """Start at ``q0``: ``z0`` has the hinge/slide values and free-joint translations of ``q0``, and zero
        for free/ball rotations."""
        q0 = np.asarray(q0, dtype=np.float64)
        if not self.manifold:
            self._z = q0.copy()
            return self._z.copy()
        self._prev[:] = q0
        self._z[:] = 0.0
        for kind, a, d in self.joints:
            if kind == _FREE:
                self._z[d : d + 3] = q0[a : a + 3]
            elif kind != _BALL:
                self._z[d] = q0[a]
        return self._z.copy()

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """Advance to the configuration ``q`` and return ``z`` (a new array)."""
        if not self.manifold:
            self._z = np.array(q, dtype=np.float64)
            return self._z  # a fresh copy already: callers may keep it
        tangent_advance(self.joints, self._prev, np.ascontiguousarray(q, dtype=np.float64), self._z)
        return self._z.copy()

    def to_qpos(self, q_ref: np.ndarray, z_ref: np.ndarray, z: np.ndarray) -> np.ndarray:
        r"""Configuration at tangent coordinates ``z``: :math:`q_{ref} \oplus (z - z_{ref})` (``mj_integratePos``)."""
        if not self.manifold:
            return np.array(z, dtype=np.float64)
        q = np.array(q_ref, dtype=np.float64)
        integrate_pos(self.joints, q, np.asarray(z, dtype=np.float64) - z_ref)
        return q


class JointMeasurement:
    r"""A sensor on the joint positions of a MuJoCo model, with noise on the manifold for free/ball joints.

    Parameters
    ----------
    model : mujoco.MjModel
    sensor : str or smo_gym.sensors.Sensor
        A preset name of :data:`smo_gym.sensors.PRESETS` or a sensor object (used as is).
    dt : float
        Sampling step [s].

    Attributes
    ----------
    z_true, z_measured : ndarray, shape (nv,)
        Tangent coordinates of the true and of the measured configuration at the last sample.
    qpos_measured : ndarray, shape (nq,)
        The measured configuration :math:`q \oplus (z^{meas} - z)`.
    """

    def __init__(self, model: mujoco.MjModel, sensor: str | Sensor, dt: float):
        self.model = model
        self.sensor = make_sensor(sensor)
        self.dt = float(dt)
        self.tangent = TangentCoordinates(model)
        self.angular = angular_dofs(model)
        #: the sensor reports single-turn angles (a :class:`~smo_gym.sensors.Wrap` stage): observers of its
        #: measurements need ``wrap`` on the angular channels
        self.wraps = any(isinstance(stage, Wrap) for stage in self.sensor.stages)
        if self.wraps and self.tangent.manifold:
            raise ValueError(
                "expected a model without free or ball joints for a single-turn (wrapping) encoder, which measures "
                "hinge angles, actual value: a model with free or ball joints"
            )
        self._z_true = self._z_measured = self._qpos_measured = self._last_qpos = None
        self._fused_block = None

    # the last sample, as kept by measure_block or (lazily unpacked) by FusedSensing
    def _unpack_fused(self) -> None:
        block, nq, nv = self._fused_block, self.model.nq, self.model.nv
        self._fused_block = None  # [qpos, qvel, qvel_estimate, qpos_measured, z_true, z_measured]
        self._last_qpos = block[:nq]
        self._qpos_measured = block[nq + 2 * nv : 2 * nq + 2 * nv]
        self._z_true = block[2 * nq + 2 * nv : 2 * nq + 3 * nv]
        self._z_measured = block[2 * nq + 3 * nv :]

    @property
    def z_true(self) -> np.ndarray | None:
        if self._fused_block is not None:
            self._unpack_fused()
        return self._z_true

    @property
    def z_measured(self) -> np.ndarray | None:
        if self._fused_block is not None:
            self._unpack_fused()
        return self._z_measured

    @property
    def qpos_measured(self) -> np.ndarray | None:
        return None if self._z_measured is None and self._fused_block is None else self.measured_qpos()

    def noise_std(self) -> np.ndarray:
        """Per-dof standard deviation of the sensor's random error, shape ``(nv,)``."""
        return self.sensor.error_std(self.model.nv, self.angular)

    def reset(self, qpos: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """First measurement of the configuration ``qpos`` (the sensor's stream comes from ``rng``)."""
        qpos = np.asarray(qpos, dtype=np.float64)
        self._fused_block = None
        self._z_true = self.tangent.reset(qpos)
        self._z_measured = self.sensor.reset(self._z_true, rng=rng, dt=self.dt, angular=self.angular)
        self._last_qpos = qpos.copy()
        self._qpos_measured = self.tangent.to_qpos(qpos, self._z_true, self._z_measured)
        return self._qpos_measured

    def measure(self, qpos: np.ndarray) -> np.ndarray:
        """Measure the next sample; returns (and stores) the measured tangent coordinates ``z_measured``."""
        return self.measure_block(np.asarray(qpos, dtype=np.float64)[None])[0]

    def measure_block(self, Q: np.ndarray) -> np.ndarray:
        """Measure consecutive samples ``Q`` (T, nq) with one compiled sensor call; returns ``Z_meas`` (T, nv).

        Same numbers as ``measure`` row by row (the sensor's stream does not depend on batching). ``Q`` may be a
        view of live simulation data (``data.qpos[None]``): what is kept of it is copied.
        """
        self._fused_block = None
        if self.tangent.manifold:
            Z = np.array([self.tangent(q) for q in Q])
            self._last_qpos = np.array(Q[-1])
            self._z_true = Z[-1]
            self._qpos_measured = None  # mapped back lazily: only the last sample of a control period is needed
            Zm = self.sensor.run(Z)
        else:  # z = qpos: no copy of the block, and the measured configuration is the measurement itself
            Zm = self.sensor.run(Q)
            self._z_true = self._last_qpos = Q[-1].copy()
            self._qpos_measured = Zm[-1]
        self._z_measured = Zm[-1]
        return Zm

    def measured_qpos(self) -> np.ndarray:
        """The measured configuration at the last sample, shape ``(nq,)``."""
        if self._fused_block is not None:
            self._unpack_fused()
        if self._qpos_measured is None:
            self._qpos_measured = self.tangent.to_qpos(self._last_qpos, self._z_true, self._z_measured)
        return self._qpos_measured


@njit(cache=True)
def _first_nonfinite(x) -> int:
    """Index of the first non-finite entry of the 1-D array ``x``, or -1."""
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return i
    return -1


_FLOAT64 = np.dtype(np.float64)
#: dtype -> entry point of :func:`_first_nonfinite` for 1-D arrays of that dtype, any layout
_NONFINITE_ENTRIES: dict = {}


def _nonfinite_entry(dtype: np.dtype):
    """Entry point of :func:`_first_nonfinite` for 1-D float32 or float64 arrays of any layout (strided views
    too), so that a caller only has to check the dtype and the number of dimensions."""
    entry = _NONFINITE_ENTRIES.get(dtype)
    if entry is None:
        import numba

        sig = (numba.types.Array(numba.from_dtype(dtype), 1, "A"),)
        if sig not in _first_nonfinite.overloads:
            _first_nonfinite.compile(sig)
        entry = _NONFINITE_ENTRIES[dtype] = _first_nonfinite.overloads[sig].entry_point
    return entry


_FAST_DTYPES = (np.dtype(np.float32), _FLOAT64)


def check_action(action, shape: tuple[int, ...]) -> None:
    """Raise a typed error for an action that is not of ``shape`` or has an entry that is not a finite real number.

    MuJoCo would otherwise zero a NaN or infinite control with a warning printed to stdout, and cast a complex
    one to its real part, silently. One compiled call for the float32 and float64 actions of RL libraries.
    """
    if type(action) is np.ndarray and action.shape == shape and action.dtype in _FAST_DTYPES and action.ndim == 1:
        bad = (_NONFINITE_ENTRIES.get(action.dtype) or _nonfinite_entry(action.dtype))(action)
        if bad == -1:
            return
        raise ValueError(f"expected a finite action, actual value: {action[bad]!r} at entry {bad}")
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError):
        arr = np.asarray(None)
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"expected an action of real numbers with shape {shape}, actual value: {action!r:.120}")
    if arr.shape != shape:
        raise ValueError(f"expected an action with shape {shape}, actual value: shape {arr.shape}")
    flat = arr.reshape(-1)
    bad = np.flatnonzero(~np.isfinite(flat.astype(np.float64)))
    if bad.size:
        raise ValueError(f"expected a finite action, actual value: {flat[bad[0]]!r} at entry {int(bad[0])}")


def check_seed(seed) -> None:
    """``reset(seed=...)`` takes None or an integer >= 0 (a typed error instead of Gymnasium's own ``Error``)."""
    if seed is None:
        return
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"expected seed to be None or an integer >= 0, actual value: {seed!r:.80}")
    if seed < 0:
        raise ValueError(f"expected seed to be None or an integer >= 0, actual value: {seed!r}")


def check_finite_observation(obs: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first non-finite entry of a sensed observation (1-D array).

    A sensed observation is a function of finite measurements and finite estimates (the sensor and the
    observer reject anything else), but the environment's observation function could still produce inf (a
    constraint force at an impossible measured configuration, say); it never reaches the agent silently. The
    check is one compiled call (a NumPy reduction costs about 1 us, comparable to the rest of the step on a
    small model).
    """
    if type(obs) is np.ndarray and obs.dtype is _FLOAT64 and obs.ndim == 1:
        bad = (_NONFINITE_ENTRIES.get(_FLOAT64) or _nonfinite_entry(_FLOAT64))(obs)
        if bad == -1:
            return
    else:
        flat = np.asarray(obs, dtype=np.float64).reshape(-1)
        if np.all(np.isfinite(flat)):
            return
        bad = int(np.flatnonzero(~np.isfinite(flat))[0])
        obs = flat
    raise ValueError(f"expected a finite sensed observation, actual value: {obs[bad]!r} at entry {bad}")


class SensingInfo(dict):
    """``info["smo"]``: the true and the sensed state at the last sample, read-only.

    The same keys from :class:`~smo_gym.wrappers.EstimatedVelocity` and, per environment, from both vector
    wrappers:

    ==================  ===============  ==========================================================================
    key                 shape            what
    ==================  ===============  ==========================================================================
    ``qpos``            ``(nq,)``        true joint configuration
    ``qvel``            ``(nv,)``        true joint velocities
    ``qvel_estimate``   ``(nv,)``        the observer's velocity estimate (what the observation holds)
    ``qpos_measured``   ``(nq,)``        the sensor's measured configuration
    ``observation``     the env's        the *clean* observation: what the wrapped stack returns at the true state
                                         (for privileged critics, and to measure the estimation error in
                                         observation space)
    ==================  ===============  ==========================================================================

    New arrays at every step, safe to keep. Neither the dictionary nor its arrays can be changed
    (``dict(info["smo"])`` and ``np.array(info["smo"]["qvel"])`` give mutable copies), so
    ``copy.copy``/``copy.deepcopy`` return the object itself: SB3's ``DummyVecEnv`` deep-copies every step's
    infos, and a generic deep copy of five small arrays costs more than a physics step of a small model.
    """

    __slots__ = ()

    @classmethod
    def of(cls, qpos, qvel, qvel_estimate, qpos_measured, observation) -> SensingInfo:
        """From the four state arrays (copied) and the clean observation (copied)."""
        return cls.from_block(
            np.concatenate((qpos, qvel, qvel_estimate, qpos_measured)), cls.slices(len(qpos), len(qvel)), observation
        )

    @staticmethod
    def slices(nq: int, nv: int) -> tuple[slice, slice, slice, slice]:
        """Where ``qpos``, ``qvel``, ``qvel_estimate`` and ``qpos_measured`` lie in a block (computed once per
        wrapper: the per-step path only slices)."""
        return (slice(0, nq), slice(nq, nq + nv), slice(nq + nv, nq + 2 * nv), slice(nq + 2 * nv, 2 * nq + 2 * nv))

    @classmethod
    def from_block(cls, block: np.ndarray, slices: tuple, observation) -> SensingInfo:
        """From one block ``[qpos, qvel, qvel_estimate, qpos_measured, ...]`` (anything after these four is
        ignored; ``slices`` from :meth:`slices`), which it owns from now on (made read-only, as are its views),
        and the clean observation (an array or a dict of arrays, copied)."""
        block.setflags(write=False)
        s0, s1, s2, s3 = slices
        return cls(
            qpos=block[s0],
            qvel=block[s1],
            qvel_estimate=block[s2],
            qpos_measured=block[s3],
            observation=_read_only_copy(observation),
        )

    def _readonly(self, *args, **kwargs):
        raise TypeError(
            "expected no change to info['smo'] (read-only), actual value: an attempt to modify it; "
            "dict(info['smo']) is a mutable copy"
        )

    __setitem__ = __delitem__ = update = pop = popitem = clear = setdefault = __ior__ = _readonly

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self

    def __reduce__(self):
        return _sensing_info, (dict(self),)


def _sensing_info(items: dict) -> SensingInfo:
    """Unpickle a :class:`SensingInfo` (its ``__setitem__`` refuses the default per-item restore)."""
    return SensingInfo({key: _read_only_copy(value) for key, value in items.items()})


def _read_only_copy(value):
    """A read-only copy of an array, or of every array of a dict (a dict observation)."""
    if isinstance(value, dict):
        return {key: _read_only_copy(item) for key, item in value.items()}
    value = np.array(value)
    value.flags.writeable = False
    return value


class VelocityEstimator:
    """An observer on the measured tangent coordinates; its velocity estimates ``qvel``.

    Parameters
    ----------
    observer : smo_gym.observers.Observer
        Any observer; its ``dt`` must be the sampling step.
    """

    def __init__(self, observer: Observer):
        if not isinstance(observer, Observer):
            raise TypeError(f"expected a smo_gym.observers.Observer, actual value: {observer!r}")
        self.observer = observer

    def reset(self, z0: np.ndarray) -> np.ndarray:
        """Start at the first measurement (velocity zero); returns the velocity estimate ``(nv,)``.

        A reset with the shape of the previous one is an :meth:`Observer.restart`: the per-channel parameters,
        derived from the gains at the first reset, are kept instead of derived again (~40 us, paid at every
        episode of a short-episode environment).
        """
        observer = self.observer
        z0 = np.asarray(z0, dtype=np.float64)
        if observer.shape == z0.shape:
            return observer.restart(z0)[..., 1]
        return observer.reset(z0)[..., 1]

    def update(self, z: np.ndarray) -> np.ndarray:
        """One sample; returns the velocity estimate ``(nv,)``."""
        return self.observer.update(z)[..., 1]

    @property
    def velocity(self) -> np.ndarray:
        return self.observer.velocity

    @property
    def filtered(self) -> np.ndarray:
        """Filtered tangent coordinates (the observer's value estimate), shape ``(nv,)``."""
        return self.observer.estimate[..., 0]


class FusedSensing:
    r"""The wrapper's hot path: one compiled call per control period (:mod:`smo_gym.wrappers._fused`).

    Sensor chain, observer update, the scratch state for the observation and the ``info["smo"]`` block in one
    call, with the numbers of the general path (``JointMeasurement.measure_block`` then ``Observer.run``). It
    drives the sensor's and the observer's own arrays and keeps their bookkeeping (the sensor's position in its
    random block, the observer's estimate and update count), so both objects stay usable as they are.

    Use :meth:`supports` first: a plain :class:`VelocityEstimator` around an observer whose ``update``/``run``
    are the base class's and whose kernel has a fused driver, a sensor whose ``run`` is the base class's, and an
    adapter with a scratch state.

    Parameters
    ----------
    measurement : JointMeasurement
    estimator : VelocityEstimator
    adapter : smo_gym.wrappers.adapters.GymnasiumMujocoAdapter
    filtered : bool
        Put the observer's filtered positions (instead of the measurement) into the observation's ``qpos``.
    """

    def __init__(self, measurement: JointMeasurement, estimator: VelocityEstimator, adapter, filtered: bool):
        from ._fused import FUSED_DRIVERS, TABLE_SLOTS

        self._slots = TABLE_SLOTS
        self.measurement, self.adapter = measurement, adapter
        self.sensor, self.observer = measurement.sensor, estimator.observer
        self.filtered = bool(filtered)
        self._driver = FUSED_DRIVERS[self.observer._kernel]
        selection = getattr(adapter, "observation_map", None)
        #: the compiled call also builds the observation (a clipped selection of the sensed state, probed by the
        #: adapter): :meth:`sample` leaves it in :attr:`observation`
        self.maps_observation = selection is not None
        if selection is None:
            selection = (np.zeros(0, dtype=np.int64), np.zeros((2, 0)))
        self._obs_index, self._obs_bounds = selection
        self._n_obs = len(self._obs_index)
        #: the compiled call copies the controller inputs the observation reads into the scratch data (the
        #: adapter's :meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.input_views`)
        self.copies_inputs = bool(getattr(adapter, "copies_inputs", False)) and hasattr(adapter, "input_views")
        self._no_obs = np.empty(0)
        self.observation = None
        self._call = None
        self._work = None
        self._static = None
        self._table = None
        model = measurement.model
        self._info_size = 2 * model.nq + 4 * model.nv
        # without free or ball joints the driver never touches z; TangentCoordinates.reset replaces its z at every
        # episode, which would cost a table row each time
        self._unused_z = np.zeros(model.nv)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        # the entry point does not pickle, the scratch views belong to the adapter's (re-made) scratch data, and
        # the table holds this process's addresses
        state.update(_call=None, _work=None, _static=None, _table=None)
        return state

    @staticmethod
    def supports(measurement: JointMeasurement, estimator: VelocityEstimator, adapter) -> bool:
        """Whether the fused path computes exactly what the general path would (see the class docstring)."""
        from ._fused import FUSED_DRIVERS

        observer = estimator.observer
        return (
            type(estimator) is VelocityEstimator
            and type(observer).update is Observer.update
            and type(observer).run is Observer.run
            and not np.any(observer.wrap)  # the drivers call the kernels directly, without unwrapping
            and observer.order >= 1
            and type(measurement.sensor).run is Sensor.run
            and getattr(observer, "_kernel", None) in FUSED_DRIVERS
            and hasattr(adapter, "scratch_state")
        )

    def _bind(self, Q: np.ndarray, qvel_true: np.ndarray) -> None:
        """Resolve the driver's compiled entry point (once: the arguments keep their types across resets).

        The entry point skips numba's type dispatch; it checks nothing, so every later call passes arrays of
        exactly these types: ``Q`` is a view of the live ``qpos`` or the wrapper's sample buffer, ``qvel_true``
        the live ``qvel`` (writeable, aligned, C-contiguous float64); ``est``, ``info``, ``Zm`` and ``obs`` are
        made here; the other arrays go through the address table (:meth:`prepare`).
        """
        from ..observers.base import _compiled_entry

        for a in (Q, qvel_true):
            if not (a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable and a.flags.aligned):
                raise TypeError(f"expected writeable C-contiguous float64 arrays, actual value: {a.dtype} {a.flags}")
        self.prepare()
        n, m = self._shape
        self._call = _compiled_entry(
            self._driver,
            (
                Q,
                qvel_true,
                np.int64(0),
                np.empty((n, m)),
                np.empty(self._info_size),
                self._Zm,
                self._no_obs,
                self._table,
            ),
        )

    def prepare(self) -> None:
        """Collect the sensor's and the observer's current arrays into the driver's address table (call after
        resetting them: a reset may replace them with new arrays of the same types).

        The table (:data:`smo_gym.wrappers._fused.TABLE_SLOTS`) holds raw addresses, so the arrays are kept in
        ``_static`` for as long as the table points to them, and each is checked: dtype, dimensions, C order.
        Rows are rebuilt only for arrays that changed (most resets replace only the tangent coordinates).
        """
        from ._fused import address

        sensor, observer = self.sensor, self.observer
        n, S = observer._state.shape
        if self._work is None or self._work.shape[1:] != (n, S):
            self._work = np.empty((2, n, S))
            self._Zm = np.empty((1, n))
        self._shape = (n, observer.order + 1)
        scratch_qpos, scratch_qvel = self.adapter.scratch_state()
        tangent = self.measurement.tangent
        static = (
            sensor._kinds,
            sensor._params,
            sensor._state,
            sensor._ring,
            sensor._ring_pos,
            sensor._rand,
            observer._state,
            observer._params,
            self._work,
            scratch_qpos,
            scratch_qvel,
            self.filtered,
            tangent.joints,
            tangent._prev,
            tangent._z if tangent.manifold else self._unused_z,
            self._obs_index,
            self._obs_bounds,
        )
        # the controller inputs the observation reads, copied by the compiled call (time, a scalar, is not)
        pairs = self.adapter.input_views()[0] if self.copies_inputs else ()
        static = static + pairs
        previous, table = self._static, self._table
        if table is not None and len(table) == len(static) and all(map(operator.is_, static, previous)):
            return  # nothing replaced (a reset usually replaces one array or none)
        slots = self._slots + tuple((f"input {i}", np.float64, -1) for i in range(len(pairs)))
        if table is None or len(table) != len(slots):
            table, previous = np.zeros((len(slots), 5), dtype=np.int64), (None,) * len(slots)
        else:
            table = table.copy()  # the table in use keeps pointing at the arrays it holds until this one is done
        for row, (array, old, (name, dtype, ndim)) in enumerate(zip(static, previous, slots, strict=True)):
            if array is old:
                continue
            if ndim == 0:
                table[row] = (int(bool(array)), 0, 0, 0, 0)
                continue
            for a in array if ndim < 0 else (array,):
                if not (
                    type(a) is np.ndarray
                    and a.dtype == dtype
                    and (ndim < 0 or a.ndim == ndim)
                    and a.flags.c_contiguous
                    and a.flags.aligned
                ):
                    raise TypeError(
                        f"expected {name} as an aligned C-contiguous {np.dtype(dtype)} array"
                        f"{f' with {ndim} dimensions' if ndim > 0 else ''}, actual value: {a!r:.80}"
                    )
            if ndim < 0:  # an input copy: [to, from, size]
                to, source = array
                if to.size != source.size:
                    raise TypeError(f"expected {name} of one size, actual value: {to.size} and {source.size}")
                table[row] = (address(to), address(source), to.size, 0, 0)
            else:
                table[row] = (address(array), *array.shape, *(0,) * (4 - ndim))
        self._static, self._table = static, table

    def sample(self, Q: np.ndarray, qvel_true: np.ndarray) -> np.ndarray | None:
        """Measure and estimate the samples ``Q`` (T, nq) of one control period.

        Returns the block ``[qpos, qvel, qvel_estimate, qpos_measured, z_true, z_measured]`` (2 nq + 4 nv,): the
        first four are ``info["smo"]`` (:meth:`SensingInfo.from_block`), the last two the tangent coordinates of the
        last sample (:class:`JointMeasurement` reads them lazily). The observation's state is written into the
        adapter's scratch, and with :attr:`maps_observation` the observation itself into a new array,
        :attr:`observation`. Returns None (nothing done) when the samples straddle the end of the sensor's random
        block: the caller then takes the general path, which splits the block and so keeps the random stream
        independent of batching.

        Raises
        ------
        ValueError
            The sensor produced a non-finite measurement (as ``Sensor.run``).
        DivergenceError
            The observer's state would become non-finite (as ``Observer.run``: nothing committed).
        """
        sensor = self.sensor
        T = Q.shape[0]
        t0 = sensor._t
        if t0 + T > BLOCK:
            if t0 < BLOCK:
                return None
            sensor._refill()  # refills in place: the prepared arrays stay valid
            t0 = 0
        call = self._call
        if call is None:
            self._bind(Q, qvel_true)
            call = self._call
        static = self._static
        if static[6] is not self.observer._state or static[2] is not sensor._state:
            # replaced since prepare(): Observer.run commits a new state array, Sensor.reset new arrays
            self.prepare()
        if self._Zm.shape[0] < T:
            self._Zm = np.empty((T, self._shape[0]))
        est = np.empty(self._shape)
        info = np.empty(self._info_size)
        obs = self.observation = np.empty(self._n_obs) if self.maps_observation else self._no_obs
        status = call(Q, qvel_true, t0, est, info, self._Zm, obs, self._table)
        sensor._t = t0 + T
        if status != -1:
            self._raise(status, Q)
        observer = self.observer
        observer._estimate = est
        observer.n_updates += T
        self.measurement._fused_block = info  # unpacked only if read (JointMeasurement.z_measured, ...)
        return info

    def _raise(self, status: int, Q: np.ndarray):
        n = self._shape[0]
        if status >= 0:
            t, channel = divmod(status, n)
            self.sensor._raise(channel, Q[t], self._Zm[t])
        t, channel = divmod(-2 - status, n)
        self.observer._raise_status(-2 - channel, self._Zm[t])


# ----------------------------------------------------------------------------------------------------------------
# calibration of the default gains
# ----------------------------------------------------------------------------------------------------------------
def calibrate_bounds(
    model: mujoco.MjModel,
    qpos0: np.ndarray,
    qvel0: np.ndarray,
    frame_skip: int,
    sample_every: int,
    *,
    derivative: int = 2,
    steps: int = 2000,
    episode: int = 500,
    quantile: float = 0.99,
    safety: float = 2.0,
    seed: int = 0,
) -> np.ndarray:
    r"""Bounds on :math:`|z^{(r)}|` per dof from a rollout of ``model`` under a random policy.

    From ``(qpos0, qvel0)`` the model is stepped ``steps`` physics steps with actions drawn uniformly from the
    actuators' control ranges and held for ``frame_skip`` steps, restarting every ``episode`` steps (and on a
    non-finite state). The velocity ``qvel`` is sampled every ``sample_every`` steps (the observer's step
    :math:`\tau`); its backward differences give the acceleration (``derivative=2``) and jerk (``3``) at that
    step. The bound is ``safety * quantile(|z^(r)|)`` per dof; dofs that did not move in the rollout (objects,
    goals) get the largest bound of the model, and every bound is floored at ``1e-3``.

    Returns
    -------
    ndarray, shape (nv,)
    """
    if derivative < 1:
        raise ValueError(f"expected derivative >= 1, actual value: {derivative}")
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(model)
    lo, hi = np.array(model.actuator_ctrlrange, dtype=float).T if model.nu else (np.zeros(0), np.zeros(0))
    limited = np.asarray(model.actuator_ctrllimited, dtype=bool) if model.nu else np.zeros(0, dtype=bool)
    lo = np.where(limited, lo, -1.0)
    hi = np.where(limited, hi, 1.0)
    dt = model.opt.timestep * sample_every
    samples: list[np.ndarray] = []
    episodes: list[np.ndarray] = []

    def restart():
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos0
        data.qvel[:] = qvel0
        mujoco.mj_forward(model, data)

    restart()
    for k in range(steps):
        if k % frame_skip == 0:
            data.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(model, data)
        if not np.all(np.isfinite(data.qvel)) or (k + 1) % episode == 0:
            if samples:
                episodes.append(np.array(samples))
            samples = []
            restart()
            continue
        if (k + 1) % sample_every == 0:
            samples.append(data.qvel.copy())
    if samples:
        episodes.append(np.array(samples))
    return bounds_from_velocities(episodes, dt, derivative=derivative, quantile=quantile, safety=safety)


def bounds_from_velocities(
    episodes: list[np.ndarray], dt: float, *, derivative: int = 2, quantile: float = 0.99, safety: float = 2.0
) -> np.ndarray:
    r"""``safety * quantile(|z^(r)|)`` per dof from sampled velocities.

    ``episodes`` holds arrays ``(T_i, nv)`` of ``qvel`` sampled every ``dt``; backward differences give
    :math:`z^{(r)}` (``r = derivative``). Dofs that never moved get the largest bound of the model, and every
    bound is floored at ``1e-3``.
    """
    if derivative < 1:
        raise ValueError(f"expected derivative >= 1, actual value: {derivative}")
    diffs = [np.diff(V, n=derivative - 1, axis=0) / dt ** (derivative - 1) for V in episodes if len(V) >= derivative]
    if not diffs:
        raise ValueError(
            f"expected a rollout long enough to calibrate, actual value: {len(episodes)} episode(s) "
            f"shorter than {derivative} samples"
        )
    D = np.abs(np.concatenate(diffs, axis=0))
    bound = safety * np.quantile(D, quantile, axis=0)
    # dofs the random policy cannot move (a pushed object, a goal) get the largest bound of the model: they may
    # be hit later, and a tiny gain would never catch up
    untouched = bound <= 1e-6 * max(float(np.max(bound)), 1e-300)
    bound[untouched] = np.max(bound)
    return np.maximum(bound, 1e-3)


_MEMORY_CACHE: dict[str, list[float]] = {}


def _cache_file() -> Path:
    root = os.environ.get("SMO_GYM_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "smo_gym"
    )
    return Path(root) / "calibration.json"


def cached_bounds(key: str, compute, *, disk: bool = True) -> np.ndarray:
    """``compute()`` memoized under ``key`` in memory and (``disk=True``) in the user cache file."""
    if key in _MEMORY_CACHE:
        return np.array(_MEMORY_CACHE[key])
    path = _cache_file()
    if disk:
        try:
            stored = json.loads(path.read_text())
            if key in stored:
                _MEMORY_CACHE[key] = stored[key]
                return np.array(stored[key])
        except (OSError, ValueError):
            pass
    value = np.asarray(compute(), dtype=float)
    _MEMORY_CACHE[key] = value.tolist()
    if disk:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            try:
                stored = json.loads(path.read_text())
            except (OSError, ValueError):
                stored = {}
            stored[key] = value.tolist()
            fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
            with os.fdopen(fd, "w") as fh:
                json.dump(stored, fh)
            os.replace(tmp, path)
        except OSError:  # a read-only home is not an error: the memory cache still works
            pass
    return value


def calibration_key(env_key: str, model: mujoco.MjModel, **settings) -> str:
    """Cache key: the environment's identity, the model itself and the calibration settings.

    The model enters by a hash of its binary form (``mj_saveModel``): a model edited in place (masses, the
    timestep) gets a calibration of its own, and the key is the same in every process.
    """
    buffer = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    text = json.dumps([env_key, hashlib.sha1(buffer.tobytes()).hexdigest(), sorted(settings.items())], default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:16] + ":" + env_key


#: `` at 0x7f...``: the address in a default ``repr``, different in every process
_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")


def stable_repr(value) -> str:
    """A text for ``value`` that is the same in every process (for cache keys).

    Functions are named by module and qualified name plus a hash of their code, constants, defaults, closure
    values and the module-level numbers, strings and arrays they read, so two different lambdas differ and the
    same one agrees across processes; arrays by a hash of their bytes; containers element by element; anything
    else by its ``repr`` without memory addresses.
    """
    if isinstance(value, dict):
        return "{" + ", ".join(f"{stable_repr(k)}: {stable_repr(v)}" for k, v in sorted(value.items(), key=str)) + "}"
    if isinstance(value, (list, tuple)):
        return type(value).__name__ + "(" + ", ".join(stable_repr(v) for v in value) + ")"
    if isinstance(value, np.ndarray):
        return f"array{value.shape}:{hashlib.sha1(np.ascontiguousarray(value).tobytes()).hexdigest()[:12]}"
    code = getattr(value, "__code__", None)
    if code is not None:
        closure = [cell.cell_contents for cell in (value.__closure__ or ())]
        # module-level numbers, strings and arrays the function reads (modules and functions by name only)
        names = getattr(value, "__globals__", {})
        data = {
            name: names[name]
            for name in code.co_names
            if isinstance(names.get(name), (bool, int, float, complex, str, np.ndarray, np.number))
        }
        parts = [
            code.co_code.hex(),
            stable_repr(list(code.co_consts)),
            stable_repr(list(value.__defaults__ or ())),
            stable_repr(closure),
            stable_repr(data),
        ]
        digest = hashlib.sha1("|".join(parts).encode()).hexdigest()[:12]
        return f"{getattr(value, '__module__', '')}.{getattr(value, '__qualname__', '')}:{digest}"
    return _ADDRESS.sub("", repr(value))
