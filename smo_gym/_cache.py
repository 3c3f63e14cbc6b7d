"""Memoized calibrations: cache keys that are the same in every process, kept in memory and in a JSON file.

The file is ``$SMO_GYM_CACHE_DIR/calibration.json`` (default ``~/.cache/smo_gym``); a read-only home is not an error,
the memory cache still works. Below the user's file lies a read-only one shipped with the package
(:data:`SHIPPED_FILE`): the calibrations of Gymnasium's MuJoCo environments and four dm_control suite tasks with the
wrapper's defaults, written by ``scripts/ship_calibrations.py``. The keys are the same (they hash the model itself and
every setting), so an environment, model, sensor or setting of its own simply misses it and is calibrated as before; a
hit spares a new process the calibration rollouts, the trials of ``observer="auto"`` and compiling the candidates it
tries.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import tempfile
from pathlib import Path

import mujoco
import numpy as np

__all__ = ["SHIPPED_FILE", "cached_bounds", "calibration_key", "memory_entries", "stable_repr"]

_MEMORY_CACHE: dict[str, list[float]] = {}
#: the calibrations shipped with the package (read-only; see the module docstring)
SHIPPED_FILE = Path(__file__).parent / "data" / "calibrations.json"


def _cache_file() -> Path:
    root = os.environ.get("SMO_GYM_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "smo_gym"
    )
    return Path(root) / "calibration.json"


@functools.cache
def _shipped() -> dict[str, list]:
    try:
        return json.loads(SHIPPED_FILE.read_text())
    except (OSError, ValueError):  # an install without the data file calibrates as before
        return {}


def cached_bounds(key: str, compute, *, disk: bool = True) -> np.ndarray:
    """``compute()`` memoized under ``key`` in memory and (``disk=True``) in the user cache file, which falls back
    on the calibrations shipped with the package (:data:`SHIPPED_FILE`) before computing."""
    if key in _MEMORY_CACHE:
        return np.array(_MEMORY_CACHE[key])
    path = _cache_file()
    if disk:
        try:
            stored = json.loads(path.read_text())
            if key in stored:
                _MEMORY_CACHE[key] = stored[key]
                return np.array(stored[key])
        except (OSError, ValueError):
            pass
        if key in _shipped():
            _MEMORY_CACHE[key] = _shipped()[key]
            return np.array(_MEMORY_CACHE[key])
    value = np.asarray(compute(), dtype=float)
    _MEMORY_CACHE[key] = value.tolist()
    if disk:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            try:
                stored = json.loads(path.read_text())
            except (OSError, ValueError):
                stored = {}
            stored[key] = value.tolist()
            fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
            with os.fdopen(fd, "w") as fh:
                json.dump(stored, fh)
            os.replace(tmp, path)
        except OSError:  # a read-only home is not an error: the memory cache still works
            pass
    return value


def memory_entries() -> dict[str, list]:
    """A copy of what this process has memoized, by key (what ``scripts/ship_calibrations.py`` ships)."""
    return {key: list(value) for key, value in _MEMORY_CACHE.items()}


def calibration_key(env_key: str, model: mujoco.MjModel, **settings) -> str:
    """Cache key: the environment's identity, the model itself and the calibration settings.

    The model enters by a hash of its binary form (``mj_saveModel``): a model edited in place (masses, the
    timestep) gets a calibration of its own, and the key is the same in every process.
    """
    buffer = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    text = json.dumps([env_key, hashlib.sha1(buffer.tobytes()).hexdigest(), sorted(settings.items())], default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:16] + ":" + env_key


#: `` at 0x7f...``: the address in a default ``repr``, different in every process
_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")


def stable_repr(value) -> str:
    """A text for ``value`` that is the same in every process (for cache keys).

    Functions are named by module and qualified name plus a hash of their code, constants, defaults, closure
    values and the module-level numbers, strings and arrays they read, so two different lambdas differ and the
    same one agrees across processes; arrays by a hash of their bytes; containers element by element; anything
    else by its ``repr`` without memory addresses.
    """
    if isinstance(value, dict):
        return "{" + ", ".join(f"{stable_repr(k)}: {stable_repr(v)}" for k, v in sorted(value.items(), key=str)) + "}"
    if isinstance(value, (list, tuple)):
        return type(value).__name__ + "(" + ", ".join(stable_repr(v) for v in value) + ")"
    if isinstance(value, np.ndarray):
        return f"array{value.shape}:{hashlib.sha1(np.ascontiguousarray(value).tobytes()).hexdigest()[:12]}"
    code = getattr(value, "__code__", None)
    if code is not None:
        closure = [cell.cell_contents for cell in (value.__closure__ or ())]
        # module-level numbers, strings and arrays the function reads (modules and functions by name only)
        names = getattr(value, "__globals__", {})
        data = {
            name: names[name]
            for name in code.co_names
            if isinstance(names.get(name), (bool, int, float, complex, str, np.ndarray, np.number))
        }
        parts = [
            code.co_code.hex(),
            stable_repr(list(code.co_consts)),
            stable_repr(list(value.__defaults__ or ())),
            stable_repr(closure),
            stable_repr(data),
        ]
        digest = hashlib.sha1("|".join(parts).encode()).hexdigest()[:12]
        return f"{getattr(value, '__module__', '')}.{getattr(value, '__qualname__', '')}:{digest}"
    return _ADDRESS.sub("", repr(value))
