"""Linear switched systems: conditions, the known-mode HOSM observer, and the bank estimating the unknown mode.

Noise-free, sampled exactly (zero-order hold): after each switch the state is recovered exactly (to the sampled
differentiator's floor) within a measured finite time shorter than the dwell time, and the bank identifies every
switch with a delay bounded by the observers' convergence time (Fridman's slides, section "Switched systems").
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_script

from smo_gym.control import (
    LinearPlant,
    NotDistinguishableError,
    NotStronglyObservableError,
    SwitchedHOSMObserver,
    SwitchedLinearSystem,
    SwitchedObserverBank,
    mode_metrics,
)

DT = 1e-3
SEGMENT = 1500  # samples per mode: the dwell time is 1.5 s
L = 300.0  # bounds the third derivative of each output error, the wrong models' mismatch included
BANK = dict(threshold=0.5, dwell=0.01, settle_time=0.3, residual_time_constant=0.02)


def oscillator(k: float, b: float, d=(0.0, 1.0)) -> LinearPlant:
    """x1' = x2, x2' = -k x1 - 0.5 x2 + b u + w, position measured (relative degree 2: strongly observable)."""
    return LinearPlant([[0, 1], [-k, -0.5]], [[0], [b]], [[1, 0]], np.array(d, float)[:, None])


@pytest.fixture(scope="module")
def record():
    system = SwitchedLinearSystem([oscillator(1, 1), oscillator(9, 1), oscillator(4, 3)], names=["a", "b", "c"])
    T = 3 * SEGMENT
    sigma = np.repeat([0, 1, 2], SEGMENT)
    t = np.arange(T) * DT
    u = (2 * np.sin(3 * t) + np.sin(7.3 * t))[:, None]
    X, Y = system.simulate([1.0, 2.0], sigma, DT, u=u)
    return system, sigma, u, X, Y


def _convergence_times(err, threshold, switches, T):
    """Per segment, the time from its start to the last sample whose error exceeds ``threshold``."""
    bounds = [0, *switches, T]
    out = []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        bad = np.flatnonzero(err[a:b] > threshold)
        out.append((bad.max() + 1) * DT if bad.size else 0.0)
    return np.array(out)


def test_conditions_report_every_assumption(record):
    system = record[0]
    c = system.conditions()
    assert c.ok and c.reason == ""
    assert c.detectable == (True, True, True) and c.strongly_observable == (True, True, True)
    assert [r.tolist() for r in c.relative_degrees] == [[2], [2], [2]]
    # mismatch of a and b: |Delta A|_F = 8 over ||[A, B; C, 0]||_F of b
    ref = np.linalg.norm([[0, 1, 0], [-9, -0.5, 1], [1, 0, 0]])
    assert c.mismatch[0, 1] == pytest.approx(8 / ref)
    assert c.distinguishable.all()


def test_known_mode_restart_is_exact_in_finite_time_after_each_switch(record):
    system, sigma, u, X, Y = record
    obs = SwitchedHOSMObserver(system, DT, L, on_switch="restart")
    X_hat = obs.run(Y, sigma, U=u, x_hat0=[0.0, 0.0])
    assert obs.switch_samples == [SEGMENT, 2 * SEGMENT]
    err = np.abs(X_hat - X).max(axis=1)
    t_conv = _convergence_times(err, 1e-2, obs.switch_samples, len(err))
    # restarted from the output alone (velocity unknown), exact again well within the dwell time
    assert np.all(t_conv > 0.0) and np.all(t_conv < 0.5), t_conv
    for a in (SEGMENT - 200, 2 * SEGMENT - 200, 3 * SEGMENT - 200):  # the sampled floor O(L dt^2) before switches
        assert err[a : a + 200].max() < 2e-3


def test_known_mode_continuation_stays_exact_across_switches(record):
    """With an unknown input acting (``w = 0.5 sin 3t + 0.3``, which the modes' model does not know, so the sliding
    correction must work), the slides' reset equations carry the estimate across each switch with no transient:
    the error stays at the sampled floor (measured 6.8e-4 everywhere, 6.1e-4 and 6.6e-4 in the 300 samples after
    the switches). Restarted at each switch from the output alone instead, the same observer has a transient there
    (measured 0.80 and 6.98): the state is continuous, so continuing is what keeps finite-time exactness."""
    system, sigma, u, _, _ = record
    t = np.arange(len(sigma)) * DT
    X, Y = system.simulate([1.0, 2.0], sigma, DT, u=u, w=(0.5 * np.sin(3 * t) + 0.3)[:, None])
    obs = SwitchedHOSMObserver(system, DT, L)  # on_switch="continue": the slides' reset equations
    err = np.abs(obs.run(Y, sigma, U=u, x_hat0=X[0]) - X).max(axis=1)
    assert err.max() < 2e-3  # no transient at the switches
    restarted = SwitchedHOSMObserver(system, DT, L, on_switch="restart").run(Y, sigma, U=u, x_hat0=X[0])
    jump = np.abs(restarted - X).max(axis=1)
    assert all(jump[k : k + 300].max() > 0.1 for k in (SEGMENT, 2 * SEGMENT))
    # the same observer without the mode change would be wrong: the model matters
    wrong = SwitchedHOSMObserver(system, DT, L).run(Y, np.zeros_like(sigma), U=u, x_hat0=X[0])
    assert np.abs(wrong - X).max() > 10 * err.max()


def test_bank_identifies_the_modes_with_delay_bounded_by_convergence(record):
    system, sigma, u, X, Y = record
    bank = SwitchedObserverBank(system, DT, L, **BANK)
    est = bank.run(Y, U=u, x_hat0=[0.0, 0.0])
    full_sigma = np.r_[sigma, sigma[-1]]
    m = mode_metrics(est, full_sigma, start=BANK["settle_time"])
    assert est.new_modes.tolist() == [1, 2] and m.missed == 0 and m.false_switches == 0
    # the switching instants themselves are seen within a few samples
    assert np.all(np.abs(est.switch_times - [SEGMENT * DT, 2 * SEGMENT * DT]) < 0.02), est.switch_times
    # detection delay: the new mode's observer converges (measured with the known-mode restart observer) plus
    # the residual filter's memory and the dwell
    obs = SwitchedHOSMObserver(system, DT, L, on_switch="restart")
    err = np.abs(obs.run(Y, sigma, U=u, x_hat0=[0.0, 0.0]) - X).max(axis=1)
    t_conv = _convergence_times(err, 1e-2, [SEGMENT, 2 * SEGMENT], len(err))[1:]
    bound = t_conv + 5 * BANK["residual_time_constant"] + BANK["dwell"]
    assert np.all(m.delays > 0) and np.all(m.delays <= bound), (m.delays, bound)
    assert m.accuracy > 0.9
    # after detection the bank's estimate is the right mode's: exact again
    k = int(round(est.detection_times[-1] / DT)) + 200
    assert np.abs(est.x_hat[k:] - X[k:]).max() < 2e-2


def test_indistinguishable_modes_are_refused_by_name():
    # the two modes differ only in where the unknown input enters: with w = 0 no output tells them apart
    system = SwitchedLinearSystem([oscillator(1, 1), oscillator(1, 1, d=(0.0, 2.0))], names=["x", "y"])
    c = system.conditions()
    assert not c.ok and c.reason.startswith("distinguishability") and "'x' and 'y'" in c.reason
    with pytest.raises(NotDistinguishableError, match="distinguishability: 'x' and 'y'"):
        SwitchedObserverBank(system, DT, L, threshold=0.5)
    SwitchedHOSMObserver(system, DT, L)  # a known mode needs no distinguishability


def test_not_strongly_observable_mode_is_refused_by_name():
    # velocity measured, unknown input in the acceleration: relative degree 1, sum 1 < n = 2 (a zero at 0)
    bad = LinearPlant([[0, 1], [-1, -0.5]], [[0], [1]], [[0, 1]], [[0], [1]])
    system = SwitchedLinearSystem([oscillator(1, 1), bad], names=["ok", "velocity-only"])
    assert system.conditions().reason.startswith("strong observability: 'velocity-only'")
    with pytest.raises(NotStronglyObservableError, match="velocity-only"):
        SwitchedHOSMObserver(system, DT, L)


@pytest.mark.parametrize(
    "modes, error",
    [
        ([], ValueError),
        (oscillator(1, 1), TypeError),
        ([oscillator(1, 1), "B"], TypeError),
        ([oscillator(1, 1), LinearPlant(np.eye(3), np.ones((3, 1)), np.eye(3)[:1], np.ones((3, 1)))], ValueError),
    ],
)
def test_bad_mode_sets(modes, error):
    with pytest.raises(error, match="expected"):
        SwitchedLinearSystem(modes)


def test_bad_arguments(record):
    system = record[0]
    with pytest.raises(ValueError, match="lipschitz > 0"):
        SwitchedHOSMObserver(system, DT, -1.0)
    with pytest.raises(ValueError, match=r"shape \(3, 1\)"):
        SwitchedHOSMObserver(system, DT, np.ones((2, 2)))
    with pytest.raises(ValueError, match="dt > 0"):
        SwitchedHOSMObserver(system, 0.0, L)
    with pytest.raises(ValueError, match="threshold > 0"):
        SwitchedObserverBank(system, DT, L, threshold=0.0)
    with pytest.raises(ValueError, match="dwell > 0"):
        SwitchedObserverBank(system, DT, L, threshold=1.0, dwell=-0.1)
    with pytest.raises(ValueError, match="at least 2 modes"):
        SwitchedObserverBank(SwitchedLinearSystem([oscillator(1, 1)]), DT, L, threshold=1.0)
    with pytest.raises(ValueError, match="mode indices"):
        system.simulate([0, 0], [0, 3], DT)
    with pytest.raises(ValueError, match="mode names"):
        SwitchedLinearSystem([oscillator(1, 1)], names=["a", "b"])
    obs = SwitchedHOSMObserver(system, DT, L)
    with pytest.raises(RuntimeError, match="never reset"):
        obs.update([0.0], 0)
    with pytest.raises(ValueError, match="mode"):
        obs.reset([0.0], 5)


# ---- MuJoCo: the demonstration's path, one seed ----------------------------------------------------------------


def test_mujoco_arm_gear_switch_is_detected():
    pytest.importorskip("mujoco")
    demo = load_script("demo_switched")
    threshold = demo.calibrate(1, 1.0)  # calibration seed 1000, not the evaluated seed
    assert threshold > 0
    steps = 800  # 1.6 s at 2 ms: nominal, then the shoulder gear drops at 0.8 s
    sigma = np.where(np.arange(steps) < steps // 2, 0, 1)
    est, sig, qvel = demo.run_episode(0, duration=1.6, threshold=threshold, sigma=sigma)
    m = mode_metrics(est, sig, start=demo.SETTLE)
    assert est.new_modes.tolist() == [1] and m.missed == 0 and m.false_switches == 0
    assert 0.0 < m.delays[0] < 0.5  # shorter than the shortest dwell of the demonstration's schedules (0.6 s)
    k0 = round(demo.SETTLE / est.dt)
    assert np.sqrt(np.mean((est.x_hat[k0:, 2:] - qvel[k0:]) ** 2)) < 0.2  # rad/s, noisy 12-bit encoder


def test_the_guide_example_runs_as_printed():
    """The python block of the "Switched systems" section of docs/guide/control.md, executed as printed."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "guide" / "control.md").read_text()
    section = text[text.index("## Switched systems") :]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    scope: dict = {}
    exec(compile(code, "control.md", "exec"), scope)
    est = scope["est"]
    assert est.new_modes.tolist() == [1]
    assert abs(est.switch_times[0] - 1.5) < 0.02 and 1.5 < est.detection_times[0] < 1.8


def test_mode_metrics_by_hand():
    from smo_gym.control import SwitchedEstimate

    dt = 0.1
    sigma = np.repeat([0, 1, 2], 10)  # true switches at 1.0 s (to 1) and 2.0 s (to 2)
    modes = np.repeat([0, 2, 0, 1], [3, 2, 7, 18])  # a false switch to 2 at 0.3 s, back at 0.5 s, to 1 at 1.2 s
    est = SwitchedEstimate(
        modes=modes,
        switch_times=np.array([0.3, 0.5, 1.0]),
        detection_times=np.array([0.3, 0.5, 1.2]),
        new_modes=np.array([2, 0, 1]),
        residual_norms=np.zeros((30, 3)),
        x_hat=np.zeros((30, 2)),
        dt=dt,
    )
    m = mode_metrics(est, sigma)
    assert m.delays == pytest.approx([0.2])
    assert m.missed == 1 and m.missed_switches == ((pytest.approx(2.0), 1, 2),)
    assert m.false_switches == 2  # the switch to 2 at 0.3 s and the one back at 0.5 s
    assert m.accuracy == pytest.approx(np.mean(modes == sigma))  # 3 + 5 + 8 right of 30
    assert np.mean(modes == sigma) == pytest.approx(16 / 30)


def test_undetectable_mode_is_named_first():
    # an unstable mode (eigenvalue +1) that the output never sees: not detectable (Hautus), hence not observable
    hidden = LinearPlant([[1.0, 0.0], [0.0, -1.0]], [[0], [1]], [[0, 1]], [[0], [1]])
    system = SwitchedLinearSystem([oscillator(1, 1), hidden], names=["ok", "hidden"])
    c = system.conditions()
    assert c.detectable == (True, False)
    assert c.reason.startswith("detectability: (A, C) of 'hidden'")
    with pytest.raises(NotStronglyObservableError, match=r"detectability: .* 'hidden'"):
        SwitchedObserverBank(system, DT, L, threshold=1.0)
    # the same mode with its unstable part seen by the output is detectable
    seen = LinearPlant([[1.0, 0.0], [0.0, -1.0]], [[0], [1]], [[1, 1]], [[0], [1]])
    assert SwitchedLinearSystem([seen]).conditions().detectable == (True,)


# ---- autonomous switching ---------------------------------------------------------------------------------------
def _direction_dependent_damper():
    """x1' = x2, x2' = -4 x1 - b x2 + u + w, position measured; damping b = 0.2 extending (x2 > 0) and 3 when
    compressing (x2 <= 0): the mode is decided by the *unmeasured* velocity, H = [0, 1]."""
    from smo_gym.control import SwitchingSurface

    def damper(b):
        return LinearPlant([[0, 1], [-4, -b]], [[0], [1]], [[1, 0]], [[0.0], [1.0]])

    system = SwitchedLinearSystem([damper(0.2), damper(3.0)], names=["extending", "compressing"])
    return system, SwitchingSurface([0, 1], [0.0], [1, 0])


def test_autonomous_switching_is_estimated_exactly_once_the_state_is():
    """The discrete-state observer sigma_hat = sigma(H x_hat) (the slides' autonomous case): from a wrong initial
    velocity and under an unknown input, the continuous estimate converges in finite time (0.16 s measured) and from
    then on every mode of every interval is right (7 switches in 6 s), the state error at the sampled floor."""
    from smo_gym.control import AutonomousSwitchedObserver

    system, surface = _direction_dependent_damper()
    T = 6000
    t = np.arange(T) * DT
    u = (3 * np.sin(4 * t) + np.sin(9.3 * t))[:, None]
    w = (0.5 * np.sin(3 * t))[:, None]
    X, Y, sigma = system.simulate([0.5, 1.0], surface, DT, u=u, w=w, steps=T)
    assert np.count_nonzero(np.diff(sigma)) >= 6
    observer = AutonomousSwitchedObserver(system, surface, DT, L)
    X_hat, modes = observer.run(Y, u)  # starts at C^+ y0: the velocity estimate is off by 1
    err = np.abs(X_hat[:T] - X[:T]).max(axis=1)
    converged = t[np.flatnonzero(err > 1e-2).max() + 1]
    assert converged < 0.3
    after = t >= converged
    np.testing.assert_array_equal(modes[:T][after], sigma[after])
    assert err[t >= converged + 0.1].max() < 2e-3
    true_switches = t[1:][np.diff(sigma) != 0]
    np.testing.assert_allclose(
        [s for s in observer.switch_times if s > converged], true_switches[true_switches > converged]
    )


def test_switching_surface_condition_holds_and_fails_with_the_weakly_unobservable_subspace():
    """V* inside ker Q (the slides' condition): x3 (stable, unmeasured, never reaching y) is weakly unobservable;
    H = e1 never sees it (holds), H = e3 reads it directly (fails, naming the mode)."""
    from smo_gym.control import SwitchingSurface

    A = [[0, 1, 0], [-1, 0, 0], [1, 0, -1]]
    plant = LinearPlant(A, [[0], [1], [0]], [[1, 0, 0]], [[0], [1], [0]])
    other = LinearPlant(np.array(A) + np.diag([0, -1, 0]), [[0], [1], [0]], [[1, 0, 0]], [[0], [1], [0]])
    system = SwitchedLinearSystem([plant, other], names=["a", "b"])
    assert SwitchingSurface([1, 0, 0], [0.0], [0, 1]).condition(system) == (True, "")
    ok, reason = SwitchingSurface([0, 0, 1], [0.0], [0, 1]).condition(system)
    assert not ok and "mode 'a'" in reason and "dimension 1" in reason
    # strongly observable modes (V* = {0}) satisfy it for every H
    damper, _ = _direction_dependent_damper()
    assert SwitchingSurface([3, -2], [0.0], [0, 1]).condition(damper)[0]


def test_detectability_and_the_surface_condition_do_not_depend_on_units():
    """A -> a A, C -> c C, D -> d D, H -> h H (time, output, input and surface units) change no verdict."""
    from smo_gym.control import SwitchingSurface

    A = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, -1.0]])
    B, C, D = np.array([[0.0], [1.0], [0.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([[0.0], [1.0], [0.0]])
    for a, cc, d in [(1e-10, 1.0, 1.0), (1e10, 1.0, 1.0), (1.0, 1e-10, 1e10), (1e-10, 1e10, 1e-10), (1e10,) * 3]:
        hidden = LinearPlant(a * np.diag([1.0, -1.0]), [[0], [1]], cc * np.array([[0.0, 1.0]]), [[0], [d]])
        seen = LinearPlant(a * np.diag([1.0, -1.0]), [[0], [1]], cc * np.array([[1.0, 1.0]]), [[0], [d]])
        assert SwitchedLinearSystem([hidden, seen]).conditions().detectable == (False, True), (a, cc, d)
        system = SwitchedLinearSystem([LinearPlant(a * A, B, cc * C, d * D)])
        for h in (1e-10, 1.0, 1e10):  # x3 is weakly unobservable: H = e1 never sees it, H = e3 does
            assert SwitchingSurface([h, 0, 0], [0.0], [0, 0]).condition(system) == (True, ""), (a, cc, d, h)
            assert not SwitchingSurface([0, 0, h], [0.0], [0, 0]).condition(system)[0], (a, cc, d, h)


def test_switching_surface_bad_input():
    from smo_gym.control import AutonomousSwitchedObserver, SwitchingSurface

    with pytest.raises(ValueError, match="increasing edges"):
        SwitchingSurface([0, 1], [1.0, 0.0], [0, 1, 0])
    with pytest.raises(ValueError, match="one per interval"):
        SwitchingSurface([0, 1], [0.0], [0])
    with pytest.raises(ValueError, match="nonzero H"):
        SwitchingSurface([0, 0], [0.0], [0, 1])
    system, surface = _direction_dependent_damper()
    with pytest.raises(ValueError, match="steps"):
        system.simulate([0, 0], surface, DT)
    with pytest.raises(TypeError, match="SwitchingSurface"):
        AutonomousSwitchedObserver(system, [0, 1], DT, L)
    with pytest.raises(RuntimeError, match="reset"):
        AutonomousSwitchedObserver(system, surface, DT, L).update([0.0])


# ---- bad input: refused with a typed error, state unchanged -------------------------------------------------------
def _small():
    """Two modes, 40 samples with a switch at 20: fast enough for the input checks."""
    system = SwitchedLinearSystem([oscillator(1, 1), oscillator(9, 1)])
    sigma = np.repeat([0, 1], 20)
    u = np.sin(np.arange(40) * DT)[:, None]
    _, Y = system.simulate([1.0, 2.0], sigma, DT, u=u)
    return system, sigma, u, Y


def test_simulate_refuses_non_finite_input_and_reports_an_escaping_trajectory():
    from smo_gym import DivergenceError
    from smo_gym.control import SwitchingSurface

    system = _small()[0]
    with pytest.raises(ValueError, match="expected x0 finite"):
        system.simulate([np.nan, 2.0], [0, 1], DT)
    with pytest.raises(ValueError, match="expected u finite"):
        system.simulate([1.0, 2.0], [0, 1], DT, u=[[np.nan], [0.0]])
    with pytest.raises(ValueError, match="expected w finite"):
        system.simulate([1.0, 2.0], [0, 1], DT, w=[[np.inf], [0.0]])
    with pytest.raises(ValueError, match=r"expected sigma as a 1-D sequence"):
        system.simulate([1.0, 2.0], [[0, 1], [1, 0]], DT)
    with pytest.raises(DivergenceError, match="expected a finite trajectory"):
        system.simulate([1.0, 2.0], [0, 1], 1e300)
    with pytest.raises(DivergenceError, match="expected a finite trajectory"):
        system.simulate([1.0, 2.0], SwitchingSurface([1, 0], [0.0], [0, 1]), 1e300, steps=3)


def test_switching_surface_refuses_non_integer_modes_and_a_nan_state():
    from smo_gym.control import SwitchingSurface

    for modes in ([0.7, 1.9], [True, False], ["a", "b"]):
        with pytest.raises(TypeError, match="expected modes"):
            SwitchingSurface([1, 0], [0.0], modes)
    with pytest.raises(ValueError, match="expected modes >= 0"):
        SwitchingSurface([1, 0], [0.0], [0, -1])
    surface = SwitchingSurface([1, 0], [0.0], [0, 1])
    with pytest.raises(ValueError, match="expected x finite"):
        surface.mode([np.nan, 0.0])
    with pytest.raises(ValueError, match=r"expected x with shape \(2,\)"):
        surface.mode([1.0, 0.0, 3.0])


def test_mode_metrics_refuses_what_is_not_a_mode_sequence():
    from smo_gym.control import SwitchedEstimate

    est = SwitchedEstimate(
        modes=np.repeat([0, 1], 5),
        switch_times=np.array([0.5]),
        detection_times=np.array([0.5]),
        new_modes=np.array([1]),
        residual_norms=np.zeros((10, 2)),
        x_hat=np.zeros((10, 2)),
        dt=0.1,
    )
    sigma = np.repeat([0, 1], 5)
    assert mode_metrics(est, sigma).accuracy == 1.0
    with pytest.raises(ValueError, match="expected sigma as mode indices"):
        mode_metrics(est, sigma + 0.7)
    with pytest.raises(ValueError, match="expected sigma as mode indices"):
        mode_metrics(est, np.r_[sigma[:-1] * 1.0, np.nan])
    with pytest.raises(ValueError, match="expected sigma as mode indices"):
        mode_metrics(est, -sigma)
    with pytest.raises(TypeError, match="expected sigma to be an array of real numbers"):
        mode_metrics(est, sigma.astype(bool))
    with pytest.raises(ValueError, match=r"expected start < 1 \(the record's end"):
        mode_metrics(est, sigma, start=100.0)
    with pytest.raises(TypeError, match="expected a SwitchedEstimate"):
        mode_metrics(None, sigma)


def test_switched_observers_refuse_what_is_not_their_input():
    system, _, u, Y = _small()
    with pytest.raises(TypeError, match="expected reset_on_switch to be True or False"):
        SwitchedObserverBank(system, DT, L, threshold=0.5, reset_on_switch="no")
    obs = SwitchedHOSMObserver(system, DT, L)
    with pytest.raises(ValueError, match=r"expected Y with shape \(T >= 1, 1\)"):
        obs.run(5.0, [0, 1])
    with pytest.raises(ValueError, match=r"expected Y with shape \(T >= 1, 1\)"):
        obs.run(np.zeros((0, 1)), [0])
    a, b = SwitchedHOSMObserver(system, DT, L), SwitchedHOSMObserver(system, DT, L)
    for z in (a, b):
        z.reset(Y[0], 0)
    for bad, error in (("1", TypeError), (True, TypeError), ([np.nan], ValueError)):
        with pytest.raises(error, match="expected"):
            a.advance(bad)
    for z in (a, b):
        z.advance(u[0])
    with pytest.raises(ValueError, match="expected a finite y,"):
        a.update([np.nan], 1)  # in a new mode: checked before its observer restarts
    with pytest.raises(ValueError, match="expected a finite y,"):
        a.switch(1, [np.nan], [0.0, 0.0])
    for k in range(1, 4):
        np.testing.assert_array_equal(a.update(Y[k], 1), b.update(Y[k], 1))
        for z in (a, b):
            z.advance(u[k])
    assert a.switch_samples == b.switch_samples == [1]
