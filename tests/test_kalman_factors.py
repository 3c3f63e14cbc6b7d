"""The constant-acceleration Kalman filters carry their covariance in U-D factors (Bierman 1977).

Each factor update is checked against the covariance formula it factors, and the filter against the textbook
recursion in exact rational arithmetic where the measurement variance is tiny against the prior: there the
recursion on the covariance itself, in double precision, loses the covariance's positivity (a negative innovation
variance for the IMM estimator).
"""

from fractions import Fraction

import numpy as np
import pytest

from smo_gym.observers import KalmanCA, KalmanIMM, _kernels

TINY = 4e-22  # a measurement variance 1e-20 times the prior velocity spread's (10 rad/s) over 1 ms, squared


def _full(u01, u02, u12, d0, d1, d2):
    U = np.array([[1.0, u01, u02], [0.0, 1.0, u12], [0.0, 0.0, 1.0]])
    return U @ np.diag([d0, d1, d2]) @ U.T


def _random_factors(rng):
    return tuple(rng.normal(size=3)) + tuple(np.exp(rng.normal(size=3)))


def test_each_factor_update_is_the_covariance_formula_it_factors():
    rng = np.random.default_rng(0)
    for _ in range(300):
        f, g = _random_factors(rng), _random_factors(rng)
        P = _full(*f)
        dt, q, r = np.exp(rng.uniform(-7, -2)), np.exp(rng.uniform(-5, 10)), np.exp(rng.uniform(-10, 0))
        F = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        Q = q * np.array(
            [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]]
        )
        prior = F @ P @ F.T + Q
        np.testing.assert_allclose(
            _full(*_kernels.kalman_ca_prior_factors(*f, dt, q)), prior, atol=1e-13 * abs(prior).max()
        )
        out = _kernels.kalman_ca_posterior_factors(*f, r)
        S = P[0, 0] + r
        K = P[:, 0] / S
        np.testing.assert_allclose(_full(*out[:6]), P - np.outer(K, P[0]), atol=1e-13 * abs(P).max())
        np.testing.assert_allclose(out[6:9], K, rtol=1e-13, atol=1e-13 * abs(K).max())
        assert out[9] == pytest.approx(S, rel=1e-13)
        delta = float(np.exp(rng.normal()))
        grown = P + np.diag([0.0, 0.0, delta])
        np.testing.assert_allclose(
            _full(*_kernels.kalman_ca_add_acceleration_variance(*f, delta)), grown, atol=1e-13 * abs(grown).max()
        )
        # the IMM's mixing: two weighted covariances and the spread of the means, d d^T
        d, (wa, s) = rng.normal(size=3), rng.uniform(0, 1, size=2)
        a, b = np.array(f), np.array(g)
        mixed = wa * P + (1 - wa) * _full(*g) + s * np.outer(d, d)
        factors = _kernels.ud_of_sum(*a[:3], *(wa * a[3:]), *b[:3], *((1 - wa) * b[3:]), *d, s)
        np.testing.assert_allclose(_full(*factors), mixed, atol=1e-13 * abs(mixed).max())


def _exact_filter(y, dt, q, r, variances):
    """The textbook recursion ``P^- = F P F^T + Q``, ``K = P^- c / S``, ``P^+ = P^- - K c^T P^-`` in rational
    arithmetic from the binary values of the inputs: estimates and covariances after each sample, as floats."""
    dt, q, r = Fraction(dt), Fraction(q), Fraction(r)
    F = [[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]]
    Q = [
        [q * dt**5 / 20, q * dt**4 / 8, q * dt**3 / 6],
        [q * dt**4 / 8, q * dt**3 / 3, q * dt**2 / 2],
        [q * dt**3 / 6, q * dt**2 / 2, q * dt],
    ]
    x = [Fraction(y[0]), Fraction(0), Fraction(0)]
    P = [[r, 0, 0], [0, Fraction(variances[0]), 0], [0, 0, Fraction(variances[1])]]
    estimates, covariances = [], []
    for sample in y[1:]:
        x = [sum(F[i][k] * x[k] for k in range(3)) for i in range(3)]
        FP = [[sum(F[i][k] * P[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
        M = [[sum(FP[i][k] * F[j][k] for k in range(3)) + Q[i][j] for j in range(3)] for i in range(3)]
        K = [M[i][0] / (M[0][0] + r) for i in range(3)]
        innovation = Fraction(sample) - x[0]
        x = [x[i] + K[i] * innovation for i in range(3)]
        P = [[M[i][j] - K[i] * M[0][j] for j in range(3)] for i in range(3)]
        estimates.append([float(v) for v in x])
        covariances.append([[float(v) for v in row] for row in P])
    return np.array(estimates), np.array(covariances)


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
@pytest.mark.parametrize("q", [1e-4, 50.0])
def test_a_tiny_measurement_variance_keeps_the_covariance_to_double_precision(dt, q):
    """30 samples of a noise-free cubic with a measurement variance 1e-20 of the prior's over one step: each
    covariance entry within 1e-9 of sqrt(P_ii P_jj) of the exact one (the recursion on the covariance itself was
    off by its whole size, and its velocity variance negative), each estimate within 1e-9 (absolute) of the
    exact one."""
    t = np.arange(31) * dt
    y = 0.3 + 0.5 * t - 2 * t**2 + 7 * t**3
    kf = KalmanCA(dt, q, TINY, initial_std=(10.0, 100.0))
    kf.reset(y[:1])
    estimates, covariances = [], []
    for sample in y[1:]:
        estimates.append(kf.update(sample[None])[0])
        covariances.append(kf.covariance[0])
    exact_x, exact_P = _exact_filter(y, dt, q, TINY, (100.0, 1e4))
    scale = np.sqrt(np.einsum("kii->ki", exact_P))
    error = np.abs(np.array(covariances) - exact_P) / (scale[:, :, None] * scale[:, None, :])
    assert error.max() < 1e-9
    assert np.abs(np.array(estimates) - exact_x).max() < 1e-9


def test_the_imm_estimator_runs_where_the_noise_is_tiny():
    """Where the covariance recursion lost its positivity the IMM estimator raised a DivergenceError at the second
    sample (the logarithm of a negative innovation variance). With both modes alike it is KalmanCA; with its
    default smooth mode it follows the cubic as closely as KalmanCA with either mode's density."""
    dt = 1e-3
    t = np.arange(400) * dt
    y = (0.3 + 0.5 * t - 2 * t**2 + 7 * t**3)[:, None]
    v = 0.5 - 4 * t + 21 * t**2

    def run(observer):
        observer.reset(y[0])
        return observer.run(y[1:])[:, 0]

    alike = run(KalmanIMM(dt, 1e-4, TINY, smooth_ratio=1.0))
    # to rounding: one of the samples' size (1e-16) moves the velocity by ~1e-13 and the acceleration by ~1e-10
    assert (np.abs(alike - run(KalmanCA(dt, 1e-4, TINY))).max(axis=0) <= [1e-12, 1e-10, 1e-8]).all()
    imm = run(KalmanIMM(dt, 1e-4, TINY))
    assert np.isfinite(imm).all()
    error = np.abs(imm[10:, 1] - v[11:]).max()
    worst_mode = max(np.abs(run(KalmanCA(dt, density, TINY))[10:, 1] - v[11:]).max() for density in (1e-6, 1e-4))
    assert error <= worst_mode
