"""The fitted linear filters of ``scripts/bench_fitted_filter.py``: the design matrix and the least-squares taps."""

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("bench_fitted_filter")


def test_differences_reach_back_to_the_episode_start_and_no_further(script):
    z = np.arange(10.0)[:, None] ** 2  # one channel, episodes [0, 4) and [4, 10)
    X = script.differences(z, [0, 4], taps=3)
    assert X.shape == (1, 10, 3)
    assert np.all(X[0, [0, 4]] == 0.0)  # each episode's first sample
    assert X[0, 2].tolist() == [4 - 1, 4 - 0, 4 - 0]  # z_2 - z_1, z_2 - z_0, then the start again
    assert X[0, 6].tolist() == [36 - 25, 36 - 16, 36 - 16]  # never into the previous episode
    assert X[0, 9].tolist() == [81 - 64, 81 - 49, 81 - 36]


def test_fit_recovers_the_filter_that_generated_the_velocities(script):
    # velocities that are exactly a two-tap filter of the measurements: the fit must find its taps and no error
    rng = np.random.default_rng(0)
    z = np.cumsum(rng.normal(size=(400, 2)), axis=0)
    starts = [0, 150]
    X = script.differences(z, starts, taps=5)
    truth = [np.array([0.7, 0.2, 0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0, -0.3])]
    qvel = np.stack([X[c] @ w for c, w in enumerate(truth)], axis=1)
    rec = SimpleNamespace(z_measured=z, qvel=qvel, episode_starts=np.array(starts), dt=0.01)
    found = script.fit_taps([rec], taps=5)
    for w, expected in zip(found, truth, strict=True):
        np.testing.assert_allclose(w, expected, atol=1e-10)
    assert script.rmse_of_taps(rec, found, taps=5) < 1e-10
    # the backward difference is the one-tap filter 1/h: its RMSE is the record's backward-difference error
    fd = [np.array([1 / rec.dt, 0.0, 0.0, 0.0, 0.0])] * 2
    errors = np.delete(X[:, :, 0].T / rec.dt - qvel, starts, axis=0)  # every sample but each episode's first
    expected = np.sqrt(np.mean(errors**2))
    assert script.rmse_of_taps(rec, fd, taps=5) == pytest.approx(expected, rel=1e-12)
    assert np.flatnonzero(~script.scored(rec)).tolist() == starts


def test_fit_weighs_each_recording_by_its_backward_difference_error(script):
    """Two recordings of one filter at scales 1 and 100: weighted by their backward-difference errors, the same
    taps fit both; a mis-specified third tap is fitted as the relative errors say, not as the faster record does."""
    rng = np.random.default_rng(1)
    recs = []
    for scale, third in ((1.0, 0.1), (100.0, -0.1)):
        z = scale * np.cumsum(rng.normal(size=(300, 1)), axis=0)
        X = script.differences(z, [0], taps=3)
        qvel = (X[0] @ np.array([0.8, 0.0, third]))[:, None]
        recs.append(SimpleNamespace(z_measured=z, qvel=qvel, episode_starts=np.array([0]), dt=0.01))
    (w,) = script.fit_taps(recs, taps=3)
    # unweighted, the record at scale 100 would decide alone (its squared errors are 1e4 times larger): -0.1
    assert abs(w[2]) < 0.05, w
