"""The Kalman filters told the control input (``KalmanCAInput``, ``KalmanIMMInput``) and the fit of their input
model (``fit_input_jumps``): what the jump model computes, against independent constructions."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from smo_gym._validation import DivergenceError
from smo_gym.observers import KalmanCA, KalmanCAInput, KalmanIMM, KalmanIMMInput, fit_input_jumps

DT = 1e-3
#: acceleration jump per unit change of each of two inputs, for three channels
GAIN = np.array([[40.0, 0.0], [-70.0, 5.0], [0.0, 60.0]])


def piecewise_run(rng, T=3000, period=5, gain=GAIN, jerk=0.0, miss=0.0):
    """Positions and velocities (T, 3) and inputs (T, 2) of a motion whose acceleration is constant over each
    sample interval but for white jerk of density ``jerk`` and jumps ``gain @ du`` (plus a miss of standard
    deviation ``miss * |du|``) where the input changes, every ``period`` samples: exactly the filters' model.
    Row ``k`` of the inputs acts over the interval ending at sample ``k``."""
    m = gain.shape[1]
    u = np.repeat(rng.uniform(-1, 1, (T // period + 1, m)), period, axis=0)[:T]
    u[0] = u[1]  # the input of the first interval is the reset's
    a = np.zeros(3)
    q, v = np.zeros((T, 3)), np.zeros((T, 3))
    for k in range(1, T):
        du = u[k] - u[k - 1]
        a = (
            a
            + gain @ du
            + miss * np.linalg.norm(du) * rng.standard_normal(3)
            + np.sqrt(jerk * DT) * rng.standard_normal(3)
        )
        q[k] = q[k - 1] + DT * v[k - 1] + DT**2 / 2 * a
        v[k] = v[k - 1] + DT * a
    return q, v, u


def test_the_fit_recovers_the_jump_model_it_was_generated_with():
    rng = np.random.default_rng(0)
    runs = [piecewise_run(rng, jerk=100.0, miss=2.0) for _ in range(4)]
    found = fit_input_jumps([v for _, v, _ in runs], [u for _, _, u in runs], DT)
    np.testing.assert_allclose(found.input_gain, GAIN, atol=0.3)  # ~6 standard errors; |G| up to 70
    # the residual's variance: q dt from the white jerk (every sample), s |du|^2 from the miss (at each change)
    np.testing.assert_allclose(found.process_noise, 100.0, rtol=0.15)
    np.testing.assert_allclose(found.jump_noise, 4.0, rtol=0.15)


def test_a_channel_the_episodes_never_move_is_fitted_as_still():
    """A joint the calibration episodes never move (Reacher's and Pusher's targets) has residuals of zero: the fit
    weighted them by 1 / 0, ran its least squares on NaN and raised numpy's LinAlgError (SVD did not converge).
    Now that channel gets no jump, no jump noise, the smallest positive process noise, and the others the fit
    they get alone; the filter built from it holds the still channel at rest."""
    rng = np.random.default_rng(7)
    runs = [piecewise_run(rng, T=600, jerk=10.0, miss=1.0) for _ in range(3)]
    inputs = [u for _, _, u in runs]
    found = fit_input_jumps([np.column_stack([v, np.zeros(len(v))]) for _, v, _ in runs], inputs, DT)
    alone = fit_input_jumps([v for _, v, _ in runs], inputs, DT)
    np.testing.assert_array_equal(found.input_gain[3], 0.0)
    assert found.jump_noise[3] == 0.0 and 0.0 < found.process_noise[3] < 1e-300
    for got, expected in zip(found, alone, strict=True):
        np.testing.assert_allclose(got[:3], expected, rtol=1e-12)
    q, _, u = runs[0]
    Y = np.column_stack([q, np.full(len(q), 0.3)])
    told = KalmanIMMInput(DT, found.process_noise, 1e-8, found.input_gain, found.jump_noise)
    told.reset(Y[0])
    estimate = told.run(Y[1:], u[1:])
    assert np.isfinite(estimate).all() and np.abs(estimate[:, 3, 1:]).max() == 0.0


def test_with_the_exact_jumps_the_estimate_is_exact_where_the_blind_filter_lags():
    """Noise-free positions of piecewise-constant acceleration, the exact gain, no miss: the model is exact, so
    after the prior is forgotten the posterior follows the truth (to round-off of the tiny measurement variance),
    while the same filter without the input lags each jump by many samples."""
    q, v, u = piecewise_run(np.random.default_rng(1))
    told = KalmanCAInput(DT, 1e-6, 1e-14, GAIN, 0.0, initial_std=(1.0, 100.0))
    blind = KalmanCA(DT, 1e-6, 1e-14, initial_std=(1.0, 100.0))
    told.reset(q[0])
    blind.reset(q[0])
    e_told = told.run(q[1:], u[1:])[..., 1] - v[1:]
    e_blind = blind.run(q[1:])[..., 1] - v[1:]
    late = slice(500, None)
    assert np.max(np.abs(e_told[late])) < 1e-6 * np.max(np.abs(v))
    assert np.max(np.abs(e_blind[late])) > 1e-3 * np.max(np.abs(v))


@pytest.mark.parametrize("cls, plain", [(KalmanCAInput, KalmanCA), (KalmanIMMInput, KalmanIMM)])
def test_without_an_input_change_it_is_the_filter_it_extends(cls, plain):
    rng = np.random.default_rng(2)
    y = np.cumsum(rng.normal(size=(200, 3)), axis=0) * 1e-3
    u = np.ones((200, 2))
    a, b = cls(DT, 50.0, 1e-6, GAIN, 3.0), plain(DT, 50.0, 1e-6)
    a.reset(y[0])
    b.reset(y[0])
    np.testing.assert_array_equal(a.run(y[1:], u[1:]), b.run(y[1:]))  # constant input: no jump, bit for bit
    np.testing.assert_array_equal(a.update(y[0]), b.update(y[0]))  # no input: the plain filter


@pytest.mark.parametrize("cls", [KalmanCAInput, KalmanIMMInput])
def test_a_batch_is_a_loop_over_its_elements_and_a_masked_reset_restarts_one(cls):
    """To round-off: the jumps of a batch are one matrix product, those of one element a vector product."""
    rng = np.random.default_rng(3)
    runs = [piecewise_run(rng, T=400, jerk=10.0) for _ in range(2)]
    Y = np.stack([q + 1e-4 * rng.standard_normal(q.shape) for q, _, _ in runs], axis=1)  # (T, 2, 3)
    U = np.stack([u for _, _, u in runs], axis=1)  # (T, 2, 2)
    batch = cls(DT, 100.0, 1e-8, GAIN, 1.0)
    batch.reset(Y[0])
    together = batch.run(Y[1:301], U[1:301])
    for i in range(2):
        alone = cls(DT, 100.0, 1e-8, GAIN, 1.0)
        alone.reset(Y[0, i])
        np.testing.assert_allclose(alone.run(Y[1:301, i], U[1:301, i]), together[:, i], rtol=1e-9, atol=1e-9)
    # environment 1 restarts at its sample 300 (as a vector env's does, after the step): environment 0 goes on as
    # if nothing happened, and 1 as a fresh filter (whose first update predicts no jump: its input is forgotten)
    batch.reset(Y[300], mask=np.array([False, True]))
    after = batch.run(Y[301:], U[301:])
    alone = cls(DT, 100.0, 1e-8, GAIN, 1.0)
    alone.reset(Y[0, 0])
    np.testing.assert_allclose(alone.run(Y[1:, 0], U[1:, 0])[300:], after[:, 0], rtol=1e-9, atol=1e-9)
    fresh = cls(DT, 100.0, 1e-8, GAIN, 1.0)
    fresh.reset(Y[300, 1])
    np.testing.assert_allclose(fresh.run(Y[301:, 1], U[301:, 1]), after[:, 1], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("cls", [KalmanCAInput, KalmanIMMInput])
def test_a_rejected_sample_or_input_leaves_the_state_as_it_was(cls):
    obs, twin = cls(DT, 100.0, 1e-8, GAIN, 1.0), cls(DT, 100.0, 1e-8, GAIN, 1.0)
    for o in (obs, twin):
        o.reset(np.zeros(3))
        o.update(np.full(3, 1e-4), np.ones(2))
    state, estimate = obs.state.copy(), obs.estimate.copy()
    for y, u, error in [
        (np.array([np.nan, 0, 0]), np.ones(2), ValueError),  # the jump was applied before the sample was refused
        (np.array([np.nan, 0, 0]), None, ValueError),  # the last input is not forgotten for a refused sample
        (np.zeros(3), np.array([np.inf, 0.0]), ValueError),
        (np.zeros(3), np.ones(3), ValueError),  # one input too many
        (np.zeros(3), "ab", TypeError),
        (np.zeros(2), np.ones(2), ValueError),
    ]:
        with pytest.raises(error):
            obs.update(y, u)
        np.testing.assert_array_equal(obs.state, state)
        np.testing.assert_array_equal(obs.estimate, estimate)
    # and it goes on as if nothing had been refused: the next input's jump is measured from the last one taken
    np.testing.assert_array_equal(
        obs.update(np.full(3, 2e-4), 3 * np.ones(2)), twin.update(np.full(3, 2e-4), 3 * np.ones(2))
    )
    state = obs.state.copy()
    Y, U = np.full((5, 3), 1e-4), np.ones((5, 2))
    Y[3, 1] = np.nan
    with pytest.raises(ValueError):
        obs.run(Y, U)  # all or nothing
    np.testing.assert_array_equal(obs.state, state)
    with pytest.raises(ValueError, match="U with shape"):
        obs.run(Y[:2], U[:3])
    with pytest.raises(NotImplementedError, match="update"):
        obs.step(obs.state, np.zeros(3))


def test_bad_input_models_are_refused_with_what_was_expected():
    with pytest.raises(ValueError, match="input_gain of shape"):
        KalmanCAInput(DT, 1.0, 1e-6, np.ones(3))
    with pytest.raises(ValueError, match="jump_noise >= 0"):
        KalmanCAInput(DT, 1.0, 1e-6, GAIN, -1.0)
    with pytest.raises(ValueError, match="jump_noise"):
        KalmanCAInput(DT, 1.0, 1e-6, GAIN, np.ones(2))
    with pytest.raises(ValueError, match="3 channels"):
        KalmanCAInput(DT, 1.0, 1e-6, GAIN).reset(np.zeros(2))
    with pytest.raises(ValueError, match="changes at least twice"):
        fit_input_jumps([np.zeros((10, 3))], [np.ones((10, 2))], DT)
    with pytest.raises(ValueError, match="finite episodes"):
        fit_input_jumps([np.zeros((10, 3))], [np.ones((9, 2))], DT)


@pytest.mark.parametrize("cls", [KalmanCAInput, KalmanIMMInput])
def test_a_pickled_filter_goes_on_as_the_original(cls):
    q, _, u = piecewise_run(np.random.default_rng(4), T=200, jerk=10.0)
    obs = cls(DT, 100.0, 1e-8, GAIN, 1.0)
    obs.reset(q[0])
    obs.run(q[1:100], u[1:100])
    copy = pickle.loads(pickle.dumps(obs))
    np.testing.assert_array_equal(copy.run(q[100:], u[100:]), obs.run(q[100:], u[100:]))


def test_a_checkpoint_would_miss_the_last_input_so_it_is_refused():
    """``Observer.checkpoint`` copies the state, the estimate and the count; the told filters also keep the last
    input, which a restore would not bring back: they refuse instead of restoring half their memory."""
    told = KalmanCAInput(DT, 1e-6, 1e-14, GAIN, 0.0)
    told.reset(np.zeros(GAIN.shape[0]))
    with pytest.raises(TypeError, match="takes one"):
        told.checkpoint()


# ---- on some channels: a part of a composite ("auto" takes a told filter on the joints where it wins) -----------
def _told_run(rng, T=600):
    runs = [piecewise_run(rng, T=T, jerk=10.0) for _ in range(2)]
    Y = np.stack([q + 1e-4 * rng.standard_normal(q.shape) for q, _, _ in runs], axis=1)  # (T, 2, 3)
    return Y, np.stack([u for _, _, u in runs], axis=1)  # (T, 2, 2)


@pytest.mark.parametrize("cls", [KalmanCAInput, KalmanIMMInput])
def test_on_some_of_its_channels_a_told_filter_estimates_exactly_what_it_does_there(cls):
    """Its channels are independent given the input: the filter on channels [2, 0] is, bit for bit, the whole
    filter's channels 2 and 0, with each per-channel parameter (the prior's too) taken there and the shared ones
    kept."""
    Y, U = _told_run(np.random.default_rng(4))
    whole = cls(DT, np.array([50.0, 100.0, 200.0]), np.array([1e-8, 2e-8, 4e-8]), GAIN, np.array([1.0, 2.0, 3.0]),
                wrap=np.array([False, True, False]), huber=3.0,
                initial_std=(np.array([1.0, 2.0, 3.0]), 50.0))  # fmt: skip
    part = whole.of_channels([2, 0])
    np.testing.assert_array_equal(part.input_gain, GAIN[[2, 0]])
    np.testing.assert_array_equal(part.process_noise, [200.0, 50.0])
    np.testing.assert_array_equal(part.wrap, [False, False])
    np.testing.assert_array_equal(part.initial_std[0], [3.0, 1.0])
    assert part.initial_std[1] == 50.0
    assert part.huber == 3.0 and part.dt == DT and type(part) is cls
    whole.reset(Y[0])
    part.reset(Y[0][..., [2, 0]])
    np.testing.assert_array_equal(part.run(Y[1:, :, [2, 0]], U[1:]), whole.run(Y[1:], U[1:])[:, :, [2, 0]])
    with pytest.raises(ValueError, match=r"channels in 0\.\.2"):
        whole.of_channels([3])


def _composite_parts(told):
    """The told filter on channels 0 and 2, a plain Kalman filter and a backward difference on 1 (as "auto"
    builds them: the parts' channels in order)."""
    from smo_gym.observers import FiniteDifference

    return [(told.of_channels([0, 2]), [0, 2]), (KalmanCA(DT, 30.0, 1e-8), [1])], FiniteDifference(DT)


@pytest.mark.parametrize("cls", [KalmanCAInput, KalmanIMMInput])
def test_a_composite_with_a_told_part_is_its_parts_side_by_side(cls):
    """``PerChannelInput``: on the told part's channels the whole told filter, bit for bit (the jumps move only
    their rows); on the others the plain observer; a batch is a loop over its elements, a masked reset restarts
    one, a pickled copy goes on as the original."""
    from smo_gym.observers import PerChannelInput

    Y, U = _told_run(np.random.default_rng(5))
    told = cls(DT, 100.0, 1e-8, GAIN, 1.0)
    parts, _ = _composite_parts(told)
    composite = PerChannelInput(parts)
    np.testing.assert_array_equal(composite.input_gain, [[40.0, 0.0], [0.0, 0.0], [0.0, 60.0]])
    composite.reset(Y[0])
    together = composite.run(Y[1:301], U[1:301])
    told.reset(Y[0])
    np.testing.assert_array_equal(together[..., [0, 2], :2], told.run(Y[1:301], U[1:301])[..., [0, 2], :2])
    plain = KalmanCA(DT, 30.0, 1e-8)
    plain.reset(Y[0, :, [1]].T)
    np.testing.assert_array_equal(together[..., [1], :2], plain.run(Y[1:301, :, [1]])[..., :2])
    for i in range(2):
        alone = PerChannelInput(parts)
        alone.reset(Y[0, i])
        np.testing.assert_allclose(alone.run(Y[1:301, i], U[1:301, i]), together[:, i], rtol=1e-12, atol=1e-12)
    copy = pickle.loads(pickle.dumps(composite))
    composite.reset(Y[300], mask=np.array([False, True]))
    after = composite.run(Y[301:], U[301:])
    fresh = PerChannelInput(parts)
    fresh.reset(Y[300, 1])
    np.testing.assert_allclose(fresh.run(Y[301:, 1], U[301:, 1]), after[:, 1], rtol=1e-12, atol=1e-12)
    copy.reset(Y[300], mask=np.array([False, True]))
    np.testing.assert_array_equal(copy.run(Y[301:], U[301:]), after)


def test_a_composite_with_a_told_part_refuses_what_it_cannot_take_and_keeps_its_state():
    from smo_gym.observers import PerChannel, PerChannelInput

    told = KalmanIMMInput(DT, 100.0, 1e-8, GAIN, 1.0)
    parts, fd = _composite_parts(told)
    with pytest.raises(TypeError, match=r"use smo_gym\.observers\.PerChannelInput"):
        PerChannel(parts)
    with pytest.raises(ValueError, match="none told the input; use PerChannel"):
        PerChannelInput([(fd, [0, 2]), (KalmanCA(DT, 30.0, 1e-8), [1])])

    class Told(KalmanIMM):  # takes an input the composite would not know how to pass on
        takes_input = True

    with pytest.raises(TypeError, match="InputJumpFilter"):
        PerChannelInput([parts[0], (Told(DT, 30.0, 1e-8), [1])])
    other = KalmanCAInput(DT, 100.0, 1e-8, np.ones((1, 3)), 1.0)  # three inputs against two
    with pytest.raises(ValueError, match=r"inputs \[2, 3\]"):
        PerChannelInput([parts[0], (other, [1])])
    composite = PerChannelInput(parts)
    composite.reset(np.zeros(3))
    composite.update(np.full(3, 1e-4), np.ones(2))
    state, estimate = composite.state.copy(), composite.estimate.copy()
    for y, u in [(np.array([0, np.nan, 0]), 2 * np.ones(2)), (np.zeros(3), np.ones(3)), (np.zeros(3), [np.nan, 0])]:
        with pytest.raises(ValueError):  # the first after the told part's jump: the jump is undone
            composite.update(y, u)
        np.testing.assert_array_equal(composite.state, state)
        np.testing.assert_array_equal(composite.estimate, estimate)


@pytest.mark.parametrize("kind", ["kalman-ca-input", "kalman-imm-input", "composite"])
def test_a_run_is_its_updates_sample_by_sample(kind):
    """``run`` is ``update`` sample by sample, bit for bit, through changes of input (the told part of a composite
    too), and all or nothing: a block refused in its middle, by a sample or by a diverging state, leaves the state,
    the estimate and the last input as they were (the jumps already applied undone)."""
    from smo_gym.observers import PerChannelInput

    Y, U = _told_run(np.random.default_rng(6), T=200)
    cls = KalmanCAInput if kind == "kalman-ca-input" else KalmanIMMInput

    def make():
        told = cls(DT, 100.0, 1e-8, GAIN, 1.0)
        return PerChannelInput(_composite_parts(told)[0]) if kind == "composite" else told

    a, b = make(), make()
    a.reset(Y[0])
    b.reset(Y[0])
    np.testing.assert_array_equal(
        a.run(Y[1:], U[1:]), np.stack([b.update(y, u) for y, u in zip(Y[1:], U[1:], strict=True)])
    )
    np.testing.assert_array_equal(a.state, b.state)
    assert a.n_updates == b.n_updates == len(Y) - 1
    state, estimate = a.state.copy(), a.estimate.copy()
    for value, error in [(np.nan, ValueError), (1e300, DivergenceError)]:  # the IMM estimator's state overflows
        if kind == "kalman-ca-input" and error is DivergenceError:
            continue  # its state stays finite
        bad = Y[:20].copy()
        bad[12, :, 0] = value  # after three changes of input
        with pytest.raises(error, match="finite"):
            a.run(bad, U[:20])
        np.testing.assert_array_equal(a.state, state)
        np.testing.assert_array_equal(a.estimate, estimate)
    np.testing.assert_array_equal(
        a.run(Y[:20], U[:20]), np.stack([b.update(y, u) for y, u in zip(Y[:20], U[:20], strict=True)])
    )


@pytest.mark.parametrize("cls", [KalmanCAInput, KalmanIMMInput])
def test_the_input_model_may_be_replaced_by_one_of_the_same_shape(cls):
    """``input_gain`` and ``jump_noise`` may be replaced: from the next update on the filter jumps as one built with
    them (set right after a reset: the same estimates bit for bit; mid-run: the last input is still known, so the
    next change of input jumps). A gain of another shape, which the compiled jump would index out of its rows, is
    refused and changes nothing."""
    Y, U = _told_run(np.random.default_rng(8), T=200)
    built = cls(DT, 100.0, 1e-8, 2.0 * GAIN, 3.0)
    replaced = cls(DT, 100.0, 1e-8, np.zeros_like(GAIN), 0.0)
    built.reset(Y[0])
    replaced.reset(Y[0])
    replaced.input_gain, replaced.jump_noise = 2.0 * GAIN, 3.0
    np.testing.assert_array_equal(replaced.run(Y[1:100], U[1:100]), built.run(Y[1:100], U[1:100]))
    replaced.input_gain = 2.0 * GAIN  # a new array of the same values, between two changes of input
    for bad, error in [(np.ones((3, 3)), ValueError), (np.ones((2, 2)), ValueError), ("ab", TypeError)]:
        with pytest.raises(error):
            replaced.input_gain = bad
    with pytest.raises(ValueError, match="jump_noise"):
        replaced.jump_noise = -1.0
    np.testing.assert_array_equal(replaced.jump_noise, [3.0, 3.0, 3.0])
    np.testing.assert_array_equal(replaced.run(Y[100:], U[100:]), built.run(Y[100:], U[100:]))


@pytest.mark.parametrize("cls", [KalmanCAInput, KalmanIMMInput])
def test_from_episodes_starts_each_channel_where_its_episodes_start(cls):
    """The prior at reset is where the episodes start, per channel (the calibration of their velocities, as the
    wrapper's Kalman filters get it): episodes whose joints start at velocities of spread 0.01, 0.1 and 1 give those
    spreads, not the constructor's wide (10, 100), whose first estimates were least-squares fits of a few noisy
    samples; a prior given is kept."""
    from smo_gym.calibration import calibration_from_velocities

    rng = np.random.default_rng(8)
    runs = [piecewise_run(rng, T=300, jerk=10.0) for _ in range(12)]
    velocity = [v + rng.normal(0.0, [0.01, 0.1, 1.0]) for _, v, _ in runs]
    inputs = [u for _, _, u in runs]
    told = cls.from_episodes(DT, velocity, inputs, 1e-8)
    starts = calibration_from_velocities(velocity, DT, (1,), noise=0.0).initial
    for r, std in zip((1, 2), told.initial_std, strict=True):
        np.testing.assert_array_equal(std, starts[r])
    assert 0.005 < told.initial_std[0][0] < 0.02 and 0.5 < told.initial_std[0][2] < 2.0
    assert cls.from_episodes(DT, velocity, inputs, 1e-8, initial_std=(10.0, 100.0)).initial_std == (10.0, 100.0)
