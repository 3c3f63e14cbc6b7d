"""Keep numba's on-disk cache honest for functions that inline code from other modules.

numba keys the cached machine code of a ``cache=True`` function on the source file that defines it (its
modification time and size). A compiled driver that inlines a kernel from another module (the wrapper's fused
hot path inlines the observer kernels, the sensor chain and the tangent arithmetic) would therefore keep running
the *old* kernel after that other module changed, silently, until its own file changes. :func:`drop_stale` removes
the cache index of such functions when a dependency is newer than it; numba then compiles afresh on the next
call (and caches again).
"""

from __future__ import annotations

import os
from collections.abc import Iterable

__all__ = ["drop_stale"]


def drop_stale(dispatchers: Iterable, dependencies: Iterable[str]) -> None:
    """Remove the on-disk cache index of every dispatcher older than the newest of ``dependencies`` (files).

    Best effort: anything unexpected (numba internals, a read-only cache directory) leaves the cache as it is.
    """
    try:
        newest = max(os.path.getmtime(path) for path in dependencies)
    except (OSError, ValueError):
        return
    for dispatcher in dispatchers:
        try:
            index = dispatcher._cache._cache_file._index_path
            if os.path.getmtime(index) < newest:
                os.remove(index)
        except (AttributeError, OSError):
            continue
