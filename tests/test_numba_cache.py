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
    for driver in _fused.FUSED_DRIVERS.values():
        assert driver._cache._cache_file._index_path.endswith(".nbi")
