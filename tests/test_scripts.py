"""Every script under ``scripts/`` answers ``--help`` with its usage and does nothing else.

A script that read ``sys.argv`` by hand took ``--help`` for an output folder, wrote its figures into ``./--help``
and ran to the end; one whose argparse spec was inconsistent refused to start (an error only a run shows).
"""

from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "scripts").glob("*.py"))


def _help(script: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "disable", "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, str(script), "--help"], cwd=cwd, env=env, capture_output=True, text=True, timeout=120
    )


def test_every_script_answers_help_without_running(tmp_path):
    assert len(SCRIPTS) > 20
    with ThreadPoolExecutor(max_workers=2) as pool:  # each is a new interpreter importing smo_gym: ~0.5 s
        done = dict(zip(SCRIPTS, pool.map(lambda s: _help(s, tmp_path), SCRIPTS), strict=True))
    failed = {s.name: (r.returncode, r.stdout[-300:] + r.stderr[-300:]) for s, r in done.items() if r.returncode}
    assert not failed
    no_usage = [s.name for s, r in done.items() if not r.stdout.startswith("usage:")]
    assert not no_usage
    assert not list(tmp_path.iterdir())  # nothing written where it ran
