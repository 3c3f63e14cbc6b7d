"""Velocities as MuJoCo reports them: the mean over the last physics step unless the model integrates with RK4."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from smo_gym.engine.measurement import VelocityEstimator, mean_velocity_span, step_mean_coefficients
from smo_gym.observers import HighGain, KalmanCA, Levant, SuperTwisting
from smo_gym.wrappers import EstimatedVelocity, VecEstimatedVelocity, VectorEstimatedVelocity


def test_step_mean_coefficients_are_taylors_formula():
    """On a cubic the combination of the derivatives at ``t`` is exactly ``(f(t) - f(t - h)) / h``."""
    t, h = 0.7, 0.01
    c0, c1, c2, c3 = 0.3, -1.2, 2.5, 4.0
    f = lambda s: c0 + c1 * s + c2 * s**2 + c3 * s**3
    derivatives = np.array([c1 + 2 * c2 * t + 3 * c3 * t**2, 2 * c2 + 6 * c3 * t, 6 * c3])
    np.testing.assert_allclose(step_mean_coefficients(3, h) @ derivatives, (f(t) - f(t - h)) / h, rtol=1e-13)
    np.testing.assert_array_equal(step_mean_coefficients(2, h), [1.0, -h / 2])


@pytest.mark.parametrize(
    ("integrator", "span"), [("RK4", None), ("Euler", 0.004), ("implicit", 0.004), ("implicitfast", 0.004)]
)
def test_mujoco_qvel_is_the_mean_velocity_of_the_last_step_except_with_rk4(integrator, span):
    """The claim :func:`mean_velocity_span` rests on, checked on MuJoCo itself: a damped pendulum's ``qvel`` equals
    ``(q_k - q_{k-1}) / h`` to round-off with every integrator but RK4."""
    xml = f"""<mujoco><option timestep="0.004" integrator="{integrator}"/><worldbody><body>
      <joint type="hinge" axis="0 1 0" damping="0.1"/><geom type="capsule" fromto="0 0 0 0 0 -1" size="0.05"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qpos[0] = 1.0
    assert mean_velocity_span(model) == span
    mismatch = []
    for _ in range(200):
        q = data.qpos.copy()
        mujoco.mj_step(model, data)
        mismatch.append(abs(data.qvel[0] - (data.qpos[0] - q[0]) / 0.004))
    assert (max(mismatch) < 1e-9) == (span is not None), max(mismatch)


def test_only_instant_reports_of_order_two_or_more_are_converted():
    h = 0.01
    assert VelocityEstimator(KalmanCA(h, 10.0, 1e-6), mean_over=h).coefficients is not None
    assert VelocityEstimator(Levant(2, h, 5.0, discretization="matching"), mean_over=h).coefficients is not None
    # Newton's backward formula makes the implicit step's outputs the derivatives at the sample time
    assert VelocityEstimator(Levant(2, h, 5.0, discretization="implicit"), mean_over=h).coefficients is not None
    assert VelocityEstimator(Levant(2, h, 5.0, discretization="euler"), mean_over=h).coefficients is None
    assert VelocityEstimator(KalmanCA(h, 10.0, 1e-6)).coefficients is None  # no span: RK4
    assert VelocityEstimator(SuperTwisting(h, 5.0), mean_over=h).coefficients is None  # order 1
    # a backward-Euler step reports a mean over its step already
    assert VelocityEstimator(HighGain(h, 20.0, order=2), mean_over=h).coefficients is None
    with pytest.raises(ValueError, match="expected mean_over > 0"):
        VelocityEstimator(KalmanCA(h, 10.0, 1e-6), mean_over=0.0)


def test_the_converted_velocity_is_the_step_mean_on_a_noise_free_signal():
    """KalmanCA on a noise-free quadratic: its derivative estimates converge to those at the sample time (the
    velocity lags by ``h f''/2`` against the step mean), and the converted velocity to the step mean."""
    h = 0.01
    t = np.arange(3000) * h
    y = 0.5 * t**2
    step_mean = t - h / 2  # (f(t) - f(t - h)) / h
    estimator = VelocityEstimator(KalmanCA(h, 1e-3, 1e-10), mean_over=h)
    estimator.reset(y[:1])
    v = np.array([estimator.update(y[k : k + 1])[0] for k in range(1, len(t))])
    raw = estimator.observer.estimate[0, 1]
    assert abs(raw - t[-1]) < 1e-6 and abs(v[-1] - step_mean[-1]) < 1e-6
    assert abs(raw - step_mean[-1]) == pytest.approx(h / 2, rel=1e-3)


def test_halfcheetah_reports_the_euler_velocity_in_the_wrapper_and_the_vector_wrapper():
    """HalfCheetah integrates with Euler: with the ideal sensor the Kalman filter's wrapper velocity error drops
    by more than 5x against its raw velocity column (measured 0.076 -> 0.0023 on a 400-step rollout), through the
    one-call compiled path; the batched vector wrapper reports the same numbers."""
    env = EstimatedVelocity(gym.make("HalfCheetah-v5"), sensor="ideal", observer="kalman-ca")
    env.reset(seed=0)
    assert env.estimator.coefficients is not None and env._fused is not None
    rng = np.random.default_rng(0)
    converted, raw = [], []
    for _ in range(150):
        _, _, _, _, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        converted.append(info["smo"]["qvel_estimate"] - info["smo"]["qvel"])
        raw.append(env.observer.estimate[:, 1] - info["smo"]["qvel"])
    rms = lambda e: np.sqrt(np.mean(np.array(e[50:]) ** 2))
    assert rms(converted) < 0.2 * rms(raw), (rms(converted), rms(raw))

    n = 2
    ref = DummyVecEnv([lambda: EstimatedVelocity(gym.make("HalfCheetah-v5"), rate="env", observer="kalman-ca")] * n)
    vec = VecEstimatedVelocity(DummyVecEnv([lambda: gym.make("HalfCheetah-v5")] * n), observer="kalman-ca")
    ref.seed(1)
    vec.seed(1)
    np.testing.assert_allclose(vec.reset(), ref.reset(), rtol=0, atol=1e-12)
    assert vec.estimator.coefficients is not None
    for _ in range(20):
        a = rng.uniform(-1, 1, (n,) + vec.action_space.shape)
        o1, _, _, i1 = ref.step(a)
        o2, _, _, i2 = vec.step(a)
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
        for info, reference in zip(i2, i1, strict=True):  # info["smo"] reports the observation's velocity
            np.testing.assert_allclose(
                info["smo"]["qvel_estimate"], reference["smo"]["qvel_estimate"], rtol=0, atol=1e-12
            )

    from gymnasium.vector import SyncVectorEnv

    ref = SyncVectorEnv([lambda: EstimatedVelocity(gym.make("HalfCheetah-v5"), rate="env", observer="kalman-ca")] * n)
    vec = VectorEstimatedVelocity(SyncVectorEnv([lambda: gym.make("HalfCheetah-v5")] * n), observer="kalman-ca")
    o1, i1 = ref.reset(seed=2)
    o2, i2 = vec.reset(seed=2)
    for _ in range(20):
        np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)
        np.testing.assert_allclose(i2["smo"]["qvel_estimate"], i1["smo"]["qvel_estimate"], rtol=0, atol=1e-12)
        a = rng.uniform(-1, 1, (n,) + vec.single_action_space.shape)
        o1, _, _, _, i1 = ref.step(a)
        o2, _, _, _, i2 = vec.step(a)
    np.testing.assert_allclose(o2, o1, rtol=0, atol=1e-12)  # and the last step's
    np.testing.assert_allclose(i2["smo"]["qvel_estimate"], i1["smo"]["qvel_estimate"], rtol=0, atol=1e-12)
