"""Tests of the conventional sliding-mode observers and the unknown-input observer (Fridman's slides, section 1).

Each test measures the defining property: finite-time sliding with the reaching time bounded by the gain, the
reduced error dynamics at the designed rate, the equivalent injection's reconstruction up to the filter lag,
step-by-step finite-time convergence, the Walcott-Zak LMI certificate recomputed in NumPy and convergence despite a
matched unknown input, the existence conditions (holding and failing, by name), and the rejection of an arbitrary
unknown input without differentiation. The plants are simulated exactly (zero-order hold of ``u`` and ``w``).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_script

from smo_gym import DivergenceError
from smo_gym import control as c
from smo_gym.design import LMIInfeasibleError

# companion form with eigenvalues -1, -2, -3, one output
A3 = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-6.0, -11.0, -6.0]])
B3 = np.array([[0.0], [0.0], [1.0]])
C3 = np.array([[1.0, 0.0, 0.0]])
# two outputs, one matched unknown input with CD != 0, no invariant zeros
AW = np.array([[0.0, 1.0, 0.0], [-2.0, -1.0, 1.0], [1.0, 0.0, -3.0]])
BW = np.array([[0.0], [1.0], [1.0]])
CW = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
DW = np.array([[0.0], [1.0], [1.0]])


# the zero-order-hold simulation and the MuJoCo demonstration are the reproduction script's
examples = load_script("reproduce_slides_conventional")
simulate = examples.simulate


def sin_input(t):
    return np.sin(t)[:, None]


# ---------------------------------------------------------------------------------------------------------------
# Utkin's observer
# ---------------------------------------------------------------------------------------------------------------
def test_output_coordinate_change_puts_the_outputs_last():
    rng = np.random.default_rng(1)
    C = rng.standard_normal((2, 5))
    T = c.output_coordinate_change(C)
    np.testing.assert_allclose(C @ np.linalg.inv(T), np.hstack([np.zeros((2, 3)), np.eye(2)]), atol=1e-12)
    with pytest.raises(ValueError, match="full row rank"):
        c.output_coordinate_change(np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0]]))


def _utkin_reaching(gain, dt=2e-4, e_y0=1.0, e_10=0.2, t_final=0.3):
    """Second-order plant, one output: the reaching time, the bound delta on |A21 e1 + A22 e_y| before it."""
    A = np.array([[0.0, 1.0], [-1.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    obs = c.UtkinObserver(A, B, C, dt, gain=gain, poles=[-3.0])
    x0 = np.array([1.0, 0.5])
    x_hat0 = x0 + obs.T_inv @ np.array([e_10, e_y0])
    t, X, U, _ = simulate(A, B, x0, t_final, dt, u=sin_input)
    Xh = obs.run(X @ C.T, U, x_hat0=x_hat0)
    sliding = obs.history["sliding"][:, 0]
    k = int(np.nonzero(~sliding)[0][-1]) + 1  # slides from sample k on, for good
    e = (Xh - X) @ obs.T.T
    drift = np.abs(e[:k, :1] @ obs.A21.T + e[:k, 1:] @ obs.A22.T).max()
    return t[k], drift, obs, e, t


def test_utkin_reaching_time_is_finite_and_scales_like_one_over_the_gain():
    """Slides: the output error reaches e_y = 0 in finite time,
    |e_y0| / (rho + delta) <= t_r <= |e_y0| / (rho - delta), delta >= |A21 e1 + A22 e_y| before sliding."""
    gains = np.array([5.0, 10.0, 20.0, 40.0, 80.0])
    times, dt = [], 2e-4
    for rho in gains:
        t_r, delta, _, e, t = _utkin_reaching(rho, dt)
        assert delta < rho
        assert 1.0 / (rho + delta) - dt <= t_r <= 1.0 / (rho - delta) + 2 * dt, (rho, t_r, delta)
        assert np.abs(e[t >= t_r, 1]).max() < 1e-12  # and stays on e_y = 0 (implicit: exactly)
        times.append(t_r)
    slope = np.polyfit(np.log(gains), np.log(times), 1)[0]
    assert -1.1 <= slope <= -0.9, slope


def test_utkin_sliding_dynamics_decay_at_the_designed_rate():
    """Slides: on e_y = 0 the error obeys e1' = (A11 + L A21) e1 (here designed at -3)."""
    t_r, _, obs, e, t = _utkin_reaching(16.0, dt=1e-3, t_final=0.6)
    np.testing.assert_allclose(obs.reduced_eigenvalues, [-3.0])
    sel = (t > t_r + 0.05) & (t < 0.6)
    rate = np.polyfit(t[sel], np.log(np.abs(e[sel, 0])), 1)[0]
    assert abs(rate - (-3.0)) < 0.03, rate


def test_utkin_equivalent_injection_reconstructs_the_unmeasured_state_up_to_the_filter_lag():
    """nu_eq = A21 e1 gives z1 = z1_hat - A21^+ nu_f; for e1 ~ exp(lambda t) the filter's relative lag is
    |lambda| tau / (1 - |lambda| tau)."""
    dt, tau, lam = 1e-3, 0.02, -3.0
    A = np.array([[0.0, 1.0], [-1.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    obs = c.UtkinObserver(A, B, C, dt, gain=10.0, poles=[lam], tau=tau)
    t, X, U, _ = simulate(A, B, [1.0, 0.5], 1.0, dt, u=sin_input)
    Xh = obs.run(X @ C.T, U, x_hat0=[0.0, 0.0])
    sel = t > 0.4
    plain = np.abs(Xh - X)[sel, 1]
    rec = np.abs(obs.history["x_reconstructed"] - X)[sel, 1]
    ratio = np.median(rec / plain)
    theory = abs(lam) * tau / (1 - abs(lam) * tau)
    assert abs(ratio / theory - 1.0) < 0.2, (ratio, theory)


def test_utkin_explicit_sign_needs_the_filter_and_keeps_its_ripple():
    """Explicit sign: nu chatters between +-rho, the filter's output stays within its lag plus the ripple of a
    square wave of amplitude rho switching every one or two samples, at most 2 rho dt / tau."""
    dt, tau, lam, rho = 1e-4, 0.02, -3.0, 10.0
    A = np.array([[0.0, 1.0], [-1.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    obs = c.UtkinObserver(A, B, C, dt, gain=rho, poles=[lam], tau=tau, discretization="euler")
    t, X, U, _ = simulate(A, B, [1.0, 0.5], 0.7, dt, u=sin_input)
    Xh = obs.run(X @ C.T, U, x_hat0=[0.0, 0.0])
    sel = t > 0.4
    assert np.all(np.abs(obs.history["nu"][sel]) == rho)  # the raw injection is useless as it stands
    plain = np.abs(Xh - X)[sel, 1]
    rec = np.abs(obs.history["x_reconstructed"] - X)[sel, 1]
    lag = abs(lam) * tau / (1 - abs(lam) * tau)
    assert np.all(rec <= lag * plain * 1.2 + 2 * rho * dt / tau), np.max(rec - lag * plain)
    assert np.median(rec / plain) < 0.15


def test_utkin_observer_is_batched():
    A = np.array([[0.0, 1.0], [-1.0, -0.5]])
    C = np.array([[1.0, 0.0]])
    obs = c.UtkinObserver(A, None, C, 1e-3, gain=[5.0])
    x0 = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]])
    ys = []
    for x in x0:
        _, X, _, _ = simulate(A, np.zeros((2, 1)), x, 0.2, 1e-3)
        ys.append(X @ C.T)
    batch = obs.run(np.stack(ys, axis=1), x_hat0=np.zeros(2))
    assert batch.shape == (201, 3, 2)
    single = obs.run(ys[1], x_hat0=np.zeros(2))
    np.testing.assert_allclose(batch[:, 1], single, atol=1e-14)


@pytest.mark.parametrize("kind", ["step_by_step", "walcott_zak", "uio"])
def test_observers_are_batched(kind, wz_design):
    """A batch of trajectories gives, entry by entry, the single-trajectory estimates."""
    dt = 1e-3
    make = {
        "step_by_step": lambda: c.StepByStepObserver(AW, BW, CW, dt, gain=[8.0]),
        "walcott_zak": lambda: c.WalcottZakObserver(AW, BW, CW, DW, dt, 1.0, design=wz_design),
        "uio": lambda: c.UnknownInputObserver(AW, BW, CW, DW, dt, decay=3.0),
    }[kind]
    ys, us = [], []
    for i, x0 in enumerate(([1.0, 0.0, 0.0], [0.0, 1.0, -1.0], [0.5, 0.5, 0.5])):
        t, X, U, _ = simulate(AW, BW, x0, 0.3, dt, u=lambda t, i=i: np.sin(t + i)[:, None], D=DW, w=_arbitrary_w)
        ys.append(X @ CW.T)
        us.append(U)
    obs = make()
    batch = obs.run(np.stack(ys, axis=1), np.stack(us, axis=1), x_hat0=np.zeros(3))
    assert batch.shape == (t.size, 3, 3)
    single = make().run(ys[2], us[2], x_hat0=np.zeros(3))
    np.testing.assert_allclose(batch[:, 2], single, atol=1e-12)


def test_utkin_bad_input():
    A = np.array([[0.0, 1.0], [-1.0, -0.5]])
    C = np.array([[1.0, 0.0]])
    with pytest.raises(ValueError, match="expected gain > 0"):
        c.UtkinObserver(A, None, C, 1e-3, gain=-1.0)
    with pytest.raises(TypeError, match="real numbers"):
        c.UtkinObserver(A, None, C, 1e-3, gain=True)
    with pytest.raises(ValueError, match="expected dt > 0"):
        c.UtkinObserver(A, None, C, 0.0, gain=1.0)
    with pytest.raises(ValueError, match="expected tau > 0"):
        c.UtkinObserver(A, None, C, 1e-3, gain=1.0, tau=0.0)
    with pytest.raises(ValueError, match=r"expected L with shape \(1x1\)"):
        c.UtkinObserver(A, None, C, 1e-3, gain=1.0, L=np.ones((2, 1)))
    with pytest.raises(ValueError, match="Hurwitz"):
        c.UtkinObserver(A, None, C, 1e-3, gain=1.0, L=[[10.0]])
    with pytest.raises(ValueError, match="shape"):
        c.UtkinObserver(A, None, np.ones((1, 3)), 1e-3, gain=1.0)
    with pytest.raises(ValueError, match="discretization"):
        c.UtkinObserver(A, None, C, 1e-3, gain=1.0, discretization="implict")
    obs = c.UtkinObserver(A, None, C, 1e-3, gain=1.0)
    with pytest.raises(RuntimeError, match="reset"):
        obs.update([0.0])
    obs.reset([0.0])
    with pytest.raises(ValueError, match=r"expected y of shape \(\.\.\., 1\), actual value: shape \(2,\)"):
        obs.update([0.0, 1.0])


def test_utkin_divergence_is_refused_and_the_state_kept():
    """An unstable plant sampled every 20 s: the prediction overflows at the sixth step; refused, state kept."""
    a, b = (c.UtkinObserver([[0.0, 1.0], [50.0, 0.0]], None, [[1.0, 0.0]], 20.0, 5.0) for _ in range(2))
    for obs in (a, b):
        obs.reset([1.0])
        for _ in range(5):
            obs.advance()
            obs.update([1.0])
    with pytest.raises(DivergenceError, match=r"expected a finite state.*actual value.*the state was kept"):
        a.advance()
    np.testing.assert_array_equal(a.x_hat, b.x_hat)
    np.testing.assert_array_equal(a.z_hat, b.z_hat)
    np.testing.assert_array_equal(a.update([0.5]), b.update([0.5]))
    np.testing.assert_array_equal(a.nu_filtered, b.nu_filtered)


def test_run_refuses_an_empty_record():
    obs = c.UtkinObserver([[0.0, 1.0], [-1.0, -0.5]], None, [[1.0, 0.0]], 1e-3, 1.0)
    with pytest.raises(ValueError, match=r"expected y with at least one sample.*actual value: shape \(0, 1\)"):
        obs.run(np.zeros((0, 1)))


# ---------------------------------------------------------------------------------------------------------------
# Drakunov's step-by-step observer
# ---------------------------------------------------------------------------------------------------------------
def test_observable_block_form_has_the_staircase_structure():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((5, 5))
    C = rng.standard_normal((2, 5))
    B = rng.standard_normal((5, 1))
    f = c.observable_block_form(A, B, C)
    assert f.sizes == (2, 2, 1)
    np.testing.assert_allclose(f.T @ f.T.T, np.eye(5), atol=1e-12)
    np.testing.assert_allclose(f.A, f.T @ A @ f.T.T, atol=1e-12)
    np.testing.assert_allclose(C @ f.T.T, np.hstack([f.C1, np.zeros((2, 3))]), atol=1e-12)
    b = f.blocks()
    for i in range(len(b)):
        for j in range(i + 2, len(b)):
            assert np.abs(f.A[b[i], b[j]]).max() < 1e-12  # nothing above the block super-diagonal
        if i + 1 < len(b):
            assert np.linalg.matrix_rank(f.A[b[i], b[i + 1]]) == f.sizes[i + 1]  # full column rank
    # an unobservable pair is refused, the condition named
    A_unobs = np.diag([-1.0, -2.0, -3.0])
    with pytest.raises(c.UnknownInputConditionError, match="observable") as err:
        c.observable_block_form(A_unobs, None, [[1.0, 1.0, 0.0]])
    assert err.value.condition == "observability"


def _step_by_step(dt, discretization="implicit", t_final=2.0):
    obs = c.StepByStepObserver(A3, B3, C3, dt, gain=[4.0, 12.0], discretization=discretization)
    t, X, U, _ = simulate(A3, B3, [1.0, 0.5, -0.3], t_final, dt, u=sin_input)
    obs.run(X @ C3.T, U, x_hat0=[0.5, -0.5, 1.0])
    xi = X @ obs.form.T.T
    return obs, t, xi, obs.history


def test_step_by_step_converges_block_by_block_in_finite_time():
    """Block i+1 is exact from the moment step i slides, and step i+1 slides only after step i."""
    dt = 1e-3
    obs, t, xi, h = _step_by_step(dt)
    err = np.abs(h["xi_hat"] - xi)
    times = []
    for i in range(obs.n_steps):
        k = int(np.nonzero(~h["sliding"][:, i])[0][-1]) + 1
        times.append(t[k])
        nxt = obs.form.blocks()[i + 1]
        # from the sample after the first sliding one (whose equivalent value still holds the reaching prior):
        assert err[k + 1 :, nxt].max() < 5 * dt  # exact up to the O(dt) of the sampled equivalent value
        assert err[:k, nxt].max() > 0.1  # and not before
        # reaching bound of step i from where it started: |s_i| / (M_i - sup |A_{i,i+1} xi_{i+1}|)
        start = 0 if i == 0 else int(round(times[i - 1] / dt))
        blk = obs.form.blocks()[i]
        sup = np.abs(xi[:, nxt] @ obs.form.A[blk, nxt].T).max()
        s0 = np.abs(h["s"][start + 1, blk]).max()
        assert t[k] - t[start] <= s0 / (obs.gain[i] - sup) + 3 * dt, (i, t[k], s0, sup)
    assert 0.0 < times[0] < times[1] < 1.0, times


def test_step_by_step_on_a_mimo_block_form_with_full_blocks():
    """Two outputs, blocks (2, 2, 1), every block of the Hessenberg form filled: exact to O(dt) after both steps."""
    rng = np.random.default_rng(7)
    A = rng.standard_normal((5, 5))
    A -= (np.linalg.eigvals(A).real.max() + 1.0) * np.eye(5)  # stable, so the gains can bound the trajectory
    B = rng.standard_normal((5, 1))
    C = rng.standard_normal((2, 5))
    errs = []
    for dt in (1e-3, 2e-3):
        obs = c.StepByStepObserver(A, B, C, dt, gain=[6.0, 25.0])
        f = obs.form
        assert f.sizes == (2, 2, 1) and all(np.abs(f.A[b, b]).max() > 0.1 for b in f.blocks())
        t, X, U, _ = simulate(A, B, [1.0, -0.5, 0.3, 0.2, -0.4], 2.0, dt, u=sin_input)
        obs.run(X @ C.T, U, x_hat0=np.zeros(5))
        assert obs.history["sliding"][t > 1.0].all()
        errs.append(np.abs(obs.history["xi_hat"] - X @ f.T.T)[t > 1.0].max())
    assert errs[0] < 0.02 and 1.6 < errs[1] / errs[0] < 2.4, errs


def test_step_by_step_noise_free_error_is_first_order_in_the_step():
    steps = [1e-3, 2e-3, 4e-3]
    errs = []
    for dt in steps:
        _, t, xi, h = _step_by_step(dt)
        errs.append(np.abs(h["xi_hat"] - xi)[t > 1.0].max())
    slope = c.fit_order(steps, errs)
    assert abs(slope - 1.0) < 0.15, (slope, errs)


def test_step_by_step_noise_response_grows_like_one_over_dt_to_the_block_index():
    """In sliding mode every injection is a backward difference: a measurement noise eta reaches block i + 1 as
    eta / dt^i. While no step saturates the observer is linear, so the noisy minus the noise-free estimate is the
    noise response alone."""
    eta, steps = 1e-5, [2e-3, 4e-3, 8e-3]
    rms = []
    for dt in steps:
        noise = eta * np.random.default_rng(0).uniform(-1.0, 1.0, size=(int(round(3.0 / dt)) + 1, 1))
        obs = c.StepByStepObserver(A3, B3, C3, dt, gain=[4.0, 12.0])
        t, X, U, _ = simulate(A3, B3, [1.0, 0.5, -0.3], 3.0, dt, u=sin_input)
        clean = obs.run(X @ C3.T, U, x_hat0=[0.5, -0.5, 1.0]) @ obs.form.T.T
        noisy = obs.run(X @ C3.T + noise, U, x_hat0=[0.5, -0.5, 1.0]) @ obs.form.T.T
        assert obs.history["sliding"][t > 1.5].all()
        d = (noisy - clean)[t > 1.5]
        rms.append(np.sqrt(np.mean(d**2, axis=0)))
    rms = np.array(rms)
    for block, exponent in ((1, -1.0), (2, -2.0)):
        assert abs(c.fit_order(steps, rms[:, block]) - exponent) < 0.15, (block, rms[:, block])


def test_step_by_step_textbook_discretization_with_low_pass_filters_has_the_filter_ripple():
    """Explicit sign and low-pass filtered injections: the next block inherits the filter's ripple, about
    M_1 dt / tau for a sign switching every sample, and the last block worse; the implicit form has none."""
    dt = 1e-3
    _, t, xi, h = _step_by_step(dt)
    implicit = np.abs(h["xi_hat"] - xi)[t > 1.0].max()
    for tau in (10 * dt, 40 * dt):
        obs = c.StepByStepObserver(A3, B3, C3, dt, gain=[4.0, 12.0], discretization="euler", tau=tau)
        t, X, U, _ = simulate(A3, B3, [1.0, 0.5, -0.3], 2.0, dt, u=sin_input)
        obs.run(X @ C3.T, U, x_hat0=[0.5, -0.5, 1.0])
        err = np.abs(obs.history["xi_hat"] - X @ obs.form.T.T)[t > 1.0]
        ripple = err[:, obs.form.blocks()[1]].max() / (obs.gain[0] * dt / tau)
        assert 0.8 < ripple < 1.6, (tau, ripple)
        assert err.max() > 10 * implicit


def test_step_by_step_bad_input():
    with pytest.raises(ValueError, match="one per step"):
        c.StepByStepObserver(A3, B3, C3, 1e-3, gain=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="gain > 0"):
        c.StepByStepObserver(A3, B3, C3, 1e-3, gain=[1.0, 0.0])
    with pytest.raises(ValueError, match="expected tau > 0"):
        c.StepByStepObserver(A3, B3, C3, 1e-3, gain=1.0, tau=-1.0)


# ---------------------------------------------------------------------------------------------------------------
# existence conditions
# ---------------------------------------------------------------------------------------------------------------
def _relative_degree_one(zeros):
    """Companion-form plant with y = C x of relative degree one w.r.t. w = the last state's input, given zeros."""
    num = np.poly(zeros)  # s^2 + a1 s + a0
    C = np.array([[num[2], num[1], num[0]]])
    D = np.array([[0.0], [0.0], [1.0]])
    return A3, B3, C, D


def test_unknown_input_conditions_hold_and_fail_by_name():
    rep = c.unknown_input_conditions(AW, CW, DW)
    assert rep.ok and rep.failing == () and rep.rank_CD == rep.rank_D == 1 and rep.strongly_observable
    # the zeros -1, -2: minimum phase, not strongly observable
    A, _, C, D = _relative_degree_one([-1.0, -2.0])
    rep = c.unknown_input_conditions(A, C, D)
    assert rep.ok and not rep.strongly_observable
    np.testing.assert_allclose(np.sort(rep.invariant_zeros.real), [-2.0, -1.0], atol=1e-8)
    # a zero at +1: not minimum phase
    A, _, C, D = _relative_degree_one([1.0, -2.0])
    rep = c.unknown_input_conditions(A, C, D)
    assert not rep.ok and rep.failing == ("minimum phase",) and "s = 1" in rep.reason
    with pytest.raises(c.UnknownInputConditionError, match="minimum phase") as err:
        c.UnknownInputObserver(A, B3, C, D, 1e-3)
    assert err.value.condition == "minimum phase"
    # relative degree two: CD = 0
    rep = c.unknown_input_conditions(A3, C3, B3)
    assert rep.failing == ("rank(CD) = rank(D)",) and rep.rank_CD == 0
    with pytest.raises(c.UnknownInputConditionError, match=r"rank\(CD\) = rank\(D\)") as err:
        c.WalcottZakObserver(A3, B3, C3, B3, 1e-3, rho=1.0)
    assert err.value.condition == "rank(CD) = rank(D)"
    # dependent unknown inputs
    rep = c.unknown_input_conditions(AW, CW, np.hstack([DW, 2 * DW]))
    assert rep.failing[0] == "rank(D) = m"


UNIT_SCALINGS = [(1e-10, 1.0, 1.0), (1e10, 1.0, 1.0), (1.0, 1e-10, 1.0), (1.0, 1e10, 1.0), (1.0, 1.0, 1e-10)]
UNIT_SCALINGS += [(1.0, 1.0, 1e10), (1e-10, 1e-10, 1e-10), (1e10, 1e10, 1e10), (1e10, 1e-10, 1e10)]


def test_unknown_input_conditions_and_block_form_do_not_depend_on_units():
    """A -> a A, C -> c C, D -> d D (time, output and input units) change no rank and no verdict, and a
    ``C D`` that vanishes exactly (rounding errors after an orthogonal change of coordinates) has rank 0."""
    T = np.linalg.qr(np.random.default_rng(4).standard_normal((3, 3)))[0]
    rotated = (T @ A3 @ T.T, C3 @ T.T, T @ B3)  # C D = 0 in exact arithmetic: relative degree 3
    assert 0.0 < np.abs(rotated[1] @ rotated[2]).max() < 1e-15
    systems = [(AW, CW, DW), (A3, C3, B3), rotated, (AW, CW, np.hstack([DW, 2 * DW]))]
    systems += [(A, C, D) for A, _, C, D in (_relative_degree_one([-1.0, -2.0]), _relative_degree_one([1.0, -2.0]))]
    for A, C, D in systems:

        def verdicts(A, C, D):
            rep = c.unknown_input_conditions(A, C, D)
            return rep.ok, rep.failing, rep.rank_D, rep.rank_CD, rep.invariant_zeros.size, rep.strongly_observable

        def block_sizes(A, C):
            try:
                return c.observable_block_form(A, None, C).sizes
            except c.UnknownInputConditionError as err:  # (A3, [2, 3, 1]): the zeros -1, -2 cancel two poles
                return err.condition

        ref, sizes = verdicts(A, C, D), block_sizes(A, C)
        for a, cc, d in UNIT_SCALINGS:
            assert verdicts(a * A, cc * C, d * D) == ref, (a, cc, d)
            assert block_sizes(a * A, cc * C) == sizes, (a, cc)
            T_c = c.output_coordinate_change(cc * C)  # C of full row rank whatever its units
            np.testing.assert_array_equal(T_c[A.shape[0] - C.shape[0] :], cc * C)
    assert c.unknown_input_conditions(*rotated).rank_CD == 0
    # Utkin's observer reconstructs x from the equivalent injection whatever the units (A21 = C A N_c != 0)
    A, B, C = np.array([[0.0, 1.0], [-1.0, -0.5]]), np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]])
    for a, cc, _ in UNIT_SCALINGS:
        obs = c.UtkinObserver(a * A, B, cc * C, 1e-3 / a, gain=10.0 * a * cc, poles=[-3.0 * a])
        obs.reset(np.zeros(1))
        assert obs.x_reconstructed is not None, (a, cc)


# ---------------------------------------------------------------------------------------------------------------
# Walcott-Zak observer
# ---------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def wz_design():
    pytest.importorskip("cvxpy")
    return c.walcott_zak_design(AW, CW, DW, decay=3.0)


def test_walcott_zak_lmi_certificate_holds_in_numpy(wz_design):
    d = wz_design
    P, G, F = d.P, d.G, d.F
    Acl = AW - G @ CW
    lyap = Acl.T @ P + P @ Acl + 2 * 3.0 * P
    assert np.linalg.eigvalsh(P).min() > 0
    assert np.linalg.eigvalsh(lyap).max() < 0
    assert np.linalg.norm(DW.T @ P - F @ CW) <= 1e-8 * np.linalg.norm(DW.T @ P)
    assert np.linalg.eigvals(Acl).real.max() < -3.0  # the decay rate that the certificate guarantees
    assert d.max_eig_lyapunov == pytest.approx(np.linalg.eigvalsh(lyap).max())
    # a gain that does not stabilize fails the re-verification
    with pytest.raises(LMIInfeasibleError, match="re-verification"):
        c.certify_walcott_zak(AW, CW, DW, P, np.zeros_like(G))


def _wz_run(design, dt, rho, discretization="implicit", t_final=4.0):
    def w(t):
        return (0.8 * np.sin(3 * t) + 0.1)[:, None]

    obs = c.WalcottZakObserver(AW, BW, CW, DW, dt, rho, design=design, tau=0.01, discretization=discretization)
    t, X, U, W = simulate(AW, BW, [1.0, 0.5, -0.3], t_final, dt, u=sin_input, D=DW, w=w)
    Xh = obs.run(X @ CW.T, U, x_hat0=np.zeros(3))
    return t, np.abs(Xh - X).max(axis=1), np.abs(obs.history["v_filtered"] - W)[:, 0]


def test_walcott_zak_converges_despite_a_matched_bounded_unknown_input(wz_design):
    """|w| <= 0.9 < rho = 1: the error converges to the O(dt) of the sampled injection; the same linear gain
    without the nonlinear term keeps an error of the size of w; the filtered injection estimates w."""
    t, err, werr = _wz_run(wz_design, 1e-3, 1.0)
    _, lin, _ = _wz_run(wz_design, 1e-3, 1e-9)
    sel = t > 3.0
    assert err[sel].max() < 2e-3 and err[0] == 1.0
    assert lin[sel].max() > 20 * err[sel].max()
    assert werr[sel].max() < 0.05, werr[sel].max()
    steps, errs = [1e-3, 2e-3, 4e-3], []
    for dt in steps:
        t, err, _ = _wz_run(wz_design, dt, 1.0)
        errs.append(err[t > 3.0].max())
    assert abs(c.fit_order(steps, errs) - 1.0) < 0.2, errs


def test_walcott_zak_explicit_discretization_also_converges(wz_design):
    """Explicit unit vector: O(rho dt) chattering; the filtered injection keeps a ripple of about 2 rho dt / tau."""
    t, err, werr = _wz_run(wz_design, 1e-3, 1.0, "euler")
    assert err[t > 3.0].max() < 5e-3
    assert werr[t > 3.0].max() < 2 * 1.0 * 1e-3 / 0.01


def test_walcott_zak_bad_input(wz_design):
    with pytest.raises(ValueError, match="expected rho > 0"):
        c.WalcottZakObserver(AW, BW, CW, DW, 1e-3, rho=0.0, design=wz_design)
    with pytest.raises(TypeError, match="WalcottZakDesign"):
        c.WalcottZakObserver(AW, BW, CW, DW, 1e-3, rho=1.0, design={"P": 1})
    with pytest.raises(ValueError, match=r"expected D with shape \(3x\*\)"):
        c.WalcottZakObserver(AW, BW, CW, np.ones((2, 1)), 1e-3, rho=1.0, design=wz_design)


def test_walcott_zak_certificate_refuses_a_bad_decay_or_tol():
    A, C, D = np.array([[0.0, 1.0], [-2.0, -3.0]]), np.eye(2), np.array([[0.0], [1.0]])
    for decay in (np.nan, -1.0, np.inf):
        with pytest.raises(ValueError, match=r"expected decay >= 0.*actual value"):
            c.certify_walcott_zak(A, C, D, np.eye(2), 5 * np.eye(2), decay=decay)
    for tol in (np.nan, -1e-6):
        with pytest.raises(ValueError, match=r"expected tol >= 0.*actual value"):
            c.certify_walcott_zak(A, C, D, np.eye(2), 5 * np.eye(2), tol=tol)
    with pytest.raises(TypeError, match="expected decay to be a real number"):
        c.certify_walcott_zak(A, C, D, np.eye(2), 5 * np.eye(2), decay=True)


def test_walcott_zak_observer_refuses_a_design_for_another_system():
    """The design's gain is re-verified on the observer's own A, C, D: A - G C must be Hurwitz there."""
    A, C, D = np.array([[0.0, 1.0], [-2.0, -3.0]]), np.eye(2), np.array([[0.0], [1.0]])
    design = c.certify_walcott_zak(A, C, D, np.eye(2), 5 * np.eye(2))
    obs = c.WalcottZakObserver(A, None, C, D, 1e-3, 1.0, design=design)
    np.testing.assert_allclose(np.sort_complex(obs.design.observer_eigenvalues), [-7.0 + 0j, -6.0], atol=1e-9)
    with pytest.raises(ValueError, match=r"expected a design for this system.*actual value"):
        c.WalcottZakObserver(5 * np.eye(2), None, C, D, 1e-3, 1.0, design=design)
    with pytest.raises(ValueError, match=r"expected a design for this system.*actual value"):
        c.WalcottZakObserver(AW, BW, CW, DW, 1e-3, 1.0, design=design)


# ---------------------------------------------------------------------------------------------------------------
# unknown-input observer without differentiation
# ---------------------------------------------------------------------------------------------------------------
def _arbitrary_w(t):
    """Large, discontinuous and growing: nothing a bounded-input observer could reject."""
    return (50.0 * np.sign(np.sin(5.0 * t)) + 10.0 * t)[:, None]


def test_uio_rejects_an_arbitrary_unknown_input_with_first_order_sampling_error():
    steps, errs = [1e-3, 2e-3, 4e-3], []
    for dt in steps:
        uio = c.UnknownInputObserver(AW, BW, CW, DW, dt, decay=3.0)
        t, X, U, _ = simulate(AW, BW, [1.0, 0.5, -0.3], 3.0, dt, u=sin_input, D=DW, w=_arbitrary_w)
        err = np.abs(uio.run(X @ CW.T, U, x_hat0=np.zeros(3)) - X).max(axis=1)
        errs.append(err[t > 2.5].max())
    np.testing.assert_allclose(uio.T @ DW, 0.0, atol=1e-12)
    assert uio.error_eigenvalues.real.max() < -3.0
    assert errs[0] < 0.02, errs  # against |w| up to 80
    assert abs(c.fit_order(steps, errs) - 1.0) < 0.15, errs


def test_uio_error_keeps_the_invariant_zeros_as_eigenvalues_and_decays_at_that_rate():
    """Darouach et al. 1994: the unobservable modes of (TA, C) are the invariant zeros: no gain moves them."""
    A, B, C, D = _relative_degree_one([-1.0, -2.0])
    with pytest.raises(c.UnknownInputConditionError, match="left of -decay"):
        c.UnknownInputObserver(A, B, C, D, 1e-3, decay=5.0)  # the zero at -1 cannot be moved left of -5
    uio = c.UnknownInputObserver(A, B, C, D, 1e-3, decay=0.5)
    ev = np.sort_complex(uio.error_eigenvalues)
    assert np.min(np.abs(ev - (-1.0))) < 1e-8 and np.min(np.abs(ev - (-2.0))) < 1e-8
    t, X, U, _ = simulate(A, B, [1.0, 0.5, -0.3], 6.0, 1e-3, u=sin_input, D=D, w=lambda t: _arbitrary_w(t) / 50)
    err = np.linalg.norm(uio.run(X @ C.T, U, x_hat0=np.zeros(3)) - X, axis=1)
    sel = (t > 2.0) & (t < 5.0)  # the -2 and -4.3 modes are gone, the O(dt) floor not yet reached
    rate = np.polyfit(t[sel], np.log(err[sel]), 1)[0]
    assert abs(rate - (-1.0)) < 0.05, rate


# ---------------------------------------------------------------------------------------------------------------
# MuJoCo: the Furuta pendulum
# ---------------------------------------------------------------------------------------------------------------
def test_mujoco_furuta_unknown_input_observers():
    """Angles only: rank(CD) = 0 (the slides' relative-degree-one condition fails, by name). With the arm's
    tachometer added, both observers track the nonlinear MuJoCo pendulum under a torque through qfrc_applied."""
    pytest.importorskip("gymnasium")
    pytest.importorskip("cvxpy")
    res = examples.furuta_mujoco_demo(t_final=3.0, verbose=False)
    assert res["angles_only_condition"] == "rank(CD) = rank(D)"
    # pendulum velocity error after 1.5 s, against the disturbance's effect on the Luenberger baseline
    assert res["walcott_zak"] < 0.2 * res["luenberger"], res
    assert res["uio"] < 0.2 * res["luenberger"], res
    assert res["w_error"] < 0.3 * res["w_amplitude"], res


def test_uio_bad_input():
    with pytest.raises(ValueError, match=r"expected D with shape \(3x\*\)"):
        c.UnknownInputObserver(AW, BW, CW, np.ones((2, 1)), 1e-3)
    with pytest.raises(ValueError, match="expected decay >= 0"):
        c.UnknownInputObserver(AW, BW, CW, DW, 1e-3, decay=-1.0)
    with pytest.raises(ValueError, match="Hurwitz"):
        c.UnknownInputObserver(AW, BW, CW, DW, 1e-3, K=-10.0 * np.ones((3, 2)))
    with pytest.raises(ValueError, match=r"expected K with shape \(3x2\)"):
        c.UnknownInputObserver(AW, BW, CW, DW, 1e-3, K=np.ones((2, 2)))
    with pytest.raises(ValueError, match="full row rank"):
        c.UnknownInputObserver(AW, BW, np.vstack([CW[0], CW[0]]), DW, 1e-3)


def test_unknown_input_observer_refuses_a_decay_its_design_misses():
    """The shifted Riccati design places the error eigenvalues left of -decay in exact arithmetic; at decay = 1e8
    its numerical solution left one at -5.3e4 and the observer was built, reporting a guarantee it does not keep
    (1e200 escaped as a LinAlgError). Where it is met, it is met."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, -2.0, -3.0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    D = np.array([[0.0], [0.0], [1.0]])
    for decay in (0.0, 10.0, 1e3):
        assert c.UnknownInputObserver(A, None, C, D, 1e-3, decay=decay).error_eigenvalues.real.max() < -decay
    for decay in (1e8, 1e200):
        with pytest.raises(ValueError, match="expected a decay the Riccati design achieves"):
            c.UnknownInputObserver(A, None, C, D, 1e-3, decay=decay)


def test_the_reproduction_script_runs_without_arguments(capsys, monkeypatch):
    """``python scripts/reproduce_slides_conventional.py`` (the guide's command) was refused by argparse: a list
    default of ``nargs="*"`` checked against ``choices`` as one value. Every example runs; an unknown one is an
    argparse error."""
    ran = []
    monkeypatch.setattr(
        examples,
        "EXAMPLES",
        {key: (title, lambda *_, key=key: ran.append(key) or []) for key, (title, _) in examples.EXAMPLES.items()},
    )
    assert examples.main([]) == 0 and ran == list(examples.EXAMPLES)
    with pytest.raises(SystemExit) as excinfo:
        examples.main(["utkin", "no-such-example"])
    assert excinfo.value.code == 2 and "no-such-example" in capsys.readouterr().err
