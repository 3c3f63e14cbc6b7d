"""Tests of smo_gym.control.unknown_inputs: strongly detectable observer, functional UIO, static left inverse.

Each plant is built so that its invariant zeros, weakly unobservable subspace and left inverse follow by hand
(written next to it); the estimators are then measured against those: finite-time exactness of the strongly
observable coordinates, decay at the rate of the slowest invariant zero for the rest, and the accuracy orders of
the identification in the sampling step and in the noise amplitude (Fridman's slides, sections 3 and 7).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_script

from smo_gym import control as c

# the example plants and the open-loop harness are the reproduction script's (one definition of each)
examples = load_script("reproduce_slides_unknown_inputs")
_w, _transformed, _OpenLoop = examples.unknown_input, examples.transformed, examples.OpenLoop
_settling_time, _identification_error = examples.settling_time, examples.identification_error
_detectable_plant, _functional_plant = examples.detectable_plant, examples.functional_plant
_left_inverse_plant = examples.left_inverse_plant


# ---------------------------------------------------------------------------------------------------------------
# strong detectability
# ---------------------------------------------------------------------------------------------------------------
def test_strong_detectability_report_finds_the_stable_zero():
    for plant in (_detectable_plant(-1.5), _transformed(_detectable_plant(-1.5))[0]):
        rep = c.strong_detectability(plant)
        assert rep.ok and not rep.strongly_observable and rep.reason == ""
        np.testing.assert_allclose(rep.invariant_zeros, [-1.5], atol=1e-9)
        assert rep.unstable_zeros.size == 0 and rep.weakly_unobservable_dim == 1
        # the zero dynamics (Molinari + friend) and the staircase zeros are independent computations
        np.testing.assert_allclose(rep.zero_dynamics.zeros, rep.invariant_zeros, atol=1e-9)
    # on the untransformed plant V* = span(e4) and the strongly observable coordinates are x1, x2, x3
    zd = c.zero_dynamics(_detectable_plant(-1.5))
    np.testing.assert_allclose(np.abs(zd.T_w), [[0, 0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(zd.T_o @ zd.T_o.T, np.eye(3), atol=1e-12)


def test_unstable_zero_is_named_and_refused():
    plant = _detectable_plant(1.0)
    rep = c.strong_detectability(plant)
    assert not rep.ok
    np.testing.assert_allclose(rep.unstable_zeros, [1.0], atol=1e-9)
    assert "unstable invariant zeros at s = 1+0j" in rep.reason
    with pytest.raises(c.NotStronglyDetectableError, match=r"strongly detectable.*unstable invariant zeros at s = 1"):
        c.StronglyDetectableObserver(plant, 1e-3, 20.0)
    # a zero on the imaginary axis is not strongly detectable either
    assert not c.strong_detectability(_detectable_plant(0.0)).ok
    # the cascaded observer keeps refusing the stable-zero plant (not strongly observable)
    with pytest.raises(c.NotStronglyObservableError, match=r"invariant zeros at s = -1\.5"):
        c.CascadedHOSMObserver(_detectable_plant(-1.5), 1e-3, 20.0)


def test_not_left_invertible_is_not_strongly_detectable():
    P = _detectable_plant(-1.5)
    dup = c.LinearPlant(P.A, P.B, P.C, np.hstack([P.D, 2 * P.D]))
    rep = c.strong_detectability(dup)
    assert not rep.ok and "not left-invertible" in rep.reason and rep.zero_dynamics is None
    with pytest.raises(c.NotStronglyDetectableError, match="expected a left-invertible triple"):
        c.zero_dynamics(dup)
    with pytest.raises(c.NotStronglyDetectableError, match="expected a left-invertible triple"):
        c.functional_observability(dup, functional=np.eye(4)[:1])
    inv = c.left_inverse(dup)
    assert not inv.static and not inv.asymptotic and "D has rank 1 < m=2" in inv.reason


def test_detectable_observer_finite_time_exact_part_and_zero_rate():
    """Strongly observable coordinates exact after ~1 s; the V* coordinate decays as exp(-1.5 t).

    Run in random coordinates (x = T x'), where no block of the construction vanishes by accident."""
    plant, T = _transformed(_detectable_plant(-1.5))
    dt = 2e-3
    L = 3 * c.output_error_lipschitz(plant, 3, e_bound=1.0, w_bounds=(1.5, 2.0, 4.0, 8.0))
    obs = c.StronglyDetectableObserver(plant, dt, L, alpha=2)
    assert obs.theoretical_orders == {"strongly observable state": 3}
    res = c.simulate(plant, _OpenLoop(obs), t_final=4.0, w=_w, x0=np.linalg.solve(T, [0.3, -0.2, 0.1, 1.0]))
    zd = obs.zero_dynamics
    assert np.abs(zd.H).max() > 0.1  # the derivative of z enters the zero dynamics here
    err = res.x_hat - res.x
    e_obs = np.abs(err @ zd.T_o.T).max(axis=1)
    e_zero = np.abs(err @ zd.T_w.T).max(axis=1)
    t_conv = _settling_time(res.t, e_obs, 1e-4)
    assert t_conv < 1.2, t_conv  # measured 0.96 s
    # then exact up to O(tau^3) (measured 1.5e-6), while the error along the zero is still 0.1-0.01
    assert e_obs[res.t > 1.5].max() < 1e-5
    sel = (res.t > 1.0) & (res.t < 3.5)
    rate = np.polyfit(res.t[sel], np.log(e_zero[sel]), 1)[0]
    assert abs(rate - (-1.5)) < 0.03 * 1.5, rate  # the slowest (here the only) invariant zero; measured -1.49997
    # w is identified as the zero dynamics converge (w = -x4 on V*): its error follows them down
    ew = np.abs(res.w_hat - res.w)[:, 0]
    assert ew[res.t > 3.5].max() < 0.05 * ew[(res.t > 1.0) & (res.t < 1.2)].max()  # measured 0.0047 vs 0.17


def test_on_a_strongly_observable_plant_it_is_the_cascade():
    """No zeros: V* = {0}, the observer must reproduce CascadedHOSMObserver sample by sample (x_hat and w_hat)."""
    plant = c.furuta_slides()
    a = c.CascadedHOSMObserver(plant, 1e-3, 300.0)
    b = c.StronglyDetectableObserver(plant, 1e-3, 300.0)
    assert b.zero_dynamics.T_w.shape == (0, 4)
    ra = c.simulate(plant, c.StateFeedback(a, Q=np.diag([10.0, 1, 1, 1])), t_final=0.5, w=c.furuta_disturbance)
    rb = c.simulate(plant, c.StateFeedback(b, Q=np.diag([10.0, 1, 1, 1])), t_final=0.5, w=c.furuta_disturbance)
    np.testing.assert_allclose(rb.x_hat, ra.x_hat, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(rb.w_hat, ra.w_hat, rtol=1e-7, atol=1e-7)


def test_detectable_pair_gain_keeps_unobservable_modes():
    """(A, C) not observable but detectable: the gain places the observable modes only."""
    A = np.array([[0.0, 1, 0], [-1, -1, 0], [1, 0, -0.7]])
    C = np.array([[1.0, 0, 0]])
    dt = 1e-2
    Ld = c.detectable_observer_gain(A, C, dt, poles=[-5.0, -6.0])
    import scipy.linalg as sla

    ev = np.linalg.eigvals(sla.expm(A * dt) @ (np.eye(3) - Ld @ C))
    np.testing.assert_allclose(np.sort(np.log(ev.real) / dt), [-6.0, -5.0, -0.7], rtol=1e-6)
    with pytest.raises(ValueError, match="expected a detectable pair"):
        c.detectable_observer_gain(A * np.array([1, 1, -1.0]), C, dt)


# ---------------------------------------------------------------------------------------------------------------
# functional unknown-input observer
# ---------------------------------------------------------------------------------------------------------------
def test_functional_existence_is_e4_zero():
    plant = _functional_plant()
    assert not c.strong_detectability(plant).ok  # no observer of the whole state
    E = np.array([[1.0, 0, 0, 0, 1.0], [0, 1.0, 1.0, 0, 0]])
    for P, F in ((plant, E), (_transformed(plant)[0], E @ _transformed(plant)[1])):
        rep = c.functional_observability(P, functional=F)
        assert rep.ok, rep.reason
        assert rep.E4.shape == (2, 1) and np.abs(rep.E4).max() < 1e-12
        np.testing.assert_allclose(rep.unstable_zeros, [1.0], atol=1e-9)
    bad = c.functional_observability(plant, functional=[0, 0, 0, 1.0, 1.0])
    assert not bad.ok and "E4 != 0" in bad.reason and "s = 1+0j" in bad.reason
    np.testing.assert_allclose(np.abs(bad.E4), [[1.0]], atol=1e-12)
    with pytest.raises(c.NoFunctionalObserverError, match=r"E4 = 0.*E4 != 0"):
        c.FunctionalUnknownInputObserver(plant, [0, 0, 0, 1.0, 0], 1e-3, 20.0)


def test_functional_observer_converges_while_the_state_diverges():
    plant, T = _transformed(_functional_plant())
    E = np.array([[1.0, 0, 0, 0, 1.0], [0, 1.0, 1.0, 0, 0]]) @ T  # row 0 sees the stable zero, row 1 none
    dt = 1e-3
    L = 3 * c.output_error_lipschitz(plant, 2, e_bound=1.0, w_bounds=(1.5, 2.0, 4.0))
    obs = c.FunctionalUnknownInputObserver(plant, E, dt, L, poles=-np.arange(4.0, 9.0))
    ctl = _OpenLoop(obs)
    res = c.simulate(plant, ctl, t_final=4.0, w=_w, x0=np.linalg.solve(T, [0.3, -0.2, 0.1, 0.5, 1.0]))
    assert np.abs(obs.zero_dynamics.H).max() > 0.1
    err = np.abs(np.array(ctl.z) - res.x @ E.T)
    assert np.abs(res.x[-1] @ T.T).max() > 20.0  # x4 grows as exp(t): no observer of the whole state could follow
    assert _settling_time(res.t, err[:, 1], 1e-4) < 0.6  # strongly observable functional: finite time
    sel = (res.t > 1.0) & (res.t < 3.5)
    rate = np.polyfit(res.t[sel], np.log(err[sel, 0]), 1)[0]
    assert abs(rate - (-2.0)) < 0.05 * 2.0, rate  # the stable zero


# ---------------------------------------------------------------------------------------------------------------
# static left inverse
# ---------------------------------------------------------------------------------------------------------------
def _derivative_stack(plant, x, W, k):
    """[y; y'; ...; y^(k)] of the trajectory through x with w, w', ... = W."""
    A, C, D = plant.A, plant.C, plant.D
    Y = []
    for j in range(k + 1):
        yj = C @ np.linalg.matrix_power(A, j) @ x
        for i in range(j):
            yj = yj + C @ np.linalg.matrix_power(A, j - 1 - i) @ D @ W[i]
        Y.append(yj)
    return np.concatenate(Y)


def test_left_inverse_exists_without_strong_observability_or_detectability():
    plant = _left_inverse_plant()
    assert not c.strong_observability(plant).ok
    assert not c.strong_detectability(plant).ok
    rep = c.left_inverse(plant)
    assert rep.static and rep.asymptotic and rep.n_derivatives == 2
    np.testing.assert_allclose(rep.invariant_zeros, [0.5], atol=1e-9)
    np.testing.assert_allclose(rep.unobservable_eigenvalues, [0.5], atol=1e-9)
    assert rep.visible_zeros.size == 0
    # the defining property: w = G Y for every state and every input (and its derivatives)
    rng = np.random.default_rng(0)
    for P in (plant, _transformed(plant)[0], c.furuta_slides()):  # the last: strongly observable
        rep = c.left_inverse(P)
        assert rep.static
        for _ in range(5):
            x, W = rng.standard_normal(P.n), rng.standard_normal((rep.n_derivatives + 1, 1))
            Y = _derivative_stack(P, x, W, rep.n_derivatives)
            np.testing.assert_allclose(rep.G @ Y, W[0], atol=1e-9 * max(1.0, np.abs(rep.G).max() * np.abs(Y).max()))


def test_no_static_left_inverse_names_the_zero():
    rep = c.left_inverse(_detectable_plant(-1.5))  # the zero -1.5 is not an unobservable mode
    assert not rep.static and rep.asymptotic
    np.testing.assert_allclose(rep.visible_zeros, [-1.5], atol=1e-9)
    with pytest.raises(c.NoStaticLeftInverseError, match=r"zeros at s = -1.5\+0j are not unobservable modes"):
        c.LeftInverseIdentifier(_detectable_plant(-1.5), 1e-3, 20.0)
    unstable = c.left_inverse(_detectable_plant(1.0))
    assert not unstable.static and not unstable.asymptotic


# ---------------------------------------------------------------------------------------------------------------
# units decide no verdict
# ---------------------------------------------------------------------------------------------------------------
UNIT_SCALINGS = [
    (1e-10, 1.0, 1.0),
    (1e10, 1.0, 1.0),
    (1.0, 1e-10, 1.0),
    (1.0, 1e10, 1.0),
    (1.0, 1.0, 1e-10),
    (1.0, 1.0, 1e10),
    (1e-10, 1e-10, 1e-10),
    (1e10, 1e10, 1e10),
]


def _detection_verdicts(A, C, D):
    det, inv = c.strong_detectability(A, C, D), c.left_inverse(A, C, D)
    zd = det.zero_dynamics
    return (
        det.ok,
        det.strongly_observable,
        det.invariant_zeros.size,
        det.unstable_zeros.size,
        det.weakly_unobservable_dim,
        None if zd is None else (zd.T_o.shape[0], zd.n_unstable),
        inv.static,
        inv.asymptotic,
        inv.n_derivatives,
        inv.visible_zeros.size,
    )


@pytest.mark.parametrize(
    "plant",
    [_detectable_plant(-1.5), _detectable_plant(1.0), _functional_plant(), _left_inverse_plant(), c.furuta_slides()],
    ids=["stable zero", "unstable zero", "two zeros", "unobservable zero", "furuta"],
)
def test_detectability_and_left_inverse_do_not_depend_on_units(plant):
    """A -> a A, C -> c C, D -> d D (time, output and input units) change no verdict and no number of
    derivatives; the static left inverse still reads w from the scaled system's output derivatives."""
    ref = _detection_verdicts(plant.A, plant.C, plant.D)
    rng = np.random.default_rng(1)
    for a, cc, d in UNIT_SCALINGS:
        P = c.LinearPlant(a * plant.A, plant.B, cc * plant.C, d * plant.D)
        assert _detection_verdicts(P.A, P.C, P.D) == ref, (a, cc, d)
        rep = c.left_inverse(P)
        if rep.static:
            x, W = rng.standard_normal(P.n), rng.standard_normal((rep.n_derivatives + 1, 1))
            Y = _derivative_stack(P, x, W, rep.n_derivatives)
            np.testing.assert_allclose(rep.G @ Y, W[0], atol=1e-9 * (np.abs(rep.G) @ np.abs(Y)).max())


def test_detectable_observer_orders_do_not_depend_on_units():
    """A -> a A (step and poles in the same time unit), C -> c C, D -> d D: the order of the strongly observable
    coordinates stays alpha + 1. Its map weighs y^(k), whose size grows as ||A||^k, and was judged by its raw
    entries: for a = 1e10 it read 4, as if y'' were not needed."""
    plant = _transformed(_detectable_plant(-1.5))[0]
    for a, cc, d in [(1e-10, 1, 1), (1e10, 1, 1), (1, 1e-10, 1e10), (1e10, 1e10, 1e-10), (1e-10, 1e-10, 1e-10)]:
        P = c.LinearPlant(a * plant.A, plant.B, cc * plant.C, d * plant.D)
        obs = c.StronglyDetectableObserver(P, 2e-3 / a, 10.0, alpha=2, poles=-a * np.linspace(10.0, 12.0, 4))
        assert obs.theoretical_orders == {"strongly observable state": 3}, (a, cc, d)


@pytest.mark.parametrize("alpha, lipschitz", [(1, 30.0), (2, 60.0)])
def test_left_inverse_identification_order_in_the_sampling_step(alpha, lipschitz):
    steps, errs = [1e-3, 2e-3, 4e-3], []
    for dt in steps:
        t, e, idf = _identification_error(dt, alpha, lipschitz)
        errs.append(e[t > 1.0].max())
    assert idf.theoretical_orders["sampling"] == alpha
    assert abs(c.fit_order(steps, errs) - alpha) <= 0.2  # measured 0.99 and 1.99
    if alpha == 2:
        t, e, _ = _identification_error(1e-3, 2, 60.0)
        assert errs[0] < 5e-4 and _settling_time(t, e, 1e-3) < 1.0  # exact up to O(tau^2) after ~0.5 s


def test_left_inverse_identification_order_in_the_noise():
    """Bounded noise eta: error O(eta^(alpha/(K+1))) = O(eta^(1/2)) for alpha = 2, K = 3 (Levant 2003)."""
    etas, errs = [1e-5, 1e-4, 1e-3], []
    for eta in etas:
        t, e, idf = _identification_error(1e-3, 2, 60.0, noise=eta)
        errs.append(e[t > 1.0].max())
    assert idf.theoretical_orders["noise"] == 0.5
    assert abs(c.fit_order(etas, errs) - 0.5) <= 0.1, errs  # measured 0.51


# ---------------------------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------------------------
def test_bad_input_is_typed_and_says_what_was_expected():
    P = _detectable_plant(-1.5)
    with pytest.raises(ValueError, match=r"expected functional with shape \(\*x4\)"):
        c.functional_observability(P, functional=np.ones((1, 3)))
    with pytest.raises(ValueError, match=r"expected functional with shape"):
        c.FunctionalUnknownInputObserver(P, np.ones((2, 5)), 1e-3, 20.0)
    with pytest.raises(TypeError, match="expected plant to be a LinearPlant"):
        c.StronglyDetectableObserver(P.A, 1e-3, 20.0)
    with pytest.raises(ValueError, match="expected dt > 0"):
        c.StronglyDetectableObserver(P, -1e-3, 20.0)
    with pytest.raises(ValueError, match="expected a square A"):
        c.strong_detectability(np.ones((2, 3)), np.ones((1, 3)), np.ones((2, 1)))
    with pytest.raises(
        TypeError, match=r"expected strong_detectability\(plant\) with a LinearPlant or strong_detectability\(A, C, D\)"
    ):
        c.strong_detectability(P.A)
    L = _left_inverse_plant()
    with pytest.raises(ValueError, match="expected lipschitz > 0"):
        c.LeftInverseIdentifier(L, 1e-3, [1.0, -1.0])
    with pytest.raises(ValueError, match="expected dt > 0"):
        c.LeftInverseIdentifier(L, 0.0, 1.0)
    with pytest.raises(ValueError, match="alpha"):
        c.LeftInverseIdentifier(L, 1e-3, 1.0, alpha=0)
    with pytest.raises(RuntimeError, match="expected reset"):
        c.LeftInverseIdentifier(L, 1e-3, 1.0).update([0.0, 0.0])
    with pytest.raises(RuntimeError, match="expected reset"):
        c.StronglyDetectableObserver(P, 1e-3, 20.0).update([0.0, 0.0])


def test_numbers_are_not_read_from_bools_strings_or_overflowing_integers():
    L = _left_inverse_plant()
    for lipschitz in (True, "2"):
        with pytest.raises(TypeError, match="expected lipschitz to be a real number"):
            c.LeftInverseIdentifier(L, 1e-3, lipschitz)
    with pytest.raises(ValueError, match="expected lipschitz > 0"):
        c.LeftInverseIdentifier(L, 1e-3, 10**400)
    with pytest.raises(ValueError, match=r"expected lipschitz a number or shape \(2,\)"):
        c.LeftInverseIdentifier(L, 1e-3, [1.0, 2.0, 3.0])
    li = c.LeftInverseIdentifier(L, 1e-3, 20.0)
    for y in (["1", "1"], [True, True]):
        with pytest.raises(TypeError, match="expected y0 to be an array of real numbers"):
            li.reset(y)
    li.reset([0.0, 0.0])
    with pytest.raises(TypeError, match="expected y to be an array of real numbers"):
        li.update(["1", "1"])
    with pytest.raises(TypeError, match="expected A to be an array of real numbers"):
        c.detectable_observer_gain([[True]], [[1.0]], 0.01)
    with pytest.raises(ValueError, match="expected finite entries in A"):
        c.detectable_observer_gain([[np.nan]], [[1.0]], 0.01)
    with pytest.raises(ValueError, match=r"expected C with shape \(\*x2\)"):
        c.detectable_observer_gain(-np.eye(2), [[1.0, 0.0, 0.0]], 0.01)
    for A, error in (
        ([[True, True], [False, False]], TypeError),
        ([["0", "1"], [0, 0]], TypeError),
        ([[np.nan, 1], [0, 0]], ValueError),
    ):
        with pytest.raises(error, match="A"):
            c.relative_degrees(A, [[1, 0]], [[0], [1]])


def test_a_double_zero_at_the_boundary_is_counted_unstable_at_every_scale():
    """A double invariant zero at 0 is computed as a pair at +-3e-8 j: scipy's sorted Schur form refused to reorder
    it (LinAlgError) for D x 1e8. Refused with its reason at every scale now (how rounding splits the defective pair,
    +-1e-8 j or +-1e-8, decides whether both halves count as unstable; the zero at 2 always does)."""
    A = np.array(
        [
            [
                -0.45785877136317954,
                1.3520018949589756,
                0.91935823089590429,
                0.38803811818992762,
                1.9542119194812797,
                -0.97129192360952132,
            ],
            [
                1.2387018478751368,
                0.3569965669241027,
                -1.1080889560509501,
                -0.061419363621461449,
                -1.078921097164115,
                1.1330104621813335,
            ],
            [
                -0.40337440888368348,
                -0.17905867219378482,
                0.86970749433256556,
                2.0481381294957077,
                0.65532742754723539,
                -2.9656527818307961,
            ],
            [
                -2.2042337330546422,
                -2.603136738645861,
                0.41329598435588805,
                -1.0985793626448774,
                2.3435041067331772,
                -1.0880695662549924,
            ],
            [
                0.15577580949381073,
                -0.91522638349376184,
                1.9621102070777372,
                1.460051710940748,
                0.57428387159685024,
                1.7675996809067569,
            ],
            [
                -0.96803234539149385,
                2.0120593452671272,
                2.1313456587638675,
                0.61691159634888404,
                1.4312879379877672,
                -1.2445497988454632,
            ],
        ]
    )
    C = np.array(
        [
            [
                -2.7019523884645307,
                -2.2734071246161132,
                -0.16876205577611181,
                1.9977907275948168,
                1.151882804615427,
                -1.0883891390092102,
            ]
        ]
    )
    D = np.array(
        [
            [0.10217321442550209],
            [-1.3241807957421705],
            [1.1786756814029382],
            [0.5728588968999091],
            [-1.4433153363450562],
            [1.8535109971685328],
        ]
    )
    for d in (1.0, 1e8, 1e-8):
        report = c.strong_detectability(A, C, d * D)
        assert not report.ok and np.isclose(report.unstable_zeros, 2.0).sum() == 1
