"""The implicit (backward Euler) discretization of Levant's, URED and the uniform Levant differentiators.

Each step is checked against an independent solve of the backward-Euler system (``scipy.optimize.brentq`` on its
scalar equation, then the linear system for the other states), the outputs against Newton's backward formula on
polynomials, and the closed loop against what theory says: exactness of order ``n + 1 - i`` without noise
(Seeber 2024) and a convergence time uniform in the initial error (Cruz-Zavala, Moreno and Fridman 2011; Angulo,
Moreno and Fridman 2013).
"""

from __future__ import annotations

from math import factorial

import numpy as np
import pytest
from scipy.optimize import brentq

from smo_gym.design import LEVANT_LAMBDAS, levant_nonrecursive
from smo_gym.observers import URED, DivergenceError, Levant, UniformLevant
from smo_gym.observers.differentiators import backward_difference_outputs

L = 2.0


def levant_terms(order: int, lipschitz: float) -> list[list[tuple[float, float]]]:
    """Injection terms ``[(gain, power), ...]`` per state of Levant's differentiator (class docstring)."""
    n = order + 1
    lam = levant_nonrecursive(np.array(LEVANT_LAMBDAS[:n]))
    return [[(lam[i] * lipschitz ** ((i + 1) / n), (order - i) / n)] for i in range(n)]


def ured_terms(lipschitz: float, beta: float = 1.0) -> list[list[tuple[float, float]]]:
    """URED's terms: ``k1 phi1`` and ``k2 phi2`` with the default gains (class docstring)."""
    k1, k2 = 1.5 * np.sqrt(lipschitz), 2.2 * lipschitz
    return [[(k1, 0.5), (k1 * beta, 1.5)], [(0.5 * k2, 0.0), (2 * beta * k2, 1.0), (1.5 * beta**2 * k2, 2.0)]]


def uniform_levant_terms(order: int, lipschitz: float, alpha: float = 1.0) -> list[list[tuple[float, float]]]:
    """The uniform differentiator's terms: Levant's plus ``k_i |e|^((n + alpha i)/n)``, ``k`` of ``(s + L^(1/n))^n``."""
    n = order + 1
    rate = lipschitz ** (1 / n)
    k = [float(np.polynomial.polynomial.polypow([rate, 1.0], n)[n - i]) for i in range(1, n + 1)]
    return [t + [(k[i], (n + alpha * (i + 1)) / n)] for i, t in enumerate(levant_terms(order, lipschitz))]


CASES = [
    (Levant, dict(order=1), levant_terms(1, L)),
    (Levant, dict(order=2), levant_terms(2, L)),
    (Levant, dict(order=3), levant_terms(3, L)),
    (Levant, dict(order=5), levant_terms(5, L)),
    (URED, dict(), ured_terms(L)),
    (UniformLevant, dict(order=2), uniform_levant_terms(2, L)),
    (UniformLevant, dict(order=3), uniform_levant_terms(3, L)),
]
IDS = ["levant1", "levant2", "levant3", "levant5", "ured", "ulevant2", "ulevant3"]


def injection(terms, sigma: float, sign: float) -> np.ndarray:
    """``psi(sigma)`` per state; a sign term (power 0) takes the value ``sign`` (in [-1, 1]) at ``sigma = 0``."""
    out = np.zeros(len(terms))
    for c, row in enumerate(terms):
        for g, p in row:
            if p == 0.0:
                out[c] += g * (np.sign(sigma) if sigma != 0.0 else sign)
            else:
                out[c] += g * np.sign(sigma) * abs(sigma) ** p
    return out


def backward_euler_solution(terms, xi: np.ndarray, y: float, dt: float):
    """Solve ``xi+ = xi + dt (A xi+ + psi(y - xi+_0))`` independently: ``brentq`` on the scalar equation in
    ``sigma = y - xi+_0``, then the linear system for ``xi+``. Returns ``(xi+, sigma, sign)``."""
    m = len(terms)
    shift = np.eye(m, k=1)
    E = np.eye(m) - dt * shift
    # xi+ = E^-1 (xi + dt psi): its first entry is linear in psi, so sigma solves one scalar equation
    rho = y - np.linalg.solve(E, xi)[0]
    first = np.linalg.solve(E, np.eye(m))[0] * dt  # d xi+_0 / d psi

    def h(sigma, sign=0.0):
        return sigma + first @ injection(terms, sigma, sign) - rho

    low, high = h(0.0, -1.0), h(0.0, 1.0)
    if low <= 0.0 <= high:  # the dead zone: sigma = 0, the sign term takes the value that solves the equation
        sign = -low / (high - low) * 2.0 - 1.0
        sigma = 0.0
    else:
        bound = abs(rho) + 1.0
        sigma = (
            brentq(h, 0.0, bound, xtol=1e-300, rtol=1e-15)
            if high < 0
            else -brentq(lambda s: h(-s), 0.0, bound, xtol=1e-300, rtol=1e-15)
        )
        sign = float(np.sign(sigma))
    return np.linalg.solve(E, xi + dt * injection(terms, sigma, sign)), sigma, sign


@pytest.mark.parametrize("cls, kwargs, terms", CASES, ids=IDS)
def test_each_step_solves_backward_euler(cls, kwargs, terms, rng):
    """On random states and measurements (a third of them in the dead zone, the others up to 1e6 times the
    dead zone's width away) the compiled step equals the independent solve and satisfies the full system.

    Equal up to the solution's sensitivity to the rounding of its input: the step depends on ``y`` through
    ``y - (E^-1 xi)_0``, which both solves round to a few ulp of ``|y| + |(E^-1 xi)_0|``; in the dead zone the last
    state moves by ``dt k_n sign`` with ``sign`` that difference over the zone's width ``theta`` (``dt^(m+1) k_n``
    and less), so an ulp of ``y`` moves it by up to ``dt^-m`` ulp. The tolerance adds the spread of the independent
    solve over ``y`` shifted by four such ulp either way."""
    dt = 1e-2
    m = len(terms)
    obs = cls(dt=dt, lipschitz=L, discretization="implicit", **kwargs)
    N = 300
    obs.reset(np.zeros(N))
    xi = rng.normal(size=(N, m)) * 10.0 ** rng.uniform(-2, 2, size=(N, 1))
    theta = sum(dt ** (c + 1) * g for c, row in enumerate(terms) for g, p in row if p == 0.0)
    E = np.eye(m) - dt * np.eye(m, k=1)
    prediction = np.linalg.solve(E, xi.T).T[:, 0]
    scale = np.where(np.arange(N) % 3 == 0, rng.uniform(-1, 1, N), rng.choice([-1, 1], N) * 10 ** rng.uniform(0, 6, N))
    y = prediction + theta * scale
    state = np.zeros((N, m + 1))
    state[:, :m] = xi
    new_state, est = obs.step(state, y)
    in_dead_zone = 0
    for c in range(N):
        want, sigma, sign = backward_euler_solution(terms, xi[c], y[c], dt)
        ulp = 4 * np.finfo(float).eps * (abs(y[c]) + abs(prediction[c]))
        spread = np.max([np.abs(backward_euler_solution(terms, xi[c], y[c] + d, dt)[0] - want) for d in (-ulp, ulp)], 0)
        np.testing.assert_array_less(np.abs(new_state[c, :m] - want), 1e-9 * np.abs(want).max() + spread + 1e-300)
        got = new_state[c, :m]
        # the full system at the new output error (a few ulp of y in y - xi+_0 move the low powers a lot)
        np.testing.assert_allclose(y[c] - got[0], sigma, rtol=1e-9, atol=1e-12 * (1 + abs(y[c])))
        if sigma == 0.0:
            in_dead_zone += 1
            assert got[0] == y[c]  # the estimate sticks to the measurement
            # the sign term's value is the step's own choice in [-1, 1]: read it off the last state's equation
            sign = (got[-1] - xi[c, -1]) / (dt * sum(g for g, p in terms[-1] if p == 0.0))
            assert abs(sign) <= 1.0 + 1e-9
        residual = got - xi[c] - dt * (np.eye(m, k=1) @ got + injection(terms, sigma, sign))
        assert np.abs(residual).max() <= 1e-9 * (1 + np.abs(got).max() + np.abs(xi[c]).max())
        np.testing.assert_allclose(est[c], backward_difference_outputs(m, dt) @ got, rtol=1e-12, atol=1e-12)
    assert in_dead_zone >= N // 3


@pytest.mark.parametrize("m", [1, 2, 3, 4, 6])
def test_outputs_are_newton_backward_formula(m):
    """``M`` maps the backward differences ``nabla^j y / tau^j`` of a polynomial of degree ``m - 1`` to its
    exact derivatives (the state in the dead zone, Seeber 2024); ``M = I`` for ``m <= 2``."""
    dt = 0.1
    rng = np.random.default_rng(m)
    coef = rng.normal(size=m)  # f(t) = sum coef_j t^j / j!
    t = -dt * np.arange(m)  # t_k, t_{k-1}, ...
    f = sum(coef[j] * t**j / factorial(j) for j in range(m))
    xi = [f[0]]
    diff = f.copy()
    for j in range(1, m):
        diff = diff[:-1] - diff[1:]
        xi.append(diff[0] / dt**j)
    np.testing.assert_allclose(backward_difference_outputs(m, dt) @ np.array(xi), coef, rtol=1e-9, atol=1e-12)
    if m <= 2:
        np.testing.assert_array_equal(backward_difference_outputs(m, dt), np.eye(m))


def _converged_errors(obs, dt: float, horizon: float) -> np.ndarray:
    """Max error of each estimate over the second half of ``sin`` sampled at ``dt`` (``|f^(j)| <= 1 < L``)."""
    t = np.arange(0.0, horizon, dt)
    m = obs.order + 1
    true = np.stack([np.sin(t + j * np.pi / 2) for j in range(m)], axis=1)
    obs.reset(np.sin(t[:1]))
    est = obs.run(np.sin(t[1:])[:, None])[:, 0]
    half = len(t) // 2
    assert np.array_equal(est[half:, 0], np.sin(t[1:])[half:])  # sticks to the measurement: no chattering
    return np.abs(est[half:] - true[1:][half:]).max(axis=0)


@pytest.mark.parametrize(
    "cls, kwargs",
    [(Levant, dict(order=1)), (Levant, dict(order=2)), (Levant, dict(order=3)), (URED, {}), (UniformLevant, {})],
    ids=["levant1", "levant2", "levant3", "ured", "ulevant2"],
)
def test_exact_without_noise_with_order_n_plus_1_minus_i(cls, kwargs):
    """After convergence the estimate of ``f^(i)`` is accurate to ``O(L tau^(n + 1 - i))`` (order ``n``): the
    exponent fitted at three steps is within 0.3 of theory; the value estimate equals the sample."""
    steps = np.array([1e-2, 5e-3, 2.5e-3])
    errors = np.array(
        [_converged_errors(cls(dt=h, lipschitz=L, discretization="implicit", **kwargs), h, 20.0) for h in steps]
    )
    n = errors.shape[1] - 1
    for i in range(1, n + 1):
        slope = np.polyfit(np.log(steps), np.log(errors[:, i]), 1)[0]
        assert abs(slope - (n + 1 - i)) <= 0.3, (i, slope, errors[:, i])
        assert errors[0, i] <= L * steps[0] ** (n + 1 - i)


def convergence_time(obs, e0: float, horizon: float, band: float = 1e-2):
    """First time after which ``|z_0 - f| + |z_1 - f'| <= band`` for good, from the initial error ``e0`` in the
    value (the reset sample is ``f(0) - e0``) on ``f = sin`` sampled at ``obs.dt``; ``inf`` if never."""
    t = np.arange(0.0, horizon, obs.dt)
    obs.reset(np.sin(t[:1]) - e0)
    est = obs.run(np.sin(t[1:])[:, None])[:, 0]
    err = np.abs(est[:, 0] - np.sin(t[1:])) + np.abs(est[:, 1] - np.cos(t[1:]))
    outside = np.flatnonzero(~(err <= band))
    if outside.size and outside[-1] == err.size - 1:
        return np.inf
    return t[1:][outside[-1] + 1] if outside.size else t[1]


@pytest.mark.parametrize(
    "make, horizon",
    [
        (lambda d: URED(dt=1e-4, lipschitz=1.0, discretization=d), 8.0),
        (lambda d: UniformLevant(order=2, dt=1e-4, lipschitz=1.0, discretization=d), 15.0),
    ],
    ids=["ured", "ulevant2"],
)
def test_uniform_convergence_time_in_discrete_time(make, horizon):
    """At ``dt = 1e-4`` the implicit step converges from initial errors 1e2 .. 1e8 in times that differ by less
    than 50% (measured: URED 3.75-5.14 s, uniform Levant order 2 10.8-11.7 s); explicit Euler URED diverges
    from 1e8 (``tau k1 beta |e|^(1/2) > 1``)."""
    times = np.array([convergence_time(make("implicit"), e0, horizon) for e0 in [1e2, 1e4, 1e6, 1e8]])
    assert np.isfinite(times).all(), times
    assert times.max() <= 1.5 * times.min(), times


def test_explicit_ured_diverges_where_implicit_converges():
    """The comparison of the test above: from 1e8 at ``dt = 1e-4`` explicit URED raises ``DivergenceError``."""
    with pytest.raises(DivergenceError):
        convergence_time(URED(dt=1e-4, lipschitz=1.0, discretization="euler"), 1e8, 1.0)
    assert np.isfinite(convergence_time(URED(dt=1e-4, lipschitz=1.0, discretization="implicit"), 1e8, 8.0))


@pytest.mark.parametrize(
    "obs, uniform",
    [
        (Levant(order=3, dt=0.1, lipschitz=L, discretization="implicit"), False),
        (URED(dt=0.1, lipschitz=L, discretization="implicit"), True),
        (UniformLevant(order=3, dt=0.1, lipschitz=L, discretization="implicit"), True),
    ],
    ids=["levant3", "ured", "ulevant3"],
)
def test_implicit_estimate_is_finite_from_huge_errors_at_a_coarse_step(obs, uniform):
    """Stable at any step: from 1e12 at ``dt = 0.1`` every implicit family stays finite, and the uniform ones
    converge within a minute (Levant's convergence time grows with the initial error)."""
    t = np.arange(0.0, 60.0, 0.1)
    obs.reset(np.array([1e12]))
    est = obs.run(np.sin(t[1:])[:, None])[:, 0]
    assert np.isfinite(est).all()
    if uniform:
        assert abs(est[-1, 1] - np.cos(t[-1])) <= 0.1


@pytest.mark.parametrize("cls", [Levant, URED, UniformLevant])
def test_unknown_discretization_names_the_implicit_one(cls):
    with pytest.raises(ValueError, match="implicit") as excinfo:
        cls(dt=1e-3, discretization="backward")
    assert "backward" in str(excinfo.value)


def test_levant_implicit_rejects_the_eigenvalue_map_parameters():
    with pytest.raises(ValueError, match="p1"):
        Levant(order=2, dt=1e-3, discretization="implicit", p1=3.0)
    with pytest.raises(ValueError, match="mu"):
        Levant(order=2, dt=1e-3, discretization="implicit", mu=1.0)


@pytest.mark.parametrize("order", [1, 2])
def test_both_discretizations_of_a_fractional_uniform_exponent_approach_one_solution(order):
    """``UniformLevant(alpha=0.5)`` has exponents :math:`(n + i/2)/n` that are not multiples of ``1/n``, which the
    kernels' fast powers do not cover: during the transient from a large error the ``euler`` and ``implicit``
    steps, two first-order discretizations of the same differential equation, differ by ``O(h)`` (measured: the
    difference halves with ``h``)."""
    differences, steps = [], (4e-4, 2e-4, 1e-4)
    for h in steps:
        y = np.sin(2 * np.arange(int(0.5 / h)) * h)[:, None]
        k = int(round(0.05 / h))  # well inside the transient, before the sliding motion
        at_k = []
        for discretization in ("euler", "implicit"):
            obs = UniformLevant(order=order, dt=h, lipschitz=8.0, alpha=0.5, discretization=discretization)
            obs.reset(y[0] + 3.0)  # a large initial error: the terms of high degree act
            at_k.append(obs.run(y[1 : k + 1])[-1, 0])
        differences.append(np.abs(at_k[0] - at_k[1]).max())
    slope = float(np.polyfit(np.log(steps), np.log(differences), 1)[0])
    assert 0.9 < slope < 1.1 and differences[-1] < 0.005, (differences, slope)  # measured 1.000, 0.0018
