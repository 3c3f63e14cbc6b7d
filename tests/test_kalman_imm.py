r"""The IMM estimator of two constant-acceleration Kalman filters (Blom and Bar-Shalom 1988).

Checked against what can be computed without it:

* the step is the textbook IMM recursion (mixing, mode-matched filtering, mode probabilities, combination),
  written here with matrices for any number of modes, equal to rounding;
* with equal modes it is :class:`~smo_gym.observers.KalmanCA`;
* on a motion that alternates smooth stretches and bursts of jerk, the mode probabilities follow the bursts and the
  velocity error is below that of either filter alone;
* its calibration rule is :class:`KalmanCA`'s, and bad parameters are typed errors.

The registry's contract tests (``tests/test_observer_api.py``: batching, masked resets, NaN, pickling, run = update
loop, bad input) run this family on its registered examples.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import estimates_of

from smo_gym.calibration import Calibration, default_observer
from smo_gym.observers import KalmanCA, make_observer
from smo_gym.observers.imm import KalmanIMM


def textbook_imm(y, dt, densities, r, stay, initial_std=(10.0, 100.0), huber=None):
    r"""The IMM estimator (Bar-Shalom, Li and Kirubarajan 2001, chapter 11) for constant-acceleration modes of
    white-jerk ``densities``, in plain NumPy with full matrices: returns the combined estimates ``(T, 3)`` (row 0
    the reset) and the mode probabilities ``(T, M)``.

    With ``huber`` (``c``), each mode's update is Masreliez and Martin's (1977) with Huber's function, the
    innovation clipped to :math:`\pm c\sqrt S`, and its likelihood that of an innovation of exactly ``c``
    standard deviations, unless the previous step's innovation (of the predicted mixture,
    :math:`\sum_j \bar c_j \nu_j`) was beyond that bound too, or the share of the first mode's recent innovations
    beyond it (an exponential average of weight 0.01) exceeds the Gaussian share, ``erfc(c / sqrt(2))``, by more
    than 0.05: then the Kalman update and the normal density."""
    M = len(densities)
    F = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    G = np.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]])
    H = np.array([1.0, 0.0, 0.0])
    switch = np.full((M, M), (1.0 - stay) / (M - 1))
    np.fill_diagonal(switch, stay)
    x = np.array([[y[0], 0.0, 0.0]] * M)
    P = np.array([np.diag([r, initial_std[0] ** 2, initial_std[1] ** 2])] * M)
    mu = np.full(M, 1.0 / M)
    estimates, probabilities = [mu @ x], [mu]
    previous, rate = 0.0, 0.0
    for sample in y[1:]:
        c = switch.T @ mu
        weights = switch * mu[:, None] / c[None, :]  # weights[i, j] = mu_{i|j}
        x0 = weights.T @ x
        P0 = np.array(
            [sum(weights[i, j] * (P[i] + np.outer(x[i] - x0[j], x[i] - x0[j])) for i in range(M)) for j in range(M)]
        )
        likelihood, innovations = np.empty(M), np.empty(M)
        for j in range(M):
            prior = F @ x0[j]
            cov = F @ P0[j] @ F.T + densities[j] * G
            S = H @ cov @ H + r
            gain = cov @ H / S
            nu = sample - H @ prior
            innovations[j] = nu
            used, u = nu, abs(nu) / np.sqrt(S)
            suspended = huber is not None and rate > math.erfc(huber / math.sqrt(2)) + 0.05  # the model does not fit
            if huber is not None and abs(previous) <= huber * np.sqrt(S) and not suspended:  # a suspected gross error
                used, u = np.clip(nu, -huber * np.sqrt(S), huber * np.sqrt(S)), min(u, huber)
            if huber is not None and j == 0:
                beyond = abs(nu) > huber * np.sqrt(S)
            rho = 0.5 * u * u
            x[j] = prior + gain * used
            P[j] = cov - np.outer(gain, H @ cov)
            likelihood[j] = -rho - 0.5 * np.log(2 * np.pi * S)  # in logs: a gross error underflows exp
        previous = c @ innovations
        if huber is not None:
            rate += 0.01 * (beyond - rate)
        likelihood = np.exp(likelihood - likelihood.max())
        mu = likelihood * c / np.sum(likelihood * c)
        estimates.append(mu @ x)
        probabilities.append(mu)
    return np.array(estimates), np.array(probabilities)


def bursts(t, rng, n_bursts=6, jerk=2000.0, width=0.02):
    """Position, velocity: an acceleration that is constant except in ``n_bursts`` short bursts of jerk
    ``+-jerk`` (``width`` s each), at random times."""
    dt = t[1] - t[0]
    j = np.zeros_like(t)
    for start in rng.uniform(0.1, t[-1] - 0.1, n_bursts):
        j[(t >= start) & (t < start + width)] = rng.choice([-1.0, 1.0]) * jerk
    a = np.cumsum(j) * dt
    v = np.cumsum(a) * dt
    return np.cumsum(v) * dt, v, j != 0.0


def test_the_step_is_the_textbook_imm_recursion(rng):
    """Equal (to rounding) to the matrix form of the IMM recursion with two modes, on a noisy bursty signal."""
    dt, q, r = 2e-3, 1e5, 1e-6
    t = np.arange(1500) * dt
    y = bursts(t, rng)[0] + np.sqrt(r) * rng.standard_normal(t.shape)
    obs = KalmanIMM(dt, q, r, smooth_ratio=0.01, stay=0.98)
    ours = estimates_of(obs, y[:, None])[:, 0]
    reference, probabilities = textbook_imm(y, dt, [0.01 * q, q], r, 0.98)
    scale = np.abs(reference).max(axis=0)  # value, velocity and acceleration differ in size
    np.testing.assert_allclose(ours / scale, reference / scale, rtol=0, atol=1e-9)
    np.testing.assert_allclose(obs.mode_probabilities[0], probabilities[-1], rtol=1e-9, atol=1e-12)


def test_equal_modes_are_the_kalman_filter(rng):
    """With ``smooth_ratio = 1`` both modes are one filter: the output is :class:`KalmanCA`'s on every channel."""
    dt, T = 1e-3, 2000
    t = np.arange(T) * dt
    Y = np.sin(3 * t)[:, None] * np.array([1.0, -2.0, 0.5]) + 1e-3 * rng.standard_normal((T, 3))
    q, r = np.array([10.0, 1e3, 1e5]), 1e-6
    ours = estimates_of(KalmanIMM(dt, q, r, smooth_ratio=1.0), Y)
    kalman = estimates_of(KalmanCA(dt, q, r), Y)
    np.testing.assert_allclose(ours, kalman, rtol=1e-9, atol=1e-9)


def test_it_follows_the_bursts_and_beats_either_filter_alone(rng):
    r"""A motion at constant acceleration but for six 20 ms bursts of jerk :math:`\pm 2000`, measured every 2 ms
    with noise 1e-3: the fast filter's density from the bursts' jerk, the smooth mode at 1 % of it. The fast mode's
    probability is high during and just after the bursts (median 0.84, against 0.13 elsewhere), and the velocity
    RMSE is at least 10 % below both :class:`KalmanCA` tuned for the bursts and tuned for the smooth stretches
    (measured: 0.081 against 0.100 and 0.131; over five other seeds 0.70-0.93 and 0.52-0.97 times them)."""
    dt, sigma = 2e-3, 1e-3
    t = np.arange(2500) * dt
    p, v, burst = bursts(t, rng)
    y = p + sigma * rng.standard_normal(t.shape)
    q = 2000.0**2 * dt
    obs = KalmanIMM(dt, q, sigma**2)
    est = [obs.reset(y[:1])]
    fast = [0.5]
    for sample in y[1:]:
        est.append(obs.update(sample[None]))
        fast.append(obs.mode_probabilities[0, 1])
    est, fast = np.array(est)[:, 0, 1], np.array(fast)
    after = slice(250, None)  # the reset transient

    def rmse(velocity):
        return float(np.sqrt(np.mean((velocity[after] - v[after]) ** 2)))

    errors = {
        "imm": rmse(est),
        "fast": rmse(estimates_of(KalmanCA(dt, q, sigma**2), y[:, None])[:, 0, 1]),
        "smooth": rmse(estimates_of(KalmanCA(dt, 0.01 * q, sigma**2), y[:, None])[:, 0, 1]),
    }
    assert errors["imm"] < 0.9 * min(errors["fast"], errors["smooth"]), errors
    # a burst shows in the innovations over the samples after it: in a burst or up to 60 ms (30 samples) after
    near = (np.convolve(burst, np.ones(30))[: len(t)] > 0)[after]
    assert np.median(fast[after][near]) > 0.5 > np.median(fast[after][~near])


@pytest.mark.parametrize(("density_ratio", "fast_median"), [(1.0, (0.8, 1.0)), (0.01, (0.0, 0.2))])
def test_the_mode_whose_model_generated_the_signal_prevails(density_ratio, fast_median, rng):
    r"""On a signal generated by one of the two models (white jerk of the fast mode's density ``q``, or of the smooth
    mode's ``0.01 q``; 4 channels, 20,000 samples at 1 ms, noise 1e-4) that mode's likelihood is larger on average,
    so its probability prevails: measured median of the fast mode 0.89 on the fast model's signal, 0.05 on the
    smooth one's."""
    dt, q, r, T = 1e-3, 1e6, 1e-8, 20000
    jerk = rng.standard_normal((T, 4)) * np.sqrt(density_ratio * q / dt)
    position = np.cumsum(np.cumsum(np.cumsum(jerk, axis=0) * dt, axis=0) * dt, axis=0) * dt
    y = position + np.sqrt(r) * rng.standard_normal(position.shape)
    obs = KalmanIMM(dt, q, r)
    obs.reset(y[0])
    fast = []
    for sample in y[1:]:
        obs.update(sample)
        fast.append(obs.mode_probabilities[:, 1])
    low, high = fast_median
    assert low <= np.median(np.array(fast)[2000:]) <= high


def test_the_calibration_rule_is_the_kalman_filters():
    """``q`` from the typical jerk and ``r`` from the noise, as :class:`KalmanCA`'s rule; a given argument wins."""
    q_step = 2 * np.pi / 4096
    cal = Calibration(1e-3, {3: np.array([300.0, 800.0])}, {3: np.array([30.0, 80.0])}, np.array([1e-3, 2e-3]), q_step)
    imm, kalman = default_observer("kalman-imm", cal), default_observer("kalman-ca", cal)
    np.testing.assert_allclose(imm.process_noise, kalman.process_noise)
    np.testing.assert_allclose(imm.measurement_noise, kalman.measurement_noise)
    assert default_observer("kalman-imm", cal, {"stay": 0.9}).stay == 0.9
    assert isinstance(make_observer("kalman-imm", dt=1e-3, process_noise=1.0, measurement_noise=1e-6), KalmanIMM)


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        (dict(smooth_ratio=0.0), ValueError),
        (dict(smooth_ratio=1.5), ValueError),
        (dict(stay=1.0), ValueError),
        (dict(stay=-0.1), ValueError),
        (dict(process_noise=-1.0), ValueError),
        (dict(initial_std=3.0), TypeError),
    ],
)
def test_bad_parameters_are_typed_errors(kwargs, error):
    params = {"dt": 1e-3, "process_noise": 1.0, "measurement_noise": 1e-6, **kwargs}
    with pytest.raises(error, match="expected"):
        KalmanIMM(**params)


@pytest.mark.parametrize("cls", [KalmanCA, KalmanIMM])
def test_a_prior_per_channel_is_each_channel_alone_with_its_own(cls):
    """The prior at reset may differ per channel (``calibrated_prior`` gives each joint the levels where its own
    episodes start): a batch (2, 3) of channels with the velocity prior per channel and one acceleration prior
    estimates, bit for bit, what each channel does alone with its scalar prior, restarts included; a prior of
    another channel count is refused at reset."""
    rng = np.random.default_rng(5)
    Y = np.cumsum(rng.standard_normal((200, 2, 3)), axis=0) * 1e-3
    velocity, acceleration = np.array([0.1, 1.0, 10.0]), 30.0
    both = cls(0.01, 50.0, 1e-6, initial_std=(velocity, acceleration))
    out = np.concatenate([both.reset(Y[0])[None], both.run(Y[1:100])])
    out = np.concatenate([out, both.reset(Y[100], mask=np.array([True, False]))[None], both.run(Y[101:])])
    for c in range(3):
        alone = cls(0.01, 50.0, 1e-6, initial_std=(velocity[c], acceleration))
        mine = np.concatenate([alone.reset(Y[0, :, c : c + 1])[None], alone.run(Y[1:100, :, c : c + 1])])
        again = alone.reset(Y[100, :, c : c + 1], mask=np.array([True, False]))[None]
        mine = np.concatenate([mine, again, alone.run(Y[101:, :, c : c + 1])])
        np.testing.assert_array_equal(out[:, :, c], mine[:, :, 0])
    with pytest.raises(ValueError, match=r"initial_std\[0\] broadcastable to the measurement shape \(2,\)"):
        cls(0.01, 50.0, 1e-6, initial_std=(velocity, acceleration)).reset(np.zeros(2))
    with pytest.raises(ValueError, match=r"initial_std\[1\]"):
        cls(0.01, 50.0, 1e-6, initial_std=(1.0, [2.0, -1.0]))


@pytest.mark.parametrize("cls", [KalmanCA, KalmanIMM])
def test_a_prior_changed_between_episodes_starts_the_next_one(cls):
    """The prior is kept from one restart to the next (checking it again cost more than the rest of a restart),
    but a new ``initial_std`` set between episodes is the next episode's, at a restart as at a reset of another
    shape: bit for bit a filter built with it."""
    rng = np.random.default_rng(6)
    Y = np.cumsum(rng.standard_normal((120, 3)), axis=0) * 1e-3
    kf = cls(0.01, 50.0, 1e-6, initial_std=(1.0, 2.0))
    kf.reset(Y[0])
    kf.run(Y[1:60])
    kf.initial_std = (np.array([5.0, 0.5, 50.0]), 7.0)
    fresh = cls(0.01, 50.0, 1e-6, initial_std=(np.array([5.0, 0.5, 50.0]), 7.0))
    np.testing.assert_array_equal(kf.restart(Y[60]), fresh.reset(Y[60]))
    np.testing.assert_array_equal(kf.run(Y[61:]), fresh.run(Y[61:]))
    kf.initial_std = (3.0, 4.0)
    pair = cls(0.01, 50.0, 1e-6, initial_std=(3.0, 4.0))
    kf.reset(Y[0, :2]), pair.reset(Y[0, :2])
    np.testing.assert_array_equal(kf.run(Y[1:, :2]), pair.run(Y[1:, :2]))
