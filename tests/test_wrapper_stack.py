"""EstimatedVelocity on top of other wrappers: every observation wrapper beneath sees the sensed observation.

The sensed observation is the MuJoCo environment's own observation function evaluated at the measured positions
and estimated velocities; each observation wrapper between that environment and ``EstimatedVelocity`` must then
be applied to it, in order, so that the result lies in the stack's observation space. Wrappers that keep state
across observations cannot be replayed that way and are refused with a message that names them.
"""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from smo_gym.wrappers import EstimatedVelocity, JointSensor

ENV = "Hopper-v5"


def _sensed(inner, **kwargs) -> EstimatedVelocity:
    return EstimatedVelocity(inner, disk_cache=False, calibration_steps=300, **kwargs)


def _bare_observation(env: EstimatedVelocity) -> np.ndarray:
    """The bare MuJoCo environment's observation at the wrapper's sensed state, computed independently."""
    return env.adapter.observation(env.measurement.measured_qpos(), env.observer.velocity)


STATELESS = {
    "TimeAwareObservation": gym.wrappers.TimeAwareObservation,
    "DtypeObservation": lambda e: gym.wrappers.DtypeObservation(e, np.float32),
    "TransformObservation": lambda e: gym.wrappers.TransformObservation(
        e, lambda o: 2.0 * o + 1.0, e.observation_space
    ),
    "ReshapeObservation": lambda e: gym.wrappers.ReshapeObservation(gym.wrappers.TimeAwareObservation(e), (3, 4)),
}


@pytest.mark.parametrize("name", sorted(STATELESS))
def test_observation_wrappers_beneath_are_applied_to_the_sensed_observation(name):
    """The returned observation is ``wrapper.observation(sensed)`` at every level, lies in the stack's space, and
    ``info["smo"]["observation"]`` is what the stack itself returns at the true state."""
    make = STATELESS[name]
    env = _sensed(make(gym.make(ENV)))
    plain = make(gym.make(ENV))
    chain = env._observation_wrappers
    assert len(chain) >= 1 and all(isinstance(w, gym.ObservationWrapper) for w in chain)
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    np.testing.assert_array_equal(info["smo"]["observation"], plain.reset(seed=3)[0])
    rng = np.random.default_rng(0)
    for _ in range(30):
        action = rng.uniform(-1, 1, 3)
        obs, reward, terminated, truncated, info = env.step(action)
        expected = _bare_observation(env)
        for wrapper in chain:
            expected = wrapper.observation(expected)
        np.testing.assert_array_equal(obs, expected)
        assert obs.dtype == env.observation_space.dtype and obs.shape == env.observation_space.shape
        assert env.observation_space.contains(obs)
        clean, plain_reward, *_ = plain.step(action)
        np.testing.assert_array_equal(info["smo"]["observation"], clean)
        assert reward == plain_reward
        if terminated or truncated:
            break


def test_time_aware_observation_keeps_its_time_entry():
    """The regression: the time entry of TimeAwareObservation was dropped (11 entries against a 12-entry space)."""
    env = _sensed(gym.wrappers.TimeAwareObservation(gym.make(ENV)))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (12,) and obs[-1] == 0.0
    for k in range(1, 4):
        obs = env.step(np.zeros(3))[0]
        assert obs.shape == (12,) and obs[-1] == k


def test_double_float32_dtype_is_kept():
    env = _sensed(gym.wrappers.DtypeObservation(gym.make(ENV), np.float32))
    assert env.reset(seed=0)[0].dtype == np.float32
    assert env.step(np.zeros(3))[0].dtype == np.float32


@pytest.mark.parametrize(
    "make, name",
    [
        (gym.wrappers.NormalizeObservation, "NormalizeObservation"),
        (lambda e: gym.wrappers.FrameStackObservation(e, 3), "FrameStackObservation"),
        (lambda e: gym.wrappers.DelayObservation(e, 2), "DelayObservation"),
    ],
)
def test_stateful_observation_wrappers_beneath_are_refused_by_name(make, name):
    """A wrapper whose observation depends on earlier ones would mix true and sensed observations: the error
    names it and says to put it on top, where it works."""
    with pytest.raises(TypeError, match=rf"{name}.*put it on top"):
        _sensed(make(gym.make(ENV)))
    on_top = make(_sensed(gym.make(ENV)))
    obs, _ = on_top.reset(seed=0)
    assert on_top.observation_space.contains(obs)
    assert on_top.observation_space.contains(on_top.step(np.zeros(3))[0])


def test_a_wrapper_that_overrides_step_is_refused():
    class Doubling(gym.Wrapper):
        def step(self, action):
            obs, *rest = self.env.step(action)
            return 2 * obs, *rest

    with pytest.raises(TypeError, match="Doubling overrides step"):
        _sensed(Doubling(gym.make(ENV)))


def test_pass_through_wrappers_beneath_change_nothing():
    """Episode recorders, reward and action wrappers beneath give exactly the observations of the bare stack."""
    from stable_baselines3.common.monitor import Monitor

    stacks = [
        Monitor,
        gym.wrappers.RecordEpisodeStatistics,
        lambda e: gym.wrappers.ClipReward(e, -1.0, 1.0),
        lambda e: gym.wrappers.ClipAction(e),
        gym.wrappers.NormalizeReward,
    ]
    for make in stacks:
        wrapped, plain = _sensed(make(gym.make(ENV))), _sensed(gym.make(ENV))
        assert wrapped._observation_wrappers == ()
        np.testing.assert_array_equal(wrapped.reset(seed=4)[0], plain.reset(seed=4)[0])
        rng = np.random.default_rng(4)
        for _ in range(20):
            action = rng.uniform(-1, 1, 3)
            np.testing.assert_array_equal(wrapped.step(action)[0], plain.step(action)[0])


def test_wrapping_twice_is_a_clear_error():
    """The regression: a second EstimatedVelocity raised AttributeError ... _step_mujoco_simulation at its step."""
    once = _sensed(gym.make(ENV))
    with pytest.raises(TypeError, match="already in the stack"):
        _sensed(once)
    with pytest.raises(TypeError, match="already in the stack"):
        _sensed(gym.wrappers.TimeAwareObservation(once))
    with pytest.raises(TypeError, match="already in the stack"):
        JointSensor(once, disk_cache=False, calibration_steps=300)


def test_joint_sensor_needs_the_bare_observation():
    """The vector wrappers rebuild observations from the bare environment's function: an observation wrapper
    beneath their sub-environment's JointSensor is refused (it belongs on the vector env)."""
    with pytest.raises(TypeError, match=r"TimeAwareObservation.*put it on top"):
        JointSensor(gym.wrappers.TimeAwareObservation(gym.make(ENV)), disk_cache=False, calibration_steps=300)


@pytest.mark.parametrize("name", ["TimeAwareObservation", "DtypeObservation"])
def test_accepted_stacks_pass_the_environment_checker(name):
    env = _sensed(STATELESS[name](gym.make(ENV)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env, skip_render_check=True)


def test_accepted_stacks_pickle():
    """With cloudpickle, as vector envs send environments to their workers (Gymnasium's TimeAwareObservation
    holds a lambda, which plain pickle refuses whatever wraps it)."""
    import cloudpickle

    env = _sensed(gym.wrappers.TimeAwareObservation(gym.make(ENV)))
    twin = pickle.loads(cloudpickle.dumps(env))
    np.testing.assert_array_equal(env.reset(seed=2)[0], twin.reset(seed=2)[0])
    np.testing.assert_array_equal(env.step(np.ones(3))[0], twin.step(np.ones(3))[0])


def test_flatten_observation_beneath_on_a_dm_control_task():
    """dm_control tasks have Dict observations: FlattenObservation beneath gives the flat sensed observation."""
    pytest.importorskip("shimmy")
    from smo_gym.envs import make

    env = _sensed(gym.wrappers.FlattenObservation(make("dm_control/cartpole-swingup-v0")))
    obs, _ = env.reset(seed=0)
    assert isinstance(obs, np.ndarray) and env.observation_space.contains(obs)
    for _ in range(5):
        obs = env.step(np.zeros(1))[0]
        expected = gym.spaces.flatten(env.unwrapped.observation_space, env.adapter.unflatten(_bare_observation(env)))
        np.testing.assert_array_equal(obs, expected)
        assert env.observation_space.contains(obs)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(calibration_safety=0.0), ValueError, "calibration_safety > 0"),
        (dict(calibration_safety=True), TypeError, "calibration_safety"),
        (dict(calibration_quantile=0.0), ValueError, r"calibration_quantile in \(0.0, 1.0\]"),
        (dict(calibration_quantile=1.5), ValueError, "calibration_quantile"),
        (dict(calibration_steps=0), ValueError, "calibration_steps"),
        (dict(calibration_steps=10.5), TypeError, "calibration_steps"),
        (dict(disk_cache="no"), TypeError, "disk_cache"),
        (dict(observer_kwargs=[("lipschitz", 1.0)]), TypeError, "observer_kwargs"),
        (dict(contact_forces="estimated"), ValueError, "no contact forces"),
        (dict(contact_forces="zero"), ValueError, "no contact forces"),
        (dict(contact_forces="nonsense"), ValueError, "contact_forces"),
    ],
)
def test_bad_options_are_refused_before_any_work(kwargs, error, match):
    with pytest.raises(error, match=match):
        EstimatedVelocity(gym.make(ENV), disk_cache=kwargs.pop("disk_cache", False), **kwargs)


def test_contact_force_modes_where_the_observation_has_contact_forces():
    for mode in ("sensor", "estimated", "zero"):
        env = EstimatedVelocity(gym.make("Ant-v5"), contact_forces=mode, disk_cache=False, calibration_steps=300)
        assert env.observation_space.contains(env.reset(seed=0)[0].astype(np.float64))


def test_single_turn_encoder_through_the_wrapper():
    """A wrapping encoder reports angles in [-pi, pi); the wrapper's observer then takes wrap on the angular
    channels, so a pendulum spinning through +-pi gives no velocity spike (the finite difference without wrap
    would see 2 pi / h)."""
    from smo_gym import sensors
    from smo_gym.observers import FiniteDifference

    env = EstimatedVelocity(
        gym.make("InvertedDoublePendulum-v5"),
        sensor=sensors.Encoder(counts_per_revolution=2**16, wrap=True),
        observer="finite-difference",
        rate="physics",
        disk_cache=False,
        calibration_steps=300,
    )
    assert env.measurement.wraps and env.observer.wrap is not None and env._fused is None
    env.reset(seed=0)
    data = env.unwrapped.data
    errors = []
    for k in range(60):  # spin the first hinge fast through +-pi: 30 rad/s, several turns
        data.qpos[1] = np.pi - 0.2 + 0.3 * k
        data.qvel[1] = 0.0
        info = env.step(np.zeros(1))[4]
        errors.append(abs(info["smo"]["qvel_estimate"][1]))
        assert -np.pi <= info["smo"]["qpos_measured"][1] < np.pi
    assert max(errors[1:]) < 100.0  # no 2 pi / h = 6283 rad/s spike
    with pytest.raises(ValueError, match="wrap on the angular channels"):
        EstimatedVelocity(
            gym.make("InvertedDoublePendulum-v5"),
            sensor=sensors.Encoder(counts_per_revolution=4096, wrap=True),
            observer=FiniteDifference(dt=env.sample_dt),
            disk_cache=False,
        )


def test_misspelled_observer_kwargs_are_unknown_parameters_with_a_suggestion():
    with pytest.raises(ValueError, match=r"unknown parameter 'lipschtz' of SuperTwisting.*did you mean 'lipschitz'"):
        _sensed(gym.make(ENV), observer="super-twisting", observer_kwargs={"lipschtz": 5.0})
    with pytest.raises(ValueError, match=r"no observer parameters but wrap for observer='auto'"):
        _sensed(gym.make(ENV), observer_kwargs={"lipschitz": 5.0})
    with pytest.raises(ValueError, match=r"unknown parameter 'ordr' of KalmanCA|unknown parameter 'ordr'"):
        _sensed(gym.make(ENV), observer="kalman-ca", observer_kwargs={"ordr": 2})
    with pytest.raises(ValueError, match=r"did you mean 'super-twisting'"):
        _sensed(gym.make(ENV), observer="super-twist")
