"""Shared base of the smo_gym MuJoCo environments: package-data models, an external-torque disturbance input.

The disturbance is a generalized force written into ``data.qfrc_applied`` on the joints listed in
``disturbance_joints`` at the start of every environment step and held over its ``frame_skip`` physics steps
(zero-order hold at the environment rate; use ``frame_skip=1`` for a disturbance that changes at every physics
step). It is either constant (:meth:`set_disturbance`) or a function of simulation time passed as ``disturbance=``
(``f(t) -> array of shape (n_disturbance,)``, evaluated at the step's start time), and is reported as
``info["disturbance"]``. The physics is stepped by ``MujocoEnv``'s own ``_step_mujoco_simulation`` (not
overridden), so :class:`smo_gym.wrappers.EstimatedVelocity` can sample inside ``frame_skip``.

When MuJoCo finds a non-finite or huge state during a step it resets the simulation with only a printed warning;
the step then ends the episode and says so in ``info["diverged"]`` (:func:`instability_warnings`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import ClassVar

import mujoco
import numpy as np
from gymnasium import utils
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.spaces import Box

from .._validation import as_real_array, check_choice, check_int_in_range, check_nonnegative

__all__ = ["ASSETS", "MAX_FRAME_SKIP", "SmoMujocoEnv", "asset_path"]

#: directory of the packaged MJCF models
ASSETS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "assets")

#: the most physics steps one environment step may take. One environment step is one control period: 10 000
#: physics steps are 10 s (VariableInertia, 1 ms) to 20 s (the others, 2 ms) of simulated time, longer than any of
#: these mechanisms takes to settle, and about 0.1 s of computation (measured: 7-10 us per physics step). A larger
#: count is a mistake, not a control period: frame_skip=10**12 ran for hours, or failed in mj_step (a C int).
MAX_FRAME_SKIP = 10_000


def asset_path(name: str) -> str:
    """Absolute path of a packaged model (works from an installed package, not only a checkout)."""
    return os.path.join(ASSETS, name)


def instability_warnings(data: mujoco.MjData) -> int:
    """How often MuJoCo found a non-finite or huge position, velocity, acceleration or control in ``data`` (it then
    resets the simulation, or zeroes the control, with only a printed warning)."""
    kinds = ("mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC", "mjWARN_BADCTRL")
    return sum(int(data.warning[int(getattr(mujoco.mjtWarning, k))].number) for k in kinds)


class SmoMujocoEnv(MujocoEnv, utils.EzPickle):
    """Base class: observation ``[qpos, qvel]``, reset noise, and a joint-torque disturbance input.

    Subclasses set ``xml_file``, ``disturbance_joints`` and implement ``_reward_terminated(obs, action)`` and
    ``_initial_state()``.

    The constructor refuses a ``frame_skip`` outside ``[1, MAX_FRAME_SKIP]`` and a ``render_mode`` that is neither
    None nor one of ``metadata["render_modes"]`` (Gymnasium's convention), before it loads the model.
    """

    xml_file: str = ""
    disturbance_joints: Sequence[str] = ()
    # on the class, as Gymnasium reads it there: gymnasium.make checks render_mode against it before construction
    # (an instance adds render_fps, which depends on frame_skip)
    metadata: ClassVar[dict] = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}

    def __init__(
        self,
        frame_skip: int,
        *,
        disturbance: Callable[[float], np.ndarray] | None = None,
        reset_noise_scale: float = 0.01,
        render_mode: str | None = None,
        **kwargs,
    ):
        utils.EzPickle.__init__(
            self,
            frame_skip=frame_skip,
            disturbance=disturbance,
            reset_noise_scale=reset_noise_scale,
            render_mode=render_mode,
            **kwargs,
        )
        frame_skip = check_int_in_range("frame_skip", frame_skip, 1, MAX_FRAME_SKIP)
        if render_mode is not None:  # refused here, not at the first render(), and before MuJoCo loads anything
            check_choice("render_mode", render_mode, self.metadata["render_modes"])
        self._reset_noise_scale = check_nonnegative("reset_noise_scale", reset_noise_scale)
        path = asset_path(self.xml_file)
        model = mujoco.MjModel.from_xml_path(path)
        n_obs = model.nq + model.nv
        MujocoEnv.__init__(
            self,
            path,
            frame_skip,
            observation_space=Box(-np.inf, np.inf, shape=(n_obs,), dtype=np.float64),
            render_mode=render_mode,
            **kwargs,
        )
        self.metadata = {**self.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        self.disturbance_dofs = np.array(
            [self.model.jnt_dofadr[self.model.joint(name).id] for name in self.disturbance_joints], dtype=int
        )
        if disturbance is not None and not callable(disturbance):
            raise TypeError(f"expected disturbance to be callable f(t) -> array, actual value: {disturbance!r}")
        self._disturbance_fn = disturbance
        self._disturbance_const = np.zeros(len(self.disturbance_dofs))
        self._last_disturbance = np.zeros(len(self.disturbance_dofs))

    # ---- disturbance input ---------------------------------------------------------------------------------
    def set_disturbance(self, torque) -> None:
        """Apply a constant generalized force on ``disturbance_joints`` from now on (added to ``disturbance=``)."""
        torque = as_real_array("torque", torque)
        if torque.shape not in ((), self._disturbance_const.shape):
            raise ValueError(
                f"expected a disturbance of shape {self._disturbance_const.shape}, actual value: {torque.shape}"
            )
        if not np.all(np.isfinite(torque)):
            raise ValueError(f"expected a finite disturbance, actual value: {torque!r}")
        self._disturbance_const = np.broadcast_to(torque, self._disturbance_const.shape).copy()

    @property
    def constant_disturbance(self) -> np.ndarray:
        """The constant generalized force :meth:`set_disturbance` applies on ``disturbance_joints`` (a copy)."""
        return self._disturbance_const.copy()

    def _disturbance_at(self, t: float) -> np.ndarray:
        d = self._disturbance_const
        if self._disturbance_fn is not None:
            value = as_real_array("disturbance(t)", self._disturbance_fn(t))
            try:
                d = d + np.broadcast_to(value, d.shape)
            except ValueError:
                raise ValueError(f"expected disturbance(t) of shape {d.shape}, actual value: {value.shape}") from None
        if not np.isfinite(d).all():  # MuJoCo would reset the simulation, silently
            raise ValueError(f"expected a finite disturbance at t = {t!r}, actual value: {d!r}")
        return d

    # ---- pickling: the constructor's arguments (EzPickle) and the constant disturbance set since -------------
    def __getstate__(self) -> dict:
        return {**utils.EzPickle.__getstate__(self), "constant_disturbance": self._disturbance_const.copy()}

    def __setstate__(self, state: dict) -> None:
        state = dict(state)
        constant = state.pop("constant_disturbance", None)
        utils.EzPickle.__setstate__(self, state)
        if constant is not None:  # a copy applies the same input as the original
            self.set_disturbance(constant)

    # ---- gymnasium API -------------------------------------------------------------------------------------
    def _get_obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos, self.data.qvel]).ravel()

    def _reward_terminated(self, obs: np.ndarray, action: np.ndarray) -> tuple[float, bool]:  # pragma: no cover
        raise NotImplementedError

    def _initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        s = self._reset_noise_scale
        qpos = self.init_qpos + self.np_random.uniform(-s, s, size=self.model.nq)
        qvel = self.init_qvel + self.np_random.uniform(-s, s, size=self.model.nv)
        return qpos, qvel

    def step(self, action):
        """One control period. ``info``: the ``disturbance`` applied, the ``time``, and ``diverged``: MuJoCo found
        a non-finite or huge state and reset the simulation (with only a printed warning); the episode then ends.

        The reward's control cost is that of the action MuJoCo applies, clipped to the action space.
        """
        action = as_real_array("action", action)
        if action.shape != self.action_space.shape:  # before anything moves
            raise ValueError(f"expected an action of shape {self.action_space.shape}, actual value: {action.shape}")
        if not np.isfinite(action).all():  # MuJoCo would replace it by 0, silently
            raise ValueError(f"expected a finite action, actual value: {action!r}")
        d = self._disturbance_at(self.data.time)
        # only its own channels: forces another wrapper applies to other joints stay (a reset clears them all)
        self.data.qfrc_applied[self.disturbance_dofs] = d
        self._last_disturbance = d
        resets = instability_warnings(self.data)
        self.do_simulation(action, self.frame_skip)
        obs = self._get_obs()
        diverged = instability_warnings(self.data) > resets or not np.all(np.isfinite(obs))
        applied = np.clip(action, self.action_space.low, self.action_space.high)
        reward, terminated = self._reward_terminated(obs, applied)
        info = {"disturbance": self._last_disturbance.copy(), "time": float(self.data.time), "diverged": diverged}
        if self.render_mode == "human":
            self.render()
        return obs, float(reward), bool(terminated or diverged), False, info

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode from :meth:`_initial_state` (drawn from the environment's random stream, which ``seed``
        reseeds), with no applied force.

        Parameters
        ----------
        seed : int, optional
            Reseeds the environment's random stream (Gymnasium's convention).
        options : dict, optional
            Read by none of these environments, like Gymnasium's own MuJoCo environments: vector environments and
            trainers pass one ``options`` dict to every sub-environment, so keys meant for others are not an error.
            To start from a chosen state, call ``set_state(qpos, qvel)`` after the reset.

        Raises
        ------
        TypeError
            ``options`` is neither None nor a dict (a mistake such as ``options="x"``, never read otherwise).
        """
        if options is not None and not isinstance(options, dict):
            raise TypeError(f"expected options to be None or a dict, actual value: {options!r:.80}")
        return super().reset(seed=seed, options=options)

    def reset_model(self):
        with np.errstate(over="ignore", invalid="ignore"):  # a non-finite initial state is refused just below
            qpos, qvel = self._initial_state()
        if not (np.isfinite(qpos).all() and np.isfinite(qvel).all()):
            raise ValueError(
                f"expected a reset_noise_scale that keeps the initial state finite, actual value: "
                f"{self._reset_noise_scale!r}"
            )
        self.set_state(qpos, qvel)
        self.data.qfrc_applied[:] = 0.0
        return self._get_obs()
