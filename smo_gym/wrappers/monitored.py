"""Online estimators on what a sensed environment measures, their record in ``info`` (:mod:`smo_gym.monitors`)."""

import gymnasium as gym

from ..monitors import check_monitor, measured


class Monitored(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Run ``monitor`` on the measured positions and the applied ``ctrl``, and put its record in ``info[key]``.

    Parameters
    ----------
    env : gymnasium.Env
        An environment with an :class:`~smo_gym.wrappers.EstimatedVelocity` in its stack (the measured positions
        ``info["smo"]["qpos_measured"]`` and its simulation adapter's ``ctrl``; never the true state).
    monitor : smo_gym.monitors.ParameterMonitor, ModeMonitor or FaultMonitor
        Anything with ``reset(q) -> record`` and ``update(q, ctrl) -> record`` (a dict of arrays); its ``dt``,
        ``nq`` and ``n_ctrl``, where it has them, must be the environment's (:func:`smo_gym.monitors.check_monitor`).
    key : str
        The ``info`` entry of the record; refused (``ValueError``) where the environment's own ``info`` has it.
    """

    def __init__(self, env: gym.Env, monitor, key: str = "monitor"):
        gym.utils.RecordConstructorArgs.__init__(self, monitor=monitor, key=key, _disable_deepcopy=True)
        gym.Wrapper.__init__(self, env)  # ctrl: from the simulation adapter of the EstimatedVelocity below, per step
        if not self.has_wrapper_attr("adapter"):  # refused before a reset or a step moves the simulation
            raise ValueError(f"expected an environment with an EstimatedVelocity in its stack, actual value: {env}")
        self.monitor, self.key = check_monitor(monitor, key, self.get_wrapper_attr("adapter")), key

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, {**info, self.key: self.monitor.reset(measured(info, self.key))}

    def step(self, action):
        *out, info = self.env.step(action)
        q, ctrl = measured(info, self.key), self.get_wrapper_attr("adapter").data.ctrl
        return *out, {**info, self.key: self.monitor.update(q, ctrl)}
