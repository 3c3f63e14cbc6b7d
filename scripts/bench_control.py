"""Output-feedback control on MuJoCo environments: sliding-mode controllers against the baselines, over seeds.

For each example, every controller is designed by ``smo_gym.control.design`` for the same environment (the same
disturbance bounds, sensor and LQR weights), run from measured positions only under the 12-bit noisy encoder
(4096 counts, 1e-3 rad noise) from the same seeded resets, and summarized by the medians over the seeds of
``closed_loop_metrics``: position error RMS and steady band (max over the second half of the run), control effort
RMS, total variation of the command per second, disturbance-identification RMS (N m or N), observer convergence
time. On the fully actuated arm the computed-torque policy (model-based super-twisting observer, no linearization)
runs too. A second table divides each sliding-mode controller's steady band and effort by the best baseline's.

Examples
--------
- two-link arm (``smo_gym/TwoLinkArm-v0``, 2 ms), torque ``0.5 sin 2t + 0.2`` N m on both joints, regulated
  to the environment's target pose (45 degrees, elbow bent 90 degrees; held horizontal, the shoulder needs 8.3 of its
  10 N m and the noise drives the motors into saturation);
- Furuta pendulum (``smo_gym/FurutaPendulum-v0``, 2 ms), arm torque ``0.04 sin 2.5t + 0.05`` N m, upright;
- inverted double pendulum (``InvertedDoublePendulum-v5``, 10 ms, reset noise 0.02), cart force
  ``2 sin 2t + 1`` N, upright;
- payload: the two-link arm at its target pose, no external torque, the lower link 1.5x heavier from t = 3 s.

Usage: ``python scripts/bench_control.py [--seeds 10] [--seconds 8] [--examples arm,furuta,...]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from smo_gym.experiments.closed_loop import compare_controllers, summarize
from smo_gym.experiments.control import format_table

CONTROLLERS = ("compensation", "ism", "lqr-luenberger", "lqr-kalman", "pid")
ARM_TARGET = [np.pi / 4, -np.pi / 2]
#: name -> (env id, make kwargs, disturbance expression, design kwargs, payload event)
EXAMPLES = {
    "arm": (
        "smo_gym/TwoLinkArm-v0",
        {"frame_skip": 1},
        "0.5*sin(2*t) + 0.2",
        {"disturbance_bound": 0.7, "disturbance_bandwidth": 2.0, "operating_point": ARM_TARGET},
        None,
    ),
    "furuta": (
        "smo_gym/FurutaPendulum-v0",
        {"frame_skip": 1},
        "0.04*sin(2.5*t) + 0.05",
        {"disturbance_bound": 0.09, "disturbance_bandwidth": 2.5},
        None,
    ),
    "double-pendulum": (
        "InvertedDoublePendulum-v5",
        {"frame_skip": 1, "reset_noise_scale": 0.02},
        "2*sin(2*t) + 1",
        {"disturbance_bound": 3.0, "disturbance_bandwidth": 2.0},
        None,
    ),
    "payload": (
        "smo_gym/TwoLinkArm-v0",
        {"frame_skip": 1},
        None,
        {"disturbance_bound": 3.0, "disturbance_bandwidth": 2.0, "operating_point": ARM_TARGET},
        (3.0, "lower", 1.5),
    ),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10, help="seeded runs per controller (default %(default)s)")
    parser.add_argument("--seconds", type=float, default=8.0, help="run length (default %(default)s)")
    parser.add_argument("--examples", default=",".join(EXAMPLES), help="comma-separated (default %(default)s)")
    parser.add_argument("--controllers", default=",".join(CONTROLLERS), help="comma-separated (default all)")
    parser.add_argument("--sensor", default="encoder-12bit-noisy", help="sensor preset (default %(default)s)")
    args = parser.parse_args(argv)
    t0 = time.time()
    for key in args.examples.split(","):
        env_id, env_kwargs, disturbance, design_kwargs, payload = EXAMPLES[key]
        controllers = args.controllers.split(",")
        if env_id == "smo_gym/TwoLinkArm-v0":  # fully actuated: the nonlinear design too
            controllers.append("computed-torque")
        rows, _ = compare_controllers(
            env_id,
            controllers,
            disturbance=disturbance,
            sensor=args.sensor,
            seeds=range(args.seeds),
            t_final=args.seconds,
            env_kwargs=env_kwargs,
            design_kwargs=design_kwargs,
            payload=payload,
            show_progress=True,
        )
        title = f"\n{key}: {env_id}, {args.sensor}, disturbance {disturbance or 'none'}"
        if payload:
            title += f", {payload[1]} mass x{payload[2]} at t = {payload[0]} s"
        print(format_table(rows, f"{title}; medians over {args.seeds} seeds, steady window t >= {args.seconds / 2} s"))
        print(format_table(summarize(rows), "sliding-mode controllers / best baseline (below 1 is better)"))
    print(f"\ndone in {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
