r"""The smo_gym environments: small mechanisms for the model-based observers and the control module.

All three observe ``[qpos, qvel]`` (true state; put :mod:`smo_gym.wrappers` around them for realistic sensing),
take actuator torques as actions, integrate with RK4, have no contacts, and accept an external joint-torque
disturbance through ``qfrc_applied`` (``disturbance=f(t)`` at construction, or ``env.unwrapped.set_disturbance``),
applied at every physics step and reported in ``info["disturbance"]``.
"""

from __future__ import annotations

import numpy as np

from .base import SmoMujocoEnv

__all__ = ["FurutaPendulumEnv", "TwoLinkArmEnv", "VariableInertiaEnv"]


class VariableInertiaEnv(SmoMujocoEnv):
    r"""One-DOF pendulum with configuration-dependent inertia (arm plus a bead coupled to the arm angle).

    A pendulum arm (hinge ``arm``, angle :math:`\theta`, 0 hanging down) carries a bead on a slide (``bead``)
    whose radial position is tied to the angle by a MuJoCo joint equality,
    :math:`r = r_0 + a\theta^2` (:math:`r_0 = 0.2` m, :math:`a = 0.3` m/rad^2). The reduced one-DOF dynamics,

    .. math::
        M(\theta)\ddot\theta + \tfrac12 M'(\theta)\dot\theta^2 + G(\theta) + b\dot\theta = \tau,\qquad
        M(\theta) = I_{arm} + m\,(r^2 + r'^2),

    have the quadratic velocity term :math:`\alpha(\theta)\dot\theta^2`, :math:`\alpha = -M'/(2M)`, that Apaza
    et al.'s transform removes: the showcase of :class:`smo_gym.observers.DissipativeSuperTwisting`. The measured
    coordinate is ``arm``; :class:`smo_gym.mechanics.MujocoDynamics` eliminates ``bead`` exactly.

    * Observation, ``Box(4)``: ``[theta, r_slide, theta_dot, r_slide_dot]`` (``r_slide = r - r_0``).
    * Action, ``Box(1)`` in ``[-3, 3]`` N m: motor torque on ``arm``.
    * Disturbance input: a torque on ``arm`` (``qfrc_applied``).
    * Reward: :math:`-\theta^2 - 0.01\tau^2` (bring the arm down and keep it still); never terminates.
    * Steps: physics 1 ms, ``frame_skip=10`` (10 ms per environment step).
    * Reset: :math:`\theta \sim \mathcal U(\pm 1)` rad, :math:`\dot\theta \sim \mathcal U(\pm 1)` rad/s (the bead
      placed consistently with the constraint).
    """

    xml_file = "variable_inertia.xml"
    disturbance_joints = ("arm",)
    #: coupling r - r0 = A * theta^2
    COUPLING = 0.3

    def __init__(self, frame_skip: int = 10, reset_noise_scale: float = 1.0, **kwargs):
        super().__init__(frame_skip, reset_noise_scale=reset_noise_scale, **kwargs)

    def _initial_state(self):
        s = self._reset_noise_scale
        th, thd = self.np_random.uniform(-s, s, size=2)
        qpos = np.array([th, self.COUPLING * th * th])
        qvel = np.array([thd, 2 * self.COUPLING * th * thd])
        return qpos, qvel

    def _reward_terminated(self, obs, action):
        return -(obs[0] ** 2) - 0.01 * float(action[0]) ** 2, False


class TwoLinkArmEnv(SmoMujocoEnv):
    r"""Two-link planar arm in the vertical plane, torque-controlled, with an external joint-torque input.

    Links of 0.5 m (1.0 kg and 0.8 kg capsules), hinges ``shoulder`` and ``elbow`` about the horizontal axis
    (angle 0: the arm horizontal), viscous damping 0.05 N m s/rad, gravity.

    * Observation, ``Box(4)``: ``[q_shoulder, q_elbow, qd_shoulder, qd_elbow]``.
    * Action, ``Box(2)``: motor torques in ``[-10, 10]`` and ``[-5, 5]`` N m.
    * Disturbance input: torques on both joints (``qfrc_applied``), e.g.
      ``disturbance=lambda t: [0.5 * np.sin(2 * t) + 0.2, 0.0]``.
    * Reward: :math:`-\|q - q^*\|^2 - 10^{-3}\|\tau\|^2` with the target :math:`q^* = (\pi/4, -\pi/2)`;
      never terminates.
    * Steps: physics 2 ms, ``frame_skip=5`` (10 ms per environment step).
    """

    xml_file = "two_link_arm.xml"
    disturbance_joints = ("shoulder", "elbow")
    TARGET = np.array([np.pi / 4, -np.pi / 2])

    def __init__(self, frame_skip: int = 5, reset_noise_scale: float = 0.1, **kwargs):
        super().__init__(frame_skip, reset_noise_scale=reset_noise_scale, **kwargs)

    def _reward_terminated(self, obs, action):
        return -float(np.sum((obs[:2] - self.TARGET) ** 2)) - 1e-3 * float(np.sum(action**2)), False


class FurutaPendulumEnv(SmoMujocoEnv):
    r"""Furuta (rotary inverted) pendulum with a matched disturbance input.

    A horizontal arm (0.2 m, hinge ``arm`` about the vertical axis) carries at its tip a pendulum (0.3 m, hinge
    ``pendulum`` about the arm's axis; 0 is upright). The motor drives the arm; the disturbance enters the same
    joint (a *matched* disturbance, the setting of the compensation controllers of Fridman's lecture slides, section 6).

    * Observation, ``Box(4)``: ``[q_arm, q_pendulum, qd_arm, qd_pendulum]``.
    * Action, ``Box(1)``: arm torque in ``[-0.5, 0.5]`` N m.
    * Disturbance input: a torque on ``arm`` (``qfrc_applied``).
    * Reward: +1 per step while upright; terminates when :math:`|q_{pendulum}| > 0.5` rad.
    * Steps: physics 2 ms, ``frame_skip=5`` (10 ms per environment step).
    * Reset: every coordinate uniform in ``+-reset_noise_scale`` (default 0.05) around upright.
    """

    xml_file = "furuta_pendulum.xml"
    disturbance_joints = ("arm",)

    def __init__(self, frame_skip: int = 5, reset_noise_scale: float = 0.05, **kwargs):
        super().__init__(frame_skip, reset_noise_scale=reset_noise_scale, **kwargs)

    def _reward_terminated(self, obs, action):
        terminated = bool(abs(obs[1]) > 0.5)
        return (0.0 if terminated else 1.0), terminated
