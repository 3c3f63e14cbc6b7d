"""HOSM observer for nonlinear systems (Fridman, Shtessel, Edwards and Yan 2008): Levant's differentiator on the
output, then the state by inverting the observability map.

Example: a damped pendulum with a known input and a discontinuous unknown input (both enter the angular
acceleration, the output's relative degree 2 = n), measured through the horizontal position of its tip,
``y = sin(theta)`` (unit length), which is nonlinear and loses observability at ``theta = +-pi/2``:

    Phi(x) = (sin th, cos th * om),   dPhi/dx = [[cos th, 0], [-sin th * om, cos th]],   det = cos(th)^2.

Theory for the sampled observer (order-1 differentiator, ``k = n - 1 = 1``): the angle comes from ``y`` itself,
the angular velocity from ``y'``, whose error is ``O(L dt)`` noise-free and ``O(eps^(1/2))`` under noise of
amplitude ``eps``; the state error is the latter's, through the bounded inverse Jacobian.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from conftest import load_script

from smo_gym.nonlinear_observers import (
    HOSMInjectionObserver,
    InputReconstructionError,
    NonlinearHOSMObserver,
    ObservabilityError,
    check_observability,
    lie_derivatives,
    observability_jacobian,
    observability_map,
)

ROOT = Path(__file__).resolve().parents[1]
DAMP = 0.1
L = 5.0  # >= |y''| along the trajectory (measured max below ~2.5)
X0 = (0.8, 0.0)
GUESS = (0.3, 0.5)


def f(x):
    return np.array([x[1], -np.sin(x[0]) - DAMP * x[1]])


def g(x):
    return np.array([0.0, 1.0])


def h(x):
    return np.sin(x[0])


def phi(x):
    return np.array([np.sin(x[0]), np.cos(x[0]) * x[1]])


def phi_jacobian(x):
    return np.array([[np.cos(x[0]), 0.0], [-np.sin(x[0]) * x[1], np.cos(x[0])]])


def inputs(t):
    """Known input plus a discontinuous unknown one: the observer uses neither."""
    return 0.5 * np.sin(2.0 * t) + 0.3 * np.sign(np.sin(3.0 * t))


def rk4_samples(F, x0, dt: float, n: int, sub: int = 4) -> np.ndarray:
    """``n`` samples every ``dt`` of ``x' = F(t, x)`` from ``x0`` (row 0), RK4 with ``sub`` substeps per sample
    (error far below the observers')."""
    X = np.empty((n, len(x0)))
    x = np.array(x0, dtype=float)
    X[0], hs, t = x, dt / sub, 0.0
    for k in range(1, n):
        for _ in range(sub):
            k1 = F(t, x)
            k2 = F(t + hs / 2, x + hs / 2 * k1)
            k3 = F(t + hs / 2, x + hs / 2 * k2)
            k4 = F(t + hs, x + hs * k3)
            x = x + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            t += hs
        X[k] = x
    return X


def simulate(dt: float, T: float, sub: int = 4) -> np.ndarray:
    """Samples of the true state over ``[0, T]``."""

    def F(t, z):
        return np.array([z[1], -np.sin(z[0]) - DAMP * z[1] + inputs(t)])

    return rk4_samples(F, X0, dt, int(round(T / dt)) + 1, sub)


_SIMS: dict[float, np.ndarray] = {}


def trajectory(dt: float) -> np.ndarray:
    if dt not in _SIMS:
        _SIMS[dt] = simulate(dt, 3.0)
    return _SIMS[dt]


def errors(dt: float, noise: float = 0.0, **kwargs) -> np.ndarray:
    X = trajectory(dt)
    Y = np.sin(X[:, 0])
    if noise:
        Y = Y + noise * np.random.default_rng(0).uniform(-1.0, 1.0, Y.shape)
    obs = NonlinearHOSMObserver(f, h, 2, dt, L, phi=phi, phi_jacobian=phi_jacobian, **kwargs)
    return np.abs(obs.run(Y, GUESS) - X)


def floor_and_time(E: np.ndarray, dt: float) -> tuple[float, float]:
    """Floor: the largest error over the second half; convergence time: the last time the error exceeds 3 floors."""
    e = E.max(axis=1)
    floor = e[len(e) // 2 :].max()
    above = np.nonzero(e > 3.0 * floor)[0]
    return float(floor), float((above[-1] + 1) * dt) if above.size else 0.0


# ---------------------------------------------------------------- Lie derivatives and observability


def test_finite_difference_map_and_jacobian_match_the_exact_ones():
    rng = np.random.default_rng(1)
    for x in rng.uniform(-1.2, 1.2, (5, 2)):
        np.testing.assert_allclose(observability_map(f, h, x), phi(x), atol=2e-8)
        np.testing.assert_allclose(observability_jacobian(f, h, x), phi_jacobian(x), atol=5e-8)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_lie_derivatives_of_a_linear_system_are_c_a_powers(n):
    """For x' = A x, y = C x: L_f^j h = C A^j x and dPhi/dx = the observability matrix, exactly. Central differences
    have no truncation error there, so only rounding remains: within the documented eps^(2/(n+2)) (module docstring:
    measured at most 5e-8 in the Jacobian)."""
    rng = np.random.default_rng(n)
    A = np.diag(np.ones(n - 1), 1)
    A[-1] = -np.arange(1, n + 1) / n
    C = rng.normal(size=n)
    x = rng.uniform(-1.0, 1.0, n)
    fl, hl = (lambda z: A @ z), (lambda z: C @ z)
    O = np.array([C @ np.linalg.matrix_power(A, j) for j in range(n)])
    np.testing.assert_allclose(lie_derivatives(fl, hl, x, n - 1)[:, 0], O @ x, atol=1e-9)
    np.testing.assert_allclose(observability_map(fl, hl, x), O @ x, atol=1e-9)
    np.testing.assert_allclose(observability_jacobian(fl, hl, x), O, atol=1e-7 * np.abs(O).max())


def test_observability_holds_on_the_swing_and_fails_at_the_singular_point():
    th = np.linspace(-1.2, 1.2, 7)
    points = np.column_stack([th, np.linspace(-1.0, 1.0, 7)])
    report = check_observability(f, h, points, g=g)
    assert report.observable.all() and (report.rank == 2).all()
    np.testing.assert_allclose(report.condition, [np.linalg.cond(phi_jacobian(p)) for p in points], rtol=1e-5)
    bad = np.vstack([points[:3], [np.pi / 2, 0.4]])
    with pytest.raises(ObservabilityError, match=r"rank 1 at point 3") as info:
        check_observability(f, h, bad)
    assert info.value.index == 3
    np.testing.assert_array_equal(info.value.point, [np.pi / 2, 0.4])
    report = check_observability(f, h, bad, raise_error=False)
    assert report.observable.tolist() == [True, True, True, False]


def test_an_input_below_the_relative_degree_is_reported():
    """An input acting on theta' reaches y' = cos(th) (om + u): the relative-degree condition fails."""
    with pytest.raises(ObservabilityError, match=r"L_g L_f\^j h_i = 0 .* at point 0"):
        check_observability(f, h, [[0.2, 0.1]], g=lambda x: np.array([1.0, 0.0]))


# ---------------------------------------------------------------- the observer


def test_finite_time_convergence_to_the_sampling_floor():
    dt = 1e-3
    E = errors(dt)
    floor, t_conv = floor_and_time(E, dt)
    # the angle is read from y = sin(th) exactly (|th| < pi/2): Newton's tolerance
    assert E[1500:, 0].max() < 1e-9
    # velocity: the implicit order-1 differentiator's O(L dt) (measured 7.9e-4)
    assert floor < 0.5 * L * dt
    # from a wrong guess (0.5 rad, 0.5 rad/s off): converged within 0.2 s (measured 0.12 s)
    assert E[0].max() > 0.4 and 0.0 < t_conv < 0.2


def test_state_error_is_first_order_in_the_sampling_step():
    dts = [4e-3, 2e-3, 1e-3]
    floors = [floor_and_time(errors(dt), dt)[0] for dt in dts]
    slope = np.polyfit(np.log(dts), np.log(floors), 1)[0]
    assert 0.85 < slope < 1.15, (floors, slope)  # theory: O(dt^(k+1-i)), k = i = 1 (measured slope 1.00)


def test_state_error_under_noise_follows_levants_bound():
    """Levant's bound for the order-1 differentiator under noise of amplitude eps is O(L^(1/2) eps^(1/2)) in y'
    (a worst case over the noise). Uniform i.i.d. noise measures below it with a flatter slope (0.34 over
    eps = 1e-4..1e-2 at dt = 1e-3; floors 0.031, 0.056, 0.145), and far below a backward difference's eps/dt."""
    dt = 1e-3
    eps = np.array([1e-4, 1e-3, 1e-2])
    floors = np.array([floor_and_time(errors(dt, noise=e), dt)[0] for e in eps])
    bound = 2.0 * np.sqrt(L * eps) + 0.5 * L * dt
    assert (floors <= bound).all() and (floors >= 0.3 * np.sqrt(L * eps)).all(), floors
    assert floors[-1] < 0.1 * eps[-1] / dt  # a backward difference would reach eps / dt = 10
    slope = np.polyfit(np.log(eps), np.log(floors), 1)[0]
    assert 0.25 < slope < 0.6, (floors, slope)


def test_finite_difference_observer_matches_the_exact_map():
    dt = 2e-3
    X = trajectory(dt)[:500]
    Y = np.sin(X[:, 0])
    exact = NonlinearHOSMObserver(f, h, 2, dt, L, phi=phi, phi_jacobian=phi_jacobian).run(Y, GUESS)
    fd = NonlinearHOSMObserver(f, h, 2, dt, L).run(Y, GUESS)
    np.testing.assert_allclose(fd, exact, atol=1e-6)


def test_third_order_system_with_finite_difference_lie_derivatives():
    """n = 3: Levant's order-2 differentiator and Phi = (h, L_f h, L_f^2 h) by nested differences. Stable linear
    part plus a bounded nonlinearity (BIBS); y = x1 + 0.1 x1^3 makes dPhi/dx triangular with diagonal
    h'(x1) = 1 + 0.3 x1^2 > 0, observable everywhere. Theory: state error O(L dt) from y'' (k = 2, i = 2)."""

    dt, N = 2e-3, 1500
    X = third_order_trajectory(dt, N)
    check_observability(f3, h3, X[::100], g=lambda z: np.array([0.0, 0.0, 1.0]))
    Y = np.array([h3(z) for z in X])
    obs = NonlinearHOSMObserver(f3, h3, 3, dt, 20.0)
    E = np.abs(obs.run(Y, [0.5, 0.5, -0.5]) - X)
    floor, t_conv = floor_and_time(E, dt)
    print(f"n = 3: floor {floor:.3g}, convergence time {t_conv:.3g} s")
    assert E[0].max() > 0.4 and t_conv < 1.0 and floor < 0.1 * 20.0 * dt, (floor, t_conv)


def test_two_outputs_with_indices_one_and_one():
    """p = n = 2, indices (1, 1): no differentiator at all, Phi = h; the state is read back exactly."""
    h2 = lambda x: np.array([np.sin(x[0]), x[1] + 0.1 * x[1] ** 3])
    X = trajectory(2e-3)[:200]
    Y = np.column_stack([np.sin(X[:, 0]), X[:, 1] + 0.1 * X[:, 1] ** 3])
    obs = NonlinearHOSMObserver(f, h2, 2, 2e-3, L, indices=(1, 1))
    np.testing.assert_allclose(obs.run(Y, GUESS), X, atol=1e-7)


def test_two_outputs_with_indices_two_and_one():
    """n = 3, indices (2, 1): the pendulum plus a filtered state c' = -c + sin(th), measured through
    y1 = sin(th) (order-1 differentiator) and y2 = c + 0.1 c^3 (no differentiator). Phi = (sin th, cos th om,
    c + 0.1 c^3) by finite differences; the state converges to the pendulum's O(L dt) floor (measured 8.9e-4 at 2 ms,
    in 0.12 s)."""

    def f3(x):
        return np.array([x[1], -np.sin(x[0]) - DAMP * x[1], -x[2] + np.sin(x[0])])

    def h3(x):
        return np.array([np.sin(x[0]), x[2] + 0.1 * x[2] ** 3])

    dt = 2e-3
    X2 = trajectory(dt)[:750]
    c = np.empty(len(X2))
    c[0] = 0.2
    for k in range(len(X2) - 1):  # exact for th held over the step; O(dt^2) per step otherwise (no matter: y2 is exact)
        c[k + 1] = np.sin(X2[k, 0]) + (c[k] - np.sin(X2[k, 0])) * np.exp(-dt)
    X = np.column_stack([X2, c])
    Y = np.array([h3(x) for x in X])
    report = check_observability(f3, h3, X[::50], indices=(2, 1), g=lambda x: np.array([0.0, 1.0, 0.0]))
    assert (report.rank == 3).all()
    obs = NonlinearHOSMObserver(f3, h3, 3, dt, L, indices=(2, 1))
    E = np.abs(obs.run(Y, [0.3, 0.5, -0.3]) - X)
    floor, t_conv = floor_and_time(E, dt)
    print(f"indices (2, 1): floor {floor:.3g}, convergence time {t_conv:.3g} s")
    assert E[0].max() > 0.4 and t_conv < 0.3 and floor < 0.5 * L * dt, (floor, t_conv)
    assert E[375:, 2].max() < 1e-6  # c from y2 alone


# ---------------------------------------------------------------- unknown-input reconstruction


def lie_top(x):
    """L_f^2 h for y = sin(th): d/dt (cos th om) along f = -sin th om^2 + cos th (-sin th - DAMP om)."""
    return np.array([-np.sin(x[0]) * x[1] ** 2 + np.cos(x[0]) * (-np.sin(x[0]) - DAMP * x[1])])


def smooth_input(t):
    return 0.5 * np.sin(2.0 * t) + 0.3 * np.cos(5.0 * t)


def square_input(t):
    return 0.5 * np.sin(2.0 * t) + 0.3 * np.sign(np.sin(3.0 * t))


@functools.lru_cache(maxsize=16)
def simulate_input(dt: float, T: float, w, D=(0.0, 1.0), sub: int = 4) -> np.ndarray:
    """The unforced pendulum plus D w(t) (only w, no known input) over ``[0, T]`` (cached: read only)."""
    D = np.asarray(D, dtype=float)
    return rk4_samples(lambda t, z: f(z) + D * w(t), X0, dt, int(round(T / dt)) + 1, sub)


def f3(x):
    """A stable linear chain plus a bounded nonlinearity (BIBS)."""
    return np.array([x[1], x[2], -x[0] - 2.0 * x[1] - 1.5 * x[2] - 0.5 * np.sin(x[0])])


def h3(x):
    """y = x1 + 0.1 x1^3: dPhi/dx triangular with diagonal 1 + 0.3 x1^2 > 0."""
    return x[0] + 0.1 * x[0] ** 3


def third_order_trajectory(dt: float, n: int) -> np.ndarray:
    """``n`` samples of the third-order system from (1, 0, 0) with the input 0.5 sin(3t) on x3' (relative degree 3)."""
    return rk4_samples(lambda t, z: f3(z) + np.array([0.0, 0.0, 0.5 * np.sin(3.0 * t)]), [1.0, 0.0, 0.0], dt, n)


L3 = 20.0  # >= |y'''| (measured max 2.6 with the smooth input): the order-2 differentiator's bound


def reconstruction(dt: float, w=smooth_input):
    X = simulate_input(dt, 3.0, w)
    obs = NonlinearHOSMObserver(
        f, h, 2, dt, L3, phi=phi, phi_jacobian=phi_jacobian, lie_top=lie_top, unknown_input=[0.0, 1.0]
    )
    Xh, W = obs.run(np.sin(X[:, 0]), GUESS, inputs=True)
    t = np.arange(len(X)) * dt
    return np.abs(Xh - X), np.abs(W[:, 0] - w(t)), t


def test_unknown_input_is_reconstructed_in_finite_time():
    """w = (y'' - L_f^2 h(x)) / (L_D L_f h(x)) with D = (0, 1): L_D L_f h = cos(th). Order-2 differentiator, so
    |y'''| <= L bounds it (w smooth). Noise-free: exact after a finite time up to the sampling floor (measured at
    1 ms: w floor 2.6e-3, state floor 8.6e-7, both converged by 0.46 s from a 0.5 rad, 0.5 rad/s wrong guess)."""
    dt = 1e-3
    E, ew, _ = reconstruction(dt)
    floor, t_conv = floor_and_time(E, dt)
    floor_w, t_conv_w = floor_and_time(ew[:, None], dt)
    print(f"input floor {floor_w:.3g}, state floor {floor:.3g}, convergence {t_conv:.3g} s / {t_conv_w:.3g} s")
    assert E[0].max() > 0.4 and ew[:10].max() > 0.3
    assert 0.0 < t_conv < 0.6 and 0.0 < t_conv_w < 0.6
    assert floor_w < 0.5 * L3 * dt and floor < 0.5 * L3 * dt**2


def test_reconstruction_orders_in_the_sampling_step():
    """Levant's accuracy for the sampled order-k differentiator, |z_j - y^(j)| = O(L tau^(k+1-j)), with k = 2: the
    input comes from z_2 (first order), the velocity from z_1 (second order: one order better than the state-only
    observer, at the price of |y'''| <= L). Measured slopes 1.00 and 2.00 over dt = 4, 2, 1 ms."""
    dts = np.array([4e-3, 2e-3, 1e-3])
    fx, fw = [], []
    for dt in dts:
        E, ew, _ = reconstruction(dt)
        fx.append(floor_and_time(E, dt)[0])
        fw.append(floor_and_time(ew[:, None], dt)[0])
    slope_x = np.polyfit(np.log(dts), np.log(fx), 1)[0]
    slope_w = np.polyfit(np.log(dts), np.log(fw), 1)[0]
    assert 0.85 < slope_w < 1.15 and 1.8 < slope_x < 2.2, (fx, fw, slope_x, slope_w)


def test_a_discontinuous_input_is_recovered_again_shortly_after_each_jump():
    """A jump of w makes y''' unbounded for an instant: the differentiator loses the input there (error about the
    jump, 0.6) and converges again in finite time (measured 0.028 s and 0.038 s after the jumps at pi/3, 2 pi/3)."""
    dt = 1e-3
    E, ew, t = reconstruction(dt, w=square_input)
    for tj in (np.pi / 3, 2 * np.pi / 3):
        near = (t > tj) & (t < tj + 0.01)
        after = (t > tj + 0.06) & (t < tj + np.pi / 3)
        assert ew[near].max() > 0.3  # the jump is felt
        assert ew[after].max() < 0.02 and E[after].max() < 1e-4, (tj, ew[after].max(), E[after].max())


def test_finite_difference_reconstruction_matches_the_exact_lie_derivatives():
    dt = 2e-3
    X = simulate_input(dt, 0.4, smooth_input)
    Y = np.sin(X[:, 0])
    exact = NonlinearHOSMObserver(
        f, h, 2, dt, L3, phi=phi, phi_jacobian=phi_jacobian, lie_top=lie_top, unknown_input=[0.0, 1.0]
    ).run(Y, GUESS, inputs=True)
    fd = NonlinearHOSMObserver(f, h, 2, dt, L3, unknown_input=lambda x: np.array([0.0, 1.0])).run(Y, GUESS, inputs=True)
    np.testing.assert_allclose(fd[0], exact[0], atol=1e-6)
    np.testing.assert_allclose(fd[1], exact[1], atol=1e-5)


def test_reconstruction_needs_a_nonzero_input_gain():
    """L_D L_f^(r-1) h(x) = 0: the input does not reach y^(r) there. With d(x) = (0, sin th) it vanishes at th = 0;
    two inputs on one output never have a rank-2 gain."""
    obs = NonlinearHOSMObserver(f, h, 2, 1e-3, L3, unknown_input=lambda x: np.array([0.0, np.sin(x[0])]))
    with pytest.raises(InputReconstructionError, match=r"expected L_D L_f\^\(r_i - 1\) h_i .* of rank m = 1") as info:
        obs.reset(0.0, [0.0, 0.3])
    np.testing.assert_array_equal(info.value.point, [0.0, 0.3])
    assert info.value.matrix.shape == (1, 1) and abs(info.value.matrix[0, 0]) < 1e-12
    obs.reset(np.sin(0.5), [0.5, 0.3])  # away from th = 0 the gain is sin(0.5) cos(0.5)
    obs = NonlinearHOSMObserver(f, h, 2, 1e-3, L3, unknown_input=np.array([[0.0, 0.0], [1.0, 2.0]]))
    with pytest.raises(InputReconstructionError, match=r"rank m = 2"):
        obs.reset(0.1, GUESS)
    with pytest.raises(ValueError, match=r"expected unknown_input at construction"):
        NonlinearHOSMObserver(f, h, 2, 1e-3, L).run([0.1, 0.1], GUESS, inputs=True)
    with pytest.raises(ValueError, match=r"expected unknown_input with shape \(2,\) or \(2, m\)"):
        NonlinearHOSMObserver(f, h, 2, 1e-3, L, unknown_input=[1.0, 0.0, 0.0])


# ---------------------------------------------------------------- Davila, Fridman, Pisano and Usai (2009)


def test_injection_observer_converges_in_finite_time_where_the_assumptions_hold():
    """D = (0, 1): dh D = 0 (i = 0..n-2) and M = dPhi/dx nonsingular for |th| < pi/2 (checked on the trajectory).
    The error in Phi-coordinates is Levant's order-1 differentiator's: exact after a finite time up to the sampled
    floor O(L dt) in the velocity, O(L dt^2) in the angle (e_0). Measured at 4, 2, 1 ms: velocity floors 0.043,
    0.020, 0.010 (slope 1.0), angle 1.3e-4, 3.2e-5, 8.5e-6; convergence 0.44-0.47 s."""
    dts = np.array([4e-3, 2e-3, 1e-3])
    fv, fq = [], []
    for dt in dts:
        X = simulate_input(dt, 3.0, square_input)
        obs = HOSMInjectionObserver(
            f, h, 2, dt, L, phi_jacobian=phi_jacobian, unknown_input=[0.0, 1.0], check_points=X[::50]
        )
        E = np.abs(obs.run(np.sin(X[:, 0]), GUESS) - X)
        t_conv = floor_and_time(E, dt)[1]
        print(f"dt {dt}: convergence {t_conv:.3g} s")
        assert E[0].max() > 0.4 and 0.0 < t_conv < 0.6, (dt, t_conv)
        fv.append(E[len(E) // 2 :, 1].max())
        fq.append(E[len(E) // 2 :, 0].max())
    assert fv[-1] < 3.0 * L * dts[-1] and fq[-1] < 3.0 * L * dts[-1] ** 2, (fv, fq)
    assert 0.85 < np.polyfit(np.log(dts), np.log(fv), 1)[0] < 1.15, fv
    assert 1.7 < np.polyfit(np.log(dts), np.log(fq), 1)[0] < 2.3, fq


def test_injection_observer_fails_where_the_input_reaches_y_prime():
    """D = (1, 0) (w acts on th'): dh D = cos(th) != 0, the slides' assumption dL_f^i h D = 0 (i = 0) fails.
    The check names it; unchecked, the input enters y' and the velocity estimate does not converge (measured
    error 0.74 rad/s over the second half at 2 ms)."""
    with pytest.raises(ObservabilityError, match=r"L_g L_f\^j h_i = 0 for j < r_i - 1 .* at point 0"):
        HOSMInjectionObserver(f, h, 2, 2e-3, L, unknown_input=[1.0, 0.0], check_points=[[0.1, 0.2], [0.5, 0.0]])
    dt = 2e-3
    X = simulate_input(dt, 3.0, square_input, D=(1.0, 0.0))
    E = np.abs(HOSMInjectionObserver(f, h, 2, dt, L, phi_jacobian=phi_jacobian).run(np.sin(X[:, 0]), GUESS) - X)
    assert E[len(E) // 2 :, 1].max() > 0.3


def test_injection_observer_requires_a_nonsingular_m():
    with pytest.raises(ObservabilityError, match=r"rank 1 at point 1"):
        HOSMInjectionObserver(f, h, 2, 1e-3, L, check_points=[[0.1, 0.0], [np.pi / 2, 0.3]])
    obs = HOSMInjectionObserver(f, h, 2, 1e-3, L, phi_jacobian=phi_jacobian)
    obs.reset(1.0, [np.pi / 2, 0.3])
    with pytest.raises(ObservabilityError, match=r"rank 1 at point 0"):
        obs.update(1.0)


def test_injection_observer_with_finite_difference_m_matches_the_exact_one():
    dt = 2e-3
    X = simulate_input(dt, 0.6, square_input)
    Y = np.sin(X[:, 0])
    exact = HOSMInjectionObserver(f, h, 2, dt, L, phi_jacobian=phi_jacobian).run(Y, GUESS)
    np.testing.assert_allclose(HOSMInjectionObserver(f, h, 2, dt, L).run(Y, GUESS), exact, atol=1e-6)


def test_injection_observer_on_a_third_order_system():
    """n = 3 (order-2 corrections |e|^(2/3), |e|^(1/3), sign) with M by finite differences: the system of
    test_third_order_system_with_finite_difference_lie_derivatives, an unknown input 0.5 sin(3t) on x3' (dh D =
    dL_f h D = 0, checked). Error floors O(L dt) in x3 (Euler-sampled sign term, constant about 2.3), far smaller
    in x1 (e_0, O(L dt^3)); measured at 2 ms with L = 20 over 1.2-1.6 s: (3.9e-7, 6.5e-4, 0.082), convergence
    1.08 s (0.048 in x3 at 1 ms: first order)."""

    dt, N = 2e-3, 800
    X = third_order_trajectory(dt, N)
    obs = HOSMInjectionObserver(f3, h3, 3, dt, 20.0, unknown_input=[0.0, 0.0, 1.0], check_points=X[::100])
    E = np.abs(obs.run([h3(z) for z in X], [0.5, 0.5, -0.5]) - X)
    late = E[600:].max(axis=0)  # after 1.2 s
    print(f"n = 3 injection: late errors {late}")
    assert E[0].max() > 0.4
    assert late[2] < 3.0 * 20.0 * dt and late[1] < 0.05 * 20.0 * dt and late[0] < 1e-5, late


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(n=1), ValueError, r"expected n >= 2"),
        (dict(dt=0.0), ValueError, r"expected dt > 0"),
        (dict(lipschitz=-1.0), ValueError, r"expected lipschitz > 0"),
        (dict(gains=[1.1, 1.5, 2.0]), ValueError, r"expected gains with shape \(2,\)"),
        (dict(h=None), TypeError, r"expected h to be a callable"),
    ],
)
def test_injection_observer_bad_construction(kwargs, error, match):
    with pytest.raises(error, match=match):
        HOSMInjectionObserver(**(dict(f=f, h=h, n=2, dt=1e-3, lipschitz=L) | kwargs))
    obs = HOSMInjectionObserver(f, h, 2, 1e-3, L)
    with pytest.raises(RuntimeError, match=r"expected reset"):
        obs.update(0.1)


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(dt=0.0), ValueError, r"expected dt > 0, actual value: 0.0"),
        (dict(dt=-1e-3), ValueError, r"expected dt > 0"),
        (dict(lipschitz=0.0), ValueError, r"expected lipschitz > 0"),
        (dict(lipschitz=-1.0), ValueError, r"expected lipschitz > 0"),
        (dict(f=3.0), TypeError, r"expected f to be a callable"),
        (dict(indices=(1, 2)), ValueError, r"r_1 \+ ... \+ r_p = n = 2"),
        (dict(tol=0.0), ValueError, r"expected tol > 0"),
    ],
)
def test_bad_construction(kwargs, error, match):
    args = dict(f=f, h=h, n=2, dt=1e-3, lipschitz=L) | kwargs
    with pytest.raises(error, match=match):
        NonlinearHOSMObserver(**args)


def test_wrong_callable_shapes_are_named():
    obs = NonlinearHOSMObserver(lambda x: np.zeros(3), h, 2, 1e-3, L)
    with pytest.raises(ValueError, match=r"expected f\(x\) with shape \(2,\), actual value: shape \(3,\)"):
        obs.reset(0.1, GUESS)
    obs = NonlinearHOSMObserver(f, h, 2, 1e-3, L, phi=lambda x: np.zeros(3))
    with pytest.raises(ValueError, match=r"expected phi\(x\) with shape \(2,\)"):
        obs.reset(0.1, GUESS)
    with pytest.raises(ValueError, match=r"expected h\(x\) with shape \(1,\), actual value: shape \(2,\)"):
        observability_map(f, lambda x: np.array([1.0, 2.0]) if x[0] != 0.3 else np.array([1.0]), [0.3, 0.1])


def test_bad_observability_arguments():
    with pytest.raises(ValueError, match=r"expected finite points with shape \(N, n\)"):
        check_observability(f, h, [[np.nan, 0.0]])
    with pytest.raises(ValueError, match=r"expected rtol > 0"):
        check_observability(f, h, [[0.1, 0.0]], rtol=0.0)
    with pytest.raises(ValueError, match=r"expected g\(x\) with shape \(n,\) or \(n, m\), n = 2"):
        check_observability(f, h, [[0.1, 0.0]], g=lambda x: np.ones(3))
    with pytest.raises(TypeError, match=r"expected h to be a callable"):
        check_observability(f, "sin", [[0.1, 0.0]])


def test_update_before_reset_and_wrong_measurement():
    obs = NonlinearHOSMObserver(f, h, 2, 1e-3, L, phi=phi, phi_jacobian=phi_jacobian)
    with pytest.raises(RuntimeError, match=r"expected reset"):
        obs.update(0.1)
    obs.reset(0.1, GUESS)
    with pytest.raises(ValueError, match=r"expected y with shape \(1,\)"):
        obs.update([0.1, 0.2])
    with pytest.raises(ValueError, match=r"expected a finite measurement"):
        obs.update(np.nan)


# ---------------------------------------------------------------- MuJoCo


def test_mujoco_pendulum_measured_through_its_tip():
    """scripts/demo_nonlinear_observer.py: f from MujocoDynamics, h = the tip's x from mj_kinematics, every Lie
    derivative by finite differences through MuJoCo. Converges from a wrong guess; the velocity floor is first order
    in dt (measured 0.0171 rad/s at 2 ms, 0.0343 at 4 ms with L = 30; convergence in 0.02 s)."""
    pytest.importorskip("mujoco")
    demo = load_script("demo_nonlinear_observer")
    coarse, fine = demo.run(dt=4e-3, T=1.0), demo.run(dt=2e-3, T=1.0)
    print({k: v for k, v in fine.items() if k != "errors"}, coarse["floor_v"])
    assert fine["initial_error"] > 0.5 and fine["t_conv"] < 0.2
    assert fine["floor_q"] < 1e-6  # the angle from y = l sin q itself (finite-difference Newton tolerance)
    assert fine["floor_v"] < 0.5 * 30.0 * 2e-3  # O(L dt)
    assert 1.6 < coarse["floor_v"] / fine["floor_v"] < 2.5  # first order: ratio 2 for dt halved


def test_the_guide_example_runs_and_converges(capsys):
    """The python block of docs/guide/nonlinear-observers.md, executed as printed."""
    text = (ROOT / "docs" / "guide" / "nonlinear-observers.md").read_text()
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    scope: dict = {}
    exec(compile(code, "nonlinear-observers.md", "exec"), scope)
    assert "singular at point 1" in capsys.readouterr().out
    err = np.abs(scope["x_hat"] - scope["x"])
    assert err[0] < 1e-6 and err[1] < 5e-3, err


def test_the_guide_examples_of_the_unknown_input_and_the_injection_observer(capsys):
    """The second, third and fourth python blocks of docs/guide/nonlinear-observers.md, executed as printed (the
    first two print the errors that the guide quotes; the last builds the global observer by the design
    algorithm)."""
    text = (ROOT / "docs" / "guide" / "nonlinear-observers.md").read_text()
    blocks = [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
    assert len(blocks) == 4
    scope: dict = {}
    exec(compile(blocks[1], "nonlinear-observers.md", "exec"), scope)
    err = np.abs(scope["x_hat"] - scope["x"])
    assert err[0] < 1e-6 and err[1] < 1e-5, err
    assert abs(scope["obs"].input_estimate[0] - scope["w"](scope["k"] * scope["dt"])) < 5e-3
    scope = {}
    exec(compile(blocks[2], "nonlinear-observers.md", "exec"), scope)
    assert "expected L_g L_f^j h_i = 0" in capsys.readouterr().out
    err = np.abs(scope["x_hat"] - scope["x"])
    assert err[0] < 1e-4 and err[1] < 3e-2, err
    scope = {}
    exec(compile(blocks[3], "nonlinear-observers.md", "exec"), scope)
    assert scope["design"].margin <= 0 and np.isfinite(scope["x_hat"]).all() and scope["x_hat"][0] == 1.0


# ---- nonlinear switched systems ---------------------------------------------------------------------------------
def _pendulum_mode_observer(a: float, dt: float, lipschitz: float) -> NonlinearHOSMObserver:
    """x1' = x2, x2' = -a sin x1 - 0.1 x2 + w, y = x1 (a = g/l: the length is the mode); exact maps."""
    return NonlinearHOSMObserver(
        lambda x: np.array([x[1], -a * np.sin(x[0]) - 0.1 * x[1]]),
        lambda x: x[0],
        2,
        dt,
        lipschitz,
        phi=lambda x: np.array(x, dtype=float),
        phi_jacobian=lambda x: np.eye(2),
        lie_top=lambda x: np.array([-a * np.sin(x[0]) - 0.1 * x[1]]),
        unknown_input=[0.0, 1.0],
    )


def test_nonlinear_switched_bank_finds_the_mode_from_the_input_reconstructions():
    """A pendulum whose length switches (g/l = 1 -> 4 at 1.5 s, back at 3 s), the angle measured: the bank of
    nonlinear HOSM observers decides the mode from the inputs each model needs (zero for the right one, with
    w = 0): both switches found, none false, instants within 40 ms, decisions within 0.25 s (measured 0.12 and
    0.14 s), and the estimated mode's state at the differentiator's floor between switches."""
    from smo_gym.control import NonlinearSwitchedObserverBank, mode_metrics

    dt, gains = 1e-3, (1.0, 4.0)

    def mode(t):
        return 1 if 1.5 <= t < 3.0 else 0

    X = rk4_samples(lambda t, x: np.array([x[1], -gains[mode(t)] * np.sin(x[0]) - 0.1 * x[1]]), [1.0, 0.0], dt, 4500)
    sigma = np.array([mode(k * dt) for k in range(4500)])
    bank = NonlinearSwitchedObserverBank(
        [_pendulum_mode_observer(a, dt, 20.0) for a in gains],
        threshold=0.3,
        dwell=0.02,
        settle_time=0.3,
        residual_time_constant=0.05,
        names=["long", "short"],
    )
    estimate = bank.run(X[:, 0], [0.8, 0.0])  # the initial angle rate guess is right, the angle off by 0.2
    metrics = mode_metrics(estimate, sigma, start=0.3)
    assert metrics.missed == 0 and metrics.false_switches == 0
    np.testing.assert_allclose(estimate.switch_times, [1.5, 3.0], atol=0.04)
    assert np.all(metrics.delays < 0.25)
    err = np.abs(estimate.x_hat - X).max(axis=1)
    steady = (np.arange(4500) * dt > 0.5) & (np.abs(np.arange(4500) * dt - 1.5) > 0.3) & (np.arange(4500) * dt < 2.9)
    assert err[steady].max() < 1e-3
    assert bank.switches[-1][2] == 0


def test_nonlinear_switched_bank_bad_input():
    from smo_gym.control import NonlinearSwitchedObserverBank

    with pytest.raises(TypeError, match="at least two"):
        NonlinearSwitchedObserverBank([_pendulum_mode_observer(1.0, 1e-3, 20.0)], threshold=0.3)
    plain = NonlinearHOSMObserver(lambda x: np.array([x[1], -np.sin(x[0])]), lambda x: x[0], 2, 1e-3, 20.0)
    with pytest.raises(ValueError, match="unknown_input"):
        NonlinearSwitchedObserverBank([plain, _pendulum_mode_observer(4.0, 1e-3, 20.0)], threshold=0.3)
    with pytest.raises(ValueError, match="same state size, sampling step"):
        NonlinearSwitchedObserverBank(
            [_pendulum_mode_observer(1.0, 1e-3, 20.0), _pendulum_mode_observer(4.0, 2e-3, 20.0)], threshold=0.3
        )
    bank = NonlinearSwitchedObserverBank([_pendulum_mode_observer(a, 1e-3, 20.0) for a in (1.0, 4.0)], threshold=0.3)
    with pytest.raises(RuntimeError, match="reset"):
        bank.update([0.0])
    with pytest.raises(TypeError, match="expected reset_on_switch to be True or False"):
        NonlinearSwitchedObserverBank(
            [_pendulum_mode_observer(a, 1e-3, 20.0) for a in (1.0, 4.0)], threshold=0.3, reset_on_switch="no"
        )


# ---- global observer without the BIBS property ------------------------------------------------------------------
def _unbounded_psi(x):
    """psi = 0.5 x1 + sin x2: x1 grows like exp(0.7 t) (not BIBS, forward complete); the part in x2..xn is
    {q, S, R} = {-1, 0, 1}-dissipative (|sin(x2 + h) - sin x2| <= |h|)."""
    return 0.5 * x[0] + np.sin(x[1])


def test_global_observer_design_algorithm_is_checked():
    from smo_gym.nonlinear_observers import design_global_observer, dissipativity_constant

    d = design_global_observer(2, -1.0, [0.0], [[1.0]])
    A, C = np.eye(2, k=1), np.array([1.0, 0.0])
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(A + np.outer(d.K, C)).real), [-1.5, -1.0])
    AK = A + np.outer(d.K, C)
    lam = np.diag(d.rho_psi / (2 - np.arange(2)) ** 2)
    np.testing.assert_allclose(d.P @ AK + AK.T @ d.P, -(2 * np.eye(2) + lam), atol=1e-10)  # step c, margin I
    assert d.margin <= 0 and d.rho_psi == pytest.approx(1.0) == dissipativity_constant(-1.0, [0.0], [[1.0]])

    def largest_eigenvalue(l):  # the theorem's matrix, written out for n = 2, N = (-1, 0)
        T = np.array([[0.0, l * l]])
        top = d.P @ AK + AK.T @ d.P + np.eye(2) + T.T @ T / l**4
        off = d.P[1] + 0.0
        return np.linalg.eigvalsh(np.block([[top, off[:, None]], [off[None, :], np.array([[-l]])]])).max()

    assert largest_eigenvalue(d.l) <= 0 < largest_eigenvalue(d.l / 2)  # the doubling search stops at the first l
    with pytest.raises(ValueError, match="q < 0"):
        design_global_observer(2, 0.5, [0.0], [[1.0]])
    with pytest.raises(ValueError, match="no"):
        design_global_observer(2, -1e-6, [0.0], [[1e6]], l_max=64.0)


def test_global_observer_is_exact_on_an_unbounded_trajectory_where_the_bibs_observer_is_not():
    """x1 grows to ~70 in 6 s: the observer of (22) converges in < 0.1 s from a velocity guess off by 2 and stays
    at its sampled floor (< 2e-3, 3e-6 of the state at the end: its copy's error stays bounded whatever x does);
    the observer of Fridman et al. 2008 with L = 20 bounds y'' only while |y''| < 20, and its error grows past 1
    once the state outgrows it."""
    from smo_gym.nonlinear_observers import GlobalHOSMObserver, design_global_observer

    dt, n = 1e-3, 6001
    X = rk4_samples(lambda t, x: np.array([x[1], _unbounded_psi(x) + 0.5 * np.sin(t)]), [1.0, 0.0], dt, n)
    d = design_global_observer(2, -1.0, [0.0], [[1.0]])
    observer = GlobalHOSMObserver(_unbounded_psi, 2, dt, K=d.K, l=d.l, lipschitz=200.0, substeps=2)
    err = np.abs(observer.run(X[:, 0], [1.0, 2.0]) - X).max(axis=1)
    t = np.arange(n) * dt
    assert t[np.flatnonzero(err > 1e-2).max() + 1] < 0.1
    assert err[t > 0.2].max() < 2e-3  # the sampled floor, which does not grow with the state
    assert np.abs(X[-1]).max() > 50 and err[-1] / np.abs(X[-1]).max() < 1e-5
    bibs = NonlinearHOSMObserver(
        lambda x: np.array([x[1], _unbounded_psi(x)]), lambda x: x[0], 2, dt, 20.0,
        phi=lambda x: np.array(x, dtype=float), phi_jacobian=lambda x: np.eye(2),
    )  # fmt: skip
    assert np.abs(bibs.run(X[:, 0], [1.0, 2.0])[-1] - X[-1]).max() > 1.0


def test_dissipativity_holds_for_the_example_and_fails_for_a_steeper_nonlinearity():
    """|sin(x2 + h) - sin(x2)| <= |h|: {-1, 0, 1}-dissipative everywhere; psi = 2 x2 has Psi = 2 h, so the form
    is -4 h^2 + h^2 = -3 h^2 < 0 at every point (found, with the value -3)."""
    from smo_gym.nonlinear_observers import check_dissipativity

    points = np.random.default_rng(1).uniform(-5, 5, (20, 2))
    ok, worst, _, _ = check_dissipativity(_unbounded_psi, -1.0, [0.0], [[1.0]], points)
    assert ok and 0.0 <= worst < 1.0  # the form over h^2 is 1 - (Psi / h)^2, in [0, 1] for a 1-Lipschitz Psi
    ok, worst, _, h = check_dissipativity(lambda x: 2.0 * x[1], -1.0, [0.0], [[1.0]], points)
    assert not ok and worst == pytest.approx(-3.0) and h.shape == (1,)
    with pytest.raises(ValueError, match="points of shape"):
        check_dissipativity(_unbounded_psi, -1.0, [0.0], [[1.0]], np.zeros(3))


def test_global_observer_bad_input():
    from smo_gym.nonlinear_observers import GlobalHOSMObserver

    with pytest.raises(ValueError, match="N\\[0\\] = -1"):
        GlobalHOSMObserver(_unbounded_psi, 2, 1e-3, K=[-2.5, -1.5], l=16.0, lipschitz=200.0, N=[1.0, 0.0])
    with pytest.raises(ValueError, match="Hurwitz"):
        GlobalHOSMObserver(_unbounded_psi, 2, 1e-3, K=[2.5, 1.5], l=16.0, lipschitz=200.0)
    observer = GlobalHOSMObserver(lambda x: x, 2, 1e-3, K=[-2.5, -1.5], l=16.0, lipschitz=200.0)
    with pytest.raises(RuntimeError, match="reset"):
        observer.update(0.0)
    observer.reset(0.0, [0.0, 0.0])
    with pytest.raises(ValueError, match="finite scalar"):
        observer.update(0.0)


# ---- bad input, refusals and divergence ------------------------------------------------------------------------------
def test_the_dissipativity_check_refuses_what_it_cannot_evaluate():
    """``check_dissipativity`` compared the form with ``<``, which is False for NaN: a NaN point, ``q`` or ``psi``
    value left the worst case at +inf and the assumption "held" ((True, inf)); the same nonlinearity at finite
    points fails it (-3). Each is refused now, and the supply rate of ``dissipativity_constant`` is checked."""
    from smo_gym.nonlinear_observers import check_dissipativity, dissipativity_constant

    psi = lambda x: 2.0 * x[1]
    ok, worst, _, _ = check_dissipativity(psi, -1.0, [0.0], [[1.0]], [[0.0, 0.0]])
    assert not ok and worst == pytest.approx(-3.0)  # q Psi^2 + h^2 = -4 h^2 + h^2 over h^2
    for args in [
        (psi, -1.0, [0.0], [[1.0]], [[0.0, np.nan]]),
        (psi, np.nan, [0.0], [[1.0]], [[0.0, 0.0]]),
        (lambda x: np.nan * x[1], -1.0, [0.0], [[1.0]], [[0.0, 0.0]]),
        (psi, -1.0, [0.0], [[1.0]], np.zeros((0, 2))),
    ]:
        with pytest.raises(ValueError, match="expected"):
            check_dissipativity(*args)
    assert dissipativity_constant(-1.0, [0.0], [[1.0]]) == pytest.approx(1.0)  # (sqrt(1) + 0) / sqrt(1)
    for q, S, R in [
        (-1.0, [0.0], [[-2.0]]),
        (-np.inf, [0.0], [[1.0]]),
        (-1.0, [np.nan], [[1.0]]),
        (-(10**400), [0.0], [[1.0]]),
    ]:
        with pytest.raises(ValueError, match="expected"):
            dissipativity_constant(q, S, R)


def test_lie_derivatives_refuse_non_finite_points_and_values_and_a_depth_beyond_accuracy():
    """NaN passed through all three maps; ``order`` had no bound although each level doubles the evaluations (order
    30: about 2**30 of them, hours)."""
    from smo_gym.nonlinear_observers import MAX_NESTING

    with pytest.raises(ValueError, match="finite state"):
        lie_derivatives(f, h, [np.nan, 0.2], 2)
    with pytest.raises(ValueError, match="finite state"):
        observability_map(f, h, [])
    with pytest.raises(ValueError, match=r"order in \[0, 10\]"):
        lie_derivatives(f, h, [0.1, 0.2], MAX_NESTING + 1)
    with pytest.raises(ValueError, match="expected f"):
        lie_derivatives(lambda x: np.array([np.nan, x[0]]), h, [0.1, 0.2], 1)
    with pytest.raises(ValueError, match="phi_jacobian"):
        check_observability(f, h, [[0.1, 0.2]], phi_jacobian=lambda x: np.full((2, 2), np.nan))


def test_injection_observer_refusals_and_divergence_keep_its_state():
    """A refused reset set the state first (then the next update returned NaN); a step that overflowed returned
    NaN without an error. Both keep the previous state now; the divergence is a DivergenceError."""
    from smo_gym import DivergenceError

    obs = HOSMInjectionObserver(f, h, 2, 1e-3, L)
    obs.reset(h(np.array(X0)), GUESS)
    before = obs.state.copy()
    with pytest.raises(ValueError, match="one finite measurement"):
        obs.reset(np.nan, [9.0, 9.0])
    np.testing.assert_array_equal(obs.state, before)
    fast = HOSMInjectionObserver(lambda x: np.array([x[1], -x[0]]), lambda x: x[0], 2, 1.0, 1e308,
                                 phi_jacobian=lambda x: np.eye(2))  # fmt: skip
    fast.reset(0.0, [1.0, 0.0])
    with pytest.raises(DivergenceError):
        for _ in range(5):
            kept = fast.state.copy()
            fast.update(0.0)
    assert np.isfinite(fast.state).all()
    np.testing.assert_array_equal(fast.state, kept)


def test_a_refused_update_leaves_the_differentiators_where_they_were():
    """The differentiators took the sample before the input's reconstruction refused it; the observer then kept the
    new derivatives and state. A refused update now leaves the observer as a twin that never saw the sample: the
    same refusal, and the same estimate afterwards."""
    make = lambda: NonlinearHOSMObserver(f, h, 2, 1e-2, 500.0, unknown_input=[0.0, 1.0], rtol=0.99)
    refused, twin = make(), make()
    for obs in (refused, twin):
        obs.reset(np.sin(0.5), [0.5, 0.0])
    samples = [0.6, 0.8, 0.95, 0.99]
    for y in samples:
        try:
            refused.update(y)
        except InputReconstructionError:
            break
        twin.update(y)
    else:
        pytest.fail("expected the reconstruction to refuse a sample")
    np.testing.assert_array_equal(refused.state, twin.state)
    np.testing.assert_array_equal(refused.derivatives, twin.derivatives)
    with pytest.raises(InputReconstructionError):
        twin.update(y)
    np.testing.assert_array_equal(refused.state, twin.state)


def test_global_observer_refuses_bad_samples_and_keeps_its_state_on_divergence():
    from smo_gym import DivergenceError
    from smo_gym.nonlinear_observers import GlobalHOSMObserver, design_global_observer

    design = design_global_observer(2, -1.0, [0.0], [[1.0]])
    obs = GlobalHOSMObserver(lambda x: 0.5 * x[0] + np.sin(x[1]), 2, 1e-3, K=design.K, l=design.l, lipschitz=200.0)
    for call in (lambda: obs.reset(np.nan, [1.0, 2.0]), lambda: obs.reset([1.0, 2.0], [1.0, 2.0])):
        with pytest.raises(ValueError, match="one finite measurement"):
            call()
    obs.reset(0.0, [0.0, 0.0])
    obs.update(0.0)
    with pytest.raises(ValueError, match="one finite measurement"):
        obs.update([1.0, 99.0])  # the first entry was used, the second ignored
    with pytest.raises(ValueError, match="T >= 1"):
        obs.run([], [0.0, 0.0])
    with pytest.raises(ValueError, match="rows of U"):
        obs.run([0.0, 0.0, 0.0], [0.0, 0.0], U=[0.0])
    wild = GlobalHOSMObserver(lambda x: 0.0, 2, 0.1, K=[-2.5, -1.5], l=1e100, lipschitz=1.0)
    wild.reset(0.0, [0.0, 0.0])
    with pytest.raises(DivergenceError):
        wild.update(1.0)  # was a FloatingPointError, with the state already moved to [1, 2.5e100]
    np.testing.assert_array_equal(wild.state, [0.0, 0.0])
    twin = GlobalHOSMObserver(lambda x: 0.0, 2, 0.1, K=[-2.5, -1.5], l=1e100, lipschitz=1.0)
    twin.reset(0.0, [0.0, 0.0])
    np.testing.assert_array_equal(wild.update(0.0), twin.update(0.0))
    with pytest.raises(ValueError, match="l_max"):
        design_global_observer(2, -1.0, [0.0], [[1.0]], l_max=0.5)  # was UnboundLocalError
    with pytest.raises(ValueError, match="negative poles"):
        design_global_observer(2, -1.0, [0.0], [[1.0]], poles=[np.nan, -1.0])


def test_newton_does_not_call_a_stall_convergence():
    """At an exactly singular Jacobian the minimum-norm step is zero with the residual unchanged; the step-size test
    called that converged (residual 1.0). From a regular start the same map is solved exactly."""
    obs = NonlinearHOSMObserver(
        lambda x: np.array([x[1], 0.0]), lambda x: x[0] ** 3, 2, 1e-3, 5.0,
        phi=lambda x: np.array([x[0] ** 3, x[1]]), phi_jacobian=lambda x: np.array([[3 * x[0] ** 2, 0.0], [0.0, 1.0]]),
        tol=1e-10,
    )  # fmt: skip
    x = obs.invert(np.array([1.0, 2.0]), [0.0, 0.0])
    assert not obs.converged and obs.residual == 1.0
    np.testing.assert_array_equal(x, [0.0, 2.0])  # the x2 the minimum-norm step reaches; x1 cannot move from 0
    x = obs.invert(np.array([1.0, 2.0]), [0.5, 0.0])
    assert obs.converged and obs.residual <= 1e-10
    np.testing.assert_allclose(x, [1.0, 2.0], atol=1e-10)


def test_the_dissipation_gain_follows_from_the_inequality_for_every_q():
    """The slides' factor 1/sqrt(-q) agrees with the inequality's bound only at q = -1: psi = 2 x2 satisfies the
    {-1/4, 0, 1} inequality (the form is -Psi^2/4 + h^2 = 0) and its gain is 2, where that factor gave 1. With S:
    (|S| + sqrt(|S|^2 - q R)) / -q, here (0.5 + sqrt(1.25)) / 1, and the sign of S counts in the check's form."""
    from smo_gym.nonlinear_observers import check_dissipativity, dissipativity_constant

    points = [[0.0, 0.0], [1.0, 2.0], [-0.5, 0.3]]
    assert check_dissipativity(lambda x: 2.0 * x[1], -0.25, [0.0], [[1.0]], points)[0]
    assert dissipativity_constant(-0.25, [0.0], [[1.0]]) == pytest.approx(2.0)
    assert dissipativity_constant(-4.0, [0.0], [[1.0]]) == pytest.approx(0.5)  # sqrt(4) / 4
    assert dissipativity_constant(-1.0, [0.5], [[1.0]]) == pytest.approx(0.5 + np.sqrt(1.25))
    ok, worst, _, _ = check_dissipativity(lambda x: 2.0 * x[1], -1.0, [0.5], [[1.0]], points)
    assert not ok and worst == pytest.approx(-1.0)  # -4 h^2 + 2 (2h)(0.5 h) + h^2 over h^2


@pytest.mark.parametrize("s, nu", [(2.0, 3.0), (2.0, 0.3)])  # l = 16 and 32; without the N term 32, without S 16
def test_global_observer_design_with_the_s_and_n_terms_written_out(s, nu):
    """The design test above has S = 0 and N = (-1, 0), where the theorem's S T_l / l^(2n-1) and l N~ C terms vanish
    (dropping either passed). With S = [s] and N = (-1, nu), n = 2: T_l = [[nu l, l^2]], and the matrix is written
    out here from the slides' inequality; each case's first l changes when one of the terms is dropped."""
    from smo_gym.nonlinear_observers import design_global_observer

    d = design_global_observer(2, -1.0, [s], [[1.0]], N=[-1.0, nu])
    A, C = np.eye(2, k=1), np.array([1.0, 0.0])
    AK = A + np.outer(d.K, C)

    def largest_eigenvalue(l):
        T = np.array([[nu * l, l * l]])
        top = d.P @ AK + AK.T @ d.P + np.eye(2) + T.T @ T / l**4
        off = d.P[1] + s * T[0] / l**3
        return np.linalg.eigvalsh(np.block([[top, off[:, None]], [off[None, :], np.array([[-l]])]])).max()

    assert largest_eigenvalue(d.l) <= 0 < largest_eigenvalue(d.l / 2)
    assert d.rho_psi == pytest.approx(s + np.sqrt(1.0 + s * s))


def test_relative_degree_and_rank_conditions_on_their_own():
    """An input reaching the output below its relative degree makes the system unobservable in the sense of the
    theorem (``observable`` is False, with the coupling 1 for g = e1 here), also one level down a chain of three (an
    input into x2 with y = x1); the rank test is relative to the largest singular value (an output scaled by 1e-8 is
    still observable)."""
    report = check_observability(f, h, [[0.2, 0.1]], g=lambda x: np.array([1.0, 0.0]), raise_error=False)
    assert not report.observable[0] and report.input_coupling[0] == pytest.approx(1.0)
    chain = lambda x: np.array([x[1], x[2], -x[0]])
    with pytest.raises(ObservabilityError, match="relative degree"):
        check_observability(chain, lambda x: x[0], [[0.1, 0.2, 0.3]], g=lambda x: np.array([0.0, 1.0, 0.0]))
    check_observability(chain, lambda x: x[0], [[0.1, 0.2, 0.3]], g=lambda x: np.array([0.0, 0.0, 1.0]))
    assert check_observability(f, lambda x: 1e-8 * np.sin(x[0]), [[0.2, 0.1]], raise_error=False).observable[0]


def test_newton_backtracks_where_the_full_step_overshoots():
    """Phi = (atan x1, x2) from x1 = 3: the full Newton step of atan overshoots and diverges (to ~1e292 without the
    backtracking, which also reported converged); damped, it reaches the root."""
    obs = NonlinearHOSMObserver(
        lambda x: np.array([x[1], 0.0]), lambda x: np.arctan(x[0]), 2, 1e-3, 5.0,
        phi=lambda x: np.array([np.arctan(x[0]), x[1]]),
        phi_jacobian=lambda x: np.array([[1.0 / (1.0 + x[0] ** 2), 0.0], [0.0, 1.0]]),
        tol=1e-12,
    )  # fmt: skip
    x = obs.invert(np.zeros(2), [3.0, 1.0])
    assert obs.converged and obs.residual <= 1e-12
    np.testing.assert_allclose(x, [0.0, 0.0], atol=1e-12)


def test_the_input_estimate_is_zero_where_the_guess_is_the_state():
    """Started at the true state, the input differentiator's top derivative starts at L_f^r h(x0), so the
    reconstructed unknown input is 0 at the reset (starting it at 0 instead gave the drift's L_f^2 h over L_d
    L_f h)."""
    x0 = np.array([0.6, -0.4])
    obs = NonlinearHOSMObserver(f, h, 2, 1e-3, 50.0, unknown_input=[0.0, 1.0])
    obs.reset(h(x0), x0)
    np.testing.assert_allclose(obs.state, x0, atol=1e-9)
    np.testing.assert_allclose(obs.derivatives, phi(x0), atol=1e-9)
    np.testing.assert_allclose(obs.input_estimate, 0.0, atol=1e-6)


def test_the_global_observer_feeds_psi_the_measured_first_coordinate():
    """psi is evaluated at v + N (Cv - y) with N = (-1, 0, ...): its first coordinate is the output (here the Taylor
    polynomial of the estimate at each Runge-Kutta stage, the estimate itself at the stage at the sample), not the
    copy's own v1 (which a mutation left every other test blind to)."""
    from smo_gym.nonlinear_observers import GlobalHOSMObserver, design_global_observer

    seen = []

    def psi(x):
        seen.append(np.array(x))
        return 0.5 * x[0] + np.sin(x[1])

    d = design_global_observer(2, -1.0, [0.0], [[1.0]])
    obs = GlobalHOSMObserver(psi, 2, 1e-2, K=d.K, l=d.l, lipschitz=200.0)
    obs.reset(1.0, [1.0, 0.0])
    obs.update(1.0)
    copy_before = obs.copy.copy()
    seen.clear()
    estimate = obs.update(1.05)
    assert seen[0][0] == pytest.approx(estimate[0], abs=1e-12) and abs(seen[0][0] - copy_before[0]) > 1e-6


def test_each_output_has_its_own_differentiator_gain():
    """With two outputs, output i is differentiated with ``lipschitz[i]`` (taking the first for both passed every
    test: none had two differentiated outputs). Two uncoupled pendulums, gains 5 and 500: each output's derivatives
    are those of a one-output observer with its gain on it alone."""

    def two(x):
        return np.concatenate([f(x[:2]), f(x[2:])])

    both = NonlinearHOSMObserver(
        two, lambda x: np.array([h(x[:2]), h(x[2:])]), 4, 1e-3, [L, 500.0], indices=(2, 2)
    )  # fmt: skip
    first, second = NonlinearHOSMObserver(f, h, 2, 1e-3, L), NonlinearHOSMObserver(f, h, 2, 1e-3, 500.0)
    X = rk4_samples(lambda t, x: two(x), [0.8, 0.0, -0.5, 0.3], 1e-3, 400)
    both.reset([h(X[0, :2]), h(X[0, 2:])], [0.3, 0.5, -0.2, 0.1])
    first.reset(h(X[0, :2]), [0.3, 0.5])
    second.reset(h(X[0, 2:]), [-0.2, 0.1])
    joint, alone = [], []
    for x in X[1:]:
        both.update([h(x[:2]), h(x[2:])])
        first.update(h(x[:2]))
        second.update(h(x[2:]))
        joint.append(both.derivatives.copy())
        alone.append(np.concatenate([first.derivatives, second.derivatives]))
    # equal but for the rounding of the start (Phi(x0) by finite differences over 4 states, not 2)
    np.testing.assert_allclose(joint, alone, rtol=1e-9, atol=1e-12)
