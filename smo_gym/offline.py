"""Offline differentiation of recorded signals with the online observers' recursions."""

from __future__ import annotations

import numpy as np

from ._validation import as_real_array, check_keywords
from .observers import Observer, make_observer

__all__ = ["differentiate"]


@check_keywords
def differentiate(y, dt: float, method: str = "levant", **params) -> np.ndarray:
    """Estimate a recorded signal and its derivatives, sample by sample, causally.

    Parameters
    ----------
    y : array_like, shape (T,) or (T, ...)
        The samples; every trailing index is an independent channel.
    dt : float
        Sampling step.
    method : str
        An observer name of :data:`smo_gym.observers.OBSERVERS` (``"levant"``, ``"super-twisting"``, ...).
    **params
        The observer's parameters (``order``, ``lipschitz``, ``discretization``, ...).

    Returns
    -------
    ndarray, shape (T, ..., order + 1)
        ``out[t, ..., i]`` is the estimate of the ``i``-th derivative at sample ``t``, using samples ``0..t``
        only (the same numbers ``update`` returns online).

    Examples
    --------
    >>> import numpy as np, smo_gym
    >>> t = np.arange(0, 10, 1e-3)
    >>> z = smo_gym.differentiate(np.sin(t), 1e-3, method="levant", order=2, lipschitz=1.0)
    >>> bool(abs(z[-1, 1] - np.cos(t[-1])) < 1e-4)
    True
    """
    y = as_real_array("y", y)
    if y.ndim == 0 or y.shape[0] == 0:
        raise ValueError(f"expected y with shape (T, ...) and T >= 1, actual value: {y.shape}")
    squeeze = y.ndim == 1
    if squeeze:
        y = y[:, None]
    observer = make_observer(method, dt=dt, **params)
    first = observer.reset(y[0])
    out = np.empty((y.shape[0],) + first.shape)
    out[0] = first
    if type(observer).run is Observer.run:
        observer.run(y[1:], out=out[1:])  # written in place: no second copy of a possibly large result
    else:  # a subclass with its own run() allocates its result
        out[1:] = observer.run(y[1:])
    return out[:, 0] if squeeze else out
