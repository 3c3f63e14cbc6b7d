"""smo_gym._numba_cache: cached code of functions that inline other modules is dropped when those change."""

from __future__ import annotations

import os
import types

from smo_gym._numba_cache import drop_stale


def _fake_dispatcher(index_path):
    return types.SimpleNamespace(
        _cache=types.SimpleNamespace(_cache_file=types.SimpleNamespace(_index_path=str(index_path)))
    )


def test_drop_stale_removes_only_indexes_older_than_a_dependency(tmp_path):
    dependency = tmp_path / "kernels.py"
    dependency.write_text("x = 1\n")
    old, new = tmp_path / "old.nbi", tmp_path / "new.nbi"
    old.write_text("")
    new.write_text("")
    t = os.path.getmtime(dependency)
    os.utime(old, (t - 10, t - 10))
    os.utime(new, (t + 10, t + 10))
    drop_stale([_fake_dispatcher(old), _fake_dispatcher(new), object()], [str(dependency)])
    assert not old.exists() and new.exists()


def test_the_fused_drivers_are_checked_against_their_dependencies():
    from smo_gym.engine import fused as _fused

    # every fused driver names a cache index numba would use (the attribute path drop_stale relies on)
    for drivers in _fused.FUSED_DRIVERS.values():
        for driver in drivers:
            assert driver._cache._cache_file._index_path.endswith(".nbi")


def test_a_composite_step_names_the_files_of_its_parts(monkeypatch):
    """The composite's callers (batch kernels, the wrapper's driver) contain its parts' code: their cached code
    must be checked against the parts' modules, not only the composite's."""
    import inspect

    from smo_gym import _numba_cache
    from smo_gym.engine import fused as _fused
    from smo_gym.observers import _kernels, composite, low_power

    step = composite.composite_step([_kernels.kalman_ca, low_power.low_power])
    expected = {inspect.getfile(composite), inspect.getfile(low_power), inspect.getfile(_kernels)}
    assert expected <= set(step.sources)
    checked = []
    monkeypatch.setattr(_numba_cache, "drop_stale", lambda dispatchers, deps: checked.append(set(deps)))
    monkeypatch.setattr(_fused.FUSED_DRIVERS, "_drivers", {})
    _fused.FUSED_DRIVERS[step.kernel]  # builds the two drivers (compiled only when called)
    assert len(checked) == 2 and all(expected <= deps for deps in checked)


_TEMPLATE_MODULE = """
from numba import njit
from smo_gym._numba_cache import cached_instance

_KERNEL = None


@njit(cache=True, inline="always")
def plus_one(x):
    return x + 1.0


@njit(cache=True, inline="always")
def twice(x):
    return 2.0 * x


def _template(a):
    s = 0.0
    for i in range(a.shape[0]):
        s += _KERNEL(a[i])
    return s


drivers = [cached_instance(_template, k.py_func.__name__, dict(cache=True), _KERNEL=k) for k in (plus_one, twice)]
"""

_RUN = """
import numpy as np, generated
a = np.arange(3.0)
print([d(a) for d in generated.drivers], [sum(d.stats.cache_hits.values()) for d in generated.drivers])
"""


def test_cached_instances_are_reused_by_a_new_process(tmp_path):
    """Each copy of a template, bound to its own kernel, computes with that kernel and is loaded from numba's disk
    cache by a second process (a closure over the kernel would compile again: its cache key pickles the kernel's
    per-process id)."""
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "generated.py").write_text(_TEMPLATE_MODULE)
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), root]), "NUMBA_CACHE_DIR": str(tmp_path / "c")}
    runs = [
        subprocess.run([sys.executable, "-c", _RUN], env=env, capture_output=True, text=True, check=True).stdout
        for _ in range(2)
    ]
    assert runs[0].strip() == "[6.0, 6.0] [0, 0]"  # 1 + 2 + 3 and 2 * (0 + 1 + 2), compiled
    assert runs[1].strip() == "[6.0, 6.0] [1, 1]"  # the same, both from the cache


def test_every_registered_step_and_fused_driver_is_cached_on_disk():
    from smo_gym.engine import fused as _fused
    from smo_gym.observers import _kernels as K

    for step in K.STEPS.values():
        drivers = (step.run, step.run_wrapped, step.shared_run, step.shared_run_wrapped)
        for f in (step.kernel, step.shared_kernel, *drivers, *_fused.FUSED_DRIVERS[step.kernel]):
            assert f._cache._cache_file._index_path.endswith(".nbi")
            assert step.label in f.py_func.__qualname__


_IMM_RUN = """
import os, sys
import numpy as np
from smo_gym.observers import KalmanIMM, imm
if sys.argv[1] == "compile":
    obs = KalmanIMM(0.01, 50.0, 1e-6, huber=3.0)
    obs.reset(np.zeros(1))
    obs.update(np.ones(1))
for f in (imm._mode_update, imm.imm_ca_step, imm.imm_ca_rows):
    print(int(os.path.exists(f._cache._cache_file._index_path)), end=" ")
"""


def test_the_imm_helpers_are_dropped_when_the_filter_halves_change(tmp_path):
    """The IMM step and its mode update are cached in ``imm.py`` and link the Kalman filter's halves from
    ``_kernels.py``: a cache older than ``_kernels.py`` must be dropped for all three cached functions, not only
    the row kernel: ``register_step``'s ``helpers`` (a stale mode update once kept an old rule of Huber's update
    after ``_kernels.py`` changed)."""
    import subprocess
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": root, "NUMBA_CACHE_DIR": str(tmp_path)}

    def run(mode):
        command = [sys.executable, "-c", _IMM_RUN, mode]
        return subprocess.run(command, env=env, capture_output=True, text=True, check=True)

    assert run("compile").stdout.split() == ["1", "1", "1"]  # compiled and cached
    from smo_gym.observers import _kernels

    past = os.path.getmtime(_kernels.__file__) - 3600.0  # the cache older than the filter halves
    for index in tmp_path.rglob("*.nbi"):
        os.utime(index, (past, past))
    assert run("look").stdout.split() == ["0", "0", "0"]  # all three dropped at import
