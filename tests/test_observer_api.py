"""The observer contract: batching, masked resets, offline/online equivalence, pickling, bad input.

Every property is checked for every registered model-free family (:data:`smo_gym.observers.FAMILIES`) on each of
the parameter sets it registers (together they cover its discretizations), with per-channel Lipschitz arrays
where the family takes one. A newly registered family is tested here without an edit.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

import smo_gym
from smo_gym import DivergenceError
from smo_gym.observers import (
    FAMILIES,
    MODEL_BASED_OBSERVERS,
    OBSERVERS,
    URED,
    FiniteDifference,
    HighGain,
    KalmanCA,
    Levant,
    LowPowerHighGain,
    SuperTwisting,
    UniformLevant,
    make_observer,
)
from smo_gym.observers.base import ObserverCheckpoint

DT = 1e-3
BATCH = (4, 7)
N_STEPS = 300


def lipschitz_array(shape=BATCH) -> np.ndarray:
    """Distinct positive bounds per channel (so a mixed-up channel would show)."""
    return 2.0 + np.arange(np.prod(shape), dtype=float).reshape(shape) * 0.37


def _example_id(family, kwargs: dict) -> str:
    d = kwargs.get("discretization", family.cls.discretizations[0])
    return f"k{kwargs['order']}-{d}" if "order" in kwargs else d


#: family name -> list of (id, constructor arguments), the examples each family registers
CONFIGS: dict[str, list[tuple[str, dict]]] = {
    name: [(f"{i}-{_example_id(family, kw)}", kw) for i, kw in enumerate(family.examples)]
    for name, family in FAMILIES.items()
    if not family.model_based
}
TAKES_LIPSCHITZ = {name for name, cfgs in CONFIGS.items() if any("lipschitz" in kw for _, kw in cfgs)}
CASES = [pytest.param(name, kw, id=f"{name}-{cid}") for name, cfgs in CONFIGS.items() for cid, kw in cfgs]


def build(name: str, kwargs: dict, lipschitz=None):
    """Observer ``name`` with ``kwargs``, plus ``lipschitz`` if it takes one (default: the per-channel array)."""
    params = dict(kwargs)
    if name in TAKES_LIPSCHITZ:
        params["lipschitz"] = lipschitz_array() if lipschitz is None else lipschitz
    return make_observer(name, dt=DT, **params)


def measurements(rng, T=N_STEPS, shape=BATCH) -> np.ndarray:
    """``(T, *shape)`` smooth signals with random amplitude, frequency and phase per channel, plus small noise."""
    t = np.arange(T)[:, None, None] * DT
    a, w, p = (rng.uniform(0.5, 2.0, shape), rng.uniform(1.0, 8.0, shape), rng.uniform(0, 2 * np.pi, shape))
    return a * np.sin(w * t + p) + 1e-4 * rng.standard_normal((T,) + shape)


def update_loop(obs, Y) -> np.ndarray:
    """Online: ``reset(Y[0])`` then ``update`` sample by sample; estimates ``(T, ..., order + 1)``."""
    out = [obs.reset(Y[0])]
    out += [obs.update(y) for y in Y[1:]]
    return np.stack(out)


def test_every_registered_family_is_tested_and_gets_the_compiled_path():
    """Every family's examples cover its discretizations; a family of compiled steps runs one of them (so it has
    the offline drivers, the shared-parameter variant and the fused driver); model-based ones are not built by
    name."""
    from smo_gym.engine.fused import FUSED_DRIVERS, fusable
    from smo_gym.observers import _kernels

    assert set(CONFIGS) == set(OBSERVERS) and not set(CONFIGS) & set(MODEL_BASED_OBSERVERS)
    for name, family in FAMILIES.items():
        assert family.cls.name == name
        if family.model_based:
            assert name in MODEL_BASED_OBSERVERS and not family.compiled
            continue
        used = {kw.get("discretization", family.cls.discretizations[0]) for kw in family.examples}
        assert used == set(family.cls.discretizations), name
        for kw in family.examples:
            obs = make_observer(name, dt=DT, **kw)
            if family.compiled:
                step = _kernels.STEPS[obs._kernel]
                assert step in family.steps and obs._kernel in FUSED_DRIVERS and fusable(obs), name
            else:
                assert obs._kernel not in _kernels.STEPS and not fusable(obs), name


# ----------------------------------------------------------------------------------------------------------------
# batching, masked reset, offline = online, pickling
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name, kwargs", CASES)
def test_batch_equals_per_channel_loop(name, kwargs, rng):
    """A ``(4, 7)`` batch (per-channel ``L``) gives the same estimates as 28 scalar observers, to 1e-12."""
    Y = measurements(rng)
    L = lipschitz_array()
    batch = update_loop(build(name, kwargs), Y)
    assert batch.shape == (N_STEPS,) + BATCH + (build(name, kwargs).order + 1,)
    for i in range(BATCH[0]):
        for j in range(BATCH[1]):
            single = build(name, kwargs, lipschitz=L[i, j])
            first = single.reset(Y[0, i, j][None])
            ref = np.concatenate([first[None], single.run(Y[1:, i, j][:, None])])[:, 0]
            np.testing.assert_allclose(batch[:, i, j], ref, rtol=1e-12, atol=1e-12, err_msg=f"channel {(i, j)}")


@pytest.mark.parametrize("name, kwargs", CASES)
def test_restart_equals_a_fresh_reset_in_place(name, kwargs, rng):
    """``restart(y)`` after a run continues exactly as a fresh observer started with ``reset(y)``, and keeps the
    state array (a compiled caller holding it stays valid)."""
    Y = measurements(rng)
    obs = build(name, kwargs)
    update_loop(obs, Y[:50])
    state_array = obs._state
    first = obs.restart(Y[50])
    assert obs.n_updates == 0 and obs._state is state_array
    fresh = build(name, kwargs)
    np.testing.assert_array_equal(first, fresh.reset(Y[50]))
    np.testing.assert_array_equal(obs.run(Y[51:]), fresh.run(Y[51:]))
    with pytest.raises(ValueError, match="expected y0 with shape"):
        obs.restart(Y[0, :2])
    bad = Y[0].copy()
    bad[1, 3] = np.nan
    with pytest.raises(ValueError, match="channel 3"):
        obs.restart(bad)


@pytest.mark.parametrize("name, kwargs", CASES)
def test_the_declared_state_width_is_the_states(name, kwargs, rng):
    """``_state_width()`` is the width of the state a reset makes: a composite (:class:`PerChannel`) sizes its rows
    and groups its parts by it, before any part is reset."""
    obs = build(name, kwargs)
    obs.reset(measurements(rng, T=1)[0])
    assert obs._state.shape[1] == obs._state_width()


@pytest.mark.parametrize("name, kwargs", CASES)
def test_restore_returns_to_the_checkpoint(name, kwargs, rng):
    """After ``restore(checkpoint())`` the observer continues exactly as a twin that never took the samples in
    between (a caller undoing a step it cannot complete), with its state array kept; a checkpoint of another shape
    is refused."""
    Y = measurements(rng)
    obs, twin = build(name, kwargs), build(name, kwargs)
    update_loop(obs, Y[:50])
    update_loop(twin, Y[:50])
    saved = obs.checkpoint()
    obs.run(Y[50:60] + 1.0)
    state_array = obs._state
    obs.restore(saved)
    assert obs._state is state_array and obs.n_updates == twin.n_updates
    np.testing.assert_array_equal(obs.estimate, twin.estimate)
    np.testing.assert_array_equal(obs.run(Y[50:]), twin.run(Y[50:]))
    with pytest.raises(ValueError, match="checkpoint of this observer"):
        obs.restore(ObserverCheckpoint(saved.state[:1], saved.estimate[:1], 0))


@pytest.mark.parametrize("mask_shape", [(4,), (4, 7)])
@pytest.mark.parametrize("name, kwargs", CASES)
def test_masked_reset_restarts_only_masked_rows(name, kwargs, mask_shape, rng):
    """After ``reset(y, mask)`` masked rows behave as a fresh observer started at ``y``, the others as if nothing
    happened (bit for bit: channels are independent); the estimate ``update`` returned before stays as it was (a
    new array, the caller's to keep: the masked reset had rewritten its rows)."""
    Y = measurements(rng)
    n1 = N_STEPS // 2
    mask = rng.random(mask_shape) < 0.5
    mask.flat[0], mask.flat[1] = True, False  # both kinds present
    full_mask = np.broadcast_to(mask[..., None], BATCH) if mask.shape == (4,) else mask

    obs, untouched, fresh = build(name, kwargs), build(name, kwargs), build(name, kwargs)
    obs.reset(Y[0])
    untouched.reset(Y[0])
    obs.run(Y[1 : n1 - 1])
    kept = obs.update(Y[n1 - 1])
    untouched.run(Y[1:n1])
    before = kept.copy()
    returned = obs.reset(Y[n1], mask=mask)
    np.testing.assert_array_equal(kept, before)
    fresh_first = fresh.reset(Y[n1])
    np.testing.assert_array_equal(returned[full_mask], fresh_first[full_mask])
    np.testing.assert_array_equal(returned[~full_mask], before[~full_mask])

    got, ref_untouched, ref_fresh = obs.run(Y[n1 + 1 :]), untouched.run(Y[n1 + 1 :]), fresh.run(Y[n1 + 1 :])
    np.testing.assert_array_equal(got[:, full_mask], ref_fresh[:, full_mask])
    np.testing.assert_array_equal(got[:, ~full_mask], ref_untouched[:, ~full_mask])


@pytest.mark.parametrize("name, kwargs", CASES)
def test_differentiate_equals_online_updates(name, kwargs, rng):
    """``smo_gym.differentiate`` started at the measurement returns exactly what ``reset`` + ``update`` return
    online, for ``(T, 4, 7)`` and ``(T,)`` input."""
    Y = measurements(rng)
    params = dict(kwargs, start="measurement")
    if name in TAKES_LIPSCHITZ:
        params["lipschitz"] = lipschitz_array()
    offline = smo_gym.differentiate(Y, DT, method=name, **params)
    np.testing.assert_array_equal(offline, update_loop(build(name, kwargs), Y))

    if name in TAKES_LIPSCHITZ:
        params["lipschitz"] = 3.0
    single = smo_gym.differentiate(Y[:, 1, 2], DT, method=name, **params)
    online = update_loop(build(name, kwargs, lipschitz=3.0), Y[:, 1, 2:3])[:, 0]
    assert single.shape == (N_STEPS, online.shape[-1])
    np.testing.assert_array_equal(single, online)


@pytest.mark.parametrize("name, kwargs", CASES)
def test_run_equals_repeated_update(name, kwargs, rng):
    """``run`` over blocks, interleaved with ``update``, equals ``update`` alone; bookkeeping follows."""
    Y = measurements(rng)
    ref = update_loop(build(name, kwargs), Y)
    obs = build(name, kwargs)
    obs.reset(Y[0])
    parts = [obs.run(Y[1:100]), obs.update(Y[100])[None], obs.run(Y[101:101]), obs.run(Y[101:])]
    got = np.concatenate(parts)
    np.testing.assert_array_equal(got, ref[1:])
    assert obs.n_updates == N_STEPS - 1
    np.testing.assert_array_equal(obs.estimate, ref[-1])
    np.testing.assert_array_equal(obs.velocity, ref[-1, ..., 1])
    assert obs.output_error.shape == BATCH


@pytest.mark.parametrize("name, kwargs", CASES)
def test_run_into_out_and_never_over_its_own_samples(name, kwargs, rng):
    """``run(Y, out=buffer)`` writes what ``run(Y)`` returns; an ``out`` that shares memory with ``Y`` is refused
    before anything runs (the estimates would overwrite samples not yet read: wrong numbers, silently)."""
    Y = measurements(rng, T=40)
    obs = build(name, kwargs)
    obs.reset(Y[0])
    twin = copy.deepcopy(obs)
    expected = twin.run(Y[1:])
    buffer = np.full(expected.shape, np.nan)
    assert obs.run(Y[1:], out=buffer) is buffer
    np.testing.assert_array_equal(buffer, expected)
    state = obs.state.copy()
    shared = np.empty(expected.size)
    samples = shared[: Y[1:].size].reshape(Y[1:].shape)
    samples[...] = Y[1:]
    with pytest.raises(ValueError, match="share memory"):
        obs.run(samples, out=shared.reshape(expected.shape))
    np.testing.assert_array_equal(obs.state, state)


@pytest.mark.parametrize("name, kwargs", CASES)
def test_update_accepts_any_array_like(name, kwargs, rng):
    """Lists, float32, Fortran-ordered and strided views give the same estimates as C-contiguous float64 (the
    fast path of ``update`` must not skip a conversion); returned arrays are fresh, not views of the state."""
    Y = measurements(rng, T=12)
    ref = update_loop(build(name, kwargs), Y)
    big = np.zeros((12, 8, 14))
    big[:, ::2, ::2] = Y
    variants = [
        lambda y, k: y.tolist(),
        lambda y, k: np.asfortranarray(y),
        lambda y, k: big[k, ::2, ::2],  # strided view
        lambda y, k: y.astype(np.float32).astype(np.float64),  # exact float32 values, checked below
    ]
    for variant in variants[:3]:
        obs = build(name, kwargs)
        got = [obs.reset(variant(Y[0], 0))] + [obs.update(variant(Y[k], k)) for k in range(1, 12)]
        np.testing.assert_array_equal(np.stack(got), ref)
    y32 = Y.astype(np.float32)
    obs32, obs64 = build(name, kwargs), build(name, kwargs)
    got32 = [obs32.reset(y32[0])] + [obs32.update(y32[k]) for k in range(1, 12)]
    got64 = update_loop(obs64, variants[3](Y, None))
    np.testing.assert_array_equal(np.stack(got32), got64)
    kept = got32[-1].copy()
    obs32.update(y32[11])
    np.testing.assert_array_equal(got32[-1], kept)


@pytest.mark.parametrize("name, kwargs", CASES)
def test_pure_step_matches_update(name, kwargs, rng):
    """``step(state, y)`` is the pure form of ``update``: same new state and estimate, ``self`` untouched."""
    Y = measurements(rng, T=20)
    obs = build(name, kwargs)
    obs.reset(Y[0])
    obs.run(Y[1:10])
    state = obs.state
    new_state, est = obs.step(state, Y[10])
    np.testing.assert_array_equal(obs.state, state)
    np.testing.assert_array_equal(est.reshape(obs.estimate.shape), obs.update(Y[10]))
    np.testing.assert_array_equal(new_state, obs.state)


@pytest.mark.parametrize("name, kwargs", CASES)
def test_pickle_round_trip_mid_run(name, kwargs, rng):
    """A pickled (or deep-copied) observer continues exactly like the original."""
    Y = measurements(rng)
    obs = build(name, kwargs)
    obs.reset(Y[0])
    obs.run(Y[1:150])
    clones = [pickle.loads(pickle.dumps(obs)), copy.deepcopy(obs)]
    ref = obs.run(Y[150:])
    for clone in clones:
        assert clone.n_updates == 149
        np.testing.assert_array_equal(clone.run(Y[150:]), ref)


# ----------------------------------------------------------------------------------------------------------------
# bad input
# ----------------------------------------------------------------------------------------------------------------
def assert_worded(excinfo):
    """Typed errors say what was expected and what was received."""
    msg = str(excinfo.value)
    assert "expected" in msg and "actual value" in msg, msg


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("name, kwargs", CASES)
def test_nonfinite_measurement_names_channel_and_keeps_state(name, kwargs, bad, rng):
    """NaN/inf in ``y`` raises ``ValueError`` naming the channel (and batch element); nothing changes."""
    Y = measurements(rng, T=20)
    obs = build(name, kwargs)
    obs.reset(Y[0])
    obs.run(Y[1:10])
    state, estimate, n = obs.state, obs.estimate.copy(), obs.n_updates
    y = Y[10].copy()
    y[2, 5] = bad
    with pytest.raises(ValueError, match=r"channel 5 of batch element \(2,\)") as excinfo:
        obs.update(y)
    assert_worded(excinfo)
    np.testing.assert_array_equal(obs.state, state)
    np.testing.assert_array_equal(obs.estimate, estimate)
    assert obs.n_updates == n
    # the observer is still usable and continues as if the bad sample never came
    ref = build(name, kwargs)
    ref.reset(Y[0])
    ref.run(Y[1:10])
    np.testing.assert_array_equal(obs.update(Y[10]), ref.update(Y[10]))


@pytest.mark.parametrize("name, kwargs", CASES)
def test_nonfinite_in_run_or_reset_raises(name, kwargs, rng):
    """``run`` and ``reset`` reject non-finite samples too, naming the channel (and ``run`` the sample); a failed
    ``run`` changes nothing."""
    Y = measurements(rng, T=20)
    obs = build(name, kwargs)
    with pytest.raises(ValueError, match="channel 3") as excinfo:
        y0 = Y[0].copy()
        y0[1, 3] = np.nan
        obs.reset(y0)
    assert_worded(excinfo)
    obs.reset(Y[0])
    obs.run(Y[1:5])
    state, estimate, n = obs.state, obs.estimate.copy(), obs.n_updates
    block = Y[5:15].copy()
    block[6, 0, 4] = np.inf
    with pytest.raises(ValueError, match=r"in Y at sample 6, actual value: \S*inf\S* at channel 4") as excinfo:
        obs.run(block)
    assert_worded(excinfo)
    np.testing.assert_array_equal(obs.state, state)
    np.testing.assert_array_equal(obs.estimate, estimate)
    assert obs.n_updates == n


#: every model-free class with its first registered example (without ``discretization``)
ALL_CLASSES = [
    (family.cls, {k: v for k, v in family.examples[0].items() if k != "discretization"})
    for family in FAMILIES.values()
    if not family.model_based
]


@pytest.mark.parametrize("dt", [0.0, -1e-3, np.nan, np.inf])
@pytest.mark.parametrize("cls, kwargs", ALL_CLASSES, ids=lambda c: getattr(c, "__name__", ""))
def test_non_positive_dt(cls, kwargs, dt):
    with pytest.raises(ValueError) as excinfo:
        cls(dt=dt, **kwargs)
    assert_worded(excinfo)


@pytest.mark.parametrize("cls, kwargs", ALL_CLASSES, ids=lambda c: getattr(c, "__name__", ""))
def test_dt_of_wrong_type(cls, kwargs):
    with pytest.raises(TypeError) as excinfo:
        cls(dt="0.001", **kwargs)
    assert_worded(excinfo)


@pytest.mark.parametrize("lipschitz", [0.0, -1.0, np.nan, [1.0, -2.0, 3.0], np.full((4, 7), -1.0)])
@pytest.mark.parametrize("cls", [SuperTwisting, Levant, URED, UniformLevant])
def test_non_positive_lipschitz_at_construction(cls, lipschitz):
    """Bad ``L`` (scalar or any entry of an array) is rejected when the observer is built, not at reset."""
    with pytest.raises(ValueError) as excinfo:
        cls(dt=1e-3, lipschitz=lipschitz)
    assert_worded(excinfo)


@pytest.mark.parametrize(
    "factory",
    [
        lambda: Levant(order=0, dt=1e-3),
        lambda: Levant(order=6, dt=1e-3),
        lambda: UniformLevant(order=0, dt=1e-3),
        lambda: UniformLevant(order=6, dt=1e-3),
        lambda: HighGain(dt=1e-3, gain=1.0, order=10),
        lambda: FiniteDifference(dt=1e-3, order=3),
        lambda: smo_gym.design.levant_lambdas(6),
    ],
)
def test_order_out_of_range(factory):
    with pytest.raises(ValueError) as excinfo:
        factory()
    assert_worded(excinfo)


@pytest.mark.parametrize("order", [2.0, "2", True])
def test_order_of_wrong_type(order):
    with pytest.raises(TypeError) as excinfo:
        Levant(order=order, dt=1e-3)
    assert_worded(excinfo)


@pytest.mark.parametrize("name, kwargs", CASES)
def test_wrong_shapes(name, kwargs, rng):
    """Measurements, blocks and masks of the wrong shape are rejected with the expected shape in the message."""
    Y = measurements(rng, T=5)
    obs = build(name, kwargs)
    with pytest.raises(ValueError) as excinfo:
        obs.reset(1.0)  # a scalar is not (..., n_channels)
    assert_worded(excinfo)
    obs.reset(Y[0])
    for bad in (Y[1, :, :6], Y[1].T, Y[1, 0], Y[:2]):
        with pytest.raises(ValueError) as excinfo:
            obs.update(bad)
        assert_worded(excinfo)
    with pytest.raises(ValueError) as excinfo:
        obs.run(Y[:, :3])
    assert_worded(excinfo)
    for mask in (np.ones(7, bool), np.ones((7, 4), bool), np.ones((4, 7, 1), bool)):
        with pytest.raises(ValueError) as excinfo:
            obs.reset(Y[1], mask=mask)
        assert_worded(excinfo)
    with pytest.raises(ValueError) as excinfo:
        obs.reset(Y[1, :2], mask=np.ones(2, bool))  # masked reset needs the full-reset shape
    assert_worded(excinfo)


@pytest.mark.parametrize("name", sorted(TAKES_LIPSCHITZ))
def test_lipschitz_not_broadcastable(name):
    obs = make_observer(name, dt=1e-3, lipschitz=np.ones(3))
    with pytest.raises(ValueError) as excinfo:
        obs.reset(np.zeros((4, 7)))
    assert_worded(excinfo)


@pytest.mark.parametrize(
    "factory",
    [
        lambda: UniformLevant(order=2, dt=1e-3, k=[1.0, 2.0]),
        lambda: UniformLevant(order=2, dt=1e-3, k=[1.0, -2.0, 1.0]),  # not Hurwitz
        lambda: HighGain(dt=1e-3, gain=1.0, order=2, coefficients=[1.0, 1.0]),
        lambda: HighGain(dt=1e-3, gain=1.0, order=1, coefficients=[-1.0, 1.0]),
        lambda: SuperTwisting(dt=1e-3),  # neither L nor (k1, k2)
        lambda: Levant(order=2, dt=1e-3, mu=-1.0),
        lambda: URED(dt=1e-3, beta=0.0),
        lambda: KalmanCA(dt=1e-3, process_noise=0.0, measurement_noise=1.0),
        lambda: KalmanCA.from_levels(1e-3, jerk_rms=0.0, measurement_variance=1.0),
    ],
)
def test_other_bad_parameters(factory):
    with pytest.raises(ValueError) as excinfo:
        factory()
    assert_worded(excinfo)


@pytest.mark.parametrize("cls, kwargs", ALL_CLASSES, ids=lambda c: getattr(c, "__name__", ""))
def test_unknown_discretization(cls, kwargs):
    with pytest.raises(ValueError, match="rk4") as excinfo:
        cls(dt=1e-3, discretization="rk4", **kwargs)
    assert_worded(excinfo)


def test_unknown_observer_name():
    with pytest.raises(ValueError, match="kalman-ca") as excinfo:  # the message lists the known names
        make_observer("no-such-observer", dt=1e-3)
    assert_worded(excinfo)
    with pytest.raises(ValueError) as excinfo:
        smo_gym.differentiate(np.zeros(10), 1e-3, method="no-such-observer")
    assert_worded(excinfo)


@pytest.mark.parametrize("name, kwargs", CASES)
def test_use_before_reset(name, kwargs):
    obs = build(name, kwargs)
    calls = [
        lambda: obs.update(np.zeros(BATCH)),
        lambda: obs.run(np.zeros((3,) + BATCH)),
        lambda: obs.step(np.zeros((28, 4)), np.zeros(28)),
        lambda: obs.velocity,
        lambda: obs.estimate,
        lambda: obs.reset(np.zeros(BATCH), mask=np.ones(4, bool)),
    ]
    for call in calls:
        with pytest.raises(RuntimeError) as excinfo:
            call()
        assert_worded(excinfo)


def test_diverging_explicit_ured_raises_and_keeps_state():
    r"""Explicit URED at a huge step diverges (its high-degree terms are stiff, ``tau k_1 \beta |e|^{1/2} \gg 1``):
    the update raises :class:`DivergenceError` (a ``RuntimeError``) naming the channel, and the previous state is
    kept, for ``update`` and for ``run``."""
    obs = URED(dt=0.1, lipschitz=1.0, discretization="euler")
    y = np.zeros((2, 3))
    obs.reset(y)
    y[1, 2] = 1e8
    state = estimate = None
    with pytest.raises(DivergenceError, match="channel 2 of batch element \\(1,\\)") as excinfo:
        for _ in range(100):
            state, estimate, n = obs.state, obs.estimate.copy(), obs.n_updates
            obs.update(y)
    assert isinstance(excinfo.value, RuntimeError)
    assert_worded(excinfo)
    assert n >= 1  # it took some steps to blow up: a genuine divergence, not a rejected input
    np.testing.assert_array_equal(obs.state, state)
    np.testing.assert_array_equal(obs.estimate, estimate)
    assert obs.n_updates == n
    assert np.all(np.isfinite(obs.state))

    # the same through run(): nothing committed
    obs2 = URED(dt=0.1, lipschitz=1.0, discretization="euler")
    obs2.reset(np.zeros((2, 3)))
    state2 = obs2.state
    with pytest.raises(DivergenceError):
        obs2.run(np.repeat(y[None], 100, axis=0))
    np.testing.assert_array_equal(obs2.state, state2)
    assert obs2.n_updates == 0


@pytest.mark.parametrize("discretization", ["taylor", "euler"])
@pytest.mark.parametrize("p1", [1.0, 0.0, -1.0, [1.0, 2.0], "1", np.nan])
def test_levant_p1_only_with_an_eigenvalue_mapping(discretization, p1):
    """``p1`` is the rate of the eigenvalue mappings of Wetzlinger, Reichhartinger and Horn; the Taylor and Euler
    steps would ignore it."""
    with pytest.raises(ValueError, match="p1") as excinfo:
        Levant(2, 1e-3, 1.0, discretization=discretization, p1=p1)
    assert_worded(excinfo)
    with pytest.raises(ValueError, match="mu") as excinfo:
        Levant(2, 1e-3, 1.0, discretization=discretization, mu=0.5)
    assert_worded(excinfo)
    Levant(2, 1e-3, 1.0, discretization="semi-implicit", p1=3.0, mu=0.5)  # where they belong


@pytest.mark.parametrize("make", [lambda: Levant(2, 1e-3, 5.0), lambda: SuperTwisting(1e-3, 5.0)])
@pytest.mark.parametrize(
    "bad",
    [
        np.ones((2, 3), complex),
        np.full((2, 3), np.datetime64("2020-01-01", "D")),
        np.ones((2, 3), dtype="m8[s]"),
        np.ones((2, 3), bool),
        np.full((2, 3), "1.0"),
        [[1.0, 2.0, 3.0], [4.0, 5.0]],
        [["1", 2.0, 3.0]] * 2,
        np.array([[None] * 3] * 2),
    ],
    ids=["complex", "datetime", "timedelta", "bool", "str", "ragged", "mixed-str", "object"],
)
def test_measurements_of_other_dtypes_are_rejected(make, bad):
    """Complex values used to lose their imaginary part and dates became nanosecond counts: now a TypeError, in
    ``reset``, ``update``, ``run`` and ``differentiate``, with the state unchanged."""
    obs = make()
    with pytest.raises(TypeError) as excinfo:
        obs.reset(bad)
    assert_worded(excinfo)
    obs.reset(np.zeros((2, 3)))
    state = obs.state
    with pytest.raises(TypeError) as excinfo:
        obs.update(bad)
    assert_worded(excinfo)
    with pytest.raises(TypeError):
        obs.run(np.array([bad, bad], dtype=object) if isinstance(bad, list) else np.stack([bad, bad]))
    np.testing.assert_array_equal(obs.state, state)
    with pytest.raises(TypeError):
        smo_gym.differentiate(
            np.array([bad, bad], dtype=object) if isinstance(bad, list) else np.stack([bad] * 2), 1e-3, "levant"
        )


def test_rejected_full_reset_keeps_the_previous_shape():
    """A full reset rejected by the parameters (here: per-channel gains of another size) used to leave the new
    shape with the old arrays, and the next update indexed them out of bounds."""
    obs = SuperTwisting(1e-3, lipschitz=np.ones(3))
    obs.reset(np.zeros(3))
    with pytest.raises(ValueError, match="broadcastable"):
        obs.reset(np.zeros(5))
    assert obs.shape == (3,)
    with pytest.raises(ValueError, match="shape"):
        obs.update(np.zeros(5))
    assert obs.update(np.ones(3)).shape == (3, 2)


def test_ragged_and_object_blocks_in_run():
    obs = Levant(2, 1e-3, 5.0)
    obs.reset(np.zeros(2))
    for Y in ([[0.0, 1.0], [2.0]], [[0.0, "a"]], [[0.0, None]], np.zeros((3, 2), complex)):
        with pytest.raises(TypeError) as excinfo:
            obs.run(Y)
        assert_worded(excinfo)
    assert obs.n_updates == 0


def test_huge_gains_fail_at_construction_not_at_reset():
    """Injection gains that overflow (``k_i ell^i``) used to reach ``numpy.linalg.inv`` at ``reset`` (LinAlgError)."""
    for factory in (
        lambda: HighGain(1e-3, 1e300, 3),
        lambda: LowPowerHighGain(1e-3, 1e300, 3),
        lambda: HighGain(1e-3, 1e200, 2, discretization="euler"),
    ):
        with pytest.raises(ValueError) as excinfo:
            factory()
        assert_worded(excinfo)


def test_an_overflowing_estimate_is_a_divergence():
    """The reported estimate :math:`e^{-\\tau N}\\hat x^+` is a sum of state entries and can overflow where the state
    does not: the compiled step used to return ``-inf`` with a success status. The step is now rejected like a
    non-finite state (found by the bad-input sweep of ``tests/test_bad_input.py``)."""
    obs = Levant(2, 1.0, 1.0, discretization="taylor")
    obs.reset(np.zeros(1))
    state = np.array([[-1.62594398e308, 2.63147785e307, 9.47702536e307, 0.0]])
    with pytest.raises(DivergenceError, match="channel 0") as excinfo:
        obs.step(state, np.array([-7.47270782e307]))
    assert_worded(excinfo)


# ----------------------------------------------------------------------------------------------------------------
# initial derivatives: reset(y0, derivatives=...)
# ----------------------------------------------------------------------------------------------------------------
#: every registered family, on its registered examples (the fixed-time ILF observer is not exact on ramps from
#: the true state at its example's rate)
DERIVATIVE_CASES = [c for c in CASES if c.values[0] != "ilf-fixed"]


def test_derivatives_of_booleans_are_refused_as_measurements_of_them_are():
    obs = Levant(2, DT, 5.0)
    with pytest.raises(TypeError, match="expected derivatives to be an array of real numbers"):
        obs.reset(np.zeros(3), derivatives=np.ones((3, 1), dtype=bool))
    with pytest.raises(TypeError, match="expected alpha"):
        smo_gym.observers.ILFDifferentiator(DT, 20.0, alpha="not a number")  # the finite-time kind ignores it


def test_derivative_cases_cover_the_registry():
    assert {p.values[0] for p in DERIVATIVE_CASES} == set(OBSERVERS) - {"ilf-fixed"}  # the class of ilf-finite


@pytest.mark.parametrize("name, kwargs", DERIVATIVE_CASES)
def test_reset_with_the_true_derivatives_tracks_a_ramp_from_the_first_sample(name, kwargs):
    """On ramps ``y = a + b t`` (every channel its own), an observer reset with the true slope ``b`` estimates it
    from the first sample on: every scheme here is exact on ramps started at the true state, up to the rounding
    that a sliding-mode step turns into a chattering of ``dt * lambda_0 L`` (here below 0.03 of ``b = 5 ... 8``).
    Reset with a zero slope, the same observer starts wrong (finite differences and the worst-case-optimal
    differentiator excepted: they estimate from the samples alone, and the first backward difference of a ramp is
    exact whatever the state). The value estimate of every update is the ramp at its
    sample time, or at the next one for an observer that reports the one-step prediction (``lead``)."""
    T, shape = 40, (2, 3)
    t = np.arange(T)[:, None, None] * DT
    a = np.linspace(-1.0, 1.0, 6).reshape(shape)
    b = np.linspace(5.0, 8.0, 6).reshape(shape)
    Y = a + b * t
    if name in TAKES_LIPSCHITZ:
        kwargs = dict(kwargs, lipschitz=20.0)
    obs = make_observer(name, dt=DT, **kwargs)
    m = obs.order + 1
    first = obs.reset(Y[0], derivatives=b[..., None])
    expected = np.zeros(shape + (m,))
    expected[..., 0], expected[..., 1] = Y[0], b
    np.testing.assert_array_equal(first, expected)
    est = np.concatenate([first[None], obs.run(Y[1:])])
    np.testing.assert_allclose(est[..., 1], np.broadcast_to(b, Y.shape), rtol=0.03)
    at = Y + np.concatenate([np.zeros((1,) + shape), np.full((T - 1,) + shape, obs.lead * DT)]) * b  # reset: t_0
    np.testing.assert_allclose(est[..., 0], at, rtol=0, atol=1e-4)
    if name not in ("finite-difference", "worst-case-optimal"):
        cold = make_observer(name, dt=DT, **kwargs)
        cold.reset(Y[0])
        cold_error, warm_error = np.max(np.abs(cold.update(Y[1])[..., 1] - b)), np.max(np.abs(est[1, ..., 1] - b))
        assert cold_error > max(0.01 * b.max(), 2.0 * warm_error)


@pytest.mark.parametrize("name, kwargs", [c for c in CASES if c.values[0] in ("levant", "high-gain", "kalman-ca")])
def test_reset_derivatives_partial_masked_and_restart(name, kwargs, rng):
    """``k < order`` derivatives fill the first ``k`` (the rest start at zero); with a mask only the masked rows
    take them, bit for bit as a fresh observer reset with them; ``restart`` accepts them as ``reset`` does."""
    Y = measurements(rng, T=60)
    obs = build(name, kwargs)
    k = obs.order - 1 if obs.order > 1 else 1
    d = rng.standard_normal(BATCH + (k,))
    first = obs.reset(Y[0], derivatives=d)
    np.testing.assert_array_equal(first[..., 1 : k + 1], d)
    assert np.all(first[..., k + 1 :] == 0.0)
    # restart = reset with the same derivatives
    obs.run(Y[1:20])
    fresh = build(name, kwargs)
    np.testing.assert_array_equal(obs.restart(Y[20], derivatives=d), fresh.reset(Y[20], derivatives=d))
    np.testing.assert_array_equal(obs.run(Y[21:30]), fresh.run(Y[21:30]))
    # masked: only the masked environments restart, with their derivatives
    mask = np.array([True, False, False, True])
    untouched = copy.deepcopy(obs)
    returned = obs.reset(Y[30], mask=mask, derivatives=d)
    restarted = build(name, kwargs).reset(Y[30], derivatives=d)
    np.testing.assert_array_equal(returned[mask], restarted[mask])
    np.testing.assert_array_equal(returned[~mask], untouched.estimate[~mask])
    ref_fresh = build(name, kwargs)
    ref_fresh.reset(Y[30], derivatives=d)
    got, ref_u, ref_f = obs.run(Y[31:]), untouched.run(Y[31:]), ref_fresh.run(Y[31:])
    np.testing.assert_array_equal(got[:, mask], ref_f[:, mask])
    np.testing.assert_array_equal(got[:, ~mask], ref_u[:, ~mask])


def test_reset_derivatives_of_the_model_based_observers_is_their_initial_velocity():
    """The mechanical observers spell the same thing ``v0``: ``derivatives[..., 0]``."""
    from smo_gym.observers import MechanicalSuperTwisting

    class Free:
        n = 2

        def acceleration(self, q, v, u):
            return np.zeros_like(q)

        def inertia(self, q):
            return np.eye(2)

    a, b = MechanicalSuperTwisting(DT, Free(), lipschitz=5.0), MechanicalSuperTwisting(DT, Free(), lipschitz=5.0)
    v0 = np.array([1.5, -2.0])
    np.testing.assert_array_equal(a.reset(np.zeros(2), derivatives=v0[:, None]), b.reset(np.zeros(2), v0=v0))
    assert a.estimate[1, 1] == -2.0
    with pytest.raises(TypeError, match="expected v0 or derivatives"):
        a.reset(np.zeros(2), v0=v0, derivatives=v0[:, None])


@pytest.mark.parametrize(
    "derivatives, error, match",
    [
        (np.zeros((4, 7, 3)), ValueError, r"k <= order = 2"),  # too many derivatives
        (np.zeros((4, 7)), ValueError, r"shape \(4, 7, 'k'\)"),  # the derivative axis is missing
        (np.zeros((7, 4, 1)), ValueError, "shape"),  # channels and batch swapped
        (np.full((4, 7, 1), np.nan), ValueError, "finite derivatives"),
        ("fast", TypeError, "array of real numbers"),
        (np.full((4, 7, 1), 1j), TypeError, "array of real numbers"),
    ],
)
def test_reset_derivatives_are_validated(derivatives, error, match):
    obs = Levant(order=2, dt=DT, lipschitz=1.0)
    with pytest.raises(error, match=match) as excinfo:
        obs.reset(np.zeros(BATCH), derivatives=derivatives)
    assert_worded(excinfo)
    assert obs.shape is None  # nothing was set up


# the steps that predict the next sample (exact on a ramp once converged), and those that form no prediction
PREDICTING = [
    ("kalman-ca", {"process_noise": 1e3, "measurement_noise": 1e-6}),
    ("kalman-imm", {"process_noise": 1e3, "measurement_noise": 1e-6}),
    ("worst-case-optimal", {"lipschitz": 5.0, "noise": 0.0}),
    ("worst-case-optimal", {"lipschitz": 5.0, "noise": 1e-4}),
    ("high-gain", {"gain": 30.0, "discretization": "euler"}),
    ("levant", {"lipschitz": 5.0, "discretization": "implicit"}),
    ("levant", {"lipschitz": 5.0, "discretization": "matching"}),
    ("filtering", {"lipschitz": 5.0, "discretization": "matching"}),
    ("super-twisting", {"lipschitz": 5.0, "discretization": "implicit"}),
    ("ured", {"lipschitz": 5.0, "discretization": "implicit"}),
    ("uniform-levant", {"lipschitz": 5.0, "discretization": "implicit"}),
]
NOT_PREDICTING = [
    ("finite-difference", {}),
    ("high-gain", {"gain": 30.0, "discretization": "implicit"}),
    ("filtering", {"lipschitz": 5.0, "discretization": "implicit"}),
    ("low-power-high-gain", {"gain": 30.0}),
]


@pytest.mark.parametrize(("name", "kwargs"), PREDICTING + NOT_PREDICTING)
def test_output_error_is_the_innovation_it_documents(name, kwargs):
    """``output_error`` is ``y_k`` minus the observer's prediction of it; on a noise-free ramp every prediction of
    a step that forms one is exact once the observer has converged (a wrong sample in the innovation leaves
    ``slope * dt = 2e-3``); the steps that form none report ``y_k`` minus the previous value estimate."""
    t = np.arange(5000) * DT
    y = (0.3 + 2.0 * t)[:, None]
    obs = make_observer(name, dt=DT, **kwargs)
    obs.reset(y[0])
    obs.run(y[1:-1])
    previous = obs.estimate[:, 0].copy()
    obs.update(y[-1])
    if (name, kwargs) in PREDICTING:
        assert np.abs(obs.output_error).max() < 1e-9
    else:
        np.testing.assert_allclose(obs.output_error, y[-1] - previous, rtol=1e-12)
