"""Output-feedback control experiments of section 6 of Fridman's lecture slides, Sliding Mode Observers.

Prints the tables and writes the plots of :func:`smo_gym.experiments.control.run_all`:

- identification accuracy of the cascaded HOSM observer vs the sampling step (fitted orders vs alpha, alpha + 1)
  and vs the noise level;
- the Furuta pendulum (slides' A, B, D; both angles measured; w(t) = 0.4 sin(2.5 t) + 0.5): LQR with a
  Luenberger observer vs HOSM compensation vs output integral sliding mode (unit vector, super-twisting), exact
  and 12-bit encoders, over a sweep of sampling steps, with the control's total variation per second;
- an unknown actuator lag mu (execution error O(mu)), compensation vs ISM;
- the unmatched case on the slides' three-DOF helicopter: compensation through the sliding surface vs LQR;
- the Furuta pendulum in MuJoCo (``smo_gym/FurutaPendulum-v0``) through ``EstimatedVelocity``.

Usage: ``python scripts/control_experiments.py [--out outputs/control] [--quick] [--no-plots]`` (the same as
``smo-gym control --reproduce``).
"""

from __future__ import annotations

import argparse
import time

from smo_gym.experiments.control import run_all


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="outputs/control", help="directory for the plots (default %(default)s)")
    parser.add_argument("--quick", action="store_true", help="fewer sampling steps and shorter runs")
    parser.add_argument("--no-plots", action="store_true", help="tables only")
    args = parser.parse_args(argv)
    t0 = time.time()
    run_all(args.out, quick=args.quick, plots=not args.no_plots)
    print(f"\ndone in {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
