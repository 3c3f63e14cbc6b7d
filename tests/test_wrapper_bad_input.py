"""A property-based sweep of the wrappers' constructors and methods: typed errors or valid results, nothing else.

Every input is either accepted, and then every observation is finite and in the observation space, or refused
with a ``TypeError``/``ValueError``/``RuntimeError`` whose message says what was expected. No raw third-party
error, no NaN, no crash. The environment is InvertedPendulum-v5 (the cheapest MuJoCo environment); calibrations
are cached in memory across examples, so one example costs a construction and a few steps.
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from smo_gym import sensors
from smo_gym.observers import OBSERVERS, SuperTwisting
from smo_gym.wrappers import EstimatedVelocity

ENV = "InvertedPendulum-v5"
TYPED = (TypeError, ValueError, RuntimeError)
#: the number of examples each sweep ran, checked at the end
TRIED = {"construct": 0, "constructed": 0, "methods": 0}

junk = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-5, 5),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.lists(st.floats(-1, 1), max_size=3),
    st.just(1 + 2j),
    st.just(np.datetime64("2026-01-01")),
    st.just(object()),
)

#: per constructor argument: (valid values, invalid values)
ARGUMENTS = {
    "sensor": (
        st.one_of(
            st.sampled_from(sorted(sensors.PRESETS)),
            st.builds(sensors.Encoder, counts_per_revolution=st.sampled_from([256, 4096])),
        ),
        st.one_of(st.sampled_from(["encoder-12bt", "", "ENCODER"]), junk),
    ),
    "observer": (
        st.one_of(st.sampled_from(sorted(OBSERVERS)), st.just(SuperTwisting(dt=0.02, lipschitz=50.0))),
        st.one_of(
            st.sampled_from(["super-twist", "levant2", ""]), st.just(SuperTwisting(dt=0.01, lipschitz=50.0)), junk
        ),
    ),
    "rate": (
        st.sampled_from(["physics", "env", 1, 2]),
        st.one_of(st.sampled_from([3, 0, -1, 1.5, True, "fast"]), junk),
    ),
    "observer_kwargs": (
        st.none(),
        st.one_of(
            st.dictionaries(
                st.sampled_from(["lipschitz", "lipschtz", "order", "discretization", "k1", "gain"]),
                st.one_of(
                    st.floats(-10, 100),
                    st.just(float("nan")),
                    st.integers(-1, 4),
                    st.sampled_from(["implicit", "euler", "matching", "x"]),
                    st.booleans(),
                ),
                min_size=1,
                max_size=2,
            ),
            junk,
        ),
    ),
    "positions": (st.sampled_from(["measured", "filtered"]), st.one_of(st.just("estimated"), junk)),
    "contact_forces": (st.just("sensor"), st.one_of(st.sampled_from(["estimated", "zero", "none"]), junk)),
    "calibration_safety": (st.floats(0.5, 5), st.one_of(st.floats(-1, 0), junk)),
    "calibration_quantile": (st.floats(0.5, 1.0), st.one_of(st.floats(-0.5, 0), st.floats(1.01, 2), junk)),
    "calibration_steps": (st.integers(100, 300), st.one_of(st.integers(-2, 0), junk)),
}


@st.composite
def constructor_arguments(draw):
    """Mostly valid arguments, with up to two drawn from the invalid values (the interesting mixes)."""
    broken = draw(st.sets(st.sampled_from(sorted(ARGUMENTS)), max_size=2))
    return {name: draw(bad if name in broken else good) for name, (good, bad) in ARGUMENTS.items()}


def _check_typed(exc: BaseException) -> None:
    assert isinstance(exc, TYPED), f"raw {type(exc).__name__}: {exc}"
    assert "expected" in str(exc), f"{type(exc).__name__} without 'expected ...': {exc}"


def _construct(**kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return EstimatedVelocity(gym.make(ENV), **{"disk_cache": False, "calibration_steps": 200, **kwargs})


@settings(max_examples=120, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(kwargs=constructor_arguments())
def test_constructor_sweep(kwargs):
    TRIED["construct"] += 1
    try:
        env = _construct(**kwargs)
    except Exception as exc:
        _check_typed(exc)
        return
    TRIED["constructed"] += 1
    obs, _ = env.reset(seed=0)
    assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
    for _ in range(3):
        try:
            obs = env.step(env.action_space.sample())[0]
        except Exception as exc:
            _check_typed(exc)
            return
        assert np.all(np.isfinite(obs))


action_values = st.one_of(
    st.builds(lambda x: np.array([x]), st.floats(allow_nan=True, allow_infinity=True)),
    st.builds(lambda x: np.array([x], dtype=np.float32), st.floats(-3, 3, width=32)),
    st.lists(st.floats(-3, 3), min_size=0, max_size=3),
    st.builds(np.zeros, st.sampled_from([(2,), (1, 1), ()])),
    junk,
)


@pytest.fixture(scope="module")
def sensed():
    return _construct()


@pytest.fixture(scope="module")
def twin():
    """A second wrapper that sees only the calls the first accepts."""
    return _construct()


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(
    seed=st.one_of(st.none(), st.integers(0, 2**64), st.integers(-5, -1), junk),
    actions=st.lists(action_values, min_size=1, max_size=4),
)
def test_method_sweep(sensed, twin, seed, actions):
    """reset(seed=...) with any value, then steps with any action: typed errors, or finite observations in the
    space; a refused action changes nothing: every later observation is the one of a twin that never saw it."""
    TRIED["methods"] += 1
    try:
        obs, info = sensed.reset(seed=seed)
    except Exception as exc:
        _check_typed(exc)
    assert sensed.observation_space.contains(sensed.reset(seed=0)[0])
    twin.reset(seed=0)
    for action in actions:
        try:
            obs, _, terminated, truncated, info = sensed.step(action)
        except Exception as exc:
            _check_typed(exc)
            continue
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(info["smo"]["qvel_estimate"]))
        np.testing.assert_array_equal(obs, twin.step(action)[0])
        if terminated or truncated:
            np.testing.assert_array_equal(sensed.reset()[0], twin.reset()[0])
    np.testing.assert_array_equal(sensed.step(np.zeros(1))[0], twin.step(np.zeros(1))[0])


def test_numpy_integer_seeds_are_the_same_seeds(sensed):
    """Gymnasium refuses NumPy integers as seeds; the wrapper takes them as the Python int they are."""
    first = sensed.reset(seed=5)[0]
    for seed in (np.int64(5), np.uint64(5), np.int32(5)):
        np.testing.assert_array_equal(sensed.reset(seed=seed)[0], first)


def test_the_sweeps_ran():
    """Runs after the sweeps (file order): the number of inputs they tried."""
    if not TRIED["construct"] or not TRIED["methods"]:
        pytest.skip("counts the examples of this file's sweeps: run it with them (the whole file)")
    print(
        f"wrapper sweep: {TRIED['construct']} constructions ({TRIED['constructed']} accepted), "
        f"{TRIED['methods']} method sequences"
    )
    assert TRIED["construct"] >= 100 and TRIED["constructed"] >= 10 and TRIED["methods"] >= 100
