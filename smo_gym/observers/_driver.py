"""``Observer.run`` with a kernel-specific compiled driver (shared by the observers of issue 5).

:func:`smo_gym.observers._kernels.run_offline` receives the kernel as a first-class function argument; numba does
not reuse its on-disk cache for such arguments in a new process and recompiles it (seconds per kernel). An observer
module that defines its own driver (the same loop calling its kernel directly, which caches) runs blocks through
:func:`run_block` instead; the bookkeeping and errors are exactly those of :meth:`Observer.run`.
"""

from __future__ import annotations

import numpy as np


def run_block(observer, Y, driver) -> np.ndarray:
    """Process ``Y`` of shape ``(T, ...)`` with ``driver(state, Y2d, params, out3d) -> (status, t)``."""
    if observer._state is None:
        raise RuntimeError("expected reset(y0) before run(Y), actual value: the observer was never reset")
    Y = np.ascontiguousarray(Y, dtype=np.float64)
    if Y.shape[1:] != observer._shape:
        raise ValueError(f"expected Y with shape (T, *{observer._shape}), actual value: {Y.shape}")
    T = Y.shape[0]
    m = observer.order + 1
    out = np.empty((T,) + observer._estimate.shape)
    if T == 0:
        return out
    status, t = driver(observer._state, Y.reshape(T, -1), observer._params, out.reshape(T, -1, m))
    if status != -1:
        observer._raise_status(status, Y[t])
    observer._estimate = out[-1].copy()
    observer.n_updates += T
    return out
