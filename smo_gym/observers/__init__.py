"""Observers: stateful estimators of signals and their derivatives, batched over ``(..., n_channels)``.

Pure NumPy and compiled kernels only: nothing here imports Gymnasium or MuJoCo.
"""

from __future__ import annotations

from .._validation import DivergenceError, check_keywords, did_you_mean
from .base import Observer
from .differentiators import URED, Levant, SuperTwisting, UniformLevant
from .discrete_hosm import DiscreteTimeHOSM
from .ilf import ILFDifferentiator, ILFFixedDifferentiator, ILFObserver
from .linear import FiniteDifference, HighGain, KalmanCA
from .low_power import LowPowerHighGain
from .mechanical import CoordinateTransform, DissipativeSuperTwisting, Dynamics, MechanicalSuperTwisting
from .switched_gain import SwitchedGain

#: name -> class, for the wrapper, the CLI and :func:`smo_gym.differentiate`
OBSERVERS: dict[str, type[Observer]] = {
    cls.name: cls for cls in (SuperTwisting, Levant, URED, UniformLevant, HighGain, FiniteDifference, KalmanCA)
}
OBSERVERS.update({cls.name: cls for cls in (SwitchedGain, LowPowerHighGain)})
OBSERVERS.update({cls.name: cls for cls in (ILFDifferentiator, ILFFixedDifferentiator)})  # ILF observers on chains


@check_keywords
def make_observer(name: str, **params) -> Observer:
    """Build an observer by its short name (``"super-twisting"``, ``"levant"``, ...) with ``params``."""
    if not isinstance(name, str) or name not in OBSERVERS:
        hint = did_you_mean(name, OBSERVERS)
        if isinstance(name, str) and name in MODEL_BASED_OBSERVERS:
            hint = " (a model-based observer: build it with its class and a dynamics object)"
        raise ValueError(f"expected an observer name in {', '.join(sorted(OBSERVERS))}, actual value: {name!r}{hint}")
    return OBSERVERS[name](**params)


#: model-based observers (built with a dynamics object, updated with ``update(y, u)``); not in OBSERVERS
MODEL_BASED_OBSERVERS: dict[str, type[Observer]] = {
    cls.name: cls for cls in (MechanicalSuperTwisting, DissipativeSuperTwisting)
}

__all__ = [
    "MODEL_BASED_OBSERVERS",
    "OBSERVERS",
    "URED",
    "CoordinateTransform",
    "DiscreteTimeHOSM",
    "DissipativeSuperTwisting",
    "DivergenceError",
    "Dynamics",
    "FiniteDifference",
    "HighGain",
    "ILFDifferentiator",
    "ILFFixedDifferentiator",
    "ILFObserver",
    "KalmanCA",
    "Levant",
    "LowPowerHighGain",
    "MechanicalSuperTwisting",
    "Observer",
    "SuperTwisting",
    "SwitchedGain",
    "UniformLevant",
    "make_observer",
]
