r"""Several environments measured (and estimated) together: one compiled call per vector step.

An in-process vector env (Gymnasium's ``SyncVectorEnv``, Stable-Baselines3's ``DummyVecEnv``) steps ``n``
environments of one model in lock step, each with its own :class:`~smo_gym.engine.measurement.JointMeasurement`:
a sensor with its own random stream and seed, and tangent coordinates for free and ball joints. Measured one by
one, each costs a few Python calls per step. :class:`MeasurementBatch` keeps their state as the rows of stacked
named arrays instead: each sensor keeps its stream in one row
(:meth:`Sensor.use_arrays <smo_gym.sensors.Sensor.use_arrays>`: stage kinds, packed parameters, stage state,
delay lines, pre-drawn random numbers), and so do the tangent coordinates
(:meth:`TangentCoordinates.use_arrays <smo_gym.engine.measurement.TangentCoordinates.use_arrays>`). Then one
compiled call, :func:`measure_rows`, measures the configurations ``Q`` ``(n, nq)`` of any subset of the
environments.

Row ``i`` runs exactly what ``measurements[i].measure(Q[i])`` runs: the tangent coordinates
(:func:`~smo_gym.engine.tangent.tangent_advance`), the sensor chain (:func:`smo_gym.sensors._chain_kernel`) with
the next row of that sensor's own random block (reserved with :meth:`~smo_gym.sensors.Sensor.reserve_random_rows`,
so the stream does not depend on batching) and the measured configuration
(:func:`~smo_gym.engine.tangent.integrate_pos`): the same numbers, bit for bit (tested). The measurements stay
usable one by one (a reset, the last sample of an episode, :meth:`~JointMeasurement.measured_qpos`): they read and
write the same rows, and each measured row is loaded into its measurement as its last sample
(:meth:`JointMeasurement.load_block <smo_gym.engine.measurement.JointMeasurement.load_block>`).

A vector step where every environment goes on needs more than the measurements: :class:`BatchedSensing` runs
:func:`measure_rows`, the batched observer's registered step on all the environments' channels and, for
observations that are a clipped selection of the state, the observations, in one compiled call as well.
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Sequence

import mujoco
import numpy as np
from numba import njit

from .. import sensors
from .._numba_cache import drop_stale
from ..observers import _kernels as K
from ..observers.base import _compiled_entry
from ..sensors import Sensor, SensorArrays, _chain_kernel
from . import tangent
from .fused import InputCopy, bound_to_step, clipped_selection, fusable_estimator
from .measurement import JointMeasurement, VelocityEstimator
from .tangent import integrate_pos, tangent_advance

__all__ = ["BatchedSensing", "MeasurementBatch", "block_slices", "measure_rows"]


def block_slices(nq: int, nv: int) -> tuple[slice, ...]:
    """Where ``qpos``, ``qvel``, ``qvel_estimate``, ``qpos_measured``, ``z_true`` and ``z_measured`` lie in a row of
    the block :meth:`MeasurementBatch.measure` returns (``2 nq + 4 nv`` columns; the first four are
    ``info["smo"]``'s, :meth:`SensingInfo.slices <smo_gym.wrappers.sensing.SensingInfo.slices>`)."""
    bounds = np.cumsum([0, nq, nv, nv, nq, nv, nv])
    return tuple(slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True))


@njit(cache=True, error_model="numpy")
def measure_rows(rows, Q, V, t0, kinds, params, state, ring, ring_pos, rand, joints, previous, z, block):
    r"""Measure the configurations ``Q[i]`` ``(n, nq)`` of the environments ``i`` where ``rows[i]`` (a boolean
    mask ``(n,)``), each with its own sensor stream and tangent coordinates.

    For each such row: the tangent coordinates :math:`z_i` of ``Q[i]`` (``joints`` (njnt, 3) the joint table of
    :func:`~smo_gym.engine.tangent.joint_table`, ``previous[i]`` (nq,) and ``z[i]`` (nv,) advanced in place;
    ``joints`` empty for a model without free or ball joints, then :math:`z_i` is ``Q[i]``), the sensor chain
    :math:`z^{meas}_i` of stream ``i`` (the arrays of :class:`~smo_gym.sensors.SensorArrays` with a leading
    environment dimension; random row ``rand[i, t0[i]]``), and the measured configuration
    :math:`q_i \oplus (z^{meas}_i - z_i)`. Row ``i`` of ``block`` ``(n, 2 nq + 4 nv)`` receives
    ``[Q[i], V[i], (untouched), qpos_measured, z_true, z_measured]`` (:func:`block_slices`); other rows are left
    as they are.

    Every configuration is checked before any stream moves. Returns -1; or ``-2 - (i * nq + j)`` for a non-finite
    ``Q[i, j]`` (nothing changed); or ``i * nv + j`` where the sensor of environment ``i`` produced a non-finite
    value in channel ``j`` (the rows before ``i`` are measured).
    """
    nq = Q.shape[1]
    nv = V.shape[1]
    manifold = joints.shape[0] > 0
    o_qvel, o_qmeas, o_z, o_zm = nq, nq + 2 * nv, 2 * nq + 2 * nv, 2 * nq + 3 * nv
    n = rows.shape[0]
    for i in range(n):
        if rows[i]:
            for j in range(nq):
                if not np.isfinite(Q[i, j]):
                    return -2 - (i * nq + j)
    zm = np.empty(nv)
    dz = np.empty(nv)
    for i in range(n):
        if not rows[i]:
            continue
        q = Q[i]
        if manifold:
            tangent_advance(joints, previous[i], q, z[i])
            y = z[i]
        else:
            y = q
        status = _chain_kernel(y, kinds[i], params[i], state[i], ring[i], ring_pos[i], rand[i, t0[i]], False, zm)
        if status != -1:
            return i * nv + status
        out = block[i]
        for k in range(nq):
            out[k] = q[k]
        for c in range(nv):
            out[o_qvel + c] = V[i, c]
            out[o_z + c] = y[c]
            out[o_zm + c] = zm[c]
        if manifold:  # q (+) (z_meas - z), as TangentCoordinates.to_qpos
            for c in range(nv):
                dz[c] = zm[c] - y[c]
            for k in range(nq):
                out[o_qmeas + k] = q[k]
            integrate_pos(joints, out[o_qmeas : o_qmeas + nq], dz)
        else:
            for c in range(nv):
                out[o_qmeas + c] = zm[c]
    return -1


# measure_rows inlines the sensor chain and the tangent arithmetic: its cached code is stale when they change
drop_stale((measure_rows,), [sensors.__file__, tangent.__file__])


def _as_input(a, shape: tuple[int, int]) -> np.ndarray:
    """``a`` as a writeable, aligned, C-contiguous float64 array of ``shape`` (the layout the compiled entry point
    of :func:`measure_rows` takes)."""
    if not (
        type(a) is np.ndarray and a.dtype == np.float64 and (f := a.flags).c_contiguous and f.writeable and f.aligned
    ):
        a = np.array(a, dtype=np.float64, order="C")
    if a.shape != shape:
        raise ValueError(f"expected an array of shape {shape}, actual value: {a.shape}")
    return a


class MeasurementBatch:
    r"""Several environments' :class:`~smo_gym.engine.measurement.JointMeasurement` as rows of stacked arrays,
    measured together by one compiled call (:func:`measure_rows`, see the module docstring).

    Make it once the measurements were reset (their sensors have a stream); :meth:`supports` says beforehand
    whether they can share one.

    Parameters
    ----------
    measurements : sequence of JointMeasurement
        One per environment, of models with equal joint tables, and sensors of the same chain (equal
        :attr:`~smo_gym.sensors.Sensor.arrays` shapes); each keeps its sensor's stream and tangent coordinates
        in its row from now on.

    Raises
    ------
    ValueError
        Measurements that cannot share a batch (:meth:`supports`), or sensors reset to different numbers of
        channels.
    RuntimeError
        A sensor that was never reset.

    Attributes
    ----------
    sensors : smo_gym.sensors.SensorArrays
        The streams, each array with a leading environment dimension ``(n, ...)``.
    previous, z : ndarray, shape (n, nq) and (n, nv)
        The tangent coordinates' last configuration and coordinates (models with free or ball joints; empty
        otherwise).
    """

    def __init__(self, measurements: Sequence[JointMeasurement]):
        if not self.supports(measurements):
            raise ValueError(
                "expected measurements of models with one joint table and sensors of one chain, actual value: "
                f"{len(measurements)} measurements that differ"
            )
        self.measurements = tuple(measurements)
        n = len(self.measurements)
        first = self.measurements[0]
        self.nq, self.nv = first.model.nq, first.model.nv
        shapes = [tuple(a.shape for a in m.sensor.arrays) for m in self.measurements]  # RuntimeError: never reset
        if any(shape != shapes[0] for shape in shapes):
            raise ValueError(f"expected sensors reset to one number of channels, actual value: streams of {shapes}")
        self.sensors = SensorArrays(*(np.zeros((n, *a.shape), dtype=a.dtype) for a in first.sensor.arrays))
        for i, measurement in enumerate(self.measurements):
            measurement.sensor.use_arrays(SensorArrays(*(a[i] for a in self.sensors)))
        tangent_coordinates = first.tangent
        if tangent_coordinates.manifold:
            self.joints = tangent_coordinates.joints
            self.previous, self.z = np.zeros((n, self.nq)), np.zeros((n, self.nv))
            for i, measurement in enumerate(self.measurements):
                measurement.tangent.use_arrays(self.previous[i], self.z[i])
        else:
            self.joints = np.zeros((0, 3), dtype=np.int64)
            self.previous, self.z = np.zeros((n, 0)), np.zeros((n, 0))
        self.slices = block_slices(self.nq, self.nv)
        self._t0 = np.zeros(n, dtype=np.int64)
        self._reserve = [m.sensor.reserve_random_rows for m in self.measurements]
        self._load = [m.load_block for m in self.measurements]
        self._call = None
        #: the live states of :meth:`measure_live`: ``(qpos (n, nq), qvel (n, nv))`` and their compiled copy from
        #: the MjData it was made for
        self._live = (np.zeros((n, self.nq)), np.zeros((n, self.nv)))
        self._live_copy = self._live_data = None
        self._every, self._every_index = np.ones(n, dtype=bool), list(range(n))

    @staticmethod
    def supports(measurements: Sequence[JointMeasurement]) -> bool:
        """Whether these measurements can share one batch: at least one; plain :class:`JointMeasurement` objects
        (a subclass may measure otherwise) of models with equal joint tables (types and addresses), and sensors of
        equal stages (so their streams have equal shapes; a sensor is its stages, so the batch computes what each
        sensor would). Decided before the resets; the batch is made after them."""
        if not measurements:
            return False
        first = measurements[0]
        return all(
            type(m) is JointMeasurement
            and isinstance(m.sensor, Sensor)
            and tuple(m.sensor.stages) == tuple(first.sensor.stages)
            and m.model.nq == first.model.nq
            and m.model.nv == first.model.nv
            and m.tangent.manifold == first.tangent.manifold
            and np.array_equal(m.tangent.joints, first.tangent.joints)
            for m in measurements
        )

    def __getstate__(self):
        raise TypeError(
            "a MeasurementBatch shares its arrays with the sensors of its measurements and does not pickle; make it "
            "again from the (unpickled) measurements"
        )

    def holds(self, i: int) -> bool:
        """Whether the sensor of environment ``i`` still keeps its stream in row ``i`` (a reset to another number of
        channels would leave it)."""
        return self.measurements[i].sensor.arrays.state.base is self.sensors.state

    def measure(self, Q: np.ndarray, V: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Measure the configurations ``Q`` ``(n, nq)`` of the environments where ``rows`` (boolean mask ``(n,)``).

        Returns the block ``(n, 2 nq + 4 nv)``, a new array: in the measured rows ``[qpos, qvel, qvel_estimate,
        qpos_measured, z_true, z_measured]`` (:func:`block_slices`) with ``qpos = Q[i]``, ``qvel = V[i]`` (``V``
        ``(n, nv)``, the true velocities, copied for ``info["smo"]``) and ``qvel_estimate`` left for the caller
        (zero); the other rows are zero. Each measured row is its measurement's last sample from now on.

        Raises
        ------
        ValueError
            Arrays of other shapes; a non-finite configuration (nothing measured), or a non-finite measurement
            produced by a sensor (the message names the environment and the channel).
        """
        n = len(self.measurements)
        Q, V = _as_input(Q, (n, self.nq)), _as_input(V, (n, self.nv))
        return self._measure(Q, V, self._as_rows(rows))

    def _as_rows(self, rows) -> np.ndarray:
        """``rows`` as the boolean mask ``(n,)`` the compiled entry point takes (``ValueError`` otherwise)."""
        n = len(self.measurements)
        rows = np.asarray(rows)
        if rows.dtype != np.bool_ or rows.shape != (n,):
            raise ValueError(f"expected a boolean mask of shape ({n},), actual value: {rows.dtype} {rows.shape}")
        return np.ascontiguousarray(rows)

    def _measure(self, Q: np.ndarray, V: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """:meth:`measure` of arrays already in the compiled entry point's layout."""
        n = len(self.measurements)
        block = np.zeros((n, 2 * self.nq + 4 * self.nv))
        measured = self._every_index if rows is self._every else np.flatnonzero(rows).tolist()
        if not measured:
            return block
        args = (rows, Q, V, self.reserve(measured), *self.sensors, self.joints, self.previous, self.z, block)
        call = self._call
        if call is None:
            call = self._call = _compiled_entry(measure_rows, args)
        status = call(*args)
        if status != -1:
            self._raise(status, Q)
        self.loaded(block, measured)
        return block

    def measure_live(self, datas: Sequence[mujoco.MjData], rows: np.ndarray | None = None) -> np.ndarray:
        """:meth:`measure` of the live states of ``datas`` (one ``MjData`` per environment): their ``qpos`` and
        ``qvel`` are gathered by one compiled copy (:class:`~smo_gym.engine.fused.InputCopy`, made again when an
        environment replaced its data); ``rows`` None measures every environment."""
        return self._measure(*self.gather(datas), self._every if rows is None else self._as_rows(rows))

    def gather(self, datas: Sequence[mujoco.MjData]) -> tuple[np.ndarray, np.ndarray]:
        """The live ``qpos`` and ``qvel`` of ``datas`` (one ``MjData`` per environment) in two arrays ``(n, nq)``
        and ``(n, nv)``, the same ones at every call: one compiled copy
        (:class:`~smo_gym.engine.fused.InputCopy`, made again when an environment replaced its data)."""
        if self._live_data is None or not all(map(operator.is_, datas, self._live_data)):
            qpos, qvel = self._live
            pairs = [(qpos[i], d.qpos) for i, d in enumerate(datas)] + [(qvel[i], d.qvel) for i, d in enumerate(datas)]
            if len(pairs) != 2 * len(self.measurements):
                raise ValueError(f"expected {len(self.measurements)} MjData, actual value: {len(datas)}")
            self._live_copy, self._live_data = InputCopy(pairs), list(datas)
        self._live_copy()
        return self._live

    def reserve(self, measured: list[int]) -> np.ndarray:
        """Reserve the next random row of the sensors of the environments ``measured``; returns each sensor's row
        (``(n,)``, the compiled measurement's ``t0``)."""
        t0, reserve = self._t0, self._reserve
        for i in measured:
            t0[i] = reserve[i](1)  # never None for one sample
        return t0

    def loaded(self, block: np.ndarray, measured: list[int]) -> None:
        """Make the rows ``measured`` of ``block`` their measurements' last samples."""
        load, views = self._load, list(block)
        for i in measured:
            load[i](views[i])

    def _raise(self, status: int, Q: np.ndarray):
        if status <= -2:
            i, j = divmod(-2 - status, self.nq)
            raise ValueError(
                f"expected a finite joint configuration, actual value: {Q[i, j]!r} at qpos[{j}] of environment {i}; "
                "no environment was measured"
            )
        i, j = divmod(status, self.nv)
        raise ValueError(
            f"expected a finite measurement, actual value: a non-finite value at channel {j} of environment {i}, "
            f"produced by the sensor model {self.measurements[i].sensor!r}; a non-finite measurement is never "
            "passed on"
        )


# the global of the template below, bound per registered observer step by cached_instance: the step's rows function
_ROWS = None


def _sense_rows_template(
    rows, Q, V, t0, kinds, params, state, ring, ring_pos, rand, joints, previous, z, block,
    observer_state, observer_params, scratch, Z, estimate, velocity, obs_index, obs_bounds, obs,
):  # fmt: skip
    r"""One vector step of the in-process environments: :func:`measure_rows`, the batched observer's step on the
    measurements of every environment, the reported velocities and the observations, in one compiled call.

    The arguments up to ``block`` are :func:`measure_rows`'s. Then the observer's state ``(N, S)`` and per-channel
    parameters ``(N, P)`` (``N = n nv``; the environments' channels in order), ``scratch`` ``(N, S)`` and ``Z``
    ``(N,)`` work space, ``estimate`` ``(N, m)`` receives the new estimate, ``velocity`` the coefficients of the
    reported velocity (:func:`~smo_gym.observers._kernels.reported_sum`), written into the ``qvel_estimate``
    columns of ``block``. Last, for observations that are a clipped selection of the sensed state (``obs_index``
    ``(k,)`` into ``[qpos_measured, qvel_estimate]``, ``obs_bounds`` ``(2, k)``; ``k = 0``: none), the
    observations ``obs`` ``(n, k)``, clipped in ``np.clip``'s order.

    Returns ``(stage, status)``: ``(-1, -1)`` on success; ``(0, status)`` a status of :func:`measure_rows`
    (nothing estimated); ``(1, status)`` the observer's step failed (its state unchanged).
    """
    status = measure_rows(rows, Q, V, t0, kinds, params, state, ring, ring_pos, rand, joints, previous, z, block)
    if status != -1:
        return 0, status
    n, nv = V.shape
    nq = Q.shape[1]
    o_vhat, o_qmeas, o_zm = nq + nv, nq + 2 * nv, 2 * nq + 3 * nv
    for i in range(n):
        for c in range(nv):
            Z[i * nv + c] = block[i, o_zm + c]
    N, S = observer_state.shape
    K._check_rows(observer_params, N, False)
    status = _ROWS(observer_state, Z, observer_params, scratch, estimate, False)
    if status != -1:
        return 1, status
    for c in range(N):
        for j in range(S):
            observer_state[c, j] = scratch[c, j]
    for i in range(n):
        out = block[i]
        for c in range(nv):
            out[o_vhat + c] = K.reported_sum(velocity, estimate[i * nv + c])  # VelocityEstimator.velocity_of
        clipped_selection(out[o_qmeas : o_qmeas + nq], out[o_vhat : o_vhat + nv], obs_index, obs_bounds, obs[i])
    return -1, -1


@functools.cache
def _sense_rows(kernel):
    """:func:`_sense_rows_template` bound to the registered step of the observer ``kernel``, cached on disk."""
    return bound_to_step(_sense_rows_template, K.STEPS[kernel])


class BatchedSensing:
    r"""The in-process vector wrappers' common step in one compiled call: measure every environment
    (:class:`MeasurementBatch`), advance the batched observer and build the observations
    (:func:`_sense_rows_template`).

    The numbers are those of :meth:`MeasurementBatch.measure_live` followed by ``estimator.update`` and
    ``estimator.velocity_of`` (tested bit for bit): the same compiled measurement and the observer's own step.

    Parameters
    ----------
    batch : MeasurementBatch
        The environments' measurements.
    estimator : VelocityEstimator
        The batched observer's estimator, observer of shape ``(n, nv)``; :meth:`supports` must hold.
    selection : tuple of ndarray, optional
        ``(index, low, high)`` when every observation is the same clipped selection of ``[qpos_measured,
        qvel_estimate]``, ``np.clip(x[index], low, high)`` (:attr:`ScratchObservation.observation_map
        <smo_gym.engine.scratch.ScratchObservation.observation_map>`): the call builds the observations too.
    """

    def __init__(self, batch: MeasurementBatch, estimator: VelocityEstimator, selection=None):
        if not self.supports(estimator):
            raise ValueError(f"expected an estimator of a compiled observer step, actual value: {estimator.observer}")
        self.batch, self.observer = batch, estimator.observer
        self._velocity = np.array([1.0] if estimator.coefficients is None else estimator.coefficients, dtype=float)
        self.maps_observation = selection is not None
        index, low, high = selection if selection is not None else (np.zeros(0, dtype=np.int64), (), ())
        self._index = np.ascontiguousarray(index, dtype=np.int64)
        self._bounds = np.array([low, high], dtype=np.float64).reshape(2, len(self._index))
        self._driver = _sense_rows(self.observer._kernel)
        self._call = self._scratch = None

    supports = staticmethod(fusable_estimator)

    def step(self, datas: Sequence[mujoco.MjData]) -> tuple[np.ndarray, np.ndarray | None]:
        """Measure the live states of ``datas`` and advance the observer by one sample.

        Returns ``(block, observations)``: the block of :meth:`MeasurementBatch.measure`, its ``qvel_estimate``
        columns filled, and the observations ``(n, k)`` with a ``selection`` (None otherwise). The observer's
        estimate is a new array (:meth:`~smo_gym.observers.Observer.advanced`).

        Raises
        ------
        ValueError
            As :meth:`MeasurementBatch.measure_live` (nothing estimated).
        smo_gym.observers.DivergenceError
            The observer's state would become non-finite (its state unchanged; the measurements were taken).
        """
        batch, observer = self.batch, self.observer
        Q, V = batch.gather(datas)
        n = len(batch.measurements)
        state, params = observer.arrays
        scratch = self._scratch
        if scratch is None or scratch[0].shape != state.shape:
            scratch = self._scratch = (np.empty_like(state), np.empty(state.shape[0]))
        estimate = np.empty((state.shape[0], observer.order + 1))
        block = np.empty((n, 2 * batch.nq + 4 * batch.nv))
        obs = np.empty((n, len(self._index)))
        measured = batch._every_index
        args = (batch._every, Q, V, batch.reserve(measured), *batch.sensors, batch.joints, batch.previous, batch.z)
        args += (block, state, params, *scratch, estimate, self._velocity, self._index, self._bounds, obs)
        call = self._call
        if call is None:
            call = self._call = _compiled_entry(self._driver, args)
        stage, status = call(*args)
        if stage == 0:
            batch._raise(status, Q)
        batch.loaded(block, measured)
        if stage == 1:
            observer._raise_status(status, scratch[1].reshape(observer.shape))
        observer.advanced(estimate.reshape(observer.estimate.shape), 1)
        return block, obs if self.maps_observation else None
