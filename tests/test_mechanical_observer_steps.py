r"""One step of the model-based super-twisting observers against their equations, and the coordinate transform.

The dissipative observer (Apaza-Perez, Moreno and Fridman 2018) is checked where its gains, its :math:`k_3` term
and its disturbance estimate enter; the shared recursion's explicit and implicit branches against the formulas of
:mod:`smo_gym.observers._mechanical_kernels`; the options of :class:`MechanicalSuperTwisting` (Davila, Fridman and
Levant 2005) against what they promise; :class:`CoordinateTransform` outside its table.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from smo_gym.mechanics import MujocoDynamics
from smo_gym.observers import CoordinateTransform, DissipativeSuperTwisting, MechanicalSuperTwisting
from smo_gym.observers._mechanical_kernels import MODEL, STATE_WIDTH, mechanical_channel_step


class Recorded:
    """Dynamics ``f(q, v)`` of ``n`` unit-inertia joints that records the ``(q, v)`` of every call."""

    def __init__(self, f, n=1):
        self.f, self.n, self.calls = f, n, []

    def acceleration(self, q, v, u=None):
        self.calls.append((np.array(q, copy=True), np.array(v, copy=True)))
        return self.f(np.asarray(q), np.asarray(v))

    def inertia(self, q):
        return np.broadcast_to(np.eye(self.n), np.shape(q) + (self.n,))


def _zero(q, v):
    return np.zeros_like(q)


def test_dissipative_euler_step_is_the_injections_of_the_equations():
    r"""From rest at 0 with no model term and the identity transform, one Euler step on the measurement
    :math:`e = 0.04` moves the estimates by exactly :math:`h k_1\phi_1(e)` and :math:`h k_2\phi_2(e)`."""
    identity = CoordinateTransform(lambda Y: np.zeros_like(Y), [-10.0], [10.0])
    h, k1, k2, mu1, mu2, e = 0.01, 5.0, 20.0, 1.5, 0.7, 0.04
    gains = dict(k1=k1, k2=k2, k3=0.0, mu1=mu1, mu2=mu2)
    observer = DissipativeSuperTwisting(h, Recorded(_zero), identity, gains, discretization="euler")
    observer.reset(np.zeros(1))
    q, v = observer.update(np.array([e]))[0]
    assert q == pytest.approx(h * k1 * (mu1 * np.sqrt(e) + mu2 * e), rel=1e-12)
    assert v == pytest.approx(h * k2 * (mu1**2 / 2 + 1.5 * mu1 * mu2 * np.sqrt(e) + mu2**2 * e), rel=1e-12)


def test_dissipative_model_is_evaluated_at_the_corrected_velocity():
    r"""The model term is :math:`\psi(y, \Upsilon(y)^{-1}(\hat x_2 - k_3\phi_1(e)))`: at every step the dynamics
    object receives that velocity, computed here from the previous estimate, measurement and transform."""
    transform = CoordinateTransform(lambda Y: np.full_like(Y, 0.3), [-5.0], [5.0], reference=[0.0])
    dynamics = Recorded(_zero)
    gains = dict(k1=5.0, k2=20.0, k3=0.8, mu1=1.5, mu2=0.7)
    observer = DissipativeSuperTwisting(0.01, dynamics, transform, gains)
    Y = 0.5 * np.sin(3 * np.arange(30) * 0.01)[:, None]
    observer.reset(Y[0])
    for k in range(1, 30):
        q, v = observer.estimate[0]
        upsilon = transform.upsilon(Y[k - 1])[0]
        e = transform.position(Y[k - 1])[0] - transform.position(np.array([q]))[0]
        phi1 = gains["mu1"] * np.sign(e) * np.sqrt(abs(e)) + gains["mu2"] * e
        expected = (v * upsilon - gains["k3"] * phi1) / upsilon
        observer.update(Y[k])
        assert dynamics.calls[-1][1][0] == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_dissipative_disturbance_is_an_acceleration():
    r"""A plant :math:`\ddot\xi = 0.5\dot\xi^2 - 1 + w` with :math:`w = 0.5` (its model knows all but ``w``), the
    transform removing the :math:`0.5\dot\xi^2` term, and a motion that takes :math:`\Upsilon` far from 1: the
    filtered injection divided by :math:`\Upsilon(y)` settles on ``w``."""
    transform = CoordinateTransform(lambda Y: np.full_like(Y, 0.5), [-4.0], [4.0], reference=[0.0], grid=4001)
    h, T = 0.002, 1500
    t = np.arange(T + 1) * h
    plant = solve_ivp(
        lambda _, s: [s[1], 0.5 * s[1] ** 2 - 0.5], (0, T * h), [0.0, 0.0], t_eval=t, rtol=1e-11, atol=1e-12
    )
    Y = plant.y[0][:, None]
    assert abs(transform.upsilon(Y[-1])[0] - 1.0) > 0.3
    gains = dict(k1=6.0, k2=40.0, k3=0.0, mu1=1.0, mu2=0.0)
    observer = DissipativeSuperTwisting(h, Recorded(lambda q, v: 0.5 * v * v - 1.0), transform, gains)
    observer.reset(Y[0], v0=[0.0])
    disturbance = []
    for y in Y[1:]:
        observer.update(y)
        disturbance.append(observer.disturbance[0])
    np.testing.assert_allclose(disturbance[-200:], 0.5, atol=0.02)


def test_the_transform_outside_its_table_and_its_reference():
    r"""With a constant :math:`\alpha = 0.5` on ``[-1, 1]``: beyond the table :math:`T_1` continues with the
    slope :math:`\Upsilon` of its end (:math:`e^{\mp 0.5}`), its inverse with the reciprocal slope, both invert each
    other everywhere, and :math:`\alpha` is 0 there; ``l_alpha`` is a magnitude; a reference outside the range is
    refused."""
    transform = CoordinateTransform(lambda Y: np.full_like(Y, 0.5), [-1.0], [1.0], reference=[0.0], grid=2001)
    y = np.linspace(-3.0, 3.0, 61)[:, None]
    np.testing.assert_allclose(transform.position_inverse(transform.position(y)), y, atol=1e-9)
    eps = 1e-6
    for end in (-2.0, 2.0):
        slope = np.diff(transform.position(np.array([[end - eps], [end + eps]])), axis=0)[0, 0] / (2 * eps)
        assert slope == pytest.approx(np.exp(-0.5 * np.sign(end)), rel=1e-6)
        assert transform.alpha(np.array([end]))[0] == 0.0
    x = transform.position(np.array([[2.0]]))[0, 0]
    inverse_slope = np.diff(transform.position_inverse(np.array([[x - eps], [x + eps]])), axis=0)[0, 0] / (2 * eps)
    assert inverse_slope == pytest.approx(np.exp(0.5), rel=1e-6)
    shifted = CoordinateTransform(lambda Y: np.full_like(Y, 0.5), [-1.0], [1.0], reference=[1.0])
    assert shifted.l_alpha == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(ValueError, match="reference"):
        CoordinateTransform(lambda Y: np.zeros_like(Y), [-1.0], [1.0], reference=[2.0])


EULER_SLIDE = """<mujoco><option timestep='0.002' integrator='Euler'><flag eulerdamp='disable'/></option>
<worldbody><body><joint type='slide' axis='0 0 1'/><geom size='0.1' mass='1'/></body></worldbody></mujoco>"""


def test_euler_substeps_reproduce_mujocos_euler_flow():
    r"""A body falling on a slide, integrated by MuJoCo's semi-implicit Euler with four physics steps per sample:
    with the exact model, ``euler_substeps=4`` (:math:`c = 5/8`) and the exact initial velocity, the prediction is
    the plant's discrete flow and the output error stays at rounding level (``c = 1/2`` misses it by 8e-5)."""
    model = mujoco.MjModel.from_xml_string(EULER_SLIDE)
    data = mujoco.MjData(model)
    Q = [data.qpos.copy()]
    for _ in range(50):
        mujoco.mj_step(model, data, nstep=4)
        Q.append(data.qpos.copy())
    observer = MechanicalSuperTwisting(4 * model.opt.timestep, MujocoDynamics(model), 1.0, euler_substeps=4)
    observer.reset(Q[0], v0=np.zeros(1))
    errors = []
    for q in Q[1:]:
        observer.update(q)
        errors.append(abs(observer.output_error[0]))
    assert max(errors) < 1e-10, max(errors)


def test_disturbance_filter_is_a_first_order_lag_of_the_raw_injection():
    r""":attr:`disturbance` follows :attr:`disturbance_raw` through :math:`d_k = d_{k-1} + \beta(r_k - d_{k-1})`
    with :math:`\beta = h/(T + h)` (the implicit Euler step of the time constant ``T``)."""
    h, T = 0.01, 0.05
    observer = MechanicalSuperTwisting(h, Recorded(_zero), 10.0, disturbance_time_constant=T)
    observer.reset(np.zeros(1))
    previous = observer.disturbance.copy()
    for k in range(1, 40):
        observer.update(np.array([(k * h) ** 2]))
        expected = previous + h / (T + h) * (observer.disturbance_raw - previous)
        np.testing.assert_allclose(observer.disturbance, expected, rtol=1e-12, atol=1e-15)
        previous = observer.disturbance.copy()


def test_a_masked_reset_continues_as_a_fresh_observer():
    """A batch row reset at a new measurement (not the one it stopped at) then runs as an observer reset there."""
    dynamics = Recorded(lambda q, v: -9.0 * np.sin(q))
    t = np.arange(80) * 0.01
    Y = np.stack([np.sin(2 * t), 0.5 * np.cos(3 * t)], axis=1)[:, :, None]  # (T, 2 rows, 1 joint)
    batch = MechanicalSuperTwisting(0.01, dynamics, 20.0)
    batch.reset(Y[0])
    batch.run(Y[1:50])
    batch.reset(Y[10], mask=np.array([False, True]))
    fresh = MechanicalSuperTwisting(0.01, dynamics, 20.0)
    fresh.reset(Y[10, 1])
    np.testing.assert_allclose(batch.run(Y[11:30])[:, 1], fresh.run(Y[11:30, 1]), rtol=1e-12)


def test_the_model_term_is_clipped_on_both_sides():
    r"""A model term of -100 against ``accel_bound = 1``: clipped to -1, the prediction moves by at most
    :math:`L h^2`, so the first output error is at most that."""
    h = 0.01
    observer = MechanicalSuperTwisting(
        h, Recorded(lambda q, v: np.full_like(q, -100.0)), 5.0, accel_bound=1.0, model_substeps=2
    )
    observer.reset(np.zeros(1))
    observer.update(np.zeros(1))
    assert abs(observer.output_error[0]) <= h * h * (1 + 1e-12)


def _parameters(h, c, g, implicit):
    return np.array([h, c, *g, 1.0 if implicit else 0.0, 0.1, 0.0, np.inf])


@pytest.mark.parametrize("g", [(3.0, 2.0, 0.0, 0.0, 4.0), (3.0, 2.0, 0.0, 5.0, 4.0)])
def test_implicit_step_without_the_discontinuous_gain_solves_its_equation(g):
    r"""The implicit branch with :math:`g_{20} = 0` (no set-valued term): the returned innovation ``w`` and the
    corrected error :math:`e = X - \hat x_1^+` satisfy
    :math:`w = e + h(g_{11}\lceil e\rfloor^{1/2} + g_{12}e) + h^2(g_{21}\lceil e\rfloor^{1/2} + g_{22}e)`."""
    rng = np.random.default_rng(0)
    h = 0.01
    for _ in range(100):
        x = np.zeros(STATE_WIDTH)
        x[0], x[1], x[MODEL] = rng.normal(), rng.normal(), 10 * rng.normal()
        X = x[0] + rng.normal() * 10.0 ** rng.uniform(-7, 0)
        new = np.zeros(STATE_WIDTH)
        new[MODEL] = x[MODEL]
        w = mechanical_channel_step(x, X, _parameters(h, 0.5, g, True), new)
        e = X - new[0]
        root = np.sign(e) * np.sqrt(abs(e))
        residual = e + h * (g[0] * root + g[1] * e) + h * h * (g[3] * root + g[4] * e)
        assert residual == pytest.approx(w, rel=1e-9, abs=1e-12)


def test_explicit_step_is_the_prediction_plus_the_injections():
    r"""The Euler branch: with :math:`w = X - \hat x_1^-`,
    :math:`\hat x_1^+ = \hat x_1^- + h(g_{11}\lceil w\rfloor^{1/2} + g_{12}w)` and
    :math:`\hat x_2^+ = \hat x_2^- + h(g_{20}\,\mathrm{sign}\,w + g_{21}\lceil w\rfloor^{1/2} + g_{22}w)`, with
    :math:`\mathrm{sign}\,0 = 0` (a zero innovation leaves the prediction)."""
    rng = np.random.default_rng(1)
    h, c, g = 0.01, 0.5, (4.0, 2.0, 8.0, 6.0, 4.0)
    for k in range(100):
        x = np.zeros(STATE_WIDTH)
        x[0], x[1], x[MODEL] = rng.normal(), rng.normal(), 10 * rng.normal()
        p1, p2 = x[0] + h * x[1] + c * h * h * x[MODEL], x[1] + h * x[MODEL]
        X = p1 if k == 0 else x[0] + rng.normal()
        new = np.zeros(STATE_WIDTH)
        new[MODEL] = x[MODEL]
        w = mechanical_channel_step(x, X, _parameters(h, c, g, False), new)
        root = np.sign(w) * np.sqrt(abs(w))
        np.testing.assert_allclose(new[0], p1 + h * (g[0] * root + g[1] * w), rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(
            new[1], p2 + h * (g[2] * np.sign(w) + g[3] * root + g[4] * w), rtol=1e-13, atol=1e-15
        )
