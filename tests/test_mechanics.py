"""MujocoDynamics: model terms against MuJoCo itself, the exact elimination of joint couplings, mismatch."""

from __future__ import annotations

import copy

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from smo_gym.mechanics import MujocoDynamics
from smo_gym.observers import Dynamics


@pytest.fixture(scope="module")
def arm():
    return gym.make("smo_gym/TwoLinkArm-v0").unwrapped


@pytest.fixture(scope="module")
def pendulum():
    return gym.make("smo_gym/VariableInertia-v0").unwrapped


def test_protocol_and_private_data(arm):
    dyn = MujocoDynamics(arm.model)
    assert isinstance(dyn, Dynamics)
    assert dyn.data is not arm.data and dyn.model is not arm.model
    arm.reset(seed=0)
    before = (arm.data.qpos.copy(), arm.data.qvel.copy(), arm.data.qacc.copy())
    dyn.acceleration(np.array([1.0, -1.0]), np.array([3.0, 2.0]), np.array([1.0, 1.0]))
    dyn.inertia(np.array([0.2, 0.3]))
    for a, b in zip(before, (arm.data.qpos, arm.data.qvel, arm.data.qacc), strict=False):
        np.testing.assert_array_equal(a, b)


def test_acceleration_and_inertia_match_mujoco(arm):
    m, d = arm.model, arm.data
    dyn = MujocoDynamics(m)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q, v, u = rng.normal(size=2), 3 * rng.normal(size=2), rng.uniform(-5, 5, size=2)
        d.qpos[:], d.qvel[:], d.ctrl[:] = q, v, u
        d.qfrc_applied[:] = 0.0
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(dyn.acceleration(q, v, u), d.qacc, rtol=1e-10, atol=1e-10)
        M = np.zeros((2, 2))
        mujoco.mj_fullM(m, d, M)
        np.testing.assert_allclose(dyn.inertia(q), M, rtol=1e-12)
        t = dyn.terms(q, v, u)
        # f = M^-1 (actuator + passive - bias), term by term
        np.testing.assert_allclose(
            np.linalg.solve(t["inertia"], t["actuator"] + t["passive"] - t["bias"]),
            t["acceleration"],
            rtol=1e-9,
            atol=1e-9,
        )


def test_batched_equals_loop(arm):
    dyn = MujocoDynamics(arm.model)
    rng = np.random.default_rng(1)
    q, v, u = rng.normal(size=(3, 2, 2)), rng.normal(size=(3, 2, 2)), rng.normal(size=(3, 2, 2))
    out = dyn.acceleration(q, v, u)
    assert out.shape == (3, 2, 2)
    for i in range(3):
        for j in range(2):
            np.testing.assert_allclose(out[i, j], dyn.acceleration(q[i, j], v[i, j], u[i, j]))
    assert dyn.inertia(q).shape == (3, 2, 2, 2)


def test_mass_mismatch_scales_inertia_not_gravity_acceleration(arm):
    exact, heavy = MujocoDynamics(arm.model), MujocoDynamics(arm.model, mass_scale=1.1, damping_scale=0.0)
    q = np.array([0.4, -0.9])
    np.testing.assert_allclose(heavy.inertia(q), 1.1 * exact.inertia(q), rtol=1e-12)
    # gravity-only motion (no velocity, no damping force, no input) is mass-independent
    free = MujocoDynamics(arm.model, damping_scale=0.0)
    np.testing.assert_allclose(heavy.acceleration(q, np.zeros(2)), free.acceleration(q, np.zeros(2)), rtol=1e-10)
    # a torque accelerates the heavier model 1/1.1 as much
    du = heavy.acceleration(q, np.zeros(2), np.array([1.0, 0.0])) - heavy.acceleration(q, np.zeros(2))
    du0 = free.acceleration(q, np.zeros(2), np.array([1.0, 0.0])) - free.acceleration(q, np.zeros(2))
    np.testing.assert_allclose(du, du0 / 1.1, rtol=1e-10)


def test_set_mass_scale_is_the_constructor_s_mismatch_from_the_nominal_model(arm):
    """A new scale replaces the old one (it does not compound) and equals building with it, bit for bit."""
    dyn, built = MujocoDynamics(arm.model, mass_scale=0.8), MujocoDynamics(arm.model, mass_scale=1.3)
    dyn.set_mass_scale(1.3)
    assert dyn.mass_scale == built.mass_scale == 1.3
    np.testing.assert_array_equal(dyn.model.body_mass, 1.3 * arm.model.body_mass)
    np.testing.assert_array_equal(dyn.model.body_inertia, 1.3 * arm.model.body_inertia)
    q, v, u = np.array([0.4, -0.9]), np.array([1.5, -2.0]), np.array([0.3, -0.1])
    np.testing.assert_array_equal(dyn.acceleration(q, v, u), built.acceleration(q, v, u))
    dyn.set_mass_scale(1.0, inertia_scale=2.0)
    np.testing.assert_array_equal(dyn.model.body_mass, arm.model.body_mass)
    np.testing.assert_array_equal(dyn.model.body_inertia, 2.0 * arm.model.body_inertia)
    with pytest.raises(ValueError, match="mass_scale > 0"):
        dyn.set_mass_scale(-1.0)
    # far out of range MuJoCo's inertia matrix is singular and the accelerations NaN or 1e14 and more
    with pytest.raises(ValueError, match=r"expected mass_scale in \[0.001, 1000\]"):
        dyn.set_mass_scale(1e100)
    with pytest.raises(ValueError, match=r"expected inertia_scale in \[0.001, 1000\]"):
        dyn.set_mass_scale(1.0, inertia_scale=1e-20)


def test_coupling_elimination_inertia_and_alpha_analytic(pendulum):
    """r = 0.2 + 0.3 th^2 (bead of mass 1): M(th) - M(0) = (r^2 + r'^2) - r0^2, alpha = -M'/(2M)."""
    dyn = MujocoDynamics(pendulum.model)
    assert dyn.n == 1
    M0 = dyn.inertia(np.array([0.0]))[0, 0]
    for th in (-1.1, 0.3, 0.8):
        r, rp, rpp = 0.2 + 0.3 * th**2, 0.6 * th, 0.6
        M = dyn.inertia(np.array([th]))[0, 0]
        assert pytest.approx(r**2 + rp**2 - 0.04, rel=1e-9) == M - M0
        dM = 2.0 * rp * (r + rpp)
        assert dyn.self_quadratic_coefficient(np.array([th]))[0] == pytest.approx(-dM / (2 * M), rel=1e-6)


def test_coupling_elimination_matches_simulated_trajectory(pendulum):
    """The rigid reduction predicts MuJoCo's (soft-constraint) motion: measured rms error 0.1 % of the rms
    acceleration; bound 1 %."""
    m, d = pendulum.model, pendulum.data
    dyn = MujocoDynamics(m)
    pendulum.reset(seed=0)
    rng = np.random.default_rng(0)
    acc_fd, model = [], []
    u = np.zeros(1)
    for k in range(1500):
        if k % 50 == 0:
            u = rng.uniform(-3, 3, size=1)
        f = dyn.acceleration(d.qpos[:1].copy(), d.qvel[:1].copy(), u)[0]
        v0 = d.qvel[0]
        d.ctrl[:] = u
        mujoco.mj_step(m, d)
        acc_fd.append((d.qvel[0] - v0) / m.opt.timestep)
        model.append(f)
    acc_fd, model = np.array(acc_fd), np.array(model)
    rms = np.sqrt(np.mean(acc_fd**2))
    assert np.sqrt(np.mean((acc_fd - model) ** 2)) < 0.01 * rms


def test_contact_modes_on_hopper():
    env = gym.make("Hopper-v5").unwrapped
    env.reset(seed=0)
    m, d = env.model, env.data
    for _ in range(60):  # fall onto the ground
        env.step(np.zeros(3))
    assert d.ncon > 0
    q, v = d.qpos.copy(), d.qvel.copy()
    mujoco.mj_forward(m, d)
    measured = MujocoDynamics(m, contact="measured").acceleration(q, v, np.zeros(3))
    unknown = MujocoDynamics(m, contact="unknown").acceleration(q, v, np.zeros(3))
    np.testing.assert_allclose(measured, d.qacc, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(unknown, d.qacc_smooth, rtol=1e-9, atol=1e-9)
    assert np.max(np.abs(measured - unknown)) > 1.0  # contact forces matter


def test_rejects_free_joints_and_bad_arguments(arm):
    free = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody></mujoco>"
    )
    with pytest.raises(ValueError, match="hinge and slide"):
        MujocoDynamics(free)
    with pytest.raises(TypeError, match="MjModel"):
        MujocoDynamics("model.xml")
    with pytest.raises(ValueError, match="contact"):
        MujocoDynamics(arm.model, contact="soft")
    with pytest.raises(ValueError, match="joint name"):
        MujocoDynamics(arm.model, joints=["wrist"])
    with pytest.raises(ValueError, match="neither"):
        MujocoDynamics(arm.model, joints=["shoulder"])
    dyn = MujocoDynamics(arm.model)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        dyn.acceleration(np.zeros(3), np.zeros(3))
    # each accepted before and answered with plausible numbers: a zero mass (a singular inertia, acceleration 0
    # under gravity), a joint named twice (its two positions, last one wins), a NaN or 1e11 control (which
    # mj_forward replaces by 0: the same acceleration as no input)
    with pytest.raises(ValueError, match="mass_scale > 0"):
        MujocoDynamics(arm.model, mass_scale=0.0)
    with pytest.raises(ValueError, match="each joint once"):
        MujocoDynamics(arm.model, joints=["shoulder", "shoulder", "elbow"])
    with pytest.raises(TypeError, match="joint names"):
        MujocoDynamics(arm.model, joints="shoulder")
    for u in (np.array([np.nan, 0.0]), np.array([1e11, 0.0]), [np.inf, 0.0]):
        with pytest.raises(ValueError, match="expected u finite and within"):
            dyn.acceleration(np.zeros(2), np.zeros(2), u)
    with pytest.raises(TypeError, match="expected q"):
        dyn.acceleration(np.zeros(2, complex), np.zeros(2))
    for step in (0.0, 1e300):
        with pytest.raises(ValueError, match="expected step"):
            dyn.self_quadratic_coefficient(np.zeros(2), step=step)


def test_copies_evaluate_on_their_own_data(arm):
    import copy
    import pickle

    dyn = MujocoDynamics(arm.model)
    q, v, u = np.array([0.3, -0.2]), np.array([1.0, 2.0]), np.array([0.5, 0.1])
    ref = dyn.acceleration(q, v, u)
    for other in (copy.deepcopy(dyn), pickle.loads(pickle.dumps(dyn))):
        assert other.data is not dyn.data
        np.testing.assert_allclose(other.acceleration(q, v, u), ref, rtol=1e-12)
        other.acceleration(q + 1.0, v, u)
        np.testing.assert_allclose(other.data.qpos, q + 1.0)  # the hot path writes into the copy's own data
        assert not np.allclose(dyn.data.qpos, q + 1.0)


def test_self_quadratic_coefficient_is_the_v_i_squared_coefficient_of_f(arm):
    """Independent check of the Christoffel formula: the second difference of f_i along v_i e_i (the damping is
    linear in v, gravity and input constant) is 2 alpha_i."""
    dyn = MujocoDynamics(arm.model)
    rng = np.random.default_rng(3)
    s = 3.0
    for _ in range(3):
        q = rng.uniform(-2, 2, size=2)
        alpha = dyn.self_quadratic_coefficient(q)
        for i in range(2):
            e = np.zeros(2)
            e[i] = s
            second = dyn.acceleration(q, e) - 2 * dyn.acceleration(q, np.zeros(2)) + dyn.acceleration(q, -e)
            assert second[i] / (2 * s * s) == pytest.approx(alpha[i], rel=1e-6, abs=1e-8)


def test_acceleration_without_input_means_zero_input_after_a_call_with_one(arm):
    """``u`` omitted is zero: a previous call's input must not linger in the scratch data (the one-environment
    fast path once kept it)."""
    dyn = MujocoDynamics(arm.model)
    q, v = np.zeros(2), np.zeros(2)
    free = dyn.acceleration(q, v)
    dyn.acceleration(q, v, np.array([5.0, 0.0]))
    np.testing.assert_array_equal(dyn.acceleration(q, v), free)
    np.testing.assert_array_equal(dyn.acceleration(q, v, np.zeros(2)), free)


def test_non_finite_or_mis_shaped_coordinates_are_refused(arm):
    """NaN or inf positions and velocities gave NaN accelerations (on the one-environment fast path as on the
    general one), inertias and coefficients; ``terms`` is documented unbatched."""
    dyn = MujocoDynamics(arm.model)
    q, v = np.array([0.3, 0.2]), np.array([0.1, -0.2])
    for bad_q, bad_v in (
        (np.array([np.nan, 0.2]), v),
        (q, np.array([np.nan, 0.0])),
        ([np.inf, 0.2], [0.1, -0.2]),
        (np.array([[0.0, 0.0], [np.inf, 0.0]]), np.zeros((2, 2))),
    ):
        with pytest.raises(ValueError, match="finite"):
            dyn.acceleration(bad_q, bad_v)
    with pytest.raises(ValueError, match="expected q finite"):
        dyn.inertia([np.inf, 0.0])
    with pytest.raises(ValueError, match="expected q finite"):
        dyn.terms([np.nan, 0.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="expected q finite"):
        dyn.self_quadratic_coefficient([np.nan, 0.0])
    with pytest.raises(ValueError, match=r"expected q and v of shape \(2,\)"):
        dyn.terms(np.zeros((2, 2)), np.zeros((2, 2)))
    alpha = dyn.alpha_function()
    with pytest.raises(ValueError, match=r"expected Y with shape \(G, 2\)"):
        alpha([0.1, 0.2])
    with pytest.raises(ValueError, match="expected Y finite"):
        alpha([[np.nan, 0.2]])
    # a large finite state still takes the fast path's answer
    np.testing.assert_array_equal(dyn.acceleration(q, v), dyn.acceleration(q.tolist(), v.tolist()))


def test_calibrate_model_miss_refuses_the_dynamics_of_another_model(arm):
    from smo_gym.mechanics import calibrate_model_miss

    body = "<body><joint name='{0}' type='hinge'/><geom size='0.1' mass='1'/>{1}</body>"
    three = mujoco.MjModel.from_xml_string(  # three hinges, two motors: the arm's indices and widths fit it
        f"<mujoco><worldbody>{body.format('a', body.format('b', body.format('c', '')))}</worldbody>"
        "<actuator><motor joint='a'/><motor joint='b'/></actuator></mujoco>"
    )
    with pytest.raises(ValueError, match="expected dynamics of model"):
        calibrate_model_miss(three, MujocoDynamics(arm.model), 1, steps=3)
    miss, acc = calibrate_model_miss(arm.model, MujocoDynamics(arm.model), 1, steps=3)
    assert miss.shape == acc.shape == (2,)


# ---- the model's terms against MuJoCo's own forward pass -----------------------------------------------------------
def _forward(model, qpos, qvel, **fields):
    """MuJoCo's forward pass at ``(qpos, qvel)`` with the given ``MjData`` inputs, on fresh data."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    for name, value in fields.items():
        getattr(data, name)[:] = value
    mujoco.mj_forward(model, data)
    return data


@pytest.mark.parametrize("scale", [0.0, 2.0])
def test_damping_scale_is_the_model_with_scaled_damping(arm, scale):
    """``damping_scale`` multiplies every joint's damping: the acceleration at a nonzero velocity (where damping
    acts) is MuJoCo's for the model with ``dof_damping`` scaled; a negative scale is refused."""
    q, v = np.array([0.4, -0.9]), np.array([2.0, -3.0])
    scaled = copy.deepcopy(arm.model)
    scaled.dof_damping[:] *= scale
    expected = _forward(scaled, q, v).qacc
    np.testing.assert_allclose(MujocoDynamics(arm.model, damping_scale=scale).acceleration(q, v), expected, rtol=1e-10)
    for name in ("damping_scale", "frictionloss_scale"):
        with pytest.raises(ValueError, match=name):
            MujocoDynamics(arm.model, **{name: -1.0})


FRICTION = """<mujoco><worldbody><body pos='0 0 1'>
<joint name='j' type='hinge' axis='0 1 0' frictionloss='{f}'/>
<geom type='capsule' fromto='0 0 0 0.5 0 0' size='0.02' mass='1'/>
</body></worldbody></mujoco>"""


def test_frictionloss_scale_zero_is_the_model_without_dry_friction():
    """A hinge whose dry friction (5 N m) holds it against gravity (2.45 N m): with the measured constraint forces the
    model barely accelerates; with ``frictionloss_scale=0`` it falls as the model without friction does."""
    model = mujoco.MjModel.from_xml_string(FRICTION.format(f=5.0))
    q, v = np.zeros(1), np.zeros(1)
    held = MujocoDynamics(model, contact="measured").acceleration(q, v)
    free = MujocoDynamics(model, contact="measured", frictionloss_scale=0.0).acceleration(q, v)
    without = _forward(mujoco.MjModel.from_xml_string(FRICTION.format(f=0.0)), q, v).qacc
    np.testing.assert_allclose(free, without, rtol=1e-9)
    assert abs(held[0]) < 0.2 * abs(free[0]), (held, free)


BEAD = """<mujoco><worldbody><body><joint name='arm' type='hinge' axis='0 1 0' damping='0.02'/>
<geom type='capsule' fromto='0 0 0 0.3 0 0' size='0.02' mass='0.5'/>
<body pos='0.3 0 0'><joint name='bead' type='slide' axis='0 0 -1' damping='0.05'/><geom size='0.03' mass='1'/></body>
</body></worldbody>
<equality><joint joint1='bead' joint2='arm' polycoef='0.05 0.1 0.3 0.2 0.1'/></equality>
<actuator><motor joint='arm'/></actuator></mujoco>"""


@pytest.mark.parametrize("state", [(0.7, 1.3), (-0.9, -2.0)])
def test_a_joint_equality_with_every_coefficient_is_reduced_exactly(state):
    r"""A bead on an arm tied by a quartic joint equality (every coefficient nonzero): the reduced model's state lies
    on MuJoCo's constraint (residual ``efc_pos`` and ``efc_J qvel`` zero), its Jacobian is MuJoCo's constraint
    Jacobian solved for the dependent joint, and its acceleration is the rigid reduction computed independently:
    ``J`` and ``dJ/dq`` of the constraint by central differences of MuJoCo's residual, ``M`` and ``qfrc_smooth``
    of the unconstrained model, :math:`a = J^T(f - M\dot J v)/(J^T M J)`."""
    model = mujoco.MjModel.from_xml_string(BEAD)
    dynamics = MujocoDynamics(model)
    theta, omega = state
    a = dynamics.acceleration(np.array([theta]), np.array([omega]))[0]
    data = _forward(model, dynamics.data.qpos, dynamics.data.qvel)
    (row,) = np.flatnonzero(data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
    J_efc = data.efc_J.reshape(data.nefc, model.nv)[row]
    assert abs(data.efc_pos[row]) < 1e-12 and abs(J_efc @ data.qvel) < 1e-12
    np.testing.assert_allclose(dynamics.jacobian(np.array([theta]))[1, 0], -J_efc[0] / J_efc[1], rtol=1e-12)

    def bead(x):  # the bead's position on the constraint: efc_pos is linear in it with slope 1
        return -_forward(model, [x, 0.0], [0.0, 0.0]).efc_pos[row]

    h = 1e-4
    y, up, down = bead(theta), bead(theta + h), bead(theta - h)
    J, curvature = np.array([1.0, (up - down) / (2 * h)]), (up - 2 * y + down) / h**2
    free = copy.deepcopy(model)
    free.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    unconstrained = _forward(free, [theta, y], J * omega)
    M = np.zeros((2, 2))
    mujoco.mj_fullM(free, unconstrained, M)
    expected = J @ (unconstrained.qfrc_smooth - M @ np.array([0.0, curvature * omega**2])) / (J @ M @ J)
    assert a == pytest.approx(expected, rel=1e-5)


def test_measured_contacts_with_a_coupling_are_mujocos_acceleration(pendulum):
    """With ``contact="measured"`` the model is MuJoCo's forward pass at the full state, the coupled joint included:
    the acceleration of the measured joint is ``qacc`` there."""
    dynamics = MujocoDynamics(pendulum.model, contact="measured")
    a = dynamics.acceleration(np.array([0.6]), np.array([2.5]))
    expected = _forward(pendulum.model, dynamics.data.qpos, dynamics.data.qvel).qacc[dynamics.dof]
    np.testing.assert_allclose(a, expected, rtol=1e-10)


def test_a_generalized_force_input_is_applied_as_given(arm):
    """``input="qfrc"``: the input is a generalized force, applied whole even beyond the actuators' ``ctrlrange``."""
    q, v, tau = np.array([0.3, -0.4]), np.array([1.0, -1.0]), np.array([25.0, -12.0])
    expected = _forward(arm.model, q, v, qfrc_applied=tau).qacc
    np.testing.assert_allclose(MujocoDynamics(arm.model, input="qfrc").acceleration(q, v, tau), expected, rtol=1e-10)


def test_the_terms_of_a_coupled_model_solve_to_its_acceleration(pendulum):
    r"""``terms`` of a model with a coupled joint are projected like its acceleration:
    :math:`M^{-1}(\tau + f_p - b) = a`."""
    terms = MujocoDynamics(pendulum.model).terms(np.array([0.6]), np.zeros(1), np.array([0.7]))
    solved = np.linalg.solve(terms["inertia"], terms["actuator"] + terms["passive"] - terms["bias"])
    np.testing.assert_allclose(solved, terms["acceleration"], rtol=1e-9)


def test_the_alpha_function_moves_one_joint_at_a_time(arm):
    r""":math:`\alpha_i` of the Coriolis-removing transform is joint ``i``'s self-quadratic coefficient with the
    other joints at the reference."""
    dynamics = MujocoDynamics(arm.model)
    alpha = dynamics.alpha_function(reference=np.array([0.2, -0.7]))(np.array([[0.9, 0.4]]))
    assert alpha[0, 0] == dynamics.self_quadratic_coefficient(np.array([0.9, -0.7]))[0]
    assert alpha[0, 1] == dynamics.self_quadratic_coefficient(np.array([0.2, 0.4]))[1]


def test_dissipative_gains_take_the_smallest_inertia_and_the_largest_upsilon(pendulum):
    """The gains of a joint are Apaza-Perez et al.'s for the bound ``L``, the damping rate over the *smallest*
    inertia of the joint's range (the largest rate), :math:`s = -c/2`, and the largest :math:`\\Upsilon` of the
    transform (VariableInertia: an inertia that varies over the range, so the extremes differ)."""
    from smo_gym import design
    from smo_gym.mechanics import default_transform, dissipative_gains

    dynamics = MujocoDynamics(pendulum.model)
    transform = default_transform(dynamics, grid=101)
    np.testing.assert_array_equal(transform.lower, [-np.pi])
    np.testing.assert_array_equal(transform.upper, [np.pi])
    inertia = [dynamics.inertia(np.array([y]))[0, 0] for y in transform.grid_y[:, 0]]
    assert max(inertia) > 1.5 * min(inertia)
    c = pendulum.model.dof_damping[0] / min(inertia)
    upsilon = max(1.0, transform.grid_upsilon.max())
    expected = design.apaza_gains(5.0, q=-1.0, s=-c / 2, r=0.0, upsilon_max=upsilon).as_dict()
    found = dissipative_gains(dynamics, transform, 5.0)
    for key, value in expected.items():
        np.testing.assert_allclose(found[key], [value], rtol=1e-6, err_msg=key)


def test_the_default_transform_spans_a_limited_joints_range():
    """A limited hinge's transform spans ``jnt_range`` and is referenced at ``qpos0`` (inside the range)."""
    from smo_gym.mechanics import default_transform

    model = mujoco.MjModel.from_xml_string(
        "<mujoco><compiler angle='radian'/><worldbody><body>"
        "<joint type='hinge' axis='0 1 0' range='0 1.5' limited='true'/>"
        "<geom type='capsule' fromto='0 0 0 0.3 0 0' size='0.02' mass='1'/></body></worldbody></mujoco>"
    )
    transform = default_transform(MujocoDynamics(model), grid=21)
    np.testing.assert_array_equal(transform.lower, [0.0])
    np.testing.assert_array_equal(transform.upper, [1.5])
    np.testing.assert_array_equal(transform.reference, [0.0])


def test_the_model_miss_of_an_exact_model_is_small_and_controls_are_held(arm):
    """With the exact model the miss (Euler's velocity update against the model's acceleration) is a few percent
    of the acceleration itself; the quantile is the one asked for (the maximum is larger); controls are held for
    ``frame_skip`` physics steps, as an environment holds them."""
    from smo_gym.mechanics import calibrate_model_miss

    dynamics = MujocoDynamics(arm.model)
    miss, accel = calibrate_model_miss(arm.model, dynamics, 1, steps=300)
    assert np.all(miss < 0.05 * accel), (miss, accel)
    worst_miss, worst_accel = calibrate_model_miss(arm.model, dynamics, 1, steps=300, quantile=1.0)
    assert np.all(worst_miss > miss) and np.all(worst_accel > accel)

    class Inputs(MujocoDynamics):
        def acceleration(self, q, v, u=None):
            self.inputs.append(np.array(u, copy=True))
            return super().acceleration(q, v, u)

    spy = Inputs(arm.model)
    spy.inputs = []
    calibrate_model_miss(arm.model, spy, 5, steps=20)
    U = np.array(spy.inputs)
    for k in range(20):
        np.testing.assert_array_equal(U[k], U[k - k % 5])
    assert not np.array_equal(U[0], U[5])
