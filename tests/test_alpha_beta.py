"""The alpha-beta tracker (Kalata 1984): steady-state Kalman gains, exact on ramps, registered like any family.

The contract tests (batching, masked reset, non-finite input, pickling, run == update loop) run on it from its
registered examples in tests/test_observer_api.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

import smo_gym
import smo_gym.specs
from smo_gym.calibration import Calibration, default_observer
from smo_gym.observers import FAMILIES, make_observer
from smo_gym.observers.alpha_beta import AlphaBeta, tracking_index_gains


def kalman_gains(sigma_w: float, sigma_v: float, T: float) -> tuple[float, float]:
    """``(alpha, beta)`` of the steady-state Kalman filter of the constant-velocity model with piecewise-constant
    white acceleration, from the discrete algebraic Riccati equation: ``K = P^- c / (c^T P^- c + r)``,
    ``alpha = K_0``, ``beta = T K_1``."""
    F = np.array([[1.0, T], [0.0, 1.0]])
    G = np.array([[T * T / 2.0], [T]])
    c = np.array([[1.0], [0.0]])
    P = solve_discrete_are(F.T, c, sigma_w**2 * (G @ G.T), np.array([[sigma_v**2]]))  # the prior covariance
    K = P @ c / (c.T @ P @ c + sigma_v**2)
    return float(K[0, 0]), float(K[1, 0] * T)


@pytest.mark.parametrize(
    "sigma_w, sigma_v, T", [(50.0, 1e-4, 1e-3), (1.0, 1e-2, 0.02), (300.0, 1e-3, 4e-3), (5.0, 1.0, 0.1)]
)
def test_gains_are_the_steady_state_kalman_gains(sigma_w, sigma_v, T):
    obs = AlphaBeta(T, sigma_w, sigma_v)
    np.testing.assert_allclose((obs.alpha, obs.beta), kalman_gains(sigma_w, sigma_v, T), rtol=1e-8)
    np.testing.assert_allclose(tracking_index_gains(sigma_w * T**2 / sigma_v), (obs.alpha, obs.beta), rtol=0)


def test_exact_on_a_ramp():
    """Started at the true state a ramp leaves no residual; started at zero slope the error decays to zero (the
    error dynamics are linear and stable: a ramp has no steady-state error)."""
    T, shape = 1e-3, (3, 2)
    t = np.arange(4000)[:, None, None] * T
    a, b = np.linspace(-1.0, 1.0, 6).reshape(shape), np.linspace(-4.0, 6.0, 6).reshape(shape)
    Y = a + b * t
    obs = AlphaBeta(T, 50.0, 1e-4)
    est = np.concatenate([obs.reset(Y[0], derivatives=b[..., None])[None], obs.run(Y[1:])])
    np.testing.assert_allclose(est[..., 0], Y, rtol=0, atol=1e-12)
    np.testing.assert_allclose(est[..., 1], np.broadcast_to(b, Y.shape), rtol=1e-9)
    cold = AlphaBeta(T, 50.0, 1e-4)
    est = np.concatenate([cold.reset(Y[0])[None], cold.run(Y[1:])])
    assert np.max(np.abs(est[1, ..., 1] - b)) > 0.1
    np.testing.assert_allclose(est[-1, ..., 1], b, rtol=1e-8)


def test_registered_with_its_gain_rule_and_compiled_drivers():
    from smo_gym.engine.fused import FUSED_DRIVERS, fusable
    from smo_gym.observers import _kernels

    family = FAMILIES["alpha-beta"]
    assert family.cls is AlphaBeta and family.bound_order() == 2 and family.compiled
    obs = make_observer("alpha-beta", dt=1e-3, alpha=0.5, beta=0.2)
    assert obs._kernel in _kernels.STEPS and obs._kernel in FUSED_DRIVERS and fusable(obs)
    assert not family.needs_calibration({"alpha": 0.5, "beta": 0.2})
    # calibrated from the data: sigma_w the typical (RMS) acceleration, sigma_v the noise, per channel
    t = np.arange(0, 5, 1e-3)
    y = np.sin(3 * t) + 1e-4 * np.random.default_rng(0).standard_normal(t.size)
    z = smo_gym.differentiate(y, 1e-3, observer="alpha-beta")
    assert np.sqrt(np.mean((z[1000:, 1] - 3 * np.cos(3 * t[1000:])) ** 2)) < 0.1
    assert smo_gym.specs.parse_observer_spec("alpha-beta:alpha=0.5:beta=0.2") == (
        "alpha-beta",
        dict(alpha=0.5, beta=0.2),
    )


@pytest.mark.parametrize(
    "kwargs, error",
    [
        (dict(), ValueError),
        (dict(acceleration_std=1.0), ValueError),
        (dict(acceleration_std=-1.0, noise_std=1.0), ValueError),
        (dict(alpha=0.5), ValueError),
        (dict(alpha=0.5, beta=0.2, noise_std=1.0), ValueError),
        (dict(alpha=2.5, beta=0.2), ValueError),
        (dict(alpha=1.5, beta=1.2), ValueError),
        (dict(alpha="0.5", beta=0.2), TypeError),
        (dict(alpha=0.5, beta=0.2, gamma=0.1), TypeError),
    ],
)
def test_bad_parameters_raise_typed_errors(kwargs, error):
    with pytest.raises(error, match="expected"):
        AlphaBeta(1e-3, **kwargs)


def test_gains_per_channel_and_the_calibration_rule():
    """Arrays of ``acceleration_std``/``noise_std`` (or of ``alpha``/``beta``) give every channel the tracker of its
    own tracking index, bit for bit; the registered rule takes each channel's typical acceleration and noise."""
    T = 1e-3
    Y = np.cumsum(np.random.default_rng(1).standard_normal((500, 2)), axis=0) * 1e-3
    both = AlphaBeta(T, [5.0, 500.0], [1e-4, 1e-3])
    both.reset(Y[0])
    joint = both.run(Y[1:])
    for c, (acc, noise) in enumerate([(5.0, 1e-4), (500.0, 1e-3)]):
        alone = AlphaBeta(T, acc, noise)
        assert (alone.alpha, alone.beta) == (both.alpha[c], both.beta[c])
        alone.reset(Y[0, c : c + 1])
        np.testing.assert_array_equal(alone.run(Y[1:, c : c + 1])[:, 0], joint[:, c])
    calibration = Calibration(T, {2: [40.0, 400.0]}, {2: [5.0, 500.0]}, [1e-4, 1e-3])
    ruled = default_observer("alpha-beta", calibration)
    np.testing.assert_allclose(ruled.alpha, both.alpha, rtol=1e-12)
    with pytest.raises(ValueError, match="stable tracker"):
        AlphaBeta(T, alpha=[0.5, 1.9], beta=[0.2, 0.5])


def _spectral_radius(alpha: float, beta: float, T: float = 1.0) -> float:
    """The largest eigenvalue magnitude of the tracker's error dynamics ``(I - K c) F``, ``K = [alpha, beta/T]``."""
    F = np.array([[1.0, T], [0.0, 1.0]])
    K = np.array([[alpha], [beta / T]])
    return float(np.max(np.abs(np.linalg.eigvals((np.eye(2) - K @ np.array([[1.0, 0.0]])) @ F))))


def test_the_tracking_index_is_capped_where_the_poles_meet():
    """Kalata's gains have their smallest spectral radius at the tracking index 8, a double pole at -(sqrt 2 - 1)^2;
    above it the radius grows towards 1 (alpha -> 1, beta -> 2). The tracker takes larger indices as 8."""
    from smo_gym.observers.alpha_beta import MAX_TRACKING_INDEX

    indices = np.concatenate([np.geomspace(1e-2, 1e6, 400), [MAX_TRACKING_INDEX]])
    radii = np.array([_spectral_radius(*tracking_index_gains(lam)) for lam in indices])
    assert radii[-1] <= radii.min() + 1e-12
    assert abs(radii[-1] - (np.sqrt(2.0) - 1.0) ** 2) < 1e-6  # a double eigenvalue: sqrt(eps) accuracy
    assert radii[indices.argmax()] > 0.999  # uncapped, the tracker approaches the stability boundary
    T = 0.01
    capped = AlphaBeta(T, 100.0, 1e-9)  # an ideal sensor: the index is 1e7
    assert (capped.alpha, capped.beta) == tracking_index_gains(MAX_TRACKING_INDEX)
    below = AlphaBeta(T, 100.0, 100.0 * T**2 / 7.5)
    np.testing.assert_allclose((below.alpha, below.beta), tracking_index_gains(7.5), rtol=1e-13)


def test_an_ideal_sensor_on_a_semi_implicit_euler_trajectory_does_not_ring():
    """A semi-implicit Euler trajectory (MuJoCo's default integrator) with impulsive accelerations, sampled
    exactly: Kalata's uncapped gains (tracking index 3e6) ring on every impulse, the capped tracker settles."""
    rng = np.random.default_rng(3)
    T, n = 0.01, 3000
    a = np.where(rng.random(n) < 0.02, rng.normal(0.0, 200.0, n), 0.0) + 5.0 * np.sin(3.0 * T * np.arange(n))
    v = np.cumsum(T * a)
    q = np.cumsum(T * v)  # the position moves by T v_k with the new velocity
    sigma_w = float(np.sqrt(np.mean(a**2)))
    alpha, beta = tracking_index_gains(sigma_w * T**2 / 1e-9)
    errors = {}
    for name, obs in (("capped", AlphaBeta(T, sigma_w, 1e-9)), ("uncapped", AlphaBeta(T, alpha=alpha, beta=beta))):
        obs.reset(q[:1])
        errors[name] = np.sqrt(np.mean((obs.run(q[1:, None])[100:, 0, 1] - v[101:]) ** 2))
    assert errors["capped"] < 0.15 < 5.0 < errors["uncapped"]
