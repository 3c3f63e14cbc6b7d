"""Cold and warm start of the default wrapper path: the first ``reset`` and ``step`` of a new process.

Measures, in fresh Python processes,

    env = EstimatedVelocity(gym.make("Hopper-v5")); env.reset(seed=0); env.step(a)

from ``import smo_gym`` to the end of the first step, three times per repeat: *cold* with empty numba and smo_gym
caches (fresh ``NUMBA_CACHE_DIR`` and ``SMO_GYM_CACHE_DIR``: everything compiles; the calibration is the one
shipped with the package, :data:`smo_gym._cache.SHIPPED_FILE`), *cold, not shipped* the same without the shipped
file (what an environment, model, sensor or setting of one's own pays: the calibration rollouts and the trials of
``observer="auto"`` run and compile their candidates), then *warm* in a process on the caches the first one filled.
Prints the median over the repeats.

The table also gives the time spent in numba compilations (numba's ``numba:compile`` events, nested ones counted
once) and their number (none in a warm process: numba loads cached code without a compile event).
``--compiles`` lists, for one cold process, every compilation with its duration (nested compilations included in
their caller's time), longest first: what a cold start pays for.

Usage::

    MUJOCO_GL=disable python scripts/bench_coldstart.py [--repeats 3] [--env Hopper-v5] [--compiles]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
compiles = []
depth = [0]
from numba.core import event


class _Compiles(event.Listener):
    def on_start(self, ev):
        ev.data["_t0"] = time.perf_counter()
        depth[0] += 1

    def on_end(self, ev):
        depth[0] -= 1
        d = ev.data["dispatcher"]
        name = getattr(d, "py_func", d).__qualname__
        compiles.append((time.perf_counter() - ev.data["_t0"], getattr(d, "py_func", d).__module__, name,
                         str(ev.data["args"]), depth[0]))


event.register("numba:compile", _Compiles())
import gymnasium as gym
import numpy as np
import smo_gym  # noqa: F401
from smo_gym import _cache
from smo_gym.wrappers import EstimatedVelocity
if {hide_shipped!r}:  # as an install without the shipped calibrations
    _cache.SHIPPED_FILE = _cache.SHIPPED_FILE.with_name("not-shipped.json")
t_import = time.perf_counter()
env = EstimatedVelocity(gym.make({env!r}))
env.reset(seed=0)
t_reset = time.perf_counter()
env.step(np.zeros(env.action_space.shape, dtype=env.action_space.dtype))
t_step = time.perf_counter()
compiles.sort(reverse=True)
print(json.dumps(dict(total=t_step - t0, imports=t_import - t0, reset=t_reset - t_import, step=t_step - t_reset,
                      compile=sum(c[0] for c in compiles if c[4] == 0), n_compiles=len(compiles),
                      compiles=compiles)))
"""


def _one(env_id: str, numba_dir: str, smo_dir: str, hide_shipped: bool = False) -> dict:
    environ = dict(os.environ, NUMBA_CACHE_DIR=numba_dir, SMO_GYM_CACHE_DIR=smo_dir)
    environ.setdefault("MUJOCO_GL", "disable")
    code = CHILD.format(env=env_id, hide_shipped=hide_shipped)
    proc = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"the child process failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--compiles", action="store_true", help="list the compilations of one cold start")
    parser.add_argument("--not-shipped", action="store_true", help="with --compiles: without the shipped file")
    args = parser.parse_args(argv)
    if args.compiles:
        with tempfile.TemporaryDirectory() as numba_dir, tempfile.TemporaryDirectory() as smo_dir:
            result = _one(args.env, numba_dir, smo_dir, args.not_shipped)
        print(f"cold start {result['total']:.2f} s; numba compilations (s, module, function, argument types):")
        for seconds, module, name, types, _ in result["compiles"]:
            print(f"{seconds:8.2f}  {module}.{name}  {types[:100]}")
        return
    cold, unshipped, warm = [], [], []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as numba_dir, tempfile.TemporaryDirectory() as smo_dir:
            cold.append(_one(args.env, numba_dir, smo_dir))
            warm.append(_one(args.env, numba_dir, smo_dir))
        with tempfile.TemporaryDirectory() as numba_dir, tempfile.TemporaryDirectory() as smo_dir:
            unshipped.append(_one(args.env, numba_dir, smo_dir, hide_shipped=True))
    print(f"{args.env}: EstimatedVelocity, first reset(seed=0) + step, median of {args.repeats} fresh processes")
    head = f"{'':18s} {'total s':>8s} {'imports':>8s} {'reset':>8s} {'step':>8s} {'compile':>8s} {'compilations':>12s}"
    print(head)
    for name, runs in (("cold", cold), ("cold, not shipped", unshipped), ("warm", warm)):
        row = [statistics.median(r[k] for r in runs) for k in ("total", "imports", "reset", "step", "compile")]
        count = statistics.median(r["n_compiles"] for r in runs)
        print(f"{name:18s} " + " ".join(f"{v:8.2f}" for v in row) + f" {count:12.0f}")
    print(f"(started {time.strftime('%Y-%m-%d %H:%M')}, python {sys.version.split()[0]})")


if __name__ == "__main__":
    main()
