r"""Huber's robust update of the constant-acceleration filters (``huber=c``; Masreliez and Martin 1977).

Checked against what can be computed without it:

* the step is the matrix recursion of ``tests/test_kalman_imm.py``'s textbook IMM with Huber's function in the
  update, the likelihood of an innovation at the bound for a clipped sample, and the two rules that stop clipping
  (the previous innovation beyond the bound; too many recent ones beyond it), equal to rounding, for
  :class:`KalmanIMM` and (equal modes) :class:`KalmanCA`;
* a threshold no innovation reaches is the Kalman filter, bit for bit;
* bounded influence: one wrong sample moves the estimate by the same amount however wrong it is (the Kalman filter
  in proportion), and it does not throw the IMM estimator into its fast mode;
* a change of motion far beyond what the filter expects is followed (two samples beyond the bound in a row are
  taken whole), within a few samples of the Kalman filter;
* where the model does not fit the motion at all (the acceleration jumping every few samples), clipping is
  suspended and the filter is the Kalman filter's equal;
* ``differentiate(..., huber=c)`` builds its default's Kalman filter with it, fitted with it, and on a glitching
  record halves the default's error;
* bad thresholds are typed errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import estimates_of
from test_kalman_fit import DT, rmse, sines
from test_kalman_imm import textbook_imm

import smo_gym
from smo_gym.calibration import calibration_of_signal
from smo_gym.observers import KalmanCA, KalmanIMM
from smo_gym.observers._kernels import HUBER_SUSPEND_EXCESS
from smo_gym.observers.linear import calibrated_prior, white_jerk_density


def glitchy_sine(dt, T, sigma, rng, glitches):
    """``sin(3 t)`` sampled every ``dt`` with Gaussian noise ``sigma`` and ``glitches`` ``{sample: size}`` added."""
    t = np.arange(T) * dt
    y = np.sin(3 * t) + sigma * rng.standard_normal(T)
    for k, size in glitches.items():
        y[k] += size
    return t, y


@pytest.mark.parametrize("huber", [2.0, 3.0])
def test_the_step_is_the_textbook_recursion_with_hubers_function(rng, huber):
    """IMM and (equal modes) KalmanCA with ``huber`` equal the matrix recursion to rounding, on a bursty signal
    with gross errors (so that clipping, the two-in-a-row rule and the linear likelihood all occur)."""
    dt, q, r = 2e-3, 1e5, 1e-6
    _, y = glitchy_sine(dt, 1500, np.sqrt(r), rng, {300: 0.2, 301: -0.3, 700: 0.05, 1100: -1.0})
    y += np.cumsum(np.cumsum(rng.standard_normal(1500))) * 1e-4  # jerk the model must follow
    ours = estimates_of(KalmanIMM(dt, q, r, smooth_ratio=0.01, stay=0.98, huber=huber), y[:, None])[:, 0]
    reference, _ = textbook_imm(y, dt, [0.01 * q, q], r, 0.98, huber=huber)
    scale = np.abs(reference).max(axis=0)
    assert np.isfinite(reference).all()
    np.testing.assert_allclose(ours / scale, reference / scale, rtol=0, atol=1e-9)
    kalman = estimates_of(KalmanCA(dt, q, r, huber=huber), y[:, None])[:, 0]
    reference, _ = textbook_imm(y, dt, [q, q], r, 0.98, huber=huber)
    np.testing.assert_allclose(kalman / scale, reference / scale, rtol=0, atol=1e-9)


@pytest.mark.parametrize("cls", [KalmanCA, KalmanIMM])
def test_a_threshold_never_reached_is_the_kalman_filter(rng, cls):
    _, y = glitchy_sine(1e-3, 2000, 1e-3, rng, {})
    Y = y[:, None] * np.array([1.0, -0.5])
    huber, kalman = cls(1e-3, 1e3, 1e-6, huber=1e9), cls(1e-3, 1e3, 1e-6)
    np.testing.assert_array_equal(estimates_of(huber, Y), estimates_of(kalman, Y))


@pytest.mark.parametrize("cls", [KalmanCA, KalmanIMM])
def test_one_wrong_sample_moves_it_the_same_however_wrong(rng, cls):
    r"""A glitch of 0.1, 1 or 100 at 10 ms (noise 1e-3): with ``huber=3`` the largest velocity error stays below
    0.5 for all three sizes, and :class:`KalmanCA`'s estimates are the same for all three (the glitch counts as 3
    standard deviations; the IMM's mode weights still see its size); the Kalman filter's error grows in proportion
    to the glitch (about 50 rad/s per unit)."""
    dt, k = 0.01, 100
    peaks, runs = {}, {}
    for size in (0.1, 1.0, 100.0):
        t, y = glitchy_sine(dt, 200, 1e-3, np.random.default_rng(5), {k: size})
        truth = 3 * np.cos(3 * t)
        for huber in (None, 3.0):
            est = estimates_of(cls(dt, 50.0, 1e-6, huber=huber), y[:, None])[:, 0]
            runs[size, huber] = est
            peaks[size, huber] = np.abs(est[k:, 1] - truth[k:]).max()
    if cls is KalmanCA:
        np.testing.assert_array_equal(runs[0.1, 3.0], runs[100.0, 3.0])
        np.testing.assert_array_equal(runs[1.0, 3.0], runs[100.0, 3.0])
    assert max(peaks[size, 3.0] for size in (0.1, 1.0, 100.0)) < 0.5
    assert peaks[100.0, None] > 1000 * peaks[100.0, 3.0]
    assert peaks[100.0, None] == pytest.approx(100 * peaks[1.0, None], rel=0.05)


def test_a_wrong_sample_does_not_switch_the_imm_to_its_fast_mode(rng):
    """A glitch of 100 standard deviations makes the fast mode certain with the normal likelihood (it predicted the
    sample less badly), and leaves its probability where it was (within 0.05; measured 0.87 -> 0.85) with the
    likelihood of an innovation of ``c`` standard deviations in both modes."""
    dt, k = 0.01, 150
    _, y = glitchy_sine(dt, 200, 1e-3, rng, {k: 0.1})
    fast = {}
    for huber in (None, 3.0):
        obs = KalmanIMM(dt, 50.0, 1e-6, huber=huber)
        obs.reset(y[:1])
        for sample in y[1:k]:
            obs.update(sample[None])
        before = obs.mode_probabilities[0, 1]
        obs.update(y[k : k + 1])
        fast[huber] = before, obs.mode_probabilities[0, 1]
    assert fast[None][1] > 0.99 > fast[None][0]
    assert abs(fast[3.0][1] - fast[3.0][0]) < 0.05


@pytest.mark.parametrize("cls", [KalmanCA, KalmanIMM])
def test_a_change_of_motion_beyond_the_model_is_followed(cls):
    r"""A velocity step of 10 (an impact) in a noise-free ramp, the filter expecting a jerk of ~1: every innovation
    after the step is far beyond ``3 sqrt(S)``, so a filter that always clipped would follow the step by at most a
    few standard deviations per sample. Two in a row are taken whole: ``huber=3`` follows the step as the Kalman
    filter does, one sample later (velocity RMSE over the 500 samples after the step within 5 % of the Kalman
    filter's; measured 0.5 % and 2.6 % for KalmanCA and KalmanIMM) and converges (below 1e-3 after 300 samples)."""
    dt, k, T = 1e-3, 500, 1000
    v = np.where(np.arange(T) < k, 1.0, 11.0)
    y = np.concatenate([[0.0], np.cumsum(v[1:]) * dt])
    errors = {}
    for huber in (None, 3.0):
        est = estimates_of(cls(dt, 1.0, 1e-8, huber=huber), y[:, None])[:, 0]
        errors[huber] = np.abs(est[:, 1] - v)
    assert errors[3.0][k] > 9.9  # the first sample after the step is clipped
    rmse = {huber: np.sqrt(np.mean(error[k:] ** 2)) for huber, error in errors.items()}
    assert rmse[3.0] < 1.05 * rmse[None]
    assert errors[3.0][k + 300 :].max() < 1e-3


def test_clipping_is_suspended_where_the_model_does_not_fit_the_motion():
    r"""An acceleration that jumps every 5 samples (uniform in +-300, 10 ms, 12-bit quantization: the motion of
    uniform random actions at the physics rate), with the process noise calibrated from the record: innovations
    beyond three standard deviations alternate with ones within, so the two-in-a-row rule alone clips every other
    jump (measured: RMSE 1.40 against the Kalman filter's 0.91). The share of innovations beyond the bound (the
    last state column) stays far above the Gaussian 0.27 %, clipping is suspended, and the RMSE is within 2 % of
    the Kalman filter's (measured 0.911 against 0.906)."""
    from smo_gym.calibration import calibration_of_signal as calibrate

    rng = np.random.default_rng(0)
    dt, T = 0.01, 4000
    a = np.repeat(rng.uniform(-300.0, 300.0, T // 5), 5)
    v = np.cumsum(a) * dt
    v -= v.mean()
    step = 2 * np.pi / 4096
    y = (np.round(np.cumsum(v) * dt / step) * step)[:, None]
    found = calibrate(y, dt, (2, 3))
    rmse_of, rates = {}, None
    for huber in (None, 3.0):
        obs = KalmanCA.from_levels(dt, found.rms(3), found.measurement_variance, huber=huber)
        est = estimates_of(obs, y)[:, 0, 1]
        rmse_of[huber] = np.sqrt(np.mean((est[100:] - v[100:]) ** 2))
        if huber is not None:
            obs.reset(y[0])
            rates = np.array([(obs.update(sample), obs.state[0, 10])[1] for sample in y[1:]])
    assert rmse_of[3.0] < 1.02 * rmse_of[None]
    threshold = math.erfc(3.0 / math.sqrt(2.0)) + HUBER_SUSPEND_EXCESS
    assert np.mean(rates[100:] > threshold) > 0.8  # suspended most of the time


def test_differentiate_builds_its_default_with_the_threshold():
    r"""Sums of sines at 1 ms, noise 1e-3, one sample in a thousand per channel off by ``N(0, 0.1^2)`` (the
    ``outliers`` sensor's errors): ``differentiate(y, dt, huber=3)`` is the Kalman filter that
    :meth:`KalmanCA.fit` fits with the threshold, and its velocity RMSE and largest error are at most 0.7x and 0.3x
    the default's (measured 0.53x and 0.13x); on the clean record it is the default within 1 %."""
    clean, v = sines()
    y = clean.copy()
    rng = np.random.default_rng(3)
    wrong = rng.random(y.shape) < 1e-3
    y[wrong] += 0.1 * rng.standard_normal(int(wrong.sum()))
    default, robust = smo_gym.differentiate(y, DT), smo_gym.differentiate(y, DT, huber=3)
    assert rmse(robust[..., 1], v) < 0.7 * rmse(default[..., 1], v)
    late = slice(2000, None)
    assert np.abs(robust[late, :, 1] - v[late]).max() < 0.3 * np.abs(default[late, :, 1] - v[late]).max()
    found = calibration_of_signal(y, DT, (2, 3))
    fitted = KalmanCA.fit(
        y, DT, found.measurement_variance, white_jerk_density(DT, found.rms(3)), huber=3, **calibrated_prior(found)
    )
    assert fitted.huber == 3.0
    np.testing.assert_allclose(robust, smo_gym.differentiate(y, DT, observer=fitted)[..., :2], rtol=1e-12, atol=1e-12)
    on_clean = smo_gym.differentiate(clean, DT, huber=3)[..., 1]
    assert rmse(on_clean, v) == pytest.approx(rmse(smo_gym.differentiate(clean, DT)[..., 1], v), rel=0.01)
    with pytest.raises(ValueError, match="huber"):
        smo_gym.differentiate(y, DT, huber=-1.0)


@pytest.mark.parametrize("cls", [KalmanCA, KalmanIMM])
@pytest.mark.parametrize("bad, error", [(0.0, ValueError), (-1.0, ValueError), (np.nan, ValueError), ("3", TypeError)])
def test_bad_thresholds_are_typed_errors(cls, bad, error):
    with pytest.raises(error, match="huber"):
        cls(0.01, 50.0, 1e-6, huber=bad)
