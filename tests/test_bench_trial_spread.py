"""``scripts/bench_trial_spread.py``: its episodes of the calibration stream are the wrapper's own trials."""

import gymnasium as gym
import numpy as np
from conftest import load_script

from smo_gym.engine.measurement import mean_velocity_span
from smo_gym.selection import default_observer, trial_errors
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers import estimated_velocity as ev


def test_the_calibration_row_is_the_ratio_auto_chose_on():
    script = load_script("bench_trial_spread")
    env = EstimatedVelocity(gym.make("InvertedPendulum-v5"), sensor="encoder-12bit-noisy", rate="env")
    found = env.observer.selection
    span = mean_velocity_span(env.adapter.model)
    for scenario, smoothing in enumerate(ev.TRIAL_SMOOTHING):
        trials = script.trials(env, ev.CALIBRATION_SEED, smoothing)
        for name in ("kalman-imm", "kalman-ca"):
            measured = trial_errors(default_observer(name, env.calibration), trials, span)
            np.testing.assert_allclose(measured, found.errors[scenario, found.candidates.index(name)], rtol=1e-12)
    other = script.trials(env, 0, ev.TRIAL_SMOOTHING[1])  # another stream: other episodes
    assert not np.array_equal(other.measured[0][:3], trials.measured[0][:3])
    env.close()
