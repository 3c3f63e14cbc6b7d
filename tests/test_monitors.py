"""Monitors in ``info``: identified parameters and fault flags from what the sensed environment measures.

The environment is ``smo_gym/TwoLinkArm-v0`` at its own 10 ms step, seen through an encoder and a velocity observer
(:class:`smo_gym.wrappers.EstimatedVelocity`); the monitors get ``info["smo"]["qpos_measured"]`` and the
simulation's ``ctrl`` only.
"""

from __future__ import annotations

import copy
import pickle

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import smo_gym  # noqa: F401  (registers the environments)
from smo_gym import wrappers
from smo_gym.fault_detection import FaultObserverBank, diagnose
from smo_gym.mechanics import MujocoDynamics
from smo_gym.monitors import FaultMonitor, ParameterMonitor

ENV_ID = "smo_gym/TwoLinkArm-v0"
TRUE_MASS = 1.2  # the simulation's forearm (body "lower"); the monitor's model says 0.8 kg
FAULTS = ("shoulder-gain", "elbow-gain", "elbow-damping")


def apply_fault(model, name: str) -> None:
    """Modify ``model`` in place: a motor losing half its gain, or the elbow's damping 0.05 -> 1.0 N m s/rad."""
    if name == "shoulder-gain":
        model.actuator_gear[0, 0] *= 0.5
    elif name == "elbow-gain":
        model.actuator_gear[1, 0] *= 0.5
    else:
        model.dof_damping[1] = 1.0


def nominal_model():
    return copy.deepcopy(gym.make(ENV_ID).unwrapped.model)


def parameter_monitor(model, dt: float) -> ParameterMonitor:
    return ParameterMonitor.from_mujoco(
        model, [("body_mass", "lower")], dt, lipschitz=150.0, observer_options={"accel_bound": 200.0}
    )


def fault_monitor(model, dt: float) -> FaultMonitor:
    faulty = []
    for name in FAULTS:
        m = copy.deepcopy(model)
        apply_fault(m, name)
        faulty.append(MujocoDynamics(m))
    bank = FaultObserverBank(
        dt,
        MujocoDynamics(model),
        faulty,
        5.0,  # rad/s^2; fault-free peaks of the nominal residual are below 2 here (seeds 0-9), the faults give 20-100
        lipschitz=100.0,
        dwell=0.2,
        settle_time=0.3,
        disturbance_time_constant=0.1,
        names=list(FAULTS),
        accel_bound=300.0,
    )
    return FaultMonitor(bank)


def make_env(payload: float | None = TRUE_MASS, sensor: str = "encoder-12bit", rate="physics"):
    """The sensed arm with both monitors stacked (identification under "identification", faults under "fault")."""
    base = gym.make(ENV_ID)
    model = copy.deepcopy(base.unwrapped.model)  # the nominal model, before the payload changes the simulation's
    if payload is not None:
        sim = base.unwrapped.model
        sim.body_mass[mujoco.mj_name2id(sim, mujoco.mjtObj.mjOBJ_BODY, "lower")] = payload
    env = wrappers.EstimatedVelocity(base, sensor=sensor, observer="super-twisting", rate=rate)
    dt = env.unwrapped.dt
    env = wrappers.Monitored(env, parameter_monitor(model, dt), key="identification")
    return wrappers.Monitored(env, fault_monitor(model, dt), key="fault")


def policy(t: float, obs: np.ndarray) -> np.ndarray:
    """PD tracking of a sum of sines on the *estimated* state (the observation): persistent excitation (the
    reference of scripts/demo_identification.py)."""
    ref = np.array([0.6 * np.sin(1.1 * t) + 0.3 * np.sin(2.9 * t), -1.0 + 0.8 * np.sin(1.7 * t + 0.5)])
    dref = np.array([0.66 * np.cos(1.1 * t) + 0.87 * np.cos(2.9 * t), 1.36 * np.cos(1.7 * t + 0.5)])
    u = 40.0 * (ref - obs[:2]) + 4.0 * (dref - obs[2:]) + np.array([np.sin(5.3 * t), 0.5 * np.sin(7.1 * t)])
    return np.clip(u, [-10.0, -5.0], [10.0, 5.0])


def run(env, steps: int, seed: int = 0, fault: tuple[int, str] | None = None):
    """``steps`` steps from ``reset(seed)``; returns the reset's info and every step's info."""
    obs, info0 = env.reset(seed=seed)
    dt = env.unwrapped.dt
    infos = []
    for k in range(steps):
        if fault is not None and k == fault[0]:
            apply_fault(env.unwrapped.model, fault[1])  # the plant changes, the monitors' models do not
        obs, _, _, _, info = env.step(policy(k * dt, obs))
        infos.append(info)
    return info0, infos


def test_identified_mass_converges_with_a_mismatched_payload():
    env = make_env()
    info0, infos = run(env, 400)  # 4 s at 10 ms
    assert info0["identification"]["theta"] == pytest.approx([0.8])  # the nominal value at reset
    theta = np.array([i["identification"]["theta"][0] for i in infos])
    # measured here: 1.17-1.18 kg over the last second (the O(h) bias of the sampled injection at h = 10 ms)
    assert np.all(np.abs(theta[-100:] - TRUE_MASS) < 0.05), theta[-100:].min()
    assert abs(theta[:10].mean() - TRUE_MASS) > 0.1  # it did have to converge
    gamma = np.array([i["identification"]["gamma_diag"][0] for i in infos])
    assert gamma[0] < 1e3 and np.all(np.diff(gamma) <= 0)  # least squares without forgetting: Gamma only shrinks
    # to the fault bank (nominal 0.8 kg) the payload is a fault outside the bank: detected, not isolated
    assert infos[-1]["fault"]["detected"] and infos[-1]["fault"]["isolated_name"] == "unknown"
    env.close()


def test_a_mid_episode_fault_is_detected_and_isolated_in_info():
    env = make_env(payload=None)
    _, infos = run(env, 200, fault=(100, "elbow-gain"))  # the elbow motor loses half its gain at t = 1 s
    flags = [i["fault"] for i in infos]
    assert not any(f["detected"] for f in flags[:100])
    last = flags[-1]
    assert last["detected"] and 1.0 <= last["detection_time"] <= 1.2
    assert last["isolated"] == 2 and last["isolated_name"] == "elbow-gain"
    assert last["detection_time"] < last["isolation_time"] <= 2.0
    first = next(k for k, f in enumerate(flags) if f["detected"])
    assert flags[first]["time"] == pytest.approx(last["detection_time"])
    # the online flags are those of the offline decision on the same record
    bank = env.monitor.bank
    d = bank.diagnose()
    assert bool(d.detected) and d.detection_time == pytest.approx(last["detection_time"])
    assert int(d.isolated) == 2 and d.isolation_time == pytest.approx(last["isolation_time"])
    env.close()


class ScriptedBank(FaultObserverBank):
    """A bank whose normalized residuals are given (the decision alone is under test)."""

    def __init__(self, rows: np.ndarray, dt: float):
        faults = [FaultFree()] * (rows.shape[1] - 1)
        super().__init__(dt, FaultFree(), faults, 1.0, n=1, lipschitz=1.0, dwell=0.05, settle_time=0.03)
        self.rows, self._k = rows, -1

    def update(self, y, u=None):
        self._k += 1
        return self.rows[self._k]


class FaultFree:
    def __call__(self, q, v, u):
        return np.zeros_like(q)


@pytest.mark.parametrize("seed", range(6))
def test_the_online_flags_are_the_decision_on_the_record_so_far(seed):
    """At every sample the record equals ``diagnose`` on the residuals up to it: detection, isolation, revocation
    (the matching model leaving the band) and unknown, on residuals that enter and leave the band in random runs."""
    rng = np.random.default_rng(seed)
    T, dt = 300, 0.01
    runs = rng.integers(1, 25, size=(T, 4)).cumsum(axis=0)  # in/out runs of random lengths, per model
    inside = np.stack([np.searchsorted(runs[:, j], np.arange(T)) % 2 == 0 for j in range(4)], axis=1)
    rows = np.where(inside, rng.uniform(0.0, 1.0, (T, 4)), rng.uniform(1.01, 3.0, (T, 4)))
    monitor = FaultMonitor(ScriptedBank(rows, dt))
    monitor.reset(np.zeros(1))
    verdicts = [0]
    for k in range(T):
        record = monitor.update(np.zeros(1), np.zeros(1))
        d = diagnose(np.vstack([np.zeros((1, 4)), rows[: k + 1]]), dt, dwell=0.05, settle_time=0.03)
        assert record["detected"] == bool(d.detected) and record["isolated"] == int(d.isolated), k
        got, expected = [record["detection_time"], record["isolation_time"]], [d.detection_time, d.isolation_time]
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12, equal_nan=True)
        verdicts.append(record["isolated"])
    revoked = sum(a >= 1 and b == -1 for a, b in zip(verdicts, verdicts[1:], strict=False))
    assert -1 in verdicts and max(verdicts) >= 1 and revoked >= 1  # unknown, isolation and revocation all occur


def test_info_keys_are_present_and_finite_from_the_first_step():
    env = make_env()
    _, info = env.reset(seed=1)
    for step_info in (info, env.step(np.zeros(2))[-1]):
        ident, fault = step_info["identification"], step_info["fault"]
        assert set(ident) == {"theta", "gamma_diag", "time"}
        assert ident["theta"].shape == ident["gamma_diag"].shape == (1,)
        assert np.isfinite(ident["theta"]).all() and np.isfinite(ident["gamma_diag"]).all()
        assert set(fault) == {
            "detected",
            "detection_time",
            "isolated",
            "isolated_name",
            "isolation_time",
            "residual_norms",
            "time",
        }
        assert fault["residual_norms"].shape == (4,) and np.isfinite(fault["residual_norms"]).all()
        assert fault["detected"] is False and fault["isolated_name"] == "no fault"
        assert "smo" in step_info  # the sensing record is passed through
    assert step_info["identification"]["time"] == pytest.approx(env.unwrapped.dt)
    recorded = env.spec.additional_wrappers[-1].kwargs  # constructor arguments, the monitor itself (not a copy)
    assert recorded["key"] == "fault" and recorded["monitor"] is env.monitor
    env.close()


def test_the_monitors_get_the_measured_positions_and_the_simulations_ctrl():
    """Through a stack that rescales actions, ``ctrl`` is the simulation's input, not the agent's action."""

    class Recorder:
        def reset(self, q):
            self.q = [np.array(q)]
            self.u = []
            return {}

        def update(self, q, u):
            self.q.append(np.array(q))
            self.u.append(np.array(u))
            return {}

    sensed = wrappers.EstimatedVelocity(gym.make(ENV_ID), sensor="encoder-12bit-noisy", observer="super-twisting")
    env = wrappers.Monitored(gym.wrappers.RescaleAction(sensed, np.float32(-1), np.float32(1)), Recorder())
    _, info = env.reset(seed=0)
    rec = env.monitor
    np.testing.assert_array_equal(rec.q[0], info["smo"]["qpos_measured"])
    _, _, _, _, info = env.step(np.array([0.5, -0.5]))
    np.testing.assert_array_equal(rec.q[1], info["smo"]["qpos_measured"])
    assert not np.array_equal(rec.q[1], info["smo"]["qpos"])  # noisy encoder: not the true state
    np.testing.assert_allclose(rec.u[0], [5.0, -2.5])  # the rescaled action in [-10, 10] x [-5, 5]
    np.testing.assert_array_equal(rec.u[0], env.unwrapped.data.ctrl)


def test_reset_restarts_the_estimates_and_seeds_reproduce_them():
    env = make_env(sensor="encoder-12bit-noisy")
    _, first = run(env, 60, seed=3)
    assert first[-1]["identification"]["theta"][0] != pytest.approx(0.8)
    _, info = env.reset(seed=5)
    assert info["identification"]["theta"] == pytest.approx([0.8])
    assert info["identification"]["gamma_diag"] == pytest.approx([1e3])  # gamma0
    assert info["identification"]["time"] == 0.0 and info["fault"]["time"] == 0.0
    _, again = run(env, 60, seed=3)
    _, other = run(env, 60, seed=4)
    np.testing.assert_array_equal(first[-1]["identification"]["theta"], again[-1]["identification"]["theta"])
    np.testing.assert_array_equal(first[-1]["fault"]["residual_norms"], again[-1]["fault"]["residual_norms"])
    assert not np.array_equal(first[-1]["identification"]["theta"], other[-1]["identification"]["theta"])
    env.close()


@pytest.mark.parametrize("clone", [lambda e: pickle.loads(pickle.dumps(e)), copy.deepcopy], ids=["pickle", "deepcopy"])
def test_a_copy_of_the_wrapped_env_runs_as_the_original(clone):
    """Gymnasium's MuJoCo envs copy and pickle by their constructor arguments (a fresh simulation, as in
    tests/test_wrapper.py): the monitors travel with their configuration, and seeded resets run both alike."""
    env = make_env(payload=None, sensor="encoder-12bit-noisy", rate="env")
    run(env, 30)  # mid-episode
    twin = clone(env)
    assert twin.monitor is not env.monitor and twin.monitor.names == env.monitor.names
    assert twin.env.monitor.identifier.least_squares is not env.env.monitor.identifier.least_squares
    _, a = run(env, 40, seed=7, fault=(20, "shoulder-gain"))
    _, b = run(twin, 40, seed=7, fault=(20, "shoulder-gain"))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x["identification"]["theta"], y["identification"]["theta"])
        np.testing.assert_array_equal(x["fault"]["residual_norms"], y["fault"]["residual_norms"])
    assert a[-1]["fault"]["detected"] == b[-1]["fault"]["detected"]
    env.close()
    twin.close()


def test_a_sync_vector_env_of_two_aggregates_the_records():
    envs = gym.vector.SyncVectorEnv([make_env, make_env])
    _, info = envs.reset(seed=[0, 1])
    assert info["identification"]["theta"].shape == (2, 1)
    obs = None
    for _ in range(5):
        obs, _, _, _, info = envs.step(np.zeros((2, 2)))
    assert obs.shape == (2, 4)
    assert info["identification"]["theta"].shape == (2, 1) and np.isfinite(info["identification"]["theta"]).all()
    assert info["identification"]["gamma_diag"].shape == (2, 1)
    assert info["fault"]["detected"].shape == (2,) and info["fault"]["residual_norms"].shape == (2, 4)
    assert list(info["fault"]["isolated_name"]) == ["no fault", "no fault"]
    assert not np.array_equal(*info["identification"]["theta"])  # two environments, two seeds
    envs.close()


def test_bad_input_raises_typed_errors():
    sensed = wrappers.EstimatedVelocity(gym.make(ENV_ID), sensor="encoder-12bit", observer="super-twisting")
    with pytest.raises(TypeError, match="reset"):
        wrappers.Monitored(sensed, object())
    model = nominal_model()
    monitor = parameter_monitor(model, 0.01)
    for key in ("", "smo"):
        with pytest.raises(ValueError, match="key"):
            wrappers.Monitored(sensed, monitor, key=key)
    with pytest.raises(TypeError, match="key"):
        wrappers.Monitored(sensed, monitor, key=3)
    with pytest.raises(ValueError, match=r"EstimatedVelocity in its stack"):  # nothing sensed below
        wrappers.Monitored(gym.make(ENV_ID), monitor)  # was refused only at reset, after the simulation moved
    with pytest.raises(RuntimeError, match="reset"):
        parameter_monitor(model, 0.01).update(np.zeros(2), np.zeros(2))
    with pytest.raises(RuntimeError, match="reset"):
        fault_monitor(model, 0.01).update(np.zeros(2), np.zeros(2))
    monitor.reset(np.zeros(2))
    with pytest.raises(ValueError, match="q_measured"):
        monitor.update(np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="q_measured"):
        monitor.update(np.array([0.0, np.nan]), np.zeros(2))
    with pytest.raises(ValueError, match="ctrl"):
        monitor.update(np.zeros(2), np.zeros(3))
    with pytest.raises(ValueError, match="ctrl"):
        monitor.update(np.zeros(2), np.array([np.inf, 0.0]))
    with pytest.raises(TypeError):
        monitor.update(np.zeros(2), "ctrl")
    with pytest.raises(TypeError, match="EquivalentInjectionIdentifier"):
        ParameterMonitor(object())
    with pytest.raises(ValueError, match="names"):
        ParameterMonitor(monitor.identifier, names=["a", "b"])
    with pytest.raises(TypeError, match="FaultObserverBank"):
        FaultMonitor(object())


def test_a_monitor_of_another_step_or_model_is_refused_at_construction():
    """A monitor built for another sampling step ran on silently, one for another model failed at its first reset
    or step, after the simulation had moved. The monitor's ``dt``, ``nq`` and ``n_ctrl`` are checked now against
    the environment step and the model, before anything runs."""
    from smo_gym.control import SwitchedLinearSystem, SwitchedObserverBank
    from smo_gym.identification import EquivalentInjectionIdentifier
    from smo_gym.monitors import ModeMonitor

    def nominal(t, x1, x2, u):
        return -x1 - 0.1 * x2

    def regressor(t, x1, x2, u):
        return np.asarray(x2)[..., None]

    sensed = wrappers.EstimatedVelocity(gym.make(ENV_ID), sensor="encoder-12bit", observer="super-twisting")
    model = nominal_model()  # the environment step: 10 ms, frame_skip 5 x timestep 2 ms
    for monitor in (parameter_monitor(model, 0.002), fault_monitor(model, 0.002)):  # the physics step
        with pytest.raises(ValueError, match=r"dt equal to the environment step 0\.01"):
            wrappers.Monitored(sensed, monitor)
    one_joint = EquivalentInjectionIdentifier(0.01, nominal, regressor, [0.5], n=1, lipschitz=50.0)
    with pytest.raises(ValueError, match=r"nq = 2 \(the model's\), actual value: 1"):
        wrappers.Monitored(sensed, ParameterMonitor(one_joint))
    with pytest.raises(ValueError, match=r"n_ctrl = 2 \(the model's\), actual value: 3"):
        wrappers.Monitored(sensed, ParameterMonitor(parameter_monitor(model, 0.01).identifier, n_ctrl=3))
    one_input = SwitchedLinearSystem([_oscillator(1, 1), _oscillator(9, 1)], names=["a", "b"])
    bank = SwitchedObserverBank(one_input, 0.01, 300.0, threshold=0.5, dwell=0.05, settle_time=0.3)
    with pytest.raises(ValueError, match=r"n_ctrl = 2 \(the model's\), actual value: 1"):
        wrappers.Monitored(sensed, ModeMonitor(bank))


def test_an_info_key_of_the_environment_is_refused_before_the_monitor_takes_the_sample():
    """``info["disturbance"]`` of smo_gym's environments (reported at steps) was overwritten without a word by a
    monitor under that key, and so was the record of a monitor below one under the same key. Refused now, at the
    reset or step whose ``info`` has the key, before the monitor resets or updates."""
    sensed = wrappers.EstimatedVelocity(gym.make(ENV_ID), sensor="encoder-12bit", observer="super-twisting")

    class Counter:  # duck-typed: no dt, nq or n_ctrl, so nothing to check at construction
        def reset(self, q):
            self.samples = 1
            return {}

        def update(self, q, u):
            self.samples += 1
            return {}

    env = wrappers.Monitored(sensed, Counter(), key="disturbance")
    env.reset(seed=0)  # the arm reports its disturbance at steps only
    with pytest.raises(ValueError, match="without the monitor's key 'disturbance'"):
        env.step(np.zeros(2))
    assert env.monitor.samples == 1  # the monitor did not take the refused step's sample
    stacked = wrappers.Monitored(wrappers.Monitored(sensed, Counter(), key="twice"), Counter(), key="twice")
    with pytest.raises(ValueError, match="without the monitor's key 'twice'"):
        stacked.reset(seed=0)
    assert not hasattr(stacked.monitor, "samples")  # refused before the outer monitor's reset


# ---- the mode of a switched system ------------------------------------------------------------------------------
def _oscillator(k: float, b: float):
    """x1' = x2, x2' = -k x1 - 0.5 x2 + b u + w, position measured."""
    from smo_gym.control import LinearPlant

    return LinearPlant([[0, 1], [-k, -0.5]], [[0], [b]], [[1, 0]], [[0.0], [1.0]])


def _bank(system):
    from smo_gym.control import SwitchedObserverBank

    return SwitchedObserverBank(system, 1e-3, 300.0, threshold=0.5, dwell=0.01, settle_time=0.3,
                                residual_time_constant=0.02)  # fmt: skip


def test_mode_monitor_is_the_bank_run_online():
    """Sample by sample, the monitor's mode and switching instants are those of SwitchedObserverBank.run on the
    whole record (measured positions offset by q0, inputs by u0)."""
    from smo_gym.control import SwitchedLinearSystem
    from smo_gym.monitors import ModeMonitor

    system = SwitchedLinearSystem([_oscillator(1, 1), _oscillator(9, 1), _oscillator(4, 3)], names=["a", "b", "c"])
    sigma = np.repeat([0, 1, 2], 1500)
    t = np.arange(sigma.size) * 1e-3
    u = (2 * np.sin(3 * t) + np.sin(7.3 * t))[:, None]
    _, Y = system.simulate([1.0, 2.0], sigma, 1e-3, u=u)
    offline = _bank(system).run(Y, u)  # Y: T + 1 samples, u[k] held over [t_k, t_k+1)
    q0, u0 = 0.3, -1.0
    monitor = ModeMonitor(_bank(system), qpos_offset=q0, ctrl_offset=u0)
    records = [monitor.reset(Y[0] + q0)] + [monitor.update(Y[k] + q0, u[k - 1] + u0) for k in range(1, len(Y))]
    np.testing.assert_array_equal([r["mode"] for r in records], offline.modes)
    assert records[-1]["switches"] == len(offline.switch_times) == 2
    assert records[-1]["switch_time"] == pytest.approx(offline.switch_times[-1])
    assert sum(r["switched"] for r in records) == 2
    assert records[-1]["mode_name"] == "c" and records[-1]["residual_norms"].shape == (3,)
    with pytest.raises(RuntimeError, match="reset"):
        ModeMonitor(_bank(system)).update(Y[1], u[0])
    with pytest.raises(ValueError, match="ctrl"):
        monitor.update(Y[1], [np.nan])
    with pytest.raises(TypeError, match="SwitchedObserverBank"):
        ModeMonitor(system)


def test_mode_monitor_in_info_through_the_monitored_wrapper():
    """The arm excited around its equilibrium torque (sines of 1.3, 2.2 and 3.1 Hz, amplitude 1: the linear regime;
    at 3 the nominal mode is left before any change), modes linearized there (shoulder gears 1 and 0.4). The
    record reaches info['mode'] at every step; the nominal mode stands while the simulation's gear is 1, and once
    it drops to 0.4 mid-episode the monitor switches to "shoulder-low", once, and stays (measured 0.68 s after the
    change; the residuals of the two modes differ by what the excitation makes of the gear, so the delay is the
    excitation's, bounded here by the 1 s left in the episode)."""
    from smo_gym import control
    from smo_gym.monitors import ModeMonitor

    env = gym.make(ENV_ID, frame_skip=1, reset_noise_scale=0.0)
    model = env.unwrapped.model
    op = control.equilibrium(model)
    plants = []
    for gear in ((1.0, 1.0), (0.4, 1.0)):
        m = copy.deepcopy(model)
        m.actuator_gear[:, 0] = gear
        plants.append(control.linearize(m, op.qpos, op.ctrl))
    bank = control.SwitchedObserverBank(
        control.SwitchedLinearSystem(plants, names=["nominal", "shoulder-low"]), 2e-3, 1000.0, threshold=50.0,
        settle_time=0.1, residual_time_constant=0.05,
    )  # fmt: skip
    sensed = wrappers.EstimatedVelocity(env, sensor="encoder-12bit", rate="env", observer="finite-difference")
    monitored = wrappers.Monitored(sensed, ModeMonitor(bank, qpos_offset=op.qpos, ctrl_offset=op.ctrl), key="mode")
    _, info = monitored.reset(seed=0)
    assert info["mode"]["mode"] == 0 and info["mode"]["time"] == 0.0
    names = []
    for k in range(1000):
        t = 2e-3 * k
        if k == 500:  # the fault: the shoulder's actuator loses 60 % of its gear
            model.actuator_gear[0, 0] = 0.4
        wiggle = [np.sin(2 * np.pi * 1.3 * t) + 0.5 * np.sin(2 * np.pi * 3.1 * t), 0.7 * np.sin(2 * np.pi * 2.2 * t)]
        *_, info = monitored.step(op.ctrl + np.array(wiggle))
        assert np.isfinite(info["mode"]["residual_norms"]).all()
        names.append(info["mode"]["mode_name"])
    assert set(names[:500]) == {"nominal"}
    detected = names.index("shoulder-low")
    assert detected > 500 and set(names[detected:]) == {"shoulder-low"}
    assert info["mode"]["switches"] == 1 and info["mode"]["time"] == pytest.approx(2.0)


def test_the_guide_mode_monitor_example_runs_as_printed(capsys):
    """The control guide's ModeMonitor block, executed: the nominal mode stands with the arm at rest."""
    from pathlib import Path

    guide = Path(__file__).resolve().parents[1] / "docs" / "guide" / "control.md"
    section = guide.read_text().split("In an environment, `smo_gym.monitors.ModeMonitor`", 1)[1]
    source = section.split("```python\n", 1)[1].split("```", 1)[0]
    exec(compile(source, str(guide), "exec"), {"__name__": "__guide__"})
    assert capsys.readouterr().out.startswith("nominal 0 ")


def test_mode_monitor_asks_for_a_reset_after_its_observers_diverge():
    """One huge but finite sample overflowed the bank's residuals (inf), and every later record held NaN without an
    error. The monitor now raises a DivergenceError and asks for a reset; indices of ``outputs`` must be integers
    (0.7 was truncated to 0, True read as 1)."""
    from smo_gym import DivergenceError
    from smo_gym.control import SwitchedLinearSystem
    from smo_gym.monitors import ModeMonitor

    system = SwitchedLinearSystem([_oscillator(1, 1), _oscillator(9, 1)], names=["a", "b"])
    monitor = ModeMonitor(_bank(system))
    monitor.reset([0.0])
    monitor.update([0.001], [0.0])
    with pytest.raises(DivergenceError, match="reset"):
        monitor.update([1e300], [0.0])
    with pytest.raises(RuntimeError, match="expected reset"):
        monitor.update([0.0], [0.0])
    record = monitor.reset([0.0])
    assert np.isfinite(record["residual_norms"]).all()
    for outputs in ([0.7], [True], [2**70]):
        with pytest.raises(ValueError, match="integer indices"):
            ModeMonitor(_bank(system), outputs=outputs)
    with pytest.raises(TypeError):
        ModeMonitor(_bank(system), ctrl_offset=None)


def test_parameter_monitor_says_when_a_refused_sample_cost_the_identifier_its_state():
    """After a huge control, the least squares refused the next sample "with the state kept", but the identifier's
    observer had taken it: the identifier cannot go on (every later call asks for a reset). The message says so."""
    from smo_gym.identification import EquivalentInjectionIdentifier

    def nominal(t, x1, x2, u):
        return -x1 - 0.1 * x2 + u

    def regressor(t, x1, x2, u):
        return np.asarray(x2)[..., None]

    monitor = ParameterMonitor(EquivalentInjectionIdentifier(1e-3, nominal, regressor, [0.5], n=1, lipschitz=50.0),
                               n_ctrl=1)  # fmt: skip
    monitor.reset([0.1])
    monitor.update([0.1001], [0.0])
    with np.errstate(over="ignore", invalid="ignore"):
        monitor.update([0.1002], [1e308])
        with pytest.raises(ValueError) as refused:
            monitor.update([0.1003], [0.0])
    assert "the state was kept" not in str(refused.value) and "reset(y0) before the next update" in str(refused.value)
    with pytest.raises(RuntimeError, match="reset"):
        monitor.update([0.1003], [0.0])


def test_mode_monitor_reads_the_qpos_entries_it_is_given():
    """``outputs`` picks the bank's outputs out of the measured qpos: a monitor reading entry 1 of (junk, y) keeps
    the same records as one reading y alone (reading the first entries instead passed every other test)."""
    from smo_gym.control import SwitchedLinearSystem
    from smo_gym.monitors import ModeMonitor

    system = SwitchedLinearSystem([_oscillator(1, 1), _oscillator(9, 1)], names=["a", "b"])
    picked, alone = ModeMonitor(_bank(system), outputs=[1]), ModeMonitor(_bank(system))
    t = np.arange(300) * 1e-3
    y = 0.1 * np.sin(3 * t)
    picked.reset([5.0, y[0]])
    alone.reset([y[0]])
    for k in range(1, t.size):
        a, b = picked.update([5.0 + k, y[k]], [0.0]), alone.update([y[k]], [0.0])
        np.testing.assert_array_equal(a["residual_norms"], b["residual_norms"])
    assert a["mode"] == b["mode"]


def test_detection_starts_exactly_at_the_settle_time():
    """The nominal residual above its band from the first sample: the first sample that counts is the one at
    ``settle_time`` (0.03 s at dt = 0.01 s), as ``diagnose`` decides it; the random runs above never fell on that
    boundary (a detection one sample later passed them)."""
    dt, T = 0.01, 10
    rows = np.column_stack([np.full(T, 2.0), np.full(T, 0.5)])
    monitor = FaultMonitor(ScriptedBank(rows, dt))
    monitor.reset(np.zeros(1))
    for _ in range(T):
        record = monitor.update(np.zeros(1), np.zeros(1))
    d = diagnose(np.vstack([np.zeros((1, 2)), rows]), dt, dwell=0.05, settle_time=0.03)
    assert record["detection_time"] == pytest.approx(0.03) == pytest.approx(d.detection_time)
