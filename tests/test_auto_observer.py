"""``observer="auto"``: per-channel observers (:class:`PerChannel`), the choice among candidates
(:mod:`smo_gym.selection`), and the default of the wrapper and of ``differentiate``."""

from __future__ import annotations

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest
from conftest import UnregisteredFiniteDifference

import smo_gym
from smo_gym import selection
from smo_gym.calibration import Calibration
from smo_gym.engine.measurement import VelocityEstimator
from smo_gym.observers import DivergenceError, FiniteDifference, KalmanCA, Levant, PerChannel
from smo_gym.selection import Selection, Trials, auto_observer, predicted_errors, select
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers import estimated_velocity as ev_module
from smo_gym.wrappers.adapters import make_adapter

DT = 1e-3


def _parts():
    return [
        (KalmanCA(dt=DT, process_noise=[1e3, 2e3], measurement_noise=1e-6), [2, 0]),
        (FiniteDifference(dt=DT), [1]),
        (Levant(dt=DT, order=2, lipschitz=5.0, discretization="implicit"), [3]),
    ]


def _signal(T: int = 400, batch: tuple[int, ...] = ()) -> np.ndarray:
    t = np.arange(T) * DT
    rng = np.random.default_rng(0)
    phases = rng.uniform(0, 2 * np.pi, batch + (4,))
    return np.sin(3 * t[:, *([None] * (len(batch) + 1))] + phases) + 1e-4 * rng.standard_normal((T, *batch, 4))


def _assert_each_part_alone(composite, parts, Y):
    """The composite's value and velocity on ``Y`` (T, n) are, bit for bit, each part's own on its channels."""
    composite.reset(Y[0])
    got = composite.run(Y[1:])
    for observer, channels in parts:
        observer.reset(Y[0, channels])
        want = observer.run(Y[1:, channels])
        np.testing.assert_array_equal(got[:, channels, :2], want[..., :2])


# ---- PerChannel ---------------------------------------------------------------------------------------------------
def test_per_channel_equals_each_part_on_its_channels():
    Y = _signal()
    composite = PerChannel(_parts(), mean_over=DT)
    composite.reset(Y[0])
    got = np.array([composite.update(y) for y in Y[1:]])
    for observer, channels in _parts():
        estimator = VelocityEstimator(observer, mean_over=DT)  # the wrapper's conversion of each part's velocity
        estimator.reset(Y[0, channels])
        want = np.array([(estimator.update(y[channels]), estimator.filtered) for y in Y[1:]])
        np.testing.assert_array_equal(got[:, channels, 1], want[:, 0])
        np.testing.assert_array_equal(got[:, channels, 0], want[:, 1])
        np.testing.assert_array_equal(composite.output_error[channels], estimator.observer.output_error)
    assert composite.names == ("kalman-ca", "finite-difference", "kalman-ca", "levant")
    assert "finite-difference: [1]" in repr(composite) and not composite.reports_instant


def test_per_channel_reports_each_parts_estimate_not_its_state():
    """With explicit steps (Levant's ``taylor``, super-twisting's ``euler``) a part's state and its reported
    estimate differ; the composite reports each part's estimate, value and velocity (the test above has only
    parts whose two agree, so it could not tell them apart)."""
    from smo_gym.observers import SuperTwisting

    def parts():
        return [
            (Levant(dt=DT, order=2, lipschitz=5.0, discretization="taylor"), [0, 3]),
            (SuperTwisting(DT, 5.0, discretization="euler"), [2]),
            (KalmanCA(dt=DT, process_noise=1e3, measurement_noise=1e-6), [1]),
        ]

    _assert_each_part_alone(PerChannel(parts()), parts(), _signal())


def test_parts_of_one_step_share_one_call_and_any_order_one_compiled_step():
    """Parts running the same step with the same state width and order (the Kalman filter with two gains, one with
    Huber's update) are one call per sample, and the composites of the same steps share one compiled step whatever
    the order and grouping of their parts: each still estimates, bit for bit, what each part does alone. Parts of
    one step with another order (Levant's differentiator of orders 1 and 2) stay two calls."""

    def parts():
        return [
            (KalmanCA(DT, 1e3, 1e-6), [0, 3]),
            (FiniteDifference(dt=DT), [1]),
            (KalmanCA(DT, 5e3, 1e-6, huber=3.0), [2]),
        ]

    Y = _signal()
    composite = PerChannel(parts())
    steps, slot = composite._slots()
    assert len(steps) == 2 and slot[0] == slot[2] != slot[1]
    assert PerChannel([parts()[i] for i in (2, 1, 0)])._kernel is composite._kernel
    assert PerChannel([parts()[1], (KalmanCA(DT, 1e3, 1e-6), [0, 2, 3])])._kernel is composite._kernel
    _assert_each_part_alone(composite, parts(), Y)
    orders = PerChannel([(Levant(dt=DT, order=k, lipschitz=5.0, discretization="implicit"), [k - 1]) for k in (1, 2)])
    steps, slot = orders._slots()
    assert len(steps) == 2 and slot[0] != slot[1] and steps[0] is steps[1]


def test_per_channel_batch_run_and_masked_reset():
    Y = _signal(batch=(3,))
    composite = PerChannel(_parts())
    composite.reset(Y[0])
    looped = np.array([composite.update(y) for y in Y[1:]])
    for b in range(3):  # batch = one environment at a time
        single = PerChannel(_parts())
        single.reset(Y[0, b])
        np.testing.assert_allclose(single.run(Y[1:, b]), looped[:, b], rtol=0, atol=1e-12)
    again = PerChannel(_parts())
    again.reset(Y[0])
    np.testing.assert_allclose(again.run(Y[1:]), looped, rtol=0, atol=1e-12)  # run == loop of update
    mask = np.array([False, True, False])
    est = composite.reset(Y[0], mask=mask)
    np.testing.assert_array_equal(est[1, :, 1], 0.0)  # restarted at rest
    np.testing.assert_array_equal(est[1, :, 0], Y[0, 1])
    np.testing.assert_array_equal(est[0], looped[-1, 0])  # the others keep their estimates
    twin = pickle.loads(pickle.dumps(composite))
    np.testing.assert_array_equal(twin.update(Y[5]), composite.update(Y[5]))


def test_per_channel_restart_equals_a_fresh_reset():
    """A new episode restarts every part's channels from the parts' own fresh states (with and without
    derivatives, in a batch): then it runs as a composite reset from scratch, to the last bit."""
    Y = _signal(batch=(2,))
    composite = PerChannel(_parts())
    composite.reset(Y[0])
    composite.run(Y[1:50])
    d = np.random.default_rng(1).standard_normal((2, 4, 1))
    for derivatives in (None, d):
        fresh = PerChannel(_parts())
        np.testing.assert_array_equal(
            composite.restart(Y[50], derivatives=derivatives), fresh.reset(Y[50], derivatives=derivatives)
        )
        np.testing.assert_array_equal(composite.state, fresh.state)
        np.testing.assert_array_equal(composite.run(Y[51:90]), fresh.run(Y[51:90]))


def test_per_channel_is_all_or_nothing():
    """A sample one part rejects is rejected for every part: the composite keeps the state it had, and the error
    names the composite's channel (the difference part observes channel 1 only)."""
    Y = _signal()
    kalman = KalmanCA(dt=DT, process_noise=1e3, measurement_noise=1e-6)
    composite = PerChannel([(kalman, [3, 0, 2]), (FiniteDifference(dt=DT), [1])])
    twin = PerChannel([(kalman, [3, 0, 2]), (FiniteDifference(dt=DT), [1])])
    for observer in (composite, twin):
        observer.reset(Y[0])
        for y in Y[1:4]:
            observer.update(y)
    before = (composite.state, composite.estimate.copy(), composite.n_updates)

    def unchanged():
        np.testing.assert_array_equal(composite.state, before[0])
        np.testing.assert_array_equal(composite.estimate, before[1])
        assert composite.n_updates == before[2]

    overflow = Y[4].copy()
    overflow[1] = 1e308  # the difference overflows to inf on channel 1; the filter's channels pass
    with pytest.raises(DivergenceError, match="channel 1"):
        composite.update(overflow)
    unchanged()
    with pytest.raises(DivergenceError, match="channel 1"):
        composite.run(np.vstack([Y[4:6], overflow]))
    unchanged()
    with pytest.raises(ValueError, match=r"finite measurements.*channel 2"):
        composite.update(np.array([0.0, 0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match=r"finite measurements"):
        composite.run(np.vstack([Y[4:6], [[0.0, 0.0, np.inf, 0.0]]]))
    unchanged()
    # and from there it goes on as if nothing had been tried
    np.testing.assert_array_equal(composite.run(Y[4:9]), twin.run(Y[4:9]))


@pytest.mark.parametrize(
    ("parts", "error", "message"),
    [
        ([], TypeError, "non-empty sequence"),
        ([(FiniteDifference(dt=DT), [0]), (FiniteDifference(dt=DT), [0])], ValueError, "exactly one part"),
        ([(FiniteDifference(dt=DT), [0]), (FiniteDifference(dt=2 * DT), [1])], ValueError, "sharing one dt"),
        ([(FiniteDifference(dt=DT), [0.5])], TypeError, "sequence of ints"),
        ([("finite-difference", [0])], TypeError, r"pair \(Observer, channels\)"),
        ([(UnregisteredFiniteDifference(dt=DT), [0])], TypeError, "runs a compiled step"),
    ],
)
def test_per_channel_rejects_bad_parts(parts, error, message):
    with pytest.raises(error, match=message):
        PerChannel(parts)


def test_per_channel_bad_calls():
    composite = PerChannel(_parts())
    with pytest.raises(RuntimeError, match="reset"):
        composite.update(np.zeros(4))
    with pytest.raises(ValueError, match="4 channels"):
        composite.reset(np.zeros(3))
    composite.reset(np.zeros(4))
    with pytest.raises(ValueError, match=r"shape \(4,\)"):
        composite.update(np.zeros((2, 4)))
    # one flat state: the pure step is update's
    y = np.array([0.1, -0.2, 0.3, 0.05])
    new_state, estimate = composite.step(composite.state, y)
    np.testing.assert_array_equal(estimate, composite.update(y))
    np.testing.assert_array_equal(new_state, composite.state)


# ---- the choice ---------------------------------------------------------------------------------------------------
def _calibration(noise, accel=1.0, jerk=10.0, n=1) -> Calibration:
    return Calibration(DT, {2: np.full(n, 2 * accel), 3: np.full(n, 2 * jerk)}, {2: accel, 3: jerk}, noise)


def test_predicted_backward_difference_error_matches_a_measurement():
    """White noise of std s on a line: the backward difference errs by sqrt(2) s / tau exactly (the line adds
    nothing); the prediction's lag term vanishes for the mean over the step."""
    s, T = 1e-4, 200_000
    y = 0.3 * np.arange(T) * DT + s * np.random.default_rng(1).standard_normal(T)
    measured = np.sqrt(np.mean((np.diff(y) / DT - 0.3) ** 2))
    (fd,) = predicted_errors(_calibration(s), ["finite-difference"], mean_over=DT)
    assert fd[0] == pytest.approx(measured, rel=0.01)


def test_predicted_kalman_error_matches_a_signal_of_its_own_model():
    """On a signal that is the Kalman filter's own model (white jerk of density q, white measurement noise r), its
    velocity RMSE is the steady-state Riccati prediction."""
    rng = np.random.default_rng(2)
    jerk, s, T = 50.0, 1e-4, 100_000
    q = jerk**2 * DT
    F = np.array([[1, DT, DT**2 / 2], [0, 1, DT], [0, 0, 1]])
    Q = q * np.array(
        [[DT**5 / 20, DT**4 / 8, DT**3 / 6], [DT**4 / 8, DT**3 / 3, DT**2 / 2], [DT**3 / 6, DT**2 / 2, DT]]
    )
    w = rng.multivariate_normal(np.zeros(3), Q, size=T)
    x = np.zeros((T, 3))
    for k in range(1, T):
        x[k] = F @ x[k - 1] + w[k]
    y = x[:, 0] + s * rng.standard_normal(T)
    kf = KalmanCA(DT, process_noise=q, measurement_noise=s**2)
    kf.reset(y[:1])
    est = kf.run(y[1:, None])[:, 0]
    measured = np.sqrt(np.mean((est[T // 10 :, 1] - x[1 + T // 10 :, 1]) ** 2))
    predicted = selection._kalman_ca_error(DT, q, s**2, np.array([1.0, 0.0]))
    assert predicted == pytest.approx(measured, rel=0.05)
    # the same filter as "auto" builds it from a calibration whose typical jerk is the signal's, predicted for it
    calibration = Calibration(DT, {3: [2 * jerk]}, {3: [jerk]}, [s])
    auto = selection.default_observer("kalman-ca", calibration)
    np.testing.assert_allclose([auto.process_noise, auto.measurement_noise], [[q], [s**2]], rtol=1e-12)
    (found,) = predicted_errors(calibration, ["kalman-ca"])
    assert found[0] == pytest.approx(measured, rel=0.05)


def test_prediction_prefers_the_difference_without_noise_and_the_filter_with_it():
    exact = select(_calibration(0.0), candidates=["finite-difference", "kalman-ca"], mean_over=DT)
    assert exact.names == ("finite-difference",) and exact.source == "prediction"
    noisy = select(_calibration(1e-3), candidates=["finite-difference", "kalman-ca"], mean_over=DT)
    assert noisy.names == ("kalman-ca",)
    assert np.isinf(predicted_errors(_calibration(1e-3), ["super-twisting"])).all()  # no closed form: never chosen
    assert "finite-difference on [0]" in str(exact)


def test_several_scenarios_choose_the_smallest_worst_regret():
    """A candidate 5 % better in one scenario but 50 % worse in the other loses to the steady one; exact ties
    (both errors 0) count as ties, and the first candidate wins them."""
    errors = np.array([[[0.95, 0.0], [1.0, 0.0]], [[1.5, 2.0], [1.0, 1.0]]])  # (scenario, candidate, channel)
    found = Selection(("a", "b"), errors, "trials")
    np.testing.assert_allclose(found.regret, [[1.5, 2.0], [1.0 / 0.95, 1.0]])
    assert found.names == ("b", "b")
    tie = Selection(("a", "b"), np.zeros((1, 2, 1)), "trials")
    assert tie.names == ("a",)


def test_a_candidate_that_loses_to_the_references_somewhere_is_not_chosen():
    """Channel 0: regret alone would pick the hedge "hg" (worst regret 1.3 against the Kalman filter's 1.5), but it
    loses to the Kalman filter by 30 % in the first scenario, and the Kalman filter is the better reference in both:
    the Kalman filter is chosen. Channel 1: each reference loses to the other somewhere, so no candidate is safe and
    the smallest worst regret decides among all (the hedge)."""
    candidates = ("finite-difference", "kalman-ca", "hg")
    errors = np.array([[[2.0, 1.0], [1.0, 2.0], [1.3, 1.3]], [[1.5, 2.0], [1.2, 1.0], [0.8, 1.3]]])
    found = Selection(candidates, errors, "trials")
    np.testing.assert_allclose(found.regret, [[2.0, 2.0], [1.5, 2.0], [1.3, 1.3]])
    assert found.safe[:, 0].tolist() == [False, True, False] and not found.safe[:, 1].any()
    assert found.names == ("kalman-ca", "hg")


def test_ratio_bound_covers_the_true_ratio():
    """The bootstrap bound of the RMSE ratio, from 60 blocks with heavy-tailed squared errors (as impacts make
    them), is above the true ratio in about its level's share of independent draws (measured 0.95 for the nominal
    0.975: the percentile bootstrap's usual undercoverage at this size), and no wider than that needs: its median
    margin over the measured ratio is 1.56 standard deviations of the measured ratio across draws (a one-sided
    normal 97.5 % bound is 1.96; an over-cautious bound would cover every draw and sit further out). The better
    reference's own bound is 1, and a candidate whose every block is a fixed multiple of the reference's is
    bounded by that multiple."""
    rng = np.random.default_rng(7)
    true = np.sqrt(np.exp(-0.1 + 0.3**2 / 2))  # sqrt(E[a] / E[b]) for a = b m, m ~ lognormal(-0.1, 0.3)
    bounds, measured = [], []
    for _ in range(300):
        b = rng.lognormal(0.0, 1.0, (60, 1))
        a = b * rng.lognormal(-0.1, 0.3, (60, 1))
        bound = selection.ratio_bound(np.stack([b, a]), refs=[0])
        assert bound[0, 0] == 1.0
        bounds.append(bound[1, 0])
        measured.append(np.sqrt(a.sum() / b.sum()))
    bounds, measured = np.array(bounds), np.array(measured)
    assert 0.9 <= np.mean(bounds >= true) <= 0.995  # binomial sd over 300 draws at 0.975: 0.009
    assert 1.0 < np.median(bounds - measured) / measured.std() < 2.5
    scaled = np.stack([np.ones((5, 1)), 4.0 * np.ones((5, 1))])
    np.testing.assert_allclose(selection.ratio_bound(scaled, refs=[0]), [[1.0], [2.0]])
    np.testing.assert_array_equal(selection.ratio_bound(scaled, refs=[]), np.ones((2, 1)))
    for level in (0.0, 1.0, True, "0.9"):
        with pytest.raises(ValueError, match="level in"):
            selection.ratio_bound(scaled, refs=[0], level=level)


def test_ratio_bound_of_a_robust_candidate_against_a_reference_with_rare_gross_errors():
    """One block in ten where the reference is thrown off (a gross error of the sensor): the candidate that never
    is, 5 % worse elsewhere, has a ratio of 0.31 and a bound of about 0.5. Fewer gross errors in a resample move
    the ratio towards 1.05, so the bound is far above the ratio, but far below 1 too."""
    b = np.ones((60, 1))
    b[::10] = 100.0
    bound = selection.ratio_bound(np.stack([b, np.full((60, 1), 1.05)]), refs=[0])
    assert np.sqrt(1.05 * 60 / b.sum()) < bound[1, 0] < 0.6


def test_a_gain_within_the_trials_spread_leaves_the_joint_to_the_reference():
    """Channel 0: a candidate measured 5 % better than the Kalman filter whose bound says it could be 9 % worse:
    the gain is within the trials' spread, the Kalman filter keeps the channel. Channel 1: 40 % better with a bound
    of 1.05 (rare gross errors): what it could lose is far less than the Kalman filter's measured 67 %, it is
    taken. Without bounds (a prediction) the measured gains decide both."""
    candidates = ("finite-difference", "kalman-ca", "imm")
    errors = np.array([[[2.0, 2.0], [1.0, 1.0], [0.95, 0.6]]])
    bound = np.array([[[2.0, 2.0], [1.0, 1.0], [1.09, 1.05]]])
    assert Selection(candidates, errors, "trials", bound=bound).names == ("kalman-ca", "imm")
    assert Selection(candidates, errors, "trials").names == ("imm", "imm")


def test_the_trials_bound_comes_from_their_blocks():
    """``select`` on trials bounds every candidate's ratio per scenario, from :func:`measure_on_trials`' blocks,
    whose sum is its RMSE's; a prediction's bound is its ratio."""
    calibration = Calibration(DT, {2: [20.0, 8.0], 3: [400.0, 16.0]}, {2: [5.0, 2.8], 3: [100.0, 5.7]}, [0.0, 1e-3])
    trials, _ = _trials(0)
    candidates = ["finite-difference", "kalman-ca", "alpha-beta"]
    found = select(calibration, trials, candidates=candidates)
    ratio = found.errors / np.min(found.errors[:, :2], axis=1, keepdims=True)
    assert found.bound.shape == found.errors.shape and np.all(found.bound[0, 2] > ratio[0, 2])
    measured = selection.measure_on_trials(selection.default_observer("alpha-beta", calibration), trials)
    assert measured.blocks.shape == (-(-(len(trials.measured[0]) - 1) // selection.BLOCK), 2)
    count = sum(len(z) - 1 for z in trials.measured)
    np.testing.assert_allclose(np.sqrt(measured.blocks.sum(axis=0) / count), measured.rmse, rtol=1e-12)
    np.testing.assert_array_equal(measured.rmse, found.errors[0, 2])
    predicted = select(calibration, candidates=candidates[:2])
    np.testing.assert_allclose(predicted.bound[0, 1], predicted.errors[0, 1] / predicted.errors[0].min(axis=0))


def test_a_gain_is_proven_against_the_reference_that_would_be_chosen():
    """The Kalman filter is 3 % worse than the backward difference in the first scenario: unsafe, so never chosen;
    its worst regret (1.98) is not what a candidate must beat, the backward difference's (2.0) is. A candidate
    whose bound is 1.99 can lose less than that: it is taken."""
    candidates = ("finite-difference", "kalman-ca", "x")
    errors = np.array([[[1.0], [1.03], [0.9]], [[1.0], [0.99], [0.5]]])
    found = Selection(candidates, errors, "trials", bound=np.full((2, 3, 1), 1.99))
    assert found.safe[:, 0].tolist() == [True, False, True]
    np.testing.assert_allclose(found.regret[:, 0], [2.0, 1.98, 1.0])
    assert found.proven[2, 0] and found.names == ("x",)


def test_a_gain_is_proven_in_every_scenario():
    """A candidate that halves the backward difference's error in both scenarios, with bounds 1.05 and 2.5: in the
    second scenario it could lose more than the reference's worst regret (2), so the gain is not proven and the
    reference keeps the channel."""
    candidates = ("finite-difference", "kalman-ca", "x")
    errors = np.array([[[1.0], [1.5], [0.5]], [[1.0], [1.5], [0.5]]])
    bound = np.array([[[1.0], [1.5], [1.05]], [[1.0], [1.5], [2.5]]])
    found = Selection(candidates, errors, "trials", bound=bound)
    assert not found.proven[2, 0] and found.names == ("finite-difference",)
    bound[1, 2, 0] = 1.9
    assert Selection(candidates, errors, "trials", bound=bound).names == ("x",)


def test_a_joint_candidate_that_only_ties_is_not_taken():
    """A model-based column whose worst regret equals that of the per-channel choice buys nothing: the
    per-channel references keep the channels (the joint column must be strictly better)."""
    candidates = ("finite-difference", "kalman-ca", "mechanical-super-twisting")
    errors = np.array([[[1.0, 1.0], [1.0, 1.2], [1.0, 1.0]]])
    assert Selection(candidates, errors, "trials", joint=True).names == ("finite-difference",) * 2
    errors[0, 2, 1] = 0.99
    assert Selection(candidates, errors, "trials", joint=True).names == ("mechanical-super-twisting",) * 2


def test_a_filter_told_the_input_is_taken_on_the_channels_it_wins():
    """``auto_observer`` with the candidate that takes the input (``joint``): a told filter on the channels it wins
    beside the model-free winners (a ``PerChannelInput``, its part ``of_channels``). A selection made for a
    model-based candidate (all channels or none) refuses it, and one made with such a candidate refuses to be read
    without it."""
    from smo_gym.observers import KalmanIMMInput, PerChannelInput

    rng = np.random.default_rng(1)
    levels = {r: rng.uniform(1.0, 2.0, 3) for r in (2, 3)}
    calibration = Calibration(DT, levels, levels, np.full(3, 1e-4), np.zeros(3), {1: np.ones(3)})
    told = KalmanIMMInput(DT, [1.0, 2.0, 3.0], 1e-8, np.arange(6.0).reshape(3, 2), [0.1, 0.2, 0.3])
    candidates = ("finite-difference", "kalman-ca", "kalman-imm-input")
    errors = np.array([[[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [0.5, 1.5, 0.5]]])  # the told filter wins channels 0, 2
    assert not selection.estimates_jointly(told) and not selection.estimates_jointly(None)
    observer = auto_observer(calibration, selection=Selection(candidates, errors, "trials"), joint=told)
    assert isinstance(observer, PerChannelInput)
    assert observer.names == ("kalman-imm-input", "finite-difference", "kalman-imm-input")
    np.testing.assert_array_equal(observer.input_gain, [[0.0, 1.0], [0.0, 0.0], [4.0, 5.0]])
    (part,) = [part for part, _ in observer.parts if part.takes_input]
    np.testing.assert_array_equal(part.process_noise, [1.0, 3.0])
    jointly = Selection(candidates, errors, "trials", joint=True)
    with pytest.raises(ValueError, match="per channel exactly if it is a filter told the input"):
        auto_observer(calibration, selection=jointly, joint=told)
    with pytest.raises(ValueError, match="last candidate"):
        auto_observer(calibration, selection=jointly)


def test_a_part_of_a_calibration_has_its_channels_values():
    """Each part of a per-channel choice is built from its channels' bounds, levels, noise, quantization step and
    initial levels (the worst-case optimal observer reads the step)."""
    rng = np.random.default_rng(0)
    fields = {name: rng.uniform(0.1, 1.0, 4) for name in ("b2", "b3", "t2", "t3", "noise", "res", "i1")}
    whole = Calibration(
        DT,
        {2: fields["b2"], 3: fields["b3"]},
        {2: fields["t2"], 3: fields["t3"]},
        fields["noise"],
        fields["res"],
        {1: fields["i1"]},
    )
    channels = np.array([3, 1])
    part = selection._take(whole, channels)
    for got, want in [
        (part.bound(2), whole.bound(2)),
        (part.bound(3), whole.bound(3)),
        (part.rms(2), whole.rms(2)),
        (part.rms(3), whole.rms(3)),
        (part.noise, whole.noise),
        (part.resolution, whole.resolution),
        (part.initial[1], whole.initial[1]),
    ]:
        np.testing.assert_array_equal(got, want[channels])


def test_one_candidate_is_taken_for_all_channels_where_a_mix_buys_less_than_the_tolerance():
    """Channel 1 alone would take "hg" (1 % better than the Kalman filter there); the Kalman filter is safe and
    within 2 % of the per-channel choice everywhere, so it observes both channels. At 3 % better, the mix stays.
    A candidate 1 % off the choice on one channel and safe everywhere is taken for all; once it is unsafe on that
    channel (3 % worse than the backward difference there) it is not."""
    candidates = ("finite-difference", "kalman-ca", "hg")
    errors = np.array([[[2.0, 2.0], [1.0, 1.01], [1.1, 1.0]], [[2.0, 2.0], [1.0, 1.0], [1.2, 1.0]]])
    per_channel = np.argmin(np.where(Selection(candidates, errors, "trials").safe, errors.max(axis=0), np.inf), 0)
    assert per_channel.tolist() == [1, 2]  # what the rule without the preference gives
    assert Selection(candidates, errors, "trials").names == ("kalman-ca", "kalman-ca")
    wider = errors.copy()
    wider[0, 1, 1] = 1.03
    assert Selection(candidates, wider, "trials").names == ("kalman-ca", "hg")
    close = np.array([[[1.0, 2.0], [1.5, 1.01], [1.01, 1.0]]])  # "hg" 1 % off on channel 0, and safe there
    assert Selection(candidates, close, "trials").names == ("hg", "hg")
    close[0, 2, 0] = 1.03
    assert Selection(candidates, close, "trials").names == ("finite-difference", "hg")


def _trials(seed: int, T: int = 3000) -> tuple[Trials, np.ndarray]:
    """Two channels: an Euler-integrated joint seen by an ideal sensor (the backward difference is exact), and a
    smooth motion seen through noise (a filter wins)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) * DT
    v0 = np.cumsum(rng.standard_normal(T)) * 0.05
    q0 = np.cumsum(v0) * DT  # q_k = q_{k-1} + tau v_k: v_k is the mean velocity over the step
    q1 = np.sin(2 * t + seed)
    v1 = 2 * np.cos(2 * t + seed)
    measured = np.column_stack([q0, q1 + 1e-3 * rng.standard_normal(T)])
    return Trials((measured,), (np.column_stack([v0, v1]),)), measured


def test_trials_choose_per_channel_and_the_choice_holds_on_new_data():
    calibration = Calibration(DT, {2: [20.0, 8.0], 3: [400.0, 16.0]}, {2: [5.0, 2.8], 3: [100.0, 5.7]}, [0.0, 1e-3])
    trials, _ = _trials(0)
    candidates = ["finite-difference", "kalman-ca"]
    found = select(calibration, trials, candidates=candidates)
    assert found.names == ("finite-difference", "kalman-ca") and found.source == "trials"
    observer = auto_observer(calibration, trials, candidates=candidates)
    assert isinstance(observer, PerChannel) and observer.selection.names == found.names
    fresh, measured = _trials(1)
    observer.reset(measured[0])
    auto = observer.run(measured[1:])[..., 1]
    for spec in candidates:  # on new data: per channel no worse than either candidate alone
        single = selection.default_observer(spec, calibration)
        single.reset(measured[0])
        err = np.sqrt(np.mean((single.run(measured[1:])[..., 1] - fresh.velocity[0][1:]) ** 2, axis=0))
        auto_err = np.sqrt(np.mean((auto - fresh.velocity[0][1:]) ** 2, axis=0))
        assert np.all(auto_err <= 1.02 * err), (spec, auto_err, err)
    assert not isinstance(
        auto_observer(calibration, selection=Selection(("kalman-ca",), np.ones((1, 1, 2)), "trials")), PerChannel
    )  # one winner everywhere: that observer itself (the wrapper's one-call path)


def test_what_auto_measures_is_what_it_deploys():
    """A channel's trial error does not depend on which channels share its observer: the composite built for a
    mixed choice (the low-power high-gain observer on channels 0 and 2, the Kalman filter on 1, which has the
    largest bound) reproduces on the trials, channel by channel, the errors the candidates had there on all
    channels."""
    rng = np.random.default_rng(3)
    t = np.arange(3000) * DT
    q = np.column_stack([np.sin(t), 0.3 * np.sin(7 * t), np.cos(2 * t)])
    v = np.column_stack([np.cos(t), 2.1 * np.cos(7 * t), -2 * np.sin(2 * t)])
    trials = Trials((q + 1e-3 * rng.standard_normal(q.shape),), (v,))
    calibration = Calibration(
        DT, {2: [1.0, 15.0, 4.0], 3: [1.0, 100.0, 8.0]}, {2: [0.7, 10.0, 2.8], 3: [0.7, 70.0, 5.7]}, [1e-3] * 3
    )
    candidates = ("low-power-high-gain", "kalman-ca")
    alone = np.stack([selection.trial_errors(selection.default_observer(c, calibration), trials) for c in candidates])
    chosen = Selection(candidates, np.array([[[1.0, 2.0, 1.0], [2.0, 1.0, 2.0]]]), "trials")
    observer = auto_observer(calibration, selection=chosen)
    assert isinstance(observer, PerChannel)
    np.testing.assert_allclose(selection.trial_errors(observer, trials), alone[[0, 1, 0], [0, 1, 2]], rtol=1e-12)


def test_auto_observer_gives_each_part_its_wrapped_channels():
    calibration = Calibration(DT, {2: [20.0, 8.0, 8.0], 3: [400.0, 16.0, 16.0]}, {2: 5.0, 3: 100.0}, [0.0, 1e-3, 0.0])
    errors = np.array([[[1.0, 2.0, 1.0], [2.0, 1.0, 2.0]]])  # the backward difference on 0 and 2, Kalman on 1
    mixed = Selection(("finite-difference", "kalman-ca"), errors, "trials")
    observer = auto_observer(calibration, selection=mixed, observer_kwargs={"wrap": np.array([True, False, True])})
    assert isinstance(observer, PerChannel) and observer.wrap.tolist() == [True, False, True]
    assert [part.wrap.tolist() for part, _ in observer.parts] == [[True, True], [False]]
    observer.reset(np.array([np.pi - 0.01, 0.0, 0.0]))
    est = observer.update(np.array([-np.pi + 0.01, 0.0, 0.0]))  # across the cut: a small step, not -2 pi
    assert est[0, 1] == pytest.approx(0.02 / DT)


def test_bad_selection_input():
    with pytest.raises(TypeError, match="Calibration"):
        select("calibration")
    with pytest.raises(ValueError, match="no observer parameters but wrap"):
        select(_calibration(1e-3), observer_kwargs={"lipschitz": 3.0})
    with pytest.raises(ValueError, match="same shape"):
        Trials((np.zeros((5, 2)),), (np.zeros((5, 3)),))
    with pytest.raises(ValueError, match="finite trials"):
        Trials((np.full((5, 1), np.nan),), (np.zeros((5, 1)),))
    trials, _ = _trials(0)
    with pytest.raises(ValueError, match="calibration's 1 channels, actual value: 2"):
        select(_calibration(1e-3), trials)
    with pytest.raises(TypeError, match="expected Trials, a non-empty sequence of them"):
        select(_calibration(1e-3), 3)
    for bad in (np.nan, -1.0, 0.0):  # an error of inf for a span that is not one
        with pytest.raises(ValueError, match="mean_over"):
            predicted_errors(_calibration(1e-3), ["levant"], mean_over=bad)
    with pytest.raises(TypeError, match="Calibration"):
        predicted_errors(None, ["levant"])
    for squared, refs in ((np.ones((2, 5)), [0]), (np.ones((2, 0, 1)), [0]), (np.ones((2, 5, 1)), [2])):
        with pytest.raises(ValueError, match=r"expected (squared|refs)"):
            selection.ratio_bound(squared, refs)


# ---- the default everywhere -----------------------------------------------------------------------------------------
def test_differentiate_defaults_to_auto():
    t = np.arange(0, 5, DT)
    exact = smo_gym.differentiate(0.5 * t**2, DT)
    assert exact.shape == (t.size, 2)
    # noise-free: the Kalman filter, whose constant-acceleration model is exact here, rather than the backward
    # difference, late by half a step (an error of tau / 2 = 5e-4)
    np.testing.assert_allclose(exact[100:, 1], t[100:], rtol=0, atol=1e-6)
    noisy = smo_gym.differentiate(np.sin(t) + 1e-3 * np.random.default_rng(0).standard_normal(t.size), DT)
    fd = np.diff(np.sin(t) + 1e-3 * np.random.default_rng(0).standard_normal(t.size)) / DT
    assert np.sqrt(np.mean((noisy[1000:, 1] - np.cos(t[1000:])) ** 2)) < 0.1 * np.sqrt(
        np.mean((fd[999:] - np.cos(t[1000:])) ** 2)
    )
    with pytest.raises(ValueError, match="no observer parameters but wrap"):
        smo_gym.differentiate(t, DT, lipschitz=2.0)


def test_the_wrapper_defaults_to_auto_chosen_on_its_own_trials(monkeypatch):
    env = EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), sensor="encoder-12bit-noisy", rate="env")
    found = env.observer.selection
    assert found.source == "trials" and len(found.names) == env.adapter.model.nv
    # two scenarios: uniform random actions and smooth (low-passed) ones
    assert found.errors.shape == (2, len(selection.CANDIDATES), env.adapter.model.nv)

    def fail(*args, **kwargs):
        raise AssertionError("ran the trials again instead of using the cache")

    monkeypatch.setattr(ev_module, "sensed_trials", fail)
    again = EstimatedVelocity(gym.make("InvertedDoublePendulum-v5"), sensor="encoder-12bit-noisy", rate="env")
    np.testing.assert_array_equal(again.observer.selection.errors, found.errors)
    # copies and pickles run the same observers on the same measurements
    env.reset(seed=3)
    actions = np.random.default_rng(3).uniform(-1, 1, (15, 1))
    for a in actions[:5]:
        env.step(a)
    for twin in (copy.deepcopy(env), pickle.loads(pickle.dumps(env))):
        o1, _ = env.reset(seed=4)
        o2, _ = twin.reset(seed=4)
        np.testing.assert_array_equal(o1, o2)
        for a in actions:
            np.testing.assert_array_equal(env.step(a)[0], twin.step(a)[0])


def test_the_trials_never_replay_an_evaluation_seed():
    """The calibration's and the trials' episodes have a seed stream of their own: the seeds users and the
    benchmarks evaluate on start elsewhere and draw other actions (seed 0 once replayed the first trial, so the
    accuracy tables scored the choice on its own data)."""
    adapter = make_adapter(gym.make("InvertedPendulum-v5").unwrapped)
    for smoothing in ev_module.TRIAL_SMOOTHING:
        (trial, *_) = ev_module.random_episodes(adapter, 1, 40, smoothing=smoothing)
        for seed in range(10):
            (evaluated, *_) = ev_module.random_episodes(adapter, 1, 40, seed, smoothing)
            assert not np.allclose(evaluated.qpos[:3], trial.qpos[:3]), seed
            assert not np.allclose(evaluated.ctrl[:3], trial.ctrl[:3]), seed


def test_a_joint_candidate_is_taken_for_all_channels_or_for_none():
    """The model-based column wins every channel when it is safe everywhere and its worst regret is the smallest,
    and none when it loses to the references on one channel, however much it wins on the others."""
    candidates = ("finite-difference", "kalman-ca", "mechanical-super-twisting")
    better = np.array([[[1.0, 1.0], [0.9, 1.1], [0.3, 0.5]]])  # (scenarios, candidates, channels)
    assert Selection(candidates, better, "trials", joint=True).names == ("mechanical-super-twisting",) * 2
    loses_once = better.copy()
    loses_once[0, 2, 1] = 1.05  # 5 % worse than finite differences on channel 1
    chosen = Selection(candidates, loses_once, "trials", joint=True)
    assert chosen.names == ("kalman-ca", "finite-difference")  # the per-channel choice without the joint column
    diverged = better.copy()
    diverged[0, 2, 0] = np.inf
    assert Selection(candidates, diverged, "trials", joint=True).names == ("kalman-ca", "finite-difference")


def test_trials_check_their_inputs():
    z = np.zeros((5, 2))
    assert Trials((z,), (z,), (np.zeros((5, 1)),)).inputs[0].shape == (5, 1)
    with pytest.raises(ValueError, match="inputs"):
        Trials((z,), (z,), (np.zeros((4, 1)),))
    with pytest.raises(ValueError, match="inputs"):
        Trials((z,), (z,), (np.full((5, 1), np.nan),))


def test_a_gross_error_moves_super_twisting_far_less_than_a_linear_filter():
    """Why super-twisting is a candidate: one wrong sample of size ``A`` (an encoder glitch) on a resting joint
    moves a linear filter's velocity estimate in proportion to ``A``, the implicit super-twisting differentiator's
    as a power of ``A`` below one (its injection is ``k1 |e|^(1/2)``, ``k2 sign(e)``). Measured, ``dt = 0.01``,
    ``L = 10``: super-twisting's peak velocity error 0.22 and 0.44 for ``A = 0.1`` and 1 (growth 2.0, at most
    ``sqrt(10)`` asserted), the backward difference's and the Kalman filter's exactly 10x (10 and 100; 4.9 and 49)."""
    dt = 0.01

    def peak(observer, size):
        y = np.zeros((200, 1))
        y[100] = size
        observer.reset(y[0])
        return float(np.max(np.abs(observer.run(y[1:])[:, 0, 1])))

    def make(name):
        params = {"super-twisting": dict(lipschitz=10.0), "kalman-ca": dict(process_noise=1e3, measurement_noise=1e-6)}
        return smo_gym.observers.make_observer(name, dt=dt, **params.get(name, {}))

    st = [peak(make("super-twisting"), a) for a in (0.1, 1.0)]
    assert st[1] / st[0] <= np.sqrt(10.0), st
    for name in ("finite-difference", "kalman-ca"):
        linear = [peak(make(name), a) for a in (0.1, 1.0)]
        np.testing.assert_allclose(linear[1] / linear[0], 10.0, rtol=1e-6)
        assert st[1] < 0.1 * linear[1], (name, st, linear)


def test_auto_takes_the_robust_imm_estimator_on_a_sensor_with_gross_errors():
    """Walker2d at the physics rate with the ``outliers`` sensor (one sample in a thousand off by ~0.1): ``auto``
    observes every joint with the IMM estimator with Huber's update (``kalman-imm:huber=3``); on the trials'
    low-passed motion its error is below half the plain IMM estimator's on every joint (measured 0.13-0.54 against
    0.44-2.7, 0.15-0.41 of it: one glitch throws the plain one into its fast mode and its estimate off)."""
    env = EstimatedVelocity(gym.make("Walker2d-v5"), sensor="outliers", rate="physics")
    selection = env.observer.selection
    assert set(selection.names) == {"kalman-imm:huber=3"}
    robust, plain = selection.candidates.index("kalman-imm:huber=3"), selection.candidates.index("kalman-imm")
    low_passed = np.asarray(selection.errors)[1]
    assert np.all(low_passed[robust] < low_passed[plain] / 2.0)


def test_the_trials_are_measured_again_when_the_calibration_changes(monkeypatch):
    """The errors ``auto`` compares depend on every candidate's gains, hence on the calibration: cached under a key
    without it, a change of the calibration (a new level, a new rule of the rollout) would keep the errors of the
    old one. Two wrappers whose calibrations differ only in their typical levels (x 100) get different errors."""
    real = ev_module.calibrate_environment
    scale = {"factor": 1.0}

    def scaled(*args, **kwargs):
        found = real(*args, **kwargs)
        typical = {r: v * scale["factor"] for r, v in found.typical.items()}
        return Calibration(found.dt, found.bounds, typical, found.noise, found.resolution, found.initial)

    monkeypatch.setattr(ev_module, "calibrate_environment", scaled)
    errors = []
    for factor in (1.0, 100.0):
        scale["factor"] = factor
        env = EstimatedVelocity(gym.make("InvertedPendulum-v5"), rate="env", disk_cache=False)
        errors.append(np.asarray(env.observer.selection.errors))
    kalman = list(env.observer.selection.candidates).index("kalman-ca")
    assert not np.allclose(errors[0][:, kalman], errors[1][:, kalman])


def test_selection_inputs_that_would_choose_wrongly_are_refused():
    """A NaN error won its channel (NaN <= x is False for every other candidate), a selection of five channels was
    applied to a calibration of two, a NaN ``mean_over`` gave NaN errors, a spec string was read letter by letter,
    and a bound between two infinite ratios came out NaN (read as 'not proven' only by accident)."""
    calibration = Calibration(DT, {2: [20.0, 8.0], 3: [400.0, 16.0]}, {2: [5.0, 2.8], 3: [100.0, 5.7]}, [0.0, 1e-3])
    with pytest.raises(ValueError, match="NaN or negative"):
        Selection(("finite-difference", "kalman-ca"), np.array([[[np.nan], [1.0]]]), "trials")
    with pytest.raises(ValueError, match="calibration's 2 channels"):
        auto_observer(calibration, selection=Selection(("finite-difference",), np.ones((1, 1, 5)), "trials"))
    trials, _ = _trials(0, T=300)
    observer = selection.default_observer("kalman-ca", calibration)
    for bad in (np.nan, -1.0, True):
        with pytest.raises((TypeError, ValueError), match="mean_over"):
            selection.measure_on_trials(observer, trials, mean_over=bad)
    for call in (lambda: select(calibration, trials, candidates="kalman-ca"), lambda: selection.candidate_orders("x")):
        with pytest.raises(TypeError, match="sequence of specs"):
            call()
    squared = np.array([[[1.0], [1.0]], [[np.inf], [np.inf]]])
    np.testing.assert_array_equal(selection.ratio_bound(squared, [0]), [[1.0], [np.inf]])
