"""LTV strong observability (Kratz and Liebscher 1998) and the cascaded HOSM observer of Galvan-Guerra, Fridman and
Davila (2017): the rank test against the LTI one, the state reconstruction, finite-time exactness on an unstable
time-varying plant with an unknown input, and the accuracy orders in the sampling step and the noise level."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from smo_gym import DivergenceError
from smo_gym.control import (
    CascadedLTVObserver,
    LTVPlant,
    NotStronglyObservableError,
    fit_order,
    furuta_slides,
    helicopter_slides,
    ltv_example,
    ltv_state_map,
    ltv_strong_observability,
    simulate_ltv,
    strong_observability,
)
from smo_gym.control.ltv import kratz_liebscher_matrices


# ---- the example: unstable (frozen eigenvalue 1.47 > 0), time-varying A, C, D; w reaches y2 directly (CD != 0)
def A(t):
    return np.array([[0.5, 1 + 0.3 * np.sin(t), 0.0], [0.0, 0.0, 1.0], [1.0, 0.4 * np.cos(t), 0.5]])


def C(t):
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.3 * np.sin(t), 1.0]])


def D(t):
    return np.array([[0.0], [0.0], [1 + 0.3 * np.cos(t)]])


def w(t):
    return np.array([0.5 * np.sin(2 * t) + 0.3 * np.cos(3 * t) + 0.2])


def dA(t, k):
    """Exact derivatives of A: the stack [A, A', ..., A^(k)]."""
    out = np.zeros((k + 1, 3, 3))
    for j in range(k + 1):
        out[j, 0, 1] = 0.3 * np.sin(t + j * np.pi / 2) + (1.0 if j == 0 else 0.0)
        out[j, 2, 1] = 0.4 * np.cos(t + j * np.pi / 2)
        if j == 0:
            out[j, 0, 0], out[j, 1, 2], out[j, 2, 0], out[j, 2, 2] = 0.5, 1.0, 1.0, 0.5
    return out


def dC(t, k):
    out = np.zeros((k + 1, 2, 3))
    out[:, 1, 1] = [0.3 * np.sin(t + j * np.pi / 2) for j in range(k + 1)]
    out[0, 0, 0], out[0, 1, 2] = 1.0, 1.0
    return out


def dD(t, k):
    out = np.zeros((k + 1, 3, 1))
    out[:, 2, 0] = [0.3 * np.cos(t + j * np.pi / 2) for j in range(k + 1)]
    out[0, 2, 0] += 1.0
    return out


EXACT = {"A": dA, "C": dC, "D": dD}
X0 = np.array([1.0, -1.0, 0.5])
LIPSCHITZ = 30.0  # bound on the 4th derivative of the output errors (alpha = 2: differentiator order 3)
T_FINAL = 2.5
STEADY = 1.5  # the errors are measured from here on


def plant(**kw):
    return LTVPlant(A, None, C, D, **kw)


@cache
def run(dt: float, noise: float = 0.0, seed: int = 0):
    """Simulate the example and run the observer (identifying w as well); returns (t, x, x_hat, w, w_hat)."""
    pl = plant(derivatives=EXACT)  # exact derivatives: faster than the numerical ones (compared in another test)
    t, X, Y, _ = simulate_ltv(pl, X0, T_FINAL, dt, w=w, substeps=4)
    if noise:
        Y = Y + noise * np.random.default_rng(seed).uniform(-1, 1, Y.shape)
    obs = CascadedLTVObserver(pl, dt, LIPSCHITZ, alpha=2, identify=True)
    Xh, Wh = np.zeros_like(X), np.zeros((len(t), 1))
    obs.reset(Y[0])
    for k in range(len(t)):
        Xh[k] = obs.update(Y[k])
        Wh[k] = obs.w_hat
        obs.advance()
    return t, X, Xh, np.array([w(s) for s in t]), Wh


# ---- strong observability -------------------------------------------------------------------------------------
def test_example_is_strongly_observable_with_two_blocks_and_K_matters():
    rep = ltv_strong_observability(plant(), np.linspace(0.0, 2 * np.pi, 25))
    assert rep.ok and rep.condition == "" and rep.blocks == 2 and rep.observability_index == 2
    assert np.all(rep.rank_S == rep.rank_S_star) and rep.margin.min() > 0.1
    # the input reaches y2' (CD != 0): O_2 has 4 rows of rank 3 and the reconstruction must drop the w-row
    _, J = kratz_liebscher_matrices(*plant().series(0.4, 2), 2)
    assert np.linalg.matrix_rank(J) == 1 and abs(J[3, 0] - (1 + 0.3 * np.cos(0.4))) < 1e-12


def test_module_example_is_this_one_with_exact_derivatives():
    ex, w_ex, x0 = ltv_example()
    assert np.array_equal(x0, X0) and w_ex(0.7) == w(0.7)
    for t in (0.0, 0.7, 2.0):
        for name in EXACT:
            assert np.abs(ex.taylor(name, t, 4) - plant(derivatives=EXACT).taylor(name, t, 4)).max() < 1e-15
            assert np.array_equal(ex.matrix(name, t), {"A": A, "C": C, "D": D}[name](t))


def test_taylor_derivatives_complex_central_and_exact_agree():
    t = 0.7
    for name, d in EXACT.items():
        exact = d(t, 4)
        for pl, tol in ((plant(), 1e-9), (plant(method="central"), 1e-6), (plant(derivatives=EXACT), 1e-15)):
            got = pl.taylor(name, t, 4) * np.array([1, 1, 2, 6, 24])[:, None, None]
            assert np.abs(got - exact).max() < tol, (name, pl.method)


def test_kratz_liebscher_recursion_matches_output_derivatives_of_a_simulation():
    """y^(i) = N_i x + sum_j D_{i+1,j} w^(j-1): check y'' against finite differences of a fine simulation."""
    pl = plant()
    dt = 1e-3
    t, X, Y, _ = simulate_ltv(pl, X0, 0.52, dt, w=w, substeps=4)
    k = 500
    O, J = kratz_liebscher_matrices(*pl.series(t[k], 3), 3)
    wk = w(t[k])
    wdot = (w(t[k] + 1e-6) - w(t[k] - 1e-6)) / 2e-6
    ybar = O @ X[k] + J @ np.concatenate([wk, wdot])
    fd1 = (Y[k + 1] - Y[k - 1]) / (2 * dt)
    fd2 = (Y[k + 1] - 2 * Y[k] + Y[k - 1]) / dt**2
    assert np.abs(ybar[:2] - Y[k]).max() < 1e-12
    assert np.abs(ybar[2:4] - fd1).max() < 1e-5
    assert np.abs(ybar[4:6] - fd2).max() < 1e-4


def test_constant_matrices_give_markov_parameters():
    """For constant matrices N_i = C A^i and D_{mu,nu} = C A^(mu-nu-1) D (five blocks exercise every rule of the
    recursion, including D_{4,2} = D_{3,1} + d/dt D_{3,2} that the slides' printed range 3 <= nu leaves out)."""
    rng = np.random.default_rng(1)
    A_, C_, D_ = rng.normal(size=(4, 4)), rng.normal(size=(2, 4)), rng.normal(size=(4, 2))
    O, J = kratz_liebscher_matrices(*LTVPlant(A_, None, C_, D_).series(0.0, 5), 5)
    P = np.linalg.matrix_power
    assert np.allclose(O, np.vstack([C_ @ P(A_, i) for i in range(5)]), rtol=1e-12, atol=1e-12)
    for i in range(5):
        for j in range(4):
            want = C_ @ P(A_, i - 1 - j) @ D_ if j < i else np.zeros((2, 2))
            assert np.allclose(J[2 * i : 2 * i + 2, 2 * j : 2 * j + 2], want, rtol=1e-12, atol=1e-12), (i, j)


@pytest.mark.parametrize("lti", [furuta_slides, helicopter_slides])
def test_constant_matrices_agree_with_the_lti_test(lti):
    p = lti()
    pl = LTVPlant(p.A, p.B, p.C, p.D)
    rep = ltv_strong_observability(pl, 0.0)
    assert rep.ok == strong_observability(p).ok is True
    assert rep.blocks == 2  # every output has relative degree 2


@pytest.mark.parametrize(
    "A_, C_, D_",
    [
        ([[0.0, 1.0], [0.0, 0.0]], [[1.0, 0.0]], [[1.0], [0.0]]),  # relative degree 1 < n: invariant zero at 0
        ([[1.0, 0.0], [0.0, -2.0]], [[1.0, 0.0]], [[1.0], [1.0]]),  # unobservable mode
        (np.diag([1.0, 2.0, 3.0]), [[1.0, 1.0, 1.0]], [[0.0], [1.0], [-1.0]]),  # relative degree 2 < n = 3
    ],
)
def test_constant_matrices_not_strongly_observable_agree_with_the_lti_test(A_, C_, D_):
    rep = ltv_strong_observability(LTVPlant(A_, None, C_, D_), 0.0)
    assert not strong_observability(np.array(A_), np.array(C_), np.array(D_)).ok
    assert not rep.ok and rep.condition in ("observability", "strong observability")


def test_observability_index_is_not_enough_derivatives():
    """x1' = x3, x3' = x4, x2' = x4 + w, y = (x1, x2): Rugh's index is 2 but x4 needs y1'' (three blocks)."""
    A_ = np.zeros((4, 4))
    A_[0, 2], A_[2, 3], A_[1, 3] = 1.0, 1.0, 1.0
    C_, D_ = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]]), np.array([[0.0], [1.0], [0.0], [0.0]])
    pl = LTVPlant(A_, None, C_, D_)
    rep = ltv_strong_observability(pl, 0.0)
    assert rep.ok and rep.observability_index == 2 and rep.blocks == 3
    assert strong_observability(
        A_, np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]]), np.array([[0.0], [1.0], [0.0], [0.0]])
    ).ok
    two = ltv_strong_observability(pl, 0.0, blocks=2)
    assert not two.ok and two.condition == "strong observability" and "rank S(t) = 4 < rank S*(t) = 5" in two.reason


def test_time_varying_failure_is_located_and_named():
    """C(t) = [cos t, 0]: observable where cos t != 0 only (C and C' + CA lose rank at pi/2), which is reported."""
    pl = LTVPlant([[0.0, 1.0], [0.0, 0.0]], None, lambda t: np.array([[np.cos(t), 0.0]]), [[0.0], [1.0]])
    assert ltv_strong_observability(pl, [0.0, 1.0]).ok
    rep = ltv_strong_observability(pl, [0.0, np.pi / 2, 1.0], blocks=2)
    assert not rep.ok and rep.condition == "observability" and "t=1.5708" in rep.reason
    assert "rank O_2(t) = 1 < n = 2" in rep.reason
    assert list(rep.rank_S != rep.rank_S_star) == [False, True, False]


def test_not_strongly_observable_raises_with_the_condition():
    bad = LTVPlant(A, None, lambda t: np.array([[1.0, 0.0, 0.0]]), [[0.0], [1.0], [0.0]])  # w enters x2: r = 2 < 3
    with pytest.raises(NotStronglyObservableError, match="strong observability condition fails: rank S"):
        CascadedLTVObserver(bad, 1e-3, 10.0)
    unobs = LTVPlant(np.diag([1.0, -1.0]), None, [[1.0, 0.0]], [[1.0], [0.0]])
    with pytest.raises(NotStronglyObservableError, match=r"observability condition fails.*not observable"):
        ltv_state_map(unobs, 0.0, 2)


def test_observer_refuses_a_sample_where_the_condition_fails():
    """Strongly observable at t0, but the sensor goes blind at t = 0.05: the run stops there, naming why."""

    def C_(t):
        return np.array([[1.0 if np.real(t) < 0.05 else 0.0, 0.0]])

    def dC_(t, k):
        out = np.zeros((k + 1, 1, 2))
        out[0] = C_(t)
        return out

    pl = LTVPlant([[0.0, 1.0], [0.0, 0.0]], None, C_, [[0.0], [1.0]], derivatives={"C": dC_})
    obs = CascadedLTVObserver(pl, 0.01, 1.0)
    obs.reset(np.zeros(1))
    with pytest.raises(NotStronglyObservableError, match=r"observability condition fails.*t=0.05") as info:
        for _ in range(20):
            obs.update(np.zeros(1))
            obs.advance()
    assert obs.t == pytest.approx(0.04), info.value  # refused while preparing the jump map for t = 0.05


# ---- state reconstruction --------------------------------------------------------------------------------------
def test_state_map_recovers_the_state_from_exact_output_derivatives_whatever_w():
    pl = plant()
    t, x = 1.3, np.array([0.3, -2.0, 1.1])
    O, J = kratz_liebscher_matrices(*pl.series(t, 2), 2)
    F = ltv_state_map(pl, t, 2)
    for wv in (0.0, 5.0, -40.0):
        assert np.abs(F @ (O @ x + J @ np.array([wv])) - x).max() < 1e-12


# ---- the observer ---------------------------------------------------------------------------------------------
def _convergence_time(t, err, tol):
    above = np.nonzero(err > tol)[0]
    return t[above[-1] + 1] if above.size else t[0]


def test_exact_after_finite_time_on_an_unstable_plant():
    r"""From an error above 0.1 the estimate is within 1e-3 in finite time (measured 1.19 s) and stays there while
    the plant grows 13.6-fold; from 1.5 s on the error is that of the order-3 differentiator, of order
    :math:`L\tau^3` (Levant 2003; measured 3.9 :math:`L\tau^3`, 7.4e-6, and eight times less at half the step)."""
    tau = 4e-3
    t, X, Xh, _, _ = run(tau)
    err = np.linalg.norm(Xh - X, axis=1)
    growth = np.linalg.norm(X[-1]) / np.linalg.norm(X[0])
    assert growth > 10  # the plant is unstable (13.6 over 2.5 s)
    assert err[0] > 0.1  # the estimate did start wrong
    assert _convergence_time(t, err, 1e-3) < 1.5
    assert err[t >= 1.5].max() < 5 * LIPSCHITZ * tau**3


def test_unknown_input_identification_order():
    """w_hat = G (Y_{l+1} - O_{l+1} e_hat). Here w is read from y2' (CD != 0) and the first derivatives only:
    G weights no e_y'', so the error is O(tau^(k+1-1)) = O(tau^3), not the worst case O(tau^alpha)."""
    obs = CascadedLTVObserver(plant(derivatives=EXACT), 4e-3, LIPSCHITZ, alpha=2, identify=True)
    expected = obs.theoretical_orders["identification"]
    assert expected == 3.0
    steps = [1.6e-2, 8e-3, 4e-3]
    errors = []
    for dt in steps:
        t, _, _, W, Wh = run(dt)
        errors.append(np.abs(Wh - W)[t >= STEADY].max())
    order = fit_order(steps, errors)
    print(f"identification errors {errors}, fitted order {order:.2f}, theory {expected}")
    assert abs(order - expected) < 0.5 and errors[-1] < 1e-3
    t, _, _, W, Wh = run(4e-3)
    assert np.abs(Wh - W)[: int(0.5 / 4e-3)].max() > 0.1  # it did have to converge


def test_identification_needs_a_higher_order_differentiator():
    with pytest.raises(ValueError, match="alpha >= 1 with identify=True"):
        CascadedLTVObserver(plant(), 1e-3, 1.0, alpha=0, identify=True)


def test_known_control_and_numerical_derivatives():
    """B(t) u with u held between samples, and A, C, D differentiated by Cauchy's formula (the default)."""
    dt = 8e-3
    pl = LTVPlant(A, lambda t: np.array([[0.0], [1 + 0.2 * np.sin(t)], [0.0]]), C, D)

    def u(t):
        return np.array([2.0 * np.sin(5 * t)])

    t, X, Y, U = simulate_ltv(pl, X0, T_FINAL, dt, w=w, u=u, substeps=4)
    Xh = CascadedLTVObserver(pl, dt, LIPSCHITZ, alpha=2).run(Y, U)
    without_u = CascadedLTVObserver(pl, dt, LIPSCHITZ, alpha=2).run(Y)
    err = np.abs(Xh - X)[t >= STEADY].max()
    print(f"steady error with B(t)u and numerical derivatives at dt={dt}: {err:.2e}")
    assert err < 2e-4  # 5.7e-5 without control at this step
    assert np.abs(without_u - X)[t >= STEADY].max() > 100 * err  # the control is not negligible


def test_accuracy_order_in_the_sampling_step():
    steps = [1.6e-2, 8e-3, 4e-3]
    errors = []
    for dt in steps:
        t, X, Xh, _, _ = run(dt)
        errors.append(np.abs(Xh - X)[t >= STEADY].max())
    obs = CascadedLTVObserver(plant(), 4e-3, LIPSCHITZ, alpha=2)
    expected = obs.theoretical_orders["state"]  # alpha + 1 = 3
    order = fit_order(steps, errors)
    print(f"errors {errors}, fitted order {order:.2f}, theory {expected}")
    assert expected == 3.0 and abs(order - expected) < 0.5


def test_accuracy_order_in_the_noise_level():
    levels = [1e-4, 1e-3, 1e-2]  # the sampling error at dt = 8e-3 is 6e-5, below the noise's effect
    errors = []
    for eps in levels:
        t, X, Xh, _, _ = run(8e-3, eps)
        errors.append(np.abs(Xh - X)[t >= STEADY].max())
    expected = CascadedLTVObserver(plant(), 8e-3, LIPSCHITZ, alpha=2).theoretical_orders["noise"]  # 3/4
    order = fit_order(levels, errors)
    print(f"errors {errors}, fitted order {order:.2f}, theory {expected}")
    assert abs(order - expected) < 0.2


# ---- bad input -------------------------------------------------------------------------------------------------
def test_wrong_shapes_and_values_are_typed_errors():
    with pytest.raises(ValueError, match=r"expected C\(t\) with shape \(2, 3\).*actual value: shape \(2, 2\)"):
        LTVPlant(A, None, lambda t: np.ones((2, 2)), D)
    assert LTVPlant(A, None, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]).C(0.0).shape == (1, 3)  # a vector C is one row
    with pytest.raises(TypeError, match="expected D a callable"):
        LTVPlant(A, None, C, None)
    with pytest.raises(ValueError, match=r"expected A\(t\) square"):
        LTVPlant(np.ones((2, 3)), None, C, D)
    late = LTVPlant(A, None, lambda t: np.ones((2, 3)) if t < 1 else np.ones((3, 3)), D)
    with pytest.raises(ValueError, match=r"expected C\(t\) with shape \(2, 3\) at t=.*actual value: shape \(3, 3\)"):
        late.C(2.0)
    with pytest.raises(ValueError, match="to accept a complex t"):
        LTVPlant(lambda t: np.array([[float(t)]]), None, [[1.0]], [[0.0]])
    with pytest.raises(ValueError, match="expected dt > 0"):
        CascadedLTVObserver(plant(), -1e-3, 1.0)
    with pytest.raises(ValueError, match="lipschitz > 0"):
        CascadedLTVObserver(plant(), 1e-3, -1.0)
    with pytest.raises(ValueError, match="P0 symmetric positive definite"):
        CascadedLTVObserver(plant(), 1e-3, 1.0, P0=-np.eye(3))
    with pytest.raises(ValueError, match="positive definite or forgetting > 0"):
        CascadedLTVObserver(plant(), 1e-3, 1.0, forgetting=0.0)
    with pytest.raises(TypeError, match="expected an LTVPlant"):
        CascadedLTVObserver(furuta_slides(), 1e-3, 1.0)
    obs = CascadedLTVObserver(plant(), 1e-3, 1.0)
    with pytest.raises(RuntimeError, match="expected reset"):
        obs.update(np.zeros(2))
    obs.reset(np.zeros(2))
    with pytest.raises(ValueError, match=r"expected y\(t\) with shape \(2,\)"):
        obs.update(np.zeros(3))


def test_rank_test_does_not_depend_on_the_scale_of_C():
    """Multiplying C by a constant changes no rank: the unobservable x2 stays unobservable with C = 1e10 [1, 0],
    and the double integrator stays strongly observable with C = 1e-10 [1, 0]."""
    for scale in (1.0, 1e10):
        unobs = LTVPlant(np.diag([1.0, -1.0]), None, [[scale, 0.0]], [[1.0], [0.0]])
        rep = ltv_strong_observability(unobs, 0.0)
        assert not rep.ok and rep.condition == "observability", (scale, rep)
    for scale in (1.0, 1e-10):
        rep = ltv_strong_observability(LTVPlant([[0.0, 1.0], [0.0, 0.0]], None, [[scale, 0.0]], [[0.0], [1.0]]), 0.0)
        assert rep.ok and rep.blocks == 2, (scale, rep)


UNIT_SCALINGS = [(1e-10, 1, 1), (1e10, 1, 1), (1, 1e-10, 1), (1, 1e10, 1), (1, 1, 1e-10), (1, 1, 1e10)]
UNIT_SCALINGS += [(1e-10, 1e-10, 1e-10), (1e10, 1e10, 1e10), (1e10, 1e-10, 1e10)]


def _in_units(a, c, d):
    """The example with time in units 1/a, y scaled by c and w by 1/d: A_a(t) = a A(a t), C_a(t) = c C(a t),
    D_a(t) = d a D(a t) (exact derivatives, chain rule)."""

    def up(k):  # d^k/dt^k M(a t) = a^k M^(k)(a t)
        return a ** np.arange(k + 1)[:, None, None]

    return LTVPlant(
        lambda t: a * A(a * t),
        None,
        lambda t: c * C(a * t),
        lambda t: d * a * D(a * t),
        derivatives={
            "A": lambda t, k: a * dA(a * t, k) * up(k),
            "C": lambda t, k: c * dC(a * t, k) * up(k),
            "D": lambda t, k: d * a * dD(a * t, k) * up(k),
        },
    )


def test_verdicts_do_not_depend_on_units():
    """A, C, D in other units of time, y and w change no verdict, no rank and not the margin (1e-10 .. 1e10). The
    blocks y^(i) of O and J scale as c a^i and were judged against the largest: the example was 'not observable'
    for a = 1e-10 or 1e10, and 'not strongly observable' for d = 1e10; for d = 1e-10 w could not be identified
    (input_map's absolute floor), and the state map of C = 1e-10 C did not annihilate w."""
    grid = np.linspace(0.0, 2 * np.pi, 9)
    ref = ltv_strong_observability(_in_units(1, 1, 1), grid)
    assert ref.ok and ref.blocks == 2 and ref.observability_index == 2
    t, x = 1.3, np.array([0.3, -2.0, 1.1])
    for a, c, d in UNIT_SCALINGS:
        pl = _in_units(a, c, d)
        rep = ltv_strong_observability(pl, grid / a)
        assert (rep.ok, rep.blocks, rep.observability_index) == (True, 2, 2), (a, c, d, rep.reason)
        assert rep.rank_S.tolist() == ref.rank_S.tolist() and rep.rank_S_star.tolist() == ref.rank_S_star.tolist()
        np.testing.assert_allclose(rep.margin, ref.margin, rtol=1e-9)
        obs = CascadedLTVObserver(pl, 4e-3 / a, LIPSCHITZ * a**4, alpha=2, identify=True)
        assert obs.theoretical_orders == {
            "state": 3.0,
            "noise": 0.75,
            "identification": 3.0,
            "identification_noise": 0.75,
        }
        O, J = kratz_liebscher_matrices(*pl.series(t / a, 2), 2)
        ybar = O @ x + J @ np.array([7.0 / (a * d)])  # any w: the map removes it
        np.testing.assert_allclose(ltv_state_map(pl, t / a, 2) @ ybar, x, atol=1e-12)


def test_blocks_that_vanish_exactly_stay_zero_at_every_scale():
    """Constant matrices in random coordinates (C D = C A D = 0 up to rounding): a chain of 3 needs three blocks at
    every scale, the LTI counterexamples stay refused for the same reason, and y = c cos(a t) x1 on a double
    integrator goes blind at t = pi / (2 a) (where C(t) is c times the rounding error of cos) and only there. For
    a = 1e-10 or 1e10 all were 'not observable' everywhere; for d = 1e-10 two counterexamples passed."""
    T = np.linalg.qr(np.random.default_rng(7).standard_normal((3, 3)))[0]
    chain = (T @ np.eye(3, k=1) @ T.T, np.array([[1.0, 0.0, 0.0]]) @ T.T, T @ np.array([[0.0], [0.0], [1.0]]))
    refused = [
        (np.eye(2, k=1), [[1.0, 0.0]], [[1.0], [0.0]], "strong observability"),  # invariant zero at 0
        (np.diag([1.0, -2.0]), [[1.0, 0.0]], [[1.0], [1.0]], "observability"),  # unobservable mode
        (np.diag([1.0, 2.0, 3.0]), [[1.0, 1.0, 1.0]], [[0.0], [1.0], [-1.0]], "strong observability"),
    ]
    for a, c, d in [(1, 1, 1), *UNIT_SCALINGS]:
        rep = ltv_strong_observability(LTVPlant(a * chain[0], None, c * chain[1], d * chain[2]), 0.0)
        assert (rep.ok, rep.blocks, rep.observability_index) == (True, 3, 3), (a, c, d)
        for A_, C_, D_, condition in refused:
            rep = ltv_strong_observability(LTVPlant(a * A_, None, c * np.array(C_), d * np.array(D_)), 0.0)
            assert not rep.ok and rep.condition == condition, (a, c, d, rep.reason)

        def dC_(t, k, a=a, c=c):
            return np.array([[[c * a**j * np.cos(a * t + j * np.pi / 2), 0.0]] for j in range(k + 1)])

        pl = LTVPlant(
            a * np.eye(2, k=1),
            None,
            lambda t, a=a, c=c: [[c * np.cos(a * t), 0.0]],
            [[0.0], [d]],
            derivatives={"C": dC_},
        )
        assert ltv_strong_observability(pl, np.array([0.0, 1.0]) / a).ok, (a, c, d)
        rep = ltv_strong_observability(pl, np.array([0.0, np.pi / 2, 1.0]) / a, blocks=2)
        assert not rep.ok and rep.condition == "observability" and "rank O_2(t) = 1 < n = 2" in rep.reason
        assert list(rep.rank_S != rep.rank_S_star) == [False, True, False], (a, c, d)


def _blind_at_half_pi():
    """y = cos(t) x1 on a double integrator: not observable at t = pi/2, the 51st sample with dt = pi/100."""
    pl = LTVPlant([[0.0, 1.0], [0.0, 0.0]], None, lambda t: np.array([[np.cos(t), 0.0]]), [[0.0], [1.0]])
    return CascadedLTVObserver(pl, np.pi / 100, 1.0)


def _steps(obs, count, start=0):
    for k in range(start, start + count):
        obs.update([np.cos(k * np.pi / 100)])
        obs.advance()


def test_refused_reset_leaves_the_observer_as_it_was():
    a, b = _blind_at_half_pi(), _blind_at_half_pi()
    for obs in (a, b):
        obs.reset([1.0])
        _steps(obs, 3)
    with pytest.raises(ValueError, match=r"expected finite y0.*actual value"):
        a.reset([np.nan])
    with pytest.raises(ValueError, match=r"expected finite z0.*actual value"):
        a.reset([1.0], z0=[np.inf, 0.0])
    with pytest.raises(ValueError, match="expected P0 symmetric positive definite"):
        a.reset([1.0], P0=-np.eye(2))
    assert a.t == b.t
    for k in range(3, 6):
        np.testing.assert_array_equal(a.update([np.cos(k * np.pi / 100)]), b.update([np.cos(k * np.pi / 100)]))
        a.advance()
        b.advance()
    np.testing.assert_array_equal(a.z, b.z)
    np.testing.assert_array_equal(a.P, b.P)
    fresh = _blind_at_half_pi()
    with pytest.raises(ValueError, match="expected finite y0"):
        fresh.reset([np.nan])
    with pytest.raises(RuntimeError, match="expected reset"):
        fresh.update([1.0])


def test_refused_update_leaves_the_observer_as_it_was():
    """The state map is refused at t + dt = pi/2 while preparing the next sample: the update is undone whole."""
    a, b = _blind_at_half_pi(), _blind_at_half_pi()
    for obs in (a, b):
        obs.reset([1.0])
        _steps(obs, 49)
    x_hat, e_hat, output_error = a.x_hat.copy(), a.e_hat.copy(), a.output_error.copy()
    for _ in range(2):  # the retry is refused for the same reason, not as a second update
        with pytest.raises(NotStronglyObservableError, match=r"t=1.5708"):
            a.update([np.cos(49 * np.pi / 100)])
    np.testing.assert_array_equal(a.x_hat, x_hat)
    np.testing.assert_array_equal(a.e_hat, e_hat)
    np.testing.assert_array_equal(a.output_error, output_error)
    np.testing.assert_array_equal(a.differentiator.state, b.differentiator.state)
    np.testing.assert_array_equal(a._dstate, b._dstate)
    with pytest.raises(ValueError, match="expected finite y"):
        a.update([np.nan])
    np.testing.assert_array_equal(a.output_error, output_error)
    c, d = _blind_at_half_pi(), _blind_at_half_pi()
    for obs in (c, d):
        obs.reset([1.0])
        _steps(obs, 2)
    with pytest.raises(ValueError, match="expected finite y"):
        c.update([np.inf])
    _steps(c, 3, start=2)
    _steps(d, 3, start=2)
    np.testing.assert_array_equal(c.x_hat, d.x_hat)


def test_run_and_lipschitz_refuse_bad_shapes():
    with pytest.raises(ValueError, match=r"expected y with at least one sample.*actual value: shape \(0, 1\)"):
        _blind_at_half_pi().run(np.zeros((0, 1)))
    with pytest.raises(ValueError, match=r"expected lipschitz a number or one per output \(2\).*shape \(3,\)"):
        CascadedLTVObserver(plant(), 1e-3, [1.0, 2.0, 3.0])


def test_simulation_refuses_non_finite_inputs_and_a_diverging_trajectory():
    pl, _w, x0 = ltv_example()
    with pytest.raises(ValueError, match=r"expected finite x0.*actual value"):
        simulate_ltv(pl, [np.nan, 0.0, 0.0], 0.1, 0.01)
    with pytest.raises(ValueError, match=r"expected finite w\(t\).*actual value"):
        simulate_ltv(pl, x0, 0.1, 0.01, w=lambda t: [np.nan])
    with pytest.raises(TypeError, match=r"expected w\(t\) to be an array of real numbers.*None"):
        simulate_ltv(pl, x0, 0.1, 0.01, w=lambda t: None)
    with pytest.raises(DivergenceError, match=r"expected a finite state.*actual value"):
        simulate_ltv(LTVPlant([[50.0]], None, [[1.0]], [[1.0]]), [1.0], 20.0, 0.5)


def test_plant_refuses_no_state_non_finite_derivatives_and_a_non_dict():
    with pytest.raises(ValueError, match=r"expected A\(t\) with at least one state.*shape \(0, 0\)"):
        LTVPlant(np.zeros((0, 0)), None, np.zeros((1, 0)), np.zeros((0, 1)))
    nan_derivs = LTVPlant(
        [[0.0, 1.0], [0.0, 0.0]],
        None,
        lambda t: np.array([[1.0, 0.0]]),
        [[0.0], [1.0]],
        derivatives={"C": lambda t, k: np.full((k + 1, 1, 2), np.nan)},
    )
    with pytest.raises(ValueError, match=r"expected finite entries in derivatives\['C'\]"):
        ltv_strong_observability(nan_derivs, 0.0)
    with pytest.raises(TypeError, match=r"expected derivatives a dict.*actual value: \[1, 2\]"):
        LTVPlant([[1.0]], None, [[1.0]], [[1.0]], derivatives=[1, 2])
