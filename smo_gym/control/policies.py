r"""Output-feedback controllers that act as policies on a sensed MuJoCo environment.

A policy maps the *measured* joint configuration of one control period to an actuator command::

    policy.reset(qpos_measured)          # at the episode's first sample
    ctrl = policy.act(qpos_measured)     # once per environment step, shape (nu,)
    policy.diagnostics                   # estimated state, identified disturbance, sliding variable

``qpos_measured`` is the environment's full ``qpos`` as the sensor reports it (``info["smo"]["qpos_measured"]`` of
:class:`smo_gym.wrappers.EstimatedVelocity`); the policy reads the joints it measures from it. The command is
clipped to the actuators' ``ctrlrange``, and every observer inside is told the command that was actually applied.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

__all__ = ["ControlDiagnostics", "OutputFeedbackPolicy"]


class ControlDiagnostics(NamedTuple):
    """What an output-feedback policy knows after its last :meth:`~OutputFeedbackPolicy.act`.

    Attributes
    ----------
    t : float
        Time of the last sample since :meth:`~OutputFeedbackPolicy.reset` [s].
    qpos : ndarray, shape (n,)
        Estimated positions of the measured joints.
    qvel : ndarray, shape (n,)
        Estimated velocities of the measured joints.
    disturbance : ndarray, shape (m,)
        Identified unknown input: generalized forces on the policy's disturbance channels (N m or N); zeros for a
        policy that does not identify it.
    sliding : ndarray, shape (nu,)
        Sliding variable of the discontinuous term; zeros for a policy without one.
    """

    t: float
    qpos: np.ndarray
    qvel: np.ndarray
    disturbance: np.ndarray
    sliding: np.ndarray


@runtime_checkable
class OutputFeedbackPolicy(Protocol):
    """An output-feedback controller on a MuJoCo environment (see the module docstring).

    Attributes
    ----------
    dt : float
        The control period the policy was designed for (the environment step ``env.unwrapped.dt``).
    name : str
        Short label for tables and plots.
    """

    dt: float
    name: str

    def reset(self, qpos_measured) -> None: ...

    def act(self, qpos_measured) -> np.ndarray: ...

    @property
    def diagnostics(self) -> ControlDiagnostics: ...
