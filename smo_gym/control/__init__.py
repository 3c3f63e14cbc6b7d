"""Output-feedback control of linear plants with unknown inputs (Fridman's slides, sections 3 and 6).

Disturbance identification with the cascaded HOSM observer, compensation control, output integral sliding mode,
compensation of unmatched disturbances through the sliding surface, and finite-time output-feedback
stabilization with Levant's arbitrary-order sliding-mode controllers (Angulo, Fridman and Levant 2012); plants
from the slides or linearized from MuJoCo models; a sampled-data closed-loop simulator with noise, quantization
and actuator lag.

Pure NumPy/SciPy on top of :mod:`smo_gym.observers`; only :func:`linearize` imports MuJoCo (lazily).
"""

from __future__ import annotations

from .controllers import (
    CompensationController,
    IntegralSlidingModeController,
    StateFeedback,
    UnmatchedCompensationController,
    lqr,
    regular_form,
)
from .estimators import CascadedHOSMObserver, LuenbergerObserver, output_error_lipschitz, sampled_observer_gain
from .finite_time import (
    DEFAULT_BETAS,
    FiniteTimeStabilizer,
    RelativeDegreeError,
    SlidingOutput,
    hosm_control,
    nested_hosm,
    quasi_continuous_hosm,
    settling_time,
    simulate_chain,
    sliding_output,
)
from .plants import (
    LinearPlant,
    MolinariDecoupling,
    NotStronglyObservableError,
    StrongObservabilityReport,
    furuta_disturbance,
    furuta_slides,
    helicopter_slides,
    invariant_zeros,
    left_annihilator,
    linearize,
    molinari_decoupling,
    relative_degrees,
    strong_observability,
)
from .simulation import SimulationResult, fit_order, simulate, steady_state_error, total_variation_rate

__all__ = [
    "DEFAULT_BETAS",
    "CascadedHOSMObserver",
    "CompensationController",
    "FiniteTimeStabilizer",
    "IntegralSlidingModeController",
    "LinearPlant",
    "LuenbergerObserver",
    "MolinariDecoupling",
    "NotStronglyObservableError",
    "RelativeDegreeError",
    "SimulationResult",
    "SlidingOutput",
    "StateFeedback",
    "StrongObservabilityReport",
    "UnmatchedCompensationController",
    "fit_order",
    "furuta_disturbance",
    "furuta_slides",
    "helicopter_slides",
    "hosm_control",
    "invariant_zeros",
    "left_annihilator",
    "linearize",
    "lqr",
    "molinari_decoupling",
    "nested_hosm",
    "output_error_lipschitz",
    "quasi_continuous_hosm",
    "regular_form",
    "relative_degrees",
    "sampled_observer_gain",
    "settling_time",
    "simulate",
    "simulate_chain",
    "sliding_output",
    "steady_state_error",
    "strong_observability",
    "total_variation_rate",
]
