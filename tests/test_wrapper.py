"""EstimatedVelocity on every Gymnasium MuJoCo v5 environment, and the sensing core under it.

Accuracy claims tested (ideal sensor, ``rate="physics"``, against the backward difference run on the same
measurements in a twin environment with the same seed and actions):

- the implicit super-twisting differentiator, inside its sliding set, *is* a backward difference of its own
  estimate (``SuperTwisting`` notes): on the median sample its error is the backward difference's (within 5 %;
  measured equal but on the Euler environments, where both are at round-off); outside it (impacts where
  ``|q''|`` exceeds the calibrated bound) it needs a few samples to re-enter, which costs RMS error up to a tenth
  of the velocity RMS (measured 0.05 against 0.77 on Pusher's joint-limit hits, 0 elsewhere);
- the default, ``auto``, is never less accurate than the backward difference, on the median sample and in RMS
  (measured 0.03-0.72 times its RMS error, equal on the Euler environments where the backward difference is exact:
  ``q_{k+1} = q_k + h v_{k+1}``).
"""

from __future__ import annotations

import copy
import pickle
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from conftest import full_forward_observation, smooth_actions

from smo_gym import _cache, observers, sensors
from smo_gym.engine import measurement
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers import estimated_velocity as ev_module

ENVS = [
    "InvertedPendulum-v5",
    "InvertedDoublePendulum-v5",
    "Reacher-v5",
    "Pusher-v5",
    "Swimmer-v5",
    "Hopper-v5",
    "HalfCheetah-v5",
    "Walker2d-v5",
    "Ant-v5",
    "Humanoid-v5",
    "HumanoidStandup-v5",
]


pytestmark = pytest.mark.usefixtures("private_calibration_cache")


def rollout(env, actions, seed, *, until_done=True):
    """Run ``actions``; with ``until_done=False`` reset (unseeded) at episode ends and keep going."""
    obs, info = env.reset(seed=seed)
    out = {"obs": [obs], "reward": [], "terminated": [], "smo": [info.get("smo")], "since_reset": [0]}
    k = 0
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        k += 1
        out["obs"].append(obs)
        out["reward"].append(r)
        out["terminated"].append(term)
        out["smo"].append(info.get("smo"))
        out["since_reset"].append(k)
        if term or trunc:
            if until_done:
                break
            obs, info = env.reset()
            k = 0
    return out


@pytest.mark.parametrize("env_id", ENVS)
def test_every_v5_env(env_id):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    raw = gym.make(env_id)
    wrapped = EstimatedVelocity(gym.make(env_id))  # default: noisy 12-bit encoder, auto, physics
    assert wrapped.observation_space == raw.observation_space
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(wrapped, skip_render_check=True)
        sb3_check_env(wrapped, warn=False)

    steps = 200
    actions = smooth_actions(raw.action_space, steps, seed=1)
    ref = rollout(raw, actions, seed=5, until_done=False)
    runs = {
        observer: rollout(
            EstimatedVelocity(gym.make(env_id), sensor="ideal", observer=observer, rate="physics"),
            actions,
            seed=5,
            until_done=False,
        )
        for observer in ("auto", "super-twisting", "finite-difference")
    }
    sta = runs["super-twisting"]
    # stepping the physics ourselves (to sample inside frame_skip) changes nothing of the simulation
    for run in runs.values():
        assert run["reward"] == ref["reward"] and run["terminated"] == ref["terminated"]
    assert all(wrapped.observation_space.contains(o) for o in runs["auto"]["obs"])
    assert len(sta["reward"]) == steps
    # the observers start at zero velocity: skip 3 control periods after every reset (convergence)
    keep = np.array(sta["since_reset"]) > 3
    true = np.array([s["qvel"] for s in sta["smo"]])[keep]
    errors = {}
    for observer, run in runs.items():
        np.testing.assert_array_equal(np.array([s["qvel"] for s in run["smo"]])[keep], true)
        errors[observer] = np.array([s["qvel_estimate"] for s in run["smo"]])[keep] - true
    scale = np.sqrt(np.mean(true**2))
    median = {k: np.median(np.abs(e).max(axis=1)) for k, e in errors.items()}
    rms = {k: np.sqrt(np.mean(e**2)) for k, e in errors.items()}
    fd = "finite-difference"
    assert median["super-twisting"] <= 1.05 * median[fd] + 1e-9 * scale, (median, scale)
    assert rms["super-twisting"] <= rms[fd] + 0.1 * scale, (rms, scale)
    assert median["auto"] <= median[fd] + 1e-9 * scale, (median, scale)
    assert rms["auto"] <= rms[fd] + 1e-9 * scale, (rms, scale)
    # with the ideal sensor the measured configuration is the true one
    np.testing.assert_allclose(sta["smo"][-1]["qpos_measured"], sta["smo"][-1]["qpos"], atol=1e-12)


def test_euler_envs_estimate_exactly():
    """HalfCheetah integrates with Euler: the backward difference is exact, so are the default (auto, which
    chooses it) and the sliding super-twisting."""
    for observer in ("auto", "super-twisting"):
        env = EstimatedVelocity(gym.make("HalfCheetah-v5"), sensor="ideal", observer=observer, rate="physics")
        assert env.adapter.model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
        res = rollout(env, smooth_actions(env.action_space, 50, 0), seed=0)
        for s in res["smo"][1:]:  # every step, the first included (at the reset the velocity is not measured)
            np.testing.assert_allclose(s["qvel_estimate"], s["qvel"], atol=1e-9 * (1 + np.abs(s["qvel"]).max()))
        assert np.abs(res["smo"][-1]["qvel"]).max() > 0.1  # and the joints moved


def test_observation_is_built_from_measurements_and_estimates():
    env = EstimatedVelocity(gym.make("Hopper-v5"), sensor="encoder-12bit-noisy")
    obs, info = env.reset(seed=0)
    for a in smooth_actions(env.action_space, 10, 0):
        obs, *_, info = env.step(a)
    s = info["smo"]
    # Hopper: obs = (qpos[1:], clip(qvel, -10, 10)), here from the sensed state only
    np.testing.assert_array_equal(obs[:5], s["qpos_measured"][1:])
    np.testing.assert_array_equal(obs[5:], np.clip(s["qvel_estimate"], -10, 10))
    assert not np.allclose(s["qpos_measured"], s["qpos"])  # the sensor did something
    assert not np.allclose(s["qvel_estimate"], s["qvel"])  # and the estimate is not the true velocity
    res = 2 * np.pi / 4096
    assert np.max(np.abs(s["qpos_measured"] - s["qpos"])) < 6e-3 + res
    # the velocities are estimated from those measurements (an estimate equal to the true velocity passes the
    # checks above): the backward difference's are the measured positions' differences over the step
    fd = EstimatedVelocity(
        gym.make("Hopper-v5"), sensor="encoder-12bit-noisy", observer="finite-difference", rate="env"
    )
    _, info = fd.reset(seed=0)
    for a in smooth_actions(fd.action_space, 10, 0):
        previous = info["smo"]["qpos_measured"]
        obs, *_, info = fd.step(a)
        s = info["smo"]
        np.testing.assert_allclose(s["qvel_estimate"], (s["qpos_measured"] - previous) / fd.unwrapped.dt, rtol=1e-12)
        np.testing.assert_array_equal(obs[5:], np.clip(s["qvel_estimate"], -10, 10))
        assert np.abs(s["qvel_estimate"] - s["qvel"]).max() > 1e-3


@pytest.mark.parametrize("env_id", ENVS)
def test_scratch_observation_equals_a_full_forward_pass(env_id):
    """At run-time inputs (actions far from the zero ``ctrl`` of construction time) and at states with active
    joint limits, the adapter's cheapest probed evaluation (pipeline, copied inputs, contact forces) gives the
    full forward pass's observation. Humanoid's ``qfrc_actuator`` reads ``ctrl`` only through the actuation
    (MuJoCo zeroes a NaN ``ctrl``, so a NaN probe alone misses it), InvertedDoublePendulum's constraint force
    reads it only while its rail limit is active."""
    env = EstimatedVelocity(gym.make(env_id), observer="finite-difference")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    model = env.adapter.model
    for _ in range(3):
        env.step(rng.uniform(env.action_space.low, env.action_space.high))
    live = env.adapter.data
    assert np.any(live.ctrl != 0)
    limited = np.flatnonzero(model.jnt_limited.astype(bool) & (model.jnt_type >= 2))  # slide and hinge joints
    for k in range(4):
        qpos = np.array(live.qpos)
        mujoco.mj_integratePos(model, qpos, 0.05 * rng.standard_normal(model.nv), 1.0)
        if k % 2 and limited.size:  # beyond the limits: the constraint solver has active limit rows
            adr = model.jnt_qposadr[limited]
            low, high = model.jnt_range[limited].T
            margin = 0.05 * (high - low)
            qpos[adr] = np.where(rng.random(limited.size) < 0.5, low - margin, high + margin)
        qvel = np.array(live.qvel) + rng.standard_normal(model.nv)
        want = full_forward_observation(env, qpos, qvel)
        np.testing.assert_array_equal(env.adapter.observation(qpos, qvel), want)


@pytest.mark.parametrize(
    "env_id, contact_forces",
    [
        ("Humanoid-v5", "estimated"),
        ("Humanoid-v5", "sensor"),
        ("Ant-v5", "estimated"),
        ("Ant-v5", "sensor"),
        ("InvertedDoublePendulum-v5", "sensor"),
        ("Pusher-v5", "sensor"),
    ],
)
def test_no_leakage_of_true_velocity(env_id, contact_forces):
    """Changing the true velocity (and everything mj_forward derives from it) with the measurements and estimates
    fixed changes no observation entry, except the contact forces taken from 'sensors' in that mode (only Ant's
    and Humanoid's observations have contact forces; other modes are refused elsewhere)."""
    env = EstimatedVelocity(gym.make(env_id), contact_forces=contact_forces)
    env.reset(seed=0)
    for a in smooth_actions(env.action_space, 5, 0):
        env.step(a)
    q_meas = env.measurement.measured_qpos().copy()
    v_hat = env.estimator.velocity.copy()
    before = env.adapter.observation(q_meas, v_hat)
    live = env.adapter.data
    own_before = env.unwrapped._get_obs()
    live.qvel[:] += 3.0
    mujoco.mj_forward(env.adapter.model, live)
    mujoco.mj_rnePostConstraint(env.adapter.model, live)
    own_after = env.unwrapped._get_obs()
    after = env.adapter.observation(q_meas, v_hat)
    changed = np.flatnonzero(before != after)
    if contact_forces == "estimated":
        assert changed.size == 0
    else:
        # only cfrc_ext entries may change: they sit at the end of Ant's and Humanoid's observations
        n_cfrc = 6 * (env.adapter.model.nbody - 1) if env_id.startswith(("Ant", "Humanoid")) else 0
        assert np.all(changed >= before.size - n_cfrc)
    # the test can fail: the environment's own observation does depend on the true velocity
    assert not np.array_equal(own_before, own_after)


def test_same_seed_same_observations_and_different_seeds_differ():
    actions = smooth_actions(gym.make("Hopper-v5").action_space, 30, 0)
    a = rollout(EstimatedVelocity(gym.make("Hopper-v5"), sensor="low-cost"), actions, seed=3)
    b = rollout(EstimatedVelocity(gym.make("Hopper-v5"), sensor="low-cost"), actions, seed=3)
    c = rollout(EstimatedVelocity(gym.make("Hopper-v5"), sensor="low-cost"), actions, seed=4)
    assert all(np.array_equal(x, y) for x, y in zip(a["obs"], b["obs"], strict=True))
    assert not np.array_equal(a["obs"][-1], c["obs"][-1])


def _noise(info_smo, i):
    return info_smo["qpos_measured"][i] - info_smo["qpos"][i]


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_env_gives_each_env_its_own_noise(mode):
    envs = gym.make_vec(
        "Hopper-v5",
        num_envs=2,
        vectorization_mode=mode,
        wrappers=[lambda e: EstimatedVelocity(e, sensor="encoder-12bit-noisy")],
    )
    alone = [EstimatedVelocity(gym.make("Hopper-v5"), sensor="encoder-12bit-noisy") for _ in range(2)]
    try:  # environment i is seeded seed + i: its measurements are those of a wrapper of its own with that seed
        obs, info = envs.reset(seed=0)
        for i, env in enumerate(alone):
            env.reset(seed=i)
        actions = np.random.default_rng(0).uniform(-1, 1, (5, 2, 3))
        for action in actions:
            obs, _r, _term, _trunc, info = envs.step(action)
            for i, env in enumerate(alone):
                own, *_, own_info = env.step(action[i])
                np.testing.assert_array_equal(info["smo"]["qpos_measured"][i], own_info["smo"]["qpos_measured"])
                np.testing.assert_array_equal(obs[i], own)
        assert obs.shape == (2,) + gym.make("Hopper-v5").observation_space.shape
    finally:
        envs.close()
    # additive noise alone does not depend on the state: two environments sharing one stream would see the same
    envs = gym.make_vec("Hopper-v5", num_envs=2, vectorization_mode=mode,
                        wrappers=[lambda e: EstimatedVelocity(e, sensor=sensors.GaussianNoise(1e-3))])  # fmt: skip
    try:
        envs.reset(seed=0)
        _obs, _r, _term, _trunc, info = envs.step(np.zeros((2, 3)))
        e0, e1 = _noise(info["smo"], 0), _noise(info["smo"], 1)
        assert np.all(e0 != 0) and np.all(e1 != 0) and np.all(np.abs(e0 - e1) > 1e-9)
    finally:
        envs.close()


def test_sb3_subproc_vec_env():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    venv = SubprocVecEnv([lambda: EstimatedVelocity(gym.make("InvertedPendulum-v5")) for _ in range(2)])
    try:
        venv.seed(0)
        venv.reset()
        for _ in range(5):
            obs, _rewards, _dones, infos = venv.step(np.zeros((2, 1), dtype=np.float32))
        assert obs.shape == (2, 4) and "smo" in infos[0]
    finally:
        venv.close()


def test_pickle_round_trip():
    """Gymnasium's MuJoCo envs pickle by their constructor arguments (EzPickle), so a clone is a fresh env; the
    wrapper's configuration, sensor and observer survive, and a seeded reset reproduces the original."""
    env = EstimatedVelocity(gym.make("Ant-v5"), sensor="low-cost")
    actions = smooth_actions(env.action_space, 10, 0)
    env.reset(seed=0)
    for a in actions[:5]:
        env.step(a)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.adapter.env is clone.unwrapped and clone.sensor == env.sensor
    assert env.spec.additional_wrappers[-1].kwargs["sensor"] == "low-cost"  # recorded constructor arguments
    o1, _ = env.reset(seed=1)
    o2, _ = clone.reset(seed=1)
    np.testing.assert_array_equal(o1, o2)
    for a in actions[5:]:
        o1, *_ = env.step(a)
        o2, *_ = clone.step(a)
        np.testing.assert_array_equal(o1, o2)


def test_a_copy_mid_episode_needs_a_reset_unless_its_simulation_came_with_it():
    """A copy of Gymnasium's MuJoCo env is a fresh simulation (EzPickle), which the copied sensor and observer do
    not describe: stepping it would estimate a jump that never happened, so it asks for a reset. Where the copy's
    simulation is the original's (here: no reset noise, a copy right after the reset) it goes on as the original."""
    env = EstimatedVelocity(gym.make("Hopper-v5"), sensor="ideal")
    env.reset(seed=0)
    env.step(np.full(3, 0.5))
    for clone in (copy.deepcopy(env), pickle.loads(pickle.dumps(env))):
        with pytest.raises(RuntimeError, match=r"expected reset.*rebuilt from its constructor"):
            clone.step(np.zeros(3))
        np.testing.assert_array_equal(clone.reset(seed=3)[0], env.reset(seed=3)[0])
        np.testing.assert_array_equal(clone.step(np.full(3, 0.5))[0], env.step(np.full(3, 0.5))[0])
    still = EstimatedVelocity(gym.make("Hopper-v5", reset_noise_scale=0.0))
    still.reset(seed=0)
    twin = pickle.loads(pickle.dumps(still))
    for action in (np.full(3, 0.5), np.full(3, -0.5)):
        np.testing.assert_array_equal(twin.step(action)[0], still.step(action)[0])


def test_rates_set_the_sampling_step():
    base = gym.make("Hopper-v5")
    h, fs = base.unwrapped.model.opt.timestep, base.unwrapped.frame_skip
    assert EstimatedVelocity(gym.make("Hopper-v5"), rate="physics").observer.dt == pytest.approx(h)
    assert EstimatedVelocity(gym.make("Hopper-v5"), rate="env").observer.dt == pytest.approx(h * fs)
    env = EstimatedVelocity(gym.make("Hopper-v5"), rate=2, sensor="ideal")
    assert env.observer.dt == pytest.approx(2 * h)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    assert env.observer.n_updates == fs // 2


def test_free_joint_tangent_coordinates_differentiate_to_qvel():
    """z from consecutive quaternions: (z_k - z_{k-1}) / h equals the body angular velocity that produced them."""
    model = gym.make("Ant-v5").unwrapped.model
    tc = measurement.TangentCoordinates(model)
    rng = np.random.default_rng(0)
    q = model.qpos0.copy()
    z_prev = tc.reset(q)
    h = 1e-3
    for _ in range(20):
        v = rng.normal(size=model.nv)
        mujoco.mj_integratePos(model, q, v, h)
        z = tc(q)
        np.testing.assert_allclose((z - z_prev) / h, v, rtol=1e-7, atol=1e-7)
        z_prev = z
    # noise on the manifold keeps unit quaternions
    m = measurement.JointMeasurement(model, "encoder-12bit-noisy", h)
    qm = m.reset(q, np.random.default_rng(1))
    assert np.isclose(np.linalg.norm(qm[3:7]), 1.0) and not np.allclose(qm[3:7], q[3:7])


def test_filtered_positions_and_gain_override():
    env = EstimatedVelocity(
        gym.make("Hopper-v5"), observer="super-twisting", positions="filtered", observer_kwargs={"lipschitz": 123.0}
    )
    assert env.observer.lipschitz == 123.0
    obs, _ = env.reset(seed=0)
    for a in smooth_actions(env.action_space, 5, 0):
        obs, *_ = env.step(a)
    np.testing.assert_allclose(obs[:5], env.estimator.filtered[1:])
    for name in observers.OBSERVERS:
        EstimatedVelocity(gym.make("InvertedPendulum-v5"), observer=name).reset(seed=0)


def test_calibration_is_cached_in_memory_and_on_disk(monkeypatch):
    first = EstimatedVelocity(gym.make("Swimmer-v5"), calibration_steps=1500).calibration

    def fail(*args, **kwargs):
        raise AssertionError("calibrated again instead of using the cache")

    monkeypatch.setattr(ev_module, "rollout_velocities", fail)
    monkeypatch.setattr(ev_module, "model_rollout_velocities", fail)
    for memory in (_cache._MEMORY_CACHE, {}):  # from memory, then from disk
        monkeypatch.setattr(_cache, "_MEMORY_CACHE", memory)
        again = EstimatedVelocity(gym.make("Swimmer-v5"), calibration_steps=1500).calibration
        np.testing.assert_array_equal(again.bound(2), first.bound(2))
        np.testing.assert_array_equal(again.rms(2), first.rms(2))


def test_bad_inputs():
    with pytest.raises(TypeError, match=r"MuJoCo.*CartPoleEnv has no model"):
        EstimatedVelocity(gym.make("CartPole-v1"))
    with pytest.raises(ValueError, match=r"encoder-12bit.*low-cost.*actual value: 'fancy'"):
        EstimatedVelocity(gym.make("Hopper-v5"), sensor="fancy")
    with pytest.raises(ValueError, match=r"super-twisting.*actual value: 'magic'"):
        EstimatedVelocity(gym.make("Hopper-v5"), observer="magic")
    with pytest.raises(ValueError, match="divisor of frame_skip=4"):
        EstimatedVelocity(gym.make("Hopper-v5"), rate=3)
    with pytest.raises(ValueError, match="'physics', 'env'"):
        EstimatedVelocity(gym.make("Hopper-v5"), rate="fast")
    with pytest.raises(TypeError, match="rate"):
        EstimatedVelocity(gym.make("Hopper-v5"), rate=2.0)
    with pytest.raises(ValueError, match="contact_forces"):
        EstimatedVelocity(gym.make("Ant-v5"), contact_forces="magic")
    with pytest.raises(ValueError, match="dt equal to the sampling step"):
        EstimatedVelocity(gym.make("Hopper-v5"), observer=observers.FiniteDifference(dt=0.1))
    # a sensor model that overflows: the NaN/inf never reaches an observation (with observer="auto" the sensor
    # already fails on the calibration's trials, at construction)
    overflowing = sensors.GaussianNoise(1e308) | sensors.GaussianNoise(1e308)
    with pytest.raises(ValueError, match="finite measurement"):
        env = EstimatedVelocity(gym.make("Hopper-v5"), sensor=overflowing)
    env = EstimatedVelocity(gym.make("Hopper-v5"), sensor=overflowing, observer="super-twisting")
    with pytest.raises(ValueError, match="finite measurement"):
        env.reset(seed=0)
        for _ in range(20):
            env.step(env.action_space.sample())


BALL_XML = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <body name="bob" pos="0 0 1">
      <joint name="ball" type="ball" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0.3 0.1 -0.5" size="0.04" mass="1"/>
    </body>
    <body name="cart" pos="0 0 0">
      <joint name="slide" type="slide" axis="1 0 0" damping="0.1"/>
      <geom type="box" size="0.1 0.1 0.1" mass="1"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="slide" gear="1" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""


def _ball_env(tmp_path):
    """A user MujocoEnv subclass with a ball joint (nq = 5, nv = 4) and no registered spec."""
    from gymnasium.envs.mujoco import MujocoEnv

    path = tmp_path / "ball.xml"
    path.write_text(BALL_XML)

    class BallCart(MujocoEnv):
        metadata = {"render_modes": ["rgb_array"], "render_fps": 100}

        def __init__(self):
            space = gym.spaces.Box(-np.inf, np.inf, shape=(9,), dtype=np.float64)
            super().__init__(str(path), 5, observation_space=space)

        def _get_obs(self):
            return np.concatenate([self.data.qpos, self.data.qvel])

        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self):
            qvel = self.init_qvel + self.np_random.normal(0, 2.0, self.model.nv)
            self.set_state(self.init_qpos, qvel)
            return self._get_obs()

    return BallCart()


def test_user_mujoco_env_with_a_ball_joint(tmp_path):
    results = {}
    for name in ("super-twisting", "finite-difference"):
        env = EstimatedVelocity(_ball_env(tmp_path), sensor="ideal", observer=name, disk_cache=False)
        assert env.adapter.model.nq == 5 and env.adapter.model.nv == 4
        results[name] = rollout(env, [np.array([0.5])] * 150, seed=0)
    # skip 0.5 s: from the zero initial estimate against reset velocities ~ N(0, 2), the super-twisting error
    # reaches its sliding set after about |e0| / (k2 - |a|) <= 2 / (1.1 L - 0.5 L) < 0.4 s with the calibrated L
    skip = 50
    true = np.array([s["qvel"] for s in results["finite-difference"]["smo"][skip:]])
    est = {k: np.array([s["qvel_estimate"] for s in r["smo"][skip:]]) for k, r in results.items()}
    # the swinging ball joint's angular velocity (local frame, like qvel) is estimated through the quaternion
    err_fd = np.sqrt(np.mean((est["finite-difference"] - true) ** 2))
    err_sta = np.sqrt(np.mean((est["super-twisting"] - true) ** 2))
    scale = np.sqrt(np.mean(true[:, :3] ** 2))
    assert scale > 0.3  # the ball joint does swing
    assert err_fd < 0.02 * scale and err_sta <= 1.5 * err_fd + 1e-9
    noisy = EstimatedVelocity(_ball_env(tmp_path), sensor="encoder-12bit-noisy", disk_cache=False)
    _obs, info = noisy.reset(seed=0)
    q = info["smo"]["qpos_measured"]
    assert np.isclose(np.linalg.norm(q[:4]), 1.0) and not np.allclose(q, info["smo"]["qpos"])


def test_a_copied_wrapper_steps_the_model_of_its_own_environment():
    """``copy.deepcopy`` rebuilds a Gymnasium MuJoCo environment with a new model; the copy's physics-rate sampling
    must step that model (an edit of it, a payload or a fault, reaches the copy's physics), not the original's."""
    import copy

    env = EstimatedVelocity(gym.make("InvertedPendulum-v5"), observer="finite-difference", disk_cache=False)
    twin = copy.deepcopy(env)
    assert twin.get_wrapper_attr("adapter").model is twin.unwrapped.model
    twin.unwrapped.model.body_mass[:] *= 10.0  # a heavier pole in the copy only
    qpos = []
    for e in (env, twin):
        e.reset(seed=3)
        for _ in range(20):
            e.step(np.array([1.0]))
        qpos.append(e.unwrapped.data.qpos.copy())
    assert not np.allclose(qpos[0], qpos[1])


def test_observer_specs_are_the_name_with_its_options():
    """``observer="kalman-imm:huber=3"`` is ``observer="kalman-imm", observer_kwargs={"huber": 3}`` (the same
    observations, bit for bit); given ``observer_kwargs`` win over the spec's; a model-based spec is refused by the
    vector wrappers as its name is, and an unknown option is a ValueError naming the valid ones."""
    from smo_gym.wrappers.vec import VectorEstimatedVelocity

    spec = EstimatedVelocity(gym.make("Hopper-v5"), observer="kalman-imm:huber=3", disk_cache=False)
    named = EstimatedVelocity(
        gym.make("Hopper-v5"), observer="kalman-imm", observer_kwargs={"huber": 3}, disk_cache=False
    )
    assert spec.observer.huber == 3.0
    np.testing.assert_array_equal(spec.reset(seed=0)[0], named.reset(seed=0)[0])
    for action in smooth_actions(spec.action_space, 5, seed=0):
        np.testing.assert_array_equal(spec.step(action)[0], named.step(action)[0])
    given = EstimatedVelocity(
        gym.make("Hopper-v5"), observer="kalman-ca:huber=1.0", observer_kwargs={"huber": 2.0}, disk_cache=False
    )
    assert given.observer.huber == 2.0
    with pytest.raises(ValueError, match="options of observer 'kalman-ca' in"):
        EstimatedVelocity(gym.make("Hopper-v5"), observer="kalman-ca:bogus=1", disk_cache=False)
    with pytest.raises(ValueError, match="expected a model-free observer for a vector wrapper"):
        VectorEstimatedVelocity(
            gym.make_vec("Hopper-v5", 2, vectorization_mode="sync"), observer="kalman-ca-input:huber=3"
        )


@pytest.mark.parametrize("rate", ["env", "physics"])
def test_a_timestep_edited_after_wrapping_is_refused_at_reset(rate):
    """The sampling step and the observer's gains are made for the model's timestep at construction: an edit after
    it (domain randomization of the timestep) is refused at the next reset, where it went unnoticed (finite
    differences then came out twice the true velocity with a doubled timestep)."""
    env = EstimatedVelocity(gym.make("HalfCheetah-v5"), rate=rate, observer="finite-difference", disk_cache=False)
    env.reset(seed=0)
    env.unwrapped.model.opt.timestep *= 2
    with pytest.raises(ValueError, match=r"expected the model's opt.timestep 0.01 .* actual value: 0.02; edit"):
        env.reset(seed=1)
    env.unwrapped.model.opt.timestep /= 2
    env.reset(seed=1)
    edited = gym.make("HalfCheetah-v5")
    edited.unwrapped.model.opt.timestep = 0.02  # edited before wrapping: the wrapper's step follows
    wrapped = EstimatedVelocity(edited, rate=rate, observer="finite-difference", disk_cache=False)
    assert wrapped.sample_dt == (0.02 if rate == "physics" else 0.1)
    # a copy rebuilds the environment from its constructor, with the XML's timestep: refused, not run at the
    # wrapper's step (velocities came out twice the true ones at the physics rate)
    copied = copy.deepcopy(wrapped)
    assert copied.unwrapped.model.opt.timestep == 0.01
    with pytest.raises(ValueError, match="again in a copy of the wrapper"):
        copied.reset(seed=0)
    copied.unwrapped.model.opt.timestep = 0.02
    copied.reset(seed=0)


def test_physics_steps_other_than_the_sampling_assumes_are_refused_at_the_env_rate():
    """At ``rate="env"`` one sample per step assumes ``frame_skip`` physics steps: a ``frame_skip`` edited after
    wrapping, or a step that simulates twice (an action repeated inside ``step``), is a RuntimeError at the
    episode's first step (finite differences came out twice the true velocity). At the physics rate the samples
    follow the physics steps taken, and the estimate is right."""
    from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
    from gymnasium.vector import SyncVectorEnv

    from smo_gym.wrappers.vec import VectorEstimatedVelocity

    class Repeat(HalfCheetahEnv):
        def step(self, action):
            self.do_simulation(action, self.frame_skip)
            return super().step(action)

    edited = EstimatedVelocity(gym.make("HalfCheetah-v5"), sensor="ideal", observer="finite-difference", rate="env")
    edited.unwrapped.frame_skip = 10
    edited.reset(seed=0)
    with pytest.raises(RuntimeError, match=r"expected 0.05 s of simulated time per sample .* actual value: 0.1 s"):
        edited.step(np.zeros(6))
    repeated = EstimatedVelocity(Repeat(), sensor="ideal", observer="finite-difference", rate="env")
    repeated.reset(seed=0)
    with pytest.raises(RuntimeError, match=r"actual value: 0\.1 s"):
        repeated.step(np.zeros(6))
    physics = EstimatedVelocity(Repeat(), sensor="ideal", observer="finite-difference", rate="physics")
    physics.reset(seed=0)
    for _ in range(3):
        info = physics.step(np.full(6, 0.5))[-1]
    q = info["smo"]
    np.testing.assert_allclose(q["qvel_estimate"], q["qvel"], rtol=0, atol=1e-9)  # Euler: exactly the new qvel
    vector = VectorEstimatedVelocity(
        SyncVectorEnv([lambda: gym.make("HalfCheetah-v5")] * 2), sensor="ideal", observer="finite-difference"
    )
    vector.env.envs[1].unwrapped.frame_skip = 10
    vector.reset(seed=0)
    with pytest.raises(RuntimeError, match=r"actual value: 0\.1 s"):
        vector.step(np.zeros((2, 6)))
