"""Bad input never crashes the interpreter, never passes silently, and is reported where it was received.

Two parts:

* regression tests of specific defects: out-of-bounds writes of the pure ``step`` (run in a subprocess, so that a
  segfault fails the test instead of killing pytest), non-finite values hidden by a sensor's delay line, silently
  converted dtypes, misspelled names, empty measurements;
* a property-based sweep (``hypothesis``, derandomized) over every public observer class, every sensor class and
  preset, their alternative constructors, ``make_observer`` and ``differentiate``, and their public methods, with
  well-formed and malformed arguments, and a systematic grid (each constructor parameter with each bad value).
  The contract: a rejected input raises ``ValueError``, ``TypeError`` or ``RuntimeError`` (or a project
  subclass) whose message says what was expected; an accepted input gives finite results; a rejected call leaves
  the object's state as it was. ``pytest -s tests/test_bad_input.py -k totals`` prints how many calls the sweep
  made and its CPU time.
"""

from __future__ import annotations

import inspect
import subprocess
import sys
import textwrap
import time
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import smo_gym
from smo_gym import observers, sensors
from smo_gym.observers import (
    URED,
    AlphaBeta,
    CoordinateTransform,
    DiscreteTimeHOSM,
    DissipativeSuperTwisting,
    FilteringDifferentiator,
    FiniteDifference,
    HighGain,
    ILFDifferentiator,
    ILFFixedDifferentiator,
    ILFObserver,
    KalmanCA,
    KalmanCAInput,
    KalmanIMM,
    KalmanIMMInput,
    Levant,
    LowPowerHighGain,
    MechanicalSuperTwisting,
    Observer,
    PerChannel,
    PerChannelInput,
    SuperTwisting,
    SwitchedGain,
    UniformLevant,
    WorstCaseOptimal,
    make_observer,
)
from smo_gym.sensors import (
    PRESETS,
    Bias,
    Chain,
    Delay,
    Drift,
    Dropout,
    Encoder,
    GaussianNoise,
    Outliers,
    Quantization,
    Sensor,
    Stage,
    UniformNoise,
    Wrap,
    make_sensor,
)

REPO = Path(__file__).resolve().parents[1]


def assert_worded(excinfo):
    """Typed errors say what was expected and what was received."""
    msg = str(excinfo.value)
    assert "expected" in msg and "actual value" in msg, msg


class Pendulums:
    """``n`` independent damped pendulums, :math:`\\ddot q = -\\sin q - 0.1\\dot q + u`: a small dynamics object.

    It checks its own input as a user's model should (the observer only checks that ``u`` is real and finite).
    """

    def __init__(self, n: int):
        self.n = n

    def acceleration(self, q, v, u=None):
        a = -np.sin(q) - 0.1 * np.asarray(v)
        if u is None:
            return a
        u = np.asarray(u, dtype=float)
        if u.shape not in ((), (self.n,), np.shape(q)):
            raise ValueError(f"expected u of shape ({self.n},) or {np.shape(q)}, actual value: {u.shape}")
        return a + u

    def inertia(self, q):
        return np.broadcast_to(np.eye(self.n), np.shape(q) + (self.n,))


#: a Hurwitz gain of the two-state chain (s^2 + 3 s + 2) for the ILF differentiators: no LMI solve in the tests
ILF_GAIN = [-3.0, -2.0]
#: gain and Lyapunov matrix of the order-1 switched-gain observer (the LMI design's, rounded): no LMI solve
SG_GAIN, SG_P = [2.6005, 2.0810], [[0.76909, -0.48053], [-0.48053, 0.60048]]


def every_observer(n: int = 3) -> list[Observer]:
    """One observer of every family of :data:`smo_gym.observers.OBSERVERS` and the model-based ones."""
    return [
        SuperTwisting(1e-3, 5.0),
        SuperTwisting(1e-3, 5.0, discretization="euler"),
        Levant(2, 1e-3, 5.0),
        Levant(2, 1e-3, 5.0, discretization="matching"),
        URED(1e-3, 5.0),
        UniformLevant(2, 1e-3, 5.0),
        HighGain(1e-3, 20.0, 2),
        FiniteDifference(1e-3),
        KalmanCA(1e-3, 10.0, 1e-6),
        SwitchedGain(1e-3, 1, gain=SG_GAIN, P=SG_P),
        LowPowerHighGain(1e-3, 20.0, 2),
        ILFDifferentiator(1e-3, 5.0, gain=ILF_GAIN),
        ILFFixedDifferentiator(1e-3, 5.0, gain=ILF_GAIN),
        DiscreteTimeHOSM(3, 1e-3, 5.0),
        MechanicalSuperTwisting(1e-3, Pendulums(n), 5.0),
        DissipativeSuperTwisting(
            1e-3,
            Pendulums(n),
            CoordinateTransform(lambda Y: 0.1 * np.tanh(Y), -np.ones(n), np.ones(n)),
            dict(k1=2.0, k2=1.0, k3=0.0, mu1=3.0, mu2=1.0),
        ),
    ]


# ================================================================================================================
# regression tests
# ================================================================================================================
def test_step_with_wrong_sizes_never_crashes_the_interpreter():
    """``Observer.step(state, y)`` hands its arrays to a compiled step that indexes them without bounds checks: a
    state or measurement of the wrong size used to write out of bounds (heap corruption, segfault) in 12 of 14
    observers. Every combination is now rejected with a typed error. Run in a subprocess: a crash fails this test
    instead of killing pytest."""
    code = textwrap.dedent(
        """
        import numpy as np
        import test_bad_input as t

        for obs in t.every_observer():
            obs.reset(np.zeros(3))
            if type(obs).step is not t.Observer.step:
                continue  # model-based: step is refused (see test_model_based_step_is_refused)
            good = obs.state
            N, S = good.shape
            cases = [(good[:1], np.zeros(300)), (good, np.zeros(1)), (good, np.zeros(300)),
                     (good[:, :1], np.zeros(N)), (np.zeros((N, S + 30)), np.zeros(N)),
                     (np.zeros((300, S)), np.zeros(300)), (np.zeros(S), np.zeros(N)),
                     (np.zeros((S + 1, N)), np.zeros(N)),
                     (np.zeros((N, S, 1)), np.zeros(N)), (good.astype(complex), np.zeros(N)),
                     (good, np.zeros(N, complex)), (np.full((N, S), np.nan), np.zeros(N))]
            for state, y in cases:
                for _ in range(20):
                    try:
                        obs.step(state, y)
                    except (ValueError, TypeError) as exc:
                        assert "expected" in str(exc), str(exc)
                        break
                else:
                    raise AssertionError(f"{type(obs).__name__} accepted state {state.shape}, y {y.shape}")
            new_state, est = obs.step(good, np.ones(3))  # the right sizes still work
            assert new_state.shape == good.shape and np.isfinite(est).all()
        print("ok")
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
        cwd=Path(__file__).parent,
        env={**__import__("os").environ, "PYTHONPATH": str(REPO)},
    )
    assert result.returncode == 0, f"exit status {result.returncode}\n{result.stdout[-2000:]}\n{result.stderr[-3000:]}"
    assert result.stdout.strip().endswith("ok")


def test_an_overflowing_coordinate_transform_is_refused_without_a_warning():
    """A range of width 1e300 makes the transform's integral overflow: the check subtracted ``inf - inf`` outside
    the guarded block, so the worded ``ValueError`` came with a ``RuntimeWarning`` (an error under the sweep's
    warnings filter; found by the sweep)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="overflows") as excinfo:
            CoordinateTransform(lambda Y: 0.1 * np.tanh(Y), -1e300, [1.0], grid=12)
    assert_worded(excinfo)


def test_model_based_step_is_refused():
    obs = MechanicalSuperTwisting(1e-3, Pendulums(2), 5.0)
    obs.reset(np.zeros(2))
    with pytest.raises(RuntimeError) as excinfo:
        obs.step(obs.state, np.zeros(2))
    assert_worded(excinfo)


@pytest.mark.parametrize(
    "factory",
    [
        lambda: SuperTwisting(1e-3, lipschitz=True),
        lambda: SuperTwisting(1e-3, lipschitz="5.0"),
        lambda: SuperTwisting(1e-3, lipschitz=5.0 + 0j),
        lambda: SuperTwisting(1e-3, k1=np.complex128(2.0), k2=3.0),
        lambda: SuperTwisting(True, lipschitz=5.0),
        lambda: Levant(2, 1e-3, [True, True]),
        lambda: Levant(2, 1e-3, np.array(["1", "2"])),
        lambda: Levant(2, 1e-3, 1.0, mu="0.5", discretization="matching"),
        lambda: URED(1e-3, 1.0, beta=True),
        lambda: UniformLevant(2, 1e-3, 1.0, k=[3.0, 3.0, 1.0 + 1j]),
        lambda: HighGain(1e-3, "20"),
        lambda: HighGain(1e-3, 20.0, coefficients=[2.0 + 0j, 1.0]),
        lambda: KalmanCA(1e-3, 1.0, 1e-6, initial_std=1.0),
        lambda: KalmanCA(1e-3, 1.0, 1e-6, initial_std="ab"),
        lambda: KalmanCA.from_levels(1e-3, jerk_rms="0.1", measurement_variance=1.0),
        lambda: LowPowerHighGain(1e-3, 20.0, 2, bounds=[True, True]),
        lambda: LowPowerHighGain(1e-3, 20.0, 2, bounds="2"),
        lambda: LowPowerHighGain(1e-3, 20.0, 2, bounds=[True, 2.0]),  # NumPy makes [1.0, 2.0] of it
        lambda: Levant(2, 1e-3, [5.0, np.array(True)]),
        lambda: SwitchedGain(1e-3, gain=[2.6 + 0j, 2.0], P=SG_P),
        lambda: SwitchedGain(1e-3, supervise="yes"),
        lambda: ILFDifferentiator(1e-3, lipschitz=True, gain=ILF_GAIN),
        lambda: DiscreteTimeHOSM(2, 1e-3, True),
        lambda: DiscreteTimeHOSM(2, 1e-3, 1.0, mu=True),
        lambda: DiscreteTimeHOSM(2, 1e-3, 1.0, mu="1"),
        lambda: MechanicalSuperTwisting(1e-3, Pendulums(2), lipschitz=[1.0, "2"]),
        lambda: MechanicalSuperTwisting(1e-3, Pendulums(2), lipschitz=(1.0, np.True_)),
    ],
)
def test_bools_strings_and_complex_numbers_are_not_gains(factory):
    """NumPy would read ``True`` as 1, ``"5.0"`` as 5 and drop an imaginary part: a gain must be a real number."""
    with pytest.raises(TypeError) as excinfo:
        factory()
    assert_worded(excinfo)


@pytest.mark.parametrize("gain", [[3.0, 2.0], [-3.0, 0.0], [0.0, -2.0], [-1.0, 5.0]])
@pytest.mark.parametrize("cls", [ILFDifferentiator, ILFFixedDifferentiator])
def test_ilf_differentiator_rejects_a_non_hurwitz_gain(cls, gain):
    """The chain's error matrix ``N + L e_1^T`` has characteristic polynomial ``s^2 - L_1 s - L_2``: Hurwitz iff
    both gains are negative."""
    with pytest.raises(ValueError, match="Hurwitz") as excinfo:
        cls(1e-3, 5.0, gain=gain)
    assert_worded(excinfo)
    cls(1e-3, 5.0, gain=[-3.0, -2.0])


@pytest.mark.parametrize("mask", ["yes", 1, [1, 0], np.array([0.0, 1.0]), [None, True], np.array(["a", "b"])])
def test_masks_must_be_bools(mask):
    """``np.asarray("yes", dtype=bool)`` is True: a mask of anything but bools used to restart every row."""
    for obs in (Levant(2, 1e-3, 5.0), DiscreteTimeHOSM(2, 1e-3, 1.0), MechanicalSuperTwisting(1e-3, Pendulums(3), 5.0)):
        obs.reset(np.zeros((2, 3)))
        obs.update(np.ones((2, 3)))
        before = obs.estimate.copy()
        with pytest.raises(TypeError) as excinfo:
            obs.reset(np.ones((2, 3)), mask=mask)
        assert_worded(excinfo)
        np.testing.assert_array_equal(obs.estimate, before)


def test_misspelled_names_are_reported_with_the_closest_one():
    cases = [
        (lambda: SuperTwisting(1e-3, lipschits=5.0), "unknown parameter 'lipschits'", "did you mean 'lipschitz'"),
        (lambda: make_observer("levant", dt=1e-3, ordr=2), "unknown parameter 'ordr'", "did you mean 'order'"),
        (
            lambda: smo_gym.differentiate(np.zeros(5), 1e-3, "super-twisting", lipschitz=1.0, k_1=2.0),
            "unknown parameter 'k_1'",
            "did you mean 'k1'",
        ),
        (lambda: make_observer("levnat", dt=1e-3), "expected an observer name", "did you mean 'levant'"),
        (lambda: make_sensor("encoder-12bits"), "expected a sensor preset", "did you mean 'encoder-12bit'"),
        (lambda: Levant(2, 1e-3, discretization="tayler"), "expected discretization", "did you mean 'taylor'"),
        (lambda: GaussianNoise(sdt=1e-3), "unknown parameter 'sdt'", "did you mean 'std'"),
        (lambda: Levant(2, 1e-3).reset(np.zeros(2), maks=None), "unknown parameter 'maks'", "did you mean 'mask'"),
        (
            lambda: MechanicalSuperTwisting(1e-3, Pendulums(2), 1.0, accel_bund=3.0),
            "unknown parameter 'accel_bund'",
            "did you mean 'accel_bound'",
        ),
        (
            lambda: DiscreteTimeHOSM(2, 1e-3, 1.0, maping="matching"),
            "unknown parameter 'maping'",
            "did you mean 'mapping'",
        ),
        (lambda: SuperTwisting(), "expected argument 'dt'", "missing"),
        (lambda: GaussianNoise(1e-3, 2e-3), "expected at most 1 positional", "actual value: 2"),
    ]
    for call, what, hint in cases:
        with pytest.raises((TypeError, ValueError)) as excinfo:
            call()
        assert what in str(excinfo.value) and hint in str(excinfo.value), str(excinfo.value)
        assert "expected" in str(excinfo.value)


def test_check_keywords_keeps_type_errors_of_the_body():
    from smo_gym._validation import check_keywords, did_you_mean

    @check_keywords
    def f(a, *, b=1):
        raise TypeError("expected b to be an int, actual value: 'x'")

    with pytest.raises(TypeError, match="b to be an int"):
        f(1, b="x")
    with pytest.raises(TypeError, match="unknown parameter 'c'"):
        f(1, c=2)
    assert did_you_mean("lipschits", ["lipschitz", "k1"]) == " (did you mean 'lipschitz'?)"
    assert did_you_mean("zzz", ["lipschitz", "k1"]) == ""
    assert inspect.signature(SuperTwisting).parameters.keys() >= {"dt", "lipschitz", "k1", "k2"}


@pytest.mark.parametrize("obs", every_observer(), ids=lambda o: type(o).__name__ + "-" + o.discretization)
@pytest.mark.parametrize("shape", [(0,), (3, 0), (0, 3)])
def test_empty_measurements_are_rejected_by_every_observer(obs, shape):
    """Zero channels (or an empty batch) behave the same in every family: a ValueError at ``reset``, naming the
    shape; the observer stays as it was (usable with its previous shape)."""
    n = 3
    obs.reset(np.zeros(n))
    with pytest.raises(ValueError, match="at least one channel") as excinfo:
        obs.reset(np.zeros(shape))
    assert_worded(excinfo)
    assert obs.update(np.ones(n)).shape == (n, obs.order + 1)


@pytest.mark.parametrize("shape", [(0,), (3, 0), (0, 3)])
def test_empty_measurements_are_rejected_by_the_other_observers_and_sensors(shape):
    for reset in (
        DiscreteTimeHOSM(2, 1e-3, 1.0).reset,
        GaussianNoise(1e-3).reset,
        lambda y: smo_gym.differentiate(np.zeros((4,) + shape), 1e-3, "levant"),
    ):
        with pytest.raises(ValueError) as excinfo:
            reset(np.zeros(shape))
        assert_worded(excinfo)
    ilf = ILFObserver(np.eye(2, k=1), [[1.0, 0.0]], [[-3.0], [2.0]], 1.0, dt=1e-3)
    with pytest.raises(ValueError) as excinfo:
        ilf.reset(np.zeros(shape[:-1] + (0,)))
    assert_worded(excinfo)


def test_abstract_bases_are_refused_with_a_worded_error():
    with pytest.raises(TypeError) as excinfo:
        Observer(1e-3, 1, None)
    assert_worded(excinfo)
    with pytest.raises(RuntimeError) as excinfo:
        Sensor().reset(np.zeros(2))
    assert_worded(excinfo)


def test_non_finite_input_to_model_terms_of_discrete_hosm():
    obs = DiscreteTimeHOSM(2, 1e-2, 1.0, gamma=[None, lambda xi, u: np.zeros(xi.shape[:-1]) + u], L_gamma=[0, 5])
    obs.reset(np.zeros(2))
    before = obs.estimate
    for u in (np.array([np.nan, 0.0]), np.array([0.0, 1j])):
        with pytest.raises((ValueError, TypeError)) as excinfo:
            obs.update(np.ones(2), u)
        assert_worded(excinfo)
    np.testing.assert_array_equal(obs.estimate, before)
    bad_model = DiscreteTimeHOSM(
        2, 1e-2, 1.0, gamma=[None, lambda xi, u: np.full(xi.shape[:-1], np.nan)], L_gamma=[0, 5]
    )
    bad_model.reset(np.zeros(2))
    with pytest.raises(ValueError, match="gamma\\[1\\]") as excinfo:
        bad_model.update(np.ones(2))
    assert_worded(excinfo)


# ================================================================================================================
# property-based sweep
# ================================================================================================================
#: what the sweep did: inputs tried (calls), rejected, accepted, per family
COUNTS: Counter = Counter()
#: per swept family: (calls, rejected, accepted, seconds of CPU) of its hypothesis sweep
SWEPT: dict[str, tuple[int, int, int, float]] = {}
#: examples per family (each is a construction followed by several method calls)
EXAMPLES = 100
#: each family's sweep must have made at least this many calls (a guard against a sweep that silently tests little).
#: The sweep is derandomized, so a given pytest command always draws the same inputs; Hypothesis also draws
#: constants found in the project's modules loaded at the time, so the counts differ a little between, say,
#: ``pytest tests/test_bad_input.py`` and the whole suite (each family makes 200 calls or more either way).
MIN_CALLS_PER_FAMILY = 130

REJECTED = object()


def _allowed(exc: BaseException) -> bool:
    """A typed error of the project: ValueError/TypeError/RuntimeError themselves or a smo_gym subclass of them
    (not numpy.linalg.LinAlgError, a ValueError subclass that says nothing about what was expected)."""
    if not isinstance(exc, (ValueError, TypeError, RuntimeError)):
        return False
    cls = type(exc)
    return cls in (ValueError, TypeError, RuntimeError, NotImplementedError) or cls.__module__.startswith("smo_gym")


def _finite_leaves(value) -> list:
    if isinstance(value, np.ndarray):
        return [value] if value.dtype.kind in "fc" else []
    if isinstance(value, (float, np.floating)):
        return [np.asarray(value)]
    if isinstance(value, (tuple, list)):
        return [leaf for v in value for leaf in _finite_leaves(v)]
    return []


def attempt(family: str, fn, *args, snapshot=None, **kwargs):
    """Call ``fn``; a rejection must be typed and worded (and leave ``snapshot()`` unchanged); a result finite."""
    COUNTS["calls"] += 1
    COUNTS[family] += 1
    before = None if snapshot is None else snapshot()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a warning here is a silent conversion or an unguarded overflow
            out = fn(*args, **kwargs)
    except Exception as exc:
        assert _allowed(exc), f"{family}: raw {type(exc).__module__}.{type(exc).__name__}: {exc}"
        assert "expected" in str(exc), f"{family}: unworded {type(exc).__name__}: {exc}"
        if before is not None and "produced by the sensor model" not in str(exc):
            after = snapshot()
            for a, b in zip(before, after, strict=False):
                np.testing.assert_array_equal(a, b, err_msg=f"{family}: state changed by a rejected call: {exc}")
        COUNTS["rejected"] += 1
        return REJECTED
    for leaf in _finite_leaves(out):
        assert np.isfinite(leaf).all(), f"{family}: non-finite result of {getattr(fn, '__name__', fn)}: {out}"
    COUNTS["accepted"] += 1
    return out


# ---- strategies ------------------------------------------------------------------------------------------------
def _datetime(shape):
    return np.full(shape, np.datetime64("2020-01-01", "D"))


#: values that no numeric parameter accepts, of every kind NumPy would silently convert or choke on
BAD_VALUES = [
    True,
    False,
    "1.0",
    "yes",
    1 + 1j,
    np.complex128(1.0),
    np.nan,
    np.inf,
    -np.inf,
    None,
    [[1.0], [2.0, 3.0]],
    np.array([]),
    np.datetime64("2020-01-01"),
    np.timedelta64(1, "s"),
    object(),
    np.array([1.0, np.nan]),
    [1.0, "2"],
    {"a": 1},
]


def good_or_bad(good: st.SearchStrategy) -> st.SearchStrategy:
    """Mostly a good value, sometimes one of :data:`BAD_VALUES`, sometimes a negative or zero number."""
    return st.one_of(good, good, good, st.sampled_from(BAD_VALUES), st.sampled_from([-1.0, 0.0, -1e300]))


def positive(lo=0.1, hi=100.0):
    return st.floats(lo, hi)


def positive_or_per_channel(n, lo=0.1, hi=100.0):
    """A scalar, one value per channel, or (rarely) one value too many."""
    return st.one_of(
        positive(lo, hi),
        positive(lo, hi),
        st.lists(positive(lo, hi), min_size=n, max_size=n).map(np.array),
        st.lists(positive(lo, hi), min_size=n + 1, max_size=n + 1),
    )


@st.composite
def measurement(draw, shape, scale=2.0):
    """A measurement of ``shape``, or something else: another shape, dtype, NaN/inf, huge values, not an array."""
    kind = draw(
        st.sampled_from(
            ["good"] * 18
            + [
                "list",
                "float32",
                "int",
                "strided",
                "nan",
                "inf",
                "huge",
                "wrong-shape",
                "empty",
                "complex",
                "datetime",
                "timedelta",
                "bool",
                "str",
                "object",
                "ragged",
                "none",
                "scalar",
            ]
        )
    )
    size = int(np.prod(shape))
    good = np.array(draw(st.lists(st.floats(-scale, scale), min_size=size, max_size=size))).reshape(shape)
    if kind == "good":
        return good
    if kind == "list":
        return good.tolist()
    if kind == "float32":
        return good.astype(np.float32)
    if kind == "int":
        return np.round(good).astype(np.int64)
    if kind == "strided":
        return np.repeat(good, 2, axis=-1)[..., ::2]
    if kind in ("nan", "inf", "huge"):
        bad = good.copy().reshape(-1)
        bad[draw(st.integers(0, size - 1))] = {"nan": np.nan, "inf": -np.inf, "huge": 1e300}[kind]
        return bad.reshape(shape)
    if kind == "wrong-shape":
        other = draw(st.sampled_from([shape[:-1] + (shape[-1] + 1,), shape + (1,), (2,) + shape, shape[::-1] + (2,)]))
        return np.zeros(other)
    if kind == "empty":
        return np.zeros(shape[:-1] + (0,))
    if kind == "complex":
        return good + 1j
    if kind == "datetime":
        return _datetime(shape)
    if kind == "timedelta":
        return np.ones(shape, dtype="m8[s]")
    if kind == "bool":
        return good > 0
    if kind == "str":
        return good.astype(str)
    if kind == "object":
        return np.array([None] * size, dtype=object).reshape(shape)
    if kind == "ragged":
        return [[1.0] * shape[-1], [1.0]]
    if kind == "none":
        return None
    return 1.0


@st.composite
def block(draw, shape, T=None):
    """``(T, *shape)`` blocks (``T`` in 0..4), or malformed ones."""
    T = draw(st.integers(0, 4)) if T is None else T
    kind = draw(st.sampled_from(["good"] * 6 + ["row", "ragged", "complex", "nan", "scalar", "wrong"]))
    good = np.array(
        draw(st.lists(st.floats(-2.0, 2.0), min_size=T * int(np.prod(shape)), max_size=T * int(np.prod(shape))))
    ).reshape((T,) + shape)
    if kind == "good":
        return good
    if kind == "row":
        return draw(measurement(shape))
    if kind == "ragged":
        return [np.zeros(shape).tolist(), [0.0]]
    if kind == "complex":
        return good.astype(complex)
    if kind == "nan":
        return np.full((max(T, 1),) + shape, np.nan)
    if kind == "scalar":
        return 0.0
    return np.zeros((T,) + shape[:-1] + (shape[-1] + 2,))


@st.composite
def mask(draw, shape):
    kind = draw(st.sampled_from(["none", "rows", "full", "wrong", "yes", "int", "list", "float"]))
    if kind == "none":
        return None
    if kind == "rows":
        return np.array(
            draw(st.lists(st.booleans(), min_size=int(np.prod(shape[:-1])), max_size=int(np.prod(shape[:-1]))))
        ).reshape(shape[:-1])
    if kind == "full":
        return np.array(
            draw(st.lists(st.booleans(), min_size=int(np.prod(shape)), max_size=int(np.prod(shape))))
        ).reshape(shape)
    if kind == "wrong":
        return np.ones(shape + (2,), bool)
    if kind == "yes":
        return "yes"
    if kind == "int":
        return np.ones(shape[:-1], dtype=int)
    if kind == "list":
        return [True] * shape[-1]
    return np.ones(shape, dtype=float)


def misspell(name: str) -> str:
    """A plausible typo of ``name`` that is not ``name``: a doubled letter at the end."""
    return name + name[-1]


# ---- the swept families ----------------------------------------------------------------------------------------
@dataclass
class Family:
    """How to build one public class: good keyword strategies given ``n`` channels, and what to call on it."""

    name: str
    cls: type
    params: callable  # n -> dict of name -> strategy (mostly good values; constructor_arguments spoils one)
    kind: str = "observer"  # observer | model | ilf-observer | dhosm | transform | sensor | abstract
    fixed: callable = field(default=lambda n: {})  # n -> values that are not swept (dynamics objects)


def name_kwargs(name) -> dict:
    """What the registered observer ``name`` needs besides ``dt`` (for make_observer and differentiate): the first
    example its registration declares (:attr:`smo_gym.observers.Family.examples`); nothing for other names."""
    family = observers.FAMILIES.get(name) if isinstance(name, str) else None
    return dict(family.examples[0]) if family is not None and family.examples else {}


def _disc(cls):
    good = st.sampled_from((None,) + cls.discretizations)
    return st.one_of(good, good, good, st.sampled_from(["implict", "rk4", 3]))


OBSERVER_FAMILIES = [
    Family(
        "SuperTwisting",
        SuperTwisting,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            k1=st.one_of(st.none(), positive()),
            k2=st.one_of(st.none(), positive()),
            discretization=_disc(SuperTwisting),
        ),
    ),
    Family(
        "Levant",
        Levant,
        lambda n: dict(
            order=st.sampled_from([1, 2, 3, 4, 5] * 3 + [0, 6]),
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            discretization=_disc(Levant),
            p1=st.one_of(st.none(), st.none(), st.none(), positive(1.0, 50.0)),
            mu=st.one_of(st.just(0.0), st.just(0.0), st.just(0.0), positive(0.0, 2.0)),
        ),
    ),
    Family(
        "FilteringDifferentiator",
        FilteringDifferentiator,
        lambda n: dict(
            order=st.sampled_from([1, 2, 3] * 3 + [0, 6]),
            filtering_order=st.sampled_from([0, 1, 2] * 3 + [-1, 5]),
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            degree=st.sampled_from([-1.0, -0.5, 0.0] * 3 + [0.5, -1.5]),
            discretization=_disc(FilteringDifferentiator),
            p1=st.one_of(st.none(), st.none(), positive(1.0, 50.0)),
        ),
    ),
    Family(
        "URED",
        URED,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            k1=st.one_of(st.none(), positive()),
            k2=st.one_of(st.none(), positive()),
            beta=positive(0.01, 5.0),
            discretization=_disc(URED),
        ),
    ),
    Family(
        "UniformLevant",
        UniformLevant,
        lambda n: dict(
            order=st.integers(1, 3),
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            alpha=positive(0.1, 2.0),
            discretization=_disc(UniformLevant),
        ),
    ),
    Family(
        "HighGain",
        HighGain,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            gain=st.one_of(positive(0.1, 1e3), st.just(1e300)),
            order=st.integers(1, 9),
            discretization=_disc(HighGain),
        ),
    ),
    Family(
        "FiniteDifference",
        FiniteDifference,
        lambda n: dict(
            dt=positive(1e-4, 2e-2), order=st.sampled_from([1, 2, 1, 2, 0, 3]), discretization=_disc(FiniteDifference)
        ),
    ),
    Family(
        "KalmanCA",
        KalmanCA,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            process_noise=positive(1e-3, 1e4),
            measurement_noise=positive(1e-8, 1.0),
            initial_std=st.one_of(
                st.tuples(positive(), positive()),
                st.tuples(positive(), positive()),
                st.sampled_from([1.0, (1.0,), "ab"]),
            ),
            discretization=_disc(KalmanCA),
        ),
    ),
    Family(
        "KalmanIMM",
        KalmanIMM,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            process_noise=st.one_of(positive(1e-3, 1e4), st.lists(positive(1e-3, 1e4), min_size=n, max_size=n)),
            measurement_noise=positive(1e-8, 1.0),
            smooth_ratio=st.one_of(positive(1e-4, 1.0), st.sampled_from([0.0, 1.5, -0.1])),
            stay=st.one_of(positive(0.5, 0.999), st.sampled_from([1.0, 0.0, 2.0])),
            initial_std=st.one_of(st.tuples(positive(), positive()), st.sampled_from([1.0, (1.0,), "ab"])),
            discretization=_disc(KalmanIMM),
        ),
    ),
    Family(
        "KalmanCAInput",
        KalmanCAInput,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            process_noise=positive(1e-3, 1e4),
            measurement_noise=positive(1e-8, 1.0),
            input_gain=st.one_of(
                st.just(np.ones((n, 1))), st.just(np.ones((n, 2))), st.sampled_from([np.ones(n), [[np.nan]] * n])
            ),
            jump_noise=st.one_of(positive(0.0, 1e3), positive_or_per_channel(n, 0.0, 1e3), st.just(-1.0)),
            discretization=_disc(KalmanCAInput),
        ),
    ),
    Family(
        "KalmanIMMInput",
        KalmanIMMInput,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            process_noise=positive(1e-3, 1e4),
            measurement_noise=positive(1e-8, 1.0),
            input_gain=st.one_of(
                st.just(np.ones((n, 1))), st.just(np.ones((n, 2))), st.sampled_from([np.ones((n + 1, 1)), "ab"])
            ),
            jump_noise=st.one_of(positive(0.0, 1e3), positive_or_per_channel(n, 0.0, 1e3)),
            smooth_ratio=st.one_of(positive(1e-4, 1.0), positive(1e-4, 1.0), st.sampled_from([0.0, 1.5])),
            discretization=_disc(KalmanIMMInput),
        ),
    ),
    Family(
        "AlphaBeta",
        AlphaBeta,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            # mostly the calibrated form (both levels, no gains); sometimes gains, missing levels or bad gains
            acceleration_std=st.one_of(positive(1.0, 1e3), positive_or_per_channel(n, 1.0, 1e3), st.none()),
            noise_std=st.one_of(positive(1e-5, 1e-2), positive(1e-5, 1e-2), st.none()),
            alpha=st.one_of(st.none(), st.none(), st.none(), positive(0.05, 1.9), st.just(2.5)),
            beta=st.one_of(st.none(), st.none(), st.none(), positive(0.01, 3.0), st.just(-1.0)),
            discretization=_disc(AlphaBeta),
        ),
    ),
    Family(
        "SwitchedGain",
        SwitchedGain,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            order=st.just(1),
            gain=st.just(SG_GAIN),
            P=st.just(SG_P),
            q=positive(1.1, 4.0),
            mu0=st.one_of(st.none(), positive(1.0, 20.0)),
            T_min=st.one_of(st.none(), positive(1e-4, 1.0)),
            supervise=st.booleans(),
            restart_threshold=st.one_of(st.none(), positive(0.01, 10.0)),
            mu_max=st.one_of(st.none(), positive(1.0, 1e3)),
            mu_min=st.one_of(st.none(), positive(1.0, 100.0)),
        ),
    ),
    Family(
        "LowPowerHighGain",
        LowPowerHighGain,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            gain=st.one_of(positive(0.1, 500.0), st.just(1e300)),
            order=st.integers(1, 4),
            bounds=st.one_of(st.none(), positive(0.1, 10.0)),
            filter_coefficient=st.one_of(st.none(), positive(0.1, 3.0)),
            readout=st.sampled_from(["peaking-free", "low-power", "peaking"]),
            discretization=_disc(LowPowerHighGain),
        ),
    ),
    Family(
        "ILFDifferentiator",
        ILFDifferentiator,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            order=st.just(1),
            rate=st.one_of(st.none(), positive(1.0, 50.0)),
            gain=st.sampled_from([ILF_GAIN] * 4 + [[1.0, 2.0]]),
            rho_min=st.just(1e-14),
            discretization=_disc(ILFDifferentiator),
        ),
    ),
    Family(
        "ILFFixedDifferentiator",
        ILFFixedDifferentiator,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            order=st.just(1),
            mu=st.just(0.5),
            alpha=st.just(2.0),
            gain=st.just(ILF_GAIN),
            discretization=_disc(ILFFixedDifferentiator),
        ),
    ),
    Family(
        "WorstCaseOptimal",
        WorstCaseOptimal,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            noise=st.one_of(st.none(), st.just(0.0), positive_or_per_channel(n, 1e-6, 1e-2)),
            window=st.one_of(st.none(), st.none(), st.integers(1, 64), st.sampled_from([0, 5000, 2.5])),
            discretization=_disc(WorstCaseOptimal),
        ),
    ),
    Family(
        "MechanicalSuperTwisting",
        MechanicalSuperTwisting,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            lipschitz=positive_or_per_channel(n),
            accel_bound=st.one_of(st.none(), positive()),
            discretization=_disc(MechanicalSuperTwisting),
            euler_substeps=st.one_of(st.none(), st.integers(1, 5)),
            model_substeps=st.integers(1, 3),
            disturbance_time_constant=positive(1e-3, 1.0),
        ),
        kind="model",
        fixed=lambda n: dict(dynamics=Pendulums(n)),
    ),
    Family(
        "DissipativeSuperTwisting",
        DissipativeSuperTwisting,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            accel_bound=st.one_of(st.none(), positive()),
            gains=st.one_of(
                st.fixed_dictionaries(
                    dict(
                        k1=positive(0.5, 5.0),
                        k2=positive(0.5, 5.0),
                        k3=st.just(0.0),
                        mu1=positive(0.5, 5.0),
                        mu2=positive(0.0, 2.0),
                    )
                ),
                st.just(dict(k1=1.0)),
            ),
        ),
        kind="model",
        fixed=lambda n: dict(
            dynamics=Pendulums(n),
            transform=CoordinateTransform(lambda Y: 0.1 * np.tanh(Y), -3 * np.ones(n), 3 * np.ones(n)),
        ),
    ),
    Family(
        "ILFObserver",
        ILFObserver,
        lambda n: dict(
            A=st.sampled_from([np.eye(2, k=1)] * 4 + [np.zeros((2, 2)), np.ones((2, 3))]),
            C=st.just([[1.0, 0.0]]),
            L=st.sampled_from([[[-3.0], [2.0]]] * 4 + [[[3.0], [2.0]]]),
            mu=st.sampled_from([1.0, 0.5]),
            kind=st.sampled_from(["finite", "fixed"] * 3 + ["finit"]),
            dt=positive(1e-4, 2e-2),
            B=st.one_of(st.none(), st.just([[0.0], [1.0]])),
            rho_min=positive(1e-16, 1e-10),
            iterations=st.integers(1, 80),
        ),
        kind="ilf-observer",
    ),
    Family(
        "DiscreteTimeHOSM",
        DiscreteTimeHOSM,
        lambda n: dict(
            n=st.sampled_from([2, 3, 4] * 3 + [1]),
            dt=positive(1e-4, 2e-2),
            p1=positive_or_per_channel(n, 1.0, 50.0),
            mu=positive(0.0, 2.0),
            mapping=st.sampled_from(["semi-implicit", "matching"] * 3 + ["tustin"]),
            gamma=st.one_of(st.none(), st.just("model")),
            L_gamma=st.none(),
        ),
        kind="dhosm",
    ),
    Family(
        "CoordinateTransform",
        CoordinateTransform,
        lambda n: dict(
            alpha=st.sampled_from(
                [lambda Y: 0.1 * np.tanh(Y)] * 4
                + [
                    lambda Y: np.zeros(Y.shape[:1]),
                    lambda Y: Y + 1j,
                    lambda Y: np.full(Y.shape, np.nan),
                    lambda Y: 1e3 * Y,
                ]
            ),
            lower=st.just(-np.ones(n)),
            upper=st.sampled_from([np.ones(n), 2 * np.ones(n), -2 * np.ones(n)]),
            reference=st.sampled_from([None, None, np.zeros(n), np.full(n, 5.0)]),
            grid=st.integers(5, 200),
        ),
        kind="transform",
    ),
    Family(
        "PerChannel",
        PerChannel,
        lambda n: dict(
            parts=st.sampled_from(
                [
                    [(FiniteDifference(1e-3), list(range(n)))],
                    [(KalmanCA(1e-3, 10.0, 1e-6), [0])]
                    + ([(FiniteDifference(1e-3), list(range(1, n)))] if n > 1 else []),
                    [(Levant(2, 1e-3, 5.0), list(range(n))[::-1])],
                ]
            ),
            mean_over=st.one_of(st.none(), positive(1e-4, 2e-2)),
        ),
    ),
    Family(
        "PerChannelInput",
        PerChannelInput,
        lambda n: dict(
            parts=st.sampled_from(
                [
                    [(KalmanIMMInput(1e-3, 10.0, 1e-6, np.ones((n, 1)), 1.0), list(range(n)))],
                    [(KalmanCAInput(1e-3, 10.0, 1e-6, np.ones((1, 2)), 1.0), [0])]
                    + ([(FiniteDifference(1e-3), list(range(1, n)))] if n > 1 else []),
                    [(FiniteDifference(1e-3), list(range(n)))],  # none told the input: refused
                ]
            ),
            mean_over=st.one_of(st.none(), positive(1e-4, 2e-2)),
        ),
    ),
    Family(
        "Observer",
        Observer,
        lambda n: dict(dt=positive(1e-4, 2e-2), order=st.integers(1, 3), discretization=st.none()),
        kind="abstract",
    ),
    # the factories and the offline entry point
    Family(
        "make_observer",
        make_observer,
        lambda n: dict(
            name=st.sampled_from(sorted(observers.OBSERVERS) + ["levnat", "mechanical-super-twisting", 3]),
            dt=positive(1e-4, 2e-2),
        ),
        kind="factory",
    ),
    Family(
        "differentiate",
        smo_gym.differentiate,
        lambda n: dict(
            y=st.one_of(block((n,), T=5), block((n,), T=0), measurement((n,))),
            dt=positive(1e-4, 2e-2),
            method=st.sampled_from(sorted(observers.OBSERVERS) + ["levnat", None]),
        ),
        kind="factory",
    ),
    # the alternative constructors
    Family(
        "HighGain.from_bounds",
        HighGain.from_bounds,
        lambda n: dict(
            dt=positive(1e-4, 2e-2), lipschitz=positive(), noise=positive(1e-6, 1e-2), order=st.integers(1, 4)
        ),
    ),
    Family(
        "KalmanCA.from_levels",
        KalmanCA.from_levels,
        lambda n: dict(
            dt=positive(1e-4, 2e-2),
            jerk_rms=positive_or_per_channel(n, 0.0, 1e3),
            measurement_variance=positive_or_per_channel(n, 0.0, 1e-2),
        ),
    ),
]

SENSOR_FAMILIES = [
    Family("GaussianNoise", GaussianNoise, lambda n: dict(std=positive_or_per_channel(n, 0.0, 0.1)), kind="sensor"),
    Family("UniformNoise", UniformNoise, lambda n: dict(bound=positive_or_per_channel(n, 0.0, 0.1)), kind="sensor"),
    Family(
        "Quantization",
        Quantization,
        lambda n: dict(
            resolution=positive_or_per_channel(n, 0.0, 0.1), linear_resolution=st.one_of(st.none(), positive(0.0, 0.1))
        ),
        kind="sensor",
    ),
    Family("Bias", Bias, lambda n: dict(value=st.floats(-1, 1), std=positive(0.0, 0.1)), kind="sensor"),
    Family("Drift", Drift, lambda n: dict(rate_std=positive_or_per_channel(n, 0.0, 0.1)), kind="sensor"),
    Family("Delay", Delay, lambda n: dict(samples=st.integers(-1, 5)), kind="sensor"),
    Family(
        "Dropout", Dropout, lambda n: dict(probability=positive(0.0, 1.0), per_channel=st.booleans()), kind="sensor"
    ),
    Family(
        "Outliers", Outliers, lambda n: dict(probability=positive(0.0, 1.0), scale=positive(0.0, 1.0)), kind="sensor"
    ),
    Family(
        "Encoder",
        Encoder,
        lambda n: dict(
            resolution=st.one_of(st.none(), positive(1e-4, 0.1)),
            noise_std=positive(0.0, 0.01),
            counts_per_revolution=st.one_of(st.none(), st.integers(1, 2**16)),
            wrap=st.booleans(),
        ),
        kind="sensor",
    ),
    Family("Wrap", Wrap, lambda n: dict(), kind="sensor"),
    Family("Chain", Chain, lambda n: dict(), kind="sensor"),
    Family("Stage", Stage, lambda n: dict(), kind="sensor"),
    Family("Sensor", Sensor, lambda n: dict(), kind="sensor"),
    Family(
        "presets",
        make_sensor,
        lambda n: dict(sensor=st.sampled_from(sorted(PRESETS) + ["encoder-12bits", "lowcost", 3, None])),
        kind="sensor",
    ),
    Family(
        "Quantization.from_counts",
        Quantization.from_counts,
        lambda n: dict(counts_per_revolution=st.integers(1, 2**20), linear_travel=positive(0.0, 1.0)),
        kind="sensor",
    ),
]


@st.composite
def constructor_arguments(draw, family: Family, n: int):
    """Keyword arguments for ``family.cls``: all good values, or one replaced by a bad one, left out, or misspelled.

    Returns ``(kwargs, misspelled name or None)``.
    """
    kwargs = {name: draw(strategy) for name, strategy in family.params(n).items()}
    mode = draw(st.sampled_from(["good"] * 4 + ["bad", "missing", "misspelled"]))
    misspelled = None
    if kwargs and mode != "good":
        name = draw(st.sampled_from(sorted(kwargs)))
        if mode == "bad":
            kwargs[name] = draw(st.one_of(st.sampled_from(BAD_VALUES), st.sampled_from([-1.0, 0.0, -1e300])))
        elif mode == "missing":
            del kwargs[name]  # its default, or a missing required argument
        else:
            misspelled = misspell(name)
            kwargs[misspelled] = kwargs.pop(name)
    if family.kind == "dhosm" and kwargs.get("gamma") == "model":
        kwargs["gamma"] = [None, lambda xi, u: -np.sin(xi[..., 0]) + (0.0 if u is None else u)]
        kwargs["L_gamma"] = [0.0, 5.0]
    return kwargs, misspelled


def _observer_snapshot(obs):
    def snap():
        if getattr(obs, "_state", None) is None:
            return (np.zeros(0),)
        return (obs._state.copy(), obs._estimate.copy(), np.array(obs.n_updates))

    return snap


def _sensor_snapshot(sensor):
    def snap():
        if getattr(sensor, "_kinds", None) is None:
            return (np.zeros(0),)
        return (sensor._state.copy(), sensor._ring.copy(), sensor._ring_pos.copy(), np.array(sensor._t))

    return snap


def _x_snapshot(obj):
    """Snapshot of the observer that keeps its estimate in ``_x`` (ILFObserver)."""

    def snap():
        return (np.zeros(0),) if obj._x is None else (obj._x.copy(), np.array(obj.n_updates))

    return snap


def _argument_free_methods(obj) -> list[str]:
    """Public methods of ``obj`` callable without arguments."""
    names = []
    for name, member in inspect.getmembers(type(obj), inspect.isfunction):
        params = list(inspect.signature(member).parameters.values())[1:]
        if not name.startswith("_") and all(
            p.default is not p.empty or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) for p in params
        ):
            names.append(name)
    return names


#: properties that are not results: the raw arrays handed to compiled callers (``Observer.arrays``,
#: ``Sensor.arrays``), whose parameter rows hold inf where a bound is disabled
_RAW_VIEWS = {"arrays"}
#: properties whose ``+inf`` is a documented value, not an overflow: ``WorstCaseOptimal.certified_bound`` (no
#: certificate: nothing measured yet, or data that contradict the bounds); NaN or ``-inf`` there still fail
_UNBOUNDED = {"certified_bound"}


def _without_documented_inf(obj, prop: str):
    """The property ``prop`` of ``obj``, with ``+inf`` read as 0 where :data:`_UNBOUNDED` documents it."""
    value = getattr(obj, prop)
    return np.where(np.isposinf(value), 0.0, value) if prop in _UNBOUNDED else value


def _properties(obj) -> list[str]:
    return [
        name
        for name, value in inspect.getmembers(type(obj))
        if isinstance(value, property) and not name.startswith("_") and name not in _RAW_VIEWS
    ]


def exercise_observer(data, family: Family, obj, shape):
    """Reset, then a random sequence of the public methods with good and bad arguments."""
    name = family.name
    snap = _observer_snapshot(obj)
    model = family.kind == "model"
    n = shape[-1]

    def inputs():
        if not model:
            return ()
        return (
            data.draw(
                st.one_of(
                    st.none(),
                    st.just(np.zeros(n)),
                    st.just(np.full(n, np.nan)),
                    st.just([0.5] * n),
                    st.just(np.ones(n, complex)),
                    st.just(np.ones(n + 1)),
                )
            ),
        )

    reset_kwargs = {}
    if model and data.draw(st.booleans()):
        reset_kwargs["v0"] = data.draw(
            st.sampled_from([np.zeros(n), [np.nan] + [0.0] * (n - 1), np.ones(n + 1), 1j, "1", 0.5])
        )
    attempt(name, obj.reset, data.draw(measurement(shape)), snapshot=snap, **reset_kwargs)
    good = np.array(
        data.draw(st.lists(st.floats(-0.5, 0.5), min_size=int(np.prod(shape)), max_size=int(np.prod(shape))))
    ).reshape(shape)
    if attempt(name, obj.reset, good, snapshot=snap) is REJECTED:
        return
    for _ in range(data.draw(st.integers(2, 8))):
        op = data.draw(st.sampled_from(["update"] * 4 + ["run", "step", "restart", "mask", "properties", "kw"]))
        if op == "update":
            attempt(name, obj.update, data.draw(measurement(shape, scale=0.5)), *inputs(), snapshot=snap)
        elif op == "run":
            Y = data.draw(block(shape))
            if model:
                U = data.draw(st.sampled_from([None, "same", np.zeros((1, n)), [[0.0] * n, [0.0]]]))
                if isinstance(U, str):  # inputs for as many samples as Y has (Y may be ragged: len, not shape)
                    U = np.zeros((len(Y) if isinstance(Y, (list, tuple)) else np.shape(Y)[0] if np.ndim(Y) else 1, n))
                attempt(name, obj.run, Y, U, snapshot=snap)
            else:
                attempt(name, obj.run, Y, snapshot=snap)
        elif op == "step":
            state = obj.state if obj.shape is not None else np.zeros((1, 1))
            state = data.draw(
                st.sampled_from(
                    [
                        state,
                        state[:1],
                        np.zeros((state.shape[0] + 5, state.shape[1])),
                        state[:, :1],
                        state.astype(complex),
                        np.full(state.shape, np.nan),
                    ]
                )
            )
            attempt(name, obj.step, state, data.draw(measurement(shape, scale=0.5)), snapshot=snap)
        elif op == "restart":
            attempt(name, obj.restart, data.draw(measurement(shape, scale=0.5)), snapshot=snap)
        elif op == "mask":
            attempt(
                name, obj.reset, data.draw(measurement(shape, scale=0.5)), mask=data.draw(mask(shape)), snapshot=snap
            )
        elif op == "kw":
            attempt(name, obj.reset, np.zeros(shape), maks=None, snapshot=snap)
        else:
            for prop in _properties(obj):
                attempt(name, _without_documented_inf, obj, prop)
    for method in _argument_free_methods(obj):  # schedule(), system_matrices(), powers_of_gain(), ...
        attempt(name, getattr(obj, method))


def exercise_ilf_observer(data, obj):
    name = "ILFObserver"
    snap = _x_snapshot(obj)
    batch = data.draw(st.sampled_from([(), (2,)]))
    if attempt(name, obj.reset, data.draw(measurement(batch + (obj.n,)))) is REJECTED:
        obj.reset(np.zeros(batch + (obj.n,)))
    k, s = obj.C.shape[0], obj.B.shape[1]
    for _ in range(data.draw(st.integers(1, 4))):
        u = data.draw(st.one_of(st.none(), measurement(batch + (max(s, 1),))))
        attempt(name, obj.update, data.draw(measurement(batch + (k,), scale=0.5)), u, snapshot=snap)
    attempt(name, obj.error_coordinates, data.draw(measurement(batch + (obj.n,))))
    attempt(name, getattr, obj, "estimate")


def exercise_dhosm(data, family: Family, obj, shape):
    """The sweep of every observer (:func:`exercise_observer`), then what only this class has: the model terms'
    input ``u`` in ``update`` and ``run``, the gain ``l(z)`` and the stability margin."""
    exercise_observer(data, family, obj, shape)
    name = family.name
    snap = _observer_snapshot(obj)
    for _ in range(data.draw(st.integers(1, 5))):
        op = data.draw(st.sampled_from(["update", "update", "run", "gain", "margin"]))
        if op == "update":
            u = data.draw(st.one_of(st.none(), st.just(0.5), st.just(np.nan), st.just(np.ones(shape, complex))))
            attempt(name, obj.update, data.draw(measurement(shape, scale=0.5)), u, snapshot=snap)
        elif op == "run":
            Y = data.draw(block(shape))
            U = data.draw(st.sampled_from([None, "same", np.zeros((1,) + shape), [[0.0], [0.0, 1.0]], np.nan]))
            if isinstance(U, str):  # inputs for as many samples as Y has (Y may be ragged: len, not shape)
                U = np.full((len(Y) if isinstance(Y, (list, tuple)) else np.shape(Y)[0] if np.ndim(Y) else 1,), 0.5)
            attempt(name, obj.run, Y, U, snapshot=snap)
        elif op == "gain":
            attempt(name, obj.gain, data.draw(measurement(shape)))
        else:
            attempt(name, obj.stability_margin, data.draw(good_or_bad(positive(1.0, 50.0))))
    attempt(name, getattr, obj, "estimate")


def exercise_transform(data, obj):
    name = "CoordinateTransform"
    shape = data.draw(st.sampled_from([(obj.n,), (2, obj.n)]))
    for method in (obj.alpha, obj.upsilon, obj.position, obj.position_inverse):
        attempt(name, method, data.draw(measurement(shape)))
    attempt(name, obj.forward, data.draw(measurement(shape)), data.draw(measurement(shape)))
    attempt(name, obj.inverse, data.draw(measurement(shape)), data.draw(measurement(shape)))


def exercise_sensor(data, name, obj, shape):
    snap = _sensor_snapshot(obj)
    n = int(np.prod(shape))
    kwargs = {}
    if data.draw(st.booleans()):
        kwargs["seed"] = data.draw(st.sampled_from([0, 1, None, -1, "a", 1.5, np.random.SeedSequence(2)]))
    if data.draw(st.integers(0, 3)) == 0:
        kwargs["rng"] = data.draw(st.sampled_from([np.random.default_rng(0), 5, "rng", None]))
    if data.draw(st.booleans()):
        kwargs["dt"] = data.draw(good_or_bad(positive(1e-4, 0.1)))
    if data.draw(st.integers(0, 3)) == 0:
        kwargs["angular"] = data.draw(
            st.sampled_from([None, np.ones(n, bool), [True] * shape[-1], "yes", np.ones(n, int), np.ones(n + 1, bool)])
        )
    if data.draw(st.integers(0, 9)) == 0:
        kwargs["sead"] = 0
    attempt(name, obj.reset, data.draw(measurement(shape)), snapshot=snap, **kwargs)
    if attempt(name, obj.reset, np.zeros(shape), seed=0, snapshot=snap) is REJECTED:
        return
    for _ in range(data.draw(st.integers(2, 8))):
        op = data.draw(st.sampled_from(["measure", "measure", "call", "run", "std"]))
        if op == "measure":
            attempt(name, obj.measure, data.draw(measurement(shape)), snapshot=snap)
        elif op == "call":
            attempt(name, obj, data.draw(measurement(shape)), snapshot=snap)
        elif op == "run":
            attempt(name, obj.run, data.draw(block(shape)), snapshot=snap)
        else:
            attempt(
                name,
                obj.error_std,
                data.draw(st.sampled_from([shape[-1], 0, 2.5, "3", -1])),
                data.draw(st.sampled_from([None, [True] * shape[-1], "yes"])),
            )


def sweep(family: Family):
    """The hypothesis test of one family (built per family so each reports its own counterexample)."""

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    )
    @given(st.data())
    def run(data):
        n = data.draw(st.integers(1, 3))
        shape = data.draw(st.sampled_from([(n,), (2, n)]))
        kwargs, misspelled = data.draw(constructor_arguments(family, n))
        if family.kind == "model":
            kwargs.update(family.fixed(n))
        if family.kind == "factory":  # the registered observer's own parameters
            name = kwargs.get("name", kwargs.get("method"))
            kwargs = {**name_kwargs(name), **kwargs}
        if family.cls is Chain:
            stages = data.draw(
                st.lists(
                    st.sampled_from(
                        [GaussianNoise(1e-3), Delay(2), Dropout(0.3), Bias(0.1), Quantization(1e-3), 3.0, "noise"]
                    ),
                    max_size=4,
                )
            )
            obj = attempt(family.name, Chain, *stages)
        else:
            obj = attempt(family.name, family.cls, **kwargs)
        if misspelled is not None:
            assert obj is REJECTED, f"{family.name} accepted the unknown parameter {misspelled!r}"
        if obj is REJECTED:
            return
        assert family.kind != "abstract", f"{family.name} was built: an abstract base must be refused"
        if family.kind == "factory":
            return  # the result was checked (finite); make_observer's observers are swept by their classes
        if family.kind in ("observer", "model"):
            if family.kind == "model":
                shape = shape[:-1] + (obj.n,)
            exercise_observer(data, family, obj, shape)
        elif family.kind == "ilf-observer":
            exercise_ilf_observer(data, obj)
        elif family.kind == "dhosm":
            exercise_dhosm(data, family, obj, shape)
        elif family.kind == "transform":
            exercise_transform(data, obj)
        else:
            exercise_sensor(data, family.name, obj, shape)

    return run


ALL_FAMILIES = OBSERVER_FAMILIES + SENSOR_FAMILIES


def run_sweep(family: Family) -> int:
    """Run the sweep of ``family``, record what it did in :data:`SWEPT`, return its number of calls."""
    before = (COUNTS[family.name], COUNTS["rejected"], COUNTS["accepted"])
    start = time.process_time()
    sweep(family)()
    after = (COUNTS[family.name], COUNTS["rejected"], COUNTS["accepted"])
    SWEPT[family.name] = (*(a - b for a, b in zip(after, before, strict=False)), time.process_time() - start)
    return SWEPT[family.name][0]


#: a good value of every swept parameter, for ``n = 2`` channels
GOOD = {
    "PerChannel": dict(parts=[(KalmanCA(1e-3, 10.0, 1e-6), [1]), (FiniteDifference(1e-3), [0])], mean_over=1e-3),
    "PerChannelInput": dict(
        parts=[(KalmanIMMInput(1e-3, 10.0, 1e-6, np.ones((1, 1)), 1.0), [1]), (FiniteDifference(1e-3), [0])],
        mean_over=1e-3,
    ),
    "SuperTwisting": dict(dt=1e-3, lipschitz=5.0, k1=3.0, k2=6.0, discretization="euler"),
    "Levant": dict(order=2, dt=1e-3, lipschitz=5.0, discretization="matching", p1=3.0, mu=0.5),
    "FilteringDifferentiator": dict(order=2, filtering_order=1, dt=1e-3, lipschitz=5.0, degree=-0.5, p1=3.0),
    "URED": dict(dt=1e-3, lipschitz=5.0, k1=3.0, k2=6.0, beta=1.0, discretization="euler"),
    "UniformLevant": dict(order=2, dt=1e-3, lipschitz=5.0, alpha=1.0, discretization="taylor"),
    "HighGain": dict(dt=1e-3, gain=20.0, order=2, discretization="euler"),
    "FiniteDifference": dict(dt=1e-3, order=2, discretization="backward"),
    "KalmanCA": dict(
        dt=1e-3, process_noise=10.0, measurement_noise=1e-6, initial_std=(1.0, 2.0), discretization="exact"
    ),
    "SwitchedGain": dict(
        dt=1e-3,
        order=1,
        gain=SG_GAIN,
        P=SG_P,
        q=2.0,
        mu0=2.0,
        T_min=0.01,
        supervise=True,
        restart_threshold=1.0,
        mu_max=100.0,
        mu_min=5.0,
    ),
    "LowPowerHighGain": dict(
        dt=1e-3, gain=20.0, order=2, bounds=2.0, filter_coefficient=1.0, readout="low-power", discretization="implicit"
    ),
    "ILFDifferentiator": dict(
        dt=1e-3, lipschitz=5.0, order=1, rate=10.0, gain=ILF_GAIN, rho_min=1e-14, discretization="implicit"
    ),
    "ILFFixedDifferentiator": dict(
        dt=1e-3, lipschitz=5.0, order=1, mu=0.5, alpha=2.0, gain=ILF_GAIN, discretization="implicit"
    ),
    "WorstCaseOptimal": dict(dt=1e-3, lipschitz=5.0, noise=1e-3, window=8, discretization="exact"),
    "KalmanIMM": dict(
        dt=1e-3,
        process_noise=10.0,
        measurement_noise=1e-6,
        smooth_ratio=0.01,
        stay=0.99,
        initial_std=(10.0, 100.0),
        discretization="exact",
    ),
    "KalmanCAInput": dict(
        dt=1e-3,
        process_noise=10.0,
        measurement_noise=1e-6,
        input_gain=np.ones((2, 1)),
        jump_noise=1.0,
        discretization="exact",
    ),
    "KalmanIMMInput": dict(
        dt=1e-3,
        process_noise=10.0,
        measurement_noise=1e-6,
        input_gain=np.ones((2, 1)),
        jump_noise=1.0,
        smooth_ratio=0.01,
        discretization="exact",
    ),
    "AlphaBeta": dict(dt=1e-3, acceleration_std=50.0, noise_std=1e-4, alpha=None, beta=None, discretization="exact"),
    "MechanicalSuperTwisting": dict(
        dt=1e-3,
        lipschitz=5.0,
        accel_bound=10.0,
        discretization="euler",
        euler_substeps=2,
        model_substeps=2,
        disturbance_time_constant=0.02,
    ),
    "DissipativeSuperTwisting": dict(dt=1e-3, accel_bound=10.0, gains=dict(k1=2.0, k2=1.0, k3=0.0, mu1=3.0, mu2=1.0)),
    "ILFObserver": dict(
        A=np.eye(2, k=1),
        C=[[1.0, 0.0]],
        L=[[-3.0], [2.0]],
        mu=0.5,
        kind="fixed",
        dt=1e-3,
        B=[[0.0], [1.0]],
        rho_min=1e-14,
        iterations=60,
    ),
    "DiscreteTimeHOSM": dict(n=3, dt=1e-3, p1=5.0, mu=0.5, mapping="matching", gamma=None, L_gamma=None),
    "CoordinateTransform": dict(
        alpha=lambda Y: 0.1 * np.tanh(Y), lower=-np.ones(2), upper=np.ones(2), reference=np.zeros(2), grid=101
    ),
    "make_observer": dict(name="levant", dt=1e-3),
    "differentiate": dict(y=np.zeros((5, 2)), dt=1e-3, method="levant"),
    "HighGain.from_bounds": dict(dt=1e-3, lipschitz=5.0, noise=1e-3, order=2),
    "KalmanCA.from_levels": dict(dt=1e-3, jerk_rms=5.0, measurement_variance=1e-6),
    "GaussianNoise": dict(std=1e-3),
    "UniformNoise": dict(bound=1e-3),
    "Quantization": dict(resolution=1e-3, linear_resolution=1e-4),
    "Bias": dict(value=0.1, std=0.01),
    "Drift": dict(rate_std=1e-3),
    "Delay": dict(samples=2),
    "Dropout": dict(probability=0.1, per_channel=True),
    "Outliers": dict(probability=0.1, scale=0.1),
    "Encoder": dict(resolution=None, noise_std=1e-3, counts_per_revolution=4096, wrap=True),
    "Wrap": dict(),
    "presets": dict(sensor="low-cost"),
    "Quantization.from_counts": dict(counts_per_revolution=4096, linear_travel=0.01),
}


def canonical_arguments(family: Family, n: int) -> dict:
    """:data:`GOOD` for ``family``, with what the family needs besides (the observer's own parameters, dynamics)."""
    kwargs = dict(GOOD[family.name])
    if family.kind == "factory":
        kwargs = {**name_kwargs(kwargs.get("name", kwargs.get("method"))), **kwargs}
    if family.kind == "model":
        kwargs.update(family.fixed(n))
    return kwargs


def smoke(family: Family, obj) -> None:
    """Reset and one sample with good values, through :func:`attempt` (finite results or typed errors)."""
    name = family.name
    if family.kind in ("observer", "model"):
        n = obj.n if family.kind == "model" else 2
        if attempt(name, obj.reset, np.zeros(n)) is not REJECTED:
            attempt(name, obj.update, np.full(n, 0.1))
    elif family.kind == "ilf-observer":
        if attempt(name, obj.reset, np.zeros(obj.n)) is not REJECTED:
            attempt(name, obj.update, np.full(obj.C.shape[0], 0.1))
    elif family.kind == "dhosm":
        if attempt(name, obj.reset, np.zeros(2)) is not REJECTED:
            attempt(name, obj.update, np.full(2, 0.1))
    elif family.kind == "transform":
        attempt(name, obj.position, np.zeros(obj.n))
    elif family.kind == "sensor" and attempt(name, obj.reset, np.zeros(2), seed=0) is not REJECTED:
        attempt(name, obj.measure, np.full(2, 0.1))


#: out-of-range numbers, in addition to :data:`BAD_VALUES`
BAD_NUMBERS = [-1.0, 0.0, -1e300, 1e300, 1e-300, 2**70, 10**400]  # the last: float() raises OverflowError


@pytest.mark.parametrize(
    "family", [f for f in ALL_FAMILIES if f.params(2) and f.kind != "abstract"], ids=lambda f: f.name
)
def test_every_parameter_with_every_bad_value(family):
    """Systematic complement of the sweep: each parameter of each constructor, one at a time, takes each value of
    :data:`BAD_VALUES` and :data:`BAD_NUMBERS`, the others their simplest good value. Each construction is refused
    with a typed, worded error, or gives an object whose reset and first update are finite or refused so."""
    n = 2
    good = canonical_arguments(family, n)
    assert attempt(family.name, family.cls, **good) is not REJECTED, f"{family.name}: {good} refused"
    for name in family.params(n):
        for bad in BAD_VALUES + BAD_NUMBERS:
            obj = attempt(family.name, family.cls, **{**good, name: bad})
            if obj is not REJECTED and family.kind != "factory":
                smoke(family, obj)


def test_sweep_covers_every_public_class():
    """The sweep's families are exactly the public classes (a new class must be added to it)."""
    skipped = {
        "Dynamics": "a typing.Protocol (the interface the sweep's Pendulums implements)",
        "DivergenceError": "an exception type",
        "Family": "the registry's record of an observer family (made by register_observer, not by users)",
    }
    public = {name for name in observers.__all__ if inspect.isclass(getattr(observers, name))} - set(skipped)
    public |= {name for name in sensors.__all__ if inspect.isclass(getattr(sensors, name))}
    assert public == {f.name for f in ALL_FAMILIES if f.name[0].isupper() and "." not in f.name}


@pytest.mark.parametrize("family", ALL_FAMILIES, ids=lambda f: f.name)
def test_sweep(family):
    calls = run_sweep(family)
    minimum = EXAMPLES if family.kind in ("abstract", "factory") else MIN_CALLS_PER_FAMILY  # one call each
    assert calls >= minimum, f"{family.name}: only {calls} calls"


def test_sweep_totals():
    """Totals over every family (running the sweeps that did not run in this session), printed for the record:
    ``pytest -s tests/test_bad_input.py -k totals``."""
    for family in ALL_FAMILIES:
        if family.name not in SWEPT:
            run_sweep(family)
    calls, rejected, accepted, cpu = (sum(v[i] for v in SWEPT.values()) for i in range(4))
    print("\ncalls per family:", {name: v[0] for name, v in SWEPT.items()})
    print(
        f"\nbad-input sweep: {len(ALL_FAMILIES)} families x {EXAMPLES} examples, {calls} calls "
        f"({rejected} rejected, {accepted} accepted), {cpu:.1f} s of CPU"
    )
    assert calls == rejected + accepted
    assert calls >= MIN_CALLS_PER_FAMILY * (len(ALL_FAMILIES) - 3)
    assert rejected > 0.2 * calls and accepted > 0.2 * calls  # both sides were exercised
