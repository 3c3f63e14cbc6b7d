#!/usr/bin/env python
r"""How much ``observer="auto"``'s trials can tell two close candidates apart: their error ratio, seed by seed.

``auto`` scores its candidates on the wrapper's trials (the calibration episodes of one seed stream,
``CALIBRATION_SEED``, measured by the wrapper's sensor; :func:`smo_gym.wrappers.estimated_velocity.sensed_trials`)
and takes a candidate on a joint if it is within 2 % of the better reference in every scenario. Whether that
choice holds on other episodes depends on how much the ratio of two candidates' errors moves from one stream of
episodes to the next. This script builds the wrapper for one environment, sensor and rate, and for the calibration
stream and ``--seeds`` others runs the trials' episodes (same policy, same length) through the two candidates
with the wrapper's calibrated gains, printing per joint the RMSE of the first over the second's, then the mean and
standard deviation over the other seeds. The calibration stream's row equals the ratio of the wrapper's own
``observer.selection.errors``; the last row is the bootstrap bound of that ratio
(:func:`smo_gym.selection.ratio_bound`, as ``auto``'s proof rule computes it where the second candidate is the
better reference): a bound that holds its level lies above the other streams' mean on all but a few joints in a
hundred.

Run: ``MUJOCO_GL=disable .venv/bin/python scripts/bench_trial_spread.py`` (Hopper-v5, ideal sensor, env rate,
the IMM estimator over KalmanCA under the low-passed policy; seconds once the wrapper is calibrated).
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("MUJOCO_GL", "disable")

import gymnasium as gym
import numpy as np

from smo_gym.engine.measurement import mean_velocity_span
from smo_gym.selection import CONFIDENCE, Trials, default_observer, measure_on_trials, ratio_bound
from smo_gym.wrappers import EstimatedVelocity
from smo_gym.wrappers import estimated_velocity as ev


def trials(env: EstimatedVelocity, seed: int, smoothing: float) -> Trials:
    """The trials ``auto`` scores on (:func:`~smo_gym.wrappers.estimated_velocity.sensed_trials`, as long), from the
    seed stream ``seed``."""
    every = round(env.measurement.dt / env.adapter.model.opt.timestep)
    steps = ev.TRIAL_STEPS * 2000  # the wrapper's default calibration steps
    return ev.sensed_trials(env.adapter, env.measurement, every, steps, smoothing, seed)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--sensor", default="ideal")
    parser.add_argument("--rate", default="env")
    parser.add_argument("--smoothing", type=float, default=0.9, help="of the trial policy (0: uniform actions)")
    parser.add_argument("--candidates", default="kalman-imm,kalman-ca", help="two specs: the ratio is first/second")
    parser.add_argument("--seeds", default="0,1,2,3,4,5,6,7,100,101,12345,31337,424242,999999,7777777")
    args = parser.parse_args(argv)
    names = args.candidates.split(",")
    if len(names) != 2:
        parser.error("--candidates takes two observer specs")
    env = EstimatedVelocity(gym.make(args.env), sensor=args.sensor, rate=args.rate)
    span = mean_velocity_span(env.adapter.model)
    observers = [default_observer(name, env.calibration) for name in names]
    setting = f"{args.env}, sensor {args.sensor}, rate {args.rate}, smoothing {args.smoothing}"
    print(f"{setting}: RMSE of {names[0]} / {names[1]} per joint on the trials' episodes of each seed stream\n")
    print("| seed | episodes | " + " | ".join(f"joint {j}" for j in range(env.adapter.model.nv)) + " |")
    print("|---|---:|" + "---:|" * env.adapter.model.nv)
    others = []
    for seed in [ev.CALIBRATION_SEED, *map(int, args.seeds.split(","))]:
        found = trials(env, seed, args.smoothing)
        errors = [measure_on_trials(observer, found, span) for observer in observers]
        ratio = errors[0].rmse / errors[1].rmse
        label = "calibration" if seed == ev.CALIBRATION_SEED else str(seed)
        print(f"| {label} | {len(found.measured)} | " + " | ".join(f"{r:.3f}" for r in ratio) + " |")
        if seed == ev.CALIBRATION_SEED:  # what the proof rule saw: the bootstrap bound of that ratio
            bound = ratio_bound(np.stack([e.blocks for e in errors]), refs=[1])[0]
        else:
            others.append(ratio)
    others = np.array(others)
    print("| mean of the others | | " + " | ".join(f"{r:.3f}" for r in others.mean(axis=0)) + " |")
    print("| standard deviation | | " + " | ".join(f"{r:.3f}" for r in others.std(axis=0, ddof=1)) + " |")
    print(f"| calibration's bound ({CONFIDENCE:.1%}) | | " + " | ".join(f"{r:.3f}" for r in bound) + " |")
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
