#!/usr/bin/env python
r"""How far ``auto`` is from the best linear filter: causal FIR differentiators fitted to the true velocities.

``scripts/bench_accuracy.py`` compares calibrated observers with each other; this script asks how much any causal
linear time-invariant estimator could do on the same rows, by fitting one to the truth. Per channel, the estimate
from the measurements :math:`z` is

.. math:: \hat v_k = \sum_{j=1}^{L} w_j\,(z_k - z_{k-j}),

(differences of the current sample and the ``L`` before it, so the estimate does not depend on the offset; the
backward difference is :math:`w = (1/h, 0, \dots, 0)`; before the ``j``-th sample of an episode ``z_{k-j}`` is its
first sample), and the taps :math:`w` minimize the squared velocity error on a recorded rollout (least squares:
the Wiener filter of the record, truncated to ``L`` taps; Wiener 1949). Three fits per row:

* **hindsight**: on the evaluated rollout itself. It knows the truth it is scored on, so no causal LTI filter of
  ``L`` taps per channel has a smaller RMSE on that rollout: the limit of the linear filters (Kalman filters,
  alpha-beta trackers and high-gain observers in steady state are linear time-invariant filters of infinite
  impulse response; with 120 taps instead of 40 the hindsight RMSE is 0.5-3 % lower on InvertedDoublePendulum
  and Hopper, so a longer memory buys little);
* **same policy**: on another rollout (another seed) of the evaluated policy: what a filter tuned to the policy's
  motion reaches out of sample;
* **both policies**: on that rollout and one under uniform random actions, the two motions ``auto``'s trials score
  its candidates on (an untrained and a trained agent): one filter for both.

The rows are those of the geometric-mean target of ``bench_accuracy.py``: every Gymnasium task of its table with a
non-ideal sensor at ``rate="physics"``, 400 environment steps of the smooth random policy (smoothing 0.9) from seed
0, recorded and scored as there (``record_rollout``, ``compare_observers``: RMSE over all dofs and every sample but
each episode's first). Numbers are ratios to the backward difference's RMSE; the last line is their geometric
mean.

Run: ``MUJOCO_GL=disable .venv/bin/python scripts/bench_fitted_filter.py`` (about 5 minutes; ``--markdown FILE``
also writes the table).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")

from smo_gym.experiments.compare import compare_observers, record_rollout

ENVS = ("InvertedPendulum-v5", "InvertedDoublePendulum-v5", "Hopper-v5", "HalfCheetah-v5", "Walker2d-v5", "Ant-v5")
SENSORS = ("encoder-12bit", "encoder-12bit-noisy", "low-cost")
#: taps per channel: in hindsight 10 are 1-13 % above 40 and 120 at most 3 % below (and overfit out of sample)
TAPS = 40


def differences(z: np.ndarray, starts, taps: int) -> np.ndarray:
    """``X[c, k, j-1] = z[k, c] - z[max(k - j, a), c]`` for the episode ``[a, b)`` holding ``k``, shape
    ``(channels, T, taps)``; zero at each episode's first sample."""
    T, n = z.shape
    bounds = list(starts) + [T]
    X = np.zeros((n, T, taps))
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        zz = z[a:b]
        for j in range(1, taps + 1):
            X[:, a + j : b, j - 1] = (zz[j:] - zz[:-j]).T
            m = min(j, b - a)
            X[:, a + 1 : a + m, j - 1] = (zz[1:m] - zz[0]).T
    return X


def scored(rec) -> np.ndarray:
    """The samples the RMSE counts: all but each episode's first."""
    mask = np.ones(len(rec.qvel), dtype=bool)
    mask[list(rec.episode_starts)] = False
    return mask


def fit_taps(recordings, taps: int) -> list[np.ndarray]:
    """Least-squares taps per channel over the scored samples of ``recordings`` (same environment and sensor),
    each recording's squared errors divided by the backward difference's mean squared error on it: the motions
    count by their relative error, not by their speed (uniform random actions move the joints faster)."""
    designs = []
    for r in recordings:
        X, mask = differences(r.z_measured, r.episode_starts, taps), scored(r)
        weight = 1.0 / np.sqrt(np.mean((X[:, :, 0].T[mask] / r.dt - r.qvel[mask]) ** 2))
        designs.append((weight * X, mask, weight * r.qvel))
    n = recordings[0].qvel.shape[1]
    found = []
    for c in range(n):
        A = np.vstack([X[c][m] for X, m, _ in designs])
        y = np.concatenate([v[m, c] for _, m, v in designs])
        found.append(np.linalg.lstsq(A, y, rcond=None)[0])
    return found


def rmse_of_taps(rec, weights, taps: int) -> float:
    X = differences(rec.z_measured, rec.episode_starts, taps)
    estimate = np.stack([X[c] @ w for c, w in enumerate(weights)], axis=1)
    mask = scored(rec)
    return float(np.sqrt(np.mean((estimate[mask] - rec.qvel[mask]) ** 2)))


def run(envs, sensors, steps: int, seed: int, smoothing: float, taps: int) -> list[dict]:
    rows = []
    for env_id in envs:
        for sensor in sensors:
            t0 = time.perf_counter()

            def recording(s, smooth, env_id=env_id, sensor=sensor):
                return record_rollout(env_id, sensor=sensor, rate="physics", steps=steps, seed=s, smoothing=smooth)

            test = recording(seed, smoothing)
            same, uniform = recording(seed + 1, smoothing), recording(seed + 2, 0.0)
            found = {r.name: r.rmse for r in compare_observers(test, ["finite-difference", "auto"])}
            row = dict(env=env_id, sensor=sensor, fd=found["finite-difference"], auto=found["auto"])
            row["hindsight"] = rmse_of_taps(test, fit_taps([test], taps), taps)
            row["same policy"] = rmse_of_taps(test, fit_taps([same], taps), taps)
            row["both policies"] = rmse_of_taps(test, fit_taps([same, uniform], taps), taps)
            rows.append(row)
            print(f"  {env_id} {sensor}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return rows


COLUMNS = ("auto", "hindsight", "same policy", "both policies")


def format_table(rows: list[dict], taps: int) -> str:
    lines = [
        f"Velocity RMSE / the backward difference's (FD), rate='physics'; FIR: {taps} taps per channel fitted by "
        "least squares to the true velocities of the rollout named",
        "",
        "| environment | sensor | FD RMSE | auto | FIR, hindsight | FIR, same policy | FIR, both policies |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        ratios = " | ".join(f"{r[c] / r['fd']:.3f}" for c in COLUMNS)
        lines.append(f"| {r['env'].removesuffix('-v5')} | {r['sensor']} | {r['fd']:.3g} | {ratios} |")
    means = " | ".join(f"**{np.exp(np.mean([np.log(r[c] / r['fd']) for r in rows])):.3f}**" for c in COLUMNS)
    lines.append(f"| geometric mean | | | {means} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", default=",".join(ENVS))
    parser.add_argument("--sensors", default=",".join(SENSORS))
    parser.add_argument("--steps", type=int, default=400, help="environment steps per rollout")
    parser.add_argument("--seed", type=int, default=0, help="of the evaluated rollout (the fits use the next two)")
    parser.add_argument("--smoothing", type=float, default=0.9, help="of the evaluated policy (as bench_accuracy.py)")
    parser.add_argument("--taps", type=int, default=TAPS)
    parser.add_argument("--markdown", metavar="FILE", help="also write the table to FILE")
    args = parser.parse_args(argv)
    if args.taps < 1 or args.steps < 1:
        parser.error("--taps and --steps must be positive")
    warnings.filterwarnings("ignore")
    rows = run(args.envs.split(","), args.sensors.split(","), args.steps, args.seed, args.smoothing, args.taps)
    table = format_table(rows, args.taps)
    print(table)
    if args.markdown:
        with open(args.markdown, "w") as f:
            f.write(
                "<!-- results file: copied verbatim from the measured run; regenerate, do not edit by hand -->\n"
                "Produced by `MUJOCO_GL=disable .venv/bin/python scripts/bench_fitted_filter.py --markdown FILE`.\n\n"
                + table
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
