"""Gain design: Levant's tables, super-twisting gains, Ackermann's formula (and LMI designs in later modules).

No Gymnasium or MuJoCo imports here: design works on numbers only.
"""

from .apaza import ApazaGains, InfeasibleGainsError, apaza_gains, apaza_lmi_matrix
from .gains import (
    LEVANT_LAMBDAS,
    MAX_LEVANT_ORDER,
    ackermann_observer_gain,
    binomial_coefficients,
    levant_gains,
    levant_lambdas,
    levant_nonrecursive,
    super_twisting_gains,
)
from .ilf import (
    BlockDecomposition,
    ILFCertificate,
    ILFDesign,
    block_decomposition,
    certify_ilf,
    ilf_gains,
)
from .lmi import (
    LMIInfeasibleError,
    SwitchedGainCertificate,
    certify_switched_gain,
    switched_gain_lmi,
    switched_gain_lmi_matrix,
)

__all__ = [
    "LEVANT_LAMBDAS",
    "MAX_LEVANT_ORDER",
    "ApazaGains",
    "BlockDecomposition",
    "ILFCertificate",
    "ILFDesign",
    "InfeasibleGainsError",
    "LMIInfeasibleError",
    "SwitchedGainCertificate",
    "ackermann_observer_gain",
    "apaza_gains",
    "apaza_lmi_matrix",
    "binomial_coefficients",
    "block_decomposition",
    "certify_ilf",
    "certify_switched_gain",
    "ilf_gains",
    "levant_gains",
    "levant_lambdas",
    "levant_nonrecursive",
    "super_twisting_gains",
    "switched_gain_lmi",
    "switched_gain_lmi_matrix",
]
