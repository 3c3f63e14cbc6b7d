"""Observers and output-feedback control of linear plants with unknown inputs (Fridman's slides, sections 1, 3, 6).

Conventional sliding-mode observers (Utkin, Drakunov's step-by-step, Walcott-Zak) and the unknown-input observer
without differentiation (Darouach et al. 1994); disturbance identification with the cascaded HOSM observer,
compensation control, output integral sliding mode,
and compensation of unmatched disturbances through the sliding surface; plants from the slides or linearized
from MuJoCo models; a sampled-data closed-loop simulator with noise, quantization and actuator lag.

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
from .conventional import (
    ObservableBlockForm,
    StepByStepObserver,
    UnknownInputConditionError,
    UnknownInputConditions,
    UnknownInputObserver,
    UtkinObserver,
    WalcottZakDesign,
    WalcottZakObserver,
    certify_walcott_zak,
    observable_block_form,
    output_coordinate_change,
    unknown_input_conditions,
    walcott_zak_design,
)
from .estimators import CascadedHOSMObserver, LuenbergerObserver, output_error_lipschitz, sampled_observer_gain
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
    "CascadedHOSMObserver",
    "CompensationController",
    "IntegralSlidingModeController",
    "LinearPlant",
    "LuenbergerObserver",
    "MolinariDecoupling",
    "NotStronglyObservableError",
    "ObservableBlockForm",
    "SimulationResult",
    "StateFeedback",
    "StepByStepObserver",
    "StrongObservabilityReport",
    "UnknownInputConditionError",
    "UnknownInputConditions",
    "UnknownInputObserver",
    "UnmatchedCompensationController",
    "UtkinObserver",
    "WalcottZakDesign",
    "WalcottZakObserver",
    "certify_walcott_zak",
    "fit_order",
    "furuta_disturbance",
    "furuta_slides",
    "helicopter_slides",
    "invariant_zeros",
    "left_annihilator",
    "linearize",
    "lqr",
    "molinari_decoupling",
    "observable_block_form",
    "output_coordinate_change",
    "output_error_lipschitz",
    "regular_form",
    "relative_degrees",
    "sampled_observer_gain",
    "simulate",
    "steady_state_error",
    "strong_observability",
    "total_variation_rate",
    "unknown_input_conditions",
    "walcott_zak_design",
]
