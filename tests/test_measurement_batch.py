"""MeasurementBatch: several environments' joint measurements in one compiled call, equal to measuring each alone.

The reference is the same measurements made one by one (``JointMeasurement.measure``), with the same seeds: the
batch must give the same numbers bit for bit, with the random blocks refilled, episodes restarted with and without
a new seed, samples measured one by one in between (what a vector env's sensor does at an episode end), on a model
with free, ball, hinge and slide joints and on one with hinges only.
"""

from __future__ import annotations

import copy
import pickle

import mujoco
import numpy as np
import pytest

from smo_gym import sensors
from smo_gym.engine.batch import MeasurementBatch, block_slices
from smo_gym.engine.measurement import JointMeasurement, TangentCoordinates

MANIFOLD = """
<mujoco>
  <worldbody>
    <body pos="0 0 1"><freejoint/><geom size=".1"/>
      <body pos="0 0 -.3"><joint type="ball"/><geom size=".05"/>
        <body pos="0 0 -.2"><joint type="hinge" axis="0 1 0"/><geom size=".05"/>
          <body pos="0 0 -.2"><joint type="slide" axis="1 0 0"/><geom size=".05"/></body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
HINGES = """
<mujoco>
  <worldbody>
    <body><joint type="hinge" axis="0 1 0"/><geom size=".1"/>
      <body pos="0 0 -.3"><joint type="hinge" axis="1 0 0"/><geom size=".05"/></body>
    </body>
  </worldbody>
</mujoco>
"""
N = 3
DT = 0.008


def _trajectories(model, steps: int, seed: int) -> np.ndarray:
    """``(steps, N, nq)`` configurations of N environments moving with random velocities (unit quaternions)."""
    rng = np.random.default_rng(seed)
    q = np.tile(np.array(model.qpos0), (N, 1))
    out = np.empty((steps, N, model.nq))
    for t in range(steps):
        for i in range(N):
            mujoco.mj_integratePos(model, q[i], rng.normal(0.0, 3.0, model.nv), DT)
        out[t] = q
    return out


def _pair(xml: str, sensor):
    """Two lists of N measurements of the same sensor: the first batched, the second measured one by one."""
    model = mujoco.MjModel.from_xml_string(xml)
    return (
        model,
        [JointMeasurement(model, copy.deepcopy(sensor), DT) for _ in range(N)],
        [JointMeasurement(model, copy.deepcopy(sensor), DT) for _ in range(N)],
    )


@pytest.mark.parametrize("xml", [MANIFOLD, HINGES], ids=["free-ball-hinge-slide", "hinges"])
@pytest.mark.parametrize("sensor", ["encoder-12bit-noisy", "low-cost", "drifting", "outliers"])
def test_batch_equals_each_measurement_alone(xml, sensor):
    model, batched, alone = _pair(xml, sensors.make_sensor(sensor))
    steps = 2 * sensors.BLOCK + 90  # the random blocks are refilled twice
    Q = _trajectories(model, steps, seed=1)
    V = np.random.default_rng(2).standard_normal((steps, N, model.nv))
    rng_batched = [np.random.default_rng([7, i]) for i in range(N)]
    rng_alone = [np.random.default_rng([7, i]) for i in range(N)]
    for i in range(N):
        np.testing.assert_array_equal(batched[i].reset(Q[0, i], rng_batched[i]), alone[i].reset(Q[0, i], rng_alone[i]))
    batch = MeasurementBatch(batched)
    q, v, _, qm, z, zm = block_slices(model.nq, model.nv)
    events = np.random.default_rng(3)
    for t in range(1, steps):
        rows = events.random(N) < 0.8
        block = batch.measure(Q[t], V[t], rows)
        for i in range(N):
            if rows[i]:
                z_alone = alone[i].measure(Q[t, i])
                np.testing.assert_array_equal(block[i, zm], z_alone)
                np.testing.assert_array_equal(block[i, z], alone[i].z_true)
                np.testing.assert_array_equal(block[i, qm], alone[i].measured_qpos())
                np.testing.assert_array_equal(block[i, q], Q[t, i])
                np.testing.assert_array_equal(block[i, v], V[t, i])
                np.testing.assert_array_equal(batched[i].measured_qpos(), alone[i].measured_qpos())
                np.testing.assert_array_equal(batched[i].z_measured, z_alone)
            else:
                assert not block[i].any()
                event = events.random()
                if event < 0.3:  # measured one by one on the batch's rows (an episode's last sample)
                    np.testing.assert_array_equal(batched[i].measure(Q[t, i]), alone[i].measure(Q[t, i]))
                elif event < 0.6:  # a new episode, the stream continues
                    np.testing.assert_array_equal(
                        batched[i].reset(Q[t, i], rng_batched[i]), alone[i].reset(Q[t, i], rng_alone[i])
                    )
                elif event < 0.7:  # a new episode with a new seed: the sensor packs its stream into its row again
                    rng_batched[i], rng_alone[i] = np.random.default_rng([t, i]), np.random.default_rng([t, i])
                    np.testing.assert_array_equal(
                        batched[i].reset(Q[t, i], rng_batched[i]), alone[i].reset(Q[t, i], rng_alone[i])
                    )
                    assert batch.holds(i)
    for i in range(N):
        assert batch.holds(i)
        for shared, own in zip(batched[i].sensor.arrays, alone[i].sensor.arrays, strict=True):
            np.testing.assert_array_equal(shared, own)


def test_a_non_finite_configuration_is_rejected_before_any_stream_moves():
    model, batched, alone = _pair(HINGES, sensors.make_sensor("low-cost"))
    Q = _trajectories(model, 3, seed=4)
    V = np.zeros((N, model.nv))
    for i in range(N):
        batched[i].reset(Q[0, i], np.random.default_rng(i))
        alone[i].reset(Q[0, i], np.random.default_rng(i))
    batch = MeasurementBatch(batched)
    before = [a.copy() for a in batch.sensors]
    bad = Q[1].copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"finite joint configuration.*qpos\[1\] of environment 2"):
        batch.measure(bad, V, np.ones(N, dtype=bool))
    for a, b in zip(batch.sensors, before, strict=True):
        np.testing.assert_array_equal(a, b)
    block = batch.measure(Q[1], V, np.ones(N, dtype=bool))  # the streams continue as if nothing happened
    for i in range(N):
        np.testing.assert_array_equal(block[i, block_slices(model.nq, model.nv)[5]], alone[i].measure(Q[1, i]))


def test_a_non_finite_measurement_names_the_environment():
    # gross errors of 1e308 standard deviations overflow to inf in almost every sample
    model, batched, _ = _pair(HINGES, sensors.Outliers(probability=1.0, scale=1e308))
    Q = _trajectories(model, 2, seed=5)
    for i in range(N):
        batched[i].reset(Q[0, i], np.random.default_rng(i))
    batch = MeasurementBatch(batched)
    with pytest.raises(ValueError, match=r"finite measurement.*channel \d of environment \d.*Outliers"):
        for _ in range(20):
            batch.measure(Q[1], np.zeros((N, model.nv)), np.ones(N, dtype=bool))


def test_supports_one_chain_reset_measurements_only_and_does_not_pickle():
    model = mujoco.MjModel.from_xml_string(HINGES)
    q0 = np.array(model.qpos0)
    never_reset = [JointMeasurement(model, "encoder-12bit", DT) for _ in range(2)]
    assert MeasurementBatch.supports(never_reset)  # decided beforehand, made after the resets
    with pytest.raises(RuntimeError, match="never reset"):
        MeasurementBatch(never_reset)
    assert not MeasurementBatch.supports([])
    mixed = [JointMeasurement(model, "encoder-12bit", DT), JointMeasurement(model, "low-cost", DT)]
    for m in mixed:
        m.reset(q0, np.random.default_rng(0))
    assert not MeasurementBatch.supports(mixed)  # another chain
    with pytest.raises(ValueError, match="one chain"):
        MeasurementBatch(mixed)
    sizes = [JointMeasurement(model, "encoder-12bit", DT) for _ in range(2)]
    sizes[0].reset(q0, np.random.default_rng(0))
    sizes[1].sensor.reset(np.zeros(5), seed=0)  # a stream of another number of channels
    with pytest.raises(ValueError, match="one number of channels"):
        MeasurementBatch(sizes)
    other = mujoco.MjModel.from_xml_string(MANIFOLD)
    models = [JointMeasurement(model, "ideal", DT), JointMeasurement(other, "ideal", DT)]
    models[0].reset(q0, np.random.default_rng(0))
    models[1].reset(np.array(other.qpos0), np.random.default_rng(0))
    assert not MeasurementBatch.supports(models)
    same = [JointMeasurement(model, "encoder-12bit", DT) for _ in range(2)]
    for m in same:
        m.reset(q0, np.random.default_rng(0))
    batch = MeasurementBatch(same)
    with pytest.raises(TypeError, match="does not pickle"):
        pickle.dumps(batch)


# ---- the views the batch is made of ------------------------------------------------------------------------------
def _reset_sensor(seed=0, n=4):
    sensor = sensors.make_sensor("low-cost")
    sensor.reset(np.zeros(n), seed=seed)
    return sensor


def test_a_sensor_keeps_its_stream_in_given_arrays_across_resets():
    shared, own = _reset_sensor(), _reset_sensor()
    rows = sensors.SensorArrays(*(np.zeros((2, *a.shape), a.dtype) for a in shared.arrays))
    shared.use_arrays(sensors.SensorArrays(*(a[1] for a in rows)))
    assert all(np.shares_memory(a, b[1]) and a.shape == b[1].shape for a, b in zip(shared.arrays, rows, strict=True))
    Y = np.random.default_rng(0).standard_normal((300, 4))
    np.testing.assert_array_equal(shared.run(Y), own.run(Y))
    np.testing.assert_array_equal(shared.reset(Y[0], seed=9), own.reset(Y[0], seed=9))  # a new stream, packed
    assert all(np.shares_memory(a, b[1]) for a, b in zip(shared.arrays, rows, strict=True))
    np.testing.assert_array_equal(shared.run(Y), own.run(Y))
    for a, b in zip(shared.arrays, own.arrays, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not rows.state[0].any()  # the other row is untouched
    twin = pickle.loads(pickle.dumps(shared))  # a copy has arrays of its own
    assert not any(np.shares_memory(a, b) for a, b in zip(twin.arrays, rows, strict=True))
    kept = [a.copy() for a in rows]
    from_twin = twin.run(Y)
    for a, b in zip(rows, kept, strict=True):  # the twin's run left the given arrays alone
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(from_twin, shared.run(Y))


def test_a_reset_to_another_size_leaves_the_given_arrays():
    sensor = _reset_sensor()
    given = sensors.SensorArrays(*(np.zeros_like(a) for a in sensor.arrays))
    sensor.use_arrays(given)
    sensor.reset(np.zeros(5), seed=1)
    assert sensor.arrays.state.shape == (len(sensor.stages), 5)
    assert sensor.arrays.state is not given.state


def test_use_arrays_rejects_what_does_not_fit():
    with pytest.raises(RuntimeError, match="never reset"):
        sensors.make_sensor("low-cost").use_arrays(None)
    sensor = _reset_sensor()
    arrays = sensor.arrays
    with pytest.raises(ValueError, match=r"state with shape"):
        sensor.use_arrays(arrays._replace(state=np.zeros((1, 1))))
    with pytest.raises(TypeError, match=r"ring_pos as a writeable, aligned, C-contiguous int64"):
        sensor.use_arrays(arrays._replace(ring_pos=np.zeros(arrays.ring_pos.shape)))
    with pytest.raises(TypeError, match=r"params as a writeable"):
        sensor.use_arrays(arrays._replace(params=np.zeros(arrays.params.shape[::-1]).T))
    for bad in ((1, 2, 3), None, tuple(arrays)[:-1]):
        with pytest.raises(TypeError, match=r"expected SensorArrays \(a tuple of the 6 arrays"):
            sensor.use_arrays(bad)


def test_tangent_coordinates_in_given_arrays():
    model = mujoco.MjModel.from_xml_string(MANIFOLD)
    Q = _trajectories(model, 20, seed=6)[:, 0]
    shared, own = TangentCoordinates(model), TangentCoordinates(model)
    previous, z = np.zeros((2, model.nq)), np.zeros((2, model.nv))
    shared.reset(Q[0])
    own.reset(Q[0])
    shared.use_arrays(previous[1], z[1])
    for q in Q[1:]:
        np.testing.assert_array_equal(shared(q), own(q))
    np.testing.assert_array_equal(z[1], own.z)
    np.testing.assert_array_equal(previous[1], own.previous)
    with pytest.raises(ValueError, match="shape"):
        shared.use_arrays(np.zeros(3), z[0])
    with pytest.raises(ValueError, match="free or ball joints"):
        TangentCoordinates(mujoco.MjModel.from_xml_string(HINGES)).use_arrays(np.zeros(2), np.zeros(2))


def test_measure_live_gathers_the_live_states_and_follows_a_replaced_mjdata():
    model, batched, alone = _pair(MANIFOLD, sensors.make_sensor("encoder-12bit-noisy"))
    datas = [mujoco.MjData(model) for _ in range(N)]
    Q = _trajectories(model, 4, seed=8)
    for i in range(N):
        batched[i].reset(Q[0, i], np.random.default_rng(i))
        alone[i].reset(Q[0, i], np.random.default_rng(i))
    batch = MeasurementBatch(batched)
    every = np.ones(N, dtype=bool)
    for t in (1, 2, 3):
        if t == 3:  # an environment replaces its MjData: the gather reads the new one
            datas[1] = mujoco.MjData(model)
        for i, data in enumerate(datas):
            data.qpos[:] = Q[t, i]
            data.qvel[:] = t + i
        block = batch.measure_live(datas, every)
        for i in range(N):
            np.testing.assert_array_equal(block[i, : model.nq], Q[t, i])
            np.testing.assert_array_equal(block[i, model.nq : model.nq + model.nv], t + i)
            np.testing.assert_array_equal(block[i, -model.nv :], alone[i].measure(Q[t, i]))
    with pytest.raises(ValueError, match="boolean mask"):
        batch.measure(Q[1], np.zeros((N, model.nv)), np.arange(N))


def test_translations_are_measured_in_metres_and_rotations_in_radians():
    """Which dofs are lengths follows the joint types (free: three translations then three rotations; ball:
    three rotations; hinge: one; slide: one translation), so a quantizer with a linear resolution puts the
    translations on its metre grid and the rotations on its angle grid."""
    model = mujoco.MjModel.from_xml_string(MANIFOLD)
    expected = np.array([False] * 3 + [True] * 3 + [True] * 3 + [True] + [False])  # free, ball, hinge, slide
    measurement = JointMeasurement(model, sensors.Quantization(2 * np.pi / 4096, linear_resolution=1e-5), DT)
    np.testing.assert_array_equal(measurement.angular, expected)
    np.testing.assert_array_equal(measurement.quantization_step(), np.where(expected, 2 * np.pi / 4096, 1e-5))
    q = _trajectories(model, 5, 0)[:, 0]
    measurement.reset(q[0], np.random.default_rng(0))
    z = measurement.measure_block(q[1:])
    translations = z[:, ~expected] / 1e-5
    np.testing.assert_allclose(translations, np.round(translations), rtol=0, atol=1e-6)


@pytest.mark.parametrize("xml", [MANIFOLD, HINGES], ids=["free-ball-hinge-slide", "hinges"])
def test_a_block_of_live_data_is_copied(xml):
    """``measure_block`` takes views of the live simulation (``data.qpos[None]``): what it keeps must not move
    when the simulation steps on."""
    model = mujoco.MjModel.from_xml_string(xml)
    q = _trajectories(model, 3, 0)[:, 0]
    measurement = JointMeasurement(model, sensors.Chain(), DT)
    measurement.reset(q[0], np.random.default_rng(0))
    live = q[1].copy()
    measurement.measure_block(live[None])
    z_true, qpos = measurement.z_true.copy(), measurement.measured_qpos().copy()
    live[:] = q[2]  # the next physics step writes into the same array
    np.testing.assert_array_equal(measurement.z_true, z_true)
    np.testing.assert_array_equal(measurement.measured_qpos(), qpos)
    # the measured configuration is mapped back from the tangent coordinates only when read: after the live data
    # moved on, it is still that of the sample (a twin measuring a copy says what)
    twin = JointMeasurement(model, sensors.Chain(), DT)
    twin.reset(q[0], np.random.default_rng(0))
    twin.measure_block(q[1][None].copy())
    measurement.reset(q[0], np.random.default_rng(0))
    live[:] = q[1]
    measurement.measure_block(live[None])
    live[:] = q[2]
    np.testing.assert_array_equal(measurement.measured_qpos(), twin.measured_qpos())


def test_tangent_coordinates_start_at_the_configuration_and_follow_the_translations():
    """``z0`` holds the hinge and slide values and the free joint's translation of ``q0``, and zero for the
    rotations (free and ball); a free joint's translation coordinates stay its position (Euclidean: the tangent
    difference is the plain one), to rounding."""
    model = mujoco.MjModel.from_xml_string(MANIFOLD)  # qpos: free (7), ball (4), hinge, slide; nv: 3 + 3 + 3 + 1 + 1
    q = _trajectories(model, 50, 0)[:, 0]
    tangent = TangentCoordinates(model)
    z0 = tangent.reset(q[0])
    np.testing.assert_array_equal(z0, np.concatenate([q[0, :3], np.zeros(6), q[0, 11:13]]))
    for k in range(1, len(q)):
        z = tangent(q[k])
        np.testing.assert_allclose(z[:3], q[k, :3], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(z[9:], q[k, 11:13])
