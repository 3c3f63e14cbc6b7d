"""Vectorized sensing: VecEstimatedVelocity (SB3) and VectorEstimatedVelocity (Gymnasium) against per-env wrappers."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from conftest import UnregisteredFiniteDifference
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnvWrapper, VecNormalize

from smo_gym import sensors
from smo_gym.engine.batch import BatchedSensing, MeasurementBatch
from smo_gym.observers import DivergenceError
from smo_gym.wrappers import EstimatedVelocity, JointSensor, VecEstimatedVelocity, VectorEstimatedVelocity

#: the keys of info["smo"], the same from every wrapper
SMO_KEYS = ("qpos", "qvel", "qvel_estimate", "qpos_measured", "observation")
ENV = "InvertedDoublePendulum-v5"  # episodes end within ~10-40 steps under random actions: many autoresets
N = 3


def _pair(n=N, seed=3, positions="measured", env_id=ENV):
    ref = DummyVecEnv([lambda: EstimatedVelocity(gym.make(env_id), rate="env", positions=positions) for _ in range(n)])
    vec = VecEstimatedVelocity(
        DummyVecEnv([lambda: gym.make(env_id) for _ in range(n)]),
        "encoder-12bit-noisy",
        "auto",
        positions=positions,
    )
    ref.seed(seed)
    vec.seed(seed)
    return ref, vec


@pytest.mark.parametrize("positions, env_id", [("measured", ENV), ("filtered", ENV), ("measured", "Hopper-v5")])
def test_vec_equals_per_env_wrappers_with_autoresets(positions, env_id):
    """Also with the in-process shortcuts: Hopper's clipped selection is built for all environments at once, and
    InvertedDoublePendulum's (with sines, cosines and a constraint force) is gathered for all environments by
    compiled calls. ``info["smo"]`` has the per-environment wrapper's layout and values, at autoresets too (the
    finished episode's last sample, like ``terminal_observation``)."""
    ref, vec = _pair(positions=positions, env_id=env_id)
    np.testing.assert_allclose(vec.reset(), ref.reset(), rtol=0, atol=1e-12)
    assert isinstance(vec._batch, MeasurementBatch)  # the environments are measured together
    rng = np.random.default_rng(0)
    n_done = 0
    for _ in range(150):
        a = rng.uniform(-1, 1, (N,) + vec.action_space.shape)
        o1, r1, d1, i1 = ref.step(a)
        o2, r2, d2, i2 = vec.step(a)
        np.testing.assert_array_equal(d1, d2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
        for i in range(N):
            assert set(i2[i]["smo"]) == set(i1[i]["smo"]) == set(SMO_KEYS)
            for key in SMO_KEYS:
                np.testing.assert_allclose(i2[i]["smo"][key], i1[i]["smo"][key], rtol=0, atol=1e-12)
        for i in np.flatnonzero(d1):
            n_done += 1
            np.testing.assert_allclose(i2[i]["terminal_observation"], i1[i]["terminal_observation"], rtol=0, atol=1e-12)
    assert n_done >= 5  # the comparison covered autoresets
    assert isinstance(vec._together, BatchedSensing)  # the steps where every environment went on: one call
    assert (vec._selection() is not None) == (env_id == "Hopper-v5" and positions == "measured")
    assert (vec._entries_plan() is not None) == (env_id == ENV and positions == "measured")


def test_gathered_observations_follow_a_replaced_mjdata():
    """The batched gather's copy table points into each environment's MjData: an environment that replaces its
    data gets a new plan, and the observations still equal the per-environment evaluation."""
    import copy

    _, vec = _pair()
    vec.reset()
    rng = np.random.default_rng(1)
    vec.step(rng.uniform(-1, 1, (N, 1)))
    plan = vec._entries_plan()
    unwrapped = vec._local[1].unwrapped
    unwrapped.data = copy.copy(unwrapped.data)
    obs, _, _done, _ = vec.step(rng.uniform(-1, 1, (N, 1)))
    assert vec._entries_plan() is not plan and vec._entries_plan().current()
    velocity = vec.observer.estimate[..., 1]
    for i, sensor in enumerate(vec._local):
        np.testing.assert_array_equal(obs[i], sensor.observe(velocity[i]))


def test_autoreset_terminal_observation_and_restart():
    _, vec = _pair()
    vec.reset()
    rng = np.random.default_rng(1)
    for _ in range(200):
        _, _, dones, infos = vec.step(rng.uniform(-1, 1, (N, 1)))
        if dones.any():
            break
    assert dones.any()
    sensors = vec.venv.envs  # wrapped in JointSensor in place (in-process: measurements read, not in infos)
    new_obs = vec.observer.estimate
    for i in np.flatnonzero(dones):
        z_terminal = sensors[i].z_step
        z_first = sensors[i].z_reset
        term = infos[i]["terminal_observation"]
        # IDP observation: [x, sin(q1), sin(q2), cos(q1), cos(q2), xdot, q1dot, q2dot, constraint]; z = qpos here
        assert term[0] == z_terminal[0]
        np.testing.assert_allclose(term[1:3], np.sin(z_terminal[1:]), rtol=0, atol=1e-15)
        # the finished episode's estimate after its last sample, not a restarted one
        assert np.any(np.abs(term[5:8]) > 1e-6)
        np.testing.assert_allclose(term[5:8], np.clip(infos[i]["smo"]["qvel_estimate"], -10, 10), atol=1e-15)
        # that environment's observer restarted at its new first measurement with zero velocity
        np.testing.assert_array_equal(new_obs[i, :, 0], z_first)
        np.testing.assert_array_equal(new_obs[i, :, 1], 0.0)
        assert not np.array_equal(z_first, z_terminal)
    for i in np.flatnonzero(~dones):  # the others were not restarted
        assert np.any(new_obs[i, :, 1] != 0.0)


def test_ppo_trains_on_vec_stack_and_save_load(tmp_path):
    from stable_baselines3 import PPO

    venv = VecNormalize(VecEstimatedVelocity(DummyVecEnv([lambda: gym.make(ENV) for _ in range(2)])))
    venv.seed(5)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(256)
    assert model.num_timesteps >= 256
    sensing, norm = venv.venv, venv
    sensing.save(tmp_path / "sensing.pkl")
    norm.save(str(tmp_path / "norm.pkl"))
    # fresh stack from disk, on new environments
    fresh = VecEstimatedVelocity.load(tmp_path / "sensing.pkl", DummyVecEnv([lambda: gym.make(ENV) for _ in range(2)]))
    fresh_norm = VecNormalize.load(str(tmp_path / "norm.pkl"), fresh)
    np.testing.assert_array_equal(fresh_norm.obs_rms.mean, norm.obs_rms.mean)
    assert fresh.config == sensing.config
    norm.training = fresh_norm.training = False
    norm.seed(11)
    fresh_norm.seed(11)
    np.testing.assert_allclose(fresh_norm.reset(), norm.reset(), rtol=0, atol=1e-12)
    a = np.full((2, 1), 0.3)
    for _ in range(20):
        o1, _, _d1, _ = norm.step(a)
        o2, _, _d2, _ = fresh_norm.step(a)
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
    model.set_env(fresh_norm)
    model.learn(64, reset_num_timesteps=False)


def test_pickles_without_venv():
    _, vec = _pair(n=2)
    vec.reset()
    clone = pickle.loads(pickle.dumps(vec))
    assert clone.venv is None
    for call in (clone.reset, lambda: clone.step(np.zeros((2, 1))), lambda: clone.seed(0)):
        with pytest.raises(RuntimeError, match="attach one with set_venv"):
            call()
    with pytest.raises(ValueError, match="expected a venv with observation space"):
        clone.set_venv(DummyVecEnv([lambda: gym.make("Hopper-v5")]))
    with pytest.raises(TypeError, match="expected a stable_baselines3 VecEnv"):
        clone.set_venv(gym.make(ENV))
    other = dict(sensor="ideal", observer="finite-difference")
    with pytest.raises(ValueError, match="expected the sub-environments' JointSensor"):
        clone.set_venv(DummyVecEnv([lambda: JointSensor(gym.make(ENV), **other) for _ in range(2)]))
    assert clone.venv is None  # refused: still without a venv, and a good one is taken
    clone.set_venv(DummyVecEnv([lambda: gym.make(ENV) for _ in range(2)]))
    assert clone.reset().shape == (2, 9)
    with pytest.raises(ValueError, match="without a venv"):
        clone.set_venv(DummyVecEnv([lambda: gym.make(ENV) for _ in range(2)]))


def test_a_saved_wrapper_loads_only_onto_a_venv_with_its_spaces(tmp_path):
    """A wrapper saved on smo_gym's two-link arm was attached to the Furuta pendulum (the same observation space,
    one input instead of two) and kept the arm's action space; a venv of float32 observations (the same shape) was
    taken too. The saved observation and action spaces must now equal the venv's; a refused venv leaves the wrapper
    without one, and the arm's own venv is then taken."""

    class Float32Observations(VecEnvWrapper):
        def __init__(self, venv):
            shape = venv.observation_space.shape
            super().__init__(venv, observation_space=gym.spaces.Box(-np.inf, np.inf, shape, np.float32))

        def reset(self):
            return self.venv.reset().astype(np.float32)

        def step_wait(self):
            obs, rewards, dones, infos = self.venv.step_wait()
            return obs.astype(np.float32), rewards, dones, infos

    def arms():
        return DummyVecEnv([lambda: gym.make("smo_gym/TwoLinkArm-v0") for _ in range(2)])

    sensing = dict(sensor="ideal", observer="finite-difference")
    VecEstimatedVelocity(arms(), **sensing).save(tmp_path / "arm.pkl")
    furuta = DummyVecEnv([lambda: gym.make("smo_gym/FurutaPendulum-v0") for _ in range(2)])
    assert furuta.observation_space == arms().observation_space  # only the action spaces tell them apart
    with pytest.raises(ValueError, match=r"expected a venv with action space Box\(\[-10\. +-5\.\]"):
        VecEstimatedVelocity.load(tmp_path / "arm.pkl", furuta)
    with open(tmp_path / "arm.pkl", "rb") as fh:
        saved = pickle.load(fh)
    with pytest.raises(ValueError, match=r"expected a venv with observation space Box.*float64.*float32"):
        saved.set_venv(Float32Observations(arms()))
    assert saved.venv is None  # refused: without a venv, as before
    saved.set_venv(arms())
    assert saved.reset().shape == (2, 4) and saved.action_space == gym.make("smo_gym/TwoLinkArm-v0").action_space


@pytest.mark.parametrize("api", ["sb3", "gymnasium"])
def test_a_refused_batch_steps_and_resets_no_environment(api):
    """Actions and seeds are checked for the whole batch before any environment is stepped or reset: a refused
    last row used to leave the rows before it stepped (an episode could even end and restart unseen)."""
    if api == "sb3":
        vec, twin = (VecEstimatedVelocity(DummyVecEnv([lambda: gym.make(ENV) for _ in range(N)])) for _ in range(2))
        for v in (vec, twin):
            v.seed(0)
            v.reset()
        step = vec.step
    else:
        make = lambda: gym.make_vec(ENV, num_envs=N, vectorization_mode="sync")
        vec, twin = VectorEstimatedVelocity(make()), VectorEstimatedVelocity(make())
        for v in (vec, twin):
            v.reset(seed=0)
        step = vec.step
    qpos = [s.adapter.data.qpos.copy() for s in vec._local]
    for bad, error in (
        (np.array([[0.1], [0.1], [np.nan]]), "at entry \\(2, 0\\)"),
        (np.zeros((N - 1, 1)), "shape"),
        (np.zeros((N + 1, 1)), "shape"),
        (np.zeros(N), "shape"),
    ):
        with pytest.raises(ValueError, match=error):
            step(bad)
        for s, q in zip(vec._local, qpos, strict=True):
            np.testing.assert_array_equal(s.adapter.data.qpos, q)
    if api == "gymnasium":
        for seed, error in (([0, 1], ValueError), ([0, 1, -1], ValueError), (True, TypeError), (2.5, TypeError)):
            with pytest.raises(error, match="seed"):
                vec.reset(seed=seed)
        with pytest.raises(TypeError, match="expected options to be None or a dict"):
            vec.reset(options="x")
        assert vec.reset(seed=np.int64(0))[0].shape == (N, 9)
        twin.reset(seed=0)
    else:
        for seed in (-1, 2.5):
            with pytest.raises((TypeError, ValueError), match="seed"):
                vec.seed(seed)
    action = np.full((N, 1), 0.2)
    np.testing.assert_array_equal(step(action)[0], twin.step(action)[0])


def test_joint_sensor_observes_only_a_real_velocity_of_its_dofs():
    """``observe`` broadcast a one-entry velocity to every dof and dropped the imaginary part of a complex one;
    ``observe_rows`` with an index that lacks the sensor's token was a bare KeyError."""
    with pytest.raises(TypeError, match="expected observer_kwargs to be a dict"):
        JointSensor(gym.make("InvertedPendulum-v5"), observer_kwargs="x")
    sensor = JointSensor(gym.make("InvertedPendulum-v5"))
    sensor.reset(seed=0)
    for bad, error in ((np.zeros(1), ValueError), (np.zeros(3), ValueError), (np.zeros(2, complex), TypeError),
                       (None, TypeError)):  # fmt: skip
        with pytest.raises(error, match="expected q"):
            sensor.observe(bad)
    assert np.isfinite(sensor.observe(np.zeros(2))).all()
    rows = np.zeros((1, 2))
    np.testing.assert_array_equal(
        sensor.observe_rows({sensor.token: 0}, rows, None, None, None, None)[0], sensor.observe(rows[0])
    )
    with pytest.raises(ValueError, match="expected an index with this sensor's token"):
        sensor.observe_rows({"another": 0}, rows, None, None, None, None)


def test_subproc_vec_env_matches_dummy_and_needs_joint_sensor():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    from smo_gym.wrappers import sensing_config

    kw = sensing_config("encoder-12bit-noisy", "super-twisting")
    sub = make_vec_env(ENV, n_envs=2, seed=4, vec_env_cls=SubprocVecEnv, wrapper_class=JointSensor, wrapper_kwargs=kw)
    dummy = make_vec_env(ENV, n_envs=2, seed=4, wrapper_class=JointSensor, wrapper_kwargs=kw)
    try:
        a, b = VecEstimatedVelocity(sub), VecEstimatedVelocity(dummy)
        np.testing.assert_allclose(a.reset(), b.reset(), rtol=0, atol=1e-12)
        rng = np.random.default_rng(2)
        for _ in range(40):
            act = rng.uniform(-1, 1, (2, 1))
            o1, _, d1, i1 = a.step(act)
            o2, _, _d2, i2 = b.step(act)
            np.testing.assert_allclose(o1, o2, rtol=0, atol=1e-12)
            for i in range(2):  # the same info["smo"] across the process boundary
                for key in SMO_KEYS:
                    np.testing.assert_allclose(i1[i]["smo"][key], i2[i]["smo"][key], rtol=0, atol=1e-12)
            for i in np.flatnonzero(d1):
                np.testing.assert_allclose(i1[i]["terminal_observation"], i2[i]["terminal_observation"], atol=1e-12)
    finally:
        sub.close()
    with pytest.raises(ValueError, match="sensing"):
        VecEstimatedVelocity(
            make_vec_env(ENV, n_envs=1, wrapper_class=JointSensor, wrapper_kwargs=kw), "ideal", "super-twisting"
        )


def test_subproc_without_joint_sensor_raises():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    sub = SubprocVecEnv([lambda: gym.make(ENV)])
    try:
        with pytest.raises(TypeError, match="JointSensor"):
            VecEstimatedVelocity(sub)
    finally:
        sub.close()


def test_gymnasium_async_without_joint_sensor_is_one_clear_error(capfd):
    """The workers are asked whether they have a JointSensor (without raising there): one TypeError here, not one
    traceback per worker."""
    import warnings

    envs = gym.make_vec(ENV, 2, vectorization_mode="async")
    try:
        with warnings.catch_warnings(record=True) as caught, pytest.raises(TypeError, match="JointSensor"):
            warnings.simplefilter("always")  # Gymnasium reports worker errors as warnings with their tracebacks
            VectorEstimatedVelocity(envs)
    finally:
        envs.close()
    assert not [w for w in caught if "Traceback" in str(w.message) or "Worker" in str(w.message)]
    assert "Traceback" not in capfd.readouterr().err


def test_vector_wrappers_say_why_not_at_the_physics_rate():
    """They sample once per vector step; the error points to per-environment wrappers, which sample inside
    frame_skip in any vector env (test_make_vec_env_with_per_env_wrapper_physics_rate)."""
    from gymnasium.vector import SyncVectorEnv

    with pytest.raises(ValueError, match=r"rate='env'.*EstimatedVelocity, rate='physics'"):
        VectorEstimatedVelocity(SyncVectorEnv([lambda: gym.make(ENV)]), rate="physics")
    with pytest.raises(ValueError, match=r"rate='env'"):
        VecEstimatedVelocity(DummyVecEnv([lambda: gym.make(ENV)]), rate="physics")
    with pytest.raises(ValueError, match=r"rate='env'"):
        JointSensor(gym.make(ENV), rate=1)


def test_gymnasium_vector_wrapper_round_trips_plain_pickle():
    """Plain pickle, given a picklable vector env (environment functions that are not lambdas)."""
    import functools

    from gymnasium.vector import SyncVectorEnv

    vec = VectorEstimatedVelocity(SyncVectorEnv([functools.partial(gym.make, ENV)] * 2), "encoder-12bit-noisy", "auto")
    vec.reset(seed=5)
    twin = pickle.loads(pickle.dumps(vec))
    assert twin._batch is None and not any(s.batched for s in twin._local)  # its sensors' streams are its own
    o1, _ = vec.reset(seed=6)
    o2, _ = twin.reset(seed=6)
    np.testing.assert_array_equal(o1, o2)
    assert isinstance(twin._batch, MeasurementBatch) and twin._batch.sensors.state is not vec._batch.sensors.state
    for a in np.random.default_rng(0).uniform(-1, 1, (10, 2, 1)):
        np.testing.assert_array_equal(vec.step(a)[0], twin.step(a)[0])


def test_make_vec_env_with_per_env_wrapper_physics_rate():
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(
        "Hopper-v5", n_envs=2, seed=0, wrapper_class=EstimatedVelocity, wrapper_kwargs=dict(rate="physics")
    )
    obs = venv.reset()
    assert obs.shape == (2, 11)
    _, _, _, infos = venv.step(np.zeros((2, 3)))
    assert not np.array_equal(obs[0], obs[1])  # own seeds and sensor streams
    assert set(infos[0]["smo"]) >= {"qvel", "qvel_estimate"}
    PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu").learn(128)


# ---- Gymnasium vector envs --------------------------------------------------------------------------------------
def _assert_same_smo(reference: dict, infos: dict) -> None:
    """``infos["smo"]`` of a vector wrapper equals what per-environment wrappers give through Gymnasium's info
    merging (the rows its ``_smo`` mask selects)."""
    rows = np.asarray(reference["_smo"], dtype=bool)
    assert set(infos["smo"]) == set(reference["smo"]) == set(SMO_KEYS) | {f"_{key}" for key in SMO_KEYS}
    np.testing.assert_array_equal(infos["_smo"], reference["_smo"])
    for key in SMO_KEYS:
        np.testing.assert_array_equal(infos["smo"][f"_{key}"], reference["smo"][f"_{key}"])
        np.testing.assert_allclose(infos["smo"][key][rows], reference["smo"][key][rows], rtol=0, atol=1e-12)


@pytest.mark.parametrize("mode", ["NextStep", "SameStep", "Disabled"])
def test_gymnasium_vector_wrapper_matches_per_env(mode):
    from gymnasium.vector import SyncVectorEnv

    ref = SyncVectorEnv([lambda: EstimatedVelocity(gym.make(ENV), rate="env") for _ in range(N)], autoreset_mode=mode)
    vec = VectorEstimatedVelocity(
        SyncVectorEnv([lambda: gym.make(ENV) for _ in range(N)], autoreset_mode=mode),
        "encoder-12bit-noisy",
        "auto",
    )
    o1, _ = ref.reset(seed=7)
    o2, _ = vec.reset(seed=7)
    np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
    assert isinstance(vec._batch, MeasurementBatch)
    rng = np.random.default_rng(3)
    n_done = 0
    for _ in range(120):
        a = rng.uniform(-1, 1, (N, 1))
        o1, r1, t1, u1, i1 = ref.step(a)
        o2, r2, t2, _u2, i2 = vec.step(a)
        np.testing.assert_array_equal(t1, t2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
        done = t1 | u1
        n_done += int(done.sum())
        _assert_same_smo(i1, i2)
        if mode == "SameStep":
            for i in np.flatnonzero(done):
                np.testing.assert_allclose(i2["final_obs"][i], i1["final_obs"][i], rtol=0, atol=1e-12)
            if done.any():
                _assert_same_smo(i1["final_info"], i2["final_info"])
        if mode == "Disabled" and done.any():
            qpos = [s.adapter.data.qpos.copy() for s in vec._local]
            with pytest.raises(RuntimeError, match="reset_mask"):  # Gymnasium stepped the others, then asserted
                vec.step(a)
            for s, q in zip(vec._local, qpos, strict=True):
                np.testing.assert_array_equal(s.adapter.data.qpos, q)
            o1, _ = ref.reset(options={"reset_mask": done.copy()})
            o2, _ = vec.reset(options={"reset_mask": done.copy()})
            np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
    assert n_done >= 5


def test_gymnasium_async_vector_env_same_step():
    from gymnasium.vector import SyncVectorEnv

    vec = VectorEstimatedVelocity(
        gym.make_vec(
            ENV, 2, vectorization_mode="async", wrappers=[JointSensor], vector_kwargs=dict(autoreset_mode="SameStep")
        )
    )
    ref = SyncVectorEnv(
        [lambda: EstimatedVelocity(gym.make(ENV), rate="env") for _ in range(2)], autoreset_mode="SameStep"
    )
    try:
        o1, _ = ref.reset(seed=1)
        o2, _ = vec.reset(seed=1)
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
        rng = np.random.default_rng(0)
        n_done = 0
        for _ in range(60):
            a = rng.uniform(-1, 1, (2, 1))
            o1, _, t1, u1, i1 = ref.step(a)
            o2, _, _, _, i2 = vec.step(a)
            np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
            _assert_same_smo(i1, i2)
            for i in np.flatnonzero(t1 | u1):
                n_done += 1
                np.testing.assert_allclose(i2["final_obs"][i], i1["final_obs"][i], rtol=0, atol=1e-12)
            if (t1 | u1).any():
                _assert_same_smo(i1["final_info"], i2["final_info"])
        assert n_done >= 3
    finally:
        vec.close()


# ---- in-process: the environments measured together ---------------------------------------------------------------
def test_masked_resets_keep_the_last_samples_of_the_other_environments():
    """Autoreset mode "disabled": after ``reset(options={"reset_mask": m})`` the rows of ``infos["smo"]`` where ``m``
    are the reset's samples, as per-environment wrappers give them; the other rows are those environments' last
    samples (which the batch measured), also after a second masked reset in a row."""
    from gymnasium.vector import SyncVectorEnv

    ref = SyncVectorEnv(
        [lambda: EstimatedVelocity(gym.make(ENV), rate="env") for _ in range(N)], autoreset_mode="Disabled"
    )
    vec = VectorEstimatedVelocity(
        SyncVectorEnv([lambda: gym.make(ENV) for _ in range(N)], autoreset_mode="Disabled"),
        "encoder-12bit-noisy",
        "auto",
    )
    ref.reset(seed=2)
    vec.reset(seed=2)
    rng = np.random.default_rng(4)
    for _ in range(3):
        a = rng.uniform(-1, 1, (N, 1))
        ref.step(a)
        *_, infos = vec.step(a)
    expected = {key: infos["smo"][key].copy() for key in SMO_KEYS}  # each environment's last sample
    for mask in (np.array([True, False, False]), np.array([False, True, False])):
        o1, i1 = ref.reset(options={"reset_mask": mask})
        o2, i2 = vec.reset(options={"reset_mask": mask})
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
        for key in SMO_KEYS:
            expected[key][mask] = i1["smo"][key][mask]
            np.testing.assert_allclose(i2["smo"][key], expected[key], rtol=0, atol=1e-12)
    a = rng.uniform(-1, 1, (N, 1))
    o1, *_ = ref.step(a)
    o2, *_ = vec.step(a)
    np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)


def test_free_joint_environments_measured_together_equal_per_env_wrappers():
    """Ant's free joint: the batch advances every environment's tangent coordinates (unit quaternions) in its row."""
    from gymnasium.vector import SyncVectorEnv

    env_id = "Ant-v5"
    ref = SyncVectorEnv([lambda: EstimatedVelocity(gym.make(env_id), rate="env") for _ in range(2)])
    vec = VectorEstimatedVelocity(
        SyncVectorEnv([lambda: gym.make(env_id) for _ in range(2)]), "encoder-12bit-noisy", "auto"
    )
    o1, _ = ref.reset(seed=3)
    o2, _ = vec.reset(seed=3)
    np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
    assert isinstance(vec._batch, MeasurementBatch) and vec._batch.previous.shape == (2, 15)
    assert isinstance(vec._together, BatchedSensing)  # the tangent arithmetic inside the one-call step too
    rng = np.random.default_rng(5)
    for _ in range(40):
        a = rng.uniform(-1, 1, (2, 8))
        o1, r1, t1, u1, i1 = ref.step(a)
        o2, r2, t2, u2, i2 = vec.step(a)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(t1 | u1, t2 | u2)
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
        _assert_same_smo(i1, i2)


@pytest.mark.parametrize("api", ["sb3", "gymnasium"])
def test_measurements_that_cannot_share_a_batch_go_the_way_of_a_worker(api, monkeypatch):
    """In-process environments whose measurements cannot share a batch (other joint tables, observations that are not
    a Box; simulated here) are measured by each JointSensor and observed through the vector env's method call, as
    across a process boundary: the same numbers as per-environment wrappers."""
    from gymnasium.vector import SyncVectorEnv

    monkeypatch.setattr(MeasurementBatch, "supports", staticmethod(lambda measurements: False))
    rng = np.random.default_rng(6)
    if api == "sb3":
        ref, vec = _pair(n=2, seed=2)
        np.testing.assert_allclose(vec.reset(), ref.reset(), rtol=0, atol=1e-12)
    else:
        ref = SyncVectorEnv([lambda: EstimatedVelocity(gym.make(ENV), rate="env") for _ in range(2)])
        vec = VectorEstimatedVelocity(SyncVectorEnv([lambda: gym.make(ENV) for _ in range(2)]), "encoder-12bit-noisy")
        np.testing.assert_allclose(vec.reset(seed=2)[0], ref.reset(seed=2)[0], rtol=0, atol=1e-12)
    assert vec._local is None and vec._batch is None
    for _ in range(60):
        a = rng.uniform(-1, 1, (2, 1))
        np.testing.assert_allclose(vec.step(a)[0], ref.step(a)[0], rtol=0, atol=1e-12)


def test_a_non_finite_measurement_in_the_batch_names_the_environment():
    """A sensor model that overflows (gross errors of 1e308 standard deviations) is caught in the batched call."""
    sensor = sensors.Outliers(probability=1.0, scale=1e308)
    vec = VecEstimatedVelocity(DummyVecEnv([lambda: gym.make(ENV) for _ in range(2)]), sensor, "super-twisting")
    vec.seed(0)
    vec.reset()
    assert isinstance(vec._batch, MeasurementBatch)
    with pytest.raises(ValueError, match=r"finite measurement.*of environment [01]"):
        for _ in range(10):
            vec.step(np.zeros((2, 1)))


@pytest.mark.parametrize("api", ["sb3", "gymnasium"])
def test_a_diverging_batched_observer_is_a_typed_error_and_keeps_its_state(api):
    """The one-call step checks the observer's new state as ``Observer.update`` does: a high-gain observer started
    at 1e307 overflows, the error names the channel and environment, the observer keeps the state it had."""
    from gymnasium.vector import SyncVectorEnv

    make = [lambda: gym.make(ENV) for _ in range(2)]
    if api == "sb3":
        vec = VecEstimatedVelocity(DummyVecEnv(make), "ideal", "high-gain")
        vec.seed(0)
        vec.reset()
    else:
        vec = VectorEstimatedVelocity(SyncVectorEnv(make), "ideal", "high-gain")
        vec.reset(seed=0)
    assert isinstance(vec._together, BatchedSensing)
    vec.observer.reset(np.full(vec.observer.shape, 1e307))
    before = vec.observer.state.copy()
    with pytest.raises(DivergenceError, match=r"channel 0 of batch element \(0,\)"):
        vec.step(np.zeros((2, 1)))
    np.testing.assert_array_equal(vec.observer.state, before)


def test_an_observer_without_a_compiled_step_takes_the_general_path():
    """A subclass of a family is a family of its own, whose Python may differ from the compiled step: the vector step
    measures, updates and observes in three moves, with the per-environment wrappers' numbers."""
    dt = gym.make(ENV).unwrapped.dt
    ref = DummyVecEnv(
        [lambda: EstimatedVelocity(gym.make(ENV), rate="env", observer=UnregisteredFiniteDifference(dt=dt))] * 2
    )
    vec = VecEstimatedVelocity(
        DummyVecEnv([lambda: gym.make(ENV)] * 2), "encoder-12bit-noisy", UnregisteredFiniteDifference(dt=dt)
    )
    ref.seed(4)
    vec.seed(4)
    np.testing.assert_allclose(vec.reset(), ref.reset(), rtol=0, atol=1e-12)
    assert vec._together is None and isinstance(vec._batch, MeasurementBatch)
    rng = np.random.default_rng(1)
    for _ in range(30):
        a = rng.uniform(-1, 1, (2, 1))
        np.testing.assert_allclose(vec.step(a)[0], ref.step(a)[0], rtol=0, atol=1e-12)


def test_batched_sensing_is_the_measurement_then_the_update_bit_for_bit():
    """The one-call step against its three moves on twin vector envs (same seeds): ``measure_live``, the observer's
    ``update`` and ``velocity_of``; equal to the last bit, with the clipped selection of Hopper's observations."""
    twins = []
    for _ in range(2):
        vec = VecEstimatedVelocity(DummyVecEnv([lambda: gym.make("Hopper-v5")] * 3), "encoder-12bit-noisy", "auto")
        vec.seed(8)
        vec.reset()
        twins.append(vec)
    together = twins[0]._together
    batch, estimator = twins[1]._batch, twins[1].estimator
    index, low, high = twins[1]._selection()
    rng = np.random.default_rng(2)
    for _ in range(40):
        a = rng.uniform(-1, 1, (3, 3))
        datas = []
        for vec in twins:
            for env, action in zip(vec.venv.envs, a, strict=True):
                env.step(action)
            datas.append([env.unwrapped.data for env in vec.venv.envs])
        block, obs = together.step(datas[0])
        reference = batch.measure_live(datas[1])
        velocity = estimator.update(np.ascontiguousarray(reference[:, batch.slices[5]]))
        reference[:, batch.slices[2]] = velocity
        x = np.concatenate((reference[:, batch.slices[3]], velocity), axis=1)
        np.testing.assert_array_equal(block, reference)
        np.testing.assert_array_equal(obs, np.clip(x[:, index], low, high))
        np.testing.assert_array_equal(twins[0].observer.estimate, twins[1].observer.estimate)


def test_sub_environments_sampled_at_different_steps_are_refused():
    """One batched observer runs at one sampling step: sub-environments of different ``frame_skip`` are refused
    (the second one's velocities came out twice too large, silently, with the first one's step)."""
    from gymnasium.vector import SyncVectorEnv

    def make(frame_skip):
        return lambda: gym.make("HalfCheetah-v5", frame_skip=frame_skip)

    with pytest.raises(ValueError, match=r"same sensing and sample step .* sample steps \[0.04, 0.08\]"):
        VectorEstimatedVelocity(SyncVectorEnv([make(4), make(8)]), sensor="ideal", observer="finite-difference")
    with pytest.raises(ValueError, match="same sensing and sample step"):
        VecEstimatedVelocity(DummyVecEnv([make(4), make(8)]), sensor="ideal", observer="finite-difference")
