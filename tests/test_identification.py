"""Parameter identification by the equivalent output injection (smo_gym.identification).

The test system is a pendulum with unknown inverse inertia and damping in regressor form,

    q'' = -g sin q + theta_1 u - theta_2 q',   theta = (1/m, d/m) = (0.5, 0.3),   Phi = [u, -q'],

identified from its sampled angle with the nominal theta_bar = (0.3, 0.1). The plant is integrated by RK4 with the
input held over each sample (what the observer assumes); every scenario of one sampling step runs as one batch.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_script

from smo_gym.identification import (
    EquivalentInjectionIdentifier,
    ForgettingFactorError,
    LeastSquaresIdentifier,
    check_forgetting_factor,
    forgetting_transition,
    least_squares_step,
    regressor_matrix,
)

G = 9.81
THETA = np.array([0.5, 0.3])
THETA_BAR = np.array([0.3, 0.1])


def regressor(t, q, v, u):
    return np.stack([np.broadcast_to(u, q.shape), -v], axis=-1)


def nominal(t, q, v, u):
    return -G * np.sin(q) + regressor(t, q, v, u) @ THETA_BAR


def simulate(h, T, sigma, excited, theta=lambda t: THETA, forgetting=None, seed=0):
    """Run the pendulum and the identifier for a batch of scenarios; returns the estimates (N, B, 2), the
    identifier and the sample times (N,)."""
    sigma = np.asarray(sigma, float)[:, None]
    excited = np.asarray(excited, float)[:, None]
    B = sigma.shape[0]
    N = int(round(T / h))
    ident = EquivalentInjectionIdentifier(h, nominal, regressor, THETA_BAR, n=1, lipschitz=20.0, forgetting=forgetting)
    noise = np.random.default_rng(seed).standard_normal((N + 1, B, 1))
    q = np.full((B, 1), 0.3)
    v = np.zeros((B, 1))
    ident.reset(q + sigma * noise[0])
    out = np.empty((N, B, 2))
    hs = h / 2
    for k in range(N):
        t = k * h
        u = excited * (2 * np.sin(1.3 * t) + 1.5 * np.sin(3.7 * t))
        th = theta(t + h / 2)

        def f(q, v, th=th, u=u):
            return -G * np.sin(q) + th[0] * u - th[1] * v

        for _ in range(2):  # RK4, input held over the sample
            k1q, k1v = v, f(q, v)
            k2q, k2v = v + hs / 2 * k1v, f(q + hs / 2 * k1q, v + hs / 2 * k1v)
            k3q, k3v = v + hs / 2 * k2v, f(q + hs / 2 * k2q, v + hs / 2 * k2v)
            k4q, k4v = v + hs * k3v, f(q + hs * k3q, v + hs * k3v)
            q = q + hs / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            v = v + hs / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        out[k] = ident.update(q + sigma * noise[k + 1], u)
    return out, ident, h * np.arange(1, N + 1)


def settling_time(t, err, tol):
    """First time after which ``|err| <= tol`` for good (inf if never)."""
    bad = np.nonzero(np.abs(err) > tol)[0]
    if bad.size == 0:
        return t[0]
    return np.inf if bad[-1] == len(t) - 1 else t[bad[-1] + 1]


# ---- the least-squares laws ---------------------------------------------------------------------------------
def test_exact_step_solves_the_continuous_laws():
    """Zero-order hold, one long sample: the closed form against a fine Euler integration of
    Gamma' = -(Gamma Phi^T Phi + ln R) Gamma and theta' = Gamma^T Phi^T (z - Phi theta)."""
    rng = np.random.default_rng(1)
    p, n, h = 3, 2, 0.5
    A = rng.standard_normal((p, p))
    R = 0.5 * np.eye(p) + 0.1 * (A + A.T) / 4  # symmetric, eigenvalues in (0, 1)
    check_forgetting_factor(R, p)
    Phi = rng.standard_normal((n, p))
    z = rng.standard_normal(n)
    Gam0 = np.diag([2.0, 1.0, 0.5])
    th0 = rng.standard_normal(p)
    E, S = forgetting_transition(R, h, p)
    Q0 = np.linalg.inv(Gam0).T
    Q1, b1 = least_squares_step(Q0, Q0 @ th0, Phi, z, E, S)
    lam, V = np.linalg.eigh(R)
    logR = (V * np.log(lam)) @ V.T
    Gam, th = Gam0.copy(), th0.copy()
    m = 20_000
    for _ in range(m):
        dG = -(Gam @ Phi.T @ Phi + logR) @ Gam
        dth = Gam.T @ Phi.T @ (z - Phi @ th)
        Gam, th = Gam + h / m * dG, th + h / m * dth
    np.testing.assert_allclose(np.linalg.inv(Q1).T, Gam, rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(np.linalg.solve(Q1, b1), th, rtol=1e-3, atol=1e-4)


def test_regressor_matrix_is_the_slides_theta_phi():
    theta = np.arange(6.0).reshape(2, 3)
    phi = np.array([0.5, -1.0, 2.0])
    np.testing.assert_allclose(regressor_matrix(phi, 2) @ theta.reshape(-1), theta @ phi)


def test_the_general_laws_are_the_slides_row_laws_for_theta_phi():
    """With Phi = I_n (x) phi^T the vector law equals the slides' matrix law row by row:
    Delta' = (z - Delta phi) phi^T Gamma with one l x l Gamma, checked on a sequence of samples with forgetting."""
    rng = np.random.default_rng(2)
    n, l, h = 2, 3, 0.05
    vec = LeastSquaresIdentifier(n * l, h, gamma0=10.0, forgetting=0.6)
    row = LeastSquaresIdentifier(l, h, gamma0=10.0, forgetting=0.6)  # each row of Delta: z_i = phi^T delta_i
    vec.reset()
    row.reset((n,))
    for _ in range(20):
        phi = rng.standard_normal(l)
        z = rng.standard_normal(n)
        vec.update(regressor_matrix(phi, n), z)
        row.update(np.broadcast_to(phi, (n, 1, l)), z[:, None])
    np.testing.assert_allclose(vec.estimate.reshape(n, l), row.estimate, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(vec.gain[:l, :l], row.gain[0], rtol=1e-10)


# ---- defining properties on the pendulum ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def excitation_runs():
    # batch: persistently exciting input; no input (only the velocity regressor is excited)
    return simulate(2e-3, 6.0, [0.0, 0.0], [1.0, 0.0])


def test_converges_under_persistent_excitation(excitation_runs):
    out, ident, t = excitation_runs
    err = out[:, 0] - THETA
    # the tolerance covers the O(h) bias of the sampled observer (measured 0.009 on theta_2 at h = 2 ms)
    ts = settling_time(t, np.max(np.abs(err) / THETA, axis=1), 0.05)
    assert ts < 3.0, ts  # measured 0.77 s
    assert np.max(np.abs(err[-1])) < 0.012
    assert np.max(np.linalg.eigvalsh(ident.gain[0])) < 1.0  # information gained in every direction


def test_no_convergence_without_persistent_excitation(excitation_runs):
    out, ident, _ = excitation_runs
    # u = 0: the input column of Phi is zero, theta_1 keeps its nominal value and its gain stays gamma0 = 1e3
    np.testing.assert_allclose(out[-1, 1, 0], THETA_BAR[0], atol=1e-9)
    assert abs(out[-1, 1, 0] - THETA[0]) > 0.19
    eig = np.linalg.eigvalsh(ident.gain[1])
    assert eig[-1] == pytest.approx(1e3, rel=1e-9)
    assert eig[0] < 1.0
    # the excited direction (damping) still converges
    assert abs(out[-1, 1, 1] - THETA[1]) < 0.02


@pytest.mark.parametrize("rate", [0.5, 1.0])
def test_forgetting_tracks_a_ramp_with_lag_slope_over_rate(rate):
    """theta_1 = 0.5 + s t: with R = exp(-rate) I the estimate lags by s / rate (plus the filter's s tau).

    The first-order lag formula assumes the forgetting window 1 / rate long against the excitation's periods
    (4.8 s and 1.7 s here); measured lags 0.100 (rate 0.5, formula 0.101) and 0.063 (rate 1, formula 0.051). At
    faster forgetting the O(h) bias and the coupling with theta_2 dominate (rate 4: 0.024 against 0.0135)."""
    s = 0.05

    def theta(t):
        return np.array([0.5 + s * t, 0.3])

    h, T = 4e-3, 8.0
    out, ident, t = simulate(h, T, [0.0], [1.0], theta=theta, forgetting=np.exp(-rate))
    err = out[:, 0, 0] - (0.5 + s * t)
    lag = -np.mean(err[t > T - 3.0])
    expected = s / rate + s * ident.filter_time_constant
    assert lag == pytest.approx(expected, rel=0.3), (lag, expected)
    assert np.max(np.abs(err[t > 4.0])) < 2.5 * expected


def test_without_forgetting_a_ramp_is_averaged_away():
    s = 0.05
    out, _, t = simulate(4e-3, 8.0, [0.0], [1.0], theta=lambda t: np.array([0.5 + s * t, 0.3]))
    lag = -(out[-1, 0, 0] - (0.5 + s * t[-1]))
    # least squares weighing the whole past alike estimates the ramp's mean over it: a lag of s t / 2 = 0.2
    # (measured 0.208), against s / rate = 0.1 with the forgetting above
    assert lag == pytest.approx(s * t[-1] / 2, rel=0.1)


def test_error_is_first_order_in_the_sampling_step():
    """Noise free: z_eq of the sampled observer is exact up to the explicit model term over one sample, O(h)."""
    steps = [8e-3, 4e-3, 2e-3]
    errs = []
    for h in steps:
        out, _, t = simulate(h, 4.0, [0.0], [1.0])
        errs.append(np.mean(np.abs(out[t > 3.0, 0] - THETA)))
    slope = np.polyfit(np.log(steps), np.log(errs), 1)[0]
    assert 0.8 < slope < 1.2, (slope, errs)  # measured 1.0


def test_error_against_the_noise_level_in_its_two_regimes():
    """Gaussian position noise eps, h = 2 ms, k2 = 22: the observer's injection saturates at k2 once eps > k2 h^2
    (about 1e-4 rad).

    Large noise (eps = 1e-4 .. 1e-3): the observer filters, its velocity is accurate to the worst-case
    O(eps^(1/2)) of the super-twisting algorithm, and so is the estimate: slope 1/2 (measured 0.41 here; 0.40 to 0.61
    for other noise seeds). Small noise (eps = 1e-6 .. 3e-5): the implicit step is a backward difference; the injection
    (a second difference, error ~ eps/h^2) and the regressor's velocity (a first difference) share the noise, an
    errors-in-variables bias of order eps^2 adds to the zero-mean part of order eps that least squares averages:
    a slope between 1 and 2 (measured 1.40 here; 1.38 to 1.42 for other seeds).
    """
    small = np.array([1e-6, 3e-6, 1e-5, 3e-5])
    large = np.array([1e-4, 3e-4, 1e-3])
    levels = np.concatenate([small, large])
    reps = 4
    sigma = np.concatenate([[0.0], np.repeat(levels, reps)])
    out, _, t = simulate(2e-3, 3.0, sigma, np.ones_like(sigma), seed=3)
    d = np.mean(np.abs(out[t > 2.0, 1:] - out[t > 2.0, :1]), axis=(0, 2))  # noise's effect: against noise free
    per_level = d.reshape(len(levels), reps).mean(axis=1)
    slope_small = np.polyfit(np.log(small), np.log(per_level[: len(small)]), 1)[0]
    slope_large = np.polyfit(np.log(large), np.log(per_level[len(small) :]), 1)[0]
    assert 1.1 < slope_small < 1.8, (slope_small, per_level)
    assert 0.25 < slope_large < 0.75, (slope_large, per_level)


# ---- bad input ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("R", "condition"),
    [
        (np.array([[0.5, 0.1], [0.0, 0.5]]), "symmetric"),
        (np.diag([0.5, -0.5]), "lambda_min(R) > 0"),
        (np.diag([0.5, 0.0]), "lambda_min(R) > 0"),
        (np.diag([0.5, 1.0]), "||R|| < 1"),
        (1.5, "||R|| < 1"),
        (np.eye(3) * 0.5, "shape"),
        (np.diag([0.5, np.nan]), "finite"),
    ],
)
def test_forgetting_factor_conditions(R, condition):
    with pytest.raises(ForgettingFactorError) as info:
        LeastSquaresIdentifier(2, 1e-3, forgetting=R)
    assert info.value.condition == condition
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"n_params": 0, "dt": 1e-3}, ValueError),
        ({"n_params": 2, "dt": -1e-3}, ValueError),
        ({"n_params": 2, "dt": 1e-3, "gamma0": 0.0}, ValueError),
        ({"n_params": 2, "dt": 1e-3, "gamma0": -1.0}, ValueError),
        ({"n_params": 2, "dt": "x"}, TypeError),
        ({"n_params": 2, "dt": 1e-3, "gamma0": 1e-310}, ValueError),  # the initial information I / gamma0 is inf
    ],
)
def test_least_squares_rejects_bad_parameters(kwargs, error):
    with pytest.raises(error, match="expected"):
        LeastSquaresIdentifier(**kwargs)


def test_least_squares_rejects_bad_shapes_and_use_before_reset():
    ls = LeastSquaresIdentifier(2, 1e-3)
    with pytest.raises(RuntimeError, match="reset"):
        ls.update(np.zeros((1, 2)), np.zeros(1))
    ls.reset()
    with pytest.raises(ValueError, match="Phi"):
        ls.update(np.zeros((1, 3)), np.zeros(1))
    with pytest.raises(ValueError, match="z with shape"):
        ls.update(np.zeros((1, 2)), np.zeros(2))
    with pytest.raises(ValueError, match="finite"):
        ls.update(np.full((1, 2), np.nan), np.zeros(1))
    for batch_shape in ((2.7,), True):  # were read as (2,) and (1,)
        with pytest.raises(TypeError, match="batch_shape entry"):
            ls.reset(batch_shape)
    assert ls.reset(np.array([3])).shape == ls.reset(3).shape == (3, 2)


def test_the_pure_steps_refuse_what_numpy_would_broadcast():
    """A ``z`` of three entries for one row of ``Phi`` gave ``b = [3, 3]``; a NaN ``phi`` a NaN regressor."""
    eye = np.eye(2)
    with pytest.raises(ValueError, match=r"z \(\.\.\., n\)"):
        least_squares_step(eye, np.zeros(2), np.ones((1, 2)), np.ones(3), eye, eye)
    with pytest.raises(ValueError, match="finite phi"):
        regressor_matrix([np.nan, 1.0], 2)


def test_a_prior_lost_next_to_the_information_is_refused_with_the_state_kept():
    """gamma0 = 1e20: after one sample of a rank-one regressor the information matrix is singular in floating
    point; ``numpy.linalg.LinAlgError`` escaped."""
    ls = LeastSquaresIdentifier(2, 1e-3, gamma0=1e20)
    ls.reset()
    before = ls.information
    with pytest.raises(ValueError, match="stays invertible"):
        ls.update([[1.0, 0.5]], [1.0])
    np.testing.assert_array_equal(ls.information, before)


def test_identifier_rejects_bad_input():
    kw = {"n": 1, "lipschitz": 20.0}
    with pytest.raises(ValueError, match="dt > 0"):
        EquivalentInjectionIdentifier(0.0, nominal, regressor, THETA_BAR, **kw)
    with pytest.raises(ValueError, match="lipschitz"):
        EquivalentInjectionIdentifier(1e-3, nominal, regressor, THETA_BAR, n=1, lipschitz=-1.0)
    with pytest.raises(ValueError, match="lipschitz > 0 or both k1 and k2"):
        EquivalentInjectionIdentifier(1e-3, nominal, regressor, THETA_BAR, n=1)
    with pytest.raises(ValueError, match="filter_time_constant > 0"):
        EquivalentInjectionIdentifier(1e-3, nominal, regressor, THETA_BAR, filter_time_constant=0.0, **kw)
    with pytest.raises(TypeError, match="callables"):
        EquivalentInjectionIdentifier(1e-3, None, regressor, THETA_BAR, **kw)
    with pytest.raises(ValueError, match="theta_bar"):
        EquivalentInjectionIdentifier(1e-3, nominal, regressor, [[0.3, 0.1]], **kw)
    ident = EquivalentInjectionIdentifier(1e-3, nominal, regressor, np.zeros(3), **kw)  # regressor has 2 columns
    with pytest.raises(RuntimeError, match="reset"):
        ident.update(np.zeros(1), np.zeros(1))
    with pytest.raises(RuntimeError, match="reset"):
        _ = ident.time  # an AttributeError
    with pytest.raises(TypeError, match="uses_acceleration"):
        EquivalentInjectionIdentifier(1e-3, nominal, regressor, THETA_BAR, uses_acceleration="no", **kw)
    ident.reset(np.zeros(1))
    with pytest.raises(ValueError, match=r"regressor to return shape \(1, 3\)"):
        ident.update(np.zeros(1), np.zeros(1))


# ---- the MuJoCo path ------------------------------------------------------------------------------------------
def test_mujoco_regressor_is_exact_for_mass_and_damping():
    """Affine parameters: the true acceleration minus the nominal one is Phi(a_true) (theta - theta_bar), exactly."""
    import gymnasium as gym
    import mujoco

    from smo_gym.mechanics import MujocoDynamics, MujocoParameterRegressor

    env = gym.make("smo_gym/TwoLinkArm-v0")
    model = env.unwrapped.model
    reg = MujocoParameterRegressor(model, [("body_mass", "lower"), ("dof_damping", "elbow")])
    np.testing.assert_allclose(reg.theta_bar, [0.8, 0.05])
    nominal, true = MujocoDynamics(model), MujocoDynamics(model)
    true.model.body_mass[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "lower")] = 1.3
    true.model.dof_damping[1] = 0.2
    q, v, u = np.array([0.3, -0.7]), np.array([1.2, -0.5]), np.array([2.0, -1.0])
    a = true.acceleration(q, v, u)
    Phi = reg(0.0, q, v, u, a)
    np.testing.assert_allclose(a - nominal.acceleration(q, v, u), Phi @ ([1.3, 0.2] - reg.theta_bar), rtol=1e-7)
    assert reg(0.0, np.stack([q, q]), v, u, a).shape == (2, 2, 2)
    with pytest.raises(ValueError, match="parameter kind"):
        MujocoParameterRegressor(model, [("body_inertia", "lower")])
    with pytest.raises(ValueError, match="name of a body"):
        MujocoParameterRegressor(model, [("body_mass", "forearm")])
    with pytest.raises(ValueError, match="step > 0"):
        MujocoParameterRegressor(model, [("body_mass", "lower")], step=0.0)
    with pytest.raises(TypeError, match="MjModel"):
        MujocoParameterRegressor(None, [("body_mass", "lower")])
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        reg(0.0, q[:1], v[:1], u, a[:1])
    env.close()


def test_mujoco_payload_mass_identified_from_encoder_readings():
    """The demo's path, short: TwoLinkArm-v0 with a 1.2 kg forearm, nominal 0.8 kg, 12-bit noisy encoder, h = 10 ms."""
    demo = load_script("demo_identification")
    t, m_true, m_hat, _ = demo.run("encoder-12bit-noisy", 5, 3.0)
    assert m_true[-1] == demo.TRUE_MASS
    assert np.max(np.abs(m_hat[t > 2.0] - m_true[t > 2.0])) < 0.05 * demo.TRUE_MASS


def test_the_guide_example_runs_and_identifies():
    from pathlib import Path

    guide = Path(__file__).resolve().parents[1] / "docs" / "guide" / "identification.md"
    source = guide.read_text().split("```python\n", 1)[1].split("```", 1)[0]
    namespace = {"__name__": "__guide__"}
    exec(compile(source, str(guide), "exec"), namespace)
    np.testing.assert_allclose(namespace["theta_hat"], [0.5, 0.3], atol=0.015)


def test_the_guide_environment_example_reads_the_payload_from_info():
    """The python block of the guide's "In an environment" section, executed as printed."""
    from pathlib import Path

    guide = Path(__file__).resolve().parents[1] / "docs" / "guide" / "identification.md"
    section = guide.read_text().split("## In an environment", 1)[1]
    source = section.split("```python\n", 1)[1].split("```", 1)[0]
    namespace = {"__name__": "__guide__"}
    exec(compile(source, str(guide), "exec"), namespace)
    assert abs(namespace["mass"] - 1.2) < 0.05 * 1.2  # the simulation's payload, from 0.8 kg nominal
    assert namespace["info"]["identification"]["gamma_diag"][0] < 1e-2
