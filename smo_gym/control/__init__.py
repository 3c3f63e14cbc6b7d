"""Observers and output-feedback control of linear plants with unknown inputs (Fridman's slides, sections 1, 3, 6, 7).

Conventional sliding-mode observers (Utkin, Drakunov's step-by-step, Walcott-Zak) and the unknown-input observer
without differentiation (Darouach, Zasadzinski and Xu 1994); disturbance identification with the cascaded HOSM
observer, compensation control, output integral sliding mode, compensation of unmatched disturbances through the
sliding surface, and finite-time output-feedback stabilization with Levant's arbitrary-order sliding-mode
controllers (Angulo, Fridman and Levant 2012); observers beyond strong observability (strongly detectable plants,
functional observers, static left inverses); for linear time-varying plants, Kratz and Liebscher's
strong-observability test and the cascaded HOSM observer of Galvan-Guerra, Fridman and Davila (2017); for linear
switched systems (section 10), the bank of cascaded HOSM observers estimating the continuous state and the mode.
For fully actuated MuJoCo mechanisms, without linearization: computed torque with the model-based super-twisting
observer's identification and compensation of the external torques, optionally with output integral sliding mode
(:class:`ComputedTorquePolicy`, an output-feedback policy on a sensed environment).
Plants come from the slides or are linearized from MuJoCo models; a sampled-data closed-loop simulator adds noise,
quantization and actuator lag. The baselines a control engineer would reach for first live here too: LQR with a
steady-state Kalman filter (:class:`KalmanObserver` in :class:`StateFeedback`) and a matrix PID on finite-difference
velocities with LQI gains (:class:`PIDController`).

On a MuJoCo environment, :func:`design` goes from the environment to an output-feedback policy in one call
(equilibrium, linearization, strong-observability check, sampled LQR, observer gains from the sensor; or, for a
fully actuated arm, :class:`ComputedTorquePolicy` without linearizing) and :func:`run_closed_loop` runs it on the
sensed environment (:mod:`smo_gym.control.closed_loop`).

NumPy/SciPy on top of :mod:`smo_gym.observers`; :func:`linearize`, :func:`design` and :class:`ComputedTorquePolicy`
import MuJoCo lazily.
"""

from __future__ import annotations

from .baselines import (
    FiniteDifferenceState,
    KalmanObserver,
    PIDController,
    default_integral_outputs,
    kalman_gain,
    van_loan_covariance,
)
from .closed_loop import (
    ClosedLoopRun,
    ExternalForce,
    closed_loop_metrics,
    parse_disturbance,
    run_closed_loop,
    scale_body_mass,
)
from .computed_torque import ComputedTorquePolicy, UnderactuatedError
from .controllers import (
    CompensationController,
    IntegralSlidingModeController,
    StateFeedback,
    UnmatchedCompensationController,
    lqr,
    regular_form,
    sampled_lqr,
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
from .ltv import (
    CascadedLTVObserver,
    LTVPlant,
    LTVStrongObservabilityReport,
    ltv_example,
    ltv_state_map,
    ltv_strong_observability,
    simulate_ltv,
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
from .policies import (
    ControlDiagnostics,
    LinearDesign,
    LinearizedPolicy,
    OperatingPoint,
    OutputFeedbackPolicy,
    actuator_map,
    default_weights,
    design,
    differentiator_bound,
    equilibrium,
    sensor_noise,
)
from .simulation import SimulationResult, fit_order, simulate, steady_state_error, total_variation_rate
from .switched import (
    AutonomousSwitchedObserver,
    ModeMetrics,
    NonlinearSwitchedObserverBank,
    NotDistinguishableError,
    SwitchedConditions,
    SwitchedEstimate,
    SwitchedHOSMObserver,
    SwitchedLinearSystem,
    SwitchedObserverBank,
    SwitchingSurface,
    mode_metrics,
)
from .unknown_inputs import (
    FunctionalObservabilityReport,
    FunctionalUnknownInputObserver,
    LeftInverseIdentifier,
    LeftInverseReport,
    NoFunctionalObserverError,
    NoStaticLeftInverseError,
    NotStronglyDetectableError,
    StrongDetectabilityReport,
    StronglyDetectableObserver,
    ZeroDynamics,
    detectable_observer_gain,
    functional_observability,
    left_inverse,
    strong_detectability,
    zero_dynamics,
)

__all__ = [
    "DEFAULT_BETAS",
    "AutonomousSwitchedObserver",
    "CascadedHOSMObserver",
    "CascadedLTVObserver",
    "ClosedLoopRun",
    "CompensationController",
    "ComputedTorquePolicy",
    "ControlDiagnostics",
    "ExternalForce",
    "FiniteDifferenceState",
    "FiniteTimeStabilizer",
    "FunctionalObservabilityReport",
    "FunctionalUnknownInputObserver",
    "IntegralSlidingModeController",
    "KalmanObserver",
    "LTVPlant",
    "LTVStrongObservabilityReport",
    "LeftInverseIdentifier",
    "LeftInverseReport",
    "LinearDesign",
    "LinearPlant",
    "LinearizedPolicy",
    "LuenbergerObserver",
    "ModeMetrics",
    "MolinariDecoupling",
    "NoFunctionalObserverError",
    "NoStaticLeftInverseError",
    "NonlinearSwitchedObserverBank",
    "NotDistinguishableError",
    "NotStronglyDetectableError",
    "NotStronglyObservableError",
    "ObservableBlockForm",
    "OperatingPoint",
    "OutputFeedbackPolicy",
    "PIDController",
    "RelativeDegreeError",
    "SimulationResult",
    "SlidingOutput",
    "StateFeedback",
    "StepByStepObserver",
    "StrongDetectabilityReport",
    "StrongObservabilityReport",
    "StronglyDetectableObserver",
    "SwitchedConditions",
    "SwitchedEstimate",
    "SwitchedHOSMObserver",
    "SwitchedLinearSystem",
    "SwitchedObserverBank",
    "SwitchingSurface",
    "UnderactuatedError",
    "UnknownInputConditionError",
    "UnknownInputConditions",
    "UnknownInputObserver",
    "UnmatchedCompensationController",
    "UtkinObserver",
    "WalcottZakDesign",
    "WalcottZakObserver",
    "ZeroDynamics",
    "actuator_map",
    "certify_walcott_zak",
    "closed_loop_metrics",
    "default_integral_outputs",
    "default_weights",
    "design",
    "detectable_observer_gain",
    "differentiator_bound",
    "equilibrium",
    "fit_order",
    "functional_observability",
    "furuta_disturbance",
    "furuta_slides",
    "helicopter_slides",
    "hosm_control",
    "invariant_zeros",
    "kalman_gain",
    "left_annihilator",
    "left_inverse",
    "linearize",
    "lqr",
    "ltv_example",
    "ltv_state_map",
    "ltv_strong_observability",
    "mode_metrics",
    "molinari_decoupling",
    "nested_hosm",
    "observable_block_form",
    "output_coordinate_change",
    "output_error_lipschitz",
    "parse_disturbance",
    "quasi_continuous_hosm",
    "regular_form",
    "relative_degrees",
    "run_closed_loop",
    "sampled_lqr",
    "sampled_observer_gain",
    "scale_body_mass",
    "sensor_noise",
    "settling_time",
    "simulate",
    "simulate_chain",
    "simulate_ltv",
    "sliding_output",
    "steady_state_error",
    "strong_detectability",
    "strong_observability",
    "total_variation_rate",
    "unknown_input_conditions",
    "van_loan_covariance",
    "walcott_zak_design",
    "zero_dynamics",
]
