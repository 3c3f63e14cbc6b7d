r"""The worst-case-optimal sampled differentiator (Haimovich, Seeber, Aldana-López and Gómez-Gutiérrez 2021).

The claims, each checked against what can be computed without the observer:

* exactness: on a quadratic with :math:`|f''| = L` and exact samples the error is :math:`Lh/2`, the smallest any
  sampled differentiator can guarantee (Seeber and Haimovich 2023), and the certified bound is that value; with a
  noise bound the bound is the closed form of the lag intervals;
* the certificate holds: :math:`|\hat v_k - f'(t_k)| \le B_k \le E_m` at every sample, for random signals with
  :math:`|f''| \le L` under uniform and adversarial :math:`\pm\epsilon` noise;
* accuracy order: the worst case is attained (an adversarial signal meets :math:`E_m` exactly), scales as
  :math:`\sqrt{\epsilon L}` and tends to the continuous optimum :math:`2\sqrt{\epsilon L}` as ``h`` shrinks;
* best worst-case accuracy among sampled differentiators (Haimovich et al. 2021): a pair of signals computed by a
  linear program, without any differentiator, that no differentiator can tell apart forces an error of
  :math:`E_m` (:math:`Lh/2` without noise), so :math:`E_m` is the optimum; on typical data the certified interval
  contains every consistent derivative but is wider than the tightest one (the linear programs' range);
* against the backward difference on a quantized encoder;
* the observer contract on this family's own parameters (per-channel noise bounds, the estimated noise);
* ``noise=None``: the estimate never exceeds the true bound and comes close to it on stationary noise.

The registry's contract tests (``tests/test_observer_api.py``) run this family on its registered examples too.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

import smo_gym
from smo_gym.calibration import Calibration, default_observer
from smo_gym.observers import FiniteDifference, WorstCaseOptimal, make_observer
from smo_gym.observers.worst_case import (
    DEFAULT_ESTIMATION_WINDOW,
    MAX_WINDOW,
    best_worst_case_error,
    bounded_noise,
    default_window,
)

#: rounding of a difference quotient of samples of size ~1 at these steps (the certificate is exact arithmetic)
ROUNDING = 1e-9


def run_with_bounds(obs, Y):
    """``reset(Y[0])`` then ``update`` per sample: estimates ``(T, ..., 2)`` and certified bounds ``(T, ...)``."""
    est, bounds = [obs.reset(Y[0])], [obs.certified_bound]
    for y in Y[1:]:
        est.append(obs.update(y))
        bounds.append(obs.certified_bound)
    return np.stack(est), np.stack(bounds)


def random_sines(rng, t, n_channels, lipschitz, n_terms=5):
    r"""``(f, f')`` of shape ``(T, n_channels)``: sums of sines with :math:`\sum_i |a_i| w_i^2 = L`, so that
    :math:`|f''| \le L` holds with equality possible (the sines can align)."""
    w = rng.uniform(0.5, 40.0, (n_terms, n_channels))
    a = rng.uniform(0.1, 1.0, (n_terms, n_channels))
    a *= lipschitz / np.sum(a * w**2, axis=0)
    phase = rng.uniform(0.0, 2.0 * np.pi, (n_terms, n_channels))
    arg = w[None] * t[:, None, None] + phase[None]
    return np.sum(a * np.sin(arg), axis=1), np.sum(a * w * np.cos(arg), axis=1)


def noise_patterns(rng, shape, eps):
    """Bounded noise, ``|eta| <= eps``: uniform, random signs, alternating signs, and blocks of one sign of random
    lengths (the pattern that biases every lag of a window the same way)."""
    T, n = shape
    blocks = np.repeat(rng.choice([-1.0, 1.0], (T, n)), rng.integers(1, 40, T), axis=0)[:T]
    return {
        "uniform": rng.uniform(-eps, eps, shape),
        "signs": eps * rng.choice([-1.0, 1.0], shape),
        "alternating": eps * np.where(np.arange(T)[:, None] % 2 == 0, 1.0, -1.0) * np.ones(shape),
        "blocks": eps * blocks,
    }


# ----------------------------------------------------------------------------------------------------------------
# exactness
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_exact_samples_of_a_quadratic_give_the_quasi_exact_error(sign):
    r"""Without noise, on :math:`f = \pm Lt^2/2 + bt + c` (:math:`|f''| = L` exactly), the window is one lag, the
    estimate is off by exactly :math:`Lh/2` at every sample and the certified bound is :math:`Lh/2`, the error
    any sampled differentiator must allow (a quadratic and its mirror image through the chord give the same
    samples)."""
    h, L, T = 1e-3, 40.0, 200
    t = np.arange(T) * h
    b, c = np.array([0.3, -2.0, 5.0]), np.array([1.0, 0.0, -0.5])
    f = sign * 0.5 * L * t[:, None] ** 2 + b * t[:, None] + c
    df = sign * L * t[:, None] + b
    obs = WorstCaseOptimal(h, L, noise=0.0)
    est, bound = run_with_bounds(obs, f)
    assert obs._params[0, 3] == 1  # the window: one lag
    np.testing.assert_allclose(np.abs(est[1:, :, 1] - df[1:]), 0.5 * L * h, rtol=1e-6)
    np.testing.assert_allclose(bound[1:], 0.5 * L * h, rtol=1e-6)
    assert np.all(np.isinf(bound[0]))  # nothing is known at the reset sample
    assert best_worst_case_error(h, L, 0.0) == pytest.approx(0.5 * L * h)


def test_exact_samples_with_a_noise_bound_give_the_closed_form():
    r"""On :math:`f = Lt^2/2` with exact samples but a noise bound :math:`\epsilon`, lag ``j`` gives
    :math:`[f' - Ljh - 2\epsilon/(jh),\ f' + 2\epsilon/(jh)]`; the intersection over ``j <= m`` is
    :math:`[f' - \min_j(Ljh + 2\epsilon/(jh)),\ f' + 2\epsilon/(mh)]`, its half-width the certified bound and its
    midpoint the estimate."""
    h, L, eps = 1e-3, 5.0, 1e-3
    m = int(default_window(h, L, eps))
    assert m == int(np.ceil(2.0 * np.sqrt(eps / L) / h)) == 29
    t = np.arange(3 * m) * h
    obs = WorstCaseOptimal(h, L, noise=eps)
    est, bound = run_with_bounds(obs, (0.5 * L * t**2)[:, None])
    j = np.arange(1, m + 1) * h
    low, high = np.min(L * j + 2.0 * eps / j), 2.0 * eps / (m * h)
    full = slice(m, None)  # the window is full from sample m on
    np.testing.assert_allclose(bound[full, 0], 0.5 * (low + high), rtol=1e-6)
    np.testing.assert_allclose(est[full, 0, 1] - L * t[full], 0.5 * (high - low), rtol=1e-6, atol=1e-9)
    assert np.all(bound[full, 0] <= best_worst_case_error(h, L, eps))


# ----------------------------------------------------------------------------------------------------------------
# the certificate
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "h, L, eps",
    [(1e-3, 5.0, 1e-3), (1e-3, 200.0, 1e-4), (2e-3, 1000.0, 5e-4), (1e-4, 1.0, 1e-6), (1e-3, 50.0, 0.0)],
    ids=["m29", "m2", "m1", "m20", "exact"],
)
def test_the_certified_bound_holds_at_every_sample(h, L, eps, rng):
    r"""Over 48 random signals with :math:`|f''| \le L` and each bounded noise pattern, every sample satisfies
    :math:`|\hat v_k - f'(t_k)| \le B_k` (``B_k`` finite: the data never contradict true bounds), and once the
    window is full :math:`B_k \le E_m`, the guaranteed worst case."""
    m = int(default_window(h, L, eps))
    T = m + 300
    t = np.arange(T) * h
    f, df = random_sines(rng, t, 48, L)
    E = float(best_worst_case_error(h, L, eps))
    for pattern, eta in noise_patterns(rng, f.shape, eps).items():
        est, bound = run_with_bounds(WorstCaseOptimal(h, L, noise=eps), f + eta)
        err = np.abs(est[1:, :, 1] - df[1:])
        assert np.all(np.isfinite(bound[1:])), pattern
        assert np.all(err <= bound[1:] + ROUNDING), (pattern, float(np.max(err - bound[1:])))
        assert np.all(bound[m:] <= E + ROUNDING), pattern
        assert np.max(err[m:]) <= E + ROUNDING


# ----------------------------------------------------------------------------------------------------------------
# the accuracy order
# ----------------------------------------------------------------------------------------------------------------
def adversarial_error(h, L, eps, m=None):
    r"""The error at the last sample of :math:`f = -Lt^2/2` with noise :math:`-\epsilon` then :math:`+\epsilon`
    on the last sample: every lag interval is then :math:`[f',\ f' + Ljh + 4\epsilon/(jh)]`, so the estimate is
    off by exactly :math:`E_m` (the worst case is attained). Returns ``(error, certified bound)``."""
    m = int(default_window(h, L, eps)) if m is None else m
    t = np.arange(m + 2) * h
    eta = np.full(t.shape, -eps)
    eta[-1] = eps
    obs = WorstCaseOptimal(h, L, noise=eps, window=m)
    est, bound = run_with_bounds(obs, (-0.5 * L * t**2 + eta)[:, None])
    return abs(est[-1, 0, 1] - (-L * t[-1])), float(bound[-1, 0])


def worst_error(h, L, eps, rng, n_channels=16):
    """The largest error over random signals under random-sign noise and the adversarial signal."""
    m = int(default_window(h, L, eps))
    t = np.arange(m + 200) * h
    f, df = random_sines(rng, t, n_channels, L)
    eta = eps * rng.choice([-1.0, 1.0], f.shape)
    est, _ = run_with_bounds(WorstCaseOptimal(h, L, noise=eps), f + eta)
    return max(float(np.max(np.abs(est[m:, :, 1] - df[m:]))), adversarial_error(h, L, eps)[0])


def test_the_worst_case_is_attained_and_scales_as_sqrt_eps_L(rng):
    r"""Over :math:`\epsilon = 10^{-6} \ldots 10^{-2}` (``L = 100``, ``h = 2\cdot10^{-5}``: windows of 10 to 1000
    lags) the worst error over the signals is the adversarial one, equal to the certified bound and to
    :math:`E_m`; its exponent in :math:`\epsilon` is 0.5 (fitted: 0.500) and it is :math:`2\sqrt{\epsilon L}` to
    within 1e-4 (measured ratios 1.0000 to 1.00007)."""
    h, L = 2e-5, 100.0
    eps = np.logspace(-6, -2, 5)
    worst = []
    for e in eps:
        err, bound = adversarial_error(h, L, e)
        assert err == pytest.approx(bound, rel=1e-6) and err == pytest.approx(best_worst_case_error(h, L, e), rel=1e-6)
        worst.append(worst_error(h, L, e, rng, n_channels=8))
    worst = np.array(worst)
    slope = np.polyfit(np.log(eps), np.log(worst), 1)[0]
    assert abs(slope - 0.5) < 1e-3, slope  # measured 0.499997
    ratio = worst / (2.0 * np.sqrt(eps * L))
    assert np.all(ratio >= 1.0 - 1e-6) and np.all(ratio <= 1.0 + 1e-4), ratio


def test_the_worst_case_tends_to_the_continuous_optimum_as_h_shrinks():
    r"""With :math:`\epsilon = 10^{-4}`, ``L = 10`` (:math:`2\sqrt{\epsilon L} = 0.0632`, best lag 6.3 ms) the
    attained worst-case error over the optimum :math:`2\sqrt{\epsilon L}` is 1.107 at ``h = 10 ms`` (one lag: the
    backward difference, :math:`2\epsilon/h + Lh/2`), 1.0014 at 1 ms and 1.000008 at 0.1 ms: never below 1 (no
    differentiator beats the optimum), down to it as ``h`` shrinks. Each is the best difference over a multiple of
    the step, :math:`\min_j (2\epsilon/(jh) + Ljh/2)`: the lag the continuous optimum wants, rounded to the grid."""
    eps, L = 1e-4, 10.0
    optimum = 2.0 * np.sqrt(eps * L)
    steps = (1e-2, 1e-3, 1e-4)
    ratios = [adversarial_error(h, L, eps)[0] / optimum for h in steps]
    lags = np.arange(1, 1000)
    on_the_grid = [np.min(2 * eps / (lags * h) + L * lags * h / 2) / optimum for h in steps]
    np.testing.assert_allclose(ratios, on_the_grid, rtol=1e-6)
    assert np.all(np.diff(ratios) < 0) and ratios[-1] < 1.0 + 1e-5


def sampled_optimum(h, L, eps, n_samples, substeps=40):
    r"""A lower bound, by a witness, of the worst-case error of *every* sampled differentiator, computed without
    any differentiator: the largest :math:`\varphi'(t_k)` over :math:`|\varphi''| \le L` (piecewise constant on a
    grid of ``h / substeps``) with :math:`|\varphi(t_k - jh)| \le \epsilon` for ``j = 0..n_samples`` and
    :math:`\varphi' = 0` at the oldest sample (so that a constant extends it to the whole past within the bound).
    The signals :math:`\pm\varphi` with noise :math:`\mp\varphi` give the same samples (all zero) but derivatives
    :math:`\pm\varphi'(t_k)`: whatever a differentiator reports, it is off by :math:`\varphi'(t_k)` on one of
    them. A linear program (``scipy.optimize.linprog``) in :math:`\varphi(t_k)`, :math:`\varphi'(t_k)` and the
    second derivative on each sub-step."""
    from scipy.optimize import linprog

    d, n = h / substeps, n_samples * substeps
    mid = (np.arange(n) + 0.5) * d  # sub-step i spans [t_k - (i + 1) d, t_k - i d]
    rows = []
    for j in range(
        n_samples + 1
    ):  # phi(t_k - s) = phi(t_k) - s phi'(t_k) + sum_i d (s - mid_i) a_i (sub-steps before s)
        s = j * h
        rows.append(np.r_[1.0, -s, np.where(mid < s, d * (s - mid), 0.0)])
    rows = np.array(rows)
    res = linprog(
        np.r_[0.0, -1.0, np.zeros(n)],  # maximize phi'(t_k)
        A_ub=np.vstack([rows, -rows]),
        b_ub=np.full(2 * len(rows), eps),
        A_eq=np.r_[0.0, 1.0, np.full(n, -d)][None],  # phi' at the oldest sample: phi'(t_k) - sum_i d a_i = 0
        b_eq=[0.0],
        bounds=[(None, None), (None, None)] + [(-L, L)] * n,
        method="highs",
    )
    assert res.status == 0, res.message
    return -res.fun


@pytest.mark.parametrize(
    "h, L, eps, m",
    [(1.0, 1.0, 0.0, 1), (1.0, 1.0, 0.0225, 1), (1.0, 1.0, 0.5625, 2), (1.0, 1.0, 2.25, 3), (1e-3, 5.0, 1e-3, 29)],
    ids=["exact", "x0.3", "x1.5", "x3", "m29"],
)
def test_the_worst_case_is_the_smallest_any_sampled_differentiator_can_guarantee(h, L, eps, m):
    r"""Best worst-case accuracy among *sampled* differentiators, not only against the continuous-time limit: the
    witness pair of :func:`sampled_optimum` (computed by a linear program, no differentiator involved) forces an
    error of :math:`E_m = \min_j(2\epsilon/(jh) + Ljh/2)` on any differentiator that sees only the samples, and
    this one never errs by more (the certificate tests); so its worst case is the optimum exactly. Without noise
    that optimum is :math:`Lh/2` (quasi-exactness, Seeber and Haimovich 2023). On the witness's samples (all
    zero) the estimate is 0 and the certified bound :math:`E_m`: it meets the optimum on both signals. A shorter
    window than the default is not optimal where the best lag is longer than one sample (the backward difference
    at ``x = 3``, measured 3.72 against 3.0)."""
    K = max(8, 2 * m + 4)  # samples the witness must respect: more than the window, so the optimum is not the window's
    optimum = sampled_optimum(h, L, eps, K, substeps=40 if m < 8 else 8)
    E = float(best_worst_case_error(h, L, eps))
    assert optimum == pytest.approx(E, rel=1e-6), (optimum, E)
    if eps == 0.0:
        assert optimum == pytest.approx(0.5 * L * h, rel=1e-6)
    est, bound = run_with_bounds(WorstCaseOptimal(h, L, noise=eps), np.zeros((m + 3, 1)))
    assert np.all(est[1:, 0, 1] == 0.0) and bound[-1, 0] == pytest.approx(optimum, rel=1e-6)
    assert int(default_window(h, L, eps)) == m
    if m > 1:  # the backward difference alone: worse than the optimum
        assert float(best_worst_case_error(h, L, eps, window=1)) > optimum * (1.0 + 1e-3)


def consistent_rates(y, h, L, eps, n_samples, substeps=4):
    r"""``(low, high)``: the range of :math:`f'(t_k)` over signals with :math:`|f''| \le L` (piecewise constant on
    a grid of ``h / substeps``) within :math:`\epsilon` of the last ``n_samples + 1`` samples of ``y`` (newest
    last), by two linear programs: every derivative some consistent signal has, so an inner approximation of what
    the data allow (a finer grid can only widen it)."""
    from scipy.optimize import linprog

    d, n = h / substeps, n_samples * substeps
    mid = (np.arange(n) + 0.5) * d
    rows = np.array([np.r_[1.0, -j * h, np.where(mid < j * h, d * (j * h - mid), 0.0)] for j in range(n_samples + 1)])
    window = y[::-1][: n_samples + 1]
    kwargs = dict(
        A_ub=np.vstack([rows, -rows]),
        b_ub=np.r_[window + eps, eps - window],
        bounds=[(None, None)] * 2 + [(-L, L)] * n,
        method="highs",
    )
    low = linprog(np.r_[0.0, 1.0, np.zeros(n)], **kwargs)
    high = linprog(np.r_[0.0, -1.0, np.zeros(n)], **kwargs)
    assert low.status == 0 and high.status == 0
    return low.fun, -high.fun


def test_the_certified_interval_contains_every_consistent_derivative_and_is_wider_than_the_tightest(rng):
    r"""At the last of 200 samples of random signals (:math:`|f''| \le L`, uniform noise within :math:`\epsilon`,
    ``m = 29``), every derivative that a signal consistent with the last 60 samples can have lies in
    :math:`[\hat v_k - B_k,\ \hat v_k + B_k]` (a check of the certificate against all consistent signals at once,
    not one). The interval is that of the lag constraints with the newest sample only, not the tightest the
    data allow: measured over 6 signals, :math:`B_k` is 1.08 to 1.50 times the half-width of the linear programs'
    range (which the worst case does not see: both are :math:`E_m` on the adversarial data)."""
    h, L, eps, T = 1e-3, 5.0, 1e-3, 200
    t = np.arange(T) * h
    f, _ = random_sines(rng, t, 6, L)
    y = f + rng.uniform(-eps, eps, f.shape)
    est, bound = run_with_bounds(WorstCaseOptimal(h, L, noise=eps), y)
    ratios = []
    for c in range(y.shape[1]):
        low, high = consistent_rates(y[:, c], h, L, eps, 60)
        centre, half = est[-1, c, 1], bound[-1, c]
        assert centre - half <= low + ROUNDING and high <= centre + half + ROUNDING, (c, low, high, centre, half)
        ratios.append(half / (0.5 * (high - low)))
    assert min(ratios) >= 1.0 - 1e-9 and max(ratios) > 1.05, ratios


def test_it_beats_the_backward_difference_on_a_quantized_encoder(rng):
    r"""A 12-bit single-turn encoder (:math:`q = 2\pi/4096`, :math:`|\eta| \le q/2 = 7.7\cdot10^{-4}` rad) at 1 kHz on
    joint motions with :math:`|f''| \le 20` rad/s^2: the backward difference's worst case is
    :math:`q/h + Lh/2 = 1.54` rad/s (measured over 16 signals and 2000 samples: 1.53), the worst-case-optimal
    differentiator's :math:`E_{13} = 0.248` rad/s (measured: 0.21-0.24 over three seeds, about seven times smaller)."""
    h, L, q = 1e-3, 20.0, 2.0 * np.pi / 4096
    t = np.arange(2000) * h
    f, df = random_sines(rng, t, 16, L)
    y = q * np.round(f / q)
    assert np.max(np.abs(y - f)) <= q / 2
    eps = float(bounded_noise(q / np.sqrt(12.0), q))  # a pure quantization error: the bound q / 2
    assert eps == pytest.approx(q / 2)
    m = int(default_window(h, L, eps))
    wco, _ = run_with_bounds(WorstCaseOptimal(h, L, noise=eps), y)
    fd_obs = FiniteDifference(h)
    fd = np.concatenate([fd_obs.reset(y[0])[None], fd_obs.run(y[1:])])
    wco_worst = float(np.max(np.abs(wco[m:, :, 1] - df[m:])))
    fd_worst = float(np.max(np.abs(fd[m:, :, 1] - df[m:])))
    E = float(best_worst_case_error(h, L, eps))
    assert pytest.approx(0.2478, abs=1e-4) == E and q / h + L * h / 2 == pytest.approx(1.544, abs=1e-3)
    assert wco_worst <= E + ROUNDING
    assert fd_worst > 1.2 and fd_worst > 5.0 * wco_worst, (fd_worst, wco_worst)


# ----------------------------------------------------------------------------------------------------------------
# the observer contract, on this family's own parameters
# ----------------------------------------------------------------------------------------------------------------
def signals(rng, T=200, shape=(3, 4), eps=1e-3):
    t = np.arange(T)[:, None, None] * 1e-3
    amp, w, p = (rng.uniform(0.5, 2.0, shape), rng.uniform(1.0, 6.0, shape), rng.uniform(0, 2 * np.pi, shape))
    return amp * np.sin(w * t + p) + rng.uniform(-eps, eps, (T,) + shape)


def per_channel_parameters(shape=(3, 4)):
    n = int(np.prod(shape))
    return (5.0 + np.arange(n).reshape(shape), 1e-4 * (1.0 + np.arange(n).reshape(shape) % 5))


@pytest.mark.parametrize("noisy", [True, False], ids=["noise", "estimated"])
def test_batch_equals_the_per_channel_loop(noisy, rng):
    """Per-channel ``L`` and noise bounds (hence per-channel windows of 6 to 14 lags) in a ``(3, 4)`` batch give
    what twelve scalar observers give, bit for bit; ``run`` equals a loop of ``update``."""
    Y = signals(rng)
    L, eps = per_channel_parameters()
    kw = dict(noise=eps) if noisy else dict(window=12)
    batch = WorstCaseOptimal(1e-3, L, **kw)
    got, bounds = run_with_bounds(batch, Y)
    if noisy:
        assert sorted(set(batch._params[:, 3])) == sorted(set(default_window(1e-3, L, eps).ravel()))
    for i in range(3):
        for j in range(4):
            single = WorstCaseOptimal(1e-3, L[i, j], **({**kw, "noise": eps[i, j]} if noisy else kw))
            first = single.reset(Y[0, i, j][None])
            ref = np.concatenate([first[None], single.run(Y[1:, i, j][:, None])])[:, 0]
            np.testing.assert_array_equal(got[:, i, j], ref)
            np.testing.assert_array_equal(bounds[-1, i, j], single.certified_bound[0])


@pytest.mark.parametrize("noisy", [True, False], ids=["noise", "estimated"])
def test_a_part_of_a_composite_estimates_as_alone(noisy, rng):
    """As the part of a :class:`~smo_gym.observers.PerChannel` on permuted channels with per-channel windows, the
    differentiator gives its own estimates bit for bit (its state holds its window: the composite had sized its rows
    by the default width of three columns, and the reset failed). Sample by sample: a composite's ``run`` would
    compile its offline driver too, for nothing this test asks."""
    from smo_gym.observers import PerChannel

    Y = signals(rng)[:, 0]
    order = [3, 0, 2, 1]
    L, eps = per_channel_parameters((4,))
    kw = dict(noise=eps[order]) if noisy else dict(window=12)

    def make():
        return WorstCaseOptimal(1e-3, L[order], **kw)

    composite, alone = PerChannel([(make(), order)]), make()
    composite.reset(Y[0])
    alone.reset(Y[0, order])
    for y in Y[1:]:
        np.testing.assert_array_equal(composite.update(y)[order, :2], alone.update(y[order]))


def test_masked_reset_pickling_and_run(rng):
    """A masked reset restarts the selected rows' windows (they estimate from the new samples only), the others
    continue bit for bit; a pickled or copied observer mid-run continues like the original."""
    Y = signals(rng, T=120)
    L, eps = per_channel_parameters()
    obs, untouched, fresh = (WorstCaseOptimal(1e-3, L, noise=eps) for _ in range(3))
    for o in (obs, untouched):
        o.reset(Y[0])
        o.run(Y[1:60])
    mask = np.array([True, False, True])
    obs.reset(Y[60], mask=mask)
    fresh.reset(Y[60])
    got, ref_u, ref_f = obs.run(Y[61:]), untouched.run(Y[61:]), fresh.run(Y[61:])
    np.testing.assert_array_equal(got[:, mask], ref_f[:, mask])
    np.testing.assert_array_equal(got[:, ~mask], ref_u[:, ~mask])

    estimated = WorstCaseOptimal(1e-3, L)
    estimated.reset(Y[0])
    estimated.run(Y[1:50])
    clones = [pickle.loads(pickle.dumps(estimated)), copy.deepcopy(estimated)]
    ref = estimated.run(Y[50:])
    for clone in clones:
        np.testing.assert_array_equal(clone.run(Y[50:]), ref)
        np.testing.assert_array_equal(clone.noise_estimate, estimated.noise_estimate)


def worded(excinfo):
    msg = str(excinfo.value)
    return "expected" in msg and "actual value" in msg


@pytest.mark.parametrize(
    "kwargs, error",
    [
        (dict(lipschitz=0.0), ValueError),
        (dict(lipschitz=[1.0, np.nan]), ValueError),
        (dict(noise=-1e-3), ValueError),
        (dict(noise=[1e-3, np.inf]), ValueError),
        (dict(noise="small"), TypeError),
        (dict(window=0), ValueError),
        (dict(window=MAX_WINDOW + 1), ValueError),
        (dict(window=2.5), TypeError),
        (dict(window=True), TypeError),
    ],
)
def test_bad_parameters_are_typed_errors(kwargs, error):
    with pytest.raises(error) as excinfo:
        WorstCaseOptimal(1e-3, **{"lipschitz": 5.0, **kwargs})
    assert worded(excinfo), str(excinfo.value)


def test_bad_measurements_and_shapes_are_typed_errors(rng):
    """A non-finite sample names its channel and changes nothing; a noise bound of another shape fails at the
    reset, which keeps the previous shape."""
    obs = WorstCaseOptimal(1e-3, 5.0, noise=np.full(3, 1e-3))
    with pytest.raises(ValueError, match="broadcastable") as excinfo:
        obs.reset(np.zeros((2, 4)))
    assert worded(excinfo) and obs.shape is None
    obs.reset(np.zeros(3))
    obs.update(np.full(3, 1e-3))
    state, bound = obs.state, obs.certified_bound
    with pytest.raises(ValueError, match="channel 1") as excinfo:
        obs.update(np.array([0.0, np.nan, 0.0]))
    assert worded(excinfo)
    np.testing.assert_array_equal(obs.state, state)
    np.testing.assert_array_equal(obs.certified_bound, bound)
    with pytest.raises(RuntimeError) as excinfo:
        _ = WorstCaseOptimal(1e-3, 5.0).certified_bound
    assert worded(excinfo)


def test_contradicting_data_lose_the_certificate_not_the_estimate():
    """A step of 1 in the samples (an impact far beyond ``L``) empties the intersection: the bound becomes
    infinite there (no certificate), the estimate stays finite, and the certificate returns once the step has left
    the window."""
    h, L, eps = 1e-3, 5.0, 1e-3
    m = int(default_window(h, L, eps))
    y = np.where(np.arange(3 * m) < m, 0.0, 1.0)[:, None]
    est, bound = run_with_bounds(WorstCaseOptimal(h, L, noise=eps), y)
    assert np.all(np.isfinite(est)) and np.isinf(bound[m + 1, 0])
    assert np.all(np.isfinite(bound[2 * m + 1 :])) and np.all(np.abs(est[2 * m + 1 :, 0, 1]) <= bound[2 * m + 1 :, 0])


# ----------------------------------------------------------------------------------------------------------------
# calibration
# ----------------------------------------------------------------------------------------------------------------
def test_default_observer_takes_the_acceleration_bound_and_a_noise_bound():
    r"""``lipschitz`` is the calibrated bound of :math:`|f''|` per channel; ``noise`` the quantization half-step plus
    three standard deviations of the rest of the error (:func:`bounded_noise`); a given argument wins."""
    q = np.array([0.0, 2 * np.pi / 4096])
    sigma = np.array([1e-3, np.sqrt(1e-6 + q[1] ** 2 / 12)])  # Gaussian 1e-3 on top of the quantization
    cal = Calibration(1e-3, {2: np.array([30.0, 80.0])}, {2: np.array([3.0, 8.0])}, sigma, q)
    obs = default_observer("worst-case-optimal", cal)
    np.testing.assert_array_equal(obs.lipschitz, [30.0, 80.0])
    np.testing.assert_allclose(obs.noise, [3e-3, q[1] / 2 + 3e-3])
    np.testing.assert_allclose(bounded_noise(sigma, q), obs.noise)
    assert default_observer("worst-case-optimal", cal, {"noise": None}).noise is None
    assert default_observer("worst-case-optimal", cal, {"lipschitz": 7.0}).noise is None  # lipschitz given: as built
    y = np.sin(np.arange(500) * 1e-3 * 4.0)[:, None] + 1e-4 * np.random.default_rng(0).standard_normal((500, 1))
    out = smo_gym.differentiate(y, 1e-3, "worst-case-optimal")  # calibrated from the signal itself
    assert out.shape == (500, 1, 2) and np.all(np.isfinite(out))
    assert isinstance(make_observer("worst-case-optimal", dt=1e-3, lipschitz=5.0), WorstCaseOptimal)


# ----------------------------------------------------------------------------------------------------------------
# the estimated noise bound
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("pattern", ["uniform", "signs"])
def test_the_noise_estimate_never_exceeds_the_bound_and_approaches_it(pattern, rng):
    r"""With ``noise=None`` the estimate :math:`\hat\epsilon_k` (the smallest bound the window's chords allow) is
    at most :math:`\epsilon` at every sample, on every signal with :math:`|f''| \le L` (a theorem, module notes).
    On stationary noise it comes close (window ``W = 32``, ``h = 1 ms``, ``L = 5``, :math:`\epsilon = 10^{-3}`;
    measured over 20 channels and 3000 samples): uniform noise, median 0.83, 5 % quantile 0.71 of
    :math:`\epsilon`; random signs, median 0.997. The estimate is the difference quotient over the lag
    :math:`\hat\jmath_k` the estimated bound makes best, so its error is within that lag's bound drawn with the true
    one, :math:`r_{\hat\jmath_k}`."""
    h, L, eps, T, W = 1e-3, 5.0, 1e-3, 3000, DEFAULT_ESTIMATION_WINDOW
    t = np.arange(T) * h
    f, df = random_sines(rng, t, 20, L)
    eta = noise_patterns(rng, f.shape, eps)[pattern]
    obs = WorstCaseOptimal(h, L)
    est, estimate = [obs.reset(f[0] + eta[0])], [obs.noise_estimate]
    for y in (f + eta)[1:]:
        est.append(obs.update(y))
        estimate.append(obs.noise_estimate)
    est, ratio = np.stack(est)[W:], np.stack(estimate)[W:] / eps
    assert np.all(ratio <= 1.0 + ROUNDING) and np.all(ratio >= 0.0)
    low, median = np.quantile(ratio, [0.05, 0.5])
    if pattern == "uniform":
        assert low > 0.65 and median > 0.8, (low, median)
    else:
        assert median > 0.99, median
    span = h * np.minimum(W, np.maximum(1, np.ceil(2.0 * np.sqrt(ratio * eps / L) / h)))
    guarantee = 2.0 * eps / span + 0.5 * L * span
    assert np.all(np.abs(est[..., 1] - df[W:]) <= guarantee + ROUNDING)


def reference_adaptive_difference(y, h, L, W):
    r"""The unknown-noise differentiator written from its equations, sample by sample in plain Python (an
    independent transcription): :math:`\hat\epsilon_k = \max(0, \max_{2 \le i \le w_k,\, 1 \le j < i}
    \tfrac12(|y_{k-j} - y_k + (y_k - y_{k-i})j/i| - Lh^2 j(i-j)/2))` with :math:`w_k = \min(k, W)`, the lag
    :math:`\hat\jmath_k = \min(w_k, \lceil 2\sqrt{\hat\epsilon_k/L}/h\rceil)` (1 where
    :math:`\hat\epsilon_k = 0`) and the derivative :math:`(y_k - y_{k-\hat\jmath})/(\hat\jmath h)`."""
    rates, noises = [0.0], [0.0]
    for k in range(1, len(y)):
        w = min(k, W)
        noise = 0.0
        for i in range(2, w + 1):
            for j in range(1, i):
                miss = y[k - j] - y[k] + (y[k] - y[k - i]) * j / i
                noise = max(noise, 0.5 * (abs(miss) - 0.5 * L * h * h * j * (i - j)))
        lag = 1 if noise == 0.0 else min(w, int(np.ceil(2.0 * np.sqrt(noise / L) / h)))
        rates.append((y[k] - y[k - lag]) / (lag * h))
        noises.append(noise)
    return np.array(rates), np.array(noises)


def test_the_unknown_noise_differentiator_follows_its_equations(rng):
    """Equal to the plain transcription (to rounding) on a noisy, quantized sine with an outlier, where the lag
    changes from sample to sample."""
    h, L, W = 1e-3, 5.0, 24
    t = np.arange(400) * h
    y = np.round((np.sin(3.0 * t) + rng.uniform(-1e-3, 1e-3, t.shape)) / 5e-4) * 5e-4
    y[200] += 0.02
    rates, noises = reference_adaptive_difference(y, h, L, W)
    obs = WorstCaseOptimal(h, L, window=W)
    obs.reset(y[:1])
    est, level = [0.0], [0.0]
    for v in y[1:]:
        est.append(obs.update(v[None])[0, 1])
        level.append(obs.noise_estimate[0])
    assert len(set(np.ceil(2.0 * np.sqrt(np.array(noises[W:]) / L) / h))) > 3  # the lag does change
    np.testing.assert_allclose(level, noises, rtol=0, atol=1e-15)
    np.testing.assert_allclose(est, rates, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize(
    ("h", "L", "eps"), [(1e-3, 5.0, 1e-3), (1e-3, 50.0, 1e-4), (1e-2, 5.0, 1e-2), (1e-3, 1.0, 1e-2)]
)
def test_the_unknown_noise_error_stays_below_the_published_worst_case(h, L, eps, rng):
    r"""Aldana-López et al. (2025) give :math:`2\sqrt{2\epsilon L} + Lh/2` as the worst-case error without a
    known noise bound, with the window :math:`W = \lceil\sqrt{2\epsilon/(Lh^2)} + 1\rceil` sized by a bound of
    the noise (the bound their reference implementation draws). Checked once the window is full, on random sines
    with :math:`|f''| \le L` under six noise patterns (uniform, random signs, alternating, random blocks, a ramp
    over the window that no chord sees, and blocks of one window): measured at most 0.79 of it, and above the
    known-noise optimum :math:`2\sqrt{\epsilon L}` by up to 26 %, the price of not knowing the noise."""
    T = 3000
    t = np.arange(T) * h
    f, df = random_sines(rng, t, 20, L)
    W = int(np.ceil(np.sqrt(2.0 * eps / (L * h * h)) + 1.0))
    k = np.arange(T)[:, None]
    patterns = noise_patterns(rng, f.shape, eps)
    patterns["ramp"] = eps * (2.0 * (k % W) / max(W - 1, 1) - 1.0) * np.ones(f.shape)
    patterns["window blocks"] = eps * np.where((k // W) % 2 == 0, 1.0, -1.0) * np.ones(f.shape)
    bound = 2.0 * np.sqrt(2.0 * eps * L) + 0.5 * L * h
    for name, eta in patterns.items():
        obs = WorstCaseOptimal(h, L, window=W)
        obs.reset(f[0] + eta[0])
        err = np.abs(obs.run((f + eta)[1:])[..., 1] - df[1:])[W:]
        assert err.max() <= bound, (name, err.max() / bound)


def test_the_noise_estimate_is_zero_on_exact_quadratics_and_forgets_an_outlier():
    """Exact samples of a quadratic within the bound miss no chord: the estimate is 0 and the differentiator the
    quasi-exact backward difference; an outlier raises it for ``W`` samples only."""
    h, L, W = 1e-3, 4.0, 16
    t = np.arange(100) * h
    y = (0.5 * L * t**2 - t)[:, None]
    y[40] += 0.01
    obs = WorstCaseOptimal(h, L, window=W)
    obs.reset(y[0])
    levels = []
    for v in y[1:]:
        obs.update(v)
        levels.append(float(obs.noise_estimate[0]))
    levels = np.array(levels)  # levels[k - 1] after sample k
    assert np.all(levels[: 40 - 1] < 1e-12) and levels[40 - 1] > 4e-3
    assert np.all(levels[40 + W :] < 1e-12)
