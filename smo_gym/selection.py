r"""``observer="auto"``: the velocity observer of every joint chosen from the evidence the calibration has.

No single observer wins everywhere (the accuracy tables of the documentation): a backward difference is exact on
an ideal encoder when the simulator integrates with Euler and every physics step is sampled, a Kalman filter tuned
from the typical jerk wins where noise dominates a smooth motion, a high-gain filter where impacts make the jerk
anything but white, two Kalman filters mixed by the IMM algorithm (:class:`smo_gym.observers.KalmanIMM`) where
smooth stretches alternate with bursts of jerk, and where the sensor makes gross errors the same with Huber's
robust update (``huber=3``: a single wrong sample moves the estimate as one three standard deviations off would)
or the super-twisting differentiator (its injection grows as a power below one of the output error, a linear
filter's in proportion). :func:`auto_observer` chooses per channel among
:data:`CANDIDATES`, each with its own calibrated gains (:func:`smo_gym.calibration.default_observer`), from their
velocity RMSE in one or more scenarios:

* **measured on trials** when the caller has them (:class:`Trials`): the wrapper simulates its own sensor on the
  positions of the calibration rollouts of its environment (the environment's own resets, under uniform random
  actions and under low-passed ones: the motion of an untrained and of a trained policy; never the episodes it is
  evaluated on) and runs every candidate on them;
* **predicted** otherwise (:func:`smo_gym.differentiate` of a recorded signal, where no truth is known), for the
  two candidates whose error has a closed form: the backward difference,

  .. math:: e_{FD}^2 = \frac{2 r}{\tau^2} + \Big(\frac{\tau - s}{2}\Big)^2 A^2,

  (noise variance ``r``, step ``tau``, typical acceleration ``A``, ``s`` the span the reported velocity is a mean
  over, 0 for the instantaneous one), and the constant-acceleration Kalman filter, whose steady-state posterior
  covariance :math:`P` (the discrete algebraic Riccati equation of its own model, Bar-Shalom, Li and Kirubarajan
  2001) gives :math:`e_{KF}^2 = c^\top P c` for the reported combination ``c`` of its derivative estimates.

The rule (:attr:`Selection.choice`): a candidate is *safe* on a channel if in every scenario it is within
:data:`TOLERANCE` (2 %) of the better of the :data:`REFERENCES`, the backward difference and the Kalman filter, what
a user would otherwise pick, and *proven* if its gain is more than the trials can explain by chance: at the upper
bound of its ratio to the better reference (:func:`ratio_bound`, a bootstrap over blocks of the trials' episodes,
worst over the scenarios) it loses less than the safe reference of smallest worst regret is measured to lose to the
best candidate. The ratio of two close candidates moves by several percent from one set of episodes to the next
(``scripts/bench_trial_spread.py``), so a gain of a few percent leaves the channel to the reference, while a robust
filter's large gain on a sensor with rare gross errors stands, though a stretch without them could make it a little
worse than the reference. Among the safe and proven candidates the one with the smallest worst regret (its error
over the best candidate's, worst over the scenarios) wins. The references are never both unsafe unless each loses to
the other in some scenario; then the smallest worst regret decides among all. Where one candidate, safe and proven
on every channel, is within :data:`TOLERANCE` of that per-channel choice on every channel and in every scenario, it
is taken for all channels: a mix would buy at most that much (a tie, as the safety rule counts it) and cost a
composite, one more family to report and, in a new process, a few seconds more of compilation (Hopper-v5 at the
physics rate: 8.2 s cold with the IMM estimator and the alpha-beta tracker mixed, 4.5 s when one observed all
joints).

A model-based observer estimates all channels together (its model couples them): as the last candidate of a
:class:`Selection` with ``joint=True`` it is taken for every channel or for none (:attr:`Selection.choice`; the
wrapper's ``observer_kwargs={"model": True}``), measured on trials that carry the inputs (:func:`trial_errors`).
A filter told the input (:class:`~smo_gym.observers.input_kalman.InputJumpFilter`, the wrapper's
``observer_kwargs={"model": "kalman-imm-input"}``) is measured the same way but chosen per channel like the others:
its channels are independent given the input, so its part on some channels
(:meth:`~smo_gym.observers.input_kalman.InputJumpFilter.of_channels`) estimates exactly what it does there, and a
:class:`~smo_gym.observers.input_kalman.PerChannelInput` holds it beside the model-free parts.

The result is a single observer when one candidate wins every channel (the wrapper's one-call path then applies),
else a :class:`smo_gym.observers.composite.PerChannel` (:class:`~smo_gym.observers.input_kalman.PerChannelInput` with
a part told the input); :class:`Selection` says what was chosen and why.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ._validation import DivergenceError, as_real_array, check_names, check_positive
from .calibration import Calibration, bound_order, default_observer
from .observers import Observer
from .observers.base import reported_coefficients, reported_velocity
from .observers.composite import PerChannel
from .observers.input_kalman import InputJumpFilter, PerChannelInput
from .observers.linear import steady_state_covariance
from .specs import MODEL_OPTIONS, parse_observer_spec

__all__ = [
    "BLOCK",
    "CANDIDATES",
    "CONFIDENCE",
    "REFERENCES",
    "RESAMPLES",
    "TOLERANCE",
    "Selection",
    "TrialErrors",
    "Trials",
    "auto_observer",
    "candidate_orders",
    "estimates_jointly",
    "measure_on_trials",
    "predicted_errors",
    "ratio_bound",
    "select",
    "trial_errors",
]

#: what a user would otherwise pick: a choice must not lose to the better of these by more than :data:`TOLERANCE`
#: in any scenario (:attr:`Selection.safe`)
REFERENCES: tuple[str, ...] = ("finite-difference", "kalman-ca")
#: how much worse than the better reference a candidate may be and still count as safe
TOLERANCE = 0.02
#: the one-sided level of the bootstrap bound (:func:`ratio_bound`) of a candidate's ratio to the better reference
#: that :attr:`Selection.proven` weighs against the reference's measured regret
CONFIDENCE = 0.975
#: bootstrap resamples of :func:`ratio_bound` (its quantile then moves by well under 1 % between seeds)
RESAMPLES = 1000
#: the most samples of an episode in one block of :class:`TrialErrors` (0.4 s at 2 ms): far longer than an
#: estimation error stays correlated, short enough that an episode which never ends gives dozens of blocks
BLOCK = 200
#: the observers ``"auto"`` chooses among, as specs (:func:`smo_gym.specs.parse_observer_spec`); on a tie the first
#: wins, so the simplest come first
CANDIDATES: tuple[str, ...] = (
    "finite-difference",
    "kalman-ca",
    "alpha-beta",
    "low-power-high-gain",
    "levant:discretization=implicit",
    "kalman-imm",
    "kalman-imm:huber=3",
    "super-twisting",
)


def candidate_orders(candidates: Sequence[str] = CANDIDATES) -> tuple[int, ...]:
    """The derivative orders a calibration needs for the gains of ``candidates``
    (:func:`smo_gym.calibration.bound_order` of each, and 2, the acceleration, for the predictions)."""
    orders = {2}
    for spec in check_names("candidates", candidates, "specs"):
        name, kw = parse_observer_spec(spec)
        orders.add(bound_order(name, kw))
    return tuple(sorted(orders))


@dataclass(frozen=True)
class Trials:
    """Measured positions with the true velocities they came from, per episode.

    Attributes
    ----------
    measured : tuple of ndarray, shape (T_i, n)
        What the sensor reported (tangent coordinates of the joints), one array per episode.
    velocity : tuple of ndarray, shape (T_i, n)
        The velocity to estimate at the same samples.
    inputs : tuple of ndarray, shape (T_i, m), optional
        The control input that acted over the interval ending at each sample (what a model-based candidate is
        given); None when unknown.
    """

    measured: tuple
    velocity: tuple
    inputs: tuple | None = None

    def __post_init__(self):
        measured = tuple(as_real_array("measured", m) for m in self.measured)
        velocity = tuple(as_real_array("velocity", v) for v in self.velocity)
        if not measured or len(measured) != len(velocity):
            raise ValueError(
                f"expected as many velocity as measured episodes (at least one), actual value: {len(measured)} "
                f"measured, {len(velocity)} velocity"
            )
        for i, (m, v) in enumerate(zip(measured, velocity, strict=True)):
            if m.ndim != 2 or m.shape != v.shape or m.shape[0] < 2:
                raise ValueError(
                    f"expected episode {i} as two arrays (T, n) of the same shape, T >= 2, actual value: shapes "
                    f"{m.shape} and {v.shape}"
                )
            if not (np.isfinite(m).all() and np.isfinite(v).all()):
                raise ValueError(f"expected finite trials, actual value: a non-finite entry in episode {i}")
        if len({m.shape[1] for m in measured}) != 1:
            raise ValueError(f"expected one channel count, actual value: {[m.shape[1] for m in measured]}")
        if self.inputs is not None:
            inputs = tuple(as_real_array("inputs", u) for u in self.inputs)
            if len(inputs) != len(measured) or any(
                u.ndim != 2 or len(u) != len(m) or not np.isfinite(u).all()
                for u, m in zip(inputs, measured, strict=False)
            ):
                raise ValueError(
                    "expected one finite array (T_i, m) of inputs per episode, as long as its measurements, "
                    f"actual value: shapes {[np.shape(u) for u in inputs]} for {[m.shape for m in measured]}"
                )
            object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "measured", measured)
        object.__setattr__(self, "velocity", velocity)


def _reference_indices(candidates: Sequence[str]) -> list[int]:
    """Where the :data:`REFERENCES` are among ``candidates``."""
    return [k for k, spec in enumerate(candidates) if spec in REFERENCES]


@dataclass(frozen=True)
class Selection:
    """What ``"auto"`` chose, and the evidence.

    Attributes
    ----------
    candidates : tuple of str
        The observer specs compared.
    errors : ndarray, shape (n_scenarios, n_candidates, n_channels)
        Velocity RMSE of every candidate on every channel in every scenario (one set of :class:`Trials`, or the
        prediction); ``inf``: no prediction, or it diverged.
    source : {"trials", "prediction"}
        Whether the errors were measured on :class:`Trials` or predicted from the calibration.
    joint : bool
        Whether the last candidate estimates all channels together (a model-based observer, which cannot be split
        over channels): :attr:`choice` then takes it for every channel or for none.
    bound : ndarray, shape (n_scenarios, n_candidates, n_channels), optional
        Upper confidence bound of each candidate's RMSE over the better reference's, from the trials' blocks
        (:func:`ratio_bound`); None: the errors are taken as exact (a prediction).
    """

    candidates: tuple
    errors: np.ndarray
    source: str
    joint: bool = False
    bound: np.ndarray | None = None

    def __post_init__(self):
        errors, shape = np.asarray(self.errors), (len(self.candidates),)
        if errors.ndim != 3 or errors.shape[1:2] != shape or not (errors >= 0).all():  # NaN would win a channel
            raise ValueError(
                f"expected errors >= 0 (inf: none) of shape (scenarios, {len(self.candidates)} candidates, channels), "
                f"actual value: shape {errors.shape}, {np.count_nonzero(~(errors >= 0))} NaN or negative"
            )
        if self.source not in ("trials", "prediction"):
            raise ValueError(f"expected source 'trials' or 'prediction', actual value: {self.source!r}")
        if self.bound is not None and np.shape(self.bound) != errors.shape:
            raise ValueError(f"expected bound of shape {errors.shape}, actual value: {np.shape(self.bound)}")

    @property
    def regret(self) -> np.ndarray:
        """The worst over scenarios of each candidate's error relative to the best of its scenario and channel,
        shape ``(n_candidates, n_channels)`` (1: the best everywhere)."""
        errors = np.asarray(self.errors, dtype=float)
        best = np.min(errors, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(errors == best, 1.0, errors / best)  # exact (0 / 0) ties count as ties
        return np.max(ratio, axis=0)

    @property
    def safe(self) -> np.ndarray:
        """Whether each candidate is, in every scenario, within :data:`TOLERANCE` of the better of the
        :data:`REFERENCES` present among the candidates (what a user would otherwise pick), shape
        ``(n_candidates, n_channels)``; all True without references."""
        errors = np.asarray(self.errors, dtype=float)
        refs = _reference_indices(self.candidates)
        if not refs:
            return np.ones(errors.shape[1:], dtype=bool)
        best = np.min(errors[:, refs], axis=1, keepdims=True)
        return np.all(errors <= (1.0 + TOLERANCE) * best, axis=0)

    @property
    def choice(self) -> np.ndarray:
        """Index into :attr:`candidates` of every channel's choice, shape ``(n_channels,)``: the smallest
        :attr:`regret` among the candidates :attr:`safe` and :attr:`proven` there (among all where none is), the
        first on a tie; replaced by one candidate for every channel where one is safe and proven on every channel
        and within :data:`TOLERANCE` of that choice on every channel and scenario (the one of smallest worst ratio,
        the first on a tie). A :attr:`joint` candidate is taken for every channel if it is safe and proven on every
        channel and its worst regret over the channels is smaller than that of the per-channel choice among the
        others."""
        if not self.joint:
            regret = np.where(self.safe & self.proven, self.regret, np.inf)
            none_safe = ~np.isfinite(regret).any(axis=0)
            regret[:, none_safe] = self.regret[:, none_safe]
            return self._one_for_all(np.argmin(regret, axis=0))
        bound = None if self.bound is None else np.asarray(self.bound)[:, :-1]
        others = Selection(self.candidates[:-1], np.asarray(self.errors)[:, :-1], self.source, bound=bound)
        per_channel = others.choice
        regret, k = self.regret, len(self.candidates) - 1
        channels = np.arange(per_channel.size)
        if (self.safe & self.proven)[k].all() and regret[k].max() < regret[per_channel, channels].max():
            return np.full(per_channel.size, k)
        return per_channel

    @property
    def proven(self) -> np.ndarray:
        """Whether each candidate's gain over the references is more than the trials' spread can explain, shape
        ``(n_candidates, n_channels)``: a reference always; another candidate if, at its :attr:`bound` (the most it
        could lose to the better reference), it loses less than the safe reference of smallest worst regret is
        measured to lose to the best candidate. All True without bounds (a prediction) or references."""
        refs = _reference_indices(self.candidates)
        proven = np.ones(np.shape(self.errors)[1:], dtype=bool)
        if self.bound is None or not refs:
            return proven
        regret = np.where(self.safe, self.regret, np.inf)[refs]  # the references' worst regret, where safe
        ref_regret = np.min(regret, axis=0)
        doubt = np.max(np.asarray(self.bound, dtype=float), axis=0)  # (C, n): the worst bound over scenarios
        proven = doubt <= ref_regret
        proven[refs] = True
        return proven

    def _one_for_all(self, choice: np.ndarray) -> np.ndarray:
        """``choice``, or one candidate for every channel where one is as good (:attr:`choice`)."""
        if np.all(choice == choice[0]):
            return choice
        errors = np.asarray(self.errors, dtype=float)
        chosen = errors[:, choice, np.arange(choice.size)][:, None]  # (scenarios, 1, channels)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(errors == chosen, 1.0, errors / chosen)  # exact (0 / 0) ties count as ties
        worst = np.max(ratio, axis=(0, 2))
        worst[~(self.safe & self.proven).all(axis=1)] = np.inf
        k = int(np.argmin(worst))
        return np.full(choice.size, k) if worst[k] <= 1.0 + TOLERANCE else choice

    @property
    def names(self) -> tuple[str, ...]:
        """The winning spec of every channel."""
        return tuple(self.candidates[i] for i in self.choice)

    def __str__(self) -> str:
        groups = {}
        for channel, name in enumerate(self.names):
            groups.setdefault(name, []).append(channel)
        return f"auto ({self.source}): " + ", ".join(f"{name} on {channels}" for name, channels in groups.items())


def _kalman_ca_error(dt: float, q: float, r: float, c: np.ndarray) -> float:
    """RMS of the reported velocity ``c . x`` of the steady-state constant-acceleration Kalman filter."""
    try:
        posterior = steady_state_covariance(dt, q, r)
    except (ValueError, np.linalg.LinAlgError):
        return np.inf
    v = np.concatenate([[0.0], c])
    return float(np.sqrt(max(v @ posterior @ v, 0.0)))


def predicted_errors(calibration: Calibration, candidates: Sequence[str], mean_over: float | None = None) -> np.ndarray:
    r"""Predicted velocity RMSE of every candidate on every channel, shape ``(n_candidates, n_channels)`` (module
    notes): closed forms for ``"finite-difference"`` and ``"kalman-ca"`` (given gains in the spec are used), ``inf``
    for the others. ``mean_over``: the span the reported velocity is a mean over (None: instantaneous)."""
    if not isinstance(calibration, Calibration):
        raise TypeError(f"expected a Calibration, actual value: {calibration!r:.80}")
    span = 0.0 if mean_over is None else check_positive("mean_over", mean_over)
    dt = calibration.dt
    r = calibration.noise.reshape(-1) ** 2  # unfloored: an ideal sensor makes the difference exact
    n = r.size
    errors = np.full((len(candidates), n), np.inf)
    for k, spec in enumerate(candidates):
        name, kw = parse_observer_spec(spec)
        if name == "finite-difference" and not kw:
            accel = calibration.rms(2).reshape(-1)
            errors[k] = np.sqrt(2.0 * r / dt**2 + ((dt - span) / 2.0 * accel) ** 2)
        elif name == "kalman-ca":
            observer = default_observer(name, calibration, kw)
            q = np.broadcast_to(observer.process_noise, calibration.noise.shape).reshape(-1)
            rr = np.broadcast_to(observer.measurement_noise, calibration.noise.shape).reshape(-1)
            c = reported_coefficients(observer, mean_over)
            c = np.array([1.0, 0.0]) if c is None else c  # the velocity, or its step mean
            errors[k] = [_kalman_ca_error(dt, float(q[i]), float(rr[i]), c) for i in range(n)]
    return errors


class TrialErrors(NamedTuple):
    """An observer's errors on :class:`Trials`, per channel: ``rmse`` (n,) over every sample but each episode's
    first, and ``blocks`` (B, n), the sums of squared errors over consecutive blocks of at most :data:`BLOCK` of
    those samples of each episode (the units :func:`ratio_bound` resamples; an episode that never ends is many of
    them). ``inf`` where the observer diverged."""

    rmse: np.ndarray
    blocks: np.ndarray


def measure_on_trials(observer: Observer, trials: Trials, mean_over: float | None = None) -> TrialErrors:
    """The :class:`TrialErrors` of ``observer`` on ``trials``. An observer that
    :attr:`~smo_gym.observers.Observer.takes_input` gets the trials' ``inputs``; each reports the mean over
    ``mean_over`` seconds where it estimates the acceleration at the sample time
    (:func:`~smo_gym.observers.base.reported_coefficients`), as the wrappers report it."""
    if not isinstance(observer, Observer) or not isinstance(trials, Trials):
        raise TypeError(
            f"expected an Observer and Trials, actual value: {type(observer).__name__} and {type(trials).__name__}"
        )
    mean_over = None if mean_over is None else check_positive("mean_over", mean_over)
    n = trials.measured[0].shape[1]
    if observer.takes_input and trials.inputs is None:
        raise ValueError("expected trials with the inputs a model-based observer needs, actual value: inputs=None")
    c = reported_coefficients(observer, mean_over)  # None: the velocity as it is
    inputs = trials.inputs if observer.takes_input else (None,) * len(trials.measured)
    total, count, blocks = np.zeros(n), 0, []
    try:
        for Z, V, U in zip(trials.measured, trials.velocity, inputs, strict=True):
            observer.reset(Z[0])
            estimate = observer.run(Z[1:]) if U is None else observer.run(Z[1:], U[1:])
            squared = (reported_velocity(estimate, c) - V[1:]) ** 2
            total += np.sum(squared, axis=0)
            count += len(Z) - 1
            blocks.append(np.add.reduceat(squared, np.arange(0, len(squared), BLOCK), axis=0))
    except DivergenceError:
        size = sum(-(-(len(Z) - 1) // BLOCK) for Z in trials.measured)
        return TrialErrors(np.full(n, np.inf), np.full((size, n), np.inf))
    return TrialErrors(np.sqrt(total / count), np.concatenate(blocks))


def trial_errors(observer: Observer, trials: Trials, mean_over: float | None = None) -> np.ndarray:
    """Velocity RMSE per channel of ``observer`` on ``trials`` (:func:`measure_on_trials`); ``inf`` where it
    diverged. Shape ``(n,)``."""
    return measure_on_trials(observer, trials, mean_over).rmse


def ratio_bound(squared: np.ndarray, refs: Sequence[int], level: float = CONFIDENCE) -> np.ndarray:
    r"""Upper confidence bound of each candidate's RMSE over the better reference's, from blocks of squared errors.

    The blocks are resampled with replacement (:data:`RESAMPLES` times, a fixed seed: the bound is a function of
    the data), and each resample's ratio :math:`\sqrt{\sum_e w_e a_e / \sum_e w_e b_e}` (:math:`a_e`,
    :math:`b_e`: the candidate's and the better reference's sums of squared errors in block :math:`e`, the better
    reference chosen on all blocks) gives the bootstrap distribution; the bound is its ``level`` quantile (the
    percentile bootstrap; Efron and Tibshirani 1993, ch. 13). A symmetric interval from the standard error would
    not do: where the reference makes rare large errors (a sensor's gross errors) the ratio has a long tail
    towards small values only, and its standard error then says a large gain is uncertain in both directions.

    Parameters
    ----------
    squared : ndarray, shape (C, B, n)
        :attr:`TrialErrors.blocks` of every candidate.
    refs : sequence of int
        The candidates that are references.
    level : float
        One-sided level in (0, 1).

    Returns
    -------
    ndarray, shape (C, n)
        1 for the better reference itself, where both sums are 0 and everywhere without references; ``inf``
        where a candidate diverged.
    """
    if isinstance(level, bool) or not isinstance(level, (int, float, np.number)) or not 0.0 < level < 1.0:
        raise ValueError(f"expected level in (0, 1), actual value: {level!r}")
    squared = as_real_array("squared", squared)
    if squared.ndim != 3 or 0 in squared.shape[:2]:
        raise ValueError(f"expected squared of shape (C, B, n) with C, B >= 1, actual value: shape {squared.shape}")
    if not (squared >= 0).all():  # a NaN or a negative sum would read as a ratio of 1 or less
        raise ValueError("expected squared errors >= 0 (inf for a diverged candidate), actual value: NaN or negative")
    if not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) and 0 <= i < len(squared) for i in refs):
        raise ValueError(f"expected refs among the {len(squared)} candidates' indices, actual value: {list(refs)!r}")
    totals = squared.sum(axis=1)  # (C, n)
    if not len(refs):
        return np.ones(totals.shape)
    best = np.asarray(refs)[np.argmin(totals[list(refs)], axis=0)]  # the better reference of each channel
    b = np.take_along_axis(squared, best[None, None, :], axis=0)[0]  # (B, n)
    blocks = squared.shape[1]
    weights = np.random.default_rng(0).multinomial(blocks, np.full(blocks, 1.0 / blocks), size=RESAMPLES)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.sqrt(np.einsum("rb,cbn->rcn", weights, squared) / np.einsum("rb,bn->rn", weights, b)[:, None])
        ratio = np.where(np.isnan(ratio), 1.0, ratio)  # 0 / 0: both exact in that resample
        bound = np.quantile(ratio, level, axis=0)
    bound = np.where(np.isnan(bound), np.inf, bound)  # the quantile between two infinite ratios is inf - inf
    bound[best, np.arange(best.size)] = 1.0
    return bound


def _trial_errors(calibration: Calibration, trials: Trials, candidates, mean_over, kwargs, joint) -> TrialErrors:
    """:func:`measure_on_trials` of every candidate, each with its calibrated gains, and of ``joint``, stacked:
    ``rmse`` (C, n), ``blocks`` (C, B, n)."""
    observers = [
        default_observer(name, calibration, {**kwargs, **kw}) for name, kw in map(parse_observer_spec, candidates)
    ]
    found = [measure_on_trials(observer, trials, mean_over) for observer in observers + joint]
    return TrialErrors(np.stack([f.rmse for f in found]), np.stack([f.blocks for f in found]))


def select(
    calibration: Calibration,
    trials: Trials | Sequence[Trials] | None = None,
    *,
    candidates: Sequence[str] = CANDIDATES,
    mean_over: float | None = None,
    observer_kwargs: dict | None = None,
    joint: Observer | None = None,
) -> Selection:
    """Compare ``candidates`` on every channel: measured on ``trials`` if given, else predicted (module notes).

    Parameters
    ----------
    calibration : Calibration
        Of the channels, with the orders :func:`candidate_orders` names.
    trials : Trials or sequence of Trials, optional
        Measured positions and true velocities of the same channels; several sets are scenarios (motions of
        different character): a channel's choice is then the candidate whose worst error relative to the best of
        each scenario is smallest (:attr:`Selection.regret`), robust to which one the observer will meet.
    candidates : sequence of str
        Observer specs (default :data:`CANDIDATES`).
    mean_over : float, optional
        The reported velocity is the mean over the last ``mean_over`` seconds (MuJoCo's ``qvel``,
        :func:`smo_gym.engine.measurement.mean_velocity_span`); None: the instantaneous one.
    observer_kwargs : dict, optional
        Constructor arguments every candidate gets (``wrap``, say).
    joint : Observer, optional
        An observer that takes the control input, compared as the last candidate under the name ``joint.name``:
        for all channels together (:attr:`Selection.joint`) if it is model-based, per channel if it is a filter
        told the input (module notes); without trials its error is ``inf`` (no evidence, not chosen).
    """
    if not isinstance(calibration, Calibration):
        raise TypeError(f"expected a Calibration, actual value: {calibration!r:.80}")
    observer_kwargs = _check_kwargs(observer_kwargs)
    candidates = tuple(check_names("candidates", candidates, "specs"))
    if not candidates:
        raise ValueError("expected at least one candidate observer, actual value: none")
    if mean_over is not None:
        mean_over = check_positive("mean_over", mean_over)
    if joint is not None and not isinstance(joint, Observer):
        raise TypeError(f"expected joint to be an Observer or None, actual value: {joint!r:.80}")
    extra = [] if joint is None else [joint]
    refs = _reference_indices(candidates)
    if trials is None:
        errors = predicted_errors(calibration, candidates, mean_over)[None]
        if joint is not None:
            errors = np.concatenate([errors, np.full((1, 1, errors.shape[2]), np.inf)], axis=1)
        bound, source = ratio_bound(errors[0][:, None] ** 2, refs)[None], "prediction"  # one block: the ratio
    else:
        scenes = [trials] if isinstance(trials, Trials) else list(trials) if isinstance(trials, Sequence) else []
        if not scenes or not all(isinstance(t, Trials) for t in scenes):
            raise TypeError(f"expected Trials, a non-empty sequence of them, or None, actual value: {trials!r:.80}")
        for t in scenes:
            if t.measured[0].shape[1] != calibration.noise.size:
                raise ValueError(
                    f"expected trials of the calibration's {calibration.noise.size} channels, actual value: "
                    f"{t.measured[0].shape[1]}"
                )
        found = [_trial_errors(calibration, t, candidates, mean_over, observer_kwargs, extra) for t in scenes]
        errors = np.stack([f.rmse for f in found])
        bound = np.stack([ratio_bound(f.blocks, refs) for f in found])
        source = "trials"
    if not np.isfinite(errors.min(axis=1)).all():
        raise ValueError(f"expected a candidate with a finite error on every channel, actual value: {errors!r}")
    names = candidates + tuple(observer.name for observer in extra)
    return Selection(names, errors, source, joint=estimates_jointly(joint), bound=bound)


def estimates_jointly(observer: Observer | None) -> bool:
    """Whether ``observer``, a candidate that takes the control input, is chosen for all channels or for none
    (:attr:`Selection.joint`): a model-based observer, whose model couples the channels; not a filter told the
    input, whose channels are independent given it (module notes)."""
    return observer is not None and not isinstance(observer, InputJumpFilter)


def _check_kwargs(observer_kwargs, allowed: tuple[str, ...] = ("wrap",)) -> dict:
    """The constructor arguments every candidate gets: ``allowed`` only (``wrap``; each candidate's gains are its
    own; ``model=False``, no model-based candidate, is dropped)."""
    kwargs = dict(observer_kwargs or {})
    if "model" in kwargs and not kwargs["model"]:
        del kwargs["model"]
    unknown = sorted(set(kwargs) - set(allowed))
    if unknown:
        model = {"model", *MODEL_OPTIONS} & set(unknown)
        hint = (
            f"{', '.join(('model', *MODEL_OPTIONS))} describe a model-based candidate, which needs an environment: "
            "EstimatedVelocity(env, observer_kwargs={'model': True, ...})"
            if model
            else "name an observer to set its gains"
        )
        raise ValueError(
            f"expected no observer parameters but {' and '.join(allowed)} for observer='auto', which calibrates the "
            f"gains of each candidate ({hint}), actual value: {unknown}"
        )
    return kwargs


def _take(calibration: Calibration, channels: np.ndarray) -> Calibration:
    """The calibration of some channels only."""

    def part(a):
        return np.asarray(a).reshape(-1)[channels]

    return Calibration(
        calibration.dt,
        {r: part(v) for r, v in calibration.bounds.items()},
        {r: part(v) for r, v in calibration.typical.items()},
        part(calibration.noise),
        part(calibration.resolution),
        {r: part(v) for r, v in calibration.initial.items()},
    )


def auto_observer(
    calibration: Calibration,
    trials: Trials | None = None,
    *,
    candidates: Sequence[str] = CANDIDATES,
    mean_over: float | None = None,
    observer_kwargs: dict | None = None,
    selection: Selection | None = None,
    joint: Observer | None = None,
) -> Observer:
    """The observer ``"auto"`` builds: per channel the winner of :func:`select`, with its calibrated gains.

    Parameters are those of :func:`select` (``selection``: an earlier one, reused as it is, e.g. from a cache, made
    with the same ``joint``). ``observer_kwargs`` may hold a per-channel ``wrap`` (an array over the channels).
    Returns the winning observer itself when one candidate wins every channel, else a
    :class:`~smo_gym.observers.composite.PerChannel` (with ``mean_over``); either way the :class:`Selection` is
    its ``selection`` attribute. ``joint`` is returned itself where it is chosen for all channels together (a
    model-based one, :attr:`Selection.joint`), and a filter told the input is taken on the channels it wins
    (:meth:`~smo_gym.observers.input_kalman.InputJumpFilter.of_channels`, in a
    :class:`~smo_gym.observers.input_kalman.PerChannelInput`).
    """
    if selection is None:
        selection = select(
            calibration, trials, candidates=candidates, mean_over=mean_over, observer_kwargs=observer_kwargs,
            joint=joint,
        )  # fmt: skip
    if not isinstance(selection, Selection):
        raise TypeError(f"expected a Selection, actual value: {type(selection).__name__}")
    if (joint is not None or selection.joint) and not (  # the last candidate takes the input: it must be joint
        isinstance(joint, Observer)
        and selection.candidates[-1] == joint.name
        and selection.joint == estimates_jointly(joint)
    ):
        raise ValueError(
            "expected joint to be the observer the selection compared as its last candidate, per channel exactly "
            f"if it is a filter told the input, actual value: {type(joint).__name__} for the candidates "
            f"{selection.candidates} (joint={selection.joint})"
        )
    if selection.joint and np.all(selection.choice == len(selection.candidates) - 1):
        joint.selection = selection
        return joint
    kwargs = _check_kwargs(observer_kwargs)
    wrap = kwargs.pop("wrap", None)
    choice = selection.choice
    if choice.size != calibration.noise.size:  # a selection made for other channels (a stale cache entry)
        raise ValueError(
            f"expected a selection over the calibration's {calibration.noise.size} channels, actual value: "
            f"{choice.size} channels"
        )
    parts = []
    for k in np.unique(choice):
        channels = np.flatnonzero(choice == k)
        name, kw = parse_observer_spec(selection.candidates[k])
        kw = {**kwargs, **kw}
        if wrap is not None and not isinstance(wrap, (bool, np.bool_)):
            kw["wrap"] = np.asarray(wrap).reshape(-1)[channels]
        elif wrap is not None:
            kw["wrap"] = wrap
        whole = len(channels) == choice.size
        if joint is not None and k == len(selection.candidates) - 1:  # per channel: a filter told the input
            parts.append((joint if whole else joint.of_channels(channels), channels))
        else:
            part = default_observer(name, calibration if whole else _take(calibration, channels), kw)
            parts.append((part, channels))
    if len(parts) == 1:
        observer = parts[0][0]
    else:
        composite = PerChannelInput if any(part.takes_input for part, _ in parts) else PerChannel
        observer = composite(parts, mean_over=mean_over)
    observer.selection = selection
    return observer
