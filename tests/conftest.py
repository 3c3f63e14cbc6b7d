"""Shared test signal and helpers for the observer tests.

The reference signal of the acceptance tests is :math:`f(t) = \\sin t + \\tfrac12\\cos 2t`, whose derivatives are
known in closed form:

.. math:: f^{(i)}(t) = \\sin(t + i\\pi/2) + \\tfrac12\\,2^i\\cos(2t + i\\pi/2),

so :math:`|f^{(i)}| \\le 1 + 2^{i-1}`: ``|f''| <= 3``, ``|f'''| <= 5``, ``|f''''| <= 9``.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
from pathlib import Path

import mujoco
import numpy as np
import pytest

from smo_gym.observers import FiniteDifference

#: the repository root
ROOT = Path(__file__).resolve().parents[1]


def load_script(name: str):
    """The module of ``scripts/<name>.py``, loaded by path (the scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@contextlib.contextmanager
def _environment_variable(name: str, value: str):
    """``os.environ[name] = value`` within the block (subprocesses inherit it), the previous state restored."""
    previous = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = previous


@pytest.fixture(autouse=True, scope="session")
def _sb3_log_directory(tmp_path_factory):
    """SB3 makes a new ``/tmp/SB3-<date-time>`` directory at every ``learn`` without a log folder (hundreds per
    run of this suite): point it at one temporary directory of the session instead."""
    with _environment_variable("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs"))):
        yield


#: sup |f^(i)| of the reference signal, i = 0..5 (triangle inequality bound 1 + 2^(i-1))
DERIVATIVE_BOUNDS = tuple(1.0 + 0.5 * 2.0**i for i in range(6))


def signal_derivatives(t, n: int) -> np.ndarray:
    """``(f, f', ..., f^(n-1))`` of ``f(t) = sin t + 0.5 cos 2t``; shape ``t.shape + (n,)``."""
    t = np.asarray(t, dtype=float)
    return np.stack(
        [np.sin(t + i * np.pi / 2) + 0.5 * 2.0**i * np.cos(2 * t + i * np.pi / 2) for i in range(n)], axis=-1
    )


def signal(t) -> np.ndarray:
    """``f(t) = sin t + 0.5 cos 2t``."""
    return signal_derivatives(t, 1)[..., 0]


def estimates_of(observer, Y: np.ndarray) -> np.ndarray:
    """Reset ``observer`` at ``Y[0]`` and run it over ``Y``; returns all estimates ``(T, ..., order + 1)``.

    Row ``t`` is the estimate at sample ``t`` (row 0 the reset estimate), as ``smo_gym.differentiate`` returns.
    """
    first = observer.reset(Y[0])
    return np.concatenate([first[None], observer.run(Y[1:])], axis=0)


def loglog_slope(x, y) -> float:
    """Least-squares slope of ``log y`` against ``log x``."""
    return float(np.polyfit(np.log(np.asarray(x, float)), np.log(np.asarray(y, float)), 1)[0])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20260522)


@pytest.fixture(scope="module")
def private_calibration_cache(tmp_path_factory):
    """Calibrations go to a temporary cache (inherited by vector-env subprocesses), not the user's."""
    with _environment_variable("SMO_GYM_CACHE_DIR", str(tmp_path_factory.mktemp("smo_cache"))):
        yield


class UnregisteredFiniteDifference(FiniteDifference):
    """A subclass of a registered family: a family of its own, whose Python could differ from the family's compiled
    step, so the compiled paths (composites, the wrapper's one-call path, batched vector steps) must not take it."""


def smooth_actions(space, n: int, seed: int) -> list:
    """A seeded smooth random policy (low-pass filtered uniform noise), so that episodes last."""
    rng = np.random.default_rng(seed)
    a = np.zeros(space.shape)
    acts = []
    for _ in range(n):
        a = 0.9 * a + 0.1 * rng.uniform(space.low, space.high)
        acts.append(a.astype(space.dtype))
    return acts


def full_forward_observation(env, qpos, qvel):
    """The environment's observation at ``(qpos, qvel)`` with every controller input of the live data, after a
    full ``mj_forward`` on fresh data, contact forces from the live data (``contact_forces="sensor"``): what the
    adapter's probed shortcuts must reproduce."""
    u = env.unwrapped
    model, live = u.model, u.data
    scratch = mujoco.MjData(model)
    scratch.time = live.time
    for name in ("ctrl", "act", "mocap_pos", "mocap_quat", "qfrc_applied", "xfrc_applied", "userdata", "eq_active"):
        getattr(scratch, name)[:] = getattr(live, name)
    scratch.qpos[:] = qpos
    scratch.qvel[:] = qvel
    mujoco.mj_forward(model, scratch)
    scratch.cfrc_ext[:] = live.cfrc_ext
    u.data = scratch
    try:
        return np.array(type(u)._get_obs(u))
    finally:
        u.data = live
