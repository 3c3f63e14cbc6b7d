"""The compiled kernels' fast paths: vectorizable roots, specialised steps, status codes.

The batch kernels of :mod:`smo_gym.observers._kernels` run specialised, vectorized loops for the common orders;
these tests hold them to the generic per-channel steps they replace, and the helper maths to long-double
references.
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from smo_gym.observers import URED, Levant, SuperTwisting, UniformLevant
from smo_gym.observers import _kernels as K


@njit(error_model="numpy")
def _cbrt_all(x):
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = K.cbrt(x[i])
    return out


@njit(error_model="numpy")
def _exp_all(x):
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = K.exp_nonpositive(x[i])
    return out


@njit(error_model="numpy")
def _generic_hosm(state, y, params, new_state, out):
    """The generic per-channel HOSM step (what ``hosm_kernel`` ran for every exponent table before)."""
    m = out.shape[1]
    for c in range(y.shape[0]):
        new_state[c, m] = K.hosm_channel_step(state[c], y[c], params[c], m, new_state[c], out[c])


@njit(error_model="numpy")
def _generic_eigmap(state, y, params, new_state, out):
    m = out.shape[1]
    for c in range(y.shape[0]):
        new_state[c, m] = K.eigmap_channel_step(state[c], y[c], params[c], m, new_state[c], out[c])


def _ulp_error(got, ref):
    """|got - ref| in units of the last place of ``got`` (``ref`` in long double)."""
    spacing = np.spacing(np.maximum(np.abs(got), np.finfo(float).tiny)).astype(np.longdouble)
    return (np.abs(got.astype(np.longdouble) - ref) / spacing).astype(float)


def test_cbrt_is_within_one_ulp_including_zero_and_subnormals():
    x = np.concatenate(
        [
            [0.0, 5e-324, 1e-310, 2.2250738585072014e-308, 1.0, 8.0, 27.0, 1e300],
            np.logspace(-320, 307, 20001),
            np.random.default_rng(0).uniform(0, 10, 20000),
        ]
    )
    got = _cbrt_all(x)
    assert got[0] == 0.0 and got[5] == 2.0 and got[6] == 3.0
    assert _ulp_error(got[1:], np.cbrt(x[1:].astype(np.longdouble))).max() < 1.0


def test_exp_nonpositive_is_within_one_ulp_and_underflows_to_zero():
    x = np.concatenate(
        [
            [0.0, -0.0, -1e-300, -708.4, -709.0, -744.0, -745.1],
            -np.logspace(-20, np.log10(700.0), 20001),
            -np.random.default_rng(1).uniform(0, 50, 20000),
        ]
    )
    got = _exp_all(x)
    assert _ulp_error(got, np.exp(x.astype(np.longdouble))).max() < 1.0
    assert _exp_all(np.array([-746.0, -1e300, -np.inf])).tolist() == [0.0, 0.0, 0.0]
    assert np.isnan(_exp_all(np.array([np.nan]))[0])


HOSM_OBSERVERS = [
    ("super-twisting euler", lambda L: SuperTwisting(1e-3, L, discretization="euler")),
    ("levant k=1", lambda L: Levant(1, 1e-3, L)),
    ("levant k=2 taylor", lambda L: Levant(2, 1e-3, L)),
    ("levant k=2 euler", lambda L: Levant(2, 1e-3, L, discretization="euler")),
    ("ured", lambda L: URED(1e-3, L)),
    ("uniform levant k=2 euler", lambda L: UniformLevant(2, 1e-3, L)),
    ("uniform levant k=2 taylor", lambda L: UniformLevant(2, 1e-3, L, discretization="taylor")),
    ("levant k=3 (generic)", lambda L: Levant(3, 1e-3, L)),
    ("uniform levant alpha=0.5 (generic)", lambda L: UniformLevant(2, 1e-3, L, alpha=0.5)),
]


@pytest.mark.parametrize("name, build", HOSM_OBSERVERS, ids=[n for n, _ in HOSM_OBSERVERS])
@pytest.mark.parametrize("n", [1, 5, 33])
def test_specialised_hosm_steps_equal_the_generic_step(name, build, n):
    """The specialised steps (m = 2, 3, known exponents) do the generic step's operations: equal to 1e-15."""
    rng = np.random.default_rng(n)
    obs = build(1.0 + rng.uniform(0, 50, n))
    y0 = rng.standard_normal(n)
    obs.reset(y0)
    state = obs.state
    state[:, 1 : obs.order + 1] = rng.standard_normal((n, obs.order))
    for y in (y0 + 1e-3 * rng.standard_normal(n), y0 + 10.0 * rng.standard_normal(n)):
        y[-1] = state[-1, 0]  # a zero error (sign 0) in the batch
        fast_state, fast_out = np.empty_like(state), np.empty((n, obs.order + 1))
        ref_state, ref_out = np.empty_like(state), np.empty((n, obs.order + 1))
        assert K.hosm_kernel(state, y, obs._params, fast_state, fast_out) == -1
        _generic_hosm(state, y, obs._params, ref_state, ref_out)
        np.testing.assert_allclose(fast_state, ref_state, rtol=1e-15, atol=1e-300)
        np.testing.assert_allclose(fast_out, ref_out, rtol=1e-15, atol=1e-300)


@pytest.mark.parametrize("mixed", [False, True])
def test_eigenvalue_mapping_kernel_equals_the_generic_step(mixed):
    """m = 3 runs five vectorized passes per mapping; rows of mixed mappings fall back to the generic step."""
    rng = np.random.default_rng(3)
    n = 19
    obs = Levant(2, 1e-2, 1.0 + rng.uniform(0, 50, n), discretization="semi-implicit", mu=0.5)
    obs.reset(rng.standard_normal(n))
    params = obs._params.copy()
    if mixed:
        params[::3, 3] = 1.0  # every third row uses the matching mapping
    state = obs.state
    state[:, 1:3] = rng.standard_normal((n, 2))
    y = rng.standard_normal(n)
    fast_state, fast_out = np.empty_like(state), np.empty((n, 3))
    ref_state, ref_out = np.empty_like(state), np.empty((n, 3))
    assert K.eigmap_kernel(state, y, params, fast_state, fast_out) == -1
    _generic_eigmap(state, y, params, ref_state, ref_out)
    np.testing.assert_array_equal(fast_state, ref_state)
    np.testing.assert_array_equal(fast_out, ref_out)


@pytest.mark.parametrize(
    "build",
    [
        lambda: Levant(2, 1e-3, 5.0),
        lambda: URED(1e-3, 5.0),
        lambda: Levant(2, 1e-3, 5.0, discretization="matching"),
        lambda: SuperTwisting(1e-3, 5.0),
    ],
)
def test_status_codes_of_the_vectorized_loops(build):
    """A non-finite measurement: its index, nothing written; a non-finite new state: ``-2 - i`` of the first."""
    obs = build()
    n = 12
    obs.reset(np.zeros(n))
    state = obs.state
    new_state = np.full_like(state, 7.0)
    out = np.full((n, obs.order + 1), 7.0)
    y = np.zeros(n)
    y[5] = np.nan
    assert obs._kernel(state, y, obs._params, new_state, out) == 5
    assert np.all(new_state == 7.0) and np.all(out == 7.0)
    y = np.zeros(n)
    y[3] = y[9] = -1e308  # the error overflows in channels 3 and 9
    state[3, 0] = state[9, 0] = 1.5e308
    assert obs._kernel(state, y, obs._params, new_state, out) == -2 - 3


def test_kernels_reject_arrays_of_the_wrong_width():
    obs = Levant(2, 1e-3, 5.0)
    obs.reset(np.zeros(4))
    with pytest.raises(ValueError, match="expected state/new_state"):
        K.hosm_kernel(obs.state, np.zeros(4), obs._params, np.empty((4, 5)), np.empty((4, 3)))


_SHARED_CASES = {
    "super-twisting implicit": dict(name="super-twisting", lipschitz=3.0),
    "super-twisting euler": dict(name="super-twisting", lipschitz=3.0, discretization="euler"),
    "levant k=1": dict(name="levant", order=1, lipschitz=3.0),
    "levant k=2 taylor": dict(name="levant", order=2, lipschitz=3.0),
    "levant k=2 euler": dict(name="levant", order=2, lipschitz=3.0, discretization="euler"),
    "levant k=3": dict(name="levant", order=3, lipschitz=3.0),
    "levant k=2 semi-implicit": dict(name="levant", order=2, lipschitz=3.0, discretization="semi-implicit"),
    "levant k=2 matching": dict(name="levant", order=2, lipschitz=3.0, discretization="matching"),
    "ured": dict(name="ured", lipschitz=3.0),
    "uniform-levant": dict(name="uniform-levant", order=2, lipschitz=3.0),
    "high-gain k=2": dict(name="high-gain", order=2, gain=30.0),
    "finite-difference k=2": dict(name="finite-difference", order=2),
    "kalman-ca": dict(name="kalman-ca", process_noise=1e2, measurement_noise=1e-6),
}


@pytest.mark.parametrize("case", list(_SHARED_CASES))
def test_shared_parameter_kernels_equal_the_per_channel_kernels(case):
    """Channels with one parameter row run the ``*_shared_kernel`` variant: bit-identical to the per-channel one."""
    from smo_gym.observers import make_observer

    params = dict(_SHARED_CASES[case])
    obs = make_observer(params.pop("name"), dt=1e-2, **params)
    rng = np.random.default_rng(3)
    t = 1e-2 * np.arange(60)[:, None, None]
    Y = np.sin(t * rng.uniform(0.5, 3.0, (1, 4, 7))) + 1e-3 * rng.standard_normal((60, 4, 7))
    obs.reset(Y[0])
    kernel, row = obs._step_kernel()
    assert kernel is K.SHARED_KERNELS[obs._kernel] and row.shape == (1, obs._params.shape[1])
    np.testing.assert_array_equal(row[0], obs._params[5])
    state = obs.state
    for y in Y[1:]:
        new_state, out = np.empty_like(state), np.empty(obs.estimate.shape[:-1] + (obs.order + 1,))
        assert obs._kernel(state, y, obs._params, new_state, out) == -1  # per-channel rows
        np.testing.assert_array_equal(obs.update(y), out)  # update(): the shared variant
        np.testing.assert_array_equal(obs.state, new_state)
        state = new_state


def test_per_channel_parameters_keep_the_per_channel_kernel_and_rows_are_checked():
    obs = Levant(2, 1e-2, np.array([1.0, 2.0, 3.0]))
    obs.reset(np.zeros(3))
    kernel, params = obs._step_kernel()
    assert kernel is K.hosm_kernel and params is obs._params
    state, out = obs.state, np.empty((3, 3))
    with pytest.raises(ValueError, match="one row per channel"):  # a shared row given to the per-channel kernel
        K.hosm_kernel(state, np.ones(3), obs._params[:1].copy(), np.empty_like(state), out)
    with pytest.raises(ValueError, match="one row per channel"):  # per-channel rows given to the shared variant
        K.hosm_shared_kernel(state, np.ones(3), obs._params, np.empty_like(state), out)
    single = Levant(2, 1e-2, 1.0)
    single.reset(np.zeros(1))
    assert single._step_kernel()[0] is K.hosm_kernel  # one channel: nothing to share
