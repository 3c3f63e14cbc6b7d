"""scripts/rl_estimation_error.py: the error statistics it prints, on signals whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("rl_estimation_error")


def test_a_delayed_estimate_shows_its_delay_and_an_error_one_step_correlated(script):
    # v(t) = (sin 2t, cos 3t) sampled every 10 ms; the estimate is v(t - 15 ms): error ~ -0.015 a(t)
    step, delay = 0.01, 0.015
    t = np.arange(0.0, 20.0, step)[:, None]
    truth = np.hstack([np.sin(2 * t), np.cos(3 * t)])
    late = np.hstack([np.sin(2 * (t - delay)), np.cos(3 * (t - delay))])
    s = script.summary([truth[:1000], truth[1000:]], [late[:1000], late[1000:]], step)
    np.testing.assert_allclose(s["lag"], delay, rtol=0.02)  # first order in the delay: 2-3 % of curvature
    np.testing.assert_allclose(s["rmse"], np.sqrt(np.mean((late - truth) ** 2, axis=0)), rtol=1e-12)
    np.testing.assert_allclose(s["max"], np.max(np.abs(late - truth), axis=0), rtol=1e-12)
    assert np.all(s["autocorrelation"] > 0.99)  # a smooth error persists from one step to the next


def test_white_errors_have_no_lag_and_no_step_correlation(script):
    rng = np.random.default_rng(0)
    step = 0.05
    t = np.arange(0.0, 500.0, step)[:, None]
    truth = np.hstack([np.sin(t), np.cos(0.5 * t)])
    estimate = truth + 0.1 * rng.standard_normal(truth.shape)
    s = script.summary([truth], [estimate], step)
    np.testing.assert_allclose(s["rmse"], 0.1, rtol=0.02)
    assert np.all(np.abs(s["autocorrelation"]) < 0.03)  # 1e4 samples: standard error 0.01
    assert np.all(np.abs(s["lag"]) < 0.01)  # standard error about 0.1 / (RMS of a * sqrt(1e4)) ~ 2e-3 s
