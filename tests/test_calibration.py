"""Calibration from data (noise level, derivative bounds, default gains) and ``smo_gym.differentiate`` without gains.

The noise estimates are checked against the standard deviation of the noise that was added, the bounds against
the closed-form derivatives of the signal, and the gain rules against the wrapper's ``default_observer``.
"""

from __future__ import annotations

import numpy as np
import pytest

import smo_gym
from smo_gym import calibration
from smo_gym.observers import OBSERVERS, HighGain, KalmanCA, SuperTwisting, make_observer

DT = 1e-3


def noisy_sine(T=20000, sigma=1e-3, seed=0, amplitude=1.0, omega=3.0, channels=1):
    t = np.arange(T)[:, None] * DT
    phase = np.arange(channels)[None, :]
    clean = amplitude * np.sin(omega * t + phase)
    return t[:, 0], clean, clean + sigma * np.random.default_rng(seed).standard_normal(clean.shape)


# ----------------------------------------------------------------------------------------------------------------
# noise level
# ----------------------------------------------------------------------------------------------------------------
def test_noise_std_recovers_gaussian_and_uniform_noise():
    """With 20000 samples the MAD's relative standard error is about 1 %; the tolerance is 5 %. Uniform noise is
    over-estimated by about 6 % (its fourth difference is flatter than a Gaussian: a larger MAD for its standard
    deviation), checked within [1.0, 1.12]."""
    _, clean, noisy = noisy_sine(sigma=2e-3, channels=2)
    np.testing.assert_allclose(calibration.noise_std(noisy), [2e-3, 2e-3], rtol=0.05)
    uniform = clean + 3e-3 * np.random.default_rng(1).uniform(-1.0, 1.0, clean.shape)
    ratio = calibration.noise_std(uniform) / (3e-3 / np.sqrt(3.0))
    assert np.all((ratio > 1.0) & (ratio < 1.12)), ratio


def test_noise_std_ignores_smooth_signals_and_rare_outliers():
    t = np.arange(5000) * DT
    cubic = 1.0 + 2.0 * t - 3.0 * t**2 + 0.5 * t**3  # a 4th difference of exactly 0, to rounding
    assert calibration.noise_std(cubic) < 1e-12
    _, _clean, noisy = noisy_sine(sigma=1e-3, seed=3)
    rng = np.random.default_rng(4)
    hit = rng.random(noisy.shape) < 0.01
    spiky = noisy + np.where(hit, rng.choice([-1.0, 1.0], noisy.shape), 0.0)  # 1 % gross errors of 1000 sigma
    np.testing.assert_allclose(calibration.noise_std(spiky), 1e-3, rtol=0.1)
    assert np.std(np.diff(spiky, 4, axis=0)) / np.sqrt(70) > 0.05  # what a plain standard deviation would say


# ----------------------------------------------------------------------------------------------------------------
# derivative bounds
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("derivative", [2, 3])
def test_derivative_bound_is_safety_times_the_quantile_of_the_true_derivative(derivative):
    r"""For :math:`A\sin\omega t` the ``r``-th derivative has amplitude :math:`A\omega^r` and its 99th percentile of
    absolute values is :math:`A\omega^r\sin(0.99\,\pi/2)`; noise-free and with noise of 1e-3 (which, differentiated
    at the sampling step, would give a quotient of order :math:`10^{-3}/\tau^r = 10^3` to :math:`10^6`), the
    bound is twice that to within 10 %."""
    _t, clean, noisy = noisy_sine(T=40000, sigma=1e-3, amplitude=2.0, omega=3.0)
    expected = 2.0 * 2.0 * 3.0**derivative * np.sin(0.99 * np.pi / 2)
    np.testing.assert_allclose(calibration.derivative_bound(clean, DT, derivative), expected, rtol=0.02)
    np.testing.assert_allclose(calibration.derivative_bound(noisy, DT, derivative), expected, rtol=0.10)
    naive = 2.0 * np.quantile(np.abs(np.diff(noisy[:, 0], derivative)), 0.99) / DT**derivative
    assert naive > 20 * expected  # without decimation the noise would set the gain


def _random_acceleration(T=5000, dt=1e-2, seed=0):
    """Samples ``y`` whose second differences are ``a dt^2`` for white Gaussian accelerations ``a``, and ``a``."""
    a = np.random.default_rng(seed).standard_normal(T - 2)
    return np.concatenate([[0.0, 0.0], np.cumsum(np.cumsum(a)) * dt**2]), a


def test_derivative_bound_and_level_of_noise_free_samples():
    """Noise-free samples (``noise=0``: the lag-1 quotients are the accelerations themselves, to rounding): the
    bound is twice the 99th percentile of the acceleration's magnitude, and the level its RMS, unclipped (Gaussian
    accelerations beyond twice that percentile, 5.2 standard deviations, have probability 2e-7)."""
    y, a = _random_acceleration()
    assert np.max(np.abs(a)) < 2.0 * np.quantile(np.abs(a), 0.99)
    np.testing.assert_allclose(
        calibration.derivative_bound(y, 1e-2, 2, noise=0.0), 2.0 * np.quantile(np.abs(a), 0.99), rtol=1e-6
    )
    np.testing.assert_allclose(calibration.derivative_rms(y, 1e-2, 2, noise=0.0), np.sqrt(np.mean(a**2)), rtol=1e-6)


def test_the_level_clips_gross_errors_at_the_worst_case_bound():
    """One sample off by 1 (a gross error of 10**4 accelerations' worth) enters three second differences: their
    quotients are clipped at twice the 99th percentile of all quotients, the rest is untouched."""
    y, _ = _random_acceleration()
    y[2500] += 1.0
    quotients = np.abs(np.diff(y, 2)) / 1e-4
    limit = 2.0 * np.quantile(quotients, 0.99)
    assert np.count_nonzero(quotients > limit) == 3
    expected = np.sqrt(np.mean(np.minimum(quotients, limit) ** 2))
    np.testing.assert_allclose(calibration.derivative_rms(y, 1e-2, 2, noise=0.0), expected, rtol=1e-6)


def test_a_channel_of_pure_noise_gets_the_quotient_at_the_last_lag():
    """White noise has no lag at which its difference quotient rises above the noise; the lags double while the
    next one spans at most half of the record (``2 s r <= T // 2``): for ``T = 4096``, ``r = 2`` the last lag
    is 1024, and the bound is twice the 99th percentile of the lag-1024 quotients."""
    T, dt, s = 4096, 1e-3, 1024
    y = 1e-3 * np.random.default_rng(1).standard_normal(T)
    second = y[2 * s :] - 2.0 * y[s:-s] + y[: -2 * s]
    expected = 2.0 * np.quantile(np.abs(second), 0.99) / (s * dt) ** 2
    np.testing.assert_allclose(calibration.derivative_bound(y, dt, 2, noise=1e-3), expected, rtol=1e-12)


def test_a_slow_derivative_shows_at_a_lag_spanning_up_to_half_the_record():
    r"""A cubic with :math:`f''' = 0.1` over 20 s at 1 ms under Gaussian noise 1e-2: at every lag spanning up to an
    eighth of the record the noise hides the jerk (at lag 512 the 99th percentile of the quotient is several times
    the jerk), and at lag 2048 (a span of 6 s) the noise part is below a quarter of it, so the bound is the safety
    factor 2 times the jerk plus at most a third: no longer mostly noise."""
    T, dt, jerk = 20000, 1e-3, 0.1
    t = np.arange(T) * dt
    y = jerk * t**3 / 6.0 + 1e-2 * np.random.default_rng(0).standard_normal(T)

    def quotient(s):
        third = y[3 * s :] - 3.0 * y[2 * s : -s] + 3.0 * y[s : -2 * s] - y[: -3 * s]
        return np.quantile(np.abs(third), 0.99) / (s * dt) ** 3

    assert quotient(512) > 5.0 * jerk  # the last lag of an eighth of the record
    bound = calibration.derivative_bound(y, dt, 3, noise=1e-2)
    assert 2.0 * jerk <= bound <= 2.0 * jerk * (1.0 + 1.0 / 3.0)
    np.testing.assert_allclose(bound, 2.0 * quotient(2048), rtol=1e-12)


def test_every_channel_is_calibrated_alone():
    """Channels are independent signals: a clean channel beside a noisy one (which needs a longer lag before its
    difference quotients rise above the noise) gets the bound and the level it gets alone, to rounding."""
    rng = np.random.default_rng(0)
    t = np.arange(5000) * 1e-3
    Y = np.column_stack([np.sin(3 * t), np.sin(2 * t) + 1e-2 * rng.standard_normal(t.size)])
    for level in (calibration.derivative_bound, calibration.derivative_rms):
        both = level(Y, 1e-3, 2)
        for c in range(2):
            np.testing.assert_allclose(both[c], level(Y[:, c], 1e-3, 2), rtol=1e-12)


def test_long_records_are_calibrated_on_a_random_subset(monkeypatch):
    """Above ``MAX_SAMPLES`` differences the statistics come from a random subset (fixed seed): the same numbers at
    every call, within 3 % of those of every difference (2^17 draws: standard errors below 1 %)."""
    _, _, noisy = noisy_sine(T=400000, sigma=1e-3, channels=2, omega=1.0)
    sub = calibration.noise_std(noisy), calibration.derivative_bound(noisy, DT, 2)
    np.testing.assert_array_equal(calibration.noise_std(noisy), sub[0])
    monkeypatch.setattr(calibration, "MAX_SAMPLES", 10**9)
    full = calibration.noise_std(noisy), calibration.derivative_bound(noisy, DT, 2)
    np.testing.assert_allclose(sub[0], full[0], rtol=0.03)
    np.testing.assert_allclose(sub[1], full[1], rtol=0.03)
    np.testing.assert_allclose(full[0], 1e-3, rtol=0.02)


def test_derivative_bound_per_channel_floor_and_validation():
    t = np.arange(4000) * DT
    Y = np.stack([np.sin(t), 10.0 * np.sin(t), np.full_like(t, 0.3)], axis=1).reshape(4000, 1, 3)
    b = calibration.derivative_bound(Y, DT, 2)
    assert b.shape == (1, 3)
    np.testing.assert_allclose(b[0, 1] / b[0, 0], 10.0, rtol=1e-6)
    assert b[0, 2] == calibration.BOUND_FLOOR  # a constant channel still gets a positive bound
    for kwargs, error in [
        (dict(dt=0.0), ValueError),
        (dict(dt=DT, derivative=0), ValueError),
        (dict(dt=DT, quantile=1.5), ValueError),
        (dict(dt=DT, noise=-1.0), ValueError),
        (dict(dt=DT, derivative=2.0), TypeError),
    ]:
        kwargs.setdefault("derivative", 2)
        with pytest.raises(error) as excinfo:
            calibration.derivative_bound(Y, **kwargs)
        assert "expected" in str(excinfo.value) and "actual value" in str(excinfo.value)
    with pytest.raises(ValueError, match="finite"):
        calibration.noise_std(np.array([0.0, 1.0, np.nan, 0.0, 1.0, 2.0]))
    with pytest.raises(TypeError, match="real numbers"):
        calibration.noise_std("abc")


# ----------------------------------------------------------------------------------------------------------------
# gain rules
# ----------------------------------------------------------------------------------------------------------------
def test_bound_order_and_needs_calibration():
    assert calibration.bound_order("super-twisting") == 2
    assert calibration.bound_order("levant") == 3
    assert calibration.bound_order("levant", {"order": 4}) == 5
    assert calibration.bound_order("high-gain", {"order": 2}) == 3  # HighGain.from_bounds bounds f^(order+1)
    assert calibration.bound_order("kalman-ca") == 3  # its process noise comes from the typical jerk
    assert not calibration.needs_calibration("finite-difference")
    assert calibration.needs_calibration("levant", {"order": 2})
    assert not calibration.needs_calibration("levant", {"lipschitz": 1.0})
    assert not calibration.needs_calibration("super-twisting", {"k1": 1.0, "k2": 2.0})
    assert calibration.needs_calibration("super-twisting", {"k1": 1.0})
    assert not calibration.needs_calibration("kalman-ca", {"process_noise": 1.0, "measurement_noise": 1.0})
    assert not calibration.needs_calibration("high-gain", {"gain": 3.0})
    assert not calibration.needs_calibration("ilf-finite", {"rate": 3.0})
    with pytest.raises(ValueError, match="kalman-ca"):
        calibration.needs_calibration("no-such-observer")


def _calibration(order, bounds, typical, noise, resolution=0.0):
    return calibration.Calibration(DT, {order: np.asarray(bounds)}, {order: np.asarray(typical)}, noise, resolution)


def test_default_observer_gain_formulas():
    noise = np.array([1e-4, 3e-4])
    acc = _calibration(2, [4.0, 9.0], [1.0, 2.0], noise)
    # the high-gain observers balance each channel's bound and noise: ell = (L / eps)^(1/n) per channel
    obs = calibration.default_observer("high-gain", acc, None)
    assert isinstance(obs, HighGain)
    np.testing.assert_allclose(obs.gain, np.sqrt([4.0 / 1e-4, 9.0 / 3e-4]))
    np.testing.assert_allclose(calibration.default_observer("low-power-high-gain", acc).gain, obs.gain)
    jerk = _calibration(3, [4.0, 9.0], [1.5, 0.5], noise)
    obs = calibration.default_observer("high-gain", jerk, {"order": 2})
    np.testing.assert_allclose(obs.gain, np.array([4.0 / 1e-4, 9.0 / 3e-4]) ** (1 / 3))
    # the Kalman filter reads the typical jerk J, q = J^2 dt, and the noise variance, per channel
    obs = calibration.default_observer("kalman-ca", jerk)
    assert isinstance(obs, KalmanCA)
    np.testing.assert_allclose(obs.process_noise, [1.5**2 * DT, 0.5**2 * DT])
    np.testing.assert_allclose(obs.measurement_noise, noise**2)
    # the sliding-mode differentiators the worst case, per channel
    obs = calibration.default_observer("super-twisting", acc, {"discretization": "euler"})
    assert isinstance(obs, SuperTwisting) and np.array_equal(obs.lipschitz, [4.0, 9.0])
    assert obs.discretization == "euler"
    obs = calibration.default_observer("levant", acc, {"lipschitz": 2.0})  # given gains win
    assert obs.lipschitz == 2.0


def test_a_calibration_without_the_order_a_family_needs_is_refused():
    acc = _calibration(2, [4.0], [1.0], [1e-3])
    with pytest.raises(ValueError, match=r"expected a calibration with typical of derivative order 3, actual value: "):
        calibration.default_observer("kalman-ca", acc)
    with pytest.raises(TypeError, match="expected a Calibration"):
        calibration.default_observer("kalman-ca", DT)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(dt=0.0), ValueError, "expected dt > 0"),
        (dict(noise=[-1.0]), ValueError, "expected noise finite and >= 0"),
        (dict(bounds={2: [np.nan]}), ValueError, r"expected bounds\[2\] finite and >= 0"),
        (dict(typical={2: [1.0, 2.0]}), ValueError, r"expected typical\[2\] of the channel shape \(1,\)"),
        (dict(bounds=[1.0]), TypeError, "expected bounds as a mapping of derivative order to array"),
        (dict(resolution=[1.0, 2.0]), ValueError, r"expected resolution of the channel shape \(1,\)"),
    ],
)
def test_calibration_bad_input(kwargs, error, match):
    fields = dict(dt=DT, bounds={2: [1.0]}, typical={2: [1.0]}, noise=[1e-3], resolution=0.0)
    with pytest.raises(error, match=match):
        calibration.Calibration(**{**fields, **kwargs})


@pytest.mark.parametrize(
    "function",
    [
        calibration.noise_std,
        calibration.quantization_step,
        lambda y: calibration.derivative_bound(y, DT, 2),
        lambda y: calibration.derivative_rms(y, DT, 2),
        lambda y: calibration.calibration_of_signal(y, DT, [2]),
    ],
)
def test_signal_calibration_refuses_what_is_not_a_real_record(function):
    """Complex samples lost their imaginary part with a warning, booleans and dates were taken as numbers, and a
    record without channels gave an empty answer: each is refused with what was expected."""
    t = np.arange(200.0)
    for bad in (np.exp(1j * t)[:, None], (t > 50)[:, None], np.arange(200).astype("datetime64[s]")[:, None]):
        with pytest.raises(TypeError, match="expected y to be an array of real numbers"):
            function(bad)
    with pytest.raises(ValueError, match="at least one channel"):
        function(np.zeros((200, 0)))


def test_calibration_from_velocities_refuses_what_are_not_episodes():
    good = np.zeros((10, 2))
    for bad, error in (
        (np.float64(1.0), TypeError),  # not a list of episodes
        (good, TypeError),  # one array: its rows would be taken for episodes
        ([good, np.zeros((10, 3))], ValueError),  # different numbers of dofs
        ([np.zeros(10)], ValueError),  # an episode without the dof axis
        ([good, np.full((10, 2), np.nan)], ValueError),
        ([good.astype(bool)], TypeError),
        ([], ValueError),
    ):
        with pytest.raises(error, match="expected episodes"):
            calibration.calibration_from_velocities(bad, DT, (2,), noise=0.0)


@pytest.mark.parametrize("dt", [1e300, 1e80, 1e-300])
def test_a_step_whose_powers_leave_the_float_range_is_refused(dt):
    """The lag quotients divide by ``(s dt)^r`` (``^2r`` for the mean square): an OverflowError, or a division by
    zero with a warning, before; a typed error now, also through :func:`smo_gym.differentiate`."""
    import warnings

    import smo_gym

    y = np.sin(np.arange(200) * 0.01)[:, None]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        calls = [lambda: calibration.derivative_rms(y, dt, 3), lambda: smo_gym.differentiate(y, dt, "kalman-ca")]
        if dt != 1e80:  # (200 dt)^3 is a float, (200 dt)^6 is not
            calls.append(lambda: calibration.derivative_bound(y, dt, 3))
        for call in calls:
            with pytest.raises(ValueError, match=r"expected dt for which \(lag dt\)\^"):
                call()


def test_quantization_step_of_a_single_sample_is_not_known():
    np.testing.assert_array_equal(calibration.quantization_step(np.ones((1, 3))), np.zeros(3))


def test_calibration_arrays_are_read_only():
    c = _calibration(2, [4.0], [1.0], [1e-3])
    with pytest.raises(ValueError, match="read-only"):
        c.bound(2)[0] = 1.0


def test_derivative_rms_matches_the_closed_form():
    """The RMS of :math:`f'' = -A\\omega^2\\sin\\omega t` over whole periods is :math:`A\\omega^2/\\sqrt2`: from clean
    samples to 1 %, and from noisy ones (the noise part of the difference quotient subtracted) to 5 %."""
    _, clean, noisy = noisy_sine(T=20944, sigma=1e-3, amplitude=2.0, omega=3.0)  # 10 periods
    expected = 2.0 * 9.0 / np.sqrt(2.0)
    np.testing.assert_allclose(calibration.derivative_rms(clean, DT, 2), expected, rtol=0.01)
    np.testing.assert_allclose(calibration.derivative_rms(noisy, DT, 2), expected, rtol=0.05)
    # without the subtraction the noise would dominate at the sampling step: sigma sqrt(6) / dt^2 ~ 2e3
    assert np.sqrt(np.mean((np.diff(noisy[:, 0], 2) / DT**2) ** 2)) > 100 * expected


def test_a_level_the_noise_hides_continues_the_two_below_it():
    r"""A sine (amplitude 1, 1 Hz, one period at 1 ms) under noise 0.3: the record gives no estimate of its jerk
    (at every lag, up to a span of half the record, the mean square of the difference quotient less its noise part
    is not positive, and :func:`derivative_rms` returns its floor), and the record's calibration takes the next
    term of the velocity and acceleration levels, :math:`a^2/v`, which for a sine is its jerk level
    :math:`\omega^3/\sqrt2` (measured 1.05 times). At its floor (1e-3 times the velocity bound) the level was
    about 10^4 times too small."""
    omega = 2.0 * np.pi
    _, _, noisy = noisy_sine(T=1000, sigma=0.3, amplitude=1.0, omega=omega)
    assert calibration.derivative_rms(noisy, DT, 3) < 0.1  # no estimate: the floor
    found = calibration.calibration_of_signal(noisy, DT, (3,))
    np.testing.assert_allclose(found.rms(3), found.rms(2) ** 2 / found.rms(1))
    np.testing.assert_allclose(found.rms(3), omega**3 / np.sqrt(2.0), rtol=0.1)


def test_derivative_rms_ignores_rare_gross_errors():
    """The ``outliers`` sensor (the noisy 12-bit encoder, one sample in a thousand off by a Gaussian error of 0.1) on
    ``sin(3t)`` at 1 ms: the typical acceleration and jerk (true RMS 6.36 and 19.1) within 5 % of what the
    outlier-free sensor gives (measured: 6.36-6.39 and 18.6-18.8 without, 6.46-6.53 and 18.8-19.0 with the
    outliers; an unclipped mean square made the jerk level 10**6 times too large), and ``differentiate``'s
    default, whose Kalman filter is built from them, keeps its velocity error small (measured 0.040 against 0.021
    without the outliers; about 4 before the clip)."""
    t = np.arange(20000)[:, None] * DT
    y, v = np.sin(3.0 * t + np.arange(4)), 3.0 * np.cos(3.0 * t + np.arange(4))
    levels, errors = {}, {}
    for preset in ("encoder-12bit-noisy", "outliers"):
        sensor = smo_gym.sensors.PRESETS[preset]()
        Y = np.concatenate([sensor.reset(y[0], seed=0)[None], sensor.run(y[1:])])
        found = calibration.calibration_of_signal(Y, DT, (2, 3))
        levels[preset] = np.stack([found.rms(2), found.rms(3)])
        errors[preset] = np.sqrt(np.mean((smo_gym.differentiate(Y, DT)[2000:, :, 1] - v[2000:]) ** 2))
    np.testing.assert_allclose(levels["outliers"], levels["encoder-12bit-noisy"], rtol=0.05)
    np.testing.assert_allclose(levels["outliers"][0], 9.0 / np.sqrt(2.0), rtol=0.05)
    assert errors["outliers"] < 0.1, errors


def test_calibration_from_velocities_levels():
    """Worst case = safety x quantile and typical = RMS of the backward differences, per dof; a dof that never
    moved gets the model's largest value."""
    rng = np.random.default_rng(0)
    V = np.column_stack([np.cumsum(rng.normal(size=4000)) * DT, np.zeros(4000)])
    c = calibration.calibration_from_velocities([V[:2500], V[2500:]], DT, (2,), noise=[1e-3, 1e-3])
    A = np.abs(np.concatenate([np.diff(V[:2500, 0]), np.diff(V[2500:, 0])])) / DT
    assert c.bound(2)[0] == pytest.approx(2.0 * np.quantile(A, 0.99))
    assert c.rms(2)[0] == pytest.approx(np.sqrt(np.mean(A**2)))
    assert c.bound(2)[1] == c.bound(2)[0] and c.rms(2)[1] == c.rms(2)[0]
    # where the episodes start: the RMS over episodes of the first velocity and of its first difference, floored
    # (the dof at rest: a Kalman filter's prior must be positive)
    firsts = np.array([V[0], V[2500]])
    np.testing.assert_allclose(c.initial[1], np.maximum(np.sqrt(np.mean(firsts**2, axis=0)), calibration.BOUND_FLOOR))
    slopes = np.array([V[1] - V[0], V[2501] - V[2500]]) / DT
    np.testing.assert_allclose(c.initial[2], np.maximum(np.sqrt(np.mean(slopes**2, axis=0)), calibration.BOUND_FLOOR))
    assert c.initial[1][1] == c.initial[2][1] == calibration.BOUND_FLOOR
    with pytest.raises(ValueError, match="initial levels > 0"):
        calibration.Calibration(DT, c.bounds, c.typical, c.noise, initial={1: [0.1, 0.0], 2: [1.0, 1.0]})


def test_calibration_rows_round_trip():
    """``as_rows`` / ``from_rows`` (the layout of the wrappers' cache) give back the calibration, with and without
    where the episodes start."""
    rng = np.random.default_rng(2)
    V = np.cumsum(rng.normal(size=(600, 3)), axis=0) * DT
    for episodes in ([V[:300], V[300:]], [V[:1], V[1:2]]):  # one-sample episodes: no start known
        c = (
            calibration.calibration_from_velocities(episodes, DT, (2, 3), noise=[1e-3, 2e-3, 3e-3])
            if len(episodes[0]) > 1
            else calibration.Calibration(DT, {2: [1.0, 2.0, 3.0], 3: [4.0, 5.0, 6.0]}, {2: 1, 3: 2}, [1e-3] * 3)
        )
        back = calibration.Calibration.from_rows(c.as_rows((2, 3)), (2, 3), DT, c.noise, c.resolution)
        for r in (2, 3):
            np.testing.assert_array_equal(back.bound(r), c.bound(r))
            np.testing.assert_array_equal(back.rms(r), c.rms(r))
        assert back.initial.keys() == c.initial.keys()
        for r in c.initial:
            np.testing.assert_array_equal(back.initial[r], c.initial[r])


def test_the_kalman_prior_comes_from_where_the_episodes_start():
    r"""A Kalman filter's prior is the distribution of the initial state. Episodes of 40 samples (10 ms, noise
    1e-3) of a motion at constant acceleration that start from velocities ~ N(0, 0.05^2) and accelerations ~ N(0,
    2^2): the calibration of their velocities gives the filter that prior (``initial_std`` = the RMS of the first
    velocity and acceleration), and its velocity RMSE over the episodes is below 0.6x the default wide prior's
    (10, 100) (measured 0.46x: the wide prior makes the first estimates least-squares fits of a few noisy samples).
    A given ``initial_std`` is kept; a recorded signal (no episodes) gets its velocity's and acceleration's bounds,
    each channel its own."""
    rng = np.random.default_rng(1)
    dt, n, T = 0.01, 200, 40
    t = np.arange(T) * dt
    v0, a0 = rng.normal(0.0, 0.05, n), rng.normal(0.0, 2.0, n)
    V = v0[:, None] + a0[:, None] * t  # (episodes, T)
    Y = np.cumsum(np.concatenate([np.zeros((n, 1)), V[:, :-1] * dt], axis=1), axis=1) + 1e-3 * rng.normal(size=(n, T))
    found = calibration.calibration_from_velocities([v[:, None] for v in V], dt, (3,), noise=1e-3)
    calibrated = calibration.default_observer("kalman-ca", found)
    np.testing.assert_allclose(calibrated.initial_std, (found.initial[1], found.initial[2]))
    wide = calibration.default_observer("kalman-ca", found, {"initial_std": (10.0, 100.0)})
    assert wide.initial_std == (10.0, 100.0)

    def rmse(observer):
        errors = []
        for y, v in zip(Y, V, strict=True):
            est = np.concatenate([observer.reset(y[:1])[None], observer.run(y[1:, None])])[:, 0, 1]
            errors.append(est[1:] - v[1:])
        return np.sqrt(np.mean(np.square(errors)))

    assert rmse(calibrated) < 0.6 * rmse(wide)
    recorded = calibration.calibration_of_signal(Y[:2].T, dt, (3,))
    assert all(np.array_equal(recorded.initial[r], recorded.bounds[r]) for r in (1, 2))
    prior = calibration.default_observer("kalman-ca", recorded).initial_std
    for r, std in zip((1, 2), prior, strict=True):
        np.testing.assert_array_equal(std, recorded.bounds[r])
    assert np.ptp(recorded.bounds[2]) > 0.0  # two channels, two priors


# ----------------------------------------------------------------------------------------------------------------
# differentiate: the wrapper's names, no gains needed
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name",
    [
        "kalman-ca",
        "high-gain",
        "super-twisting",
        "levant",
        "ured",
        "switched-gain",
        "low-power-high-gain",
        "finite-difference",
    ],
)
def test_differentiate_without_gains_is_calibrated_from_the_data(name):
    """``observer=`` takes the wrapper's names and every one works with no gains: calibrated from the data, the
    velocity of a noisy sine is within 0.05 (RMS) of the truth after the transient (finite differences: their
    noise level :math:`\\sqrt2\\sigma/\\tau`). Before, ``kalman-ca`` and ``high-gain`` raised ``TypeError`` and
    ``super-twisting`` ``ValueError``."""
    t, _clean, noisy = noisy_sine(T=10000, sigma=1e-4)
    z = smo_gym.differentiate(noisy[:, 0], DT, observer=name)
    assert z.shape == (10000, OBSERVERS[name](**_minimal(name)).order + 1)
    error = z[2000:, 1] - 3.0 * np.cos(3.0 * t[2000:])
    rms = np.sqrt(np.mean(error**2))
    assert rms < (0.2 if name == "finite-difference" else 0.05), rms


def _minimal(name):
    """Enough constructor arguments to read the default order."""
    params = {"dt": DT}
    if name in ("super-twisting", "ured"):
        params["lipschitz"] = 1.0
    if name in ("high-gain", "low-power-high-gain"):
        params["gain"] = 1.0
    if name == "kalman-ca":
        params.update(process_noise=1.0, measurement_noise=1.0)
    return params


@pytest.mark.parametrize("name", ["super-twisting", "kalman-ca"])
def test_differentiate_calibrated_equals_the_calibration_functions(name):
    """The calibrated observer is exactly ``default_observer`` with the ``calibration_of_signal`` of the data
    (passing that object gives the same numbers, from either start), per channel for ``(T, 2, 3)`` data."""
    _, _, noisy = noisy_sine(T=3000, sigma=1e-4, channels=6)
    Y = noisy.reshape(3000, 2, 3)
    c = calibration.calibration_of_signal(Y, DT, (calibration.bound_order(name),))
    np.testing.assert_allclose(c.noise, 1e-4, rtol=0.25)  # the data's noise level, per channel
    obs = calibration.default_observer(name, c)
    for start in ("measurement", "kalman"):
        np.testing.assert_array_equal(
            smo_gym.differentiate(Y, DT, observer=name, start=start),
            smo_gym.differentiate(Y, DT, observer=obs, start=start),
        )
    assert obs.shape is None  # the object passed in is copied, not run


@pytest.mark.parametrize("name", ["kalman-ca", "auto", "levant"])
def test_differentiate_does_not_depend_on_the_memory_layout(name):
    """The same record in C order, in Fortran order and transposed (``axis=1``) gives the same estimates bit for
    bit: the calibration's levels are means, whose sums NumPy orders by the layout (the jerk level of a Fortran
    record was one ulp off, the Kalman filter's estimates 1e-13)."""
    rng = np.random.default_rng(3)
    t = np.arange(600) * 1e-2
    y = np.stack([3 * t + 0.5 * np.sin(2 * t), np.cos(1.3 * t), 0.2 * t**2], 1) + 1e-4 * rng.standard_normal((600, 3))
    reference = smo_gym.differentiate(y, 1e-2, name)
    np.testing.assert_array_equal(smo_gym.differentiate(np.asfortranarray(y), 1e-2, name), reference)
    transposed = smo_gym.differentiate(np.ascontiguousarray(y.T), 1e-2, name, axis=1)
    np.testing.assert_array_equal(np.moveaxis(transposed, 1, 0), reference)


@pytest.mark.parametrize("observer", ["levant", "auto"])
def test_differentiate_asks_to_rescale_a_record_whose_variance_overflows(observer):
    """A record of amplitude 1e300 has a noise level whose square overflows: a ``ValueError`` that says to rescale,
    without overflow warnings first (it had warned three times, then named the Kalman start's ``measurement_noise``,
    a parameter the user never passed)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"noise level of 2\.84e\+300; rescale the record"):
            smo_gym.differentiate(np.array([1e300, -1e300] * 40), 1e-2, observer)


def test_differentiate_method_alias_axis_and_errors():
    _, _, noisy = noisy_sine(T=500, channels=3)
    ref = smo_gym.differentiate(noisy, DT, observer="levant", order=2, lipschitz=30.0)
    np.testing.assert_array_equal(smo_gym.differentiate(noisy, DT, method="levant", order=2, lipschitz=30.0), ref)
    np.testing.assert_array_equal(smo_gym.differentiate(noisy, DT, "levant", order=2, lipschitz=30.0), ref)
    along_last = smo_gym.differentiate(noisy.T, DT, observer="levant", axis=-1, order=2, lipschitz=30.0)
    assert along_last.shape == (3, 500, 3)
    np.testing.assert_array_equal(along_last, np.moveaxis(ref, 0, 1))
    cases = [
        (lambda: smo_gym.differentiate(noisy, DT, observer="levant", method="levant"), TypeError),
        (
            lambda: smo_gym.differentiate(noisy, DT, observer=make_observer("finite-difference", dt=DT), order=1),
            TypeError,
        ),
        (lambda: smo_gym.differentiate(noisy, 2 * DT, observer=make_observer("finite-difference", dt=DT)), ValueError),
        (lambda: smo_gym.differentiate(noisy, DT, axis=2), ValueError),
        (lambda: smo_gym.differentiate(noisy, -DT), ValueError),
        (lambda: smo_gym.differentiate(np.zeros((0, 3)), DT), ValueError),
        (lambda: smo_gym.differentiate(np.where(np.arange(500)[:, None] == 7, np.nan, noisy), DT), ValueError),
        (lambda: smo_gym.differentiate(noisy, DT, observer="levant", wrap=[True, False]), ValueError),
    ]
    for call, error in cases:
        with pytest.raises(error) as excinfo:
            call()
        assert "expected" in str(excinfo.value) and "actual value" in str(excinfo.value), excinfo.value


def test_differentiate_calibrates_wrapped_angles_on_the_unwrapped_signal():
    """With ``wrap`` the calibration sees the continuous angle: the jumps of 2 pi would otherwise set a bound of
    order ``2 pi / dt^2``. The calibrated observer estimates the spin rate once it has caught up from zero (its
    gain ``k2 = 1.1 L`` with ``L`` about twice the largest acceleration, 8: about three seconds to reach 30)."""
    t = np.arange(8000) * DT
    true = 30.0 * t + 0.5 * np.sin(4.0 * t)
    wrapped = np.mod(true + np.pi, 2 * np.pi) - np.pi + 1e-4 * np.random.default_rng(5).standard_normal(t.size)
    z = smo_gym.differentiate(wrapped, DT, observer="super-twisting", wrap=True)
    rate = 30.0 + 2.0 * np.cos(4.0 * t)
    assert np.sqrt(np.mean((z[5000:, 1] - rate[5000:]) ** 2)) < 0.1
    bound = calibration.derivative_bound(np.unwrap(wrapped), DT, 2)
    assert bound < 100.0 < calibration.derivative_bound(wrapped, DT, 2)


def test_the_sensor_declares_its_quantization_step():
    """An encoder's step is 2 pi / counts on angular channels and its linear resolution on linear ones; noise alone
    has none; the calibration of a wrapped environment carries the sensor's."""
    from smo_gym import sensors

    encoder = sensors.Encoder(counts_per_revolution=4096, linear_resolution=1e-4) | sensors.GaussianNoise(1e-3)
    np.testing.assert_allclose(
        encoder.quantization_step(3, angular=[True, False, True]), [2 * np.pi / 4096, 1e-4, 2 * np.pi / 4096]
    )
    np.testing.assert_array_equal(sensors.GaussianNoise(1e-3).quantization_step(2), [0.0, 0.0])
    import gymnasium as gym

    from smo_gym.wrappers import EstimatedVelocity

    env = EstimatedVelocity(gym.make("InvertedPendulum-v5"), sensor="encoder-12bit", observer="kalman-ca")
    np.testing.assert_array_equal(env.calibration.resolution, env.measurement.quantization_step())
    assert env.calibration.resolution[1] == pytest.approx(2 * np.pi / 4096)  # the hinge


def test_a_slow_quantized_staircase_gets_the_rounding_error_as_its_noise_level():
    """A ramp of 1e-4 per sample read by a 12-bit encoder (one count per ~15 samples) is a staircase whose
    differences are mostly zero: without a floor the noise estimate was 0 and the jerk bound 6e6 (the true jerk is
    0), which made ``differentiate`` without gains chatter by rad/s."""
    dt, step = 1e-3, 2 * np.pi / 4096
    y = 0.3 + 0.1 * np.arange(20000) * dt
    Y = (step * np.floor(y / step + 0.5))[:, None]
    np.testing.assert_allclose(calibration.noise_std(Y), step / np.sqrt(12.0), rtol=1e-12)
    c = calibration.calibration_of_signal(Y, dt, (3,))
    assert c.bound(3)[0] < 10.0 and c.rms(3)[0] < 10.0, (c.bound(3), c.rms(3))
    z = smo_gym.differentiate(Y[:, 0], dt, observer="levant")
    assert np.sqrt(np.mean((z[5000:, 1] - 0.1) ** 2)) < 0.05
    # a channel that moves by many counts per sample is not a staircase: no floor
    _, _, noisy = noisy_sine(T=5000, sigma=0.0)
    fine = step * np.floor(noisy / step + 0.5)
    assert calibration._staircase_std(fine)[0] == 0.0


def test_a_joint_that_rests_and_moves_fast_gets_the_rounding_error_of_one_count():
    """A 12-bit encoder on a joint that stands still 70 % of the time and moves at 3 rad/s (two counts per sample)
    in between: a staircase whose quantization error is that of one count, :math:`\\Delta/\\sqrt{12}`, however
    far it moves when it moves (the typical move, two counts, doubled the estimate), and whose lattice step is the
    count."""
    dt, step = 1e-3, 2 * np.pi / 4096
    t = np.arange(20000) * dt
    v = np.where(t % 1.0 < 0.3, 3.0, 0.0) * np.where(t % 2.0 < 1.0, 1.0, -1.0)
    Y = (step * np.floor((0.2 + np.cumsum(v) * dt) / step + 0.5))[:, None]
    moves = np.abs(np.diff(Y[:, 0]))
    assert 0.6 < np.mean(moves == 0.0) < 0.8 and np.median(moves[moves > 0]) > 1.5 * step
    np.testing.assert_allclose(calibration.noise_std(Y), step / np.sqrt(12.0), rtol=1e-9)
    np.testing.assert_allclose(calibration.quantization_step(Y), step, rtol=1e-9)
    # nine moves are too few to show a lattice: the median move stands in for the count
    few = step * np.repeat(np.arange(10.0), 500)[:, None]
    assert calibration.quantization_step(few)[0] == 0.0
    np.testing.assert_allclose(calibration.noise_std(few), step / np.sqrt(12.0), rtol=1e-9)


def test_the_lattice_of_a_signal_that_moves_many_counts_per_sample():
    """``sin(30 t)`` at 1 ms through a 12-bit encoder moves by 14 counts in the median sample and by one count only
    near its turning points: the step is the smallest move, of which all others are multiples."""
    step = 2 * np.pi / 4096
    Y = step * np.round(np.sin(30.0 * np.arange(5000) * DT) / step)
    moves = np.abs(np.diff(Y))
    assert np.median(moves[moves > 0]) > 10 * step
    np.testing.assert_allclose(calibration.quantization_step(Y[:, None]), [step], rtol=1e-9)


def test_quantization_step_asks_for_its_share_of_lattice_moves():
    """Gross errors of 5 to 50 counts (any real number of them) in 2 % of the samples of a lattice signal: about
    88 % of the moves are on the lattice, below the default share of 0.99 (no step) and above a share of 0.8."""
    step = 0.01
    t = np.arange(4000) * DT
    Y = step * np.round(np.sin(3.0 * t) / step)
    rng = np.random.default_rng(0)
    hit = np.flatnonzero(rng.random(t.size) < 0.02)
    Y[hit] += step * rng.uniform(5.0, 50.0, hit.size) * rng.choice([-1.0, 1.0], hit.size)
    moves = np.abs(np.diff(Y))
    moves = moves[moves > 0] / step
    assert 0.8 < np.mean(np.abs(moves - np.round(moves)) < 1e-6) < 0.95
    assert calibration.quantization_step(Y[:, None])[0] == 0.0
    np.testing.assert_allclose(calibration.quantization_step(Y[:, None], share=0.8), [step], rtol=1e-9)


def test_calibration_refuses_values_that_are_not_real_numbers():
    with pytest.raises(TypeError, match="expected noise to be an array of real numbers"):
        calibration.Calibration(DT, {2: [1.0]}, {2: [1.0]}, ["a"])
    with pytest.raises(TypeError, match=r"expected bounds\[2\] to be an array of real numbers"):
        calibration.Calibration(DT, {2: [1.0 + 1j]}, {2: [1.0]}, [1e-3])


@pytest.mark.parametrize("preset", ["ideal", "encoder-12bit", "encoder-12bit-noisy", "low-cost"])
def test_quantization_step_is_recovered_from_the_data(preset):
    """An unknown sensor's quantization step is the lattice its samples lie on: each preset's declared step (12 and
    10 bits, noise before or after the rounding), and 0 without quantization."""
    from smo_gym.calibration import quantization_step
    from smo_gym.sensors import make_sensor

    t = np.arange(0.0, 5.0, 1e-3)
    f = np.column_stack([np.sin(t), 0.3 * np.cos(2 * t) + 1.7])
    sensor = make_sensor(preset)
    y = np.vstack([sensor.reset(f[0], seed=0), sensor.run(f[1:])])
    np.testing.assert_allclose(quantization_step(y), sensor.quantization_step(2), rtol=1e-9)
    found = calibration.calibration_of_signal(y, 1e-3, (2,)).resolution
    np.testing.assert_allclose(found, sensor.quantization_step(2), rtol=1e-9)
    given = calibration.calibration_of_signal(y, 1e-3, (2,), resolution=0.0)  # a given step wins
    assert np.all(given.resolution == 0.0)


def test_quantization_step_refuses_what_is_not_a_lattice():
    from smo_gym.calibration import quantization_step

    rng = np.random.default_rng(0)
    t = np.arange(0.0, 2.0, 1e-3)
    noisy = np.round(np.sin(t) / 0.01) * 0.01 + 1e-4 * rng.standard_normal(t.size)  # noise after the rounding
    still = np.zeros(t.size)  # never moves: no step to see
    few = np.where(t < 0.01, 0.0, 0.01)  # one move: too little evidence
    np.testing.assert_array_equal(quantization_step(np.column_stack([noisy, still, few])), 0.0)


@pytest.mark.parametrize("name", ["kalman-ca", "kalman-imm"])
def test_a_kalman_filter_given_one_noise_calibrates_the_other(name):
    """``differentiate(y, dt, "kalman-ca", process_noise=1.0)`` was refused ("no default gains are known ... given by
    position and by keyword"): the rule passed both noises by position and the given one again by keyword. The
    given one is kept, the other comes from the calibration as when neither is given."""
    dt = 0.01
    y = np.sin(np.arange(400) * dt)[:, None] + 1e-3 * np.random.default_rng(0).standard_normal((400, 1))
    cal = calibration.calibration_of_signal(y, dt, (3,))
    both = calibration.default_observer(name, cal)
    q_only = calibration.default_observer(name, cal, {"process_noise": 2.0})
    r_only = calibration.default_observer(name, cal, {"measurement_noise": 1e-4})
    np.testing.assert_array_equal(q_only.process_noise, 2.0)
    np.testing.assert_array_equal(q_only.measurement_noise, both.measurement_noise)
    np.testing.assert_array_equal(r_only.process_noise, both.process_noise)
    np.testing.assert_array_equal(r_only.measurement_noise, 1e-4)
    assert np.all(np.isfinite(smo_gym.differentiate(y, dt, name, process_noise=2.0)))


def test_a_refused_gain_value_keeps_its_own_error():
    """A gain of the wrong type is the validator's TypeError, not "no default gains are known" (the rule calibrates
    the other gains; only a missing argument of a family without a rule is that message's case)."""
    with pytest.raises(TypeError, match="expected filtering_order to be an integer"):
        smo_gym.differentiate(np.sin(np.arange(400) * 0.01), 0.01, "filtering", filtering_order=1.0)


def test_samples_near_the_float_limit_and_bad_options_are_refused():
    """Finite samples of +-1e308 overflowed in their differences: ``noise_std`` returned NaN and ``derivative_bound``
    the floor (a lag whose difference is 0 'settled'). Options were converted without a check (``share=nan`` found
    no step in a quantized signal, ``minimum=-5``, ``safety=-1`` gave floor bounds)."""
    y = np.array([-1e308, 1e308] * 50)
    for call in (
        lambda: calibration.noise_std(y),
        lambda: calibration.derivative_bound(y, 0.01, 1, noise=0.0),
        lambda: calibration.quantization_step(y),
        lambda: smo_gym.differentiate(y, 0.01),
    ):
        with pytest.raises(ValueError, match="rescale the signal"):
            call()
    ramp = np.arange(100.0) * 0.01
    for kwargs in ({"share": np.nan}, {"minimum": -5}, {"tolerance": -1.0}):
        with pytest.raises(ValueError, match="expected"):
            calibration.quantization_step(ramp, **kwargs)
    for kwargs in ({"safety": -1.0}, {"quantile": 2.0}):
        with pytest.raises(ValueError, match="expected"):
            calibration.calibration_from_velocities([np.ones((10, 2))], 0.01, (2,), noise=0.0, **kwargs)
    for noise in (10**400, True, "abc"):
        with pytest.raises(TypeError, match="expected noise"):
            calibration.derivative_bound(np.sin(ramp), 0.01, 2, noise=noise)


def test_messages_name_what_the_caller_gave():
    """A sensor option of the wrong type was reported as a missing option; ``parse_value`` of a non-string raised
    AttributeError; an observer order beyond what a calibration can bound was "derivative 101"; an array ``start``
    raised NumPy's ambiguous truth value."""
    from smo_gym import specs

    with pytest.raises(TypeError, match="expected samples to be an integer"):
        specs.make_sensor("delay:samples=2.5")
    with pytest.raises(ValueError, match="expected the options samples"):
        specs.make_sensor("delay")
    with pytest.raises(TypeError, match="as a string"):
        specs.parse_value(None)
    y = np.sin(np.arange(400) * 0.01)
    with pytest.raises(ValueError, match=r"observer of order n bound the derivative n \+ 1.*101"):
        smo_gym.differentiate(y, 0.01, "levant", order=100)
    with pytest.raises(ValueError, match="expected start"):
        smo_gym.differentiate(y, 0.01, start=np.array([1, 2]))


def test_rows_of_another_layout_are_refused():
    """``Calibration.from_rows`` read rows of any count (too few raised zip's bare message, too many were dropped)."""
    cal = calibration.calibration_of_signal(np.sin(np.arange(400) * 0.01)[:, None], 0.01, (2, 3))
    rows = cal.as_rows((2, 3))
    np.testing.assert_array_equal(
        calibration.Calibration.from_rows(rows, (2, 3), 0.01, cal.noise).bound(3), cal.bound(3)
    )
    for bad in (rows[:3], np.vstack([rows, rows[:1]]), rows[:, 0]):
        with pytest.raises(ValueError, match="expected rows of shape"):
            calibration.Calibration.from_rows(bad, (2, 3), 0.01, cal.noise)
