"""Observers: stateful estimators of signals and their derivatives, batched over ``(..., n_channels)``.

Pure NumPy and compiled kernels only: nothing here imports Gymnasium or MuJoCo. Every family registers itself
(:func:`register_observer`); importing this package imports each of its modules, so a family defined in a new
module of the package is registered without an import here.
"""

from __future__ import annotations

import importlib
import pkgutil

from .._validation import DivergenceError, check_keywords, did_you_mean
from .alpha_beta import AlphaBeta
from .base import Observer
from .composite import PerChannel
from .differentiators import URED, Levant, SuperTwisting, UniformLevant
from .discrete_hosm import DiscreteTimeHOSM
from .filtering import FilteringDifferentiator
from .ilf import ILFDifferentiator, ILFFixedDifferentiator, ILFObserver
from .imm import KalmanIMM
from .input_kalman import KalmanCAInput, KalmanIMMInput, PerChannelInput, fit_input_jumps
from .linear import FiniteDifference, HighGain, KalmanCA
from .low_power import LowPowerHighGain
from .mechanical import CoordinateTransform, DissipativeSuperTwisting, Dynamics, MechanicalSuperTwisting
from .registry import FAMILIES, MODEL_BASED_OBSERVERS, OBSERVERS, Family, family_of, register_observer
from .switched_gain import SwitchedGain
from .worst_case import WorstCaseOptimal

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")


@check_keywords
def make_observer(name: str, **params) -> Observer:
    """Build an observer by its short name (``"super-twisting"``, ``"levant"``, ...) with ``params``."""
    if not isinstance(name, str) or name not in OBSERVERS:
        hint = did_you_mean(name, OBSERVERS)
        if isinstance(name, str) and name in MODEL_BASED_OBSERVERS:
            hint = " (a model-based observer: build it with its class and a model or an input gain)"
        raise ValueError(f"expected an observer name in {', '.join(sorted(OBSERVERS))}, actual value: {name!r}{hint}")
    return OBSERVERS[name](**params)


__all__ = [
    "FAMILIES",
    "MODEL_BASED_OBSERVERS",
    "OBSERVERS",
    "URED",
    "AlphaBeta",
    "CoordinateTransform",
    "DiscreteTimeHOSM",
    "DissipativeSuperTwisting",
    "DivergenceError",
    "Dynamics",
    "Family",
    "FilteringDifferentiator",
    "FiniteDifference",
    "HighGain",
    "ILFDifferentiator",
    "ILFFixedDifferentiator",
    "ILFObserver",
    "KalmanCA",
    "KalmanCAInput",
    "KalmanIMM",
    "KalmanIMMInput",
    "Levant",
    "LowPowerHighGain",
    "MechanicalSuperTwisting",
    "Observer",
    "PerChannel",
    "PerChannelInput",
    "SuperTwisting",
    "SwitchedGain",
    "UniformLevant",
    "WorstCaseOptimal",
    "family_of",
    "fit_input_jumps",
    "make_observer",
    "register_observer",
]
