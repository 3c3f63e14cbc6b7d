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


def test_the_printed_calibration_row_is_the_ratio_of_the_selection(capsys):
    """``main`` prints, for the calibration stream, the first candidate's RMSE over the second's per joint: the
    ratio of the errors the selection itself recorded (not upside down, not of another scenario)."""
    script = load_script("bench_trial_spread")
    smoothing = ev.TRIAL_SMOOTHING[-1]
    argv = ["--env", "InvertedPendulum-v5", "--sensor", "encoder-12bit-noisy", "--rate", "env"]
    assert script.main([*argv, "--smoothing", str(smoothing), "--seeds", "0,1"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("| calibration |"))
    env = EstimatedVelocity(gym.make("InvertedPendulum-v5"), sensor="encoder-12bit-noisy", rate="env")
    found = env.observer.selection
    scenario = len(ev.TRIAL_SMOOTHING) - 1
    imm, ca = (found.errors[scenario, found.candidates.index(name)] for name in ("kalman-imm", "kalman-ca"))
    assert row.split("|")[3:-1] == [f" {r:.3f} " for r in imm / ca]
    env.close()
