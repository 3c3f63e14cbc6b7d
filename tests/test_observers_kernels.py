"""The compiled kernels: vectorizable roots, status codes, widths, the shared-parameter variants.

The helper maths of :mod:`smo_gym.observers._kernels` is held to long-double references.
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from smo_gym.observers import URED, Levant, SuperTwisting
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


@pytest.mark.parametrize(
    "build",
    [
        lambda: Levant(2, 1e-3, 5.0, discretization="taylor"),
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
    obs = Levant(2, 1e-3, 5.0, discretization="taylor")
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
    "discrete-hosm n=3 semi-implicit": dict(name="discrete-hosm", n=3, p1=10.0),
    "discrete-hosm n=2 matching": dict(name="discrete-hosm", n=2, p1=10.0, discretization="matching"),
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
    assert kernel is K.STEPS[obs._kernel].shared_kernel and row.shape == (1, obs._params.shape[1])
    np.testing.assert_array_equal(row[0], obs._params[5])
    state = obs.state
    for y in Y[1:]:
        new_state, out = np.empty_like(state), np.empty(obs.estimate.shape[:-1] + (obs.order + 1,))
        assert obs._kernel(state, y, obs._params, new_state, out) == -1  # per-channel rows
        np.testing.assert_array_equal(obs.update(y), out)  # update(): the shared variant
        np.testing.assert_array_equal(obs.state, new_state)
        state = new_state


def test_per_channel_parameters_keep_the_per_channel_kernel_and_rows_are_checked():
    obs = Levant(2, 1e-2, np.array([1.0, 2.0, 3.0]), discretization="taylor")
    obs.reset(np.zeros(3))
    kernel, params = obs._step_kernel()
    assert kernel is K.hosm_kernel and params is obs._params
    state, out = obs.state, np.empty((3, 3))
    with pytest.raises(ValueError, match="one row per channel"):  # a shared row given to the per-channel kernel
        K.hosm_kernel(state, np.ones(3), obs._params[:1].copy(), np.empty_like(state), out)
    with pytest.raises(ValueError, match="one row per channel"):  # per-channel rows given to the shared variant
        K.hosm_shared_kernel(state, np.ones(3), obs._params, np.empty_like(state), out)
    single = Levant(2, 1e-2, 1.0, discretization="taylor")
    single.reset(np.zeros(1))
    assert single._step_kernel()[0] is K.hosm_kernel  # one channel: nothing to share
