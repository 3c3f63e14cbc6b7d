"""``control.design``: from a MuJoCo environment to an output-feedback policy, and the closed loop it runs in."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import smo_gym  # noqa: F401 - registers the environments
from smo_gym import control
from smo_gym.control.closed_loop import ExternalForce, closed_loop_metrics, parse_disturbance, run_closed_loop
from smo_gym.control.policies import ControlDiagnostics, OutputFeedbackPolicy, design, equilibrium

ARM = "smo_gym/TwoLinkArm-v0"
FURUTA = "smo_gym/FurutaPendulum-v0"
IDP = "InvertedDoublePendulum-v5"
#: (env id, make kwargs, disturbance on the actuated joints, its bounds for the design)
EXAMPLES = {
    "two-link arm": (ARM, {"frame_skip": 1}, "0.5*sin(2*t) + 0.2", {"disturbance_bound": 0.7}),
    "Furuta": (FURUTA, {"frame_skip": 1}, "0.04*sin(2.5*t) + 0.05", {"disturbance_bound": 0.09}),
    "inverted double pendulum": (
        IDP,
        {"frame_skip": 1, "reset_noise_scale": 0.02},
        "2*sin(2*t) + 1",
        {"disturbance_bound": 3.0},
    ),
}


def _run(key, controller, sensor="encoder-12bit-noisy", t_final=4.0, seed=0, **design_kwargs):
    env_id, kwargs, expr, bounds = EXAMPLES[key]
    env = gym.make(env_id, **kwargs)
    policy = design(env, controller, sensor=sensor, disturbance_bandwidth=2.5, **bounds, **design_kwargs)
    return run_closed_loop(env, policy, t_final=t_final, seed=seed, sensor=sensor, disturbance=parse_disturbance(expr))


# ---- operating point and linearization --------------------------------------------------------------------------
def test_equilibrium_holds_the_arm_against_gravity_computed_by_hand():
    """Horizontal two-link arm: the holding torques are the links' weights times their lever arms."""
    model = gym.make(ARM).unwrapped.model
    op = equilibrium(model)
    g = 9.81
    shoulder = 1.0 * g * 0.25 + 0.8 * g * (0.5 + 0.25)  # link masses at their centres (capsules along x)
    elbow = 0.8 * g * 0.25
    # the hinges turn about +y, so gravity (-z) drives them positive and the motors hold with negative torques
    np.testing.assert_allclose(op.ctrl, [-shoulder, -elbow], rtol=1e-6)
    np.testing.assert_array_equal(op.qpos, model.qpos0)


def test_equilibrium_balances_the_unactuated_joints_by_newton():
    """The double pendulum's qpos0 is off balance by ~1e-6 rad; the returned pose has no gravity torque left on
    the hinges, which the actuator (on the cart) could not hold."""
    model = gym.make(IDP).unwrapped.model
    op = equilibrium(model)
    d = mujoco.MjData(model)
    d.qpos[:] = model.qpos0
    mujoco.mj_forward(model, d)
    before = np.abs(d.qfrc_bias[1:]).max()
    d.qpos[:] = op.qpos
    mujoco.mj_forward(model, d)
    assert before > 1e-5
    assert np.abs(d.qfrc_bias[1:]).max() < 1e-9 * before * 1e4
    assert 0 < np.abs(op.qpos - model.qpos0).max() < 1e-4


def test_equilibrium_refuses_a_pose_the_actuators_cannot_hold():
    model = gym.make(FURUTA).unwrapped.model
    with pytest.raises(ValueError, match=r"unactuated joints \[.pendulum.\]"):
        equilibrium(model, [0.0, 1.0])  # the pendulum 1 rad from upright, no actuator on it
    with pytest.raises(ValueError, match="finite operating point of shape"):
        equilibrium(model, [0.0])


def test_linearize_force_dofs_is_matched_exactly_on_actuated_joints_and_equals_the_inverse_inertia():
    """A force on a joint driven by a gear-1 motor enters exactly like the motor (D = B), and (RK4 model, explicit
    Euler differentiation without implicit damping) equals the continuous-time M(q0)^-1 E."""
    model = gym.make(ARM).unwrapped.model
    op = equilibrium(model)
    plant = control.linearize(model, op.qpos, op.ctrl, force_dofs=[0, 1])
    np.testing.assert_allclose(plant.D, plant.B, atol=1e-9)
    d = mujoco.MjData(model)
    d.qpos[:] = op.qpos
    mujoco.mj_forward(model, d)
    M = np.zeros((2, 2))
    mujoco.mj_fullM(model, d, M)
    np.testing.assert_allclose(plant.D[2:], np.linalg.inv(M), rtol=1e-6)
    with pytest.raises(TypeError, match="D or force_dofs"):
        control.linearize(model, D=plant.D, force_dofs=[0])
    with pytest.raises(ValueError, match="force_dofs in"):
        control.linearize(model, force_dofs=[5])


def test_sampled_lqr_solves_the_sampled_riccati_equation_and_tends_to_the_continuous_gain():
    """The double pendulum at 10 ms (continuous design's fastest pole near -100 rad/s, one sample): the sampled gain
    satisfies the discrete Riccati equation re-checked in NumPy, is stabilizing, differs from the continuous gain by
    tens of percent, and tends to it as the step goes to zero."""
    env = gym.make(IDP, frame_skip=1)
    model = env.unwrapped.model
    op = equilibrium(model)
    plant = control.linearize(model, op.qpos, op.ctrl)
    Q, R = control.policies.default_weights(model, op.qpos, np.eye(3)[:, :1])
    dt = 0.01
    K = control.sampled_lqr(plant, dt, Q, R)
    Phi, G = plant.discretize(dt)
    P = np.eye(6)
    for _ in range(20_000):  # value iteration of the discrete Riccati equation
        P = Q * dt + Phi.T @ P @ Phi - Phi.T @ P @ G @ np.linalg.solve(R * dt + G.T @ P @ G, G.T @ P @ Phi)
    np.testing.assert_allclose(K, np.linalg.solve(R * dt + G.T @ P @ G, G.T @ P @ Phi), rtol=1e-6)
    assert np.abs(np.linalg.eigvals(Phi - G @ K)).max() < 1.0
    K_c = control.lqr(plant.A, plant.B, Q, R)
    assert np.abs(K - K_c).max() > 0.1 * np.abs(K_c).max()
    np.testing.assert_allclose(control.sampled_lqr(plant, 1e-6, Q, R), K_c, rtol=1e-3)


# ---- the design's refusals ----------------------------------------------------------------------------------------
def test_design_refuses_a_system_that_is_not_strongly_observable_and_says_why():
    env = gym.make(IDP, frame_skip=1)
    with pytest.raises(control.NotStronglyObservableError, match=r"invariant zeros|Molinari|normal rank"):
        design(env, "compensation", measured=["slider"])
    # the same outputs are enough for a Luenberger observer (observable, not strongly observable)
    assert design(env, "lqr-luenberger", measured=["slider"]).design.joints == ("slider",)


def test_design_bad_input_gives_typed_errors():
    env = gym.make(ARM)
    with pytest.raises(ValueError, match="expected controller to be one of"):
        design(env, "pd")
    with pytest.raises(TypeError, match="MuJoCo environment"):
        design(gym.make("CartPole-v1"))
    with pytest.raises(ValueError, match="joint of the model"):
        design(env, measured=["wrist"])
    with pytest.raises(ValueError, match="disturbance_bound"):
        design(env, disturbance_bound=-1.0)


def test_policy_contract_reset_first_finite_input_and_commands_within_range():
    env = gym.make(ARM)
    policy = design(env, "ism")
    assert isinstance(policy, OutputFeedbackPolicy)
    np.testing.assert_array_equal(policy.diagnostics.qpos, policy.design.operating_point.qpos)  # before reset
    with pytest.raises(RuntimeError, match="reset"):
        policy.act(np.zeros(2))
    policy.reset(np.zeros(2))
    with pytest.raises(ValueError, match="finite measured positions"):
        policy.act(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        policy.act(np.zeros(3))
    u = policy.act(np.array([1.0, -1.0]))  # far off: the command saturates
    lo, hi = env.unwrapped.model.actuator_ctrlrange.T
    assert np.all(u >= lo) and np.all(u <= hi)
    diag = policy.diagnostics
    assert isinstance(diag, ControlDiagnostics)
    assert diag.qpos.shape == diag.qvel.shape == (2,) and diag.disturbance.shape == (2,) and diag.sliding.shape == (2,)


# ---- closed loops -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", list(EXAMPLES))
@pytest.mark.parametrize("controller", ["compensation", "ism"])
def test_designed_controller_stabilizes_each_example_from_noisy_encoders(key, controller):
    """12-bit encoder with 1e-3 rad noise, a constant-plus-sinusoid disturbance, measured positions only: the loop
    stays up and regulates to within a few hundredths (the noise-limited level; the LQR with a Luenberger observer,
    biased by the disturbance, ends at 0.02-0.3 on the same runs: scripts/bench_control.py)."""
    run = _run(key, controller)
    assert not run.terminated
    m = closed_loop_metrics(run, 2.0)
    assert m["steady band"] < 0.1, m


def test_compensation_identifies_the_disturbance_with_the_order_of_the_sampling_step():
    """Noise-free encoder, arm, alpha = 2: the identification error after convergence shrinks like tau^alpha
    (Fridman's slides, section 6: identification O(tau^alpha)); measured order 1.9 over 2, 4, 8 ms."""
    errors, steps = [], []
    for frame_skip in (1, 2, 4):
        env = gym.make(ARM, frame_skip=frame_skip)
        policy = design(env, "compensation", sensor="ideal", disturbance_bound=0.7, disturbance_bandwidth=2.0)
        run = run_closed_loop(
            env, policy, t_final=3.0, seed=0, sensor="ideal", disturbance=parse_disturbance("0.5*sin(2*t) + 0.2")
        )
        sel = run.t >= 1.5
        errors.append(np.abs(run.disturbance_hat - run.disturbance)[sel].max())
        steps.append(policy.dt)
    order = control.fit_order(steps, errors)
    assert 1.5 < order < 2.5, (order, errors)
    assert errors[0] < 0.05 * 0.7  # under 5 % of the disturbance's amplitude at 2 ms


def test_compensation_beats_lqr_with_a_luenberger_observer_on_the_disturbed_arm():
    comp = closed_loop_metrics(_run("two-link arm", "compensation"), 2.0)
    base = closed_loop_metrics(_run("two-link arm", "lqr-luenberger"), 2.0)
    assert comp["steady band"] < 0.1 * base["steady band"], (comp, base)


# ---- disturbances and events ------------------------------------------------------------------------------------
def test_parse_disturbance_evaluates_arithmetic_of_t_and_nothing_else():
    f = parse_disturbance("0.5*sin(2*t) + 0.2, -step(t - 1)")
    np.testing.assert_allclose(f(0.0), [0.2, 0.0])
    np.testing.assert_allclose(f(2.0), [0.5 * np.sin(4.0) + 0.2, -1.0])
    for bad in ("__import__('os')", "t.real", "open('x')", "[t]", "'a'", "x + 1", ""):
        with pytest.raises(ValueError, match="expected"):
            parse_disturbance(bad)


@pytest.mark.parametrize("env_id", [IDP, ARM])
def test_external_force_acts_through_qfrc_applied_or_the_environments_own_input(env_id):
    """A constant force on the first joint, nothing else: the velocity change over one step equals the
    unforced one plus h M^-1 w (integrated over the step), and info reports it."""
    base, pushed = gym.make(env_id, frame_skip=1), ExternalForce(gym.make(env_id, frame_skip=1), lambda t: 2.0, [0])
    base.reset(seed=1)
    pushed.reset(seed=1)
    zero = np.zeros(base.action_space.shape)
    base.step(zero)
    _, _, _, _, info = pushed.step(zero)
    np.testing.assert_array_equal(info["disturbance"], [2.0])
    dv = pushed.unwrapped.data.qvel - base.unwrapped.data.qvel
    M = np.zeros((base.unwrapped.model.nv,) * 2)
    mujoco.mj_fullM(base.unwrapped.model, base.unwrapped.data, M)
    expected = base.unwrapped.model.opt.timestep * np.linalg.solve(M, np.eye(M.shape[0])[:, 0] * 2.0)
    np.testing.assert_allclose(dv, expected, rtol=0.05, atol=1e-9)


def test_payload_event_changes_the_mass_mid_run_and_compensation_absorbs_it():
    """The lower link gains half its mass at 1.5 s (at the environment's target pose): the change is a matched
    disturbance the cascade identifies, so the compensated arm is back on target (3e-3 rad after 2.5 s), where the
    LQR with a Luenberger observer stays 0.15 rad off. (Doubling the mass saturates the motors during the
    transient and the compensated loop does not recover within the run: a limit of the linear design.)"""
    env = gym.make(ARM, frame_skip=1)
    target = env.unwrapped.TARGET
    policy = design(env, "compensation", operating_point=target, disturbance_bound=3.0)
    run = run_closed_loop(
        env,
        policy,
        t_final=3.0,
        seed=0,
        events=((1.5, control.closed_loop.scale_body_mass("lower", 1.5)),),
    )
    assert env.unwrapped.model.body("lower").mass[0] == pytest.approx(1.2)
    np.testing.assert_array_equal(run.target, target)
    late = np.abs(run.qpos - run.target).max(axis=1)[run.t >= 2.5]
    assert late.max() < 0.02


def test_cli_runs_a_closed_loop_and_prints_the_table(capsys, tmp_path):
    from smo_gym.cli import main

    status = main(
        [
            "control",
            "--controller",
            "compensation,lqr-luenberger",
            "--frame-skip",
            "2",
            "--seconds",
            "1",
            "--no-plots",
            "--no-progress",
        ]
    )
    out = capsys.readouterr().out
    assert status == 0
    assert "compensation" in out and "lqr-luenberger" in out and "steady band" in out


def test_design_computed_torque_uses_the_operating_point_and_refuses_underactuated_models():
    env = gym.make(ARM, frame_skip=1)
    target = env.unwrapped.TARGET
    policy = design(env, "computed-torque", operating_point=target, disturbance_bound=0.7)
    assert isinstance(policy, control.ComputedTorquePolicy)
    run = run_closed_loop(env, policy, t_final=3.0, seed=0, disturbance=parse_disturbance("0.5*sin(2*t) + 0.2"))
    np.testing.assert_array_equal(run.target, target)
    assert closed_loop_metrics(run, 1.5)["steady band"] < 0.02
    with pytest.raises(control.UnderactuatedError, match="pendulum"):
        design(gym.make(FURUTA), "computed-torque")


class _PointMass(gym.Env):
    """A mass on a slide with an unlimited motor: the smallest MuJoCo environment ``design`` accepts."""

    XML = """<mujoco><option timestep="0.002"/><worldbody><body><joint name="x" type="slide" axis="1 0 0"/>
      <geom type="sphere" size="0.1" mass="1"/></body></worldbody>
      <actuator><motor joint="x" ctrllimited="false"/></actuator></mujoco>"""

    def __init__(self):
        self.model = mujoco.MjModel.from_xml_string(self.XML)
        self.dt = 0.002


def test_an_unlimited_actuator_is_not_clipped_to_its_empty_range():
    """MuJoCo stores ctrlrange (0, 0) for an unlimited actuator: the command must not be clipped to it."""
    policy = design(_PointMass(), "lqr-luenberger", sensor="ideal", disturbance_bound=1.0)
    policy.reset(np.array([0.1]))
    assert policy.act(np.array([0.1]))[0] < -1.0  # pushes back, well outside (0, 0)


def test_integral_sliding_mode_does_not_wind_up_while_the_motors_saturate():
    """From the arm's reset the target is 1.5 rad away and the motors saturate for most of a second. The sliding
    variable integrates only what the actuator delivered: without that, the integral wound up during the transient
    and the arm sat 0.009-0.011 rad off target for seconds while the unit-vector term unwound it; now it is within
    0.002-0.003 rad after 1 s, like compensation control."""
    env = gym.make(ARM, frame_skip=1)
    policy = design(env, "ism", operating_point=env.unwrapped.TARGET, disturbance_bound=0.7, disturbance_bandwidth=2.0)
    run = run_closed_loop(env, policy, t_final=3.0, seed=0, disturbance=parse_disturbance("0.5*sin(2*t) + 0.2"))
    assert np.abs(run.ctrl[run.t < 0.3]).max() == pytest.approx(10.0)  # the transient does saturate
    err = np.abs(run.qpos - run.target).max(axis=1)
    assert err[run.t >= 1.0].max() < 0.006


def test_the_guide_example_runs_as_printed(capsys):
    """The first python block of the control guide (design, closed loop, metrics) executed as printed."""
    from pathlib import Path

    guide = Path(__file__).resolve().parents[1] / "docs" / "guide" / "control.md"
    source = guide.read_text().split("```python\n", 1)[1].split("```", 1)[0]
    assert "control.design(" in source and len(source.strip().splitlines()) < 15
    exec(compile(source, str(guide), "exec"), {"__name__": "__guide__"})
    band = float(capsys.readouterr().out.split()[0])
    assert band < 0.1


def test_design_unmatched_refuses_what_the_surface_cannot_compensate_and_runs_otherwise():
    """The surface compensation of Ferreira et al. needs the disturbance reachable through the pseudo-control: a
    torque on the Furuta pendulum (no actuator) is refused with the reason; the arm's torque (matched) is handled."""
    env = gym.make(FURUTA, frame_skip=1)
    with pytest.raises(ValueError, match="compensated on the regulated output"):
        design(env, "unmatched", disturbance=["pendulum"], disturbance_bound=0.004)
    run = _run("Furuta", "unmatched")
    assert not run.terminated
    assert closed_loop_metrics(run, 2.0)["steady band"] < 0.1


def test_external_force_on_a_joint_outside_the_environments_own_input():
    """The Furuta environment's own input drives the arm; a force on the pendulum goes to qfrc_applied and stays
    there through the environment's step (which rewrites only its own channels)."""
    env = ExternalForce(gym.make(FURUTA, frame_skip=1), lambda t: [0.01, -0.002], [0, 1])
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(1))
    np.testing.assert_allclose(env.unwrapped.data.qfrc_applied, [0.01, -0.002])
    np.testing.assert_allclose(info["disturbance"], [0.01, -0.002])


def test_a_comparison_too_short_for_its_steady_window_is_refused():
    """The metrics are taken over the second half of the run: with less than two control steps in it every entry was
    inf or nan, printed as a table. Refused before any run."""
    from smo_gym.experiments.closed_loop import compare_controllers

    with pytest.raises(ValueError, match="two control steps"):
        compare_controllers("InvertedPendulum-v5", ["lqr-kalman"], t_final=0.1, seeds=[0], show_progress=False)


def test_kalman_baseline_with_an_exact_sensor_is_refused_in_designs_terms():
    """The Kalman baseline weighs samples by the sensor's error variance; an ideal sensor has none. The refusal came
    from KalmanObserver, naming ``noise_std``, an argument the caller of design never gave; it now names the
    sensor, the joints it measures exactly and what to use instead, and every other controller still designs."""
    env = gym.make("smo_gym/TwoLinkArm-v0", frame_skip=1)
    with pytest.raises(ValueError, match=r"sensor 'ideal' measures \['shoulder', 'elbow'\] exactly.*lqr-luenberger"):
        design(env, "lqr-kalman", sensor="ideal")
    assert design(env, "lqr-luenberger", sensor="ideal").name == "lqr-luenberger"
    assert design(env, "lqr-kalman", sensor="encoder-12bit").name == "lqr-kalman"  # quantization: Delta^2/12


def test_a_run_that_mujoco_reset_is_a_failed_run():
    """A disturbance of 1e300 N made MuJoCo reset the simulation at every step (a printed warning only), and the
    comparison reported a steady band *better* than without it (0.0017 against 0.0074). Such a run fell."""
    from smo_gym.experiments.closed_loop import compare_controllers

    rows, _ = compare_controllers("InvertedPendulum-v5", ["lqr-luenberger"], t_final=0.4, disturbance="1e300")
    assert rows[0]["fell"] == "1/1" and rows[0]["steady band"] == np.inf
    rows, _ = compare_controllers("InvertedPendulum-v5", ["lqr-luenberger"], t_final=0.4)
    assert rows[0]["fell"] == "0/1" and np.isfinite(rows[0]["steady band"])


def test_comparison_arguments_are_checked_before_any_run():
    """A NaN payload time was never reached (the run was the undisturbed one), empty seeds gave a row of inf, a
    controller name as a string was read letter by letter, and summarize divided by a baseline's zero band."""
    from smo_gym.experiments.closed_loop import compare_controllers, summarize

    cases = [
        (dict(payload=(float("nan"), "pole", 100.0)), ValueError, "event time"),
        (dict(payload=(0.1,)), ValueError, "payload"),
        (dict(seeds=[]), ValueError, "seed"),
        (dict(t_final=10**400), ValueError, "t_final"),
    ]
    for kwargs, error, match in cases:
        with pytest.raises(error, match=match):
            compare_controllers("InvertedPendulum-v5", ["lqr-luenberger"], **{"t_final": 0.4, **kwargs})
    with pytest.raises(TypeError, match="sequence of names"):
        compare_controllers("InvertedPendulum-v5", "pid", t_final=0.4)
    rows = [
        {"controller": "lqr-luenberger", "steady band": 0.0, "effort RMS": 0.0},
        {"controller": "ism", "steady band": 0.1, "effort RMS": 1.0},
    ]
    assert summarize(rows)[0]["band / best baseline"] == np.inf
    f = parse_disturbance("t")
    with pytest.raises(ValueError, match="t to be finite"):
        f(10**400)
    with pytest.raises(ValueError, match="nested less deeply"):
        parse_disturbance("+".join(["t"] * 100000))


def test_equilibrium_and_default_weights_refuse_what_is_not_a_finite_configuration():
    model = gym.make(ARM).unwrapped.model
    with pytest.raises(TypeError, match="expected qpos to be an array of real numbers"):
        equilibrium(model, [True, False])
    with pytest.raises(TypeError, match=r"expected model to be a mujoco\.MjModel"):
        equilibrium(None)
    with pytest.raises(ValueError, match=r"expected qpos finite with shape \(2,\)"):
        control.policies.default_weights(model, [np.nan, 0.0], np.eye(2))


def test_differentiator_bound_refuses_bad_bounds_and_an_unstable_error_map():
    """A NaN noise bound or an error map with spectral radius >= 1 ran 200,000 iterations into NaN."""
    plant = control.furuta_slides()
    Ld = control.sampled_observer_gain(plant.A, plant.C, 0.01)
    bound = control.policies.differentiator_bound
    ok = bound(plant, 0.01, Ld, 2, (1.0, 1.0, 1.0), [1e-3, 1e-3])
    assert np.isfinite(ok).all()
    np.testing.assert_array_equal(bound(plant, 0.01, Ld, 2, 1.0, [1e-3, 1e-3]), ok)  # one bound for every i
    for noise in ([np.nan, 1e-3], [-1.0, -1.0]):
        with pytest.raises(ValueError, match="expected noise_bound >= 0"):
            bound(plant, 0.01, Ld, 2, (1.0, 1.0, 1.0), noise)
    with pytest.raises(ValueError, match=r"expected L_d making the error map Phi \(I - L_d C\) stable"):
        bound(plant, 0.01, np.zeros((4, 2)), 2, (1.0, 1.0, 1.0), [1e-3, 1e-3])
    with pytest.raises(ValueError, match=r"expected L_d with shape \(4, 2\)"):
        bound(plant, 0.01, np.zeros((2, 2)), 2, (1.0,), [1e-3, 1e-3])
    with pytest.raises(ValueError, match="expected w_bounds with at least one entry"):
        bound(plant, 0.01, Ld, 2, (), [1e-3, 1e-3])
    with pytest.raises(TypeError, match="expected order to be an integer"):
        bound(plant, 0.01, Ld, 2.5, (1.0,), [1e-3, 1e-3])


def test_policy_act_refuses_bools_strings_and_complex_positions():
    policy = design(gym.make(ARM), "lqr-luenberger")
    twin = design(gym.make(ARM), "lqr-luenberger")
    for p in (policy, twin):
        p.reset(np.zeros(2))
    for q in ([True, False], ["0.1", "0"], np.array([0.1 + 1j, 0.0])):
        with pytest.raises(TypeError, match="expected qpos_measured to be an array of real numbers"):
            policy.act(q)
    np.testing.assert_array_equal(policy.act(np.array([0.1, 0.0])), twin.act(np.array([0.1, 0.0])))
