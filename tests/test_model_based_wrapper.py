"""EstimatedVelocity with the model-based observers built from the environment's own model."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from smo_gym import wrappers
from smo_gym.observers import DissipativeSuperTwisting, KalmanIMMInput, MechanicalSuperTwisting
from smo_gym.wrappers.model_based import InputAwareEstimator


def velocity_rmse(env, T=300, seed=0):
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    errs = []
    for k in range(T):
        if k % 4 == 0:
            a = 0.3 * rng.uniform(env.action_space.low, env.action_space.high)
        *_, info = env.step(a)
        errs.append(info["smo"]["qvel"] - info["smo"]["qvel_estimate"])
    e = np.array(errs)[T // 4 :]
    return float(np.sqrt(np.mean(e**2)))


def test_mechanical_observer_in_the_wrapper_beats_model_free():
    """Two-link arm, 10 % heavier model, noisy 12-bit encoder, physics rate (measured 0.11 vs 0.52 / 0.78)."""
    mb = wrappers.EstimatedVelocity(
        gym.make("smo_gym/TwoLinkArm-v0"),
        observer="mechanical-super-twisting",
        observer_kwargs={"mass_scale": 1.1},
        disk_cache=False,
    )
    assert isinstance(mb.observer, MechanicalSuperTwisting)
    assert mb.observer.dynamics.model is not mb.unwrapped.model
    st = wrappers.EstimatedVelocity(gym.make("smo_gym/TwoLinkArm-v0"), disk_cache=False)
    fd = wrappers.EstimatedVelocity(gym.make("smo_gym/TwoLinkArm-v0"), observer="finite-difference", disk_cache=False)
    r_mb = velocity_rmse(mb)
    assert r_mb < velocity_rmse(st)
    assert r_mb < velocity_rmse(fd)


def test_the_wrapper_passes_the_action_to_the_model():
    """Dropping the input (u = 0 in the model) is measurably worse: the action reaches the observer."""
    mb = wrappers.EstimatedVelocity(
        gym.make("smo_gym/TwoLinkArm-v0"),
        observer="mechanical-super-twisting",
        observer_kwargs={"lipschitz": 20.0, "accel_bound": 1000.0},
        disk_cache=False,
    )
    with_input = velocity_rmse(mb)
    mb.estimator.update = lambda z: mb.observer.update(z, None)[..., 1]
    assert velocity_rmse(mb) > 2 * with_input


def test_dissipative_in_the_wrapper_and_limits():
    gains = {"k1": 2.0, "k2": 1.0, "k3": 0.0, "mu1": 12.0, "mu2": 12.0}
    ds = wrappers.EstimatedVelocity(
        gym.make("smo_gym/TwoLinkArm-v0"),
        observer="dissipative-super-twisting",
        observer_kwargs={"gains": gains},
        disk_cache=False,
    )
    assert isinstance(ds.observer, DissipativeSuperTwisting)
    assert np.isfinite(velocity_rmse(ds, T=100))
    with pytest.raises(ValueError, match="couplings"):
        wrappers.EstimatedVelocity(
            gym.make("smo_gym/VariableInertia-v0"), observer="mechanical-super-twisting", disk_cache=False
        )


# ---- the model-based names through EstimatedVelocity -----------------------------------------------------------
def estimates(env, T=60, seed=0):
    """Velocity estimates and measured positions over ``T`` steps of a seeded piecewise-constant policy."""
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    vel, meas = [], []
    for k in range(T):
        if k % 4 == 0:
            a = 0.3 * rng.uniform(env.action_space.low, env.action_space.high)
        *_, info = env.step(a)
        vel.append(info["smo"]["qvel_estimate"])
        meas.append(info["smo"]["qpos_measured"])
    return np.array(vel), np.array(meas)


def test_a_model_based_name_in_estimated_velocity_builds_the_model_based_observer():
    """The observer on a mismatched private model, the action as input, the general path; the same settings give
    the same estimates, bit for bit."""
    kw = {"mass_scale": 1.1, "contact": "measured"}
    ev = wrappers.EstimatedVelocity(
        gym.make("smo_gym/TwoLinkArm-v0"), observer="mechanical-super-twisting", observer_kwargs=kw, disk_cache=False
    )
    again = wrappers.EstimatedVelocity(
        gym.make("smo_gym/TwoLinkArm-v0"), observer="mechanical-super-twisting", observer_kwargs=kw, disk_cache=False
    )
    assert isinstance(ev.observer, MechanicalSuperTwisting)
    assert isinstance(ev.estimator, InputAwareEstimator)
    dyn = ev.observer.dynamics
    assert dyn.mass_scale == 1.1 and dyn.contact == "measured" and ev.mass_scale_range is None
    np.testing.assert_array_equal(dyn.model.body_mass, 1.1 * ev.unwrapped.model.body_mass)
    np.testing.assert_array_equal(ev.model_miss_bound, again.model_miss_bound)
    np.testing.assert_array_equal(estimates(ev)[0], estimates(again)[0])
    assert ev._fused is None  # not fusable: the general path, which feeds the action
    gains = {"k1": 2.0, "k2": 1.0, "k3": 0.0, "mu1": 12.0, "mu2": 12.0}
    ds = wrappers.EstimatedVelocity(
        gym.make("smo_gym/TwoLinkArm-v0"),
        observer="dissipative-super-twisting",
        observer_kwargs={"gains": gains},
        disk_cache=False,
    )
    assert isinstance(ds.observer, DissipativeSuperTwisting) and ds.observer.dynamics.mass_scale == 1.0
    assert np.all(np.isfinite(estimates(ds, T=20)[0]))


def test_a_mass_scale_range_draws_a_scale_per_episode_from_the_seed():
    low, high = 0.8, 1.25
    kw = {"mass_scale": (low, high), "lipschitz": 20.0, "accel_bound": 1000.0}

    def wrapper():
        return wrappers.EstimatedVelocity(
            gym.make("smo_gym/TwoLinkArm-v0"),
            observer="mechanical-super-twisting",
            observer_kwargs=kw,
            disk_cache=False,
        )

    a, b = wrapper(), wrapper()
    assert a.mass_scale_range == (low, high)
    assert a.observer.dynamics.mass_scale == 0.5 * (low + high)  # before the first reset: the midpoint
    va, za = estimates(a, seed=3)
    scale = a.observer.dynamics.mass_scale
    vb, zb = estimates(b, seed=3)
    assert b.observer.dynamics.mass_scale == scale
    np.testing.assert_array_equal(va, vb)
    np.testing.assert_array_equal(za, zb)
    np.testing.assert_array_equal(a.observer.dynamics.model.body_mass, scale * a.unwrapped.model.body_mass)
    scales = []
    for seed in range(8):
        a.reset(seed=seed)
        scales.append(a.observer.dynamics.mass_scale)
    a.reset()  # no seed: the stream goes on
    scales.append(a.observer.dynamics.mass_scale)
    assert len(set(scales)) == len(scales)
    assert all(low <= s <= high for s in scales)
    # the draw has a stream of its own: the sensor's noise is that of any wrapper reset with the same seed
    fd = wrappers.EstimatedVelocity(gym.make("smo_gym/TwoLinkArm-v0"), observer="finite-difference", disk_cache=False)
    np.testing.assert_array_equal(estimates(fd, seed=3)[1], za)


def test_the_calibrated_bound_of_a_range_covers_both_ends():
    def bound(scale):
        env = wrappers.EstimatedVelocity(
            gym.make("smo_gym/TwoLinkArm-v0"),
            observer="mechanical-super-twisting",
            observer_kwargs={"mass_scale": scale},
            calibration_steps=400,
            disk_cache=False,
        )
        return env.model_miss_bound

    np.testing.assert_array_equal(bound((0.7, 1.4)), np.maximum(bound(0.7), bound(1.4)))


@pytest.mark.parametrize(
    ("env_id", "kwargs", "error", "match"),
    [
        ("smo_gym/TwoLinkArm-v0", {"observer_kwargs": {"mass_scale": (1.2, 1.1)}}, ValueError, "low <= high"),
        ("smo_gym/TwoLinkArm-v0", {"observer_kwargs": {"mass_scale": -1.0}}, ValueError, r"mass_scale in \[0.001"),
        ("smo_gym/TwoLinkArm-v0", {"observer_kwargs": {"mass_scale": (0.0, 1.1)}}, ValueError, r"mass_scale in \["),
        ("smo_gym/TwoLinkArm-v0", {"observer_kwargs": {"mass_scale": (1, 2, 3)}}, ValueError, "pair"),
        ("smo_gym/TwoLinkArm-v0", {"observer_kwargs": {"mass_scale": "1.1"}}, TypeError, "real number"),
        ("smo_gym/TwoLinkArm-v0", {"observer_kwargs": {"contact": "soft"}}, ValueError, "contact"),
        ("smo_gym/TwoLinkArm-v0", {"rate": 3}, ValueError, "divisor of frame_skip"),
        ("smo_gym/VariableInertia-v0", {}, ValueError, "couplings"),
        ("Ant-v5", {}, ValueError, "hinge and slide"),
    ],
)
def test_bad_model_based_settings_are_refused(env_id, kwargs, error, match):
    with pytest.raises(error, match=match) as excinfo:
        wrappers.EstimatedVelocity(gym.make(env_id), observer="mechanical-super-twisting", disk_cache=False, **kwargs)
    assert "expected" in str(excinfo.value) and "actual value" in str(excinfo.value)


def test_an_absurd_mass_scale_is_refused_by_its_name():
    """A mass scale of 1e100 (or 1e-100) made the model's inertia matrix singular and its accelerations NaN, and the
    user, who never passed a lipschitz, read "expected lipschitz > 0 everywhere, actual value: array([nan, nan])".
    An end of a range with the gains given (no calibration) was found only when a reset drew near it, or never."""
    told = {"lipschitz": 20.0, "accel_bound": 1000.0}
    for observer, kwargs in (
        ("mechanical-super-twisting", {"mass_scale": 1e100}),
        ("mechanical-super-twisting", {"mass_scale": 1e-100}),
        ("auto", {"model": True, "mass_scale": 1e100}),
        ("mechanical-super-twisting", {"mass_scale": (1e-100, 1.0), **told}),
        ("mechanical-super-twisting", {"mass_scale": (0.5, 1.9e3), **told}),
    ):
        with pytest.raises(ValueError, match=r"expected mass_scale in \[0.001, 1000") as excinfo:
            wrappers.EstimatedVelocity(
                gym.make("smo_gym/TwoLinkArm-v0"), observer=observer, observer_kwargs=kwargs, disk_cache=False
            )
        assert "lipschitz" not in str(excinfo.value)
    # the ends of the range stay usable
    from smo_gym.mechanics import MASS_SCALE_RANGE, MujocoDynamics

    for scale in MASS_SCALE_RANGE:
        assert MujocoDynamics(gym.make("smo_gym/TwoLinkArm-v0").unwrapped.model, mass_scale=scale).mass_scale == scale


def test_the_vector_wrappers_refuse_a_model_based_name():
    """One batched observer update per vector step has no per-environment action: refused, pointing elsewhere."""
    with pytest.raises(ValueError, match="make_vec") as excinfo:
        wrappers.JointSensor(gym.make("smo_gym/TwoLinkArm-v0"), observer="dissipative-super-twisting")
    assert "expected a model-free observer" in str(excinfo.value)
    envs = gym.make_vec("smo_gym/TwoLinkArm-v0", num_envs=2, vectorization_mode="sync")
    with pytest.raises(ValueError, match="expected a model-free observer"):
        wrappers.VectorEstimatedVelocity(envs, observer="mechanical-super-twisting")
    # auto with a model would choose the model-based observer and then run it without the actions
    with pytest.raises(ValueError, match="actual value: 'auto' with a model"):
        wrappers.VectorEstimatedVelocity(envs, observer_kwargs={"model": True, "mass_scale": 1.1})
    told = KalmanIMMInput(envs.unwrapped.get_attr("dt")[0], 10.0, 1e-6, np.ones((2, 2)), 1.0)
    with pytest.raises(ValueError, match="expected a model-free observer"):  # an object was run without actions
        wrappers.VectorEstimatedVelocity(envs, observer=told)
    envs.close()


def test_the_default_bound_is_the_model_miss_where_the_environment_goes():
    """InvertedDoublePendulum-v5 ends an episode when the pole falls; the model's own rollout from ``qpos0`` does
    not, and its pole spins and its cart hits the rails (constraints the model does not know): calibrated there, the
    bound was 20-75x the miss of the environment's episodes and the observer a backward difference. The bound is
    ``safety`` (2) times a quantile of the miss per physics step, measured here on other random episodes."""
    env = wrappers.EstimatedVelocity(
        gym.make("InvertedDoublePendulum-v5"),
        observer="mechanical-super-twisting",
        observer_kwargs={"mass_scale": 1.1},
        disk_cache=False,
    )
    sim, dyn = gym.make("InvertedDoublePendulum-v5").unwrapped, env.observer.dynamics
    rng, misses = np.random.default_rng(5), []
    sim.reset(seed=5)
    for _ in range(300):
        u = rng.uniform(-1.0, 1.0, 1)
        for _ in range(sim.frame_skip):
            q, v = sim.data.qpos.copy(), sim.data.qvel.copy()
            sim.data.ctrl[:] = u
            mujoco.mj_step(sim.model, sim.data)
            misses.append(np.abs((sim.data.qvel - v) / sim.model.opt.timestep - dyn.acceleration(q, v, u)))
        if sim.data.site_xpos[0, 2] <= 1.0:  # the environment's termination: the pole's tip below 1 m
            sim.reset()
    misses = np.array(misses)
    assert np.all(env.model_miss_bound >= 2.0 * 0.5 * np.quantile(misses, 0.99, axis=0))
    assert np.all(env.model_miss_bound <= 2.0 * 2.0 * misses.max(axis=0))


def test_the_sb3_vector_wrapper_refuses_a_model_based_name():
    env_util = pytest.importorskip("stable_baselines3.common.env_util")
    venv = env_util.make_vec_env("smo_gym/TwoLinkArm-v0", n_envs=2)
    with pytest.raises(ValueError, match="expected a model-free observer"):
        wrappers.VecEstimatedVelocity(venv, observer="mechanical-super-twisting")
    with pytest.raises(ValueError, match="actual value: 'auto' with a model"):
        wrappers.VecEstimatedVelocity(venv, observer_kwargs={"model": True})
    venv.close()


def test_auto_with_a_model_takes_the_model_based_observer_where_it_wins():
    """InvertedDoublePendulum at the physics rate, a 10 % heavier model, noisy 12-bit encoder: the model-based
    observer beats every model-free candidate on the trials (measured RMSE 0.06-0.11 against 0.07-0.22 for the best
    model-free candidate of each joint), so ``model=True`` picks it, with the action as its input, and it beats the
    model-free choice on a new episode."""
    make = lambda **kw: wrappers.EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), disk_cache=False, **kw)
    with_model = make(observer_kwargs={"model": True, "mass_scale": 1.1})
    assert isinstance(with_model.observer, MechanicalSuperTwisting)
    assert isinstance(with_model.estimator, InputAwareEstimator)
    assert with_model.observer.dynamics.mass_scale == pytest.approx(1.1)
    selection = with_model.observer.selection
    assert selection.joint and selection.candidates[-1] == "mechanical-super-twisting"
    assert set(selection.names) == {"mechanical-super-twisting"}
    free = make()
    # the same trials: equal to rounding (one entry of 48 has differed by one ulp in a process that ran other tests
    # first; other trials would move them by percents)
    np.testing.assert_allclose(selection.errors[:, :-1], free.observer.selection.errors, rtol=1e-12, atol=0)
    assert episodes_rmse(with_model) < 0.8 * episodes_rmse(free)


def episodes_rmse(env, T=600, seed=5):
    """Velocity RMSE over ``T`` steps of uniform random actions, resetting where an episode ends."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    errs = []
    for _ in range(T):
        *_, terminated, truncated, info = env.step(env.action_space.sample())
        errs.append(info["smo"]["qvel"] - info["smo"]["qvel_estimate"])
        if terminated or truncated:
            env.reset()
    return float(np.sqrt(np.mean(np.square(errs))))


def test_auto_keeps_the_model_free_choice_when_the_model_loses():
    """A model three times too heavy loses to the references on the trials: the per-joint choice stays, and its
    selection shows the model's column."""
    env = wrappers.EstimatedVelocity(
        gym.make("InvertedDoublePendulum-v5"), disk_cache=False, observer_kwargs={"model": True, "mass_scale": 3.0}
    )
    assert not isinstance(env.observer, MechanicalSuperTwisting)
    assert not isinstance(env.estimator, InputAwareEstimator)
    selection = env.observer.selection
    assert selection.candidates[-1] == "mechanical-super-twisting"
    assert "mechanical-super-twisting" not in selection.names


def test_auto_refuses_an_unknown_model():
    with pytest.raises(ValueError, match="expected observer in mechanical-super-twisting"):
        wrappers.EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), observer_kwargs={"model": "kalman-ca"})


def test_auto_without_a_model_refuses_model_settings_and_takes_model_false():
    with pytest.raises(
        ValueError, match=r"describe a model-based candidate, which needs an environment.*\['mass_scale'\]"
    ):
        wrappers.EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), observer_kwargs={"mass_scale": 1.1})
    env = wrappers.EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), observer_kwargs={"model": False})
    assert "mechanical-super-twisting" not in env.observer.selection.candidates


def test_model_based_specs_train_through_smo_gym_rl():
    """The spec syntax of ``smo-gym train --observer`` reaches the model-based observers and auto's model: the same
    observers as the keyword arguments, and per-environment wrappers (the vector wrappers have no control input)
    even at the environment rate."""
    from smo_gym import rl

    env = rl.make_env("InvertedDoublePendulum-v5", observer="mechanical-super-twisting:mass_scale=1.1")
    assert isinstance(env.observer, MechanicalSuperTwisting)
    assert env.observer.dynamics.mass_scale == pytest.approx(1.1)
    venv = rl.make_vec("InvertedDoublePendulum-v5", observer="auto:model=true:mass_scale=1.1", rate="env", n_envs=2)
    assert not isinstance(venv, wrappers.VecEstimatedVelocity)
    (observer,) = set(map(type, venv.get_attr("observer")))
    assert observer is MechanicalSuperTwisting  # at 50 ms too the heavier model beats the model-free candidates
    assert venv.reset().shape == (2, 9)
    venv.close()


def test_the_filters_told_the_actions_run_in_the_wrapper_and_in_auto():
    """``"kalman-imm-input"`` by name and as ``auto``'s candidate: fitted on the trials' episodes, given the action
    at each sample, reporting MuJoCo's step-mean velocity where it integrates with Euler; on InvertedPendulum at the
    physics rate with the noisy 12-bit encoder it is chosen and beats the model-free choice at the samples the agent
    sees, on new uniform random episodes (measured: 0.42x; 0.55x while it started from the wide prior)."""
    from smo_gym.engine.measurement import mean_velocity_span

    make = lambda **kw: wrappers.EstimatedVelocity(gym.make("InvertedPendulum-v5"), disk_cache=False, **kw)
    named = make(observer="kalman-imm-input")
    assert isinstance(named.observer, KalmanIMMInput) and isinstance(named.estimator, InputAwareEstimator)
    assert named.observer.input_gain.shape == (2, 1)
    assert named.estimator.coefficients is None and mean_velocity_span(named.adapter.model) is None  # RK4
    cheetah = wrappers.EstimatedVelocity(gym.make("HalfCheetah-v5"), observer="kalman-ca-input", disk_cache=False)
    assert cheetah.estimator.coefficients is not None  # Euler: the step mean, as the model-free observers report
    told = make(observer_kwargs={"model": "kalman-imm-input"})
    assert set(told.observer.selection.names) == {"kalman-imm-input"}
    assert episodes_rmse(told) < 0.7 * episodes_rmse(make())
    with pytest.raises(TypeError, match="mass_scale"):  # no model to scale
        make(observer_kwargs={"model": "kalman-ca-input", "mass_scale": 1.1})
    with pytest.raises(ValueError, match="expected a model-free observer"):
        wrappers.JointSensor(gym.make("InvertedPendulum-v5"), observer="kalman-ca-input")


def test_auto_takes_the_filter_told_the_actions_on_the_joints_where_it_wins():
    """Its channels are independent given the action, so ``auto`` weighs it joint by joint like any candidate. On
    InvertedDoublePendulum with the low-cost sensor at the physics rate it wins the cart only (on the hinges the
    robust IMM estimator blind to the action is the better on the trials): a composite of the two that takes the
    action. On InvertedPendulum with the noise-free 12-bit encoder it wins both joints and beats the model-free
    choice on new uniform random episodes (measured: 0.031 against 0.068; while the told filter started from the
    constructor's wide prior it won the hinge only there, 0.038)."""
    from smo_gym.observers import PerChannelInput

    def make(env_id, sensor, **kw):
        return wrappers.EstimatedVelocity(gym.make(env_id), sensor=sensor, rate="physics", disk_cache=False, **kw)

    told = {"model": "kalman-imm-input"}
    mixed = make("InvertedDoublePendulum-v5", "low-cost", observer_kwargs=told)
    assert isinstance(mixed.observer, PerChannelInput) and isinstance(mixed.estimator, InputAwareEstimator)
    assert mixed.observer.selection.names == ("kalman-imm-input", "kalman-imm:huber=3", "kalman-imm:huber=3")
    assert not mixed.observer.selection.joint
    assert [idx.tolist() for part, idx in mixed.observer.parts if part.takes_input] == [[0]]
    assert np.isfinite(episodes_rmse(mixed, T=100))
    whole = make("InvertedPendulum-v5", "encoder-12bit", observer_kwargs=told)
    assert isinstance(whole.observer, KalmanIMMInput) and isinstance(whole.estimator, InputAwareEstimator)
    assert episodes_rmse(whole) < 0.6 * episodes_rmse(make("InvertedPendulum-v5", "encoder-12bit"))


def test_the_filters_told_the_actions_run_on_an_environment_with_joints_that_never_move():
    """Reacher's target joints never move in the calibration episodes: the fit of the input model raised numpy's
    LinAlgError there (and on Pusher) before it took a still channel as still."""
    env = wrappers.EstimatedVelocity(gym.make("Reacher-v5"), observer="kalman-imm-input", disk_cache=False)
    np.testing.assert_array_equal(env.observer.input_gain[2:], 0.0)  # the target's two slides
    env.reset(seed=0)
    for _ in range(20):
        obs, *_ = env.step(env.action_space.sample())
    assert np.isfinite(obs).all()


def test_a_filter_told_the_actions_given_as_an_object_gets_them():
    """The wrapper chose the estimator that passes the action by the observer's name only: a told filter given as
    an object ran without it, its jumps never happening. Its estimates are now those of the same filter fed the
    recorded measurements and actions."""
    env = gym.make("InvertedPendulum-v5")
    told = KalmanIMMInput(env.unwrapped.dt, 10.0, 1e-6, np.array([[0.5], [-30.0]]), 1.0)
    wrapped = wrappers.EstimatedVelocity(env, sensor="ideal", observer=told, rate="env")
    assert isinstance(wrapped.estimator, InputAwareEstimator)
    _, info = wrapped.reset(seed=0)
    measured, actions, estimates = [info["smo"]["qpos_measured"]], [], []
    for action in np.random.default_rng(0).uniform(-0.3, 0.3, (15, 1)):
        *_, info = wrapped.step(action)
        measured.append(info["smo"]["qpos_measured"])
        actions.append(action)
        estimates.append(info["smo"]["qvel_estimate"])
    told.reset(measured[0])
    replayed = told.run(np.array(measured[1:]), np.array(actions))[..., 1]
    np.testing.assert_allclose(estimates, replayed, rtol=1e-12, atol=1e-12)
    told.reset(measured[0])
    assert np.abs(told.run(np.array(measured[1:]))[..., 1] - replayed).max() > 1e-3  # the jumps matter here


def test_a_recording_keeps_its_inputs_for_the_filters_told_the_actions():
    """``compare_observers`` runs them on a recording as the wrapper runs them (the recorded ``ctrl``)."""
    from smo_gym.experiments.compare import compare_observers, parse_observer_specs, record_rollout

    rec = record_rollout("InvertedPendulum-v5", sensor="encoder-12bit-noisy", steps=150, seed=0)
    assert rec.inputs.shape == (len(rec.qvel), 1)
    fd, told = compare_observers(rec, ["finite-difference", "kalman-ca-input"])
    assert told.rmse < 0.8 * fd.rmse
    with pytest.raises(ValueError, match="expected model-free observers"):
        parse_observer_specs(["kalman-ca-input"])  # a recording without its inputs cannot run it
