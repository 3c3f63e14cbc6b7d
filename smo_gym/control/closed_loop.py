r"""Closed-loop runs of output-feedback policies on sensed MuJoCo environments, and the numbers they report.

:func:`run_closed_loop` puts a policy (:mod:`smo_gym.control.policies`) in the loop of an environment wrapped by
:class:`smo_gym.wrappers.EstimatedVelocity`: the policy sees the sensor's measured positions only
(``info["smo"]["qpos_measured"]``: noise, quantization, delay, dropouts of the sensor preset), an external force
enters through MuJoCo's ``qfrc_applied`` (:class:`ExternalForce`), and events (a payload change) happen at set
times. :func:`closed_loop_metrics` turns a run into the table's numbers.

Disturbances are written as expressions of the time ``t`` (:func:`parse_disturbance`), e.g.
``"0.5*sin(2*t) + 0.2"``, one per channel separated by commas.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Sequence
from typing import NamedTuple

import gymnasium as gym
import numpy as np

from .._validation import check_nonnegative, check_positive, check_real
from ..envs.base import SmoMujocoEnv, instability_warnings

__all__ = [
    "ClosedLoopRun",
    "ExternalForce",
    "closed_loop_metrics",
    "parse_disturbance",
    "run_closed_loop",
    "scale_body_mass",
]

#: functions and constants a disturbance expression may use (NumPy's)
_FUNCTIONS = {
    name: getattr(np, name)
    for name in ("sin", "cos", "tan", "exp", "log", "sqrt", "abs", "sign", "tanh", "arctan", "minimum", "maximum")
}
_FUNCTIONS["step"] = lambda x: np.heaviside(x, 1.0)
_CONSTANTS = {"pi": np.pi, "e": np.e}
_NODES = (
    ast.Expression,
    ast.BinOp,
    ast.UnaryOp,
    ast.Call,
    ast.Name,
    ast.Load,
    ast.Constant,
    ast.Add,
    ast.Sub,
    ast.Mult,
    ast.Div,
    ast.Pow,
    ast.USub,
    ast.UAdd,
    ast.Tuple,
)


def parse_disturbance(expr: str) -> Callable[[float], np.ndarray]:
    r"""A function ``f(t) -> ndarray (m,)`` from comma-separated expressions of ``t``.

    Allowed: numbers, ``t``, ``pi``, ``e``, ``+ - * / **``, and :data:`_FUNCTIONS` (``sin cos tan exp log sqrt abs
    sign tanh arctan minimum maximum``, and ``step(x)``, the unit step). Nothing else is evaluated, so an
    expression from the command line cannot run code.

    Examples
    --------
    >>> f = parse_disturbance("0.5*sin(2*t) + 0.2, 0")
    >>> f(0.0)
    array([0.2, 0. ])
    """
    if not isinstance(expr, str) or not expr.strip():
        raise ValueError(f"expected a disturbance expression of t such as '0.5*sin(2*t)', actual value: {expr!r}")
    try:
        tree = ast.parse(f"({expr.strip()},)", mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"expected a valid expression of t, actual value: {expr!r} ({exc.msg})") from None
    except (RecursionError, MemoryError):  # nesting deeper than the parser's stack
        raise ValueError(f"expected an expression of t nested less deeply, actual value: {expr!r:.80}") from None
    for node in ast.walk(tree):
        if not isinstance(node, _NODES):
            raise ValueError(
                f"expected arithmetic, t and the functions {sorted(_FUNCTIONS)} only, actual value: {expr!r} "
                f"uses {type(node).__name__}"
            )
        if isinstance(node, ast.Name) and node.id not in _FUNCTIONS and node.id not in _CONSTANTS and node.id != "t":
            raise ValueError(f"expected names t, {sorted(_CONSTANTS)} or functions, actual value: {node.id!r}")
        if isinstance(node, ast.Call) and not (isinstance(node.func, ast.Name) and node.func.id in _FUNCTIONS):
            raise ValueError(f"expected calls of {sorted(_FUNCTIONS)} only, actual value: {ast.unparse(node)!r}")
        if isinstance(node, ast.Constant):
            if type(node.value) not in (int, float):
                raise ValueError(f"expected numbers only, actual value: {node.value!r} in {expr!r}")
            node.value = float(node.value)  # float arithmetic: 9**9**9 overflows instead of running for minutes
    try:
        code = compile(tree, "<disturbance>", "eval")
    except (RecursionError, MemoryError):
        raise ValueError(f"expected an expression of t nested less deeply, actual value: {expr!r:.80}") from None
    scope = {"__builtins__": {}, **_FUNCTIONS, **_CONSTANTS}

    def disturbance(t: float) -> np.ndarray:
        t = check_real("t", t)
        try:
            with np.errstate(all="ignore"):  # a non-finite value is reported below, with the time
                value = np.array(eval(code, scope, {"t": t}), dtype=float)  # the tree was checked above
        except (ArithmeticError, TypeError, ValueError, RecursionError) as exc:
            raise ValueError(
                f"expected {expr!r:.80} to evaluate at t = {t!r}, actual value: {type(exc).__name__}: {exc}"
            ) from None
        if value.ndim != 1 or not np.isfinite(value).all():
            raise ValueError(f"expected {expr!r:.80} finite numbers at t = {t!r}, actual value: {value!r:.200}")
        return value

    disturbance(0.0)  # wrong arguments of a function, nested tuples: refused now, not in the middle of a run
    disturbance.expression = expr  # for tables and plots
    return disturbance


class ExternalForce(gym.Wrapper):
    r"""Apply a generalized force :math:`w(t)` to chosen joints, through MuJoCo's ``qfrc_applied``.

    Evaluated at the start of every environment step and held over its physics steps (zero-order hold at the
    control rate); reported as ``info["disturbance"]``. On the joints of an environment's own disturbance input (the
    smo_gym environments' ``set_disturbance``, which rewrites them at every step) the force goes through that
    input; on other joints ``qfrc_applied`` is written at their ``qvel`` addresses before the step (MuJoCo never
    clears it; a reset does).

    Parameters
    ----------
    env : gymnasium.Env
        A MuJoCo environment (any wrapper stack).
    force : callable
        ``force(t) -> array_like (m,)`` of the simulation time ``data.time`` [s].
    dofs : array_like of int, shape (m,)
        ``qvel`` addresses of the channels.
    """

    def __init__(self, env: gym.Env, force: Callable[[float], np.ndarray], dofs):
        super().__init__(env)
        if not callable(force):
            raise TypeError(f"expected force to be a callable f(t) -> array, actual value: {force!r}")
        self.force = force
        dofs = np.asarray(dofs).reshape(-1)
        if dofs.dtype.kind not in "iu":  # 0.9 was taken as dof 0
            raise TypeError(f"expected dofs to be integer qvel addresses, actual value: {dofs!r}")
        self.dofs = dofs.astype(int)
        nv = self.env.unwrapped.model.nv
        if self.dofs.size == 0 or self.dofs.min() < 0 or self.dofs.max() >= nv:
            raise ValueError(f"expected qvel addresses in [0, {nv}), actual value: {self.dofs.tolist()}")
        unwrapped = self.env.unwrapped
        own = [int(d) for d in unwrapped.disturbance_dofs] if isinstance(unwrapped, SmoMujocoEnv) else []
        # the environment writes its own channels at every step: forces on them go through its input
        self._own_slot = np.array([own.index(int(d)) for d in self.dofs if int(d) in own], dtype=int)
        self._own_mask = np.array([int(d) in own for d in self.dofs], dtype=bool)

    def _value(self) -> np.ndarray:
        w = np.broadcast_to(np.asarray(self.force(float(self.env.unwrapped.data.time)), dtype=float), self.dofs.shape)
        if not np.all(np.isfinite(w)):
            raise ValueError(f"expected a finite external force, actual value: {w!r}")
        return w

    def step(self, action):
        w = self._value()
        u = self.env.unwrapped
        if not self._own_mask.any():
            u.data.qfrc_applied[self.dofs] = w
            obs, reward, terminated, truncated, info = self.env.step(action)
        else:  # added to the environment's own constant for this step, which is then restored as it was
            constant = u.constant_disturbance
            total = constant.copy()
            total[self._own_slot] += w[self._own_mask]
            u.set_disturbance(total)
            u.data.qfrc_applied[self.dofs[~self._own_mask]] = w[~self._own_mask]
            try:
                obs, reward, terminated, truncated, info = self.env.step(action)
            finally:
                u.set_disturbance(constant)
        info["disturbance"] = w.copy()
        return obs, reward, terminated, truncated, info


def scale_body_mass(body: str, factor: float) -> Callable[[gym.Env], None]:
    """An event for :func:`run_closed_loop`: multiply a body's mass and inertia by ``factor`` (a payload change)."""
    factor = check_positive("factor", factor)

    def event(env: gym.Env) -> None:
        model = env.unwrapped.model
        try:
            b = model.body(body).id
        except KeyError:
            names = [model.body(i).name for i in range(model.nbody)]
            raise ValueError(f"expected a body of the model ({', '.join(names)}), actual value: {body!r}") from None
        model.body_mass[b] *= factor
        model.body_inertia[b] *= factor

    event.description = f"mass of {body!r} x {factor:g}"
    return event


class ClosedLoopRun(NamedTuple):
    """Sampled trajectories of one closed-loop run (row ``k`` at ``t_k``, before the step's command acts).

    Attributes
    ----------
    name : str
        The policy's name.
    t : ndarray, shape (T,)
    qpos, qvel : ndarray, shape (T, nq), (T, nv)
        True state.
    qpos_measured : ndarray, shape (T, nq)
    ctrl : ndarray, shape (T, nu)
        Command applied over ``[t_k, t_k+1)``.
    disturbance : ndarray, shape (T, m)
        True external force over ``[t_k, t_k+1)``.
    diagnostics : tuple of ControlDiagnostics
        The policy's estimates after each command.
    target : ndarray, shape (nq,)
    terminated : bool
        The environment ended the episode early (e.g. a pendulum fell).
    """

    name: str
    t: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    qpos_measured: np.ndarray
    ctrl: np.ndarray
    disturbance: np.ndarray
    diagnostics: tuple
    target: np.ndarray
    terminated: bool

    @property
    def qvel_hat(self) -> np.ndarray:
        """Estimated velocities, shape ``(T, nv)``."""
        return np.array([d.qvel for d in self.diagnostics])

    @property
    def disturbance_hat(self) -> np.ndarray:
        """Identified disturbance, shape ``(T, m)``."""
        return np.array([d.disturbance for d in self.diagnostics])


def run_closed_loop(
    env: gym.Env,
    policy,
    *,
    t_final: float,
    seed: int | None = 0,
    disturbance: Callable[[float], np.ndarray] | None = None,
    disturbance_dofs=None,
    sensor="encoder-12bit-noisy",
    events: Sequence[tuple[float, Callable[[gym.Env], None]]] = (),
    target=None,
) -> ClosedLoopRun:
    r"""Run ``policy`` on ``env`` for ``t_final`` seconds from the environment's own reset, sensing through
    :class:`~smo_gym.wrappers.EstimatedVelocity`.

    Parameters
    ----------
    env : gymnasium.Env
        A fresh MuJoCo environment (it is wrapped here: the external force, then the sensing); closed at the end.
    policy : OutputFeedbackPolicy
        Designed for ``env`` (its ``dt`` must be the environment step).
    t_final : float
        Duration [s]; the run stops earlier if the environment terminates.
    seed : int, optional
        Seeds the environment's reset and the sensor.
    disturbance : callable, optional
        ``w(t)`` on ``disturbance_dofs`` (default the policy's disturbance channels, else the actuated joints).
    sensor : str or Sensor
        Sensor preset of the wrapper.
    events : sequence of (float, callable)
        ``(time, event(env))``: applied once at the first step at or after ``time`` (e.g. :func:`scale_body_mass`).
    target : array_like, shape (nq,), optional
        Reference configuration recorded with the run (default the policy's operating point, else ``qpos0``).
    """
    from ..wrappers import EstimatedVelocity

    t_final = check_positive("t_final", t_final)
    dt = float(env.unwrapped.dt)
    if abs(policy.dt - dt) > 1e-12 * dt:
        raise ValueError(f"expected a policy designed for dt = {dt} (the environment step), actual value: {policy.dt}")
    model = env.unwrapped.model
    # the sensing of the wrapper; the policy reads the measured positions only, so the cheapest observer suffices
    sensed = EstimatedVelocity(env, sensor=sensor, rate="env", observer="finite-difference")
    if disturbance is not None:  # on top: the sensing wrapper accepts only observation wrappers beneath it
        if disturbance_dofs is None:  # the linearized design's channels
            disturbance_dofs = getattr(getattr(policy, "design", None), "disturbance_dofs", None)
        if disturbance_dofs is None:  # the joints the actuators drive
            disturbance_dofs = np.unique(model.jnt_dofadr[model.actuator_trnid[:, 0]])
        sensed = ExternalForce(sensed, disturbance, disturbance_dofs)
    if target is None:
        op = getattr(getattr(policy, "design", None), "operating_point", None)
        target = getattr(policy, "target", None) if op is None else op.qpos
    target = model.qpos0.copy() if target is None else np.asarray(target, dtype=float)
    pending = sorted(_checked_events(events), key=lambda e: e[0])
    _, info = sensed.reset(seed=seed)
    data = env.unwrapped.data
    unstable = instability_warnings(data)
    policy.reset(info["smo"]["qpos_measured"])
    n = int(round(t_final / dt))
    rows: dict[str, list] = {k: [] for k in ("t", "qpos", "qvel", "qm", "ctrl", "w", "diag")}
    terminated = False
    for k in range(n):
        t = k * dt
        while pending and pending[0][0] <= t + 1e-12:
            pending.pop(0)[1](sensed)
        smo = info["smo"]
        u = policy.act(smo["qpos_measured"])
        rows["t"].append(t)
        rows["qpos"].append(np.array(smo["qpos"]))
        rows["qvel"].append(np.array(smo["qvel"]))
        rows["qm"].append(np.array(smo["qpos_measured"]))
        rows["ctrl"].append(u.copy())
        rows["diag"].append(policy.diagnostics)
        _, _, terminated, _truncated, info = sensed.step(u)
        rows["w"].append(np.atleast_1d(info.get("disturbance", np.zeros(0))).copy())
        if instability_warnings(env.unwrapped.data) > unstable:  # MuJoCo reset the simulation: the run failed
            terminated = True
        if terminated:
            break
    sensed.close()
    return ClosedLoopRun(
        name=getattr(policy, "name", type(policy).__name__),
        t=np.array(rows["t"]),
        qpos=np.array(rows["qpos"]),
        qvel=np.array(rows["qvel"]),
        qpos_measured=np.array(rows["qm"]),
        ctrl=np.array(rows["ctrl"]),
        disturbance=np.array(rows["w"]),
        diagnostics=tuple(rows["diag"]),
        target=target,
        terminated=bool(terminated),
    )


def _checked_events(events) -> list:
    """``(time, event)`` pairs with a finite time >= 0 and a callable (a NaN time was never reached, silently)."""
    checked = []
    for event in events:
        if not (isinstance(event, tuple) and len(event) == 2 and callable(event[1])):
            raise TypeError(f"expected events as (time, callable) pairs, actual value: {event!r:.80}")
        checked.append((check_nonnegative("event time", event[0]), event[1]))
    return checked


def closed_loop_metrics(run: ClosedLoopRun, t_steady: float) -> dict[str, float]:
    r"""The table's numbers for one run.

    ``error RMS`` and ``steady band`` are the RMS and the maximum of :math:`\|q - q^*\|_\infty` over
    :math:`t \ge` ``t_steady`` (all joints); ``effort RMS`` the RMS of the command there; ``TV(u)/s`` its total
    variation per second (:func:`smo_gym.control.total_variation_rate`); ``ident. RMS`` the RMS of
    :math:`\hat w - w` there (NaN for a policy that does not identify); ``converged [s]`` the observer's
    convergence time: the first time after which the velocity error :math:`\|\hat v - v\|_\infty` stays below twice
    its 95th percentile over the steady window. A run that terminated early reports ``inf`` errors.
    """
    from .simulation import total_variation_rate

    if not isinstance(run, ClosedLoopRun):
        raise TypeError(f"expected a ClosedLoopRun, actual value: {type(run).__name__}")
    t_steady = check_real("t_steady", t_steady)
    out = {"fell": float(run.terminated)}
    sel = run.t >= t_steady
    if not run.terminated and sel.sum() == 1:
        raise ValueError(
            f"expected a steady window of two samples or more, actual value: one, from t_steady = {t_steady!r} "
            f"(the run ends at {run.t[-1]!r})"
        )
    if run.terminated or not sel.any():
        return {**out, "error RMS": np.inf, "steady band": np.inf, "effort RMS": np.nan, "TV(u)/s": np.nan,
                "ident. RMS": np.nan, "converged [s]": np.nan}  # fmt: skip
    err = np.abs(run.qpos - run.target).max(axis=1)
    out["error RMS"] = float(np.sqrt(np.mean(err[sel] ** 2)))
    out["steady band"] = float(err[sel].max())
    out["effort RMS"] = float(np.sqrt(np.mean(run.ctrl[sel] ** 2)))
    out["TV(u)/s"] = total_variation_rate(run.ctrl[sel], run.t[sel])
    w_hat = run.disturbance_hat
    identifies = w_hat.shape == run.disturbance.shape and np.any(w_hat != 0)
    out["ident. RMS"] = float(np.sqrt(np.mean((w_hat - run.disturbance)[sel] ** 2))) if identifies else np.nan
    verr = np.abs(run.qvel_hat - run.qvel[:, : run.qvel_hat.shape[1]]).max(axis=1)
    level = 2.0 * np.quantile(verr[sel], 0.95)
    above = np.nonzero(verr > level)[0]
    out["converged [s]"] = float(run.t[above[-1] + 1]) if above.size and above[-1] + 1 < run.t.size else 0.0
    return out
