"""The smo_gym environments: registration, package data, Gymnasium's checker, the disturbance input."""

from __future__ import annotations

import importlib.resources
import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import smo_gym.envs
from smo_gym.envs import ENV_IDS

IDS = sorted(ENV_IDS)


@pytest.mark.parametrize("env_id", IDS)
def test_registered_and_passes_check_env(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the checker's advice on unbounded Box spaces and unnormalised actions
        check_env(env.unwrapped, skip_render_check=True)
    obs, _info = env.reset(seed=3)
    assert obs.shape == env.observation_space.shape == (env.unwrapped.model.nq + env.unwrapped.model.nv,)
    obs2, *_ = env.step(env.action_space.sample())
    assert np.all(np.isfinite(obs2))
    assert env.spec.max_episode_steps == 1000
    # the documented time step
    assert env.unwrapped.dt == pytest.approx(0.01)
    env.close()


def test_models_are_package_data():
    root = importlib.resources.files("smo_gym.envs") / "assets"
    for name in ("variable_inertia.xml", "two_link_arm.xml", "furuta_pendulum.xml"):
        assert (root / name).is_file()
    # 'module:id' form registers on demand
    env = gym.make("smo_gym.envs:smo_gym/FurutaPendulum-v0")
    env.reset(seed=0)


def test_disturbance_input_acts_like_a_joint_torque():
    """Action a with no disturbance and action 0 with disturbance a (motor gear 1) give the same trajectory."""
    a = np.array([1.5, -0.7])
    e1 = gym.make("smo_gym/TwoLinkArm-v0").unwrapped
    e2 = gym.make("smo_gym/TwoLinkArm-v0", disturbance=lambda t: a).unwrapped
    o1, _ = e1.reset(seed=5)
    o2, _ = e2.reset(seed=5)
    np.testing.assert_array_equal(o1, o2)
    for _ in range(30):
        o1, *_ = e1.step(a)
        o2, _, _, _, info = e2.step(np.zeros(2))
    np.testing.assert_allclose(o1, o2, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(info["disturbance"], a)
    # a constant disturbance set later adds to it
    e2.unwrapped.set_disturbance([0.1, 0.0])
    *_, info = e2.step(np.zeros(2))
    np.testing.assert_allclose(info["disturbance"], a + [0.1, 0.0])
    with pytest.raises(ValueError, match="shape"):
        e2.unwrapped.set_disturbance([1.0, 2.0, 3.0])
    with pytest.raises(TypeError, match="callable"):
        gym.make("smo_gym/TwoLinkArm-v0", disturbance=3.0)


def test_time_varying_disturbance_uses_physics_time():
    f = lambda t: np.array([0.5 * np.sin(2 * t) + 0.2])
    env = gym.make("smo_gym/FurutaPendulum-v0", disturbance=f).unwrapped
    env.reset(seed=0)
    *_, info = env.step(np.zeros(1))
    # held over the step from its start time t = 0
    np.testing.assert_allclose(info["disturbance"], f(0.0))
    np.testing.assert_allclose(env.data.qfrc_applied, [f(0.0)[0], 0.0])  # matched: only the arm joint
    *_, info = env.step(np.zeros(1))
    np.testing.assert_allclose(info["disturbance"], f(env.dt))


def test_envs_keep_mujoco_env_stepping_for_the_wrapper():
    """The wrapper samples inside frame_skip only through MujocoEnv._step_mujoco_simulation."""
    from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

    for cls in (smo_gym.envs.VariableInertiaEnv, smo_gym.envs.TwoLinkArmEnv, smo_gym.envs.FurutaPendulumEnv):
        assert cls._step_mujoco_simulation is MujocoEnv._step_mujoco_simulation


def test_variable_inertia_reset_respects_the_coupling():
    env = gym.make("smo_gym/VariableInertia-v0").unwrapped
    obs, _ = env.reset(seed=2)
    th, r, thd, rd = obs
    assert r == pytest.approx(0.3 * th**2)
    assert rd == pytest.approx(0.6 * th * thd)
    for _ in range(100):
        obs, *_ = env.step(env.action_space.sample())
    assert obs[1] == pytest.approx(0.3 * obs[0] ** 2, abs=1e-3)


def test_furuta_terminates_when_the_pendulum_falls():
    env = gym.make("smo_gym/FurutaPendulum-v0")
    env.reset(seed=0)
    terminated = False
    for _ in range(500):
        _, reward, terminated, _, _ = env.step(np.array([0.5]))
        if terminated:
            break
    assert terminated and reward == 0.0


def test_import_registers_once():
    smo_gym.envs.register_envs()  # idempotent
    assert all(env_id in gym.registry for env_id in ENV_IDS)


def test_plain_import_registers_the_environments():
    """``import smo_gym`` alone makes ``gymnasium.make("smo_gym/...")`` work, without loading MuJoCo code first."""
    code = (
        "import sys, gymnasium as gym, smo_gym; assert 'smo_gym.envs' not in sys.modules; "
        "env = gym.make('smo_gym/TwoLinkArm-v0'); env.reset(seed=0); print(type(env.unwrapped).__name__)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "MUJOCO_GL": "disable"},
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "TwoLinkArmEnv"


def test_a_simulation_mujoco_reset_ends_the_episode():
    """A disturbance of 1e6 N m made MuJoCo reset the simulation at every step, with only a printed warning: the
    environment returned the reset state, reward 1.0 and terminated False forever (its check, time going back,
    misses a reset early in the step)."""
    env = smo_gym.envs.FurutaPendulumEnv()
    env.set_disturbance(1e6)
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, _, terminated, truncated, info = env.step([0.0])
    assert terminated and not truncated and info["diverged"]
    env.set_disturbance(0.0)
    env.reset(seed=0)
    assert not env.step([0.0])[4]["diverged"]


def test_actions_rewards_and_copies_keep_their_meaning():
    """A finite action of 1e200 gave reward -inf (VariableInertia raised OverflowError after the physics step);
    an action of another shape reached Gymnasium's checker after the disturbance was written; pickling and
    deepcopy lost a set_disturbance; a reset noise of 1e300 put inf in the observation."""
    import copy
    import pickle

    arm = smo_gym.envs.TwoLinkArmEnv()
    arm.reset(seed=0)
    assert np.isfinite(arm.step([1e200, 1e200])[1])
    pendulum = smo_gym.envs.VariableInertiaEnv()
    pendulum.reset(seed=1)
    assert np.isfinite(pendulum.step([1e308])[1])
    arm.reset(seed=0)
    before = arm.data.qfrc_applied.copy()
    with pytest.raises(ValueError, match=r"action of shape \(2,\)"):
        arm.step(np.zeros(3))
    np.testing.assert_array_equal(arm.data.qfrc_applied, before)
    arm.set_disturbance([1.0, -1.0])
    for clone in (pickle.loads(pickle.dumps(arm)), copy.deepcopy(arm)):
        np.testing.assert_array_equal(clone.constant_disturbance, [1.0, -1.0])
    with pytest.raises(ValueError, match="keeps the initial state finite"):
        smo_gym.envs.VariableInertiaEnv(reset_noise_scale=1e300).reset(seed=0)


def test_frame_skip_is_bounded_at_construction():
    """frame_skip=10**12 was accepted: the first step then ran for hours, or failed inside mj_step (a C int)."""
    for frame_skip in (10**12, 2**31, 10_001):
        with pytest.raises(ValueError, match=r"expected frame_skip in \[1, 10000\], actual value"):
            smo_gym.envs.TwoLinkArmEnv(frame_skip=frame_skip)
    with pytest.raises(ValueError, match="frame_skip"):
        gym.make("smo_gym/FurutaPendulum-v0", frame_skip=10**12)
    env = smo_gym.envs.TwoLinkArmEnv(frame_skip=smo_gym.envs.base.MAX_FRAME_SKIP)  # the bound itself is accepted
    assert env.dt == pytest.approx(20.0)


def test_an_unknown_render_mode_is_refused_before_the_model_loads():
    """render_mode="bad" was accepted and failed only at the first render(); and gymnasium.make warned that even
    "rgb_array" was not among the possible render modes (an empty list on the class)."""

    class Unloadable(smo_gym.envs.TwoLinkArmEnv):
        xml_file = "no_such_model.xml"  # loading it would fail: the render mode is refused first

    for render_mode in ("bad", "rgb", 3):
        with pytest.raises(ValueError, match="expected render_mode to be one of 'human', 'rgb_array'"):
            Unloadable(render_mode=render_mode)
    with warnings.catch_warnings(), pytest.raises(ValueError, match="did you mean 'rgb_array'"):
        warnings.simplefilter("ignore")  # gymnasium.make's own warning about it, before the constructor refuses it
        gym.make("smo_gym/TwoLinkArm-v0", render_mode="rgb")
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*render_modes")  # none for a valid one
        env = gym.make("smo_gym/TwoLinkArm-v0", render_mode="rgb_array")
    assert env.unwrapped.metadata["render_fps"] == 100


def test_reset_refuses_options_that_are_not_a_dict():
    """options="x" was silently ignored. A dict is accepted and, as by Gymnasium's MuJoCo environments, not read
    (vector environments and trainers pass one options dict to every sub-environment)."""
    env = smo_gym.envs.FurutaPendulumEnv()
    for options in ("x", ["qpos"], 1.0):
        with pytest.raises(TypeError, match="expected options to be None or a dict, actual value"):
            env.reset(seed=0, options=options)
    plain, _ = env.reset(seed=0)
    for options in (None, {}, {"qpos": np.zeros(2)}):
        np.testing.assert_array_equal(env.reset(seed=0, options=options)[0], plain)
