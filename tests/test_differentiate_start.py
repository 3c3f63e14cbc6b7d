"""How ``smo_gym.differentiate`` starts a differentiator: at the first measurement, or from the calibrated Kalman
filter's estimate once the filter's prior is forgotten.

A sliding-mode differentiator started at rest converges in a time that grows as its gain falls (Levant 2003); on a
slow signal with a small calibrated bound that is longer than the record. The Kalman start removes that transient:
checked on a cubic polynomial (the error after 2 s, against the measurement start and against the Kalman filter
alone), transcribed from its definition (filter, settling count, reset, run), with the settling count re-derived
from the filter's own covariance, and for the defaults, short records, wrapped angles and bad input.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import smo_gym
from smo_gym import calibration
from smo_gym.observers import OBSERVERS, KalmanCA, make_observer
from smo_gym.observers.composite import PerChannel

DT = 1e-3


def cubic(T: int = 20000, channels: int = 4, noise: float = 1e-3, seed: int = 0):
    """A slow cubic (its third derivative about 0.01) with a velocity near 1 at the start, and noisy samples."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-2.0, 2.0, (3, channels))
    scale = 2.0 / (T * DT)
    u = (scale * np.arange(T) * DT - 1.0)[:, None]
    y = c[0] * u + c[1] * u**2 + c[2] * u**3
    v = scale * (c[0] + 2 * c[1] * u + 3 * c[2] * u**2)
    return y + noise * rng.standard_normal(y.shape), v


def rmse_after(estimate, truth, seconds: float = 2.0) -> float:
    skip = round(seconds / DT)
    return float(np.sqrt(np.mean((estimate[skip:] - truth[skip:]) ** 2)))


@pytest.mark.parametrize(
    "name, gain, of_kalman", [("filtering", 40.0, 0.5), ("levant", 25.0, 1.0), ("super-twisting", 3.0, None)]
)
def test_kalman_start_removes_the_slow_start(name, gain, of_kalman):
    """Velocity RMSE after 2 s (seed 0): filtering 0.095 from the measurement, 0.0012 from the Kalman start;
    Levant (order 2) 0.12 and 0.0024; super-twisting 0.020 and 0.0056; the Kalman filter alone 0.0039. Asserted:
    the start gains at least ``gain`` (about half the measured factor), and the second-order differentiators, whose
    model is the filter's, end up below ``of_kalman`` times the filter they started from (super-twisting, first
    order, does not: its error is its noise floor, not the start). Levant's recursion, with the calibrated bound
    2.2-4.3 times the true jerk, is 0.63 times the filter (0.0013 and 0.0010 with 3 and 10 times that bound; 0.22
    when the bound was mostly noise, before the calibration's lags reached half the record)."""
    Y, v = cubic()
    kalman = rmse_after(smo_gym.differentiate(Y, DT, observer="kalman-ca")[..., 1], v)
    at_rest = rmse_after(smo_gym.differentiate(Y, DT, observer=name, start="measurement")[..., 1], v)
    started = rmse_after(smo_gym.differentiate(Y, DT, observer=name)[..., 1], v)
    assert started < at_rest / gain, (started, at_rest)
    if of_kalman is not None:
        assert started < of_kalman * kalman, (started, kalman)


@pytest.mark.parametrize("name, params", [("filtering", {}), ("levant", {"order": 3}), ("super-twisting", {})])
def test_kalman_start_is_the_filter_then_the_observer(name, params):
    """The definition, step by step from the public pieces: the calibrated Kalman filter up to its settling sample
    ``m``, then the calibrated observer reset at the filter's estimate there (as many derivatives as both have)."""
    Y, _ = cubic(T=6000, channels=3)
    got = smo_gym.differentiate(Y, DT, observer=name, **params)

    found = calibration.calibration_of_signal(Y, DT, sorted({calibration.bound_order(name, params), 3}))
    kf = calibration.default_observer("kalman-ca", found)
    m = kf.settling_samples(limit=Y.shape[0] - 1)
    assert 10 < m < Y.shape[0] - 1  # a slow signal: a long start, yet one that ends
    head = smo_gym.differentiate(Y[: m + 1], DT, observer=kf)
    obs = calibration.default_observer(name, found, params)
    k = min(obs.order, 2)
    obs.reset(head[m, :, 0], derivatives=head[m, :, 1 : k + 1])
    tail = obs.run(Y[m + 1 :])

    assert got.shape == Y.shape + (obs.order + 1,)
    np.testing.assert_array_equal(got[: m + 1, :, : k + 1], head[..., : k + 1])
    np.testing.assert_array_equal(got[: m + 1, :, k + 1 :], 0.0)
    np.testing.assert_array_equal(got[m + 1 :], tail)


def test_settling_samples_follows_the_filters_own_covariance():
    """Checked channel by channel against :attr:`KalmanCA.covariance` after each update (the steady state taken
    where the recursion stops moving, not from a formula), for ``rho = q dt**5 / r`` from 1e-12 to 1e-4: at the
    count the velocity's standard deviation is within a factor 2 of its steady state, and 10 % earlier it is not
    (the count does not waste samples); a multi-channel filter returns the largest count."""
    dt = 1e-2
    q = np.array([1.0, 1e-2, 1e-4, 1e-6])
    r = np.array([1e-6, 1e-4, 1e-4, 1e-4])  # rho 1e-4, 1e-8, 1e-10, 1e-12
    kf = KalmanCA(dt, q, r)
    kf.reset(np.zeros(q.size))
    history = [kf.covariance[:, 1, 1]]
    for _ in range(8000):
        kf.update(np.zeros(q.size))
        history.append(kf.covariance[:, 1, 1])
    history = np.sqrt(np.array(history))
    steady = history[-1]
    np.testing.assert_allclose(history[-100], steady, rtol=1e-9)  # converged
    counts = [KalmanCA(dt, q[c], r[c]).settling_samples() for c in range(q.size)]
    assert counts == sorted(counts) and counts[-1] > 200
    for c, m in enumerate(counts):
        assert history[m, c] <= 2.0 * steady[c], (c, m)
        assert history[int(0.9 * m), c] > 2.0 * steady[c], (c, m)
    assert kf.settling_samples() == max(counts)
    assert kf.settling_samples(limit=5) == 5
    assert KalmanCA(dt, 1e12, 1e-12).settling_samples() == 2  # three samples fix value, velocity and acceleration
    assert KalmanCA(dt, 1e-300, 1e-2).settling_samples(limit=10**6) == 10**6  # no overflow on the way


def test_defaults_start_only_calibrated_differentiators_from_the_kalman_filter():
    """``start=None``: the Kalman start for a calibrated family whose first estimates hinge on its initial
    derivatives; the measurement start for given gains, an observer object, the self-starting families and
    ``auto`` (its choices here are the backward difference and the Kalman filter)."""
    Y, _ = cubic(T=3000, channels=2)

    def same(observer, **kw):
        a = smo_gym.differentiate(Y, DT, observer=observer, **kw)
        b = smo_gym.differentiate(Y, DT, observer=observer, start="measurement", **kw)
        return np.array_equal(a, b)

    assert not same("filtering")
    assert not same("high-gain")
    assert not same("alpha-beta")
    assert same("filtering", lipschitz=0.1)
    assert same(make_observer("levant", dt=DT, order=2, lipschitz=0.1))
    for name in ("finite-difference", "kalman-ca", "kalman-imm", "worst-case-optimal", "auto"):
        assert same(name), name
    levant = make_observer("levant", dt=DT, order=2, lipschitz=0.1)
    fd, kca = (
        make_observer("finite-difference", dt=DT),
        make_observer("kalman-ca", dt=DT, process_noise=1.0, measurement_noise=1e-6),
    )
    assert PerChannel([(fd, [0]), (kca, [1])]).self_starting
    assert not PerChannel([(fd, [0]), (levant, [1])]).self_starting
    # asked for, the Kalman start also applies to given gains and objects (the filter calibrated from the data)
    assert not np.array_equal(
        smo_gym.differentiate(Y, DT, observer=levant, start="kalman"),
        smo_gym.differentiate(Y, DT, observer=levant),
    )


def test_short_records_are_the_kalman_filters():
    """A record shorter than the settling count is the filter's estimate throughout (zeros above its order); one
    sample is the measurement itself. The first 40 ms of a slow cubic: its jerk is hidden by the noise, and the
    filter settles slowly (a cubic over 40 ms, whose derivatives the record shows, settles in 3 samples)."""
    Y = cubic(T=20000, channels=2)[0][:40]
    got = smo_gym.differentiate(Y, DT, observer="levant", order=3)
    found = calibration.calibration_of_signal(Y, DT, (3, 4))
    kf = calibration.default_observer("kalman-ca", found)
    assert kf.settling_samples() > 40
    np.testing.assert_array_equal(got[..., :3], smo_gym.differentiate(Y, DT, observer=kf))
    np.testing.assert_array_equal(got[..., 3], 0.0)
    one = smo_gym.differentiate(Y[:1], DT, observer="filtering", lipschitz=1.0, start="kalman")
    np.testing.assert_array_equal(one[0, :, 0], Y[0])
    np.testing.assert_array_equal(one[0, :, 1:], 0.0)


def test_wrapped_angles_stay_continuous_across_the_hand_over():
    """An angle turning at 3 rad/s, measured modulo 2 pi with noise: the value estimate stays continuous (no jump
    of 2 pi where the observer takes over from the filter) and the velocity stays right."""
    t = np.arange(8000) * DT
    angle = 3.0 * t + 0.1 * np.sin(2.0 * t) + 1.0
    rate = 3.0 + 0.2 * np.cos(2.0 * t)
    noisy = angle + 1e-3 * np.random.default_rng(3).standard_normal(t.size)
    y = np.mod(noisy + np.pi, 2 * np.pi) - np.pi
    z = smo_gym.differentiate(y, DT, observer="filtering", wrap=True)
    assert np.max(np.abs(np.diff(z[:, 0]))) < 0.05
    assert np.max(np.abs(z[2000:, 0] - angle[2000:])) < 0.01
    assert np.sqrt(np.mean((z[2000:, 1] - rate[2000:]) ** 2)) < 0.05


#: families whose recursion chatters: a rounding difference grows to a part of their noise-driven error, so a noisy
#: record rescaled (not by a power of two) gives estimates that differ by up to 1 % of their amplitude
CHATTERING = {"super-twisting", "ured", "ilf-finite"}


def _units_record(noise: float, velocity: bool = False):
    y, v = cubic(T=3000, channels=2, noise=noise)
    t = np.arange(3000) * DT
    y, v = y + np.sin(2.0 * t)[:, None], v + 2.0 * np.cos(2.0 * t)[:, None]
    return (y, v) if velocity else y


def _check_units(name: str, y: np.ndarray) -> None:
    base = smo_gym.differentiate(y, DT, name)
    for scale in (1e5, 1e-6, 1e120, 1e-120):
        scaled = smo_gym.differentiate(scale * y, DT, name) / scale
        atol = 1e-4 * np.abs(base[..., 1]).max()
        np.testing.assert_allclose(scaled[..., :2], base[..., :2], rtol=0, atol=atol, err_msg=f"units x {scale}")


@pytest.mark.parametrize("name", ["auto", *sorted(OBSERVERS)])
def test_the_estimates_do_not_depend_on_the_units(name):
    """Differentiation is linear and every level the calibration takes from a record scales with it, so the same
    record in units 1e5 times smaller (counts, micrometres) or 1e6 times larger (metres of a micrometre vibration)
    gives the estimates (value and velocity) scaled alike, to rounding: the Kalman filter's prior at reset is the
    record's own derivative bounds, and the floors of the levels are relative to its velocity bound. Before,
    with a fixed prior (10, 100) Levant's velocity was 3.4x its amplitude off in the small units, and with floors
    fixed at 1e-3 and 1e-6 every family but finite differences 0.5-0.7 times it in the large ones. And in units
    1e120 times larger or smaller: the Kalman filter's measurement update multiplied two variances (overflow above
    1e154, underflow below 1e-154), and every family starts from that filter. Noise-free here; the noisy record
    below."""
    _check_units(name, _units_record(0.0))


@pytest.mark.parametrize("scale", [1e-20, 1e30])
def test_auto_works_in_far_units_without_warnings(scale):
    """``auto`` compares the candidates' steady-state errors through the Kalman filter's Riccati equation; solved in
    the record's units, scipy's balancing warned ("invalid value encountered in cast") from levels of about 1e-40
    (a record in units 1e20 times smaller, or 1e30 times larger). Solved in units of the noise it does not, and the
    estimates scale with the record."""
    y = _units_record(1e-3)
    base = smo_gym.differentiate(y, DT)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scaled = smo_gym.differentiate(scale * y, DT) / scale
    np.testing.assert_allclose(scaled[..., :2], base[..., :2], rtol=0, atol=1e-4 * np.abs(base[..., 1]).max())


@pytest.mark.parametrize("name", ["auto", *sorted(set(OBSERVERS) - CHATTERING)])
def test_the_estimates_of_a_noisy_record_do_not_depend_on_the_units(name):
    """As above with noise 1e-3 on the record (its calibration finds the noise and the level floors do not act)."""
    _check_units(name, _units_record(1e-3))


@pytest.mark.parametrize("name", sorted(CHATTERING))
def test_chattering_families_are_as_accurate_in_any_units(name):
    """The families whose estimates a rescaling moves by their chattering are as accurate in units 1e5 times
    smaller or 1e6 times larger (velocity RMSE after 1 s within 5 %). URED's high-degree terms took its weight
    ``beta`` in absolute units before the calibration scaled it: 20 times the RMSE in units 1e5 times smaller."""
    y, v = _units_record(1e-3, velocity=True)
    rmse = {}
    for scale in (1.0, 1e5, 1e-6):
        estimate = smo_gym.differentiate(scale * y, DT, name)[1000:, :, 1] / scale
        rmse[scale] = np.sqrt(np.mean((estimate - v[1000:]) ** 2))
    np.testing.assert_allclose([rmse[1e5], rmse[1e-6]], rmse[1.0], rtol=0.05, err_msg=str(rmse))


@pytest.mark.parametrize("name", ["kalman-ca", "kalman-imm", "auto"])
def test_the_noise_floor_does_not_limit_a_noise_free_record(name, monkeypatch):
    """A noise-free cubic at 1 ms: the record's noise floor is below what limits the estimate (the filter's model),
    so a floor a thousand times lower gives the same velocity RMSE within 2 %. At a millionth of the largest motion
    in one sample (the floor before the Kalman filters' covariance was carried in factors) KalmanCA's RMSE was 37
    times what it is at a billionth."""
    t = np.arange(4000) * DT
    y, v = 0.3 + 0.5 * t - 2 * t**2 + 0.7 * t**3, 0.5 - 4 * t + 2.1 * t**2

    def rmse():
        return np.sqrt(np.mean((smo_gym.differentiate(y, DT, name)[500:, 1] - v[500:]) ** 2))

    at_floor = rmse()
    monkeypatch.setattr(calibration, "RECORD_NOISE_FLOOR", calibration.RECORD_NOISE_FLOOR * 1e-3)
    assert at_floor == pytest.approx(rmse(), rel=0.02)


def test_bad_start_and_limit_are_rejected():
    Y, _ = cubic(T=200, channels=1)
    with pytest.raises(ValueError, match="expected start to be 'kalman' or 'measurement', actual value: 'Kalman'"):
        smo_gym.differentiate(Y, DT, observer="levant", start="Kalman")
    with pytest.raises(ValueError, match="limit"):
        KalmanCA(DT, 1.0, 1e-6).settling_samples(limit=-1)
