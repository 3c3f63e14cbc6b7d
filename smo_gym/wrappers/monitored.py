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
    monitor : smo_gym.monitors.ParameterMonitor or smo_gym.monitors.FaultMonitor
        Anything with ``reset(q) -> record`` and ``update(q, ctrl) -> record`` (a dict of arrays).
    key : str
        The ``info`` entry of the record.
    """

    def __init__(self, env: gym.Env, monitor, key: str = "monitor"):
        gym.utils.RecordConstructorArgs.__init__(self, monitor=monitor, key=key, _disable_deepcopy=True)
        gym.Wrapper.__init__(self, env)  # ctrl: from the simulation adapter of the EstimatedVelocity below, per step
        self.monitor, self.key = check_monitor(monitor, key), key
        if not self.has_wrapper_attr("adapter"):  # refused before a reset or a step moves the simulation
            raise ValueError(f"expected an environment with an EstimatedVelocity in its stack, actual value: {env}")

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, {**info, self.key: self.monitor.reset(measured(info))}

    def step(self, action):
        *out, info = self.env.step(action)
        return *out, {**info, self.key: self.monitor.update(measured(info), self.get_wrapper_attr("adapter").data.ctrl)}
