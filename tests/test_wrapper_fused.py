"""The wrapper's one-compiled-call hot path (FusedSensing) computes exactly what the general path computes."""

from __future__ import annotations

import copy
import pickle

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from conftest import UnregisteredFiniteDifference, full_forward_observation
from gymnasium.envs.mujoco.hopper_v5 import HopperEnv
from gymnasium.envs.mujoco.inverted_pendulum_v5 import InvertedPendulumEnv

from smo_gym.engine import FusedSensing
from smo_gym.engine.scratch import INPUT_FIELDS, OBSERVED_FIELDS, copy_observed_fields
from smo_gym.observers import DivergenceError
from smo_gym.specs import parse_observer_spec
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers.adapters import make_adapter
from smo_gym.wrappers.sensing import SensingInfo

KEYS = ("qpos", "qvel", "qvel_estimate", "qpos_measured", "observation")


def _pair(env_id: str, seed: int, **kwargs):
    """Two identical wrappers reset with ``seed``; the second is then forced onto the general path (the test
    never resets it again: a reset would choose the fused path anew)."""
    fused = EstimatedVelocity(gym.make(env_id), disk_cache=False, **kwargs)
    general = EstimatedVelocity(gym.make(env_id), disk_cache=False, **kwargs)
    first = fused.reset(seed=seed)[0], general.reset(seed=seed)[0]
    general._fused = None
    return fused, general, first


@pytest.mark.parametrize(
    "env_id, observer, rate, sensor, positions",
    [
        ("HalfCheetah-v5", "super-twisting", "physics", "low-cost", "measured"),
        ("HalfCheetah-v5", "super-twisting", "env", "encoder-12bit-noisy", "filtered"),
        # observers of order 2 that report at the sample time: on an RK4 model, and on HalfCheetah's and Hopper's
        # Euler, where the compiled call reports the step-mean velocity (the observation reads it: Hopper's clip,
        # which the chattering of Levant's explicit step exercises)
        ("Walker2d-v5", "levant", "physics", "encoder-12bit-noisy", "measured"),
        ("HalfCheetah-v5", "kalman-ca", "physics", "ideal", "measured"),
        ("Hopper-v5", "levant:discretization=taylor", "env", "encoder-12bit-noisy", "filtered"),
        ("HalfCheetah-v5", "high-gain", 5, "drifting", "measured"),
        ("Walker2d-v5", "kalman-ca", "physics", "outliers", "filtered"),
        ("Walker2d-v5", "kalman-imm:huber=3", "physics", "outliers", "measured"),
        ("HalfCheetah-v5", "finite-difference", "env", "ideal", "measured"),
        ("HalfCheetah-v5", "worst-case-optimal", "physics", "encoder-12bit-noisy", "measured"),
        # the observation built by the compiled call, with Hopper's clip of the velocities at +-10 (active with
        # finite differences of the outlier sensor)
        ("Hopper-v5", "finite-difference", "physics", "outliers", "measured"),
        # free joints (quaternions): tangent coordinates and the measured/filtered configuration on the manifold
        ("Ant-v5", "super-twisting", "physics", "encoder-12bit-noisy", "filtered"),
        ("Humanoid-v5", "super-twisting", "env", "low-cost", "measured"),
        # the default where it mixes: the alpha-beta tracker and the Kalman filter on different joints, one
        # composite step (PerChannel)
        ("Walker2d-v5", "auto", "physics", "encoder-12bit-noisy", "measured"),
    ],
)
def test_fused_path_equals_general_path(env_id, observer, rate, sensor, positions):
    # HalfCheetah: frame_skip 5, so at rate="physics" control periods straddle the sensor's 256-sample random
    # blocks (the fused path hands those to the general path) and the stream must stay the same throughout
    observer, options = parse_observer_spec(observer)
    fused, general, (obs_f, obs_g) = _pair(
        env_id, 3, observer=observer, observer_kwargs=options or None, rate=rate, sensor=sensor, positions=positions
    )
    assert isinstance(fused._fused, FusedSensing)
    assert observer != "auto" or len(set(fused.observer.names)) > 1  # a PerChannel of several families
    np.testing.assert_array_equal(obs_f, obs_g)
    rng = np.random.default_rng(0)
    clipped = False
    for _ in range(120):
        action = rng.uniform(-1, 1, fused.action_space.shape)
        of, rf, tf, uf, inf_f = fused.step(action)
        og, rg, tg, ug, inf_g = general.step(action)
        np.testing.assert_array_equal(of, og)
        assert (rf, tf, uf) == (rg, tg, ug)
        for key in KEYS:
            np.testing.assert_array_equal(inf_f["smo"][key], inf_g["smo"][key])
        if tf or uf:  # the general twin is never reset (see _pair)
            break
        if env_id == "Hopper-v5":
            clipped |= bool(np.any(np.abs(inf_f["smo"]["qvel_estimate"]) > 10))
    assert fused._fused.maps_observation == (env_id in ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5"))
    assert clipped or env_id != "Hopper-v5" or observer == "auto"  # the clip was exercised (auto stays within it)
    np.testing.assert_array_equal(fused.observer.estimate, general.observer.estimate)
    np.testing.assert_array_equal(fused.observer.state, general.observer.state)
    assert fused.observer.n_updates == general.observer.n_updates
    np.testing.assert_array_equal(fused.measurement.z_measured, general.measurement.z_measured)
    np.testing.assert_array_equal(fused.measurement.z_true, general.measurement.z_true)
    np.testing.assert_array_equal(fused.measurement.measured_qpos(), general.measurement.measured_qpos())


@pytest.mark.parametrize("env_id, rate", [("Humanoid-v5", "env"), ("InvertedDoublePendulum-v5", "physics")])
def test_fused_input_copies_give_the_full_forward_observation(env_id, rate):
    """The compiled call copies the inputs the observation reads (Humanoid: ctrl; InvertedDoublePendulum, with its
    full forward pass: all of them) into the scratch data: every step's observation equals a full forward pass
    at the sensed state with the live inputs."""
    env = EstimatedVelocity(gym.make(env_id), observer="super-twisting", rate=rate, disk_cache=False)
    env.reset(seed=1)
    assert env._fused.copies_inputs
    rng = np.random.default_rng(1)
    for _ in range(20):
        obs, *_, terminated, truncated, info = env.step(rng.uniform(env.action_space.low, env.action_space.high))
        smo = info["smo"]
        want = full_forward_observation(env, smo["qpos_measured"], smo["qvel_estimate"])
        np.testing.assert_array_equal(obs, want)
        if terminated or truncated:
            env.reset()


def test_fused_path_is_taken_only_where_it_is_exact():
    hopper = EstimatedVelocity(gym.make("Hopper-v5"), observer="super-twisting", disk_cache=False)
    hopper.reset(seed=0)
    assert hopper._fused is not None
    # free joints go through it too
    humanoid = EstimatedVelocity(gym.make("Humanoid-v5"), observer="super-twisting", disk_cache=False)
    humanoid.reset(seed=0)
    assert humanoid._fused is not None
    # the implicit-Lyapunov-function differentiator's step is compiled too (its implicit equation solved in it)
    ilf = EstimatedVelocity(gym.make("InvertedPendulum-v5"), observer="ilf-finite", disk_cache=False)
    ilf.reset(seed=0)
    assert ilf._fused is not None
    # and the worst-case-optimal differentiator (a window of past samples in its state)
    wco = EstimatedVelocity(gym.make("InvertedPendulum-v5"), observer="worst-case-optimal", disk_cache=False)
    wco.reset(seed=0)
    assert wco._fused is not None
    # a subclass of a family is a family of its own, whose Python may differ from the compiled step: not fused
    subclass = EstimatedVelocity(
        gym.make("InvertedPendulum-v5"), observer=UnregisteredFiniteDifference(dt=0.02), disk_cache=False
    )
    subclass.reset(seed=0)
    assert subclass._fused is None


def test_fused_errors_name_the_channel_and_keep_the_state():
    env = EstimatedVelocity(gym.make("Hopper-v5"), sensor="ideal", rate="env", disk_cache=False)
    env.reset(seed=0)
    env.step(np.zeros(3))
    fused = env._fused
    state = env.observer.state
    t = env.sensor._t
    Q = np.array(env.unwrapped.data.qpos)[None]
    Q[0, 2] = np.nan
    with pytest.raises(ValueError, match="channel 2"):
        fused.sample(Q, np.zeros(env.unwrapped.model.nv))
    np.testing.assert_array_equal(env.observer.state, state)
    assert env.sensor._t == t + 1  # the sample was consumed, as Sensor.run does
    # a diverging observer: a finite jump whose difference quotient overflows (1.7e308 / dt)
    env = EstimatedVelocity(
        gym.make("Hopper-v5"), sensor="ideal", rate="env", observer="finite-difference", disk_cache=False
    )
    env.reset(seed=0)
    state = env.observer.state
    Q = np.array(env.unwrapped.data.qpos)[None]
    Q[0, 1] = 1.7e308
    with pytest.raises(DivergenceError, match="channel 1"):
        env._fused.sample(Q, np.zeros(env.unwrapped.model.nv))
    np.testing.assert_array_equal(env.observer.state, state)


def test_fused_wrapper_copies_and_pickles_mid_episode():
    env = EstimatedVelocity(gym.make("HalfCheetah-v5"), observer="super-twisting", disk_cache=False)
    env.reset(seed=1)
    actions = np.random.default_rng(1).uniform(-1, 1, (20, 6))
    for a in actions[:5]:
        env.step(a)  # bound to this wrapper's scratch data and arrays
    # MuJoCo environments copy and pickle by their constructor arguments (a fresh simulation): reset both alike
    for twin in (copy.deepcopy(env), pickle.loads(pickle.dumps(env))):
        o1, _ = env.reset(seed=7)
        o2, _ = twin.reset(seed=7)
        np.testing.assert_array_equal(o1, o2)
        for a in actions:
            o1 = env.step(a)[0]
            o2 = twin.step(a)[0]
            np.testing.assert_array_equal(o1, o2)
        # the copy's hot path writes into the copy's scratch data, not the original's
        assert twin.adapter.evaluation.scratch_state()[0] is twin._fused._static[9]
        assert not np.shares_memory(
            twin.adapter.evaluation.scratch_state()[0], env.adapter.evaluation.scratch_state()[0]
        )


def test_sensing_info_is_read_only_and_copies_as_itself():
    env = EstimatedVelocity(gym.make("Hopper-v5"), disk_cache=False)
    env.reset(seed=0)
    info = env.step(np.zeros(3))[4]["smo"]
    assert isinstance(info, SensingInfo) and isinstance(info, dict)
    assert set(info) == set(KEYS)
    assert copy.deepcopy(info) is info and copy.copy(info) is info  # safe: nothing in it can change
    with pytest.raises(TypeError, match="read-only"):
        info["qvel"] = np.zeros(6)
    with pytest.raises(ValueError):
        info["qvel"][0] = 1.0
    kept = {k: v.copy() for k, v in info.items()}
    env.step(np.ones(3))  # a new step never changes what an earlier step returned
    for key in info:
        np.testing.assert_array_equal(info[key], kept[key])
    mutable = dict(info)
    mutable["extra"] = 1
    back = pickle.loads(pickle.dumps(info))
    assert type(back) is SensingInfo and all(np.array_equal(back[k], info[k]) for k in info)
    assert not back["qvel"].flags.writeable


def test_adapter_probes_what_the_observation_reads():
    hopper = EstimatedVelocity(gym.make("Hopper-v5"), disk_cache=False).adapter.evaluation
    assert not hopper.reads_contacts and hopper.fresh_observation and hopper._bare
    ant = EstimatedVelocity(gym.make("Ant-v5"), disk_cache=False).adapter.evaluation
    assert ant.reads_contacts  # Ant-v5's observation includes cfrc_ext
    no_contacts = EstimatedVelocity(
        gym.make("Ant-v5", include_cfrc_ext_in_observation=False), disk_cache=False
    ).adapter.evaluation
    assert not no_contacts.reads_contacts
    # the cheapest stages that reproduce the forward pass: none for a state observation, the kinematics for
    # Humanoid's com inertias and velocities (and actuator forces, which read ctrl), all of it for
    # InvertedDoublePendulum's constraint force (which copies every input)
    for env_id, pipeline, inputs in [
        ("Hopper-v5", "none", ()),
        ("Humanoid-v5", "kinematics", ("ctrl",)),
        ("InvertedDoublePendulum-v5", "forward", INPUT_FIELDS),
    ]:
        evaluation = make_adapter(gym.make(env_id).unwrapped).evaluation
        assert evaluation.pipeline == pipeline, env_id
        assert (evaluation.input_fields if evaluation.copies_inputs else ()) == inputs, env_id


def test_an_observation_that_is_a_view_of_the_data_is_copied():
    """An observation that returns a view of what it reads (here the body positions, after the kinematics) is not
    fresh: each sensed observation is a copy, which the next step leaves as it was (the probe once evaluated it
    without the kinematics, saw the view unchanged and returned the same view at every step)."""

    class BodyPositions(HopperEnv):
        def _get_obs(self):
            return self.data.xpos[1:]

    env = EstimatedVelocity(BodyPositions(), sensor="ideal", disk_cache=False)
    assert env.adapter.evaluation.pipeline == "kinematics" and not env.adapter.evaluation.fresh_observation
    env.reset(seed=0)
    first = env.step(np.ones(3))[0]
    kept = first.copy()
    second = env.step(-np.ones(3))[0]
    np.testing.assert_array_equal(first, kept)
    assert not np.shares_memory(first, second) and not np.array_equal(first, second)
    qpos, qvel = env.measurement.measured_qpos(), env.observer.velocity
    np.testing.assert_array_equal(second, full_forward_observation(env, qpos, qvel))


def test_an_observation_that_reads_the_live_simulation_is_refused():
    """An observation function that keeps views of ``data.qpos`` and ``data.qvel`` from ``__init__`` reads the live
    simulation, not the data the wrapper evaluates it on: the sensed observation was the true state, silently. It
    is refused with a message that says why; the probe leaves the live data as it found it, bit for bit."""

    class KeptViews(HopperEnv):
        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self._qpos, self._qvel = self.data.qpos, self.data.qvel

        def _get_obs(self):
            return np.concatenate([self._qpos[1:], np.clip(self._qvel, -10, 10)])

    with pytest.raises(ValueError, match="reads the state from the data it is given") as excinfo:
        EstimatedVelocity(KeptViews(), disk_cache=False)
    assert "KeptViews" in str(excinfo.value) and "actual value" in str(excinfo.value)

    class NoisyKeptViews(KeptViews):  # an observation with noise of its own is judged by what NaN reaches
        def _get_obs(self):
            return super()._get_obs() + 1e-3 * self.np_random.standard_normal(11)

    with pytest.raises(ValueError, match="reads the state from the data it is given"):
        EstimatedVelocity(NoisyKeptViews(), disk_cache=False)

    class Noisy(HopperEnv):  # reads the data it is given, with noise of its own: accepted, and noisy
        def _get_obs(self):
            return super()._get_obs() + 1e-3 * self.np_random.standard_normal(11)

    noisy = EstimatedVelocity(Noisy(), sensor="ideal", disk_cache=False)
    noisy.reset(seed=0)
    first = noisy.step(np.zeros(3))[0]
    qpos, qvel = noisy.measurement.measured_qpos(), noisy.observer.velocity
    assert 0 < np.max(np.abs(first - np.concatenate([qpos[1:], np.clip(qvel, -10, 10)]))) < 0.01
    env = gym.make("Humanoid-v5").unwrapped
    env.reset(seed=0)
    env.step(env.action_space.sample())
    fields = [name for name in dir(env.data) if not name.startswith("_")]
    before = {
        name: np.array(getattr(env.data, name)) for name in fields if isinstance(getattr(env.data, name), np.ndarray)
    }
    make_adapter(env)
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(env.data, name), value, err_msg=name)


def test_an_observation_of_the_time_reads_the_live_clock():
    """``data.time`` is an input a controller knows: an observation that reads it gets the simulation's time at
    every step, and the snapshot of the live data that a vector environment's terminal observation is built from
    after the reset (:func:`copy_observed_fields`) keeps the time at which the episode ended."""

    class Clock(HopperEnv):
        def _get_obs(self):
            return np.concatenate([self.data.qpos[1:], self.data.qvel, [self.data.time]])

    env = EstimatedVelocity(Clock(), disk_cache=False)
    assert env.adapter.evaluation.input_fields == ("time",)
    assert env.reset(seed=0)[0][-1] == 0.0
    for _ in range(3):
        assert env.step(np.ones(3))[0][-1] == env.unwrapped.data.time > 0.0
    live = env.unwrapped.data
    live.time = 1.25
    snapshot = copy_observed_fields(live, mujoco.MjData(env.unwrapped.model))
    assert snapshot.time == 1.25
    for name in OBSERVED_FIELDS:
        np.testing.assert_array_equal(getattr(snapshot, name), getattr(live, name))


def test_observation_entries_are_gathered_clipped_and_checked():
    """Humanoid's and Ant's observations are clipped selections of MjData entries after the forward-pass stages:
    gathered by one compiled call, equal to _get_obs at run-time states (here with Ant's contact forces beyond
    its clip at +-1), and a non-finite entry raises the wrapper's error. Reacher's is not (its last entries
    are differences of two body positions)."""
    humanoid = make_adapter(gym.make("Humanoid-v5").unwrapped).evaluation
    assert set(humanoid.observation_entries[0]) == {"qpos", "qvel", "cinert", "cvel", "qfrc_actuator", "cfrc_ext"}
    assert make_adapter(gym.make("Reacher-v5").unwrapped).evaluation.observation_entries is None
    env = EstimatedVelocity(gym.make("Ant-v5"), disk_cache=False)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        env.step(rng.uniform(-1, 1, 8))
    adapter = env.adapter
    assert adapter.checks_observation
    qpos, qvel = env.measurement.measured_qpos(), env.observer.velocity
    live = adapter.data
    live.cfrc_ext[1:] = 5.0 * rng.standard_normal(live.cfrc_ext[1:].shape)  # "sensed" forces beyond the clip
    obs = adapter.observation(qpos, qvel)
    np.testing.assert_array_equal(obs, full_forward_observation(env, qpos, qvel))
    assert np.sum(np.abs(obs) == 1.0) > 10
    live.cfrc_ext[2, 1] = np.nan
    with pytest.raises(ValueError, match="expected a finite sensed observation"):
        adapter.observation(qpos, qvel)


def test_observation_map_is_found_only_for_clipped_selections():
    """Hopper's observation (qpos[1:], clip(qvel, -10, 10)) is a clipped selection; a transformed or mixed
    observation is not, and keeps the environment's own _get_obs."""
    index, bounds = make_adapter(gym.make("Hopper-v5").unwrapped).evaluation.observation_map
    np.testing.assert_array_equal(index, np.arange(1, 12))
    np.testing.assert_array_equal(bounds[:, :5], [[-np.inf] * 5, [np.inf] * 5])
    np.testing.assert_array_equal(bounds[:, 5:], [[-10.0] * 6, [10.0] * 6])
    index, _ = make_adapter(
        gym.make("Hopper-v5", exclude_current_positions_from_observation=False).unwrapped
    ).evaluation.observation_map
    np.testing.assert_array_equal(index, np.arange(12))

    class Transformed(HopperEnv):
        def __init__(self, transform, **kwargs):
            super().__init__(**kwargs)
            self.transform = transform

        def _get_obs(self):
            return self.transform(self.data.qpos.copy(), self.data.qvel.copy())

    for transform in (
        lambda q, v: np.concatenate([np.sin(q), v]),  # not the entry itself
        lambda q, v: np.concatenate([q, 2.0 * v]),  # not unit slope
        lambda q, v: np.concatenate([q, v[:3] + v[3:]]),  # follows two entries
        lambda q, v: np.concatenate([q, v, [1.0]]),  # a constant entry
        lambda q, v: np.concatenate([q, np.clip(v, -10, 10) * (np.abs(v) < 1e5)]),  # only for small
        lambda q, v: np.concatenate([q, v]).astype(np.float32),
    ):
        adapter = make_adapter(Transformed(transform)).evaluation
        assert adapter._bare and adapter.observation_map is None
    env = EstimatedVelocity(Transformed(lambda q, v: np.concatenate([q, 2.0 * v])), disk_cache=False)
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(obs[6:], 2.0 * info["smo"]["qvel_estimate"])


@pytest.mark.parametrize("env_id", ["Humanoid-v5", "Ant-v5"])
def test_compiled_tangent_arithmetic_is_mujocos(env_id):
    """differentiate_pos / integrate_pos equal mj_differentiatePos / mj_integratePos (free and hinge joints),
    for large rotations (beyond pi: the wrap of the angle) and tiny ones (the zero-norm branch), from unit
    quaternions and from quaternions of other norms (which MuJoCo normalizes first; a zero one is the identity)."""
    import mujoco

    from smo_gym.engine.tangent import differentiate_pos, integrate_pos, joint_table

    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    model = env.model
    joints = joint_table(model)
    rng = np.random.default_rng(0)
    for k in range(100):
        q1 = np.array(env.data.qpos)
        mujoco.mj_integratePos(model, q1, rng.standard_normal(model.nv) * (3.0 if k % 2 else 0.01), 1.0)
        v = rng.standard_normal(model.nv) * (3.0 if k % 3 else 1e-12)
        if k % 4 == 1:  # quaternions of norm 0.5 .. 2, or 0
            quat = joints[joints[:, 0] == mujoco.mjtJoint.mjJNT_FREE, 1][0] + 3 + np.arange(4)
            q1[quat] *= 0.0 if k == 5 else rng.uniform(0.5, 2.0)
        q2, mine = q1.copy(), q1.copy()
        mujoco.mj_integratePos(model, q2, v, 1.0)
        integrate_pos(joints, mine, v)
        np.testing.assert_allclose(mine, q2, rtol=0, atol=1e-14)
        d, d_mine = np.zeros(model.nv), np.zeros(model.nv)
        mujoco.mj_differentiatePos(model, d, 1.0, q1, q2)
        differentiate_pos(joints, q1, q2, d_mine)
        np.testing.assert_allclose(d_mine, d, rtol=0, atol=1e-14)


def test_fused_path_on_dm_control_equals_general_path():
    """dm_control through shimmy (Dict observations, Physics.step sampled by the callback hook) takes the fused
    path too, with the same observations as the general path."""
    pytest.importorskip("shimmy")
    from smo_gym.wrappers.dm_control import make_dm_control

    fused = make_dm_control("cartpole", "swingup", observer="super-twisting", rate="physics", disk_cache=False)
    general = make_dm_control("cartpole", "swingup", observer="super-twisting", rate="physics", disk_cache=False)
    fused.reset(seed=1)
    general.reset(seed=1)
    general._fused = None
    assert fused._fused is not None
    rng = np.random.default_rng(0)
    for _ in range(60):
        action = rng.uniform(-1, 1, fused.action_space.shape)
        of, og = fused.step(action)[0], general.step(action)[0]
        assert of.keys() == og.keys()
        for key in of:
            np.testing.assert_array_equal(of[key], og[key])


def test_info_dicts_are_never_reused_across_steps():
    """Every step's info['smo'] is a new dict whose arrays no other step shares, read-only, unchanged by later
    steps, and the last one agrees with the observer and the measurement."""
    env = EstimatedVelocity(gym.make("HalfCheetah-v5"), disk_cache=False)
    env.reset(seed=0)
    actions = np.random.default_rng(2).uniform(-1, 1, (150, 6))
    kept, copies = [], []
    for a in actions:
        smo = env.step(a)[4]["smo"]
        kept.append(smo)
        copies.append({k: np.array(v) for k, v in smo.items()})
    assert len({id(s) for s in kept}) == len(kept)
    for smo, copied in zip(kept, copies, strict=True):
        for key in KEYS:
            assert not smo[key].flags.writeable
            np.testing.assert_array_equal(smo[key], copied[key])
    np.testing.assert_array_equal(kept[-1]["qvel_estimate"], env.estimator.velocity)
    np.testing.assert_array_equal(kept[-1]["qpos_measured"], env.measurement.measured_qpos())


def test_reset_observation_is_the_full_forward_pass_at_the_measurement():
    """The first observation of every episode is the environment's observation at the measured positions and
    zero velocity (full forward pass), and ``info["smo"]["observation"]`` the environment's own at the true
    state."""
    env = EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), disk_cache=False)
    bare = gym.make("InvertedDoublePendulum-v5")
    for seed in (0, 1, 2):
        obs, info = env.reset(seed=seed)
        qpos = env.measurement.measured_qpos()
        np.testing.assert_array_equal(obs, full_forward_observation(env, qpos, np.zeros(env.unwrapped.model.nv)))
        np.testing.assert_array_equal(info["smo"]["observation"], bare.reset(seed=seed)[0])
    assert "_get_obs" not in vars(env.unwrapped)


def test_sines_and_cosines_are_gathered_only_where_they_equal_numpys(monkeypatch):
    """InvertedDoublePendulum's observation (qpos[0], sin and cos of the hinge angles, clipped velocities and
    constraint force) is gathered with compiled sin/cos, equal to _get_obs at run-time states; on a platform where
    NumPy's sin/cos differ from the C library's (simulated), the adapter keeps _get_obs for it (and still gathers
    observations without them)."""
    from smo_gym.engine import scratch
    from smo_gym.engine.fused import ENTRY_COS, ENTRY_SIN, entry_functions_match_numpy

    assert entry_functions_match_numpy()
    env = EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), disk_cache=False)
    names, _, _, functions = env.adapter.evaluation.observation_entries
    assert list(functions).count(ENTRY_SIN) == 2 and list(functions).count(ENTRY_COS) == 2
    assert "qfrc_constraint" in names
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        env.step(rng.uniform(-1, 1, 1))
        qpos, qvel = env.measurement.measured_qpos(), env.observer.velocity
        np.testing.assert_array_equal(env.adapter.observation(qpos, qvel), full_forward_observation(env, qpos, qvel))
    monkeypatch.setattr(scratch, "entry_functions_match_numpy", lambda: False)
    assert make_adapter(gym.make("InvertedDoublePendulum-v5").unwrapped).evaluation.observation_entries is None
    assert make_adapter(gym.make("Ant-v5").unwrapped).evaluation.observation_entries is not None


USERDATA_PENDULUM = """<mujoco><size nuserdata="1"/><worldbody><body pos="0 0 1">
<joint name="j" type="hinge" axis="0 1 0"/><geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.05"/></body>
</worldbody><actuator><motor joint="j" ctrlrange="-1 1"/></actuator></mujoco>"""


def test_an_observation_of_userdata_reads_what_the_environment_wrote(tmp_path):
    """``data.userdata`` is where an environment keeps what a controller knows (a goal written at reset and at
    every step): an observation that reads it gets the live value, as it gets ``ctrl`` (it stayed 0 before)."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    path = tmp_path / "pendulum.xml"
    path.write_text(USERDATA_PENDULUM)

    class Goal(MujocoEnv):
        metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 250}

        def __init__(self):
            space = Box(-np.inf, np.inf, shape=(3,), dtype=np.float64)
            super().__init__(str(path), 2, observation_space=space)

        def _get_obs(self):
            return np.concatenate([self.data.qpos, self.data.qvel, self.data.userdata])

        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            self.data.userdata[0] = 0.7
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self):
            self.set_state(self.init_qpos + 0.1, self.init_qvel)
            self.data.userdata[0] = 0.7
            return self._get_obs()

    env = EstimatedVelocity(Goal(), disk_cache=False)
    assert "userdata" in env.adapter.evaluation.input_fields
    assert env.reset(seed=0)[0][-1] == 0.7
    assert env.step(np.zeros(1))[0][-1] == 0.7


TWO_LINKS = """<mujoco><option timestep="0.01"/><worldbody><body pos="0 0 1">
<joint name="j1" type="hinge" axis="0 1 0" damping="0.1"/><geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.05"/>
<body pos="0 0 -0.5"><joint name="j2" type="hinge" axis="0 1 0" damping="0.1"/>
<geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.05"/><site name="tip" pos="0 0 -0.5"/></body></body>
</worldbody><actuator><motor joint="j1" gear="5" ctrlrange="-1 1"/><motor joint="j2" gear="5" ctrlrange="-1 1"/>
</actuator></mujoco>"""


def _goal_env(path, kind: str, ends_after: int = 10_000):
    """A two-link arm whose observation reads attributes the environment draws at every reset but the first: a goal
    (zero before) in the joint error ``qpos - goal`` (``kind="joints"``, with clipped velocities: a clipped
    selection of the state until then) or in the tip-to-goal vector (``"tip"``, a selection of ``site_xpos``
    entries until then), or the velocities' clip bound (``"clip"``, 10 before, then below the arm's speed; the
    velocity is zero at every reset: the bound shows only at larger ones)."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    class Reach(MujocoEnv):
        metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 20}

        def __init__(self):
            self.goal, self.limit, self.resets, self.steps = np.zeros(2), 10.0, 0, 0
            space = Box(-np.inf, np.inf, shape=(4 if kind == "tip" else 5,), dtype=np.float64)
            super().__init__(str(path), 5, observation_space=space)

        def _get_obs(self):
            d = self.data
            if kind == "tip":
                return np.concatenate([d.qvel, d.site_xpos[0, ::2] - self.goal])
            return np.concatenate([d.qpos - self.goal, np.clip(d.qvel, -self.limit, self.limit), [d.qpos[0]]])

        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            self.steps += 1
            return self._get_obs(), 0.0, self.steps % ends_after == 0, False, {}

        def reset_model(self):
            self.set_state(self.init_qpos + self.np_random.uniform(-0.1, 0.1, 2), self.init_qvel)
            if self.resets and kind == "clip":
                self.limit = self.np_random.uniform(0.01, 0.02)
            elif self.resets:
                self.goal = self.np_random.uniform(-1.0, 1.0, 2)
            self.resets += 1
            return self._get_obs()

    return Reach


@pytest.mark.parametrize("kind", ["joints", "tip", "clip"])
@pytest.mark.parametrize("rate", ["env", "physics"])
def test_compiled_observation_shortcuts_are_checked_at_every_reset(tmp_path, kind, rate):
    """An observation that reads attributes the environment draws at reset (a goal, zero at construction; a clip
    bound) is a clipped selection of the state, or of MjData entries, only until then: the reset checks the
    compiled shortcut against the environment's own observation and drops it, and every later observation is
    the environment's own at the sensed state (the shortcut had returned the state, the goal silently dropped)."""
    path = tmp_path / "reach.xml"
    path.write_text(TWO_LINKS)
    env = EstimatedVelocity(_goal_env(path, kind)(), rate=rate, observer="kalman-ca", disk_cache=False)
    evaluation = env.adapter.evaluation
    assert (evaluation.observation_entries if kind == "tip" else evaluation.observation_map) is not None
    rng = np.random.default_rng(0)
    clipped = 0
    for episode in range(3):
        obs, info = env.reset(seed=episode)
        # the first reset leaves the attributes as they were: the shortcut holds
        dropped = evaluation.observation_map is None and evaluation.observation_entries is None
        assert dropped == (episode > 0) and env._fused is not None
        assert env._fused.maps_observation == (kind != "tip" and episode == 0)
        for _ in range(3):
            obs, *_, info = env.step(rng.uniform(-1, 1, 2))
            qpos, qvel = info["smo"]["qpos_measured"], info["smo"]["qvel_estimate"]
            np.testing.assert_array_equal(obs, full_forward_observation(env, qpos, qvel))
            clipped += np.any(np.abs(qvel) > env.unwrapped.limit)
    assert kind != "clip" or clipped > 0  # the drawn bound was active
    assert copy.deepcopy(env).adapter.evaluation.observation_map is None  # through __getstate__


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Humanoid-v5", "Ant-v5", "InvertedDoublePendulum-v5"])
def test_the_v5_environments_keep_their_compiled_observations_across_resets(env_id):
    """The reset's check of the compiled shortcuts holds for the v5 environments (their observations read nothing
    but MjData), at the reset state and at clipped extremes: none loses its compiled observation."""
    env = EstimatedVelocity(gym.make(env_id), disk_cache=False)
    evaluation = env.adapter.evaluation
    shortcut = evaluation.observation_map, evaluation.observation_entries
    assert any(s is not None for s in shortcut)
    for seed in range(3):
        env.reset(seed=seed)
        env.step(env.action_space.sample())
    assert (evaluation.observation_map, evaluation.observation_entries) == shortcut
    assert evaluation.verify()


def _check_vector_steps(venv, steps: int = 10) -> None:
    """Step ``venv`` (two environments of two actuators) with random actions: every observation is the
    environment's own at the sensed state."""
    rng = np.random.default_rng(0)
    for _ in range(steps):
        obs, *_, infos = venv.step(rng.uniform(-1, 1, (2, 2)))
        for i, sub in enumerate(venv.env.envs):
            qpos, qvel = infos["smo"]["qpos_measured"][i], infos["smo"]["qvel_estimate"][i]
            np.testing.assert_array_equal(obs[i], full_forward_observation(sub, qpos, qvel))


@pytest.mark.parametrize("kind", ["joints", "tip"])
def test_vector_wrappers_check_the_compiled_observations_at_every_reset(tmp_path, kind):
    """The in-process vector wrapper's shared selection, its compiled step's and the batched gather are made
    again once an autoreset drops an environment's shortcut: every observation is the environment's own at the
    sensed state."""
    from gymnasium.vector import SyncVectorEnv

    from smo_gym.wrappers.vec import VectorEstimatedVelocity

    path = tmp_path / "reach.xml"
    path.write_text(TWO_LINKS)
    make = _goal_env(path, kind, ends_after=4)
    venv = VectorEstimatedVelocity(
        SyncVectorEnv([make, make], autoreset_mode=gym.vector.AutoresetMode.SAME_STEP),
        observer="kalman-ca",
        positions="measured",
        disk_cache=False,
    )
    venv.reset(seed=0)
    assert (venv._selection() if kind == "joints" else venv._entries_plan()) is not None
    _check_vector_steps(venv)
    assert venv._selection() is None and venv._entries_plan() is None


LEG_ON_FLOOR = """<mujoco><option timestep="0.005"/><worldbody><geom type="plane" size="5 5 .1"/>
<body pos="0 0 0.6"><joint type="slide" axis="0 0 1" damping="0.5"/>
<joint name="hinge" type="hinge" axis="0 1 0" damping="0.1"/><geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.05"/>
</body></worldbody><actuator><motor joint="hinge" gear="1" ctrlrange="-1 1"/></actuator></mujoco>"""


@pytest.mark.parametrize("flag", ["touching", "penetrating"])
def test_an_observation_of_contacts_gets_the_collision_detection(tmp_path, flag):
    """A foot-contact flag read from ``data.ncon`` and ``data.contact`` (counts and structures, which the NaN probes
    cannot mark, empty at probe states in the air), or from the contacts' distances, takes the full forward pass:
    the sensed flag is the contact at the sensed state once the leg has fallen onto the floor (it stayed 0 before,
    the collision never run; the distances were missed by a probe that only made the geoms touch)."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    path = tmp_path / "leg.xml"
    path.write_text(LEG_ON_FLOOR)

    class Leg(MujocoEnv):
        metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 200}

        def __init__(self):
            super().__init__(str(path), 1, observation_space=Box(-np.inf, np.inf, shape=(5,), dtype=np.float64))

        def _get_obs(self):
            d = self.data
            if flag == "touching":
                on = any({d.contact.geom1[i], d.contact.geom2[i]} == {0, 1} for i in range(d.ncon))
            else:  # contacts at a positive distance (a margin) do not count: the contacts' numbers are read
                on = bool(np.any(d.contact.dist[: d.ncon] < 0.0))
            return np.concatenate([d.qpos, d.qvel, [float(on)]])

        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self):
            self.set_state(self.init_qpos, self.init_qvel)
            return self._get_obs()

    env = EstimatedVelocity(Leg(), sensor="ideal", observer="kalman-ca", rate="env", disk_cache=False)
    assert env.adapter.evaluation.pipeline == "forward"
    env.reset(seed=0)
    for _ in range(200):
        obs, *_, info = env.step(np.zeros(1))
    assert obs[-1] == 1.0 and info["smo"]["observation"][-1] == 1.0  # on the floor
    np.testing.assert_array_equal(
        obs, full_forward_observation(env, info["smo"]["qpos_measured"], info["smo"]["qvel_estimate"])
    )


def _two_links(path, after_physics, frame_skip=5):
    """The two-link arm whose step runs ``after_physics(env, action)`` in place of ``do_simulation`` alone."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    class Arm(MujocoEnv):
        metadata = {
            "render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"],
            "render_fps": 100 // frame_skip,
        }

        def __init__(self):
            space = Box(-np.inf, np.inf, shape=(4,), dtype=np.float64)
            super().__init__(str(path), frame_skip, observation_space=space)

        def _get_obs(self):
            return np.concatenate([self.data.qpos, self.data.qvel])

        def step(self, action):
            after_physics(self, action)
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self):
            self.set_state(self.init_qpos + self.np_random.uniform(-0.1, 0.1, 2), self.init_qvel)
            return self._get_obs()

    return Arm()


def test_the_last_sample_at_the_physics_rate_is_the_steps_end(tmp_path):
    """A state the environment sets after its physics (a joint it re-centres) is the step's last sample at the
    physics rate as at the env rate: the sensed and the reported true configuration are the step's end (they were
    the last physics substep's, before the re-centring)."""
    path = tmp_path / "arm.xml"
    path.write_text(TWO_LINKS)

    def recentre(env, action):
        env.do_simulation(action, env.frame_skip)
        env.set_state(env.data.qpos * [1.0, 0.0], env.data.qvel * [1.0, 0.0])

    for rate in ("physics", "env"):
        env = EstimatedVelocity(_two_links(path, recentre), sensor="ideal", observer="kalman-ca", rate=rate)
        env.reset(seed=0)
        for _ in range(3):
            obs, *_, info = env.step(np.full(2, 0.5))
            live = env.unwrapped.data.qpos
            assert live[1] == 0.0
            np.testing.assert_array_equal(obs[:2], live)
            np.testing.assert_array_equal(info["smo"]["qpos"], live)


def test_too_few_physics_steps_to_sample_are_refused(tmp_path):
    """At a rate inside ``frame_skip`` the samples come from the physics steps the environment takes through
    ``do_simulation``: a step that takes none there (``mj_step`` called directly), or fewer than one sample needs,
    is a RuntimeError that says how many it saw (fewer than one sample's gave "expected n_samples in [1, 256]")."""
    import mujoco

    path = tmp_path / "arm.xml"
    path.write_text(TWO_LINKS)

    def direct(env, action):
        env.data.ctrl[:] = action
        mujoco.mj_step(env.model, env.data, nstep=env.frame_skip)

    def short(env, action):
        env.do_simulation(action, 2)

    for after_physics, rate, seen in ((direct, "physics", 0), (short, 5, 2)):
        arm = _two_links(path, after_physics, frame_skip=10)
        env = EstimatedVelocity(arm, sensor="ideal", observer="kalman-ca", rate=rate)
        env.reset(seed=0)
        with pytest.raises(RuntimeError, match=rf"physics steps per step\(\).* actual value: {seen}; use rate="):
            env.step(np.zeros(2))


LOCKED_ELBOW = """<mujoco><option timestep="0.005"/><worldbody><body pos="0 0 1">
<joint name="shoulder" type="hinge" axis="0 1 0" damping="0.1"/>
<geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.05"/>
<body pos="0.5 0 0"><joint name="elbow" type="hinge" axis="0 1 0" damping="0.1"/>
<geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.05"/></body></body></worldbody>
<equality><joint joint1="elbow" active="true"/></equality>
<actuator><motor joint="shoulder" gear="5" ctrlrange="-1 1"/><motor joint="elbow" gear="5" ctrlrange="-1 1"/>
</actuator></mujoco>"""


def _gripper(path, reads_flag: bool):
    """An arm whose elbow lock (an equality constraint, on in the model) the environment releases at reset and
    switches at every step by the sign of the second action: the observation reads the accelerations (the full
    forward pass) or the lock's flag alone."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    class Gripper(MujocoEnv):
        metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 40}

        def __init__(self):
            space = Box(-np.inf, np.inf, shape=(5 if reads_flag else 6,), dtype=np.float64)
            super().__init__(str(path), 5, observation_space=space)

        def _get_obs(self):
            d = self.data
            return np.concatenate([d.qpos, d.qvel, d.eq_active.astype(float) if reads_flag else d.qacc])

        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            self.data.eq_active[0] = action[1] > 0.0
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self):
            self.set_state(self.init_qpos + self.np_random.uniform(-0.1, 0.1, 2), self.init_qvel)
            self.data.eq_active[0] = 0
            return self._get_obs()

    return Gripper


@pytest.mark.parametrize("reads_flag", [False, True])
def test_which_equality_constraints_are_on_is_copied(tmp_path, reads_flag):
    """Which equality constraints are on (``eq_active``, a uint8 array an environment switches: a weld for a grasp)
    is one of the controller's inputs: the sensed accelerations and a flag read from it follow the live switch, in
    the single and the vector wrappers (the scratch data kept the model's lock, silently)."""
    from gymnasium.vector import SyncVectorEnv

    from smo_gym.wrappers.vec import VectorEstimatedVelocity

    path = tmp_path / "gripper.xml"
    path.write_text(LOCKED_ELBOW)
    make = _gripper(path, reads_flag)
    env = EstimatedVelocity(make(), sensor="ideal", observer="kalman-ca")
    assert env.adapter.evaluation.pipeline == ("none" if reads_flag else "forward")
    obs, info = env.reset(seed=0)
    rng = np.random.default_rng(0)
    switched = set()
    for _ in range(6):
        np.testing.assert_array_equal(
            obs, full_forward_observation(env, info["smo"]["qpos_measured"], info["smo"]["qvel_estimate"])
        )
        obs, *_, info = env.step(rng.uniform(-1, 1, 2))
        switched.add(bool(env.unwrapped.data.eq_active[0]))
    assert switched == {False, True}
    live = env.unwrapped.data
    live.eq_active[0] = 0  # the model's lock is on: a vector env's terminal snapshot keeps the live switch
    assert copy_observed_fields(live, mujoco.MjData(env.unwrapped.model)).eq_active[0] == 0
    vector = VectorEstimatedVelocity(SyncVectorEnv([make, make]), sensor="ideal", observer="kalman-ca")
    vector.reset(seed=0)
    for _ in range(4):
        obs, *_, infos = vector.step(rng.uniform(-1, 1, (2, 2)))
        for i, sub in enumerate(vector.env.envs):
            qpos, qvel = infos["smo"]["qpos_measured"][i], infos["smo"]["qvel_estimate"][i]
            np.testing.assert_array_equal(obs[i], full_forward_observation(sub, qpos, qvel))


def test_the_collision_probe_keeps_observations_of_the_state_alone_on_their_shortcuts(tmp_path):
    """An observation of the state alone on a model of many geoms (a chain of 40 links of 6 boxes: making every
    pair of geoms touch overflows MuJoCo's arena) or with an equality constraint (inactive) keeps the bare path
    and the compiled selection (the overflow counted as reading collisions: the full forward pass at every step,
    2.8x the step time; the constraint took the selection away)."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    boxes = "".join(f'<geom type="box" size=".02 .02 .02" pos="{0.03 * k} 0 0"/>' for k in range(6))
    chain = "".join(f'<body pos="0.2 0 0"><joint type="hinge" axis="0 1 0"/>{boxes}' for _ in range(40))
    models = {
        "chain": f"<mujoco><worldbody>{chain}{'</body>' * 40}</worldbody></mujoco>",
        "equality": TWO_LINKS.replace("<actuator>", '<equality><joint joint1="j1" joint2="j2" active="false"/>'
                                                    "</equality><actuator>"),
    }  # fmt: skip
    for name, xml in models.items():
        path = tmp_path / f"{name}.xml"
        path.write_text(xml)
        model = mujoco.MjModel.from_xml_path(str(path))
        nq, fps = model.nq, round(1.0 / model.opt.timestep)

        class State(MujocoEnv):
            metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": fps}

            def __init__(self):
                super().__init__(str(path), 1, observation_space=Box(-np.inf, np.inf, (2 * nq,), np.float64))

            def _get_obs(self):
                return np.concatenate([self.data.qpos, self.data.qvel])

        evaluation = make_adapter(State()).evaluation
        assert evaluation.pipeline == "none" and evaluation.observation_map is not None, name


def _rebuilt_env(path, change: str, observe: str = "tip", ends_after: int = 10_000):
    """The two-link arm with its model rebuilt from the XML at every reset but the first (a procedurally generated
    world): ``change="geometry"`` lengthens the upper link and divides the motors' gear by 100 (the same joints),
    ``"joints"`` also adds a third link, ``"timestep"`` also halves the timestep (the attribute ``change``, set on
    the instance after wrapping: the calibration's rollouts reset a copy of the environment). It observes the
    joints and the tip's position (``observe="tip"``: entries of MjData, which the length moves) or the joints'
    positions and their velocities clipped at the first motor's gear (``"clip"``: a clipped selection of the state,
    which the gear changes)."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    class Rebuilt(MujocoEnv):
        metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 20}

        def __init__(self):
            self.resets, self.steps, self.change = 0, 0, change
            space = Box(-np.inf, np.inf, shape=(7 if observe == "tip" else 4,), dtype=np.float64)
            super().__init__(str(path), 5, observation_space=space)

        def _get_obs(self):
            d, gear = self.data, self.model.actuator_gear[0, 0]
            if observe == "clip":
                return np.concatenate([d.qpos[:2], np.clip(d.qvel[:2], -gear, gear)])
            return np.concatenate([d.qpos[:2], d.qvel[:2], d.site_xpos[0]])

        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            self.steps += 1
            return self._get_obs(), 0.0, self.steps % ends_after == 0, False, {}

        def reset_model(self):
            if self.resets:
                xml = TWO_LINKS.replace('<body pos="0 0 -0.5">', f'<body pos="0 0 {-0.5 - 0.1 * self.resets}">')
                xml = xml.replace('gear="5"', 'gear="0.05"')
                if self.change == "joints":
                    xml = xml.replace(
                        "</body></body>", "<body><joint type='hinge'/><geom size='.1'/></body></body></body>"
                    )
                elif self.change == "timestep":
                    xml = xml.replace('timestep="0.01"', 'timestep="0.005"')
                self.model = mujoco.MjModel.from_xml_string(xml)
                self.data = mujoco.MjData(self.model)
            self.set_state(np.full(self.model.nq, 0.1), np.zeros(self.model.nv))
            self.resets += 1
            return self._get_obs()

    return Rebuilt


@pytest.mark.parametrize("observe", ["tip", "clip"])
@pytest.mark.parametrize("rate", ["env", "physics"])
def test_a_model_rebuilt_at_reset_is_followed(tmp_path, rate, observe):
    """An environment that rebuilds its model at reset (the same joints, a longer link, another gear): every sensed
    observation is the environment's own on the new model (the scratch evaluation, its compiled gather or selection,
    had stayed on the first model: the tip a link length off, the velocities clipped at the old gear), and the
    physics-rate samples come from the new model's steps."""
    path = tmp_path / "arm.xml"
    path.write_text(TWO_LINKS)
    make = _rebuilt_env(path, "geometry", observe)
    env = EstimatedVelocity(make(), sensor="ideal", observer="kalman-ca", rate=rate, disk_cache=False)
    rng, clipped = np.random.default_rng(0), 0
    for episode in range(3):
        obs, info = env.reset(seed=episode)
        assert env.adapter.evaluation.model is env.unwrapped.model and env._fused is not None
        smo = info["smo"]
        np.testing.assert_array_equal(obs, full_forward_observation(env, smo["qpos_measured"], smo["qvel_estimate"]))
        for _ in range(5):
            obs, *_, info = env.step(rng.uniform(-1, 1, 2))
            qpos, qvel = info["smo"]["qpos_measured"], info["smo"]["qvel_estimate"]
            np.testing.assert_array_equal(qpos, env.unwrapped.data.qpos)  # the ideal sensor
            np.testing.assert_array_equal(obs, full_forward_observation(env, qpos, qvel))
            clipped += episode > 0 and np.any(np.abs(qvel) > 0.05)
    assert env.unwrapped.model.body_pos[2, 2] == pytest.approx(-0.7) and clipped > 0


@pytest.mark.parametrize("observe", ["tip", "clip"])
def test_a_model_rebuilt_at_reset_in_a_vector_env_is_followed(tmp_path, observe):
    """The same in the in-process vector wrapper, whose autoresets rebuild the models: its batched gather and its
    shared selection are made again on the new scratch data."""
    from gymnasium.vector import SyncVectorEnv

    from smo_gym.wrappers.vec import VectorEstimatedVelocity

    path = tmp_path / "arm.xml"
    path.write_text(TWO_LINKS)
    make = _rebuilt_env(path, "geometry", observe, ends_after=4)
    venv = VectorEstimatedVelocity(
        SyncVectorEnv([make, make], autoreset_mode=gym.vector.AutoresetMode.SAME_STEP),
        sensor="ideal",
        observer="kalman-ca",
        positions="measured",
        disk_cache=False,
    )
    venv.reset(seed=0)
    _check_vector_steps(venv)
    assert all(sub.unwrapped.resets == 3 for sub in venv.env.envs)
    assert (venv._entries_plan() if observe == "tip" else venv._selection()) is not None


@pytest.mark.parametrize(
    "change, message", [("joints", r"nq=2, nv=2.*actual value: nq=3, nv=3"), ("timestep", "opt.timestep 0.01 .* 0.005")]
)
@pytest.mark.parametrize("rate", ["env", "physics"])
def test_a_model_rebuilt_with_other_joints_or_timestep_is_refused(tmp_path, change, message, rate):
    """A rebuilt model with other joints (the observer's channels, the sensor's state) or another timestep (the
    sampling step the gains were made for) is refused at the reset that brings it, with both sides named, and the
    wrapper is left un-reset: a step then asks for a reset (it had gone on with the old model's arrays, whose
    compiled step wrote past them into the heap)."""
    from gymnasium.vector import SyncVectorEnv

    from smo_gym.wrappers.vec import VectorEstimatedVelocity

    path = tmp_path / "arm.xml"
    path.write_text(TWO_LINKS)
    env = EstimatedVelocity(_rebuilt_env(path, "geometry")(), observer="kalman-ca", rate=rate, disk_cache=False)
    env.unwrapped.change = change
    env.reset(seed=0)
    env.step(np.zeros(2))
    for _ in range(2):
        with pytest.raises(ValueError, match=message):
            env.reset(seed=1)
        with pytest.raises(RuntimeError, match="its last reset raised"):
            env.step(np.zeros(2))
    make = _rebuilt_env(path, "geometry", ends_after=2)
    autoreset = gym.vector.AutoresetMode.SAME_STEP
    venv = VectorEstimatedVelocity(SyncVectorEnv([make, make], autoreset_mode=autoreset), observer="kalman-ca",
                                   disk_cache=False)  # fmt: skip
    for sub in venv.env.envs:
        sub.unwrapped.change = change
    venv.reset(seed=0)
    venv.step(np.zeros((2, 2)))
    with pytest.raises(ValueError, match=message):  # the autoreset after the episode's end
        venv.step(np.zeros((2, 2)))
    with pytest.raises(RuntimeError, match="its last reset raised"):
        venv.step(np.zeros((2, 2)))


@pytest.mark.parametrize("rate", ["env", "physics"])
def test_a_model_replaced_in_the_middle_of_an_episode_is_refused(tmp_path, rate):
    """An environment that replaces its model and data inside ``step`` (with a third joint) is refused at the next
    step with a ``ValueError`` naming both sizes: the compiled step reads the live ``qpos`` without a check, and had
    written the new model's three joints past the old arrays (a heap corruption that aborted the interpreter)."""
    from gymnasium.envs.mujoco import MujocoEnv
    from gymnasium.spaces import Box

    path = tmp_path / "arm.xml"
    path.write_text(TWO_LINKS)

    class Swap(MujocoEnv):
        metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 20}

        def __init__(self):
            self.steps, self.swap = 0, False
            super().__init__(str(path), 5, observation_space=Box(-np.inf, np.inf, shape=(4,), dtype=np.float64))

        def _get_obs(self):
            return np.concatenate([self.data.qpos[:2], self.data.qvel[:2]])

        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            self.steps += 1
            if self.swap and self.steps == 2:
                three = "<body><joint type='hinge'/><geom size='.1'/></body></body></body>"
                self.model = mujoco.MjModel.from_xml_string(TWO_LINKS.replace("</body></body>", three))
                self.data = mujoco.MjData(self.model)
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self):
            self.set_state(self.init_qpos + 0.1, self.init_qvel)
            return self._get_obs()

    env = EstimatedVelocity(Swap(), observer="kalman-ca", rate=rate, disk_cache=False)
    env.unwrapped.swap = True  # after the calibration's rollouts, which step a copy
    env.reset(seed=0)
    assert env._fused is not None
    env.step(np.zeros(2))
    env.step(np.zeros(2))  # the environment replaces its model here
    for _ in range(2):
        with pytest.raises(ValueError, match=r"qpos of size 2, qvel of size 2\), actual value: sizes 3 and 3"):
            env.step(np.zeros(2))


class _PoleCentre(InvertedPendulumEnv):
    """InvertedPendulum observing also where its pole's body is (which an edit of the model's geometry moves)."""

    def _get_obs(self):
        return np.concatenate([super()._get_obs(), self.data.xpos[2]])


def test_a_copy_follows_in_place_edits_of_its_model():
    """A copy of the wrapper (pickled, or deep-copied) evaluates observations on its own environment's model, which
    Gymnasium rebuilds from the constructor: an in-place edit there (domain randomisation) is seen (the copy's
    scratch evaluation had a copy of the original's model, on which the edit never showed)."""
    env = EstimatedVelocity(_PoleCentre(), sensor="ideal", observer="kalman-ca", disk_cache=False)
    for clone in (env, pickle.loads(pickle.dumps(env)), copy.deepcopy(env)):
        clone.unwrapped.model.body_pos[2, 2] = 0.5
        obs, info = clone.reset(seed=0)
        obs, *_, info = clone.step(np.full(1, 0.5))
        qpos, qvel = info["smo"]["qpos_measured"], info["smo"]["qvel_estimate"]
        assert obs[-1] > 0.4
        np.testing.assert_array_equal(obs, full_forward_observation(clone, qpos, qvel))
