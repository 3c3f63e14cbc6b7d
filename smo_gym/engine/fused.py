r"""One compiled call per control period: sensor chain, observer recursion and the wrapper's outputs.

A wrapped environment step on a small model (InvertedPendulum-v5: ~30 us of physics and Python) has room for
only a few microseconds of sensing, and each Python-level operation costs two to three times more right after
``mj_step`` (the simulator has evicted the interpreter's caches) than in a micro-benchmark. So the wrapper's hot
path is one compiled function per observer kernel that, for the ``T`` samples of a control period,

1. runs the sensor chain (:func:`smo_gym.sensors._chain_block`, the call and random numbers of ``Sensor.run``),
2. advances the observer (its own compiled step, with the checks of the batch kernel ``Observer.update``
   calls), all or nothing: the state is committed only if every sample passed,
3. writes the sensed state into the scratch ``MjData`` (measured or filtered ``qpos``, estimated ``qvel``) and
   the ``info["smo"]`` block (true ``qpos``, true ``qvel``, estimated ``qvel``, measured ``qpos``),
4. and, where the observation is a clipped selection of ``qpos``/``qvel`` (probed by the adapter: Hopper,
   HalfCheetah, Walker2d, Swimmer, InvertedPendulum), the observation itself.

Free and ball joints go through the same compiled tangent coordinates as the general path
(:mod:`smo_gym.engine.tangent`).

The numbers are those of the general path (``Sensor.run`` then ``Observer.run``), bit for bit (tested): the
driver calls the same compiled sensor chain (:func:`smo_gym.sensors._chain_block`) and the observer's own step.
It is one template (:func:`_sense_template`) bound to each registered kernel and to the kind of joints, generated
and cached on disk (:data:`FUSED_DRIVERS`; a compiled function taking the kernel as an argument would be
recompiled in every new process, see :func:`smo_gym._numba_cache.cached_instance`). The joint kind is a
compile-time constant because compilation, not the call, is what a new process pays for (the first step from an
empty cache): a model without free or ball joints never compiles the tangent arithmetic. Observers that are not a
registered compiled family (or a :class:`~smo_gym.observers.PerChannel` of such families, whose composite step is
registered too) use the general path.

Status codes of a driver: ``-1`` success; ``t * nv + j >= 0`` the sensor produced a non-finite value at sample
``t``, channel ``j``; ``-2 - (t * nv + j)`` the observer's state became non-finite there.
"""

from __future__ import annotations

import functools
import math
import operator
from collections.abc import Callable, Mapping
from typing import NamedTuple

import numpy as np
from numba import carray, njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .._numba_cache import cached_instance
from ..observers import _kernels as K
from ..observers.base import _compiled_entry
from ..observers.composite import compiled_step
from ..sensors import BLOCK, _chain_block
from .measurement import JointMeasurement, VelocityEstimator
from .tangent import integrate_pos, tangent_advance

__all__ = [
    "ENTRY_COS",
    "ENTRY_IDENTITY",
    "ENTRY_SIN",
    "FUSED_DRIVERS",
    "TABLE_SLOTS",
    "EntryGather",
    "FusedSensing",
    "InputCopy",
    "address",
    "bound_to_step",
    "clipped_selection",
    "copy_entries",
    "entry_functions_match_numpy",
    "fusable",
    "fusable_estimator",
    "gather_entries",
]

#: the arrays a driver reads through its address table, in row order: (name, dtype, ndim); the row of an array
#: is ``[address, *shape, 0...]`` (5 columns), the row of the flag ``filtered`` is ``[0 or 1, 0, 0, 0, 0]``. Rows
#: after these are copies of the controller inputs into the scratch data: ``[to, from, size, 0, 0]`` (float64).
TABLE_SLOTS = (
    ("kinds", np.int64, 1),
    ("sensor_params", np.float64, 3),
    ("sensor_state", np.float64, 2),
    ("ring", np.float64, 3),
    ("ring_pos", np.int64, 1),
    ("rand", np.float64, 4),
    ("state", np.float64, 2),
    ("params", np.float64, 2),
    ("work", np.float64, 3),
    ("scratch_qpos", np.float64, 1),
    ("scratch_qvel", np.float64, 1),
    ("filtered", bool, 0),
    ("joints", np.int64, 2),
    ("prev", np.float64, 1),
    ("z", np.float64, 1),
    ("obs_index", np.int64, 1),
    ("obs_bounds", np.float64, 2),
    ("velocity", np.float64, 1),
)
_N_SLOTS = len(TABLE_SLOTS)
_SLOT_ROW = {name: row for row, (name, _, _) in enumerate(TABLE_SLOTS)}
#: the rows of the observer's and the sensor's state: :meth:`FusedSensing.sample` checks they are the arrays in use
_OBSERVER_STATE, _SENSOR_STATE = _SLOT_ROW["state"], _SLOT_ROW["sensor_state"]


# the globals of the template below, bound per observer step and joint kind by cached_instance: the step's
# rows function (called directly, not through its batch kernel: one compiled level less, whose LLVM optimization
# of the observer's code a cold start would pay once more)
_ROWS = None
_MANIFOLD = False


def _sense_template(Q, qvel_true, t0, est, info, Zm, obs, table):
    """Sensor, observer and outputs for the samples ``Q`` (T, nq) of one control period (see module docstring).

    The arguments that change every call come first; the others are read through the address ``table`` (rows of
    :data:`TABLE_SLOTS`: numba converts every array argument of a call from Python, ~0.1 us each and two to three
    times that right after the physics step, so the seventeen prepared arrays would cost more than the rest of the
    call; its rows after those copy the controller inputs the observation reads from the live into the scratch
    data, see :func:`copy_entries`; :class:`FusedSensing` keeps the arrays alive and checks them):
    ``qvel_true`` (nv,) the live velocity, ``t0`` the sensor's position in its random block ``rand``, ``est``
    (nv, m) receives the estimate at the last sample, ``info`` (2 nq + 4 nv,) the block
    ``[qpos, qvel, qvel_estimate, qpos_measured, z_true, z_measured]``, ``Zm`` (>= T, nv) the measurements (work
    space), ``obs`` (n_obs,) receives the observation if it is a selection of the sensed state (empty otherwise,
    see the end). Then the sensor's arrays (``kinds`` ... ``rand``, see :class:`smo_gym.sensors.Sensor`), the
    observer's state (nv, S) and parameters, ``work`` (2, nv, S) ping-pong buffers of the state, the scratch
    ``qpos``/``qvel`` of the observation, ``filtered`` (put the observer's filtered value instead of the
    measurement into ``scratch_qpos``), and the tangent coordinates of free/ball joints
    (:mod:`smo_gym.engine.tangent`): ``joints`` (njnt, 3), empty for a model without them (then ``z = qpos``),
    ``prev`` (nq,) the last configuration and ``z`` (nv,) its tangent coordinates, both advanced in place. Last,
    for an observation that is a selection of the sensed state (:attr:`ScratchObservation.observation_map
    <smo_gym.engine.scratch.ScratchObservation.observation_map>`): ``obs[i] = min(max(x[obs_index[i]],
    obs_bounds[0, i]), obs_bounds[1, i])`` with ``x = [scratch_qpos, scratch_qvel]``.
    """
    copy_entries(table[_N_SLOTS:])  # the input copies into the scratch data: [to, from, size, 0, 0]
    r = table
    kinds = carray(_pointer(r[0, 0]), (r[0, 1],), np.int64)
    sparams = carray(_pointer(r[1, 0]), (r[1, 1], r[1, 2], r[1, 3]), np.float64)
    sstate = carray(_pointer(r[2, 0]), (r[2, 1], r[2, 2]), np.float64)
    ring = carray(_pointer(r[3, 0]), (r[3, 1], r[3, 2], r[3, 3]), np.float64)
    ring_pos = carray(_pointer(r[4, 0]), (r[4, 1],), np.int64)
    rand = carray(_pointer(r[5, 0]), (r[5, 1], r[5, 2], r[5, 3], r[5, 4]), np.float64)
    state = carray(_pointer(r[6, 0]), (r[6, 1], r[6, 2]), np.float64)
    params = carray(_pointer(r[7, 0]), (r[7, 1], r[7, 2]), np.float64)
    work = carray(_pointer(r[8, 0]), (r[8, 1], r[8, 2], r[8, 3]), np.float64)
    scratch_qpos = carray(_pointer(r[9, 0]), (r[9, 1],), np.float64)
    scratch_qvel = carray(_pointer(r[10, 0]), (r[10, 1],), np.float64)
    filtered = r[11, 0] != 0
    joints = carray(_pointer(r[12, 0]), (r[12, 1], r[12, 2]), np.int64)
    prev = carray(_pointer(r[13, 0]), (r[13, 1],), np.float64)
    z = carray(_pointer(r[14, 0]), (r[14, 1],), np.float64)
    obs_index = carray(_pointer(r[15, 0]), (r[15, 1],), np.int64)
    obs_bounds = carray(_pointer(r[16, 0]), (r[16, 1], r[16, 2]), np.float64)
    velocity = carray(_pointer(r[17, 0]), (r[17, 1],), np.float64)
    T, nq = Q.shape
    n, S = state.shape
    for c in range(n):
        for j in range(S):
            work[0, c, j] = state[c, j]
    # the true tangent coordinates of the samples, measured in place by the sensor chain (as Sensor.run)
    for t in range(T):
        if _MANIFOLD:
            tangent_advance(joints, prev, Q[t], z)
            for c in range(n):
                Zm[t, c] = z[c]
        else:
            for c in range(n):
                Zm[t, c] = Q[t, c]
    block = Zm[:T]
    # prime is a bool value, not the literal False: then this is the chain Sensor.run compiled (one compilation)
    status = _chain_block(block, kinds, sparams, sstate, ring, ring_pos, rand, t0, block, np.bool_(False))
    if status != -1:
        return status
    K._check_rows(params, n, False)
    cur = 0
    for t in range(T):
        status = K._first_nonfinite(Zm[t])  # the batch kernel's checks, as Observer.update makes them
        if status == -1:
            status = _ROWS(work[cur], Zm[t], params, work[1 - cur], est, False)
        if status != -1:
            return -2 - (t * n + (-2 - status if status <= -2 else status))
        cur = 1 - cur
    for c in range(n):
        for j in range(S):
            state[c, j] = work[cur, c, j]
    last = Q[T - 1]
    zm = Zm[T - 1]
    o_qvel, o_vhat, o_qmeas, o_z, o_zm = nq, nq + n, nq + 2 * n, 2 * nq + 2 * n, 2 * nq + 3 * n
    for i in range(nq):
        info[i] = last[i]
    for c in range(n):
        v = K.reported_sum(velocity, est[c])  # VelocityEstimator.velocity_of, bit for bit
        info[o_qvel + c] = qvel_true[c]
        info[o_vhat + c] = v
        info[o_zm + c] = zm[c]
        info[o_z + c] = z[c] if _MANIFOLD else last[c]
        scratch_qvel[c] = v
    if _MANIFOLD:  # measured configuration q (+) (z_meas - z), filtered one q_meas (+) (z_filtered - z_meas)
        dz = np.empty(n)
        for c in range(n):
            dz[c] = zm[c] - z[c]
        for i in range(nq):
            info[o_qmeas + i] = last[i]
        integrate_pos(joints, info[o_qmeas : o_qmeas + nq], dz)
        for i in range(nq):
            scratch_qpos[i] = info[o_qmeas + i]
        if filtered:
            for c in range(n):
                dz[c] = est[c, 0] - zm[c]
            integrate_pos(joints, scratch_qpos, dz)
    else:
        for c in range(n):
            info[o_qmeas + c] = zm[c]
            scratch_qpos[c] = est[c, 0] if filtered else zm[c]
    clipped_selection(scratch_qpos, scratch_qvel, obs_index, obs_bounds, obs)
    return -1


@njit(cache=True, error_model="numpy")
def clipped_selection(qpos, qvel, index, bounds, obs):
    """``obs[i] = np.clip(x[index[i]], bounds[0, i], bounds[1, i])`` with ``x = [qpos, qvel]``, in ``np.clip``'s
    order (the lower bound first): the observation of :attr:`ScratchObservation.observation_map
    <smo_gym.engine.scratch.ScratchObservation.observation_map>` at a sensed state."""
    nq = qpos.shape[0]
    for i in range(obs.shape[0]):
        k = index[i]
        v = qpos[k] if k < nq else qvel[k - nq]
        v = max(v, bounds[0, i])
        obs[i] = min(v, bounds[1, i])


@intrinsic
def _pointer(typingctx, address):
    """The integer ``address`` as a ``void *`` (for :func:`numba.carray`)."""
    if not isinstance(address, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return types.voidptr(address), codegen


@njit(cache=True, error_model="numpy")
def copy_entries(table):
    """Copy float64 blocks by address, rows ``[to, from, size, ...]`` (the controller inputs into the scratch
    data; further columns are ignored)."""
    for row in range(table.shape[0]):
        to = carray(_pointer(table[row, 0]), (table[row, 2],), np.float64)
        source = carray(_pointer(table[row, 1]), (table[row, 2],), np.float64)
        for i in range(table[row, 2]):
            to[i] = source[i]


def address(array: np.ndarray) -> int:
    """The address of an array's first element, as the address tables of this module hold it."""
    return array.__array_interface__["data"][0]


ENTRY_IDENTITY = 0
"""Entry function code: the observation entry is the MjData entry itself."""
ENTRY_SIN = 1
"""Entry function code: the observation entry is ``sin`` of the MjData entry."""
ENTRY_COS = 2
"""Entry function code: the observation entry is ``cos`` of the MjData entry."""


@njit(cache=True)
def _entry_function(code, v):
    """``v``, ``sin(v)`` or ``cos(v)`` by ``code`` (:data:`ENTRY_IDENTITY`, :data:`ENTRY_SIN`, :data:`ENTRY_COS`)."""
    if code == ENTRY_SIN:
        return math.sin(v)
    if code == ENTRY_COS:
        return math.cos(v)
    return v


@njit(cache=True, error_model="numpy")
def gather_entries(addresses, functions, bounds, obs):
    """``obs[i] = clip(f_i(*addresses[i]), bounds[0, i], bounds[1, i])`` as ``np.clip`` (NaN stays NaN), ``f_i``
    the identity, ``sin`` or ``cos`` (``functions[i]``: :data:`ENTRY_IDENTITY`, :data:`ENTRY_SIN`,
    :data:`ENTRY_COS`): the observation as a function of MjData entries, one entry each
    (:attr:`ScratchObservation.observation_entries
    <smo_gym.engine.scratch.ScratchObservation.observation_entries>`). ``sin`` and ``cos`` are the C
    library's, as NumPy's on the platforms the adapter's probe accepts. Returns the first entry that is not
    finite, or -1."""
    for i in range(obs.shape[0]):
        v = _entry_function(functions[i], carray(_pointer(addresses[i]), (1,), np.float64)[0])
        if v == v:  # not NaN
            v = max(v, bounds[0, i])
            v = min(v, bounds[1, i])
        obs[i] = v
        if not np.isfinite(v):
            return i
    return -1


@njit(cache=True)
def _entry_functions(x, functions, out):
    """``out[i] = f_i(x[i])`` with :func:`gather_entries`' functions (the probe compares them with NumPy's)."""
    for i in range(x.shape[0]):
        out[i] = _entry_function(functions[i], x[i])


@functools.cache
def entry_functions_match_numpy(n: int = 4096, seed: int = 2468) -> bool:
    """Whether :func:`gather_entries`' ``sin``/``cos`` equal NumPy's ``np.sin``/``np.cos`` bit for bit, on random
    arguments of magnitudes 1e-8 to 1e4, each through NumPy both as one long array and as two-element arrays (the
    size an environment's ``_get_obs`` passes, where NumPy may take another loop). NumPy can use its own SIMD
    implementations on some CPUs; then the adapter keeps the environment's ``_get_obs`` for such observations.
    Computed once per process."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(n) * 10.0 ** rng.uniform(-8, 4, n)
    for code, numpy_function in ((ENTRY_SIN, np.sin), (ENTRY_COS, np.cos)):
        out = np.empty(n)
        _entry_functions(x, np.full(n, code, dtype=np.int64), out)
        pairs = np.concatenate([numpy_function(x[i : i + 2]) for i in range(0, n, 2)])
        if not (np.array_equal(out, numpy_function(x)) and np.array_equal(out, pairs)):
            return False
    return True


class FusedDriver(NamedTuple):
    """The two compiled drivers of an observer kernel (:func:`_sense_template`), compiled on first call: only the
    one a model needs is compiled, and a model without free or ball joints never compiles the tangent arithmetic."""

    flat: Callable
    """For models whose joints are all hinges and slides (``z = qpos``)."""
    manifold: Callable
    """For models with free or ball joints (tangent coordinates, :mod:`smo_gym.engine.tangent`)."""


class _FusedDrivers(Mapping):
    """Observer kernel -> its fused driver, for every step registered with
    :func:`smo_gym.observers._kernels.register_step` (:data:`~smo_gym.observers._kernels.STEPS`).

    Each driver is :func:`_sense_template` with the kernel bound (:func:`smo_gym._numba_cache.cached_instance`:
    cached on disk, reused by a new process), generated on first use, so that a family registered after this
    module was imported has its driver too. Its cached code is dropped when the kernel's module, the kernels of
    :mod:`smo_gym.observers._kernels`, the sensor chain or the tangent arithmetic change (its cached machine code
    contains theirs).
    """

    def __init__(self):
        self._drivers: dict = {}

    def __getitem__(self, kernel) -> FusedDriver:
        driver = self._drivers.get(kernel)
        if driver is None:
            step = K.STEPS[kernel]  # KeyError: not a registered kernel
            driver = self._drivers[kernel] = FusedDriver(
                flat=bound_to_step(_sense_template, step, _MANIFOLD=False),
                manifold=bound_to_step(_sense_template, step, ".manifold", _MANIFOLD=True),
            )
        return driver

    def __iter__(self):
        return iter(list(K.STEPS))

    def __len__(self) -> int:
        return len(K.STEPS)


def bound_to_step(template, step: K.Step, suffix: str = "", **constants):
    """A compiled caller of an observer's step: ``template`` with its global ``_ROWS`` bound to ``step.rows`` (and
    ``constants`` to theirs), cached on disk under the step's label plus ``suffix``
    (:func:`smo_gym._numba_cache.cached_instance`). Its cached code is dropped when the step's modules, the kernels of
    :mod:`smo_gym.observers._kernels`, the sensor chain, the tangent arithmetic or this module's helpers
    (:func:`clipped_selection`) change (it contains theirs)."""
    from .. import sensors
    from . import tangent

    deps = [*step.sources, K.__file__, sensors.__file__, tangent.__file__, __file__]
    options = dict(cache=True, error_model="numpy")
    return cached_instance(template, step.label + suffix, options, deps, _ROWS=step.rows, **constants)


#: observer kernel -> its fused driver (every registered step has one, generated on first use)
FUSED_DRIVERS = _FusedDrivers()


def fusable(observer) -> bool:
    """Whether the fused drivers serve this observer: it runs a registered compiled step as it is
    (:func:`smo_gym.observers.composite.compiled_step`: a registered family with compiled steps only, or a
    :class:`~smo_gym.observers.PerChannel` of such families)."""
    return compiled_step(observer) is not None


def fusable_estimator(estimator: VelocityEstimator) -> bool:
    """Whether a compiled caller of the observer's step computes exactly what ``estimator`` would: a plain
    :class:`VelocityEstimator` around a :func:`fusable` observer of order >= 1 without wrapped channels (the
    drivers call the kernels directly, without unwrapping)."""
    observer = estimator.observer
    return (
        type(estimator) is VelocityEstimator and fusable(observer) and not np.any(observer.wrap) and observer.order >= 1
    )


class FusedSensing:
    r"""The wrapper's hot path: one compiled call per control period (:mod:`smo_gym.engine.fused`).

    Sensor chain, observer update, the scratch state for the observation and the ``info["smo"]`` block in one
    call, with the numbers of the general path (``JointMeasurement.measure_block`` then ``Observer.run``). It
    drives the sensor's and the observer's own arrays and keeps their bookkeeping (the sensor's position in its
    random block, the observer's estimate and update count), so both objects stay usable as they are.

    Use :meth:`supports` first: a plain :class:`VelocityEstimator` around an observer of a registered compiled
    family or a composite of them (:func:`fusable`) and an adapter with a scratch state (every sensor qualifies: a
    sensor is its stages, see :class:`smo_gym.sensors.Sensor`).

    Parameters
    ----------
    measurement : JointMeasurement
    estimator : VelocityEstimator
    adapter : smo_gym.wrappers.adapters.GymnasiumMujocoAdapter
    filtered : bool
        Put the observer's filtered positions (instead of the measurement) into the observation's ``qpos``.
    """

    def __init__(self, measurement: JointMeasurement, estimator: VelocityEstimator, adapter, filtered: bool):
        self._slots = TABLE_SLOTS
        self.measurement, self.adapter = measurement, adapter
        self.sensor, self.observer = measurement.sensor, estimator.observer
        self.filtered = bool(filtered)
        # the combination of the estimate's derivatives reported as the velocity (the step mean, or column 1)
        self._velocity = np.array([1.0] if estimator.coefficients is None else estimator.coefficients, dtype=float)
        drivers = FUSED_DRIVERS[self.observer._kernel]
        self._driver = drivers.manifold if measurement.tangent.manifold else drivers.flat
        self.evaluation = evaluation = adapter.evaluation
        self._selection = selection = evaluation.observation_map
        #: the compiled call also builds the observation (a clipped selection of the sensed state, probed by the
        #: adapter): :meth:`sample` leaves it in :attr:`observation`
        self.maps_observation = selection is not None
        if selection is None:
            selection = (np.zeros(0, dtype=np.int64), np.zeros((2, 0)))
        self._obs_index, self._obs_bounds = selection
        self._n_obs = len(self._obs_index)
        #: the compiled call copies the controller inputs the observation reads into the scratch data (the
        #: adapter's :meth:`~smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.input_views`)
        self.copies_inputs = bool(evaluation.copies_inputs)
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
        return fusable_estimator(estimator) and adapter.evaluation is not None

    def _bind(self, Q: np.ndarray, qvel_true: np.ndarray) -> None:
        """Resolve the driver's compiled entry point (once: the arguments keep their types across resets).

        The entry point skips numba's type dispatch; it checks nothing, so every later call passes arrays of
        exactly these types: ``Q`` is a view of the live ``qpos`` or the wrapper's sample buffer, ``qvel_true``
        the live ``qvel`` (writeable, aligned, C-contiguous float64); ``est``, ``info``, ``Zm`` and ``obs`` are
        made here; the other arrays go through the address table (:meth:`prepare`).
        """
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

        The table (:data:`smo_gym.engine.fused.TABLE_SLOTS`) holds raw addresses, so the arrays are kept in
        ``_static`` for as long as the table points to them, and each is checked: dtype, dimensions, C order.
        Rows are rebuilt only for arrays that changed (most resets replace only the tangent coordinates).

        Raises
        ------
        ValueError
            The live ``MjData`` is not of the measured model's size (the compiled call reads it without a check).
        """
        live, model = self.evaluation.live(), self.measurement.model
        if live.qpos.shape != (model.nq,) or live.qvel.shape != (model.nv,):  # the compiled call reads them unchecked
            raise ValueError(
                f"expected the live MjData of the model measured (qpos of size {model.nq}, qvel of size {model.nv}), "
                f"actual value: sizes {live.qpos.size} and {live.qvel.size} (a model replaced in the middle of an "
                "episode: replace it in reset_model, where the wrappers follow it)"
            )
        sensed, estimated = self.sensor.arrays, self.observer.arrays
        # a selection the evaluation dropped or probed again at a reset (ScratchObservation.verify and follow) is built
        # by the evaluation from then on
        self.maps_observation = self.maps_observation and self.evaluation.observation_map is self._selection
        n, S = estimated.state.shape
        if self._work is None or self._work.shape[1:] != (n, S):
            self._work = np.empty((2, n, S))
            self._Zm = np.empty((1, n))
        self._shape = (n, self.observer.order + 1)
        scratch_qpos, scratch_qvel = self.evaluation.scratch_state()
        tangent = self.measurement.tangent
        static = (
            *sensed,
            *estimated,
            self._work,
            scratch_qpos,
            scratch_qvel,
            self.filtered,
            tangent.joints,
            tangent.previous,
            tangent.z if tangent.manifold else self._unused_z,
            self._obs_index,
            self._obs_bounds,
            self._velocity,
        )
        # the controller inputs the observation reads, copied by the compiled call (time, a scalar, is not)
        pairs = self.evaluation.input_views()[0] if self.copies_inputs else ()
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
        sensor, observer = self.sensor, self.observer
        T = Q.shape[0]
        # a used-up block is refilled in place (the prepared arrays stay valid); more samples than a block holds
        # (frame_skip above BLOCK) take the general path, which splits them
        t0 = sensor.reserve_random_rows(T) if T <= BLOCK else None
        if t0 is None:
            return None
        call = self._call
        if call is None:
            self._bind(Q, qvel_true)
            call = self._call
        static = self._static
        if static[_OBSERVER_STATE] is not observer.arrays.state or static[_SENSOR_STATE] is not sensor.arrays.state:
            # replaced since prepare(): Observer.run commits a new state array, Sensor.reset new arrays
            self.prepare()
        if self._Zm.shape[0] < T:
            self._Zm = np.empty((T, self._shape[0]))
        est = np.empty(self._shape)
        info = np.empty(self._info_size)
        obs = self.observation = np.empty(self._n_obs) if self.maps_observation else self._no_obs
        status = call(Q, qvel_true, t0, est, info, self._Zm, obs, self._table)
        if status != -1:
            self._raise(status, Q)
        observer.advanced(est, T)
        self.measurement.load_block(info)
        return info

    def _raise(self, status: int, Q: np.ndarray):
        n = self._shape[0]
        if status >= 0:
            t, channel = divmod(status, n)
            self.sensor._raise(channel, Q[t], self._Zm[t])
        t, channel = divmod(-2 - status, n)
        self.observer._raise_status(-2 - channel, self._Zm[t])


class InputCopy:
    """One compiled copy of float64 arrays, ``to[...] = source`` for each ``(to, source)`` pair of equal size.

    The address table of :func:`copy_entries` is made here and lives as long as this object, which keeps the
    arrays it points into alive (the pairs are held).

    Parameters
    ----------
    pairs : sequence of (ndarray, ndarray)
        C-contiguous float64 arrays, destination first.
    source : object, optional
        What the sources belong to (e.g. the live ``MjData``), for the owner's cache.
    reads_time : bool
        Whether the owner also copies the scalar ``time`` (not part of the compiled copy).
    """

    def __init__(self, pairs, source=None, reads_time: bool = False):
        for to, origin in pairs:
            for a in (to, origin):
                if not (type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous):
                    raise TypeError(f"expected C-contiguous float64 arrays, actual value: {a!r:.80}")
            if to.size != origin.size:
                raise TypeError(f"expected arrays of one size, actual value: {to.size} and {origin.size}")
        self.pairs = tuple(pairs)
        self.source, self.reads_time = source, bool(reads_time)
        self._table = np.array(
            [(address(to), address(origin), to.size) for to, origin in self.pairs], dtype=np.int64
        ).reshape(-1, 3)
        self._call = _compiled_entry(copy_entries, (self._table,))

    def __call__(self) -> None:
        self._call(self._table)

    def __getstate__(self):
        raise TypeError("an InputCopy holds this process's addresses and does not pickle; make it again")


class EntryGather:
    """One compiled gather of single float64 entries of several arrays, clipped, or their sines and cosines.

    ``obs[i] = clip(f_i(fields[names[i]].flat[flat[i]]), bounds[0, i], bounds[1, i])`` (:func:`gather_entries`);
    the address table is made here and lives as long as this object, which keeps the fields alive.

    Parameters
    ----------
    fields : dict of str to ndarray
        C-contiguous float64 arrays by name.
    names : sequence of str
        The field of each entry.
    flat, functions : ndarray of int64, shape (n,)
        Flat index into the field, and the entry function code (:data:`ENTRY_IDENTITY`, ...).
    bounds : ndarray, shape (2, n)
        Clip bounds.
    """

    def __init__(self, fields: dict, names, flat, functions, bounds):
        base = {}
        for name, array in fields.items():
            if not (type(array) is np.ndarray and array.dtype == np.float64 and array.flags.c_contiguous):
                raise TypeError(f"expected {name} as a C-contiguous float64 array, actual value: {array!r:.80}")
            base[name] = address(array)
        for name, k in zip(names, flat, strict=True):
            if not 0 <= int(k) < fields[name].size:
                raise ValueError(f"expected an entry of {name} (size {fields[name].size}), actual value: {int(k)}")
        self.fields = dict(fields)
        self.functions = np.ascontiguousarray(functions, dtype=np.int64)
        self.bounds = np.ascontiguousarray(bounds, dtype=np.float64)
        self.addresses = np.array(
            [base[name] + 8 * int(k) for name, k in zip(names, flat, strict=True)], dtype=np.int64
        )
        self._parts = (self,)
        self._call = _compiled_entry(
            gather_entries, (self.addresses, self.functions, self.bounds, np.empty(len(self.addresses)))
        )

    @classmethod
    def concatenate(cls, gathers) -> EntryGather:
        """One gather of the entries of several (e.g. one per environment of a vector env), in order."""
        gathers = tuple(gathers)
        self = cls.__new__(cls)
        self.fields = {}
        self._parts = gathers  # keeps every part's fields alive
        self.functions = np.concatenate([g.functions for g in gathers])
        self.bounds = np.ascontiguousarray(np.concatenate([g.bounds for g in gathers], axis=1))
        self.addresses = np.concatenate([g.addresses for g in gathers])
        self._call = gathers[0]._call
        return self

    def __len__(self) -> int:
        return len(self.addresses)

    def __call__(self, obs: np.ndarray) -> int:
        """Fill ``obs`` (n,); returns the index of the first non-finite entry, or -1."""
        return self._call(self.addresses, self.functions, self.bounds, obs)

    def __getstate__(self):
        raise TypeError("an EntryGather holds this process's addresses and does not pickle; make it again")
