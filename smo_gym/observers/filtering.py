r"""Robust exact filtering differentiators (Levant & Livne), of homogeneity degree ``d`` in ``[-1, 0]``.

A differentiator of order ``n`` (estimates :math:`z_0, \ldots, z_n` of :math:`f, \ldots, f^{(n)}`) gets
:math:`n_f` integrators of its output error in front, the filter states :math:`w_1, \ldots, w_{n_f}`:

.. math::
    \dot w_i = w_{i+1} + k_{i-1}\lceil\sigma\rfloor^{p_{i-1}},\quad i < n_f,\qquad
    \dot w_{n_f} = z_0 - f + k_{n_f-1}\lceil\sigma\rfloor^{p_{n_f-1}},\\
    \dot z_j = z_{j+1} + k_{n_f+j}\lceil\sigma\rfloor^{p_{n_f+j}},\quad j < n,\qquad
    \dot z_n = k_{N-1}\lceil\sigma\rfloor^{p_{N-1}},\qquad \sigma = -w_1,

a chain of :math:`N = n + n_f + 1` states :math:`\xi = (w_1, \ldots, w_{n_f}, z_0, \ldots, z_n)` whose first one
is driven to zero (without filter, :math:`\sigma = f - z_0`: the plain differentiator). The injections are those
of Andritsch, Horn, Koch, Niederwieser, Wetzlinger and Reichhartinger: all ``N`` eigenvalues of the error dynamics,
frozen at :math:`\sigma`, sit at :math:`s(\sigma) = -r|\sigma|^q`, :math:`q = d/(1 - d(N-1))`, that is
:math:`k_c = \binom{N}{c+1}r^{c+1}` and :math:`p_c = 1 + q(c+1)`. For ``d = -1``, :math:`p_c = (N-1-c)/N`:
Levant & Livne's filtering differentiator (Levant's differentiator for :math:`n_f = 0`), exact on signals with
:math:`|f^{(n+1)}| \le L` after a finite time, with gains from :math:`(s + r)^N`; for ``d = 0`` the linear
high-gain observer with all poles at :math:`-r`. The filter states integrate the error :math:`n_f` times, so that
noise of small local average is rejected. Accuracy for ``d = -1``, by the homogeneity argument of Levant (2003)
as Levant & Livne use it (weights ``n + 1 - i`` for :math:`z_i - f^{(i)}`, ``n + 1 + k`` for the k-th filter state
from the input): noise bounded by :math:`\varepsilon` gives :math:`O(\varepsilon^{(n+1-i)/(n+1)})` in
:math:`z_i`, as without filter; noise whose :math:`n_f`-th integral is bounded by :math:`\varepsilon` gives
:math:`O(\varepsilon^{(n+1-i)/(n+n_f+1)})`; i.i.d. sampled noise of amplitude :math:`\varepsilon` (integrals that
are random walks) gives a velocity error :math:`O(\varepsilon^{n/(n+3/2)}\tau^{n/(2n+3)})` for every
:math:`n_f \ge 1`, which ``tests/test_filtering_differentiator.py`` derives and measures.

Discretizations
---------------
``"matching"``
    the state-dependent eigenvalue mapping of Wetzlinger, Reichhartinger and Horn (2019), (16), as Andritsch et
    al. extend it: :math:`z = e^{h s(\sigma_k)}`, placed by Ackermann's formula on the sampled chain
    (:func:`~smo_gym.observers.differentiators.eigenvalue_mapping_vectors`). It is the compiled eigenvalue-map step
    of :class:`~smo_gym.observers.Levant` ``(discretization="matching")`` and
    :class:`~smo_gym.observers.DiscreteTimeHOSM` (:func:`smo_gym.observers._kernels.eigmap_channel_step`), which is
    this family's ``filtering_order = 0``, ``d = -1`` case, bit for bit.
``"implicit"``
    backward Euler of the continuous system, solved exactly per sample: its first row is one scalar equation in
    :math:`\sigma_{k+1}`, strictly monotone, with a dead zone for ``d = -1``
    (:func:`smo_gym.observers._kernels.filtering_implicit_channel_step`).

References
----------
.. [LL20] A. Levant and M. Livne, "Robust exact filtering differentiators", European Journal of Control 55, 2020.
.. [AHK21] B. Andritsch, M. Horn, S. Koch, H. Niederwieser, M. Wetzlinger and M. Reichhartinger, "The robust exact
   differentiator toolbox revisited: filtering and discretization features", IEEE International Conference on
   Mechatronics (ICM), 2021.
.. [WRH] M. Wetzlinger, M. Reichhartinger and M. Horn, "Higher order sliding mode inspired nonlinear
   discrete-time observer", eqs. (16), (31), (35).
"""

from __future__ import annotations

from math import comb

import numpy as np

from .._validation import check_int_in_range, check_keywords, check_positive_array, check_real_in_range
from ..design.gains import MAX_LEVANT_ORDER
from . import _kernels
from .base import Observer
from .differentiators import (
    _ImplicitOutputs,
    _pack_eigmap,
    backward_difference_outputs,
    eigenvalue_map_rate,
    eigenvalue_mapping_vectors,
)
from .registry import lipschitz_rule, register_observer

__all__ = ["MAX_FILTERING_ORDER", "FilteringDifferentiator"]

#: the largest number of filter states ``n_f`` (with ``order <= 5``, at most 10 states, as ``DiscreteTimeHOSM``)
MAX_FILTERING_ORDER = 4


@register_observer(
    "filtering",
    steps=(_kernels.eigmap_rows, _kernels.filtering_implicit_rows),
    calibrate=lipschitz_rule,
    given=(("lipschitz",), ("p1",)),
    examples=(
        dict(order=2, filtering_order=1, lipschitz=5.0, discretization="matching"),
        dict(order=1, filtering_order=2, lipschitz=5.0, degree=-0.5, discretization="matching"),
        dict(order=3, filtering_order=0, lipschitz=5.0, degree=0.0, discretization="matching"),
        dict(order=2, filtering_order=1, lipschitz=5.0, discretization="implicit"),
        dict(order=1, filtering_order=2, lipschitz=5.0, degree=-0.4, discretization="implicit"),
        dict(order=2, filtering_order=0, lipschitz=5.0, degree=0.0, discretization="implicit"),
    ),
)
class FilteringDifferentiator(_ImplicitOutputs, Observer):
    r"""Levant & Livne's robust exact filtering differentiator of homogeneity degree ``d`` ([LL20], [AHK21]).

    Order ``n`` (``order``) with :math:`n_f` (``filtering_order``) integrations of the output error in front
    (module notes): the estimates ``xhat[..., i]`` are :math:`z_i \approx f^{(i)}`, ``i = 0..n``; the filter
    states are internal (columns ``n + 1 ..`` of :attr:`state`).

    Parameters
    ----------
    order : int
        ``n`` in ``[1, 5]``: derivatives estimated.
    filtering_order : int
        :math:`n_f` in ``[0, 4]``: filter states (0: the plain differentiator).
    dt : float
        Sampling step ``h``.
    lipschitz : float or array_like
        ``L >= |f^(n+1)|`` (per channel if an array); sets the default rate ``r``.
    degree : float
        Homogeneity degree ``d`` in ``[-1, 0]``: -1 the discontinuous (sliding-mode) differentiator, 0 the linear
        high-gain one, in between continuous and finite-time-free.
    discretization : {"implicit", "matching"}
        Module notes; default ``"implicit"``, the more accurate of the two on every table of the documentation
        (the wrapper's accuracy rows: geometric-mean regret 1.43 against 3.22; at 10 ms the eigenvalue mapping can
        be worse than the backward difference).
    p1 : float or array_like, optional
        The rate ``r`` (Wetzlinger et al.'s :math:`p_1`): the gains are those of :math:`(s + r)^N`,
        :math:`N = n + n_f + 1`. Default :math:`(1.1L)^{1/N}`, so that the gain of the sign term,
        :math:`r^N`, is Levant's :math:`\lambda_0 L` with :math:`\lambda_0 = 1.1`
        (:func:`~smo_gym.observers.differentiators.eigenvalue_map_rate`; for ``filtering_order = 0`` the default of
        :class:`~smo_gym.observers.Levant`'s eigenvalue maps).
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Notes
    -----
    **Indexing.** [LL20] write the filter states :math:`w_1, \ldots, w_{n_f}` with :math:`w_1` the outermost
    integral of :math:`z_0 - f`, and the differentiator's :math:`z_0, \ldots, z_n` after them; :math:`z_{n_f}`
    of the one chain :math:`(z_0, \ldots, z_{n+n_f})` of [AHK21] (``z_0 = w_1``) is the estimate of ``f``. The state
    here stores the ``z`` block first (:math:`z_0, \ldots, z_n, w_1, \ldots, w_{n_f}`, then the innovation), so
    that column 0 is the value estimate as in every family.

    **The sampled input (a derivation, not [AHK21]'s choice).** Sampling the chain exactly with the measurement
    held over the step (the zero-order hold of :math:`f` in :math:`\dot w_{n_f} = z_0 - f`, as [AHK21] do) makes
    the filter see :math:`f` half a step late: on a polynomial of degree ``n``, where the differentiator should be
    exact, the fixed point of that step has :math:`z_0 - f = \tfrac h2 f'` and :math:`z_1 - f' = \tfrac h2 f''`
    (computed: with ``n = 2``, :math:`n_f = 1`, ``d = 0`` on :math:`1 + 2t + 3t^2` at ``h = 1 ms``, errors
    :math:`6\cdot10^{-2}` and :math:`3\cdot10^{-3}` at ``t = 20 s``). Here the filter's input
    :math:`u = z_0 - f` is held instead: :math:`w_i` moves by its own Taylor terms plus
    :math:`h^{n_f-i+1}/(n_f-i+1)!\,(z_{0,k} - y_k)`, the ``z`` block by the Taylor matrix (31)
    (:func:`~smo_gym.observers.differentiators.filtering_chain_matrix`). On the true trajectory of a polynomial of
    degree ``<= n`` the input is zero, so that trajectory is a fixed point and the discrete differentiator is exact
    there, as Wetzlinger et al.'s is without filter (tested: :math:`|z_i - f^{(i)}| \propto h^{n+1-i}` for
    ``d = -1``). The eigenvalues are placed on that sampled chain by Ackermann's formula, as in [WRH].

    **Reports.** Both report the derivatives at the sample time. ``"matching"`` stores the one-step prediction and
    reports it moved back, :math:`e^{-hN_z}\hat z_{k+1}`, as :class:`~smo_gym.observers.Levant` does;
    ``"implicit"`` reports :math:`M z` with ``M`` Newton's backward formula
    (:func:`~smo_gym.observers.differentiators.backward_difference_outputs`), as the implicit
    :class:`~smo_gym.observers.Levant` does after Seeber (2024): on the true trajectory of a polynomial of degree
    ``<= order`` the filter states are zero, :math:`z_0` is the sample and the other ``z`` are its backward
    differences, late by :math:`h f''/2` and more, which ``M`` maps to the derivatives exactly. A reset with
    ``derivatives`` starts the filter states at zero, the equilibrium on the true signal.
    """

    discretizations = ("implicit", "matching")

    @check_keywords
    def __init__(
        self,
        order: int = 2,
        filtering_order: int = 1,
        dt: float = 1e-3,
        lipschitz=1.0,
        degree: float = -1.0,
        discretization: str | None = None,
        *,
        p1=None,
        wrap=None,
    ):
        order = check_int_in_range("order", order, 1, MAX_LEVANT_ORDER)
        self.filtering_order = check_int_in_range("filtering_order", filtering_order, 0, MAX_FILTERING_ORDER)
        self.degree = check_real_in_range("degree", degree, -1.0, 0.0)
        super().__init__(dt, order, discretization, wrap)
        check_positive_array("lipschitz", lipschitz)  # validate now, not at reset
        self.lipschitz = lipschitz
        if p1 is not None:
            check_positive_array("p1", p1)
        self.p1 = p1
        if self.discretization == "implicit":
            backward_difference_outputs(order + 1, self.dt)  # fail at construction, not at reset, if it overflows
        if self.discretization == "matching":
            try:
                with np.errstate(all="ignore"):
                    V = eigenvalue_mapping_vectors(order + 1, self.dt, self.filtering_order)
                finite = np.isfinite(V).all()
            except np.linalg.LinAlgError:  # dt^(N-1) underflows: a singular observability matrix
                finite = False
            if not finite:
                raise ValueError(
                    f"expected dt giving a finite eigenvalue mapping (dt^{self.n_states - 1} representable), "
                    f"actual value: {self.dt!r}"
                )

    @property
    def n_states(self) -> int:
        """``N = order + filtering_order + 1``: the states of the chain."""
        return self.order + 1 + self.filtering_order

    @property
    def _kernel(self):
        return _kernels.eigmap_kernel if self.discretization == "matching" else _kernels.filtering_implicit_kernel

    def _predicts(self):
        return self.discretization == "matching"

    @property
    def reports_instant(self) -> bool:
        return True  # matching: the prediction moved back to the sample; implicit: Newton's backward formula

    def _state_width(self) -> int:
        return self.n_states + 1

    def _innovation_column(self) -> int:
        return self.n_states

    def _rate(self, shape) -> np.ndarray:
        """The rate ``r`` per channel: ``p1``, or :math:`(1.1L)^{1/N}`."""
        if self.p1 is not None:
            return self._per_channel("p1", self.p1, shape)
        return eigenvalue_map_rate(self._per_channel("lipschitz", self.lipschitz, shape), self.n_states)

    def _channel_params(self, shape):
        r = self._rate(shape)
        m, n = self.order + 1, self.n_states
        if self.discretization == "matching":
            return _pack_eigmap(
                self.dt, r, 0.0, "matching", m, filtering_order=self.filtering_order, degree=self.degree
            )
        with np.errstate(over="ignore"):  # reported below
            gains = np.array([comb(n, c + 1) for c in range(n)])[None, :] * r[:, None] ** np.arange(1, n + 1)[None, :]
        if not np.isfinite(gains).all():
            raise ValueError(
                f"expected a rate r giving finite gains (r^{n} representable), actual value: r up to {r.max()!r} "
                f"(from lipschitz={self.lipschitz!r}, p1={self.p1!r})"
            )
        head = np.column_stack([np.full(r.shape, self.dt), np.full(r.shape, self.degree)])
        outputs = np.broadcast_to(backward_difference_outputs(m, self.dt).reshape(1, -1), (r.size, m * m))
        return np.hstack([head, gains, outputs])

    def __repr__(self) -> str:
        wrap = "" if self.wrap is None else f", wrap={self.wrap!r}"
        return (
            f"{type(self).__name__}(order={self.order}, filtering_order={self.filtering_order}, dt={self.dt}, "
            f"degree={self.degree}, discretization={self.discretization!r}{wrap})"
        )
