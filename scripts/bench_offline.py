"""Offline throughput: ``Observer.run`` and ``smo_gym.differentiate`` against a loop of ``update`` and ``np.diff``.

For each shape of a recorded signal ``Y`` (time first), prints the throughput in millions of channel-samples per
second (``Y.size / seconds``) of

* ``run``: ``observer.reset(Y[0]); observer.run(Y[1:])`` (the estimates allocated by ``run``),
* ``run, out=``: the same into a preallocated output array (``run(Y[1:], out=...)``, the array reused): without
  the page faults of a fresh result, which cost about as much as the recursion on the long record,
* ``update loop``: ``observer.reset(Y[0])`` and one ``observer.update(Y[t])`` per sample (on the first
  ``--loop-samples`` samples only for long records: the rate per sample does not depend on the length), the
  estimates dropped,
* ``loop, kept``: the same loop keeping every estimate in an array allocated for them, as ``run`` returns them
  (``out[t] = observer.update(Y[t])``): the work ``run`` does, written in Python,
* ``differentiate``: ``smo_gym.differentiate(Y, dt, observer=..., lipschitz=...)`` (given gains: no calibration),
* ``np.diff``: ``np.diff(Y, axis=0)``, the memory-bound reference of a first difference,
* ``hand loop`` (super-twisting only): :func:`hand_loop`, the implicit super-twisting recursion written here as the
  plainest compiled loop (scalar gains, time outer and channels inner, one finiteness flag per sample, a fresh
  output): what compiled code of this step reaches on this machine with no engine around it,

and the ratios ``run / update loop``, ``run / loop, kept`` and ``differentiate / np.diff``. The default observer is
the default family of the wrapper, :class:`smo_gym.observers.SuperTwisting` with its default discretization
(``"implicit"``).

Timing: the median over ``--repeats`` runs (after one warm-up run, which also compiles), of the process CPU time by
default (the code is single-threaded; CPU time is what a shared machine disturbs least), or of wall-clock time with
``--wall``.

Usage::

    MUJOCO_GL=disable python scripts/bench_offline.py [--repeats 5] [--observer super-twisting] [--wall]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np
from numba import njit

import smo_gym
from smo_gym.design.gains import super_twisting_gains
from smo_gym.observers import make_observer

SHAPES = ((1_000_000, 8), (1000, 4096, 8))


def _seconds(f, repeats: int, clock) -> float:
    f()  # warm-up (compiles on the first call)
    times = []
    for _ in range(repeats):
        t0 = clock()
        f()
        times.append(clock() - t0)
    return statistics.median(times)


def _signal(shape, dt: float) -> np.ndarray:
    """Smooth signals with small noise, one per channel, time first (a random walk of the acceleration)."""
    rng = np.random.default_rng(0)
    t = np.arange(shape[0])[(slice(None),) + (None,) * (len(shape) - 1)] * dt
    phase = rng.uniform(0, 2 * np.pi, shape[1:])
    return np.sin(t + phase) + 1e-4 * rng.standard_normal(shape)


@njit(error_model="numpy")
def hand_loop(x0: np.ndarray, Y: np.ndarray, dt: float, k1: float, k2: float) -> np.ndarray:
    """The implicit super-twisting recursion (``SuperTwisting``'s closed form) on ``Y`` (T, N) from the values
    ``x0`` (N,) at zero velocity, written as a bare loop; returns the estimates (T, N, 2), or stops at a non-finite
    sample."""
    T, N = Y.shape
    out = np.empty((T, N, 2))
    x = x0.copy()
    v = np.zeros(N)
    thr, b = dt * dt * k2, dt * k1
    for t in range(T):
        bad = False
        for c in range(N):
            y = Y[t, c]
            w = y - x[c] - dt * v[c]
            stick = abs(w) <= thr
            a = 0.0 if stick else abs(w) - thr
            r = 2.0 * a / (b + math.sqrt(b * b + 4.0 * a))
            sign = 1.0 if w > 0.0 else -1.0
            x[c] = y - (0.0 if stick else sign * r * r)
            v[c] += dt * k2 * (w / thr if stick else sign)
            out[t, c, 0] = x[c]
            out[t, c, 1] = v[c]
            bad |= not (math.isfinite(x[c]) & math.isfinite(v[c]) & math.isfinite(w))
        if bad:
            return out[:t]
    return out


def bench(shape, observer: str, dt: float, lipschitz: float, repeats: int, loop_samples: int, clock) -> dict:
    Y = _signal(shape, dt)
    obs = make_observer(observer, dt=dt, lipschitz=lipschitz)
    n = Y.size

    def run():
        obs.reset(Y[0])
        obs.run(Y[1:])

    reused = np.empty((Y.shape[0] - 1, *Y.shape[1:], 2))

    def run_into():
        obs.reset(Y[0])
        obs.run(Y[1:], out=reused)

    flat = Y.reshape(Y.shape[0], -1)
    k1, k2 = super_twisting_gains(lipschitz)

    def hand():
        hand_loop(flat[0], flat[1:], dt, k1, k2)

    Yl = Y[: min(loop_samples, Y.shape[0])]

    def loop():
        obs.reset(Yl[0])
        for t in range(1, Yl.shape[0]):
            obs.update(Yl[t])

    def kept():
        obs.reset(Yl[0])
        out = np.empty((Yl.shape[0] - 1,) + obs.estimate.shape)
        for t in range(1, Yl.shape[0]):
            out[t - 1] = obs.update(Yl[t])

    def differentiate():
        smo_gym.differentiate(Y, dt, observer=observer, lipschitz=lipschitz)

    def diff():
        np.diff(Y, axis=0)

    rates = {
        "run": n / _seconds(run, repeats, clock),
        "run, out=": n / _seconds(run_into, repeats, clock),
        "update loop": Yl.size / _seconds(loop, max(1, repeats // 2), clock),
        "loop, kept": Yl.size / _seconds(kept, max(1, repeats // 2), clock),
        "differentiate": n / _seconds(differentiate, repeats, clock),
        "np.diff": n / _seconds(diff, repeats, clock),
    }
    if observer == "super-twisting" and obs.discretization == "implicit":
        rates["hand loop"] = n / _seconds(hand, repeats, clock)
    return {k: v / 1e6 for k, v in rates.items()}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--observer", default="super-twisting")
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--lipschitz", type=float, default=50.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--loop-samples", type=int, default=20_000)
    parser.add_argument("--wall", action="store_true", help="wall-clock time instead of process CPU time")
    args = parser.parse_args(argv)
    clock = time.perf_counter if args.wall else time.process_time
    print(
        f"{args.observer} (dt={args.dt}, lipschitz={args.lipschitz}), M channel-samples/s, median of "
        f"{args.repeats} ({'wall' if args.wall else 'CPU'} time)"
    )
    rates = ("run", "run, out=", "update loop", "loop, kept", "differentiate", "np.diff", "hand loop")
    header = ("shape", *rates, "run/loop", "run/kept", "diff./np.diff")
    print(f"{header[0]:>16s} " + " ".join(f"{h:>13s}" for h in header[1:]))
    for shape in SHAPES:
        r = bench(shape, args.observer, args.dt, args.lipschitz, args.repeats, args.loop_samples, clock)
        ratios = (r["run"] / r["update loop"], r["run"] / r["loop, kept"], r["differentiate"] / r["np.diff"])
        cells = [f"{r[k]:13.1f}" if k in r else f"{'-':>13s}" for k in rates] + [f"{v:13.2f}" for v in ratios]
        print(f"{shape!s:>16s} " + " ".join(cells))


if __name__ == "__main__":
    main()
