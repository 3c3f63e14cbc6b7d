"""Keep numba's on-disk cache honest for functions whose machine code contains code from other modules.

numba keys the cached machine code of a ``cache=True`` function on the source file that defines it (its
modification time and size). A compiled driver that inlines or links a kernel from another module (the wrapper's
fused hot path contains the observer kernels, the sensor chain and the tangent arithmetic) would therefore keep running
the *old* kernel after that other module changed, silently, until its own file changes. :func:`drop_stale` removes
the cache index of such functions when a dependency is newer than it; numba then compiles afresh on the next
call (and caches again).
"""

from __future__ import annotations

import os
import types
from collections.abc import Iterable

__all__ = ["cached_instance", "drop_stale"]


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


def cached_instance(template, label: str, options: dict, dependencies: Iterable[str] = (), **constants):
    """``template`` compiled with ``constants`` bound to its global names, as a function numba caches on disk.

    Why not a closure: numba keys a cached closure on a pickle of its cell contents, and a numba dispatcher pickles
    with a random per-process id, so a factory ``make_driver(kernel)`` returning ``njit(cache=True)(closure)``
    compiled afresh in every new process (measured: a cache miss in each fresh process). Here the constants are
    globals of a copy of ``template`` (same code, its own globals dict); numba reads globals as compile-time
    constants, and caches the copy under its own name ``template[label]`` in ``template``'s file. ``label`` must
    be unique per set of constants (the cache tells copies apart by name only: they share their bytecode).

    Parameters
    ----------
    template : function
        A plain module-level function whose body names ``constants`` as globals.
    label : str
        The copy's name in the cache, e.g. the qualified name of the kernel it calls.
    options : dict
        Options of :func:`numba.njit` (``cache=True`` for an on-disk cache).
    dependencies : iterable of str
        Files whose code the copy inlines (the kernels' modules): a cached copy older than one of them is
        dropped (:func:`drop_stale`), since numba checks ``template``'s own file only.
    **constants
        The global names to bind.
    """
    from numba import njit

    namespace = dict(template.__globals__, **constants)
    fn = types.FunctionType(template.__code__, namespace, template.__name__, template.__defaults__)
    fn.__qualname__ = f"{template.__qualname__}[{label}]"
    fn.__doc__ = template.__doc__
    dispatcher = njit(**options)(fn)
    drop_stale([dispatcher], [template.__code__.co_filename, *dependencies])
    return dispatcher
