"""Sensor models: each stage's statistics, composition, seeding and the NaN guard.

Statistical checks use sample sizes whose sampling error is far below the tolerance (stated at each test), with
fixed seeds, so they are deterministic and would fail on a wrong scale, sign or distribution.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from smo_gym import sensors
from smo_gym.sensors import (
    Bias,
    Chain,
    Delay,
    Drift,
    Dropout,
    Encoder,
    GaussianNoise,
    Outliers,
    Quantization,
    UniformNoise,
    Wrap,
    make_sensor,
)


def assert_worded(excinfo):
    """Typed errors say what was expected and what was received."""
    msg = str(excinfo.value)
    assert "expected" in msg and "actual value" in msg, msg


def ramp(T: int, n: int, seed: int = 0) -> np.ndarray:
    """A moving signal (T, n): smooth random walk, so quantization errors are spread over the cell."""
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.uniform(0.0, 1e-2, size=(T, n)), axis=0)


def measure_all(sensor, Y, seed=0, **kwargs) -> np.ndarray:
    first = sensor.reset(Y[0], seed=seed, **kwargs)
    return np.concatenate([first[None], sensor.run(Y[1:])], axis=0)


def test_ideal_is_identity():
    Y = ramp(300, 5)
    assert np.array_equal(measure_all(make_sensor("ideal"), Y), Y)


def test_gaussian_noise_std():
    # 40000 samples: the sample std has relative standard error 1/sqrt(2N) = 0.35 %, tolerance 3 %
    Y = ramp(20000, 2)
    sensor = GaussianNoise([1e-3, 5e-3])
    err = measure_all(sensor, Y) - Y
    np.testing.assert_allclose(err.std(axis=0), [1e-3, 5e-3], rtol=0.03)
    np.testing.assert_allclose(sensor.error_std(2), err.std(axis=0), rtol=0.03)  # declared = measured
    assert np.all(np.abs(err.mean(axis=0)) < 4 * np.array([1e-3, 5e-3]) / np.sqrt(20000))


def test_uniform_noise_is_bounded_with_variance_b2_over_3():
    Y = ramp(20000, 3)
    sensor = UniformNoise(2e-3)
    err = measure_all(sensor, Y) - Y
    assert np.max(np.abs(err)) <= 2e-3
    np.testing.assert_allclose(err.std(axis=0), 2e-3 / np.sqrt(3), rtol=0.03)
    # the declared level, which calibrations read instead of estimating it, is the measured one
    np.testing.assert_allclose(sensor.error_std(3), err.std(axis=0), rtol=0.03)


@pytest.mark.parametrize("per_channel", [False, True])
def test_the_first_measurement_is_never_drifted_dropped_or_an_outlier(per_channel):
    """``reset`` documents its measurement as never delayed, dropped or an outlier: with a drift, a dropout and
    outliers that act at almost every later sample, the first measurement is the true signal; the stages act from
    the next sample on (the drift's first step, a drop holding that first value, or an outlier), and again
    after a reset that continues the random stream."""
    y0 = np.array([0.3, -1.2, 2.0])
    moved = 0
    for seed in range(20):
        sensor = Chain(Drift(1.0), Dropout(0.99, per_channel=per_channel), Outliers(0.99, 1e3))
        np.testing.assert_array_equal(sensor.reset(y0, seed=seed), y0)
        moved += np.count_nonzero(sensor.measure(y0) != y0)
    assert moved >= 0.9 * 20 * y0.size
    # a new episode on the same stream restarts the drift at zero, wherever the last episode left it
    rng, drift = np.random.default_rng(0), Drift(1.0)
    drift.reset(y0, rng=rng)
    assert np.abs(drift.run(np.tile(y0, (50, 1)))[-1] - y0).min() > 0.1
    np.testing.assert_array_equal(drift.reset(y0, rng=rng), y0)


def test_quantization_grid_and_error_bound_per_joint_kind():
    res, lin = 2 * np.pi / 4096, 1e-5
    Y = ramp(5000, 2)
    out = measure_all(Quantization(res, linear_resolution=lin), Y, angular=[True, False])
    steps = out / np.array([res, lin])
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    err = out - Y
    assert np.all(np.abs(err[:, 0]) <= res / 2 + 1e-15) and np.all(np.abs(err[:, 1]) <= lin / 2 + 1e-15)
    np.testing.assert_allclose(err[:, 0].std(), res / np.sqrt(12), rtol=0.05)


def test_encoder_presets_from_counts():
    enc = Encoder(counts_per_revolution=4096)
    assert enc.resolution == 2 * np.pi / 4096
    assert make_sensor("encoder-12bit") == enc
    assert make_sensor("encoder-12bit-noisy") == Encoder(resolution=2 * np.pi / 4096, noise_std=1e-3)
    # linear channels: the same encoder on a drive of 1 cm per radian
    q = Quantization.from_counts(4096)
    assert np.isclose(q.linear_resolution, 2 * np.pi * 0.01 / 4096)
    with pytest.raises(ValueError, match="exactly one of resolution and counts_per_revolution"):
        Encoder()


def test_noisy_encoder_output_on_grid_and_error_std():
    Y = ramp(20000, 2)
    sensor = make_sensor("encoder-12bit-noisy")
    out = measure_all(sensor, Y)
    res = 2 * np.pi / 4096
    np.testing.assert_allclose(out / res, np.round(out / res), atol=1e-6)
    # noise before the counter: error variance sigma^2 + res^2/12 (error_std), within 5 %
    np.testing.assert_allclose((out - Y).std(axis=0), sensor.error_std(2), rtol=0.05)


def test_bias_fixed_and_per_episode():
    Y = ramp(100, 3)
    np.testing.assert_allclose(
        measure_all(Bias([0.1, -0.2, 0.0]), Y) - Y, np.broadcast_to([0.1, -0.2, 0.0], Y.shape), atol=1e-12
    )
    s = Bias(std=0.01)
    e1 = measure_all(s, Y, seed=1) - Y
    e2 = measure_all(s, Y, seed=2) - Y
    assert np.allclose(e1, e1[0], atol=1e-12)  # constant within an episode
    assert not np.allclose(e1[0], e2[0])  # redrawn at reset
    # drawn from N(0, std^2): 20,000 channels' offsets (sample error of their std ~0.5 %)
    offsets = Bias(std=0.01).reset(np.zeros(20000), seed=3)
    np.testing.assert_allclose(offsets.std(), 0.01, rtol=0.03)


def test_drift_is_a_random_walk_with_sqrt_time_growth():
    # 4000 independent channels: std of the drift after t seconds is sigma*sqrt(t); sample error ~1.1 %, tol 5 %
    dt, sigma = 1e-3, 2e-3
    Y = np.zeros((1001, 4000))
    err = measure_all(Drift(sigma), Y, dt=dt)
    np.testing.assert_allclose(err[1000].std(), sigma * np.sqrt(1.0), rtol=0.05)
    np.testing.assert_allclose(err[250].std(), sigma * np.sqrt(0.25), rtol=0.05)


def test_delay_shifts_by_k_samples():
    Y = ramp(50, 2)
    out = measure_all(Delay(3), Y)
    np.testing.assert_array_equal(out[3:], Y[:-3])
    np.testing.assert_array_equal(out[:3], np.broadcast_to(Y[0], (3, 2)))


@pytest.mark.parametrize("per_channel", [False, True])
def test_dropout_holds_last_value_at_rate_p(per_channel):
    # 20000 samples x 4 channels at p = 0.1: the held fraction has standard error <= 0.2 %, tolerance 1 %
    Y = ramp(20000, 4)
    out = measure_all(Dropout(0.1, per_channel=per_channel), Y)
    held = out[1:] == out[:-1]
    fresh = out[1:] == Y[1:]
    assert np.all(held | fresh)  # every output is either new or the previous one
    assert abs(held.mean() - 0.1) < 0.01
    if not per_channel:
        assert np.all(held == held[:, :1])  # a lost packet freezes every channel
    else:
        assert not np.all(held == held[:, :1])


def test_outliers_rate_and_scale():
    Y = ramp(50000, 2)
    err = measure_all(Outliers(0.01, 1.0), Y) - Y
    gross = err != 0.0
    assert abs(gross.mean() - 0.01) < 0.002
    np.testing.assert_allclose(err[gross].std(), 1.0, rtol=0.1)


def test_composition_order_and_equivalences():
    a, b = GaussianNoise(1e-3), Quantization(1e-2)
    assert (a | b) == Chain(a, b) and len((a | b | Delay(1)).stages) == 3
    Y = ramp(2000, 2)
    noisy_then_quantized = measure_all(a | b, Y)
    quantized_then_noisy = measure_all(b | a, Y)
    assert np.allclose(noisy_then_quantized / 1e-2, np.round(noisy_then_quantized / 1e-2))
    assert not np.allclose(quantized_then_noisy / 1e-2, np.round(quantized_then_noisy / 1e-2))


def test_seeding_and_batching_independence():
    Y = ramp(3 * sensors.BLOCK + 17, 5)
    s = make_sensor("low-cost")
    one = measure_all(s, Y, seed=7)
    # the same seed gives the same stream; measure() sample by sample equals run() on blocks
    s2 = make_sensor("low-cost")
    first = s2.reset(Y[0], seed=7)
    rows = np.array([first] + [s2.measure(y) for y in Y[1:]])
    np.testing.assert_array_equal(one, rows)
    assert not np.array_equal(one, measure_all(s, Y, seed=8))
    # two sensors from one preset do not share a stream: interleaved, each gives what it gives alone
    a, b = make_sensor("low-cost"), make_sensor("low-cost")
    za, zb = [a.reset(Y[0], seed=7)], [b.reset(Y[0], seed=7)]
    for y in Y[1:]:
        za.append(a.measure(y))
        zb.append(b.measure(y))
    np.testing.assert_array_equal(np.array(za), one)
    np.testing.assert_array_equal(np.array(zb), one)


def test_batch_shape_and_pickle():
    Y = ramp(200, 6).reshape(200, 2, 3)
    s = make_sensor("encoder-12bit-noisy")
    s.reset(Y[0], seed=0)
    s2 = pickle.loads(pickle.dumps(s))
    np.testing.assert_array_equal(s.run(Y[1:]), s2.run(Y[1:]))
    assert s.measure(Y[0]).shape == (2, 3)


def test_every_preset_runs_and_unknown_names_are_listed():
    Y = ramp(100, 3)
    for name in sensors.PRESETS:
        out = measure_all(make_sensor(name), Y, dt=1e-3)
        assert out.shape == Y.shape and np.all(np.isfinite(out))
    with pytest.raises(ValueError, match=r"encoder-12bit-noisy.*actual value: 'nope'"):
        make_sensor("nope")


def test_nan_never_passes_silently():
    s = make_sensor("encoder-12bit")
    s.reset(np.zeros(3), seed=0)
    with pytest.raises(ValueError, match=r"finite measurement.*channel 1.*true signal"):
        s.measure(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="finite measurement"):
        s.run(np.array([[0.0, 0.0, np.inf]]))
    # an overflowing model (huge outliers on a huge signal) is caught as well
    wild = Outliers(1.0, 1e308) | GaussianNoise(1e308)
    wild.reset(np.full(2, 1e308), seed=0)
    with pytest.raises(ValueError, match="sensor model"):
        for _ in range(50):
            wild.measure(np.full(2, 1e308))
    with pytest.raises(ValueError, match="std >= 0"):
        GaussianNoise(np.nan)
    with pytest.raises(ValueError, match="probability"):
        Dropout(1.5)
    with pytest.raises(RuntimeError, match="reset"):
        make_sensor("ideal").measure(np.zeros(2))


def test_restart_with_the_same_generator_continues_the_stream_and_restarts_the_state():
    """An episode restart (``reset`` with the previous generator) keeps the random block but restarts every
    stage's state: delay lines are primed with the new first value, a per-episode bias is drawn again; the whole
    sequence is reproducible from the seed."""
    from smo_gym.sensors import Bias, Delay, GaussianNoise

    def episodes(seed):
        sensor = Delay(2) | Bias(0.0, std=0.1) | GaussianNoise(1e-6)
        rng = np.random.default_rng(seed)
        out = [sensor.reset(np.zeros(3), rng=rng)]
        out += [sensor.measure(np.full(3, float(k))) for k in range(1, 6)]
        block = sensor._rand
        out.append(sensor.reset(np.full(3, 50.0), rng=rng))
        assert sensor._rand is block  # no refill at the restart
        out += [sensor.measure(np.full(3, 51.0 + k)) for k in range(3)]
        return np.array(out)

    a, b = episodes(0), episodes(0)
    np.testing.assert_array_equal(a, b)
    bias_1, bias_2 = a[0], a[6] - 50.0
    assert np.all(np.abs(bias_1 - bias_2) > 1e-4)  # drawn again for the new episode
    # the delay line restarted at 50: two samples of the new first value, then 51 (none of the old episode)
    np.testing.assert_allclose(a[7:9], np.broadcast_to(50.0 + bias_2, (2, 3)), atol=1e-5)
    np.testing.assert_allclose(a[9], 51.0 + bias_2, atol=1e-5)


def test_restart_is_a_reset_on_the_same_stream():
    """``restart(y0)`` is ``reset(y0, rng=<the last reset's generator>)`` with the same ``dt`` and ``angular``, bit
    for bit over episodes (a drawn bias, a delay line, dropouts, noise), and refuses what that reset would not take:
    before any reset, another shape, a non-finite true signal (the state kept: the stream goes on as a twin's)."""
    from smo_gym.sensors import Bias, Delay, GaussianNoise

    def make():
        return Delay(2) | Bias(0.0, std=0.1) | Dropout(0.3) | GaussianNoise(1e-3)

    angular = np.array([True, False, True])
    Y = np.cumsum(np.full((40, 3), 0.01), axis=0)
    reset, restart = make(), make()
    with pytest.raises(RuntimeError, match="reset"):
        restart.restart(Y[0])
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    got = {"reset": [reset.reset(Y[0], rng=rng_a, dt=0.01, angular=angular)],
           "restart": [restart.reset(Y[0], rng=rng_b, dt=0.01, angular=angular)]}  # fmt: skip
    for episode in range(1, 4):
        start = 10 * episode
        got["reset"].append(reset.reset(Y[start], rng=rng_a, dt=0.01, angular=angular))
        got["restart"].append(restart.restart(Y[start]))
        for name, sensor in (("reset", reset), ("restart", restart)):
            got[name] += list(sensor.run(Y[start + 1 : start + 10]))
    np.testing.assert_array_equal(np.array(got["restart"]), np.array(got["reset"]))
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        restart.restart(Y[0, :2])
    bad = Y[0].copy()
    bad[2] = np.nan
    with pytest.raises(ValueError, match="channel 2") as excinfo:
        restart.restart(bad)
    assert_worded(excinfo)
    np.testing.assert_array_equal(restart.run(Y[:5]), reset.run(Y[:5]))


# ---- bad input ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "sensor", [Delay(2), Dropout(0.5), Delay(3) | Dropout(0.3) | GaussianNoise(1e-3), make_sensor("low-cost")], ids=repr
)
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_sensor_rejects_a_non_finite_true_signal_at_once_and_keeps_its_state(sensor, bad):
    """A delay line or a held sample used to store a NaN true signal and pass it on ``d`` samples later, blaming
    the sensor model for it; now the sample that carries it is rejected, naming the channel, and the sensor goes
    on as if it had never seen it (same stream, same delay line)."""
    Y = np.cumsum(np.full((12, 3), 0.01), axis=0)
    reference = sensor.reset(Y[0], seed=3), [sensor.measure(y) for y in Y[1:]]
    sensor.reset(Y[0], seed=3)
    got = []
    for k, y in enumerate(Y[1:]):
        if k in (2, 5):
            bad_y = y.copy()
            bad_y[1] = bad
            with pytest.raises(ValueError, match="channel 1") as excinfo:
                sensor.measure(bad_y)
            assert_worded(excinfo)
            with pytest.raises(ValueError, match="channel 1"):
                sensor.run(np.stack([y, bad_y]))  # in a block: nothing of the block is committed either
        got.append(sensor.measure(y))
    np.testing.assert_array_equal(np.array(got), np.array(reference[1]))
    with pytest.raises(ValueError, match="channel 2") as excinfo:
        sensor.reset(np.array([0.0, 1.0, bad]), seed=3)
    assert_worded(excinfo)


def test_sensor_block_over_several_refills_is_all_or_nothing():
    sensor = Delay(2) | GaussianNoise(1e-3)
    Y = np.zeros((3 * sensors.BLOCK, 2))
    sensor.reset(Y[0], seed=0)
    expected = sensor.run(Y[1:])
    sensor.reset(Y[0], seed=0)
    bad = Y[1:].copy()
    bad[2 * sensors.BLOCK, 0] = np.nan
    with pytest.raises(ValueError, match="channel 0"):
        sensor.run(bad)
    np.testing.assert_array_equal(sensor.run(Y[1:]), expected)


@pytest.mark.parametrize(
    "call",
    [
        lambda s: s.reset(np.zeros(2), rng=5),
        lambda s: s.reset(np.zeros(2), seed="five"),
        lambda s: s.reset(np.zeros(2), seed=-1),
        lambda s: s.reset(np.zeros(2), dt="0.01"),
        lambda s: s.reset(np.zeros(2), angular="yes"),
        lambda s: s.reset(np.zeros(2), angular=[1, 0]),
        lambda s: s.reset(np.zeros(2), angular=[True, False, True]),
        lambda s: s.reset(np.zeros((2, 0))),
        lambda s: s.reset(np.zeros(2, complex)),
        lambda s: s.reset(np.array(["2020-01-01", "2020-01-02"], dtype="datetime64[D]")),
        lambda s: s.reset([[0.0, 1.0], [2.0]]),
        lambda s: s.reset(np.zeros(2), sead=1),
        lambda s: s.error_std(2.5),
    ],
)
def test_sensor_reset_arguments_are_checked(call):
    sensor = GaussianNoise(1e-3) | Delay(1)
    with pytest.raises((ValueError, TypeError)) as excinfo:
        call(sensor)
    assert_worded(excinfo)
    assert sensor._kinds is None  # nothing was set up by the rejected reset


def test_reserving_random_rows_takes_a_count_within_one_block():
    """A compiled caller reads the reserved rows of the random block: a count outside ``[1, BLOCK]`` would make it
    read outside it (a negative one crashed the interpreter), so it is refused, and nothing is reserved."""
    sensor = GaussianNoise(1e-3)
    with pytest.raises(RuntimeError, match="never reset"):
        sensor.reserve_random_rows(1)
    sensor.reset(np.zeros(3), seed=0)
    before = sensor.reserve_random_rows(1)
    for bad, error in ((-10**7, ValueError), (0, ValueError), (sensors.BLOCK + 1, ValueError), (2.5, TypeError),
                       ("a", TypeError), (True, TypeError)):  # fmt: skip
        with pytest.raises(error) as excinfo:
            sensor.reserve_random_rows(bad)
        assert_worded(excinfo)
    assert sensor.reserve_random_rows(np.int64(2)) == before + 1  # the refused calls reserved nothing
    assert np.isfinite(sensor.measure(np.zeros(3))).all()
    # rows that end exactly at the block's end fit; one more would straddle it (None, nothing reserved); a block
    # used up is refilled and its rows start at 0
    rest = sensors.BLOCK - sensor._t
    assert sensor.reserve_random_rows(rest + 1) is None
    assert sensor.reserve_random_rows(rest) == sensors.BLOCK - rest
    assert sensor.reserve_random_rows(3) == 0


def test_sensor_measure_rejects_converted_dtypes():
    sensor = GaussianNoise(1e-3)
    sensor.reset(np.zeros(2), seed=0)
    for bad in (
        np.ones(2, complex),
        np.array(["1", "2"]),
        np.array([True, False]),
        [[1.0], [2.0, 3.0]],
        "1.0",
        np.array([None, 1.0]),
        np.array([1, 2], dtype="timedelta64[s]"),
    ):
        with pytest.raises(TypeError) as excinfo:
            sensor.measure(bad)
        assert_worded(excinfo)
        with pytest.raises(TypeError):
            sensor.run(np.array([bad], dtype=object) if isinstance(bad, list) else np.asarray(bad)[None])


@pytest.mark.parametrize(
    "factory",
    [
        lambda: GaussianNoise(True),
        lambda: GaussianNoise("0.1"),
        lambda: GaussianNoise(1e-3 + 1j),
        lambda: GaussianNoise(np.zeros((2, 2))),
        lambda: Quantization(np.datetime64("2020")),
        lambda: Bias("1"),
        lambda: Dropout(0.1, per_channel="yes"),
        lambda: Dropout(True),
        lambda: Delay(2.0),
        lambda: Outliers(0.1, [1j]),
        lambda: Encoder(counts_per_revolution=4096.0),
        lambda: Quantization.from_counts(4096, linear_travel="1"),
        lambda: GaussianNoise(std=1e-3, mean=0.0),
        lambda: Chain(GaussianNoise(1e-3), 3.0),
    ],
)
def test_sensor_constructors_reject_converted_values(factory):
    with pytest.raises((TypeError, ValueError)) as excinfo:
        factory()
    assert_worded(excinfo)


# ----------------------------------------------------------------------------------------------------------------
# single-turn encoders: angles reported modulo 2 pi
# ----------------------------------------------------------------------------------------------------------------
TWO_PI = 2 * np.pi


def spinning(T: int, offsets=(0.0,), dt: float = 1e-3) -> np.ndarray:
    """``30 t + offset`` (T, n): about 4.8 turns per second, crossing +-pi many times."""
    return 30.0 * np.arange(T)[:, None] * dt + np.asarray(offsets)[None, :]


def test_single_turn_encoder_reports_the_quantized_angle_modulo_two_pi():
    """``Encoder(wrap=True)``: the count of the incremental encoder reduced to [-pi, pi), computed here directly;
    linear channels are quantized but not wrapped."""
    true = spinning(2000, offsets=(0.0, 1.0))
    res = TWO_PI / 4096
    got = measure_all(Encoder(res, wrap=True), true, angular=[True, False])
    counts = res * np.floor(true / res + 0.5)
    lin_res = res * 0.01  # the linear channel: the same encoder on 1 cm per radian
    expected_angle = counts[:, 0] - TWO_PI * np.floor((counts[:, 0] + np.pi) / TWO_PI)
    np.testing.assert_allclose(got[:, 0], expected_angle, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[:, 1], lin_res * np.floor(true[:, 1] / lin_res + 0.5), rtol=0, atol=1e-12)
    assert np.all(got[:, 0] >= -np.pi) and np.all(got[:, 0] < np.pi)
    assert got[:, 1].max() > 50.0  # not wrapped
    assert "wrap=True" in repr(Encoder(res, wrap=True))


def test_noisy_single_turn_encoder_wraps_after_noise_and_quantization():
    """Noise acts before the counter and the wrap after it: outputs lie on the grid and in [-pi, pi), and the
    unwrapped output is the true angle within the noise. The error statistics are unchanged by the wrap."""
    true = spinning(20000, offsets=(0.3,))
    res = TWO_PI / 4096
    enc = Encoder(res, noise_std=1e-3, wrap=True)
    got = measure_all(enc, true)
    assert np.all(got >= -np.pi - 1e-12) and np.all(got < np.pi + 1e-12)
    np.testing.assert_allclose(got, np.round(got / res) * res, rtol=0, atol=1e-12)
    err = np.unwrap(got, axis=0) - true
    # 20000 samples: relative standard error of the std 0.5 %, tolerance 5 %
    np.testing.assert_allclose(err.std(), np.sqrt(1e-6 + res**2 / 12), rtol=0.05)
    np.testing.assert_array_equal(enc.error_std(1), Encoder(res, noise_std=1e-3).error_std(1))
    assert [type(s) for s in enc.stages] == [GaussianNoise, Quantization, Wrap]
    assert Chain(GaussianNoise(1e-3), Quantization(res), Wrap()) == enc


def test_wrap_maps_onto_the_half_open_circle():
    """A single-turn reading lies in ``[-pi, pi)``: every odd multiple of pi reads ``-pi`` (``round`` would give
    ``+pi`` for some of them, a reading of one angle as two values a full turn apart)."""
    x = np.array([np.pi, 3 * np.pi, 5 * np.pi, -np.pi, -3 * np.pi, 2.0, -7.0])
    sensor = Wrap()
    for out in (sensor.reset(x, seed=0), sensor.measure(x)):
        np.testing.assert_array_equal(out[:5], -np.pi)
        np.testing.assert_allclose(out[5:], [2.0, 2 * np.pi - 7.0], rtol=1e-15)


def test_encoder_wrap_must_be_a_bool():
    with pytest.raises(TypeError, match="expected wrap") as excinfo:
        Encoder(1e-3, wrap="no")
    assert "actual value" in str(excinfo.value)


@pytest.mark.parametrize("method", ["measure", "run", "reset", "__call__"])
def test_a_sensor_is_its_stages_subclasses_cannot_replace_the_stream(method):
    # every path (Sensor.run, the wrapper's fused driver) runs the stages through the compiled chain, so a class
    # with its own stream would be run differently by different paths: refused where it is defined
    with pytest.raises(TypeError, match=f"overrides {method}"):
        type("Custom", (sensors.GaussianNoise,), {method: lambda self, *a, **k: None})


def test_a_sensor_subclass_with_stages_only_is_accepted():
    class Quiet(sensors.GaussianNoise):
        """A preset: only the parameters differ."""

    assert Quiet(0.1).stages[0].std == 0.1


def test_a_sensor_spec_is_accepted_wherever_a_preset_is():
    """The wrapper's ``sensor`` (and everything built on ``make_sensor``) takes the spec syntax the guide documents:
    a 1024-count encoder delayed by two samples, as ``smo_gym.specs`` builds it."""
    import gymnasium as gym

    from smo_gym import specs
    from smo_gym.wrappers import EstimatedVelocity

    spec = "encoder:counts_per_revolution=1024+delay:samples=2"
    assert repr(sensors.make_sensor(spec)) == repr(specs.make_sensor(spec))
    env = EstimatedVelocity(gym.make("InvertedPendulum-v5"), sensor=spec, disk_cache=False)
    np.testing.assert_allclose(env.measurement.quantization_step()[1], 2 * np.pi / 1024)
    env.reset(seed=0)
    env.step(np.zeros(1))
