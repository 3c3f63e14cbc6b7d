import gymnasium as gym

from ..monitors import check_monitor, measured


class Monitored(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """``info[key] = monitor.update(info["smo"]["qpos_measured"], ctrl)``, reset alike (why: :mod:`smo_gym.monitors`)"""

    def __init__(self, env: gym.Env, monitor, key: str = "monitor"):
        gym.utils.RecordConstructorArgs.__init__(self, monitor=monitor, key=key, _disable_deepcopy=True)
        gym.Wrapper.__init__(self, env)  # ctrl: from the simulation adapter of the EstimatedVelocity below, per step
        self.monitor, self.key = check_monitor(monitor, key), key

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, {**info, self.key: self.monitor.reset(measured(info))}

    def step(self, action):
        *out, info = self.env.step(action)
        return *out, {**info, self.key: self.monitor.update(measured(info), self.get_wrapper_attr("adapter").data.ctrl)}
