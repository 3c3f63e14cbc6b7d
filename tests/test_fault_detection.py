"""Fault detection and isolation with a bank of super-twisting observers (Rios, Davila, Fridman and Edwards).

The defining properties on a noise-free pendulum: every observer of the bank converges in finite time; the nominal
residual then *is* the fault (filtered), the matching model's residual vanishes, each known fault is isolated and
its detection delay is bounded by what the residual filter needs (computed from the true fault signal, and shorter
than the observers' own convergence time); a fault-free run raises no alarm and a fault outside the bank is
detected but reported unknown.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import load_script

from smo_gym.fault_detection import FaultDiagnosis, FaultObserverBank, calibrate_threshold, diagnose

G_L, DAMP, GAIN = 9.81, 0.2, 1.0
H = 1e-3
T_FAULT = 1.0
STEPS = 2000
THETA = 0.1  # rad/s^2: the matching model's residual, noise-free, is the O(h) discretization error (~1e-2 here)
TAU = 0.02
DWELL = 0.1
SETTLE = 0.5
L = 30.0


def f(q, v, u):
    """Pendulum with viscous friction and a torque input: q'' = -g/l sin q - c q' + b u."""
    return -G_L * np.sin(q) - DAMP * v + GAIN * u


FAULTS = [
    lambda q, v, u: -0.5 * GAIN * u,  # actuator loses half its gain
    lambda q, v, u: -1.5 * v,  # extra viscous friction
    lambda q, v, u: 2.0 + 0.0 * q,  # constant torque offset
]
UNKNOWN = lambda q, v, u: -4.0 * q  # a stiffness: outside the bank
CASES = [None, *FAULTS, UNKNOWN]


def u_of(t):
    return 3.0 * np.sin(2.0 * t) + 2.0 * np.sin(5.3 * t) + 1.0


def simulate():
    """Every case at once (batch axis), RK4 with the input held over each sample; the fault starts at T_FAULT.

    Returns positions, velocities, inputs and the true fault signal, each of shape (STEPS + 1, 5, 1); ``U[k]`` and
    ``F[k]`` are the input and the fault over the interval ending at sample ``k``."""
    nb = len(CASES)
    x, v = np.zeros((nb, 1)), np.full((nb, 1), 0.5)
    Y, V, U, F = (np.zeros((STEPS + 1, nb, 1)) for _ in range(4))
    Y[0], V[0] = x, v

    def fault(q, w, u, on):
        out = np.zeros_like(q)
        if on:
            for i, c in enumerate(CASES):
                if c is not None:
                    out[i] = c(q[i], w[i], u[i])
        return out

    for k in range(STEPS):
        u = np.full((nb, 1), u_of((k + 1) * H))
        on = k >= round(T_FAULT / H)

        def rhs(q, w, u=u, on=on):
            return w, f(q, w, u) + fault(q, w, u, on)

        a1 = rhs(x, v)
        a2 = rhs(x + H / 2 * a1[0], v + H / 2 * a1[1])
        a3 = rhs(x + H / 2 * a2[0], v + H / 2 * a2[1])
        a4 = rhs(x + H * a3[0], v + H * a3[1])
        F[k + 1] = fault(x, v, u, on)
        x = x + H / 6 * (a1[0] + 2 * a2[0] + 2 * a3[0] + a4[0])
        v = v + H / 6 * (a1[1] + 2 * a2[1] + 2 * a3[1] + a4[1])
        Y[k + 1], V[k + 1], U[k + 1] = x, v, u
    return Y, V, U, F


def make_bank(**kw):
    args = dict(lipschitz=L, n=1, dwell=DWELL, settle_time=SETTLE, disturbance_time_constant=TAU)
    args.update(kw)
    return FaultObserverBank(H, f, FAULTS, THETA, names=["actuator", "friction", "offset"], **args)


@pytest.fixture(scope="module")
def pendulum():
    Y, V, U, F = simulate()
    bank = make_bank()
    bank.reset(Y[0])  # velocity estimate 0 against a true 0.5 rad/s: the convergence transient
    vel = np.zeros_like(V)
    res = np.zeros(Y.shape[:2] + (4,))
    for k in range(1, STEPS + 1):
        bank.update(Y[k], U[k])
        vel[k] = bank.velocity(0)
        res[k] = bank.residuals[..., 0]
    return dict(Y=Y, V=V, U=U, F=F, vel=vel, res=res, diagnosis=bank.diagnose())


def convergence_time(err, tol):
    """First time after which |err| stays below tol (err of shape (T,))."""
    above = np.flatnonzero(np.abs(err) > tol)
    return 0.0 if above.size == 0 else (above[-1] + 1) * H


def filtered(signal):
    """The bank's residual filter r_k = r_{k-1} + beta (s_k - r_{k-1}), beta = h / (tau + h), applied to a signal."""
    beta = H / (TAU + H)
    out = np.zeros_like(signal)
    for k in range(1, signal.shape[0]):
        out[k] = out[k - 1] + beta * (signal[k] - out[k - 1])
    return out


def test_finite_time_exact_reconstruction(pendulum):
    kf = round(T_FAULT / H)
    err = pendulum["vel"][:, 0, 0] - pendulum["V"][:, 0, 0]
    tc = convergence_time(err, 1e-4)
    assert 0.0 < tc < SETTLE  # converged from the initial error in finite time, before decisions start
    assert np.abs(err[math.ceil(2 * tc / H) :]).max() < 1e-5  # and stays at the discretization level
    # after convergence the velocity is exact up to the sampling (noise-free). Inside the sliding set the implicit
    # step's velocity is a model-corrected backward difference, so what the model misses (the fault F) costs O(h |F|)
    k_c = math.ceil(tc / H)
    verr = np.abs(pendulum["vel"][k_c:, :, 0] - pendulum["V"][k_c:, :, 0])
    assert verr[:, 0].max() < 1e-4  # exact model: the RK4-versus-Taylor discretization only
    assert verr.max() < H * np.abs(pendulum["F"]).max()
    # the nominal residual reconstructs the fault: it equals the filtered true fault signal F(x, u), once the filter
    # has forgotten the convergence transient (by settle_time)
    target = filtered(pendulum["F"][:, :, 0])
    k_s = round(SETTLE / H)
    gap = np.abs(pendulum["res"][k_s:, :, 0] - target[k_s:])
    assert gap.max() < 0.05 * np.abs(pendulum["F"][kf:, 1:]).max()
    # inside the band (the largest gap is the one-sample lag of the injection at the fault's onset jump)
    assert gap.max() < THETA
    away = np.r_[k_s:kf, kf + round(5 * TAU / H) : STEPS + 1] - k_s  # 5 filter time constants after the onset
    assert gap[away].max() < THETA / 5  # a small fraction of the band


def test_each_known_fault_is_isolated_and_the_unknown_one_is_not(pendulum):
    d = pendulum["diagnosis"]
    assert isinstance(d, FaultDiagnosis)
    assert d.isolated.tolist() == [0, 1, 2, 3, -1]
    assert d.detected.tolist() == [False, True, True, True, True]
    assert [d.label(i) for i in range(5)] == ["no fault", "actuator", "friction", "offset", "unknown"]
    assert np.isnan(d.detection_time[0]) and np.isnan(d.isolation_time[[0, 4]]).all()
    # the matching model's residual is the smallest at the end, and inside the band
    final = d.final_norms(100)
    for i in (1, 2, 3):
        assert np.argmin(final[i, 1:]) + 1 == i and final[i, i] < 1.0


def test_no_false_alarm_on_the_fault_free_run(pendulum):
    k0 = round(SETTLE / H)
    rho = pendulum["diagnosis"].residual_norms
    assert not pendulum["diagnosis"].detected[0]
    assert rho[k0:, 0, 0].max() < 0.5  # with a margin of 2: not a near miss


def test_detection_and_isolation_delays_are_bounded(pendulum):
    """Detection: the nominal observer stays in its sliding mode through the fault (k2 > |F|), so its injection
    jumps to F at once and the delay is the residual filter's, tau ln(|F| / (|F| - theta)) for |F| >= its smallest
    value over the delay. Isolation: the matching model's injection drops to 0 at once; its filtered residual decays
    from at most R (its largest pre-fault value) into the band within tau ln(R / theta), then the dwell."""
    d = pendulum["diagnosis"]
    kf = round(T_FAULT / H)
    err = pendulum["vel"][:, 0, 0] - pendulum["V"][:, 0, 0]
    tc = convergence_time(err, 1e-3)
    rho = d.residual_norms
    for i in (1, 2, 3):
        delay = d.detection_time[i] - T_FAULT
        fmin = np.abs(pendulum["F"][kf + 1 : kf + 21, i, 0]).min()  # over the first 20 ms
        bound = TAU * math.log(fmin / (fmin - THETA)) + 2 * H
        assert 0.0 <= delay <= bound, (i, delay, bound)
        assert delay < tc  # faster than the observers' own convergence from an initial error
        R = rho[round(SETTLE / H) : kf, i, i].max() * THETA
        iso_bound = TAU * math.log(R / THETA) + DWELL + 3 * H
        assert d.isolation_time[i] - T_FAULT <= iso_bound, (i, d.isolation_time[i] - T_FAULT, iso_bound)
        assert d.isolation_time[i] >= d.detection_time[i] + DWELL - H


def test_batched_bank_equals_single_runs(pendulum):
    Y, U = pendulum["Y"], pendulum["U"]
    single = make_bank().run(Y[:600, 2], U[:600, 2])
    np.testing.assert_allclose(single.residual_norms, pendulum["diagnosis"].residual_norms[:600, 2], rtol=1e-12)


# ---- the decision rule on hand-made residuals -----------------------------------------------------------------


def test_diagnose_on_hand_made_residuals():
    T, dt = 40, 0.1
    rho = np.full((T, 3), 5.0)
    rho[:, 0] = 0.2
    rho[10:, 0] = 3.0  # nominal leaves the band at sample 10
    rho[:, 1] = 0.5  # model 1 inside all along...
    rho[12:16, 1] = 2.0  # ...but not from sample 12 to 15
    rho[14:, 2] = 0.5  # model 2 inside from sample 14 on
    d = diagnose(rho, dt, dwell=0.3, settle_time=0.0)
    # windows of 3 samples counted from detection: model 1 complete at 10..12? no (12 outside); at 16..18 -> 18;
    # model 2 complete at 14..16 -> 16, alone
    assert d.detected and d.detection_time == pytest.approx(1.0)
    assert d.isolated == 2 and d.isolation_time == pytest.approx(1.6)
    # two models inside together: undecided until one leaves
    rho2 = np.full((T, 3), 5.0)
    rho2[:, 0] = 0.2
    rho2[10:, 0] = 3.0
    rho2[:25, 1] = 0.5
    rho2[8:, 2] = 0.5
    d2 = diagnose(rho2, dt, dwell=0.3)
    assert d2.isolated == 2 and d2.isolation_time == pytest.approx(2.5)  # model 1 leaves at 25: model 2 alone
    # a verdict whose model leaves the band later is revoked: model 1 fits from 10 to 19, then model 2 from 20 on
    rho5 = np.full((T, 3), 5.0)
    rho5[:, 0] = 0.2
    rho5[10:, 0] = 3.0
    rho5[10:20, 1] = 0.5
    rho5[20:, 2] = 0.5
    d5 = diagnose(rho5, dt, dwell=0.3)
    assert d5.isolated == 2 and d5.isolation_time == pytest.approx(2.2)
    rho5[30, 2] = 2.0  # and model 2 leaves once too: nothing stands by the end (window 31..33 does)
    assert diagnose(rho5, dt, dwell=0.3).isolation_time == pytest.approx(3.3)
    rho5[38, 2] = 2.0  # an exit too late for another full window: unknown
    assert diagnose(rho5, dt, dwell=0.3).isolated == -1
    # an excursion before settle_time is ignored; nothing after it: no fault
    rho3 = np.full((T, 2), 0.1)
    rho3[3, 0] = 9.0
    assert not diagnose(rho3, dt, dwell=0.2, settle_time=0.5).detected
    assert diagnose(rho3, dt, dwell=0.2).detected
    # detected, nobody stays in the band: unknown
    rho4 = np.full((T, 3), 5.0)
    assert diagnose(rho4, dt, dwell=0.2).isolated == -1


def test_calibrate_threshold():
    r = np.zeros((100, 3, 2))
    r[5, 0, 0] = 50.0  # inside the settling time: left out
    r[50, 1, 0] = -2.0
    r[70, 2, 1] = 0.5
    np.testing.assert_allclose(calibrate_threshold(r, 0.01, settle_time=0.1, margin=2.0), [4.0, 1.0])
    with pytest.raises(ValueError, match="not all zero"):
        calibrate_threshold(np.zeros((10, 2)), 0.01)
    with pytest.raises(ValueError, match="margin > 0"):
        calibrate_threshold(r, 0.01, margin=0.0)


# ---- bad input ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(faults=[]), ValueError, "at least one fault"),
        (dict(faults=[1.0]), TypeError, "faults\\[0\\]"),
        (dict(faults=lambda q, v, u: q), TypeError, "sequence of models"),
        (dict(threshold=0.0), ValueError, "threshold > 0"),
        (dict(threshold=[0.1, 0.2]), ValueError, "threshold > 0"),
        (dict(threshold=-1.0), ValueError, "threshold > 0"),
        (dict(lipschitz=-1.0), ValueError, "lipschitz"),
        (dict(lipschitz=None, k1=0.0, k2=1.0), ValueError, "k1"),
        (dict(dwell=0.0), ValueError, "dwell > 0"),
        (dict(dt=-0.01), ValueError, "dt > 0"),
        (dict(n=None), ValueError, "expected n"),
        (dict(names=["a"]), ValueError, "3 fault names"),
        (dict(nominal="f"), TypeError, "nominal"),
    ],
)
def test_bad_construction(kwargs, error, match):
    args = dict(dt=H, nominal=f, faults=FAULTS, threshold=THETA, lipschitz=L, n=1)
    args.update(kwargs)
    with pytest.raises(error, match=match):
        FaultObserverBank(**args)


def test_bad_use():
    bank = make_bank()
    with pytest.raises(RuntimeError, match="reset"):
        bank.update(np.zeros(1))
    with pytest.raises(RuntimeError, match="reset"):
        _ = bank.residuals
    with pytest.raises(ValueError, match="channels"):
        bank.reset(np.zeros(2))
    with pytest.raises(ValueError, match="shape"):
        bank.run(np.zeros((10, 2)))
    bank.reset(np.zeros(1))
    with pytest.raises(RuntimeError, match="at least one update"):
        bank.diagnose()
    with pytest.raises(ValueError, match="shape"):
        bank.update(np.zeros(3))
    with pytest.raises(ValueError, match="q \\+ 1"):
        diagnose(np.zeros((10, 1)), 0.1, dwell=0.1)
    with pytest.raises(ValueError, match="dwell > 0"):
        diagnose(np.zeros((10, 2)), 0.1, dwell=-0.1)
    with pytest.raises(ValueError, match="2 model names"):
        diagnose(np.zeros((10, 2)), 0.1, dwell=0.1, names=["a"])


def test_run_checks_the_whole_record_before_resetting():
    """A NaN at sample 5 was found after the reset and 4 updates: the previous history was lost."""
    bank = make_bank()
    Y = np.zeros((10, 1))
    bank.run(Y, U=np.zeros((10, 1)))
    before = len(bank._history)
    Y[5] = np.nan
    with pytest.raises(ValueError, match="finite measurements Y, actual value: NaN or inf at sample 5"):
        bank.run(Y)
    U = np.zeros((10, 1))
    U[3] = np.inf
    with pytest.raises(ValueError, match="finite inputs U"):
        bank.run(np.zeros((10, 1)), U=U)
    with pytest.raises(ValueError, match="one row per sample"):
        bank.run(np.zeros((10, 1)), U=np.zeros((9, 1)))
    assert len(bank._history) == before and bank.diagnose().residual_norms.shape == (before + 1, 4)


def test_threshold_and_decision_refuse_overflow_and_mistyped_names():
    with pytest.raises(ValueError, match="finite threshold"):
        calibrate_threshold(np.full((3, 1), 1e10), 0.01, margin=1e308)
    with pytest.raises(ValueError, match="none empty"):
        calibrate_threshold(np.ones((3, 0)), 0.01)
    with pytest.raises(ValueError, match="settle_time / dt"):
        calibrate_threshold(np.ones((3, 1)), 1e-300, settle_time=1e300)
    rho = np.zeros((10, 2))
    with pytest.raises(ValueError, match="settle_time / dt"):
        diagnose(rho, 1e-300, dwell=0.01, settle_time=1e300)
    with pytest.raises(ValueError, match="dwell / dt"):
        diagnose(rho, 1e-300, dwell=1e300)
    with pytest.raises(TypeError, match="expected names"):
        diagnose(rho, 0.1, dwell=0.1, names="ab")
    with pytest.raises(TypeError, match="expected names"):
        diagnose(rho, 0.1, dwell=0.1, names=5)
    with pytest.raises(TypeError, match="expected names"):
        FaultObserverBank(H, f, FAULTS, THETA, lipschitz=L, n=1, names="abc")
    assert diagnose(rho, 0.1, dwell=0.1, names=["a", "b"]).names == ("a", "b")


# ---- MuJoCo: the demonstration's path, one seed ----------------------------------------------------------------


def test_mujoco_arm_actuator_fault_is_isolated_and_fault_free_is_quiet():
    pytest.importorskip("mujoco")
    demo = load_script("demo_fault_detection")
    threshold = demo.calibrate(1, 1.2)  # calibration seed 1000, not the evaluated seed
    assert threshold.shape == (2,) and np.all(threshold > 0)
    d, _ = demo.run_episode(0, "elbow-gain", duration=1.4, fault_time=0.7, threshold=threshold)
    assert d.detected and 0.7 <= d.detection_time < 0.8
    assert d.label() == "elbow-gain"
    quiet, _ = demo.run_episode(0, None, duration=1.4, fault_time=0.7, threshold=threshold)
    assert not quiet.detected and quiet.label() == "no fault"


def test_the_guide_environment_example_flags_the_fault_in_info():
    """The python block of the guide's "In an environment" section, executed as printed."""
    guide = Path(__file__).resolve().parents[1] / "docs" / "guide" / "fault-detection.md"
    section = guide.read_text().split("## In an environment", 1)[1]
    source = section.split("```python\n", 1)[1].split("```", 1)[0]
    namespace = {"__name__": "__guide__"}
    exec(compile(source, str(guide), "exec"), namespace)
    fault = namespace["fault"]
    assert fault["detected"] and 1.0 <= fault["detection_time"] <= 1.2  # the motor weakens at t = 1 s
    assert fault["isolated_name"] == "elbow-gain" and fault["isolation_time"] > fault["detection_time"]
