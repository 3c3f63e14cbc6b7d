"""Control, fault detection and identification: a refused call changes nothing, and NaN never passes silently.

Each case was found by fuzzing the public API: a call raised after part of its state had moved (a retry then
gave other numbers), a NaN was taken and stayed in an estimate, an integral or a metric, or an expression ran for
minutes.
"""

from __future__ import annotations

import copy
import time

import gymnasium as gym
import numpy as np
import pytest

from smo_gym import DivergenceError
from smo_gym import control as c
from smo_gym.control.closed_loop import ExternalForce, parse_disturbance
from smo_gym.control.finite_time import settling_time
from smo_gym.control.simulation import fit_order
from smo_gym.fault_detection import FaultObserverBank, diagnose
from smo_gym.identification import EquivalentInjectionIdentifier, LeastSquaresIdentifier
from smo_gym.selection import ratio_bound


def test_disturbance_expressions_evaluate_in_floats_and_are_checked_when_parsed():
    start = time.perf_counter()
    with pytest.raises(ValueError, match="OverflowError"):  # integer powers ran for minutes (a Python big int)
        parse_disturbance("9**9**9")
    assert time.perf_counter() - start < 1.0
    for expr, message in (
        ("sin(t, t)", "evaluate at t = 0.0"),
        ("minimum(t)", "evaluate at t = 0.0"),
        ("(1, (2, 3))", "evaluate at t = 0.0"),
        ("1/t", "ZeroDivisionError"),
        ("log(t - 1)", "finite numbers"),
        ("True", "numbers only"),
    ):
        with pytest.raises(ValueError, match=message):
            parse_disturbance(expr)
    f = parse_disturbance("0.5*sin(2*t) + 0.2, 2**3")
    np.testing.assert_allclose(f(1.0), [0.5 * np.sin(2.0) + 0.2, 8.0])
    with pytest.raises(ValueError, match=r"finite numbers at t = -1\.0"):
        parse_disturbance("sqrt(t)")(-1.0)


def nominal(q, v, u):
    return -9.81 * np.sin(q) - 0.2 * v + u


def diverging_fault(q, v, u):
    """A fault model that breaks down for large inputs (its observer refuses the sample)."""
    return np.full_like(q, np.nan) if np.any(np.asarray(u) > 5) else 0 * q


def test_a_bank_whose_later_model_refuses_a_sample_asks_for_a_reset():
    """The nominal observer had taken the sample the fault model's observer refused: a retry went on from two
    different instants (residuals 83.7 against a clean bank's 71.4), silently."""
    bank = FaultObserverBank(1e-3, nominal, [lambda q, v, u: -0.5 * u, diverging_fault], 0.1, lipschitz=30.0, n=1)
    bank.reset([0.0])
    for k in range(5):
        bank.update([1e-3 * k], [0.0])
    with pytest.raises(Exception, match="expected"):
        bank.update([5e-3], [10.0])
    with pytest.raises(RuntimeError, match="model 2 refused a sample the models before it had taken"):
        bank.update([5e-3], [0.0])
    bank.reset([0.0])  # and a reset starts it again
    assert bank.update([1e-3], [0.0]).shape == (3,)


def test_the_identifier_refuses_a_non_finite_regressor_before_anything_steps():
    bad = {"now": False}

    def regressor(t, q, v, u):
        out = np.stack([v], -1)
        return out * np.nan if bad["now"] else out

    ident = EquivalentInjectionIdentifier(1e-3, lambda t, q, v, u: nominal(q, v, u), regressor, [0.0], n=1,
                                          lipschitz=30.0)  # fmt: skip
    twin = copy.deepcopy(ident)
    for identifier in (ident, twin):
        identifier.reset([0.0], v0=[0.5])
    y = np.cumsum(np.full(60, 5e-4))
    for k in range(50):
        np.testing.assert_array_equal(ident.update([y[k]], [0.1]), twin.update([y[k]], [0.1]))
    bad["now"] = True
    with pytest.raises(ValueError, match="finite regressor"):
        ident.update([y[50]], [0.1])
    bad["now"] = False
    for k in range(50, 60):  # as if the refused call never happened (it broke every later update before)
        np.testing.assert_array_equal(ident.update([y[k]], [0.1]), twin.update([y[k]], [0.1]))


def test_least_squares_refuses_an_overflowing_update_and_keeps_its_state():
    ls = LeastSquaresIdentifier(2, 0.01)
    ls.reset()
    ls.update(np.eye(2), [1.0, 2.0])
    before = (ls.estimate, ls.information)
    with pytest.raises(ValueError, match="overflows"):
        ls.update(np.full((2, 2), 1e200), [1.0, 1.0])
    np.testing.assert_array_equal(ls.estimate, before[0])
    np.testing.assert_array_equal(ls.information, before[1])


def test_the_ltv_observer_refuses_a_covariance_step_before_changing_it():
    """``P`` and ``z`` were overwritten before the positive-definiteness check raised: each retry drifted further
    (minimum eigenvalue -9, then -19)."""
    plant, w, x0 = c.ltv_example()
    _t, _X, Y, _U = c.simulate_ltv(plant, x0, 0.2, 1e-3, w=w)
    obs = c.CascadedLTVObserver(plant, 1e-3, 100.0, Q=lambda t: 1e4 * np.eye(3), forgetting=0.0)
    obs.reset(Y[0])
    with pytest.raises(RuntimeError, match="positive definite"):
        for y in Y:
            obs.update(y)
            obs.advance()
    z, P, t = obs.z.copy(), obs.P.copy(), obs.t
    for _ in range(2):
        with pytest.raises(RuntimeError, match="positive definite"):
            obs.advance()
        np.testing.assert_array_equal(obs.z, z)
        np.testing.assert_array_equal(obs.P, P)
        assert obs.t == t


def oscillator(k: float) -> c.LinearPlant:
    """x1' = x2, x2' = -k x1 - 0.5 x2 + u + w, position measured."""
    return c.LinearPlant([[0, 1], [-k, -0.5]], [[0], [1]], [[1, 0]], [[0.0], [1.0]])


def test_a_refused_sample_or_reset_leaves_the_switched_observer_as_it_was():
    """The sample counter moved before the measurement was refused (the next switch was then recorded one
    sample late), and a refused reset left its mode set."""
    system = c.SwitchedLinearSystem([oscillator(1.0), oscillator(9.0)])
    obs, twin = (c.SwitchedHOSMObserver(system, 1e-3, 300.0) for _ in range(2))
    for o in (obs, twin):
        o.reset([0.1], 0)
        o.advance([0.0])
    with pytest.raises(ValueError):
        obs.update([np.nan], 1)
    for k in range(1, 4):
        np.testing.assert_array_equal(obs.update([0.1 + 1e-4 * k], 1), twin.update([0.1 + 1e-4 * k], 1))
        obs.advance([0.0])
        twin.advance([0.0])
    assert obs.switch_samples == twin.switch_samples == [1]
    fresh = c.SwitchedHOSMObserver(system, 1e-3, 300.0)
    with pytest.raises(ValueError):
        fresh.reset([np.nan], 1)
    assert fresh.mode is None


def test_a_refused_reset_keeps_the_previous_one_and_nan_is_refused():
    plant = oscillator(1.0)
    utkin = c.UtkinObserver(plant.A, plant.B, plant.C, 0.01, 5.0)
    utkin.reset([[1.0], [2.0]])
    with pytest.raises(ValueError, match="finite"):
        utkin.reset([[np.nan], [2.0]])
    assert utkin.update([[1.1], [2.1]]).shape == (2, 2)  # the previous reset is kept (it was wiped)
    with pytest.raises(ValueError, match="finite measurements"):
        utkin.update([[np.nan], [2.1]])
    luenberger = c.LuenbergerObserver(plant, 0.01)
    luenberger.reset([0.0])
    with pytest.raises(ValueError, match="x_hat0"):
        luenberger.reset([0.0], x_hat0=[np.nan, 0.0])
    luenberger.update([0.1])
    with pytest.raises(ValueError, match="finite u"):
        luenberger.advance(np.nan)
    assert np.isfinite(luenberger.x_hat).all()
    hosm = c.CascadedHOSMObserver(plant, 0.01, 100.0)
    hosm.reset([0.0])
    hosm.update([0.0])
    with pytest.raises(ValueError, match="finite u"):  # it stayed in the prediction, and every later sample failed
        hosm.advance([np.nan])
    held = c.CascadedHOSMObserver(plant, 0.01, 100.0, injection="held")
    held.reset([0.0])
    with pytest.raises(RuntimeError, match="update"):  # was an AttributeError
        held.advance([0.0])


def test_controllers_refuse_nan_before_their_state_moves():
    plant = oscillator(1.0)
    feedback = c.StateFeedback(c.LuenbergerObserver(plant, 0.01), Q=np.eye(2), R=np.eye(1))
    feedback.reset([0.1])
    for limits in ((np.nan, np.nan), (1.0, -1.0), ([0.0, 1.0], 1.0)):
        with pytest.raises(ValueError, match="limits"):
            feedback.step([0.1], 0.0, limits=limits)
    assert np.isfinite(feedback.step([0.1], 0.0, limits=(-1.0, 1.0))).all()
    pid = c.PIDController(plant, 0.01)
    pid.reset([0.0])
    with pytest.raises(ValueError, match="finite"):  # a NaN stayed in the integral for good
        pid.step([np.nan], 0.0)
    assert np.isfinite(pid.step([0.1], 0.01)).all()


def test_metrics_do_not_read_nan_as_good():
    with pytest.raises(ValueError, match="NaN at sample 2"):  # compares as in the band: "no fault"
        diagnose(np.array([[0.5, 2.0], [0.5, 2.0], [np.nan, 2.0]]), 0.01, dwell=0.01)
    assert settling_time(np.arange(5.0), [1.0, 0.1, np.nan, np.nan, np.nan], 0.5) == np.inf  # was 1.0: settled
    with pytest.raises(ValueError, match="tol"):
        settling_time(np.arange(3.0), [1.0, 0.1, 0.1], np.nan)
    with pytest.raises(ValueError, match="shapes"):
        settling_time(np.arange(3.0), [1.0, 0.1], 0.5)
    with pytest.raises(ValueError, match="two steps or more"):  # a slope from one point was 0.5
        fit_order([0.1], [0.1])
    with pytest.raises(ValueError, match="> 0"):
        fit_order([0.1, -0.2], [0.1, 0.2])
    assert fit_order([0.1, 0.2, 0.4], [0.01, 0.04, 0.16]) == pytest.approx(2.0)
    squared = np.ones((2, 4, 1))
    squared[1, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN or negative"):  # read as a ratio of 1
        ratio_bound(squared, [0])


def test_environments_refuse_nan_instead_of_mujoco_replacing_it():
    """MuJoCo replaces a NaN control by 0 and resets a simulation a NaN force made diverge, with a warning only:
    the episode went on from the start, not terminated, with a finite reward."""
    env = gym.make("smo_gym/TwoLinkArm-v0", disturbance=lambda t: [np.nan, 0.0] if t > 0.05 else [0.0, 0.0])
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite disturbance at t"):
        for _ in range(20):
            env.step(np.zeros(2))
    env = gym.make("smo_gym/TwoLinkArm-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite action"):
        env.unwrapped.step(np.array([np.nan, 0.0]))
    for kwargs, message in ((dict(frame_skip=0), "frame_skip"), (dict(frame_skip=-1), "frame_skip"),
                            (dict(reset_noise_scale=np.nan), "reset_noise_scale")):  # fmt: skip
        with pytest.raises(ValueError, match=message):
            gym.make("smo_gym/TwoLinkArm-v0", **kwargs)


def test_an_external_force_on_the_disturbance_joints_adds_to_the_constant_one():
    """It replaced the constant of ``set_disturbance`` on the joints it does not push."""
    env = gym.make("smo_gym/TwoLinkArm-v0")
    env.unwrapped.set_disturbance([0.3, 0.0])
    pushed = ExternalForce(env, lambda t: [0.2], dofs=[1])
    pushed.reset(seed=0)
    pushed.step(np.zeros(2))
    np.testing.assert_array_equal(env.unwrapped.data.qfrc_applied, [0.3, 0.2])
    np.testing.assert_array_equal(env.unwrapped.constant_disturbance, [0.3, 0.0])


def test_computed_torque_design_defaults_to_the_measured_joints_target():
    """With a joint coupled by an equality (VariableInertia's bead) the default target had every joint's qpos0."""
    policy = c.design(gym.make("smo_gym/VariableInertia-v0"), "computed-torque")
    np.testing.assert_array_equal(policy.target, [0.0])


def test_options_that_were_ignored_or_inverted_are_refused():
    """``cancel_drift="no"`` and ``feedforward="False"`` became True, a NaN ``t_start`` switched compensation off
    for good, negative noise levels and time constants were ignored, a negative ``dt`` gave matrices."""
    plant = oscillator(1.0)
    hosm = c.CascadedHOSMObserver(plant, 0.01, 100.0)
    cases = [
        (lambda: c.CompensationController(hosm, Q=np.eye(2), R=np.eye(1), t_start=np.nan), ValueError, "t_start"),
        (lambda: c.UnmatchedCompensationController(hosm, feedforward="False"), TypeError, "feedforward"),
        (lambda: c.FiniteTimeStabilizer(hosm, alpha=1.0, cancel_drift="no"), TypeError, "cancel_drift"),
        (lambda: plant.discretize(-0.01), ValueError, "dt > 0"),
        (lambda: plant.discretize(0.01, actuator_tau=-1.0), ValueError, "actuator_tau"),
        (lambda: c.sampled_observer_gain(plant.A, plant.C, -0.01), ValueError, "dt > 0"),
        (lambda: c.output_error_lipschitz(plant, 2, e_bound=-1.0), ValueError, "e_bound"),
        (
            lambda: c.simulate_chain(lambda z, t: 0 * z[..., 0], [1.0, 0.0], 0.01, 0.1, substeps=0),
            ValueError,
            "substeps",
        ),
    ]
    feedback = c.StateFeedback(c.LuenbergerObserver(plant, 0.01), Q=np.eye(2), R=np.eye(1))
    for option in (dict(noise_std=-1.0), dict(noise_std=np.nan), dict(resolution=np.nan), dict(w_step=-1.0)):
        cases.append((lambda option=option: c.simulate(plant, feedback, t_final=0.1, **option), ValueError, "expected"))
    for make, error, message in cases:
        with pytest.raises(error, match=message):
            make()


def test_shapes_and_types_give_typed_errors_not_index_errors():
    plant = oscillator(1.0)
    utkin = c.UtkinObserver(plant.A, plant.B, plant.C, 0.01, 5.0)
    cases = [
        (lambda: c.left_annihilator([[1.0], [np.nan]]), ValueError),
        (lambda: c.left_annihilator([1.0, 2.0]), ValueError),
        (lambda: c.default_integral_outputs(np.eye(2)), TypeError),
        (lambda: c.simulate_chain(lambda z, t: 0 * z[..., 0], 1.0, 0.01, 0.1), ValueError),
        (lambda: c.total_variation_rate([], []), ValueError),
        (lambda: utkin.run(np.zeros((5, 1)), u=np.zeros((2, 1))), ValueError),
        (lambda: c.PIDController(plant, 0.01, integral_outputs=[7]), ValueError),
    ]
    for make, error in cases:
        with pytest.raises(error, match="expected"):
            make()


def test_indices_names_and_counts_are_not_coerced():
    """``ExternalForce(dofs=[0.9])`` pushed dof 0, an unknown body's mass event raised a bare KeyError in the
    middle of a run, string matrices were converted."""
    env = gym.make("smo_gym/TwoLinkArm-v0")
    with pytest.raises(TypeError, match="integer qvel addresses"):
        ExternalForce(env, lambda t: [0.2], dofs=[0.9])
    with pytest.raises(ValueError, match="expected a body of the model"):
        c.scale_body_mass("nobody", 2.0)(env)
    with pytest.raises(TypeError, match="LinearPlant"):
        c.default_integral_outputs("plant")
    with pytest.raises(TypeError, match="A to be an array of real numbers"):
        c.LinearPlant([["1", "0"], ["0", "1"]], [[0], [1]], [[1, 0]], [[0], [1]])


def test_structure_helpers_refuse_what_their_decompositions_cannot_take():
    """NaN entries reached an SVD ('SVD did not converge', a LinAlgError), a B without columns a reduction over an
    empty array, and zero derivative blocks numpy's 'need at least one array'."""
    from smo_gym.control.finite_time import sliding_output
    from smo_gym.control.ltv import input_map, kratz_liebscher_matrices

    with pytest.raises(ValueError, match="expected finite A and B"):
        sliding_output([[np.nan, 1.0], [0.0, 0.0]], [0.0, 1.0])
    with pytest.raises(ValueError, match="at least one input"):
        sliding_output(np.eye(2), np.zeros((2, 0)))
    with pytest.raises(ValueError, match="expected a finite J"):
        input_map(np.eye(2), np.full((2, 1), np.nan), 1)
    with pytest.raises(ValueError, match="expected blocks >= 1"):
        kratz_liebscher_matrices(np.zeros((3, 2, 2)), np.zeros((3, 1, 2)), np.zeros((3, 2, 1)), 0)


def test_ltv_times_and_matrices_of_the_wrong_type_are_named():
    """``t=True`` was time 1; ``t="x"`` and a matrix entry beyond a float's range escaped as NumPy's own
    ValueError and OverflowError."""
    from smo_gym.control.ltv import LTVPlant, ltv_strong_observability

    plant = LTVPlant([[0.0, 1.0], [0.0, 0.0]], None, [[1.0, 0.0]], [[0.0], [1.0]])
    for t in (True, "x"):
        with pytest.raises(TypeError, match="expected t"):
            ltv_strong_observability(plant, t)
    with pytest.raises(ValueError, match="within a float's range"):
        LTVPlant([[10**400]], None, [[1.0]], [[1.0]])


def _oscillator():
    return c.LinearPlant([[0.0, 1.0], [-1.0, -0.5]], [[0.0], [1.0]], [[1.0, 0.0]], [[0.0], [1.0]])


def test_a_controller_step_refused_before_the_observer_takes_the_sample():
    """``step(y, None)`` raised from ``t >= t_start`` after the observer had taken ``y`` (the next commands then
    differed from a twin's by 1.26), a NaN time skipped the compensation, and a ``K`` of three columns for two
    states was accepted until the first step's matmul."""
    plant = _oscillator()
    a, b = (c.CompensationController(c.LuenbergerObserver(plant, 0.01)) for _ in range(2))
    for ctl in (a, b):
        ctl.reset([0.1])
    for bad_t, error in ((None, TypeError), (np.nan, ValueError)):
        with pytest.raises(error, match="expected t"):
            a.step([0.12], bad_t)
    for k in range(1, 4):
        np.testing.assert_array_equal(a.step([0.1 + 0.01 * k], 0.01 * k), b.step([0.1 + 0.01 * k], 0.01 * k))
    with pytest.raises(ValueError, match=r"expected K with shape \(1x2\)"):
        c.StateFeedback(c.LuenbergerObserver(plant, 0.01), K=[[1.0, 2.0, 3.0]])
    with pytest.raises(TypeError, match="expected K"):
        c.StateFeedback(c.LuenbergerObserver(plant, 0.01), K=[[True, False]])
    with pytest.raises(TypeError, match="expected an observer of a LinearPlant"):
        c.StateFeedback("observer")


def test_observer_gains_refuse_what_they_cannot_place():
    """The held injection took poles in the right half-plane (its error dynamics then had eigenvalues 1 and 2);
    bool and string bounds and matrices were read as numbers; scipy's refusals arrived in its own words."""
    plant = _oscillator()
    with pytest.raises(ValueError, match="negative real parts"):
        c.CascadedHOSMObserver(plant, 0.01, 100.0, injection="held", poles=[1.0, 2.0])
    for bad in (True, "100"):
        with pytest.raises(TypeError, match="expected lipschitz"):
            c.CascadedHOSMObserver(plant, 0.01, bad)
    with pytest.raises(TypeError, match="poles to be numbers"):
        c.sampled_observer_gain(plant.A, plant.C, 0.01, poles=[True, False])
    with pytest.raises(ValueError, match="negative real parts"):  # NumPy reads a bool among floats as 1.0
        c.sampled_observer_gain(plant.A, plant.C, 0.01, poles=[True, -2.0])
    with pytest.raises(TypeError, match="expected A"):
        c.sampled_observer_gain(np.eye(2, dtype=bool), plant.C, 0.01)
    with pytest.raises(ValueError, match="expected poles the output can place"):
        c.sampled_observer_gain(np.eye(2), [[1.0, 0.0]], 0.01, poles=[-1.0, -1.0])


def test_a_luenberger_estimate_leaving_the_floats_is_refused_with_the_state_kept():
    """The estimate went to -inf, then NaN, without an error."""
    obs = c.LuenbergerObserver(_oscillator(), 0.01)
    obs.reset([0.0], x_hat0=[1.7e308, 0.0])
    with pytest.raises(DivergenceError, match="state was kept"):
        obs.update([-1.7e308])
    np.testing.assert_array_equal(obs.x_hat, [1.7e308, 0.0])


def test_simulation_helpers_refuse_what_they_would_misread():
    """``x0=[1.0]`` was copied into every state; a NaN control or a decreasing time gave a number."""
    plant = _oscillator()
    ctl = c.StateFeedback(c.LuenbergerObserver(plant, 0.01))
    with pytest.raises(ValueError, match=r"x0 of shape \(2,\)"):
        c.simulate(plant, ctl, t_final=0.02, x0=[1.0])
    with pytest.raises(ValueError, match="increasing t"):
        c.total_variation_rate([0.0, 1.0, 2.0], [0.0, 5.0, 1.0])
    with pytest.raises(ValueError, match="finite u"):
        c.total_variation_rate([0.0, np.nan, 1.0], [0.0, 1.0, 2.0])


def test_lqr_and_regular_form_say_what_is_wrong():
    """An unstabilizable pair or a singular R raised scipy's LinAlgError and ValueError words, a negative Q gave a
    gain for a cost that is not one, a 1-D B an IndexError, a B without columns the identity."""
    from smo_gym.control.controllers import regular_form

    with pytest.raises(ValueError, match="expected \\(A, B\\) stabilizable"):
        c.lqr([[1.0, 0.0], [0.0, 1.0]], [[0.0], [1.0]])
    for kwargs, what in (({"Q": -np.eye(2)}, "Q symmetric positive semi-definite"), ({"R": 0.0}, "R symmetric")):
        with pytest.raises(ValueError, match=what):
            c.lqr([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], **kwargs)
    with pytest.raises(ValueError, match=r"B of shape \(n, q\)"):
        regular_form(np.zeros((2, 0)))
    with pytest.raises(ValueError, match="finite entries in B"):
        regular_form([[np.nan], [1.0]])


def test_simulation_arguments_are_checked_before_the_run():
    """A plant that is not one raised AttributeError, a string seed NumPy's SeedSequence error, a horizon of 1e300
    'Maximum allowed size exceeded'; steady_state_error took index 5 of two states into an IndexError, 0.5 as an
    index, and reported an empty index list as 't0 after the record's end'."""
    plant = _oscillator()
    ctl = c.StateFeedback(c.LuenbergerObserver(plant, 0.01))
    with pytest.raises(TypeError, match="expected a LinearPlant"):
        c.simulate("plant", ctl, t_final=0.02)
    with pytest.raises(TypeError, match="expected seed"):
        c.simulate(plant, ctl, t_final=0.02, seed="a")
    with pytest.raises(ValueError, match="expected at most"):
        c.simulate(plant, ctl, t_final=1e300)
    with pytest.raises(TypeError, match="expected a LinearPlant"):
        c.output_error_lipschitz("plant", 2)
    result = c.simulate(plant, ctl, t_final=0.05, x0=[0.1, 0.0])
    for indices in ([5], [0.5], []):
        with pytest.raises(ValueError, match="expected indices"):
            c.steady_state_error(result, 0.0, indices)
    assert c.steady_state_error(result, 0.0, [0]) == pytest.approx(np.abs(result.x[:, 0]).max())


def test_a_regulated_output_that_is_not_a_finite_matrix_of_the_state_is_refused():
    """NaN entries reached LAPACK (a LinAlgError and 'DLASCL illegal value' lines on stderr); a row of the wrong
    length a matmul error."""
    heli = c.helicopter_slides()
    observer = c.CascadedHOSMObserver(heli, 1e-3, 10.0)
    n = heli.n
    for regulated, what in (([[np.nan] * n], "finite entries in regulated"), ([[1.0] * (n + 1)], "regulated")):
        with pytest.raises(ValueError, match=what):
            c.UnmatchedCompensationController(observer, rho=0.5, regulated=regulated)
