"""The offline time loop (``_kernels.run_offline``) against the per-sample kernel it drives.

The loop alternates two state buffers, two samples at a time, so each parity of the record length and of a failing
sample takes its own branch: every one must report the failing sample and leave the last accepted state, exactly
as stepping the kernel one sample at a time does.
"""

from __future__ import annotations

import numpy as np
import pytest

from smo_gym.observers import Levant, SuperTwisting
from smo_gym.observers import _kernels as K

N = 5  # channels (not a multiple of the vector width: the kernels' scalar tails run too)


def _observer(name):
    if name == "super-twisting":  # the implicit super-twisting kernel
        return SuperTwisting(dt=1e-3, lipschitz=50.0)
    return Levant(order=1, dt=1e-3, lipschitz=50.0)  # the HOSM kernel


def _stepped(obs, state, Y):
    """``(status, t, state, out)`` of the kernel applied sample by sample (the reference of ``run_offline``)."""
    kernel, params = obs._kernel, obs._params
    out = np.full((Y.shape[0], N, obs.order + 1), np.nan)
    for t in range(Y.shape[0]):
        new = np.empty_like(state)
        status = kernel(state, Y[t], params, new, out[t])
        if status != -1:
            return status, t, state, out
        state = new
    return -1, Y.shape[0], state, out


def _failure_index(T, fail):
    """The sample made non-finite for a failure label (None: none)."""
    return {"first": 0, "last": T - 1, "odd": min(1, T - 1), "even": min(2, T - 1)}.get(fail)


def _cases():
    """``(T, fail)`` with every label a case of its own: a failure at a sample another label already covers at
    that ``T`` is left out (at ``T = 1`` every position is the first), and so are alternating samples at ``T = 1``."""
    cases = []
    for T in (1, 2, 7, 8):
        seen = set()
        for fail in (None, "first", "last", "odd", "even", "divergence"):
            where = _failure_index(T, fail)
            if (where is not None and where in seen) or (fail == "divergence" and T == 1):
                continue
            seen.add(where)
            cases.append((T, fail))
    return cases


@pytest.mark.parametrize("name", ["super-twisting", "levant"])
@pytest.mark.parametrize(("T", "fail"), _cases())
def test_run_offline_equals_the_kernel_stepped_sample_by_sample(name, T, fail):
    rng = np.random.default_rng(T)
    obs = _observer(name)
    obs.reset(rng.standard_normal(N))
    Y = np.cumsum(1e-3 * rng.standard_normal((T, N)), axis=0)
    where = _failure_index(T, fail)
    if where is not None:
        Y[where, 3] = np.nan
    if fail == "divergence":  # finite samples of alternating sign at the largest float: the innovation overflows
        Y[:, 2] = np.finfo(float).max * (-1.0) ** np.arange(T)
    state0 = obs._state.copy()
    status, t, ref_state, ref_out = _stepped(obs, state0.copy(), Y)
    if where is not None:  # a non-finite sample: the kernel names its channel
        assert (status, t) == (3, where)
    elif fail == "divergence" and T > 1 and name == "super-twisting":  # the implicit step overflows; Levant does not
        assert status < -1 and t <= 1
    state = state0.copy()
    out = np.full_like(ref_out, np.nan)
    assert K.run_offline(obs._kernel, state, Y, obs._params, out) == (status, t)
    np.testing.assert_array_equal(state, ref_state)  # the last accepted state, after t samples
    np.testing.assert_array_equal(out[:t], ref_out[:t])


@pytest.mark.parametrize("name", ["super-twisting", "levant"])
@pytest.mark.parametrize("wrap", [False, True])
def test_run_with_shared_gains_equals_the_per_channel_driver(name, wrap):
    """``Observer.run`` with scalar gains drives the shared-parameter kernel; it must give the per-channel
    driver's results bit for bit (the same arithmetic with the parameters loop invariant)."""
    rng = np.random.default_rng(0)
    obs = _observer(name)
    obs.reset(rng.standard_normal(N))
    Y = np.cumsum(1e-2 * rng.standard_normal((9, N)), axis=0)
    period = np.full(N, 2 * np.pi) if wrap else None
    kernel, params = obs._step_kernel()
    assert kernel is K.STEPS[obs._kernel].shared_kernel and params.shape[0] == 1
    results = []
    for k, p in ((obs._kernel, obs._params), (kernel, params)):
        state, out = obs._state.copy(), np.full((9, N, obs.order + 1), np.nan)
        assert K.run_offline(k, state, Y, p, out, period) == (-1, 9)
        results.append((state, out))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])
    if not wrap:  # Observer.run takes the shared path
        np.testing.assert_array_equal(obs.run(Y), results[0][1])
