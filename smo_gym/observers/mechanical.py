r"""Model-based super-twisting velocity observers for mechanical systems.

A mechanical system with measured positions :math:`q \in \mathbb R^n`,

.. math:: \dot q = v,\qquad \dot v = f(q, v, u) + w,\qquad y = q,

where ``f`` is what a model knows (inertia, Coriolis, gravity, springs, damping, actuators) and ``w`` what it does
not (contacts, model mismatch, external forces). The observers here get ``f`` from a *dynamics object* (the
:class:`Dynamics` protocol, implemented for MuJoCo by :class:`smo_gym.mechanics.MujocoDynamics`), so their
discontinuous gain bounds only ``w`` instead of the whole acceleration, and the equivalent output injection
estimates ``w`` itself (external joint torques :math:`M(q) w`).

Discretizations
---------------
Both observers share one recursion (:mod:`smo_gym.observers._mechanical_kernels`), per joint, with the model term
``m`` evaluated *explicitly* at the previous sample and the sliding-mode injection treated either

``"semi-implicit"`` (default)
    implicitly, in closed form (the set-valued implicit Euler of the super-twisting part, Brogliato, Polyakov and
    Efimov 2020, with the model term as a known drift): no discretization chattering; inside the sliding set the
    injection takes the exact equivalent value.
``"euler"``
    explicitly (forward Euler of the injection): chattering of amplitude :math:`O(k_2 h)` in the velocity.

The model prediction is :math:`\hat q^- = \hat q + h\hat v + c h^2 m`, :math:`\hat v^- = \hat v + h m`, with
:math:`c = 1/2` (Taylor, consistent with the continuous-time plant; RK4 plants) or, for a plant integrated by
MuJoCo's semi-implicit Euler with ``n`` physics steps per sample, :math:`c = (n+1)/(2n)` (``euler_substeps=n``),
which reproduces that integrator's discrete flow exactly when the model is exact and the acceleration constant
over the sample.

Saturation (Wetzlinger et al., eq. (33))
--------------------------------
With ``accel_bound`` the model term is clipped, :math:`\mathrm{sat}_{L_\gamma}(m)`: a large velocity error then
cannot drive the model term (quadratic in velocity through the Coriolis terms) to a finite escape time, which is
what makes an unsaturated model-based observer fail from large initial errors on multi-DOF systems.

References
----------
.. [DFL05] J. Davila, L. Fridman and A. Levant, "Second-order sliding-mode observer for mechanical systems",
   IEEE TAC 50(11), 2005 (presented in Fridman's slides, section 4, where the correction signs are
   printed flipped: the correct injections use ``y - xhat_1`` with positive gains).
.. [AMFA18] J. C. Apaza-Perez, J. A. Moreno and L. Fridman, "Dissipative approach to sliding mode observers
   design for uncertain mechanical systems", Automatica 87, 2018 (in Fridman's slides, "Dissipative approach").
.. [WRH] M. Wetzlinger, M. Reichhartinger and M. Horn, "Higher order sliding mode inspired nonlinear
   discrete-time observer", eq. (33).
.. [BPE20] B. Brogliato, A. Polyakov and D. Efimov, "The implicit discretization of the super-twisting
   sliding-mode control algorithm", IEEE TAC 65(8), 2020.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from .._validation import (
    as_real_array,
    check_int_in_range,
    check_keywords,
    check_mask,
    check_positive,
)
from ..design.gains import super_twisting_gains
from . import _mechanical_kernels as _mk
from .base import Observer, checked_input
from .registry import register_observer

__all__ = ["CoordinateTransform", "DissipativeSuperTwisting", "Dynamics", "MechanicalSuperTwisting"]


@runtime_checkable
class Dynamics(Protocol):
    r"""What a model-based observer needs from a mechanical model.

    Attributes
    ----------
    n : int
        Number of measured coordinates (the observer's channels).

    Methods
    -------
    acceleration(q, v, u=None) -> ndarray, shape (..., n)
        :math:`f(q, v, u)`, the model acceleration; ``q, v`` of shape ``(..., n)`` (batched over leading
        dimensions), ``u`` the input in the object's own convention (controls, torques) or ``None``. Must return
        an array (it is copied into the observer's state).
    inertia(q) -> ndarray, shape (..., n, n)
        :math:`M(q)`, to turn acceleration disturbances into joint torques.
    """

    n: int

    def acceleration(self, q, v, u=None) -> np.ndarray: ...

    def inertia(self, q) -> np.ndarray: ...


def _check_dynamics(dynamics) -> int:
    if not isinstance(dynamics, Dynamics):
        raise TypeError(
            "expected a dynamics object with n, acceleration(q, v, u) and inertia(q), actual value: "
            f"{type(dynamics).__name__}"
        )
    return check_int_in_range("dynamics.n", dynamics.n, 1, 10_000)


def _model_term_error(shape, value) -> ValueError:
    return ValueError(
        f"expected dynamics.acceleration to return an array of shape {shape}, actual value: "
        f"{type(value).__name__} of shape {np.shape(value) if hasattr(value, 'shape') else '?'}"
    )


def _signed_root(e: np.ndarray) -> np.ndarray:
    return np.sign(e) * np.sqrt(np.abs(e))


class _ModelBasedSuperTwisting(Observer):
    """Shared shell: model term in Python (dynamics object), injection in the compiled kernel."""

    discretizations = ("semi-implicit", "euler")
    takes_input = True
    #: the observer runs in transformed coordinates (:meth:`_measure`, :meth:`_to_estimate` and
    #: :meth:`_from_estimate` are not the identity): a subclass that overrides them sets this
    transformed: ClassVar[bool] = False

    def __init__(self, dt, dynamics, *, accel_bound, discretization, euler_substeps, disturbance_time_constant):
        super().__init__(dt, 1, discretization)
        if not self.dt * self.dt > 0.0:  # the prediction divides by h^2 (model_substeps) and scales by it
            raise ValueError(f"expected dt with a representable square dt**2 > 0, actual value: {self.dt!r}")
        self.dynamics = dynamics
        self.n = _check_dynamics(dynamics)
        self.accel_bound = None if accel_bound is None else self._per_channel("accel_bound", accel_bound, (self.n,))
        if euler_substeps is None:
            self.position_weight = 0.5
        else:
            ns = check_int_in_range("euler_substeps", euler_substeps, 1, 1_000_000)
            self.position_weight = (ns + 1) / (2.0 * ns)
        self.euler_substeps = euler_substeps
        self.disturbance_time_constant = check_positive("disturbance_time_constant", disturbance_time_constant)
        self._y_prev: np.ndarray | None = None
        self._v0 = None
        self._model_call = None
        self._mb_out_shape = None
        self._neg_bound = None if self.accel_bound is None else -self.accel_bound
        self.model_substeps = 1

    # ---- hooks -------------------------------------------------------------------------------------------
    def _gains_row(self) -> np.ndarray:  # pragma: no cover - abstract
        """``(g11, g12, g20, g21, g22)`` per channel, shape ``(n, 5)``."""
        raise NotImplementedError

    def _measure(self, y: np.ndarray) -> np.ndarray:
        """Measurement in observer coordinates (identity unless transformed)."""
        return y

    def _model_term(self, y_prev: np.ndarray, state: np.ndarray, u) -> np.ndarray:  # pragma: no cover
        """Model term ``m`` (a new array of the measurement shape) from the previous measurement and the state."""
        raise NotImplementedError

    def _to_estimate(self, x1: np.ndarray, x2: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return x1, x2

    def _from_estimate(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return q, v

    # ---- Observer plumbing -------------------------------------------------------------------------------
    @property
    def _kernel(self):
        return _mk.mechanical_kernel

    def _state_width(self) -> int:
        return _mk.STATE_WIDTH

    def _innovation_column(self) -> int:
        return _mk.INNOVATION

    def _channel_params(self, shape):
        if shape[-1] != self.n:
            raise ValueError(f"expected measurements with {self.n} channels (dynamics.n), actual value: shape {shape}")
        N = int(np.prod(shape))
        beta = self.dt / (self.disturbance_time_constant + self.dt)
        head = np.array([self.dt, self.position_weight])
        tail = np.array(
            [1.0 if self.discretization == "semi-implicit" else 0.0, beta, 1.0 if self.model_substeps > 1 else 0.0]
        )
        bound = np.full(self.n, np.inf) if self.accel_bound is None else self.accel_bound
        rows = np.hstack([np.tile(head, (self.n, 1)), self._gains_row(), np.tile(tail, (self.n, 1)), bound[:, None]])
        return np.tile(rows, (N // self.n, 1))

    def _initial_state(self, y0, params):
        y0s = y0.reshape(self._shape)
        v0 = np.zeros(self._shape) if self._v0 is None else np.broadcast_to(self._v0, self._shape)
        x1, x2 = self._from_estimate(y0s, v0)
        state = np.zeros((y0.shape[0], _mk.STATE_WIDTH))
        state[:, _mk.X1] = np.reshape(x1, -1)
        state[:, _mk.X2] = np.reshape(x2, -1)
        return state

    @check_keywords
    def reset(self, y0, mask=None, v0=None, *, derivatives=None) -> np.ndarray:
        """Start at the measurement ``y0`` (shape ``(..., n)``) with velocity estimate ``v0`` (default zero).

        ``mask`` restarts only some batch elements (see :meth:`Observer.reset`). ``derivatives`` of shape
        ``(..., n, 1)`` is the common observer spelling of ``v0`` (``derivatives[..., 0]``); give one of them.
        ``v0`` must be finite and broadcast to the shape of ``y0``; anything rejected leaves the observer as it was.
        """
        y0 = self._as_measurement(y0, "y0")
        if derivatives is not None:
            if v0 is not None:
                raise TypeError("expected v0 or derivatives (the same initial velocity), actual value: both given")
            x0 = self._initial_estimate(y0, derivatives)
            v0 = None if x0 is None else x0[..., 1]
        if v0 is not None:
            v0 = as_real_array("v0", v0)
            try:
                np.broadcast_to(v0, y0.shape)
            except ValueError:
                raise ValueError(
                    f"expected v0 broadcastable to the shape of y0 {y0.shape}, actual value: shape {v0.shape}"
                ) from None
            if not np.isfinite(v0).all():
                bad = tuple(int(i) for i in np.argwhere(~np.isfinite(v0))[0])
                raise ValueError(f"expected a finite v0, actual value: {v0[bad]!r} at index {bad}")
        self._v0 = v0
        try:
            super().reset(y0, mask)
        finally:
            self._v0 = None
        if mask is None:
            self._y_prev = np.ascontiguousarray(y0, dtype=np.float64).copy()
            self._mb_out_shape = self._shape + (2,)
            self._model_call = None
        else:
            mk = check_mask("mask", mask)
            if mk.shape == self._shape[:-1]:
                mk = np.broadcast_to(mk[..., None], self._shape)
            self._y_prev[mk] = y0[mk]
        q, v = self._to_estimate(
            self._state[:, 0].reshape(self._shape), self._state[:, 1].reshape(self._shape), self._y_prev
        )
        self._estimate = np.stack([q, v], axis=-1)
        return self._estimate.copy()

    def update(self, y, u=None) -> np.ndarray:
        """Process one sample.

        Parameters
        ----------
        y : array_like, shape (..., n)
            Measured positions at the new sample.
        u : array_like, optional
            The input that acted during the sample interval ending at ``y`` (for an environment: the action passed
            to the ``step`` that returned ``y``), in the dynamics object's convention.

        Returns
        -------
        ndarray, shape (..., n, 2)
            ``[..., 0]`` position estimate, ``[..., 1]`` velocity estimate.
        """
        state = self._state
        if state is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")
        if type(y) is not np.ndarray or y.dtype != np.float64 or not y.flags.c_contiguous:
            y = np.ascontiguousarray(self._as_measurement(y, "y"))
        if y.shape != self._shape:
            raise ValueError(f"expected y with shape {self._shape}, actual value: {y.shape}")
        u = checked_input(u)
        # model term at the previous sample (explicit), optionally saturated (Wetzlinger et al., eq. (33)): the
        # kernel reads it from the row it writes (the scratch), so a rejected step leaves the state as it was
        scratch = self._scratch
        if self.model_substeps == 1:
            m = self._model_term(self._y_prev, state, u)  # saturated in the kernel
            try:
                scratch[:, _mk.MODEL] = np.reshape(m, -1)
            except (ValueError, TypeError):
                raise _model_term_error(self._shape, m) from None
        else:
            m, m_pos = self._substep_prediction(self._y_prev, state, u)
            scratch[:, _mk.MODEL] = m.reshape(-1)
            scratch[:, _mk.MODEL_POS] = m_pos.reshape(-1)
        X = self._measure(y) if self.transformed else y
        out = np.empty(self._mb_out_shape)
        call = self._model_call
        if call is None:
            call = self._bind_model_kernel(state, X, out)
        status = call(state, X, self._params, scratch, out)
        if status != -1:
            if status >= 0:
                self._raise_nonfinite(y, "y")
            raise _divergence(self)
        self._state, self._scratch = self._scratch, state
        np.copyto(self._y_prev, y)
        if self.transformed:
            q, v = self._to_estimate(out[..., 0], out[..., 1], y)
            out[..., 0] = q
            out[..., 1] = v
        self._estimate = out
        self.n_updates += 1
        return out

    def __getstate__(self):
        state = super().__getstate__()
        state["_model_call"] = None  # compiled entry points do not pickle; rebound on the next update
        return state

    def _bind_model_kernel(self, state, X, out):
        """Compiled entry point of the kernel for these argument types (skips numba's per-call dispatch)."""
        kernel = self._kernel
        try:
            import numba

            sig = tuple(numba.typeof(a) for a in (state, X, self._params, self._scratch, out))
            if sig not in kernel.overloads:
                kernel.compile(sig)
            self._model_call = kernel.overloads[sig].entry_point
        except Exception:  # numba internals changed: the dispatcher is always correct
            self._model_call = kernel
        return self._model_call

    def _x2(self, state) -> np.ndarray:
        """The x2 column as an array of the measurement shape (a view for a single environment)."""
        return state[:, 1] if len(self._shape) == 1 else state[:, 1].reshape(self._shape)

    @check_keywords
    def run(self, Y, U=None) -> np.ndarray:
        """Process a recorded block ``Y`` (T, ..., n) with inputs ``U`` (T, ...) sample by sample.

        All or nothing, as :meth:`Observer.run`: if a sample is rejected (non-finite ``Y`` or ``U``, a diverging
        state), the observer keeps the state it had before the call.
        """
        return self._run_updates(Y, U, (self._y_prev,))

    def step(self, state, y):
        raise NotImplementedError(
            "expected update(y, u) for a model-based observer (its model term needs the "
            "dynamics and the input), actual value: step(state, y)"
        )

    # ---- disturbance estimate -----------------------------------------------------------------------------
    def _injection_scale(self) -> np.ndarray:
        """Factor turning the x2-channel injection into an acceleration (1, or 1/Upsilon(y))."""
        return 1.0

    @property
    def disturbance(self) -> np.ndarray:
        r"""Low-pass filtered equivalent output injection: the estimate of the unknown acceleration ``w``,
        shape ``(..., n)`` (first-order filter of time constant ``disturbance_time_constant``)."""
        self._require_reset()
        return self._state[:, _mk.FILTERED].reshape(self._shape) * self._injection_scale()

    @property
    def disturbance_raw(self) -> np.ndarray:
        """The unfiltered injection of the last step (the per-sample equivalent value), shape ``(..., n)``."""
        self._require_reset()
        return self._state[:, _mk.INJECTION].reshape(self._shape) * self._injection_scale()

    @property
    def external_torque(self) -> np.ndarray:
        r"""Estimated external generalized forces :math:`\hat\tau_{ext} = M(y)\,\hat w`, shape ``(..., n)``."""
        d = self.disturbance
        M = np.asarray(self.dynamics.inertia(self._y_prev))
        return np.einsum("...ij,...j->...i", M, d)


def _divergence(obs):
    from .._validation import DivergenceError

    return DivergenceError(
        "expected a finite observer state, actual value: non-finite model term or state after the update "
        f"(dt={obs.dt}); the step was rejected and the previous state kept. An unsaturated model term can escape "
        "in finite time from large velocity errors (Coriolis terms): bound it with accel_bound "
        "(Wetzlinger et al., eq. (33)), use the dissipative observer, or reduce dt."
    )


@register_observer("mechanical-super-twisting", bound=2, model_based=True)
class MechanicalSuperTwisting(_ModelBasedSuperTwisting):
    r"""Super-twisting velocity observer for mechanical systems (Davila, Fridman and Levant 2005).

    Per joint, with :math:`e = y - \hat q`,

    .. math::
        \dot{\hat q} = \hat v + k_1 |e|^{1/2}\mathrm{sign}(e),\qquad
        \dot{\hat v} = \mathrm{sat}\bigl(f(y, \hat v, u)\bigr) + k_2\,\mathrm{sign}(e),

    with :math:`k_1 = 1.5\sqrt L,\ k_2 = 1.1 L` where ``L`` bounds
    :math:`|f(y, \hat v, u) - f(y, v, u) + w|`, i.e. only what the model does *not* know plus the model's
    sensitivity to the velocity error. After convergence :math:`\hat v = v` and the equivalent value of
    :math:`k_2\,\mathrm{sign}(e)` equals ``w``; its low-pass filtered value is :attr:`disturbance`, and
    :attr:`external_torque` is :math:`M(y)\,\hat w`.

    Parameters
    ----------
    dt : float
        Sampling step [s].
    dynamics : Dynamics
        The model (e.g. :class:`smo_gym.mechanics.MujocoDynamics`), with ``dynamics.n`` channels.
    lipschitz : float or array_like, shape (n,), optional
        ``L`` per joint; required unless ``k1`` and ``k2`` are both given.
    k1, k2 : float or array_like, optional
        Override the gains.
    accel_bound : float or array_like, optional
        :math:`L_\gamma`: clip the model term to ``[-accel_bound, accel_bound]`` (Wetzlinger et al., eq. (33)). Default
        ``None``: no saturation (not recommended from large initial errors).
    discretization : {"semi-implicit", "euler"}
        See the module docstring.
    euler_substeps : int, optional
        Match a semi-implicit-Euler plant with this many physics steps per sample (see the module docstring).
    model_substeps : int
        Integrate the model over the sample interval with this many semi-implicit Euler substeps (one dynamics
        evaluation each, each saturated) instead of one Taylor step: for observers sampled slower than the
        physics (``rate="env"``), where a single model evaluation per sample misses the variation of ``f``
        within the sample. With ``model_substeps = frame_skip`` the cost per physics step equals that of the
        physics-rate observer. ``euler_substeps`` is then ignored.
    disturbance_time_constant : float
        Time constant [s] of the filter on the equivalent output injection.

    Notes
    -----
    Shapes: measurements ``(..., n)``, estimates ``(..., n, 2)``. ``update(y, u)`` takes the input that acted over
    the interval ending at ``y``. Inside the sliding set of the implicit step the velocity estimate is
    :math:`(y_{k+1} - \hat q_k)/h + (1 - c) h m_k`: a model-corrected backward difference; outside it, the
    correction is bounded by :math:`k_2 h` per step, which is what filters the measurement noise.
    """

    @check_keywords
    def __init__(
        self,
        dt: float,
        dynamics: Dynamics,
        lipschitz=None,
        *,
        k1=None,
        k2=None,
        accel_bound=None,
        discretization: str | None = None,
        euler_substeps: int | None = None,
        model_substeps: int = 1,
        disturbance_time_constant: float = 0.02,
    ):
        super().__init__(
            dt,
            dynamics,
            accel_bound=accel_bound,
            discretization=discretization,
            euler_substeps=euler_substeps,
            disturbance_time_constant=disturbance_time_constant,
        )
        self.model_substeps = check_int_in_range("model_substeps", model_substeps, 1, 100_000)
        if lipschitz is None and (k1 is None or k2 is None):
            raise ValueError("expected lipschitz > 0 or both k1 and k2, actual value: lipschitz=None")
        shape = (self.n,)
        L = None if lipschitz is None else self._per_channel("lipschitz", lipschitz, shape)
        self.lipschitz = L
        self.k1 = super_twisting_gains(L)[0] * np.ones(self.n) if k1 is None else self._per_channel("k1", k1, shape)
        self.k2 = super_twisting_gains(L)[1] * np.ones(self.n) if k2 is None else self._per_channel("k2", k2, shape)

    def _gains_row(self):
        z = np.zeros(self.n)
        return np.column_stack([self.k1, z, self.k2, z, z])

    def _model_term(self, y_prev, state, u):
        return self.dynamics.acceleration(y_prev, self._x2(state), u)

    def _substep_prediction(self, y_prev, state, u):
        r"""Model flow over the sample by ``model_substeps`` semi-implicit Euler steps from ``(y_prev, v_hat)``.

        Returns ``m = (v^- - \hat v)/h`` and ``m_pos = (q^- - y_{prev} - h\hat v)/h^2`` so that the kernel's
        prediction is :math:`\hat q^- = \hat q + h\hat v + h^2 m_{pos}`, :math:`\hat v^- = \hat v + h m`.
        """
        x2 = state[:, 1].reshape(self._shape)
        ns = self.model_substeps
        hs = self.dt / ns
        q = y_prev.copy()
        v = x2.copy()
        dpos = np.zeros(self._shape)
        for _ in range(ns):
            a = self.dynamics.acceleration(q, v, u)
            if np.shape(a) != self._shape:
                raise _model_term_error(self._shape, a)
            a = as_real_array("dynamics.acceleration", a, copy=True)
            if self.accel_bound is not None:
                np.clip(a, self._neg_bound, self.accel_bound, out=a)
            v = v + hs * a
            q = q + hs * v
            if not np.isfinite(q).all():  # (so is v if q is) the next substep's dynamics would refuse it
                raise _divergence(self)
            dpos += hs * (v - x2)
        return (v - x2) / self.dt, dpos / (self.dt * self.dt)


class CoordinateTransform:
    r"""Apaza et al.'s state transform removing a self-quadratic velocity term, tabulated per channel.

    For :math:`\ddot\xi_1 = \psi(\xi_1, \xi_2) + \alpha(\xi_1)\xi_2^2 + \ldots`,

    .. math::
        \Upsilon(y) = \exp\Bigl(-\int_a^y \alpha(s)\,ds\Bigr),\qquad
        x_1 = T_1(\xi_1) = \int_a^{\xi_1}\Upsilon(\mu)\,d\mu,\qquad x_2 = \Upsilon(\xi_1)\,\xi_2,

    gives :math:`\dot x_2 = \Upsilon(\psi + u + w)`: the quadratic term is gone. For a one-DOF system
    :math:`M(q)\ddot q + \tfrac12 M'(q)\dot q^2 + \ldots = \tau`, :math:`\alpha = -M'/(2M)` and
    :math:`\Upsilon = \sqrt{M(q)/M(a)}`, so :math:`x_2^2 M(a)/2` is the kinetic energy.

    ``alpha`` is integrated by the trapezoidal rule on a uniform grid of ``grid`` points over
    ``[lower, upper]`` per channel; :math:`\Upsilon` is held constant outside the range and :math:`T_1` continued
    linearly, so :math:`T_1` stays strictly increasing and invertible everywhere (assumption A-2 of the paper,
    :math:`|\int_a^y\alpha| \le L_\alpha`, holds on the tabulated range by construction).

    Parameters
    ----------
    alpha : callable
        ``alpha(Y) -> A`` with ``Y, A`` of shape ``(G, n)``: column ``i`` of ``A`` is :math:`\alpha_i` evaluated at
        column ``i`` of ``Y`` (per-channel functions of the channel's own coordinate).
    lower, upper : array_like, shape (n,)
    reference : array_like, shape (n,), optional
        ``a``, where :math:`T_1(a) = 0` and :math:`\Upsilon(a) = 1`; default the midpoint.
    grid : int
    """

    @check_keywords
    def __init__(self, alpha: Callable[[np.ndarray], np.ndarray], lower, upper, reference=None, grid: int = 1001):
        if not callable(alpha):
            raise TypeError(f"expected alpha to be a callable alpha(Y) -> A, actual value: {alpha!r}")
        lower = np.atleast_1d(as_real_array("lower", lower))
        upper = np.atleast_1d(as_real_array("upper", upper))
        if (
            lower.shape != upper.shape
            or lower.ndim != 1
            or lower.size == 0
            or np.any(~(upper > lower))
            or not np.isfinite(upper - lower).all()
        ):
            raise ValueError(f"expected finite lower < upper of equal shape (n,), actual value: {lower!r}, {upper!r}")
        n = lower.size
        a = (lower + upper) / 2 if reference is None else as_real_array("reference", reference)
        try:
            a = np.broadcast_to(a, (n,))
        except ValueError:
            raise ValueError(f"expected reference of shape ({n},), actual value: shape {a.shape}") from None
        if np.any(~((a >= lower) & (a <= upper))):
            raise ValueError(f"expected lower <= reference <= upper, actual value: {a!r}")
        G = check_int_in_range("grid", grid, 11, 10**7)
        Y = lower + (upper - lower) * np.linspace(0.0, 1.0, G)[:, None]
        A = as_real_array("alpha(Y)", alpha(Y))
        if A.shape != Y.shape or not np.all(np.isfinite(A)):
            raise ValueError(f"expected alpha(Y) finite with shape {Y.shape}, actual value: shape {A.shape}")
        dy = (upper - lower) / (G - 1)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflowing transform is reported below
            cum = np.vstack([np.zeros(n), np.cumsum((A[1:] + A[:-1]) / 2 * dy, axis=0)])  # int_lower^y alpha
            cum_a = np.array([np.interp(a[i], Y[:, i], cum[:, i]) for i in range(n)])
            ups = np.exp(-(cum - cum_a))
            T = np.vstack([np.zeros(n), np.cumsum((ups[1:] + ups[:-1]) / 2 * dy, axis=0)])
            T_a = np.array([np.interp(a[i], Y[:, i], T[:, i]) for i in range(n)])
            T = T - T_a  # inf - inf where T overflows: reported below, without a warning
            finite = np.isfinite(T).all() and np.all(ups > 0)
        if not finite:
            raise ValueError(
                "expected alpha and a range whose transform Upsilon = exp(-int alpha) and T_1 are "
                "finite and positive, actual value: it overflows (a smaller range or alpha)"
            )
        self.n, self.lower, self.upper, self.reference = n, lower, upper, a
        self.grid_y, self.grid_alpha, self.grid_upsilon, self.grid_T = Y, A, ups, T
        #: :math:`L_\alpha = \max|\int_a^y \alpha|` over the range (assumption A-2)
        self.l_alpha = float(np.max(np.abs(cum - cum_a)))

    def _per_channel(self, fn, y):
        y = as_real_array("y", y)
        if y.ndim == 0 or y.shape[-1] != self.n:
            raise ValueError(f"expected y with shape (..., {self.n}), actual value: shape {y.shape}")
        if not np.isfinite(y).all():
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(y))[0])
            raise ValueError(f"expected finite coordinates, actual value: {y[bad]!r} at channel {bad[-1]}")
        out = np.empty_like(y)
        for i in range(self.n):
            out[..., i] = fn(i, y[..., i])
        return out

    def alpha(self, y) -> np.ndarray:
        r""":math:`\alpha_i(y_i)` (interpolated, zero outside the range), shape ``(..., n)``."""
        return self._per_channel(lambda i, yi: np.interp(yi, self.grid_y[:, i], self.grid_alpha[:, i], 0.0, 0.0), y)

    def upsilon(self, y) -> np.ndarray:
        r""":math:`\Upsilon_i(y_i)`, shape ``(..., n)``."""
        return self._per_channel(lambda i, yi: np.interp(yi, self.grid_y[:, i], self.grid_upsilon[:, i]), y)

    def position(self, y) -> np.ndarray:
        r""":math:`T_1(y)` per channel (linear continuation outside the range), shape ``(..., n)``."""

        def f(i, yi):
            gy, gT, gu = self.grid_y[:, i], self.grid_T[:, i], self.grid_upsilon[:, i]
            base = np.interp(yi, gy, gT)
            return (
                base
                + np.where(yi < gy[0], (yi - gy[0]) * gu[0], 0.0)
                + np.where(yi > gy[-1], (yi - gy[-1]) * gu[-1], 0.0)
            )

        return self._per_channel(f, y)

    def position_inverse(self, x) -> np.ndarray:
        r""":math:`T_1^{-1}(x)` per channel, shape ``(..., n)``."""

        def f(i, xi):
            gy, gT, gu = self.grid_y[:, i], self.grid_T[:, i], self.grid_upsilon[:, i]
            base = np.interp(xi, gT, gy)
            return (
                base
                + np.where(xi < gT[0], (xi - gT[0]) / gu[0], 0.0)
                + np.where(xi > gT[-1], (xi - gT[-1]) / gu[-1], 0.0)
            )

        return self._per_channel(f, x)

    def forward(self, q, v) -> tuple[np.ndarray, np.ndarray]:
        """``T(q, v) = (T1(q), Upsilon(q) v)``."""
        return self.position(q), _finite_product("v", as_real_array("v", v), self.upsilon(q))

    def inverse(self, x1, x2) -> tuple[np.ndarray, np.ndarray]:
        """``T^-1(x1, x2) = (q, x2 / Upsilon(q))``."""
        q = self.position_inverse(x1)
        return q, _finite_product("x2", as_real_array("x2", x2), 1.0 / self.upsilon(q))


def _finite_product(name: str, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a * b`` (broadcast), or ``ValueError`` if ``a`` is not finite or does not broadcast with ``b``."""
    if not np.isfinite(a).all():
        raise ValueError(f"expected finite {name}, actual value: {a!r}")
    try:
        with np.errstate(over="ignore"):
            out = a * b
    except ValueError:
        raise ValueError(f"expected {name} with shape {b.shape}, actual value: {a.shape}") from None
    if not np.isfinite(out).all():
        raise ValueError(f"expected {name} small enough for a finite transformed value, actual value: {a!r}")
    return out


def _gain_value(gains, key):
    if isinstance(gains, Mapping):
        if key not in gains:
            raise ValueError(f"expected gains with keys k1, k2, k3, mu1, mu2, actual value: missing {key!r}")
        return gains[key]
    if not hasattr(gains, key):
        raise TypeError(f"expected gains as a mapping or an ApazaGains, actual value: {type(gains).__name__}")
    return getattr(gains, key)


@register_observer("dissipative-super-twisting", bound=2, model_based=True)
class DissipativeSuperTwisting(_ModelBasedSuperTwisting):
    r"""Dissipative super-twisting observer with the Coriolis-removing transform (Apaza-Perez, Moreno and
    Fridman 2018; Fridman's slides, "Dissipative approach").

    In the coordinates :math:`x = T(\xi)` of :class:`CoordinateTransform` (``y_T = y`` the measured position,
    :math:`X = T_1(y)` the transformed measurement, :math:`e = X - \hat x_1`),

    .. math::
        \dot{\hat x}_1 &= \hat x_2 + k_1\phi_1(e),\\
        \dot{\hat x}_2 &= \Upsilon(y)\,\psi\bigl(y, \Upsilon(y)^{-1}(\hat x_2 - k_3\phi_1(e))\bigr) + k_2\phi_2(e),\\
        \phi_1(e) &= \mu_1\lceil e\rfloor^{1/2} + \mu_2 e,\qquad
        \phi_2(e) = \tfrac{\mu_1^2}{2}\lceil e\rfloor^{0} + \tfrac{3\mu_1\mu_2}{2}\lceil e\rfloor^{1/2} + \mu_2^2 e,

    which is the slide's observer with :math:`\phi(\hat x_1 - x_1) = -\phi(e)` (the injections are odd). ``psi``
    is the model acceleration *without* the removed term,
    :math:`\psi_i(y, v) = f_i(y, v, u) - \alpha_i(y_i) v_i^2`, with ``f`` from the dynamics object (it includes
    the input). Estimates are reported in the original coordinates, :math:`\hat q = T_1^{-1}(\hat x_1)`,
    :math:`\hat v = \hat x_2/\Upsilon(y)`; :attr:`disturbance` is the filtered :math:`k_2\phi_2` divided by
    :math:`\Upsilon(y)`, i.e. an acceleration.

    What is removed, and what is not
    --------------------------------
    Exactly :math:`\alpha_i(y_i)\,v_i^2`, per channel, with :math:`\alpha_i` a function of that channel's own
    coordinate (for one DOF: :math:`-M'/(2M)`, all of the Coriolis/centrifugal term). For several DOF use
    :meth:`smo_gym.mechanics.MujocoDynamics.alpha_function`, which evaluates the self-quadratic coefficient
    :math:`\alpha_i` with the other joints frozen at a reference configuration. The model term still contains
    everything else computed from the full model: cross terms :math:`v_iv_j`, the dependence of
    :math:`\alpha_i` on the other joints, and the difference between the frozen and actual coefficient. Those
    stay quadratic in the velocity error and act as the bounded perturbation of the theory only while the
    velocity errors are bounded; ``accel_bound`` guarantees that bound.

    Parameters
    ----------
    dt : float
    dynamics : Dynamics
    transform : CoordinateTransform
    gains : ApazaGains or mapping
        ``k1, k2, k3, mu1, mu2`` (e.g. from :func:`smo_gym.design.apaza_gains`).
    accel_bound, discretization, euler_substeps, disturbance_time_constant :
        As :class:`MechanicalSuperTwisting`; ``accel_bound`` clips the transformed model term
        :math:`\Upsilon\psi`.
    """

    transformed = True

    @check_keywords
    def __init__(
        self,
        dt: float,
        dynamics: Dynamics,
        transform: CoordinateTransform,
        gains,
        *,
        accel_bound=None,
        discretization: str | None = None,
        euler_substeps: int | None = None,
        disturbance_time_constant: float = 0.02,
    ):
        super().__init__(
            dt,
            dynamics,
            accel_bound=accel_bound,
            discretization=discretization,
            euler_substeps=euler_substeps,
            disturbance_time_constant=disturbance_time_constant,
        )
        if not isinstance(transform, CoordinateTransform) or transform.n != self.n:
            raise TypeError(f"expected a CoordinateTransform with n={self.n}, actual value: {transform!r}")
        self.transform = transform
        shape = (self.n,)
        self.k1 = self._per_channel("k1", _gain_value(gains, "k1"), shape)
        self.k2 = self._per_channel("k2", _gain_value(gains, "k2"), shape)
        self.mu1 = self._per_channel("mu1", _gain_value(gains, "mu1"), shape)
        try:
            mu2 = np.broadcast_to(as_real_array("mu2", _gain_value(gains, "mu2")), shape)
            k3 = np.broadcast_to(as_real_array("k3", _gain_value(gains, "k3")), shape)
        except ValueError:
            raise ValueError(
                f"expected mu2 and k3 broadcastable to ({self.n},), actual value: "
                f"{_gain_value(gains, 'mu2')!r}, {_gain_value(gains, 'k3')!r}"
            ) from None
        if np.any(~(mu2 >= 0)) or not np.all(np.isfinite(mu2)) or not np.all(np.isfinite(k3)):
            raise ValueError(f"expected mu2 >= 0 and finite k3, actual value: mu2={mu2!r}, k3={k3!r}")
        self.mu2, self.k3 = mu2.copy(), k3.copy()

    def _gains_row(self):
        k1, k2, m1, m2 = self.k1, self.k2, self.mu1, self.mu2
        return np.column_stack([k1 * m1, k1 * m2, k2 * m1**2 / 2, 1.5 * k2 * m1 * m2, k2 * m2**2])

    def _measure(self, y):
        return self.transform.position(y)

    def _from_estimate(self, q, v):
        return self.transform.forward(q, v)

    def _to_estimate(self, x1, x2, y):
        return self.transform.position_inverse(x1), x2 / self.transform.upsilon(y)

    def _model_term(self, y_prev, state, u):
        x2 = state[:, 1].reshape(self._shape)
        e = state[:, _mk.ERROR].reshape(self._shape)
        ups = self.transform.upsilon(y_prev)
        phi1 = self.mu1 * _signed_root(e) + self.mu2 * e
        v = (x2 - self.k3 * phi1) / ups
        f = self.dynamics.acceleration(y_prev, v, u)
        if np.shape(f) != self._shape:
            raise _model_term_error(self._shape, f)
        return ups * (as_real_array("dynamics.acceleration", f) - self.transform.alpha(y_prev) * v * v)

    def _injection_scale(self):
        return 1.0 / self.transform.upsilon(self._y_prev)
