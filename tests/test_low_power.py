"""Low-power peaking-free high-gain observer (Astolfi et al. 2018; Astolfi and Marconi 2015) against HighGain (2)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_script

from smo_gym.observers import OBSERVERS, HighGain, LowPowerHighGain, make_observer
from smo_gym.observers.low_power import low_power_matrices


def _max_degree_in_gain(matrices_at) -> int:
    """Highest power of ell in the entries of ``matrices_at(ell)`` (1-D array), by exact finite differences.

    A polynomial of degree ``d`` in ell has a nonzero ``d``-th forward difference and a zero ``(d+1)``-th one on
    integer nodes; the differences are computed on ell = 1, 2, ..., 12 in exact integer-valued arithmetic.
    """
    values = np.array([matrices_at(float(ell)) for ell in range(1, 13)])
    for degree in range(11, -1, -1):
        diff = np.diff(values, n=degree, axis=0)
        if np.any(np.abs(diff) > 1e-6 * np.abs(values).max()):
            return degree
    return 0


# ---- structure ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("order", [1, 2, 3, 5, 8])
def test_only_powers_one_and_two_of_the_gain(order):
    """The implemented gains are ell and ell^2 only, whatever n; the standard observer needs ell^n."""
    lp = LowPowerHighGain(dt=1e-3, gain=1.0, order=order, bounds=1.0)

    def lp_entries(ell):
        M = low_power_matrices(order + 1, ell, lp.coefficients, lp.filter_coefficient)
        return np.concatenate([M["F0"].ravel(), M["Fc"].ravel(), M["G"]])

    def hg_entries(ell):
        A, H = HighGain(dt=1e-3, gain=ell, order=order).system_matrices()
        return np.concatenate([A.ravel(), H])

    assert _max_degree_in_gain(lp_entries) == 2
    assert _max_degree_in_gain(hg_entries) == order + 1
    assert lp.powers_of_gain() == [0, 1, 2]
    # the compiled recursion uses these matrices: its parameters at ell and 2 ell differ like the matrices do
    M = lp.system_matrices()
    assert M["F"].shape == (2 * order + 1, 2 * order + 1)


@pytest.mark.parametrize("n", [2, 3, 4, 6, 10])
def test_default_coefficients_put_every_pole_at_minus_ell(n):
    """K_i = (2, (n-i)/i), k_n = 1: characteristic polynomial (s + ell)^(2n-1), the rate of HighGain's default."""
    ell = 3.0
    lp = LowPowerHighGain(dt=1e-3, gain=ell, order=n - 1)
    F = lp.system_matrices()["F"]
    coeffs = np.poly(F)
    target = np.poly(np.full(2 * n - 1, -ell))
    np.testing.assert_allclose(coeffs, target, rtol=1e-9, atol=1e-9 * np.abs(target).max())
    A, _ = HighGain(dt=1e-3, gain=ell, order=n - 1).system_matrices()
    np.testing.assert_allclose(np.poly(A), np.poly(np.full(n, -ell)), rtol=1e-9)


def test_estimates_converge_without_noise():
    r"""Linear regime (inside the bounds), every pole at ``-ell``: the estimate of the ``i``-th derivative lags by
    :math:`O(|f^{(4)}| / \ell^{4 - i})` for ``order=3``, so doubling ``ell`` divides the error of the value by 16,
    of the second derivative by 4 and of the last by 2 (measured 15.99, 3.99 and 2.00), the last being the largest
    (about ``(2n - 1) |f^(n)| / ell`` through the cascade of poles). The step is small enough (10 us) that the
    discretization's own lag (``h |f^{(i+1)}| / 2``) stays below these; the velocity's error is at that level
    already (a few 1e-5 to 2e-4, no clean power of ``ell``), so only its size is checked."""
    h = 1e-5
    t = np.arange(0.0, 1.0, h)
    f = np.stack([np.sin(2 * t + k * np.pi / 2) * 2.0**k for k in range(5)], axis=-1)
    errs = []
    for ell in (200.0, 400.0):
        obs = LowPowerHighGain(dt=h, gain=ell, order=3, bounds=[3.0, 5.0, 9.0])
        obs.reset(f[0, :1])
        z = obs.run(f[1:, :1])[:, 0]
        errs.append(np.abs(z[-50000:] - f[1:][-50000:, :4]).max(axis=0))
    errs = np.array(errs)
    assert errs[0, -1] == pytest.approx(7 * 16 / 200.0, rel=0.02)  # measured 0.5600
    assert errs[0, 1] < 1e-3
    ratio = errs[0] / errs[1]
    np.testing.assert_allclose(ratio[[0, 2, 3]], [16.0, 4.0, 2.0], rtol=0.03)


# ---- peaking -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("order", [2, 3])
def test_peaking_bounded_for_low_power_and_growing_like_ell_power_for_high_gain(order):
    """Transient peak of xhat_i, i <= n-1, for ell in {10, 100, 1000}, fitted as ell^p.

    Standard observer (2): p_i = i - 1 (measured 0.99, 1.99, 3.00). Peaking-free observer: p_i ~ 0, the peaks stay
    below 1.9 for a signal bounded by 1 with saturation levels 1.5 (measured exponents <= 0.02). The last estimate
    xhat_n = eta (Astolfi et al. 2018) is bounded too.
    """
    compare = load_script("compare_low_power")
    res = compare.peaking_exponents(order, bound=1.5)
    n = order + 1
    hg, lp = res["high-gain"], res["low-power-high-gain"]
    for i in range(1, n):  # 1-based estimate index i + 1 in 2..n
        assert hg["exponents"][i] == pytest.approx(i, abs=0.1)
    assert np.all(np.abs(lp["exponents"]) < 0.1)
    assert lp["peaks"].max() < 2.0
    # at ell = 1000 the standard observer's xhat_2 already peaks 500 times higher
    assert hg["peaks"][-1, 1] > 300 * lp["peaks"][-1, 1]


@pytest.mark.parametrize("order", [2, 3])
def test_auxiliary_states_peak_like_ell_not_ell_power_n_minus_1(order):
    """Astolfi et al. 2018, Introduction: with the saturations the n - 1 auxiliary states xi_(i,2) may reach values
    proportional to ell, not ell^(n-1). Measured exponents 0.99-1.11 for n = 3, 4."""
    compare = load_script("compare_low_power")
    peaks = np.array(
        [compare.transient_peaks(LowPowerHighGain, ell, order, bounds=1.5, readout="low-power") for ell in compare.ELLS]
    )
    exponents = np.polyfit(np.log(compare.ELLS), np.log(peaks), 1)[0]
    assert np.all(np.abs(exponents[1:] - 1.0) < 0.2), exponents


def test_without_saturation_the_low_power_estimates_peak():
    """The saturations do the work: the same observer without bounds peaks like ell in xi_(1,2)."""
    compare = load_script("compare_low_power")
    peaks = [compare.transient_peaks(LowPowerHighGain, ell, 2, readout="low-power")[1] for ell in (10.0, 1000.0)]
    assert peaks[1] / peaks[0] > 50


# ---- noise ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("noise", ["white", "sine"])
def test_noise_sensitivity_against_high_gain_at_equal_rate(noise, capsys):
    """Same ell (all poles at -ell for both): the noise-induced RMS error of every derivative estimate is smaller
    for the low-power observer (Astolfi and Marconi 2015; 2018, Section 3), n = 3 and 4, noise 1e-3 at ell = 50.

    Measured (n = 4, white): xhat_4 0.40 against 3.49, xhat_3 0.075 against 0.28; n = 3, white: xhat_3 0.019
    against 0.076; with the sine at 20 ell the gap is larger (n = 4: xhat_4 5e-4 against 4.35). For n = 2 the
    observer is the standard one followed by a first-order filter: less noise on xhat_2, but more lag error
    (total RMS 0.039 against 0.026 at ell = 50).
    """
    compare = load_script("compare_low_power")
    for order in (2, 3):
        res = compare.noise_errors(order, noise=noise)
        hg, lp = res["high-gain"]["noise"], res["low-power-high-gain"]["noise"]
        with capsys.disabled():
            print(f"\n  n = {order + 1}, {noise} noise, noise-induced RMS: high-gain {hg}, low-power {lp}")
        assert np.all(lp[1:] < hg[1:])
        assert lp[-1] < 0.5 * hg[-1]


# ---- discretization --------------------------------------------------------------------------------------------------
def test_implicit_step_solves_the_saturated_equation():
    """Each step satisfies s_k = s_(k-1) + h (F0 s_k + Fc sat(P s_k) + G y_k), saturations active or not, even at
    ell h = 50 where explicit Euler would diverge."""
    ell, h, order = 5000.0, 1e-2, 3
    bounds = np.array([1.0, 2.0, 3.0])
    obs = LowPowerHighGain(dt=h, gain=ell, order=order, bounds=bounds)
    M = obs.system_matrices()
    rng = np.random.default_rng(1)
    obs.reset(np.zeros(5))
    clamped = 0
    T = obs.state_scale()
    for _ in range(30):
        prev = obs.internal_state
        y = rng.normal(scale=3.0, size=5)
        obs.update(y)
        new = obs.internal_state
        for c in range(5):
            s, s0 = new[c], prev[c]
            sat = np.clip(M["P"] @ s, -bounds, bounds)
            clamped += int(np.any(np.abs(M["P"] @ s) > bounds))
            residual = s - s0 - h * (M["F0"] @ s + M["Fc"] @ sat + M["G"] * y[c])
            # in the scaled coordinates zeta = s / T the equation has coefficients of order ell h
            scaled = np.abs(residual / T).max()
            assert scaled <= 1e-12 * (1 + h * ell) * max(1.0, np.abs(s / T).max()), scaled
    assert clamped > 10
    assert np.all(np.abs(obs.estimate) < 50)


# ---- API -----------------------------------------------------------------------------------------------------------
def test_registered_and_offline():
    import smo_gym

    assert OBSERVERS["low-power-high-gain"] is LowPowerHighGain
    assert isinstance(make_observer("low-power-high-gain", dt=1e-3, gain=10.0, order=2), LowPowerHighGain)
    t = np.arange(0.0, 2.0, 1e-3)
    z = smo_gym.differentiate(np.sin(t), 1e-3, method="low-power-high-gain", gain=100.0, order=2, bounds=2.0)
    assert z.shape == (t.size, 3) and abs(z[-1, 1] - np.cos(t[-1])) < 1e-2


def test_batched_equals_per_channel_loops():
    rng = np.random.default_rng(0)
    T, h = 300, 1e-3
    t = np.arange(T) * h
    Y = np.sin(3 * t[:, None, None] + rng.uniform(0, 6, (4, 3))) * 5.0 + 0.01 * rng.standard_normal((T, 4, 3))
    kw = dict(dt=h, gain=300.0, order=2, bounds=[4.0, 20.0])  # saturations active in the transient
    batched = LowPowerHighGain(**kw)
    out = np.concatenate([batched.reset(Y[0])[None], batched.run(Y[1:])])
    for e in range(4):
        for c in range(3):
            single = LowPowerHighGain(**kw)
            ref = [single.reset(Y[0, e, c : c + 1])] + [single.update(Y[k, e, c : c + 1]) for k in range(1, T)]
            np.testing.assert_allclose(out[:, e, c], np.array(ref)[:, 0], rtol=0, atol=1e-12)


def test_masked_reset_and_nan():
    obs = LowPowerHighGain(dt=1e-3, gain=50.0, order=2, bounds=2.0)
    obs.reset(np.zeros((2, 3)))
    obs.run(np.ones((100, 2, 3)))
    kept = obs.state[:3].copy()
    obs.reset(np.full((2, 3), 4.0), mask=np.array([False, True]))
    np.testing.assert_array_equal(obs.state[:3], kept)
    assert np.all(obs.estimate[1, :, 0] == 4.0) and np.all(obs.estimate[1, :, 1:] == 0.0)
    y = np.zeros((2, 3))
    y[0, 1] = np.inf
    with pytest.raises(ValueError, match="channel 1 of batch element \\(0,\\)"):
        obs.update(y)


@pytest.mark.parametrize(
    "kwargs, exc",
    [
        (dict(dt=1e-3, gain=-1.0), ValueError),
        (dict(dt=1e-3, gain="10"), TypeError),
        (dict(dt=1e-3, gain=10.0, order=0), ValueError),
        (dict(dt=1e-3, gain=10.0, order=2.0), TypeError),
        (dict(dt=1e-3, gain=10.0, order=2, bounds=[1.0, -1.0]), ValueError),
        (dict(dt=1e-3, gain=10.0, order=2, bounds=[1.0, 1.0, 1.0]), ValueError),
        (dict(dt=1e-3, gain=10.0, order=3, coefficients=[[1.0, 1.0]] * 3), ValueError),
        (dict(dt=1e-3, gain=10.0, order=2, coefficients=[[1.0, 1.0]]), ValueError),
        (dict(dt=1e-3, gain=10.0, readout="fast"), ValueError),
        (dict(dt=0.0, gain=10.0), ValueError),
    ],
)
def test_bad_parameters_raise_typed_errors(kwargs, exc):
    with pytest.raises(exc, match="expected"):
        LowPowerHighGain(**kwargs)


def test_the_active_set_solver_matches_lapack_and_pivots():
    """The compiled elimination of the active-set iteration solves like ``np.linalg.solve``, also where the first
    pivot is zero (no pivoting would divide by it)."""
    from smo_gym.observers.low_power import solve_in_place

    rng = np.random.default_rng(0)
    cases = [rng.normal(size=(n, n)) + n * np.eye(n) for n in (1, 3, 5, 7)]
    cases.append(np.array([[0.0, 2.0, 1.0], [1.0, 1.0, 0.0], [3.0, 0.0, 1.0]]))
    for M in cases:
        b = rng.normal(size=len(M))
        A, x = M.copy(), b.copy()
        solve_in_place(A, x)
        np.testing.assert_allclose(x, np.linalg.solve(M, b), rtol=1e-12, atol=1e-12)


def test_a_gain_per_channel_is_each_channel_with_its_own_gain():
    """An array ``gain`` runs every channel as the observer with that channel's gain would, bit for bit, and the
    internal state, a reset with derivatives and the repr follow it."""
    h, gains = 1e-3, np.array([20.0, 80.0, 20.0])
    t = np.arange(400) * h
    Y = np.column_stack([np.sin(t), np.sin(3 * t), np.cos(t)]) + 1e-4 * np.random.default_rng(0).standard_normal(
        (400, 3)
    )
    obs = LowPowerHighGain(dt=h, gain=gains, order=2, bounds=[5.0, 50.0])
    d0 = np.array([[1.0, 0.0], [3.0, 0.0], [0.0, -1.0]])
    obs.reset(Y[0], derivatives=d0)
    est = obs.run(Y[1:])
    for c, g in enumerate(gains):
        alone = LowPowerHighGain(dt=h, gain=g, order=2, bounds=[5.0, 50.0])
        alone.reset(Y[:1, c], derivatives=d0[c : c + 1])
        np.testing.assert_array_equal(alone.run(Y[1:, c : c + 1])[:, 0], est[:, c])
        np.testing.assert_array_equal(alone.internal_state[0], obs.internal_state[c])
    assert "gain=[20.0, 80.0, 20.0]" in repr(obs)
    np.testing.assert_allclose(obs.state_scale()[1], obs.state_scale(80.0))
    with pytest.raises(ValueError, match="expected a gain for an observer with one per channel"):
        obs.system_matrices()
    with pytest.raises(ValueError, match="gain"):
        LowPowerHighGain(dt=h, gain=[20.0, -1.0])
    with pytest.raises(ValueError, match="broadcastable to the measurement shape"):
        obs.reset(np.zeros(2))
