"""Gain helpers and linear recursions re-derived independently in the test.

Each test implements the published formula itself (Levant's recursive form (7), Ackermann's formula, a textbook
Kalman filter, backward Euler) in plain NumPy and compares it with the library.
"""

from __future__ import annotations

from math import comb, factorial

import numpy as np
import pytest

from smo_gym.design import (
    LEVANT_LAMBDAS,
    ackermann_observer_gain,
    binomial_coefficients,
    levant_gains,
    levant_lambdas,
    levant_nonrecursive,
    super_twisting_gains,
)
from smo_gym.observers import FiniteDifference, HighGain, KalmanCA, Levant
from smo_gym.observers.differentiators import eigenvalue_mapping_vectors, taylor_matrix


def spow(x, p):
    """``|x|^p sign(x)`` (``p = 0``: sign)."""
    return np.sign(x) * np.abs(x) ** p


# ----------------------------------------------------------------------------------------------------------------
# Levant's lambdas: recursive (7) and non-recursive forms
# ----------------------------------------------------------------------------------------------------------------
def test_levant_lambda_table():
    """Fridman's slides below (7): lambda_0..5 = 1.1, 1.5, 2, 3, 5, 8; ``recursive`` lists them in state order."""
    assert LEVANT_LAMBDAS == (1.1, 1.5, 2.0, 3.0, 5.0, 8.0)
    for k in range(1, 6):
        np.testing.assert_array_equal(levant_lambdas(k, "recursive"), [LEVANT_LAMBDAS[k - i] for i in range(k + 1)])


@pytest.mark.parametrize("k, expected", [(1, (1.5, 1.1)), (2, (2.0, 2.12, 1.1)), (3, (3.0, 4.16, 3.06, 1.1))])
def test_levant_nonrecursive_values(k, expected):
    """Livne & Levant (2014) list the non-recursive parameters (2, 2.12, 1.1) and (3, 4.16, 3.06, 1.1)."""
    np.testing.assert_array_equal(np.round(levant_lambdas(k, "nonrecursive"), 2), expected)


def levant_rhs_recursive(z, f, L, k):
    r"""Right-hand side of eq. (7) of Fridman's slides, written recursively as printed:

    .. math:: \nu_0 = -\lambda_k L^{1/(k+1)}\lceil z_0 - f\rfloor^{k/(k+1)} + z_1,\quad
              \nu_i = -\lambda_{k-i} L^{1/(k+1-i)}\lceil z_i - \nu_{i-1}\rfloor^{(k-i)/(k+1-i)} + z_{i+1},\quad
              \dot z_k = -\lambda_0 L\,\mathrm{sign}(z_k - \nu_{k-1}).
    """
    lam = LEVANT_LAMBDAS
    dz = np.empty_like(z)
    prev = f
    for i in range(k + 1):
        s = z[..., i] - prev
        if i < k:
            nu = -lam[k - i] * L ** (1.0 / (k + 1 - i)) * spow(s, (k - i) / (k + 1 - i)) + z[..., i + 1]
        else:
            nu = -lam[0] * L * np.sign(s)
        dz[..., i] = nu
        prev = nu
    return dz


def levant_corrections_nonrecursive(z, f, L, k):
    """``-gains[i] * ceil(z_0 - f)^powers[i]`` from the library's :func:`levant_gains` (the non-recursive form)."""
    gains, powers = levant_gains(k, L)
    return -gains * spow((z[..., 0] - f)[..., None], powers)


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_recursive_and_nonrecursive_forms_agree(k, rng):
    """At random points the recursive (7) and the non-recursive right-hand sides coincide (Levant 2003)."""
    n = 500
    z = rng.normal(scale=3.0, size=(n, k + 1))
    f = rng.normal(scale=3.0, size=n)
    L = rng.uniform(0.1, 50.0, size=n)
    rec = levant_rhs_recursive(z, f, L, k)
    nonrec = levant_corrections_nonrecursive(z, f, L, k)
    nonrec[:, :k] += z[:, 1:]
    np.testing.assert_allclose(nonrec, rec, rtol=1e-11, atol=1e-12 * np.abs(rec).max())


@pytest.mark.parametrize("discretization", ["euler", "taylor"])
@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_levant_kernel_step_is_the_recursive_form(k, discretization, rng):
    r"""One step of :class:`Levant` is :math:`z^+ = T z + \tau\,\dot z_{(7)} - \tau N z`: the Taylor (or Euler)
    propagation of the chain plus :math:`\tau` times the corrections of the recursive form (7); the reported
    estimate is :math:`T^{-1} z^+` (the predictor moved back one step, ``_kernels`` docstring)."""
    n, m, dt = 50, k + 1, 0.01
    L = rng.uniform(0.5, 20.0, size=n)
    obs = Levant(k, dt, L, discretization=discretization)
    obs.reset(np.zeros(n))
    z = rng.normal(size=(n, m))
    f = rng.normal(size=n)
    state = np.zeros((n, m + 1))
    state[:, :m] = z
    new_state, out = obs.step(state, f)

    corrections = levant_rhs_recursive(z, f, L, k)
    corrections[:, :k] -= z[:, 1:]  # (7) minus the chain z_{i+1}: the injection terms alone
    if discretization == "taylor":
        T = np.array([[dt ** (j - i) / factorial(j - i) if j >= i else 0.0 for j in range(m)] for i in range(m)])
    else:
        T = np.eye(m) + dt * np.eye(m, k=1)
    expected = z @ T.T + dt * corrections
    np.testing.assert_allclose(new_state[:, :m], expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(new_state[:, m], f - z[:, 0], rtol=1e-14, atol=0)  # innovation y - yhat^-
    back = np.linalg.inv(taylor_matrix(m, dt))
    np.testing.assert_allclose(out, new_state[:, :m] @ back.T, rtol=1e-12, atol=1e-12)


def test_super_twisting_and_binomial_gains():
    k1, k2 = super_twisting_gains(4.0)
    assert (k1, k2) == (pytest.approx(3.0), pytest.approx(4.4))
    k1a, k2a = super_twisting_gains(np.array([1.0, 9.0]))
    np.testing.assert_allclose(k1a, [1.5, 4.5])
    np.testing.assert_allclose(k2a, [1.1, 9.9])
    for n in range(1, 8):
        rate = 1.7
        np.testing.assert_allclose(np.concatenate([[1.0], binomial_coefficients(n, rate)]), np.poly([-rate] * n))


# ----------------------------------------------------------------------------------------------------------------
# Ackermann's formula and Wetzlinger et al.'s eigenvalue-mapping gains
# ----------------------------------------------------------------------------------------------------------------
def random_poles(rng, n):
    """``n`` stable poles, with a complex-conjugate pair when ``n >= 2``."""
    poles = list(-rng.uniform(0.5, 3.0, size=n))
    if n >= 2:
        re, im = -rng.uniform(0.5, 2.0), rng.uniform(0.5, 2.0)
        poles[0], poles[1] = complex(re, im), complex(re, -im)
    return np.array(poles)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
def test_ackermann_places_the_eigenvalues(n, rng):
    """``eig(A - l c^T)`` equals the requested poles (random observable ``(A, c)``; distinct poles)."""
    for _ in range(5):
        A = rng.normal(size=(n, n))
        c = rng.normal(size=n)
        poles = random_poles(rng, n)
        l = ackermann_observer_gain(A, c, poles)
        assert l.shape == (n,) and np.isrealobj(l)
        eig = np.linalg.eigvals(A - np.outer(l, c))
        np.testing.assert_allclose(np.sort_complex(eig), np.sort_complex(poles), atol=1e-6)


def test_ackermann_rejects_unobservable_and_bad_input():
    A = np.diag([1.0, 2.0])
    with pytest.raises(ValueError, match="observable") as excinfo:
        ackermann_observer_gain(A, [1.0, 0.0], [-1.0, -2.0])  # the second mode is invisible
    assert "expected" in str(excinfo.value) and "actual value" in str(excinfo.value)
    with pytest.raises(ValueError, match="conjugation"):
        ackermann_observer_gain(np.eye(2, k=1), [1.0, 0.0], [-1 + 1j, -2.0])
    with pytest.raises(ValueError, match="expected"):
        ackermann_observer_gain(np.eye(3), [1.0, 0.0], [-1.0, -2.0])
    for A, c, poles in ((None, [1.0], [-1.0]), (np.eye(2, k=1), [1.0, 0.0], [True, False])):
        with pytest.raises(TypeError, match="expected"):
            ackermann_observer_gain(A, c, poles)
    with pytest.raises(ValueError, match="finite"):
        ackermann_observer_gain(np.eye(2, k=1), [1.0, 0.0], [np.nan, -1.0])


def test_ackermann_refuses_a_gain_that_misplaces_the_poles_by_a_little_in_its_polynomial():
    """Ten real modes 1 .. 15 seen through one output (observability condition number 2e13): the formula's gain
    has a characteristic polynomial off by 2e-5 relative, which puts complex pairs up to 2.9 away from the poles
    -1 .. -10 (measured with the check loosened to 0.1): refused, not returned."""
    A, c, poles = np.diag(np.linspace(1.0, 15.0, 10)), np.ones(10), -np.arange(1.0, 11.0)
    with pytest.raises(ValueError, match="places the eigenvalues"):
        ackermann_observer_gain(A, c, poles)


def test_ackermann_refuses_a_gain_that_does_not_place_the_poles(rng):
    """An observable but nearly unobservable pair (three modes 1e-6 apart, condition number ~1e13): the formula
    in floating point returned a gain with eigenvalues near +-3.5e5 instead of -1, -2, -3, without a word."""
    A = np.diag([1.0, 1.0 + 1e-6, 1.0 + 2e-6])
    with pytest.raises(ValueError, match="places the eigenvalues"):
        ackermann_observer_gain(A, [1.0, 1.0, 1.0], [-1.0, -2.0, -3.0])
    # the check passes what the formula does place, repeated poles included (their eigenvalues are ill-conditioned,
    # the characteristic polynomial is not)
    l = ackermann_observer_gain(np.eye(3, k=1), [1.0, 0.0, 0.0], [-2.0, -2.0, -2.0])
    np.testing.assert_allclose(np.poly(np.eye(3, k=1) - np.outer(l, [1.0, 0.0, 0.0])), np.poly([-2.0] * 3))
    # the same refusal in slow time units: with A and the poles scaled by 2^-27 (exact) the check was absolute and
    # a gain placing the eigenvalues at -94, -28 +- 47j, -6.4 +- 8.3j, -6 (scaled back) instead of -8 .. -48 passed
    A = np.array([[2, 3, 3, 1, 0, 0], [3, 2, 0, 0, -2, 0], [1, 3, 0, -1, 2, 0], [0, 0, -3, -1, 2, 0]]
                 + [[0, 2, -3, -2, 0, -1], [0, 0, -1, 0, 0, 0]], dtype=float)  # fmt: skip
    c, poles = np.array([0.0, 3.0, 0.0, -1.0, 3.0, 0.0]), -8.0 * np.arange(1, 7)
    for a in (1.0, 2.0**-27):
        with pytest.raises(ValueError, match="places the eigenvalues"):
            ackermann_observer_gain(a * A, c, a * poles)


def test_ackermann_observability_does_not_depend_on_units():
    """A -> a A, c -> s c (time and output units) leave (A, c) observable or not: the blocks c A^i of the
    observability matrix scale as s a^i, and NumPy's rank on the raw stack called a 3-state chain unobservable for
    a = 1e-10 and 1e10. The gain scales as l -> (a / s) l when the poles scale with a; a pair that is unobservable
    in exact arithmetic stays refused at every scale, in random coordinates too."""
    chain, e1, poles = np.eye(3, k=1), np.array([1.0, 0.0, 0.0]), np.array([-1.0, -2.0, -3.0])
    l = ackermann_observer_gain(chain, e1, poles)
    T = np.linalg.qr(np.random.default_rng(4).standard_normal((2, 2)))[0]
    blind = (T @ np.diag([1.0, 2.0]) @ T.T, np.array([1.0, 0.0]) @ T.T)  # the second mode is invisible
    for a in (1e-10, 1.0, 1e10):
        for s in (1e-10, 1.0, 1e10):
            np.testing.assert_allclose(ackermann_observer_gain(a * chain, s * e1, a * poles), (a / s) * l, rtol=1e-9)
            with pytest.raises(ValueError, match="observable pair"):
                ackermann_observer_gain(a * blind[0], s * blind[1], a * poles[:2])


def independent_ackermann_repeated(A, z):
    """Ackermann for ``c = e_1`` and all poles at ``z``, directly: ``l = (A - zI)^m O^{-1} e_m``."""
    m = A.shape[0]
    O = np.vstack([np.linalg.matrix_power(A, i)[0] for i in range(m)])
    return np.linalg.matrix_power(A - z * np.eye(m), m) @ np.linalg.solve(O, np.eye(m)[-1])


@pytest.mark.parametrize("m", [2, 3, 4, 5, 6])
@pytest.mark.parametrize("dt", [1e-3, 0.01, 0.1])
def test_eigenvalue_mapping_vectors_place_all_eigenvalues_at_z(m, dt, rng):
    r"""Wetzlinger et al., (35): :math:`l(z) = \sum_j (-z)^{m-j} v_j` gives :math:`\det(sI - A + l c^T) = (s - z)^m`.

    Compared through the characteristic polynomial, not the eigenvalues: ``A - l c^T`` is a single Jordan block,
    whose eigenvalues move by :math:`O(\delta^{1/m})` under a perturbation :math:`\delta`.
    """
    A = taylor_matrix(m, dt)
    V = eigenvalue_mapping_vectors(m, dt)
    assert V.shape == (m + 1, m)
    c = np.eye(m)[0]
    for z in np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, size=4)]):
        l = sum((-z) ** (m - j) * V[j] for j in range(m + 1))
        np.testing.assert_allclose(l, independent_ackermann_repeated(A, z), rtol=1e-9, atol=1e-9 * np.abs(V).max())
        charpoly = np.poly(A - np.outer(l, c))
        target = np.array([comb(m, i) * (-z) ** i for i in range(m + 1)])
        np.testing.assert_allclose(charpoly, target, atol=1e-8)


@pytest.mark.parametrize("mode", ["semi-implicit", "matching"])
@pytest.mark.parametrize("k", [1, 2, 4])
def test_eigenvalue_mapping_step(mode, k, rng):
    r"""One step of ``Levant(discretization="semi-implicit"/"matching")`` is Wetzlinger et al.'s
    :math:`\hat\xi^+ = A\hat\xi + l(z_n(\sigma))\,\sigma`, with :math:`\sigma = y - \hat\xi_1` and the eigenvalue
    (15) :math:`z = |\sigma|^{1/n}/(h p_1\mu|\sigma| + |\sigma|^{1/n} + h p_1)` or (16)
    :math:`z = \exp(-h p_1 (1 + \mu|\sigma|)/|\sigma|^{1/n})`, all computed here from the paper."""
    n_ch, m, dt, p1, mu = 40, k + 1, 0.02, 3.0, 0.5
    obs = Levant(k, dt, 1.0, discretization=mode, p1=p1, mu=mu)
    obs.reset(np.zeros(n_ch))
    xi = rng.normal(size=(n_ch, m))
    y = rng.normal(size=n_ch) * np.logspace(-6, 3, n_ch)
    state = np.zeros((n_ch, m + 1))
    state[:, :m] = xi
    new_state, _out = obs.step(state, y)
    A = taylor_matrix(m, dt)
    for c in range(n_ch):
        sigma = y[c] - xi[c, 0]
        a, root = abs(sigma), abs(sigma) ** (1.0 / m)
        if mode == "semi-implicit":
            z = root / (dt * p1 * mu * a + root + dt * p1)
        else:
            z = np.exp(-dt * p1 * (1.0 + mu * a) / root)
        expected = A @ xi[c] + independent_ackermann_repeated(A, z) * sigma
        np.testing.assert_allclose(new_state[c, :m], expected, rtol=1e-9, atol=1e-9 * (1 + abs(sigma)))


# ----------------------------------------------------------------------------------------------------------------
# linear recursions: Kalman filter and high-gain observer
# ----------------------------------------------------------------------------------------------------------------
def textbook_kalman_ca(Y, dt, q, r, s_v, s_a):
    """Constant-acceleration Kalman filter, written out with matrices (Bar-Shalom et al. 2001, 6.2.3)."""
    F = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q = q * np.array(
        [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]]
    )
    H = np.array([[1.0, 0.0, 0.0]])
    x = np.array([Y[0], 0.0, 0.0])
    P = np.diag([r, s_v**2, s_a**2])
    xs, Ps = [x.copy()], [P.copy()]
    for y in Y[1:]:
        x = F @ x
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + r
        K = P @ H.T / S
        x = x + (K * (y - H @ x)).ravel()
        P = (np.eye(3) - K @ H) @ P
        xs.append(x.copy())
        Ps.append(P.copy())
    return np.array(xs), np.array(Ps)


def test_kalman_ca_equals_textbook_filter(rng):
    """``KalmanCA`` (hand-expanded compiled recursion) equals the matrix-form Kalman filter to 1e-10."""
    dt, q, r = 0.01, 40.0, 1e-4
    t = np.arange(0.0, 3.0, dt)
    Y = np.sin(3 * t) + np.sqrt(r) * rng.standard_normal(t.size)
    obs = KalmanCA(dt, q, r, initial_std=(5.0, 20.0))
    est = [obs.reset(Y[:1])[0]]
    covs = [obs.covariance[0]]
    for y in Y[1:]:
        est.append(obs.update(np.array([y]))[0])
        covs.append(obs.covariance[0])
    xs, Ps = textbook_kalman_ca(Y, dt, q, r, 5.0, 20.0)
    np.testing.assert_allclose(np.array(est), xs, rtol=1e-10, atol=1e-10)
    scale = np.abs(Ps).max(axis=0)  # entries range from 1e-4 (P00) to 4e2 (P22): compare each on its own scale
    np.testing.assert_allclose(np.array(covs) / scale, Ps / scale, rtol=1e-10, atol=1e-10)


def test_kalman_ca_from_levels():
    """``q = J^2 dt`` per channel: the variance ``q dt`` of the acceleration's change per sample is ``(J dt)^2``."""
    kf = KalmanCA.from_levels(0.01, jerk_rms=[50.0, 2.0], measurement_variance=1e-6)
    np.testing.assert_allclose(kf.process_noise, [50.0**2 * 0.01, 2.0**2 * 0.01])
    assert kf.measurement_noise == 1e-6


def test_kalman_ca_per_channel_parameters_equal_one_filter_per_channel(rng):
    Y = np.cumsum(rng.normal(size=(300, 2)), axis=0) * 1e-3
    both = KalmanCA(0.01, [2.0, 300.0], [1e-6, 4e-6])
    both.reset(Y[0])
    joint = both.run(Y[1:])
    for c, (q, r) in enumerate(((2.0, 1e-6), (300.0, 4e-6))):
        alone = KalmanCA(0.01, q, r)
        alone.reset(Y[0, c : c + 1])
        np.testing.assert_array_equal(alone.run(Y[1:, c : c + 1]), joint[:, c : c + 1])


@pytest.mark.parametrize("order", [1, 2, 4])
def test_high_gain_implicit_is_backward_euler(order, rng):
    r"""Backward Euler of :math:`\dot x = N x + D(\ell)K(y - x_1)`, solved here with ``np.linalg.solve``:
    :math:`(I - \tau(N - Hc^T))x_k = x_{k-1} + \tau H y_k`, :math:`H_i = \binom{n}{i}\ell^i`."""
    dt, ell = 0.01, 40.0
    n = order + 1
    H = np.array([comb(n, i) * ell**i for i in range(1, n + 1)])
    M = np.eye(n) - dt * (np.eye(n, k=1) - np.outer(H, np.eye(n)[0]))
    Y = np.cos(2 * np.arange(200) * dt) + 1e-3 * rng.standard_normal(200)
    obs = HighGain(dt, ell, order)
    x = np.zeros(n)
    x[0] = Y[0]
    np.testing.assert_array_equal(obs.reset(Y[:1])[0], x)
    for y in Y[1:]:
        x = np.linalg.solve(M, x + dt * H * y)
        # 1e-9: for order 4 the entries of M span 1 to tau*ell^5 = 1e6 (cond 2e11); the two solvers (inverse
        # precomputed once vs. LU per step) then differ by up to 7e-11 relative (measured)
        np.testing.assert_allclose(obs.update(np.array([y]))[0], x, rtol=1e-9, atol=1e-9 * np.abs(x).max())


def test_high_gain_euler_is_forward_euler_predictor(rng):
    r"""``discretization="euler"``: :math:`x_{k+1} = x_k + \tau((N - Hc^T)x_k + H y_k)`, reported moved back by
    :math:`e^{-\tau N}`."""
    dt, ell = 0.002, 30.0
    H = np.array([2 * ell, ell**2])
    Y = np.sin(np.arange(100) * dt) + 1e-3 * rng.standard_normal(100)
    obs = HighGain(dt, ell, 1, discretization="euler")
    obs.reset(Y[:1])
    x = np.array([Y[0], 0.0])
    back = np.array([[1.0, -dt], [0.0, 1.0]])
    for y in Y[1:]:
        x = x + dt * (np.array([x[1], 0.0]) + H * (y - x[0]))
        np.testing.assert_allclose(obs.update(np.array([y]))[0], back @ x, rtol=1e-12, atol=1e-12)


def test_finite_difference_is_np_diff(rng):
    dt = 0.01
    Y = rng.normal(size=(50, 3))
    v = FiniteDifference(dt, 1)
    first = v.reset(Y[0])
    got = np.concatenate([first[None], v.run(Y[1:])])
    np.testing.assert_allclose(got[1:, :, 1], np.diff(Y, axis=0) / dt, rtol=1e-12)
    np.testing.assert_array_equal(got[:, :, 0], Y)
    a = FiniteDifference(dt, 2)
    a.reset(Y[0])
    acc = a.run(Y[1:])[..., 2]
    np.testing.assert_array_equal(acc[0], 0.0)  # no previous velocity after a reset
    np.testing.assert_allclose(acc[1:], np.diff(Y, 2, axis=0) / dt**2, rtol=1e-9)
    # a reset told the velocity takes it as the previous difference: the next acceleration differentiates it
    v0 = rng.normal(size=3)
    a.reset(Y[0], derivatives=v0[:, None])
    np.testing.assert_allclose(a.update(Y[1])[:, 2], ((Y[1] - Y[0]) / dt - v0) / dt, rtol=1e-12)


@pytest.mark.parametrize("discretization", ["implicit", "euler"])
def test_high_gain_per_channel_is_each_channel_with_its_own_gain(discretization, rng):
    """An array ``gain`` runs every channel as the observer with that channel's gain would, bit for bit."""
    dt, gains = 0.002, np.array([30.0, 120.0])
    Y = np.column_stack([np.sin(np.arange(300) * dt), np.cos(3 * np.arange(300) * dt)])
    Y += 1e-4 * rng.standard_normal(Y.shape)
    both = HighGain(dt, gains, 2, discretization=discretization)
    both.reset(Y[0])
    joint = both.run(Y[1:])
    for c, ell in enumerate(gains):
        alone = HighGain(dt, ell, 2, discretization=discretization)
        alone.reset(Y[0, c : c + 1])
        np.testing.assert_array_equal(alone.run(Y[1:, c : c + 1])[:, 0], joint[:, c])
    with pytest.raises(ValueError, match="expected a gain for an observer with one per channel"):
        both.system_matrices()
    np.testing.assert_allclose(HighGain.from_bounds(dt, [4.0, 9.0], [1e-4, 1e-4]).gain, np.sqrt([4e4, 9e4]))


def test_gain_helpers_refuse_bools_strings_and_overflow():
    """``True`` was read as the pole 1, overflowing gains came back as inf or as OverflowError/LinAlgError."""
    A, c = [[0.0, 1.0], [0.0, 0.0]], [1.0, 0.0]
    with pytest.raises(TypeError, match="expected poles"):
        ackermann_observer_gain(A, c, [True, -2.0])
    with pytest.raises(TypeError, match="expected poles"):
        ackermann_observer_gain(A, c, ["a", "b"])
    with pytest.raises(ValueError, match="finite coefficients"):
        ackermann_observer_gain(A, c, [-1e200, -1e200])
    with pytest.raises(ValueError, match="non-recursive gains are finite"):
        levant_nonrecursive([1e300] * 3)
    with pytest.raises(ValueError, match="finite coefficients"):
        binomial_coefficients(3, 1e300)
    with pytest.raises(TypeError, match="expected form"):
        levant_lambdas(2, np.array(["a", "b"]))
    np.testing.assert_allclose(ackermann_observer_gain(A, c, [-1.0, -2.0]), [3.0, 2.0])
