#!/usr/bin/env python
"""Write the calibrations shipped with the package: Gymnasium's MuJoCo environments and the dm_control suite tasks
of the benchmarks, with the wrapper's defaults.

For every environment of :data:`ENVS` and both sampling rates, ``EstimatedVelocity(gym.make(env_id), rate=rate)`` (for a
dm_control task what ``make_dm_control(domain, task, rate=rate)`` builds) is built with its defaults (sensor
``encoder-12bit-noisy``, ``observer="auto"``) and ``disk_cache=False`` (so neither the user's cache nor the file being
replaced is read): the calibration rollouts and the trials of ``"auto"`` run, and what they memoized
(:func:`smo_gym._cache.memory_entries`: the calibration levels and the trials' errors, under the same keys the wrapper
looks up) is written to :data:`smo_gym._cache.SHIPPED_FILE`.

A new process then finds these environments calibrated: it skips the rollouts and the trials, and compiling the
candidates the trials run (``scripts/bench_coldstart.py``). The keys hash the model and every setting, so anything
else misses the file and is calibrated as before. Rerun this script after a change to the calibration, the
trials or the candidates of ``"auto"`` (``tests/test_shipped_calibrations.py`` recomputes one environment and
fails on a stale file).

Usage::

    MUJOCO_GL=disable python scripts/ship_calibrations.py [--envs Hopper-v5,...] [--check]

``--check`` writes nothing: it compares the computed entries with the shipped ones and exits 1 on a difference.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")

import gymnasium as gym

from smo_gym import _cache
from smo_gym._extras import progress, require
from smo_gym.wrappers import EstimatedVelocity

ENVS = (
    "Ant-v5",
    "HalfCheetah-v5",
    "Hopper-v5",
    "Humanoid-v5",
    "HumanoidStandup-v5",
    "InvertedDoublePendulum-v5",
    "InvertedPendulum-v5",
    "Pusher-v5",
    "Reacher-v5",
    "Swimmer-v5",
    "Walker2d-v5",
    # the suite tasks of the documentation's dm_control table (shimmy's ids, as make_dm_control builds them)
    "dm_control/acrobot-swingup-v0",
    "dm_control/cartpole-swingup-v0",
    "dm_control/cheetah-run-v0",
    "dm_control/walker-walk-v0",
)
RATES = ("physics", "env")


def computed_entries(envs) -> dict[str, list]:
    """The memoized calibrations of ``envs`` at both rates, computed in this process."""
    if any(env_id.startswith("dm_control/") for env_id in envs):
        require("shimmy", "dm_control")  # registers the dm_control/... ids
    jobs = [(env_id, rate) for env_id in envs for rate in RATES]
    for env_id, rate in progress(jobs, desc="calibrating", unit="env"):
        t0 = time.perf_counter()
        EstimatedVelocity(gym.make(env_id), rate=rate, disk_cache=False).close()
        print(f"  {env_id} rate={rate}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return _cache.memory_entries()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default=",".join(ENVS), help="comma-separated environment ids")
    parser.add_argument("--check", action="store_true", help="compare with the shipped file instead of writing it")
    args = parser.parse_args(argv)
    envs = [e for e in args.envs.split(",") if e]
    entries = computed_entries(envs)
    shipped = json.loads(_cache.SHIPPED_FILE.read_text()) if _cache.SHIPPED_FILE.exists() else {}
    if args.check:
        stale = [k for k, v in entries.items() if k not in shipped or not np.allclose(shipped[k], v, rtol=1e-9)]
        for key in stale:
            print(f"stale or missing: {key}")
        print(f"{len(entries) - len(stale)} of {len(entries)} entries match the shipped file")
        return 1 if stale else 0
    # the entries of the environments not recomputed stay; those of the recomputed ones are replaced
    kept = {k: v for k, v in shipped.items() if k.split(":", 1)[1] not in envs}
    entries = dict(sorted({**kept, **entries}.items()))
    _cache.SHIPPED_FILE.parent.mkdir(parents=True, exist_ok=True)
    lines = ",\n".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in entries.items())  # one entry per line
    _cache.SHIPPED_FILE.write_text("{\n" + lines + "\n}\n")
    size = _cache.SHIPPED_FILE.stat().st_size
    print(f"wrote {len(entries)} entries ({size / 1024:.0f} KiB) to {_cache.SHIPPED_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
