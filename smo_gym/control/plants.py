r"""Linear plants with unknown inputs, their strong-observability checks, and the slides' example models.

A plant is the triple of Fridman's slides, section 3, eq. (9), with a control input:

.. math::
    \dot x = A x + B u + D w,\qquad y = C x,

``x`` in :math:`\mathbb R^n`, ``u`` in :math:`\mathbb R^q` (known control), ``w`` in :math:`\mathbb R^m` (the
*unknown* input), ``y`` in :math:`\mathbb R^p`. Everything here is pure NumPy/SciPy; :func:`linearize` imports
MuJoCo lazily.

References
----------
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, sections 3 and 6.
.. [FLD07] L. Fridman, A. Levant and J. Davila, "Observation of linear systems with unknown inputs via high-order
   sliding-modes", Int. J. Systems Science 38(10), 2007.
.. [Mol76] B. P. Molinari, "A strong controllability and observability in linear multivariable control",
   IEEE TAC 21(5), 1976.
.. [Hau83] M. L. J. Hautus, "Strong detectability and observers", Linear Algebra Appl. 50, 1983.
.. [EV82] A. Emami-Naeini and P. Van Dooren, "Computation of zeros of linear multivariable systems",
   Automatica 18(4), 1982 (the staircase reduction behind :func:`invariant_zeros`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from .._scaling import pow2 as _pow2
from .._scaling import unit as _unit
from .._validation import as_real_array, check_nonnegative, check_positive

__all__ = [
    "LinearPlant",
    "MolinariDecoupling",
    "NotStronglyObservableError",
    "StrongObservabilityReport",
    "furuta_disturbance",
    "furuta_slides",
    "helicopter_slides",
    "invariant_zeros",
    "left_annihilator",
    "linearize",
    "molinari_decoupling",
    "relative_degrees",
    "strong_observability",
]

#: tolerance of the rank decisions: singular values below ``RANK_TOL * max(largest, 1)`` count as zero, relative to
#: the matrix's scale above 1 and absolute below it (so that a product that vanishes in exact arithmetic, whose
#: entries are rounding errors, has rank 0). The public functions apply it to matrices built from the factors
#: ``A``, ``C``, ``D`` brought to unit norm (``_scaling.unit``): a product ``C A^k D`` is then judged against
#: ``||C|| ||A||^k ||D||``, the scale of its rounding errors, and no verdict depends on the units of the data
RANK_TOL = 1e-9


class NotStronglyObservableError(ValueError):
    """The triple ``(A, C, D)`` is not strongly observable; the message says which condition failed."""


def _matrix(name: str, value, shape: tuple[int | None, int | None]) -> np.ndarray:
    arr = np.array(as_real_array(name, value))  # bool, string and complex entries refused
    if arr.ndim == 1 and shape[1] in (1, None):  # a vector is one column
        arr = arr[:, None]
    if arr.ndim != 2 or any(s is not None and s != a for s, a in zip(shape, arr.shape, strict=False)):
        want = "x".join("*" if s is None else str(s) for s in shape)
        raise ValueError(f"expected {name} with shape ({want}), actual value: shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"expected finite entries in {name}, actual value: {arr!r}")
    return arr


def _square_matrix(name: str, value) -> np.ndarray:
    """``value`` as a finite square float matrix with at least one row (a number: 1 x 1)."""
    M = _matrix(name, np.atleast_2d(value), (None, None))
    if M.shape[0] != M.shape[1] or M.shape[0] == 0:
        raise ValueError(f"expected a square {name} with at least one row, actual value: shape {M.shape}")
    return M


def _check_definite(name: str, M: np.ndarray, *, definite: bool = False) -> None:
    """Refuse a ``M`` that is not symmetric positive (semi-)definite, up to rounding relative to its norm (an
    absolute floor would pass ``-1e-13 I`` as semi-definite): a covariance, or a quadratic cost's weight."""
    tol = 1e-12 * np.linalg.norm(M)
    low = np.linalg.eigvalsh((M + M.T) / 2).min() if M.size else 0.0
    if np.linalg.norm(M - M.T) > tol or (low <= 0.0 if definite else low < -tol):
        what = "definite" if definite else "semi-definite"
        raise ValueError(
            f"expected {name} symmetric positive {what}, actual value: {M.tolist()!s:.120} (smallest eigenvalue "
            f"{low:.3g})"
        )


def _check_triple(A, C, D) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, C, D)`` as float matrices after checking that ``A`` is square and the shapes agree."""
    A = _matrix("A", A, (None, None))
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"expected a square A, actual value: shape {A.shape}")
    return A, _matrix("C", np.atleast_2d(C), (None, n)), _matrix("D", D, (n, None))


def _triple(plant, C, D, caller: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The checked ``(A, C, D)`` of ``caller(plant)`` or ``caller(A, C, D)``."""
    if isinstance(plant, LinearPlant):
        if C is not None or D is not None:
            raise TypeError(
                f"expected {caller}(plant) or {caller}(A, C, D), actual value: a LinearPlant and also C={C!r}, D={D!r}"
            )
        return plant.A, plant.C, plant.D
    if C is None or D is None:
        raise TypeError(
            f"expected {caller}(plant) with a LinearPlant or {caller}(A, C, D) with three matrices, "
            f"actual value: {type(plant).__name__} {plant!r} with C={C!r}, D={D!r}"
        )
    return _check_triple(plant, C, D)


def _rank(M: np.ndarray) -> int:
    if M.size == 0:
        return 0
    s = np.linalg.svd(M, compute_uv=False)
    return int(np.sum(s > RANK_TOL * max(s[0], 1.0)))


def left_annihilator(M: np.ndarray) -> np.ndarray:
    r"""Rows spanning the left null space of ``M``: :math:`M^\perp` with :math:`M^\perp M = 0` (orthonormal rows).

    ``M`` of shape ``(r, c)`` gives shape ``(r - rank M, r)``; ``M = 0`` gives the identity.
    """
    M = as_real_array("M", M)
    if M.ndim != 2 or not np.isfinite(M).all():
        raise ValueError(f"expected a finite matrix M (r, c), actual value: {M!r:.80}")
    if M.size == 0 or np.all(M == 0):
        return np.eye(M.shape[0])
    U, s, _ = np.linalg.svd(M)
    rank = int(np.sum(s > RANK_TOL * max(s[0], 1.0)))
    return U[:, rank:].T.copy()


def relative_degrees(A, C, D) -> np.ndarray:
    r"""Relative degree of every output row with respect to the unknown input (Fridman's slides, section 3).

    .. math:: c_i A^j D = 0,\ j = 0..r_i - 2,\qquad c_i A^{r_i - 1} D \neq 0.

    Returns
    -------
    ndarray of int, shape (p,)
        ``r_i``; ``0`` marks an output that ``w`` never reaches (``c_i A^j D = 0`` for all ``j < n``).

    Raises
    ------
    ValueError
        If a matrix is not finite (a NaN compares as zero: every output would read as unreached) or the shapes
        do not agree.
    """
    A, C, D = _check_triple(A, C, D)
    n = A.shape[0]
    A, D = _unit(A), _unit(D)  # c_i A^j D judged against ||c_i|| ||A||^j ||D||, whatever the units
    r = np.zeros(C.shape[0], dtype=int)
    for i, c in enumerate(C):
        v = _unit(c)
        for j in range(n):
            if np.abs(v @ D).max() > RANK_TOL:
                r[i] = j + 1
                break
            v = v @ A
    return r


def _svd_full(M: np.ndarray):
    """``U, s, Vh`` of ``M`` with square ``U`` and ``Vh``; an empty ``M`` gives identities and no singular values."""
    if min(M.shape) == 0:
        return np.eye(M.shape[0]), np.zeros(0), np.eye(M.shape[1])
    return np.linalg.svd(M, full_matrices=True)


def _system_matrix(A, B, C) -> np.ndarray:
    """``[[A, B], [C, 0]]``."""
    return np.block([[A, B], [C, np.zeros((C.shape[0], B.shape[1]))]])


def _balance_system(A, B, C, tol: float):
    r"""Scale ``(A, B, C)`` by powers of two without changing its zeros.

    Inputs and outputs are scaled first (columns of ``B``, rows of ``C``) to the Frobenius norm of ``A``, so that
    units do not decide ranks. Then the states, by the diagonal similarity that balances the rows and columns of
    the system matrix :math:`S = \begin{bmatrix} A & B \\ C & 0 \end{bmatrix}` (Parlett and Reinsch 1969, as
    SLICOT's ``TB01ID`` does): LAPACK's ``gebal`` on the square matrix with zero input rows and output columns
    (``gebal`` leaves coordinates with a zero row or column unscaled, so only the states are scaled, with ``B``
    and ``C`` counted in their row and column norms). All three scalings leave the zeros unchanged.

    Balancing trusts every entry to full relative accuracy. Where roundoff stands in for a zero (a state whose
    row holds only entries like ``1e-30``, as finite differences leave for a free, unactuated joint), it scales
    that state so far that its *significant* entries (above ``tol * ||S||_F``) drop below the rank decisions'
    level ``tol * ||S'||_F`` of the balanced matrix, which invents zeros. A scaling that does so is refused: the
    balancing is recomputed with the entries at or below ``tol * ||S||_F`` left out, and if that too loses an
    entry, the states are not scaled.
    """
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    ref = np.linalg.norm(A) or 1.0
    with np.errstate(divide="ignore"):
        B = B * _pow2(ref / np.linalg.norm(B, axis=0))
        C = C * _pow2(ref / np.linalg.norm(C, axis=1))[:, None]
    if n == 0:
        return A, B, C
    S = _system_matrix(A, B, C)
    significant = np.abs(S) > tol * np.linalg.norm(S)
    Z = np.zeros((n + m + p, n + m + p))
    for T in (S, np.where(significant, S, 0.0)):  # all entries, then the significant ones only
        Z[:n, :n], Z[:n, n : n + m], Z[n + m :, :n] = T[:n, :n], T[:n, n:], T[n:, :n]
        d = sla.matrix_balance(Z, permute=False, separate=True)[1][0][:n]
        As, Bs, Cs = A / d[:, None] * d[None, :], B / d[:, None], C * d[None, :]
        Ss = _system_matrix(As, Bs, Cs)
        if np.all(np.abs(Ss[significant]) > tol * np.linalg.norm(Ss)):
            return As, Bs, Cs
    return A, B, C


def _reduce(A, B, C, F, tol: float):
    r"""Emami-Naeini and Van Dooren's (1982) procedure *reduce*: the same finite zeros, ``F`` of full row rank.

    System :math:`\dot x = Ax + Bu,\ y = Cx + Fu` (``F`` the direct feedthrough, the paper's ``D``), pencil
    :math:`S(\lambda) = \begin{bmatrix} A - \lambda I & B \\ C & F \end{bmatrix}`. Each step compresses the rows
    of ``F`` (SVD: ``U^T F = [F_r; 0]``, ``F_r`` of full row rank ``rho``), then the columns of the output rows
    that ``u`` does not reach, ``C_0`` (rank ``mu``; state basis ``[ker C_0, row space of C_0]``, orthogonal).
    A vector in the kernel of ``S(lambda)`` has ``C_0 x = 0``, i.e. no component ``x_2`` along the row space; the
    rows of ``A`` for ``x_2`` then no longer contain ``lambda`` and become outputs:

    .. math::
        (A, B, C, F) \leftarrow \left(A_{11},\ B_1,\ \begin{bmatrix} A_{21} \\ C_{r,1} \end{bmatrix},\
        \begin{bmatrix} B_2 \\ F_r \end{bmatrix}\right),

    a unimodular (constant-row) equivalence that removes ``mu`` states and keeps the finite zeros; rows of
    ``C_0`` beyond its rank are zero rows of the pencil (left Kronecker structure) and are dropped. It stops when
    ``mu = 0``. Singular values at or below ``tol`` (absolute) count as zero. All transformations are orthogonal.
    """
    while True:
        n = A.shape[0]
        U, sf, _ = _svd_full(F)
        rho = int(np.sum(sf > tol))
        UC, UF = U.T @ C, U.T @ F
        C_r, F_r, C_0 = UC[:rho], UF[:rho], UC[rho:]
        _, sc, Vh = _svd_full(C_0)
        mu = int(np.sum(sc > tol))
        if mu == 0:
            return A, B, C_r, F_r
        T = np.vstack([Vh[mu:], Vh[:mu]]).T  # columns: ker C_0, then its row space
        A, B, C_r = T.T @ A @ T, T.T @ B, C_r @ T
        k = n - mu
        A, B, C, F = A[:k, :k], B[:k], np.vstack([A[k:, :k], C_r[:, :k]]), np.vstack([B[k:], F_r])


def _zeros_and_rank(A, B, C, tol: float) -> tuple[np.ndarray, int]:
    """Finite zeros of ``(A, B, C, 0)`` and the normal rank of its transfer matrix (see :func:`invariant_zeros`)."""
    m, p = B.shape[1], C.shape[0]
    A, B, C = _balance_system(A, B, C, tol)
    tol_abs = tol * np.linalg.norm(_system_matrix(A, B, C))  # Frobenius norm of the balanced system matrix
    A, B, C, F = _reduce(A, B, C, np.zeros((p, m)), tol_abs)
    # the same on the dual system (transposed pencil): F gets full column rank as well, hence square, invertible
    At, Ct, Bt, Ft = _reduce(A.T, C.T, B.T, F.T, tol_abs)
    A, B, C, F = At.T, Bt.T, Ct.T, Ft.T
    r = F.shape[0]
    if F.shape[1] != r:
        raise RuntimeError(f"expected a square feedthrough after the two reductions, actual value: shape {F.shape}")
    nf = A.shape[0]
    if nf == 0:
        return np.zeros(0, dtype=complex), r
    # kernel of [C F] (F invertible): [x; u] = N z; the pencil restricted to it is ([A B] - lambda [I 0]) N
    _, _, Vh = _svd_full(np.hstack([C, F]))
    N = Vh[r:].T
    with np.errstate(all="ignore"):
        z = sla.eigvals(np.hstack([A, B]) @ N, N[:nf])
    return np.sort_complex(z[np.isfinite(z)]), r


def invariant_zeros(A, C=None, D=None, *, tol: float = RANK_TOL) -> np.ndarray:
    r"""Invariant zeros of ``(A, C, D)``: the finite ``s`` where the Rosenbrock matrix loses rank.

    .. math:: R(s) = \begin{bmatrix} sI - A & -D \\ C & 0 \end{bmatrix},\qquad
              \operatorname{rank} R(s_0) < \operatorname{normal\,rank} R .

    Computed as Emami-Naeini and Van Dooren (1982) do (and SLICOT's ``AB08ND``): after a balancing by powers of
    two (which leaves the zeros unchanged), the staircase procedure *reduce* removes from the system pencil the
    infinite zeros and the non-square (Kronecker) structure with orthogonal transformations, once for the rows
    and once, on the dual system, for the columns, which leaves a system with an invertible feedthrough; its
    zeros are the generalized eigenvalues of a regular pencil of the size of the number of finite zeros, found by
    QZ. No eigenvalue at infinity is ever formed, so there is nothing to cut off: every value returned is a zero
    of a system within about ``tol * ||S||_F`` of the balanced one (backward stability of the orthogonal
    reductions), ``S = [A, D; C, 0]``. Works for any numbers of outputs and unknown inputs; for ``p < m`` or a
    rank-deficient ``D`` the pencil has deficient normal rank and the zeros are those of its regular part
    (:func:`strong_observability` reports the normal rank).

    Parameters
    ----------
    A : array_like, shape (n, n), or LinearPlant
        A :class:`LinearPlant` (then ``C`` and ``D`` are taken from it and must be omitted).
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)
        Unknown-input matrix (a vector is one column).
    tol : float
        In ``(0, 1)``. Rank decisions: singular values at or below ``tol`` times the Frobenius norm of the balanced
        system
        matrix count as zero. The default :data:`RANK_TOL` is the one of every rank decision in this module
        (models linearized by finite differences carry relative errors near ``1e-10``); a model known to machine
        precision may use a value down to about ``n * 1e-16``.

    Returns
    -------
    ndarray of complex, shape (n_zeros,)
        Sorted by real part, then imaginary part; complex zeros come in conjugate pairs.

    References
    ----------
    .. [EV82] A. Emami-Naeini and P. Van Dooren, "Computation of zeros of linear multivariable systems",
       Automatica 18(4), 415-430, 1982.
    """
    A, C, D = _triple(A, C, D, "invariant_zeros")
    if check_positive("tol", tol) >= 1.0:
        raise ValueError(f"expected tol < 1, actual value: {tol!r}")
    return _zeros_and_rank(A, D, C, float(tol))[0]


@dataclass(frozen=True)
class MolinariDecoupling:
    r"""Result of Molinari's decoupling algorithm: an algebraic relation between output derivatives and the state.

    .. math:: M x = Q\,\begin{bmatrix} y \\ \dot y \\ \vdots \\ y^{(N)} \end{bmatrix},

    valid for *every* unknown input ``w`` (Fridman's slides, eq. (12); [Mol76]).

    Attributes
    ----------
    M : ndarray, shape (r, n)
        Orthonormal-row form of Molinari's ``M_k``; ``ker M`` is the weakly unobservable subspace ``V*``.
    Q : ndarray, shape (r, p * (N + 1))
        Weights of the stacked derivatives ``[y; y'; ...; y^(N)]``.
    n_derivatives : int
        ``N``: the highest output derivative the relation needs.
    steps : int
        ``k``, the number of Molinari steps until the rank stopped growing.
    """

    M: np.ndarray
    Q: np.ndarray
    n_derivatives: int
    steps: int

    @property
    def rank(self) -> int:
        return _rank(self.M)

    def state_map(self) -> np.ndarray:
        r"""``M^+ Q``, shape ``(n, p (N + 1))``: the state from the derivative stack when ``rank M = n``."""
        return np.linalg.pinv(self.M) @ self.Q


def molinari_decoupling(A, C, D) -> MolinariDecoupling:
    r"""Molinari's decoupling algorithm (Fridman's slides, section 3; [Mol76]).

    With :math:`M_1 = C` (so :math:`M_1 x = y`), each step removes the unknown input from the derivative of what
    is known:

    .. math::
        \frac{d}{dt}(M_k x) = M_k A x + M_k D w
        \;\Rightarrow\; (M_k D)^\perp M_k A\, x = (M_k D)^\perp \frac{d}{dt}(M_k x),\qquad
        M_{k+1} = \begin{bmatrix} (M_k D)^\perp M_k A \\ C \end{bmatrix}.

    The bookkeeping ``M_k x = Q_k Y`` over the derivative stack ``Y`` is carried along (``d/dt`` shifts ``Q_k`` by
    one derivative). Rows are compressed to an orthonormal basis of the row space after each step. It stops when
    the rank stops growing; ``ker M`` is then the weakly unobservable subspace (``ker M_n = V*``), so the triple is
    strongly observable iff ``rank M = n``.

    The steps run on ``A / a``, ``C / c``, ``D / d``, each scaled to unit norm by a power of two, so that no rank
    decision depends on units: in the time ``a t`` the output ``y / c`` has the derivatives ``y^(k) / (c a^k)``,
    which is how ``Q`` is scaled back to the derivatives of ``y``.
    """
    A, C, D = np.asarray(A, float), np.asarray(C, float), np.asarray(D, float)
    n, p = A.shape[0], C.shape[0]
    a, c = _pow2(np.linalg.norm(A)), _pow2(np.linalg.norm(C))
    A, C, D = A / a, C / c, _unit(D)
    width = p * (n + 2)

    def shift(Q):
        out = np.zeros_like(Q)
        out[:, p:] = Q[:, :-p]
        return out

    Q1 = np.zeros((p, width))
    Q1[:, :p] = np.eye(p)
    M, Q = C.copy(), Q1.copy()
    rank, steps = _rank(M), 1
    M, Q = _compress(M, Q)
    while steps < n + 1:
        N = left_annihilator(M @ D)
        M_new = np.vstack([N @ M @ A, C])
        Q_new = np.vstack([N @ shift(Q), Q1])
        M_new, Q_new = _compress(M_new, Q_new)
        r_new = _rank(M_new)
        if r_new <= rank:
            break
        M, Q, rank, steps = M_new, Q_new, r_new, steps + 1
    used = np.nonzero(np.any(np.abs(Q) > 0, axis=0))[0]
    n_der = int(used.max() // p) if used.size else 0
    Q = Q[:, : p * (n_der + 1)] / (c * a ** np.repeat(np.arange(n_der + 1), p))  # weights of y^(k)
    return MolinariDecoupling(M=M, Q=Q, n_derivatives=n_der, steps=steps)


def _compress(M, Q):
    U, s, _ = np.linalg.svd(M, full_matrices=False)
    r = int(np.sum(s > RANK_TOL * max(s[0] if s.size else 0.0, 1.0)))
    Ur = U[:, :r]
    Mc, Qc = Ur.T @ M, Ur.T @ Q
    Qc[np.abs(Qc) < 1e-14 * max(np.abs(Qc).max(initial=0.0), 1.0)] = 0.0
    return Mc, Qc


@dataclass(frozen=True)
class StrongObservabilityReport:
    """What :func:`strong_observability` found; ``ok`` is the verdict and ``reason`` explains a failure."""

    ok: bool
    reason: str
    relative_degrees: np.ndarray
    invariant_zeros: np.ndarray
    normal_rank: int
    weakly_unobservable_dim: int
    molinari: MolinariDecoupling | None = field(default=None, repr=False)


def strong_observability(A, C=None, D=None) -> StrongObservabilityReport:
    r"""Check that ``(A, C, D)`` is strongly observable (Fridman's slides, section 3; [Hau83]).

    Equivalent conditions: the state can be recovered from ``y`` and its derivatives whatever ``w`` is; the
    Rosenbrock matrix has full column rank ``n + m`` for every complex ``s`` (full normal rank and no invariant
    zeros); the weakly unobservable subspace is ``{0}`` (``rank M = n`` in Molinari's algorithm). All three are
    computed and must agree. The normal rank and the zeros come from one staircase reduction
    (:func:`invariant_zeros`): normal rank ``n + r``, ``r`` the normal rank of the transfer matrix
    :math:`C (sI - A)^{-1} D`.

    Parameters
    ----------
    A : array_like, shape (n, n), or LinearPlant
        ``strong_observability(plant)`` or ``strong_observability(A, C, D)``.
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)
    """
    A, C, D = _triple(A, C, D, "strong_observability")
    n, p, m = A.shape[0], C.shape[0], D.shape[1]
    rel = relative_degrees(A, C, D)
    all_zeros, r = _zeros_and_rank(A, D, C, RANK_TOL)
    normal_rank = n + r
    mol = molinari_decoupling(A, C, D)
    v_dim = n - mol.rank
    zeros = np.array([], dtype=complex)
    reason = ""
    if _rank(_unit(D)) < m:
        reason = (
            f"D has rank {_rank(_unit(D))} < m={m} columns: some unknown inputs act identically on the state and "
            "can never be told apart"
        )
    elif p < m:
        reason = (
            f"fewer measured outputs (p={p}) than unknown inputs (m={m}): the Rosenbrock matrix cannot have "
            "full column rank"
        )
    elif normal_rank < n + m:
        reason = (
            f"the Rosenbrock matrix [sI - A, -D; C, 0] has normal rank {normal_rank} < n + m = {n + m}: the "
            "unknown input is not left-invertible from y (the whole complex plane consists of 'zeros')"
        )
    else:
        zeros = all_zeros
        if zeros.size:
            z = ", ".join(f"{complex(z):.4g}" for z in np.sort_complex(zeros))
            reason = (
                f"the triple has invariant zeros at s = {z} (rank [sI - A, -D; C, 0] < n + m there): an input "
                f"w(t) = w0 exp(s t) hides a nonzero state from y"
            )
    if not reason and v_dim > 0:
        reason = f"Molinari's algorithm leaves a weakly unobservable subspace of dimension {v_dim}"
    if reason and v_dim > 0 and "weakly" not in reason:
        reason += f"; Molinari's algorithm finds a weakly unobservable subspace of dimension {v_dim}"
    if reason:
        unreached = np.nonzero(rel == 0)[0]
        if unreached.size:
            reason += f"; outputs {unreached.tolist()} are not reached by w at all"
    return StrongObservabilityReport(
        ok=not reason,
        reason=reason,
        relative_degrees=rel,
        invariant_zeros=zeros,
        normal_rank=normal_rank,
        weakly_unobservable_dim=v_dim,
        molinari=mol,
    )


class LinearPlant:
    r"""A linear plant with a known control and an unknown input (Fridman's slides, eq. (9)).

    .. math:: \dot x = A x + B u + D w(t),\qquad y = C x.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, q)
        Control input matrix (a vector is taken as one column).
    C : array_like, shape (p, n)
        Measured outputs.
    D : array_like, shape (n, m)
        Unknown-input matrix.
    state_names : sequence of str, optional
        Labels of the state entries, for tables and plots.

    Notes
    -----
    Simulation (exact zero-order hold for ``u``, Gauss-Legendre quadrature of the convolution with ``w`` on a
    fine internal step) lives in :func:`smo_gym.control.simulate` via :meth:`discretize`.
    """

    def __init__(self, A, B, C, D, *, state_names=None):
        self.A, self.C, self.D = _check_triple(A, C, D)
        n = self.A.shape[0]
        self.B = _matrix("B", B, (n, None))
        self.state_names = tuple(state_names) if state_names is not None else tuple(f"x{i}" for i in range(n))
        if len(self.state_names) != n:
            raise ValueError(f"expected {n} state names, actual value: {len(self.state_names)}")

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    @property
    def n_unknown(self) -> int:
        return self.D.shape[1]

    def strong_observability(self) -> StrongObservabilityReport:
        """See :func:`strong_observability`."""
        return strong_observability(self)

    def require_strongly_observable(self) -> StrongObservabilityReport:
        """Return the report, or raise :class:`NotStronglyObservableError` saying why the check failed."""
        rep = self.strong_observability()
        if not rep.ok:
            raise NotStronglyObservableError(
                "expected a strongly observable triple (A, C, D) (state recoverable from y and its derivatives "
                f"for any unknown input w), actual value: {rep.reason} (relative degrees "
                f"{rep.relative_degrees.tolist()})"
            )
        return rep

    def discretize(self, dt: float, *, actuator_tau: float = 0.0):
        r"""Exact zero-order-hold matrices ``(Phi, Gamma)`` over ``dt`` (augmented by a first-order actuator).

        With ``actuator_tau = mu > 0`` the state is ``[x; u_a]`` and :math:`\mu \dot u_a = u - u_a`.
        """
        dt = check_positive("dt", dt)
        A, B = self.augmented(actuator_tau)[:2]
        n, q = A.shape[0], B.shape[1]
        M = np.zeros((n + q, n + q))
        M[:n, :n], M[:n, n:] = A * dt, B * dt
        E = sla.expm(M)
        return E[:n, :n], E[:n, n:]

    def augmented(self, actuator_tau: float = 0.0):
        """``(A, B, D)`` of the plant with a first-order actuator of time constant ``actuator_tau`` (0: none)."""
        actuator_tau = check_nonnegative("actuator_tau", actuator_tau)
        if actuator_tau == 0.0:
            return self.A, self.B, self.D
        n, q = self.n, self.n_inputs
        A = np.block([[self.A, self.B], [np.zeros((q, n)), -np.eye(q) / actuator_tau]])
        B = np.vstack([np.zeros((n, q)), np.eye(q) / actuator_tau])
        D = np.vstack([self.D, np.zeros((q, self.n_unknown))])
        return A, B, D

    def __repr__(self) -> str:
        return (
            f"LinearPlant(n={self.n}, inputs={self.n_inputs}, outputs={self.n_outputs}, "
            f"unknown inputs={self.n_unknown})"
        )


def furuta_slides(*, as_printed: bool = False) -> LinearPlant:
    r"""The Furuta pendulum of Fridman's slides, section 6 ("Experiments"), linearized upright.

    ``x = [theta, alpha, theta_dot, alpha_dot]`` (arm angle, pendulum angle from upright), both angles measured,
    ``B = D`` (the disturbance is matched), the slides' disturbance being ``w(t) = 0.4 sin(2.5 t) + 0.5``.

    .. math::
        A = \begin{bmatrix} 0&0&1&0\\0&0&0&1\\0&82.4&-1.31&0\\0&56.81&-0.37&0\end{bmatrix},\quad
        B = D = \begin{bmatrix}0\\0\\46.75\\13.20\end{bmatrix},\quad
        C = \begin{bmatrix}1&0&0&0\\0&1&0&0\end{bmatrix}.

    Notes
    -----
    **Reconstruction.** The text copy prints ``A[2, 2] = 1,31`` and ``A[3, 2] = 0,37`` (positive). Both equal
    ``0.0280 * B[2]`` and ``0.0280 * B[3]`` to three digits: the column is the arm's viscous friction torque
    ``-b theta_dot`` entering through the same channel as the motor torque, so its sign must be negative (with
    the printed signs the friction would *feed* energy and add an unstable mode at ``+0.77``). We use the
    negative signs; ``as_printed=True`` gives the printed matrix for comparison. Either way the triple is
    strongly observable (both outputs have relative degree 2, ``2 + 2 = n``).
    """
    s = 1.0 if as_printed else -1.0
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [0, 82.4, s * 1.31, 0], [0, 56.81, s * 0.37, 0]], dtype=float)
    B = np.array([[0.0], [0.0], [46.75], [13.20]])
    C = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    return LinearPlant(A, B, C, B.copy(), state_names=("theta", "alpha", "theta_dot", "alpha_dot"))


def furuta_disturbance(t):
    r"""The slides' matched disturbance :math:`w(t) = 0.4\sin(2.5 t) + 0.5`, shape ``(len(t), 1)``."""
    t = np.asarray(t, dtype=float)
    return (0.4 * np.sin(2.5 * t) + 0.5)[..., None]


def helicopter_slides() -> LinearPlant:
    r"""The three-DOF helicopter of Fridman's slides, section 6 (unmatched compensation), linearized at zero pitch.

    .. math::
        \ddot\epsilon_1 = 0.45\,((u_1 + f_1) + (u_2 + f_2)),\quad
        \ddot\epsilon_2 = 3.05\,((u_1 + f_1) - (u_2 + f_2)),\quad
        \ddot\epsilon_3 = -0.49\,\epsilon_2 + \nu,

    (elevation, pitch, travel). State ``x = [e1, e2, e3, e1_dot, e2_dot, e3_dot]``, the three angles measured,
    unknown input ``w = [f1, f2, nu]``: ``f`` is matched, ``nu`` (a travel torque) is unmatched and reaches the
    travel only through the pitch. ``D = [B, e_6]``.

    Notes
    -----
    The slides give the equations only; the matrices follow from them without ambiguity. The triple is strongly
    observable (``C A D`` is invertible: relative degree 2 for every output, ``2 + 2 + 2 = n``). Ferreira et
    al.'s (2013) assumption ``span D1 ⊂ span A12`` does *not* hold here (``nu`` is two integrators away from the
    actuated pitch rate), which is why the slides treat this example with the dynamic sliding surface of
    Ferreira et al. (2015); :class:`smo_gym.control.UnmatchedCompensationController` covers it through the
    identified disturbance's derivative (see its Notes).
    """
    A = np.zeros((6, 6))
    A[0:3, 3:6] = np.eye(3)
    A[5, 1] = -0.49
    B = np.zeros((6, 2))
    B[3] = [0.45, 0.45]
    B[4] = [3.05, -3.05]
    D = np.hstack([B, np.eye(6)[:, [5]]])
    C = np.hstack([np.eye(3), np.zeros((3, 3))])
    return LinearPlant(
        A, B, C, D, state_names=("elevation", "pitch", "travel", "elevation_dot", "pitch_dot", "travel_dot")
    )


def linearize(
    model,
    qpos0=None,
    ctrl0=None,
    *,
    data=None,
    eps: float = 1e-6,
    centered: bool = True,
    method: str = "difference",
    D=None,
    C=None,
    force_dofs=None,
) -> LinearPlant:
    r"""Linearize a MuJoCo model around an equilibrium with ``mujoco.mjd_transitionFD``.

    MuJoCo returns the one-step map :math:`\delta x_{k+1} = A_d \delta x_k + B_d \delta u_k` of its integrator
    over ``model.opt.timestep`` ``h``, state ``x = [dq (nv tangent), qvel (nv), act (na)]``. Conversion to
    continuous time:

    ``"difference"`` (default)
        :math:`A = (A_d - I)/h,\ B = B_d/h` for the velocity (and activation) rows: the Jacobian of the
        acceleration that MuJoCo's Euler step :math:`v^+ = v + h\,a` uses (up to ``O(h)`` for the implicit
        integrators); the position rows are set to the exact kinematics :math:`\dot q = v` (for hinge and
        slide joints). Taken literally, ``(A_d - I)/h`` would give the position rows the semi-implicit artifact
        ``h dv+/dx`` and ``B`` position entries ``h dv+/du``: a spurious relative degree 1 from the input to the
        measured positions and an invariant zero near ``-1/h``. Always real.
    ``"logm"``
        :math:`A = \log(A_d)/h,\ B = (\int_0^h e^{As}ds)^{-1} B_d`: the continuous system whose exact ZOH
        discretization is ``(A_d, B_d)``. Fails (``ValueError``) when ``A_d`` has eigenvalues on the negative
        real axis.

    Parameters
    ----------
    model : mujoco.MjModel
        Not modified. ``mjd_transitionFD`` does not support the RK4 integrator: such models are linearized on a
        copy with the Euler integrator (the same continuous dynamics; only ``"logm"`` depends on the step).
    qpos0 : array_like, shape (nq,), optional
        Equilibrium configuration (default ``model.qpos0``); ignored when ``data`` is given.
    ctrl0 : array_like, shape (nu,), optional
        Equilibrium control (default zeros).
    data : mujoco.MjData, optional
        Linearize at this state instead (copied, not modified).
    eps : float
        Finite-difference step.
    D : array_like, shape (2 nv + na, m), optional
        Unknown-input matrix; default ``B`` (input-matched disturbance).
    C : array_like, optional
        Output matrix; default the joint positions ``[I_nv, 0]``.
    force_dofs : array_like of int, optional
        Instead of ``D``: the unknown input is a generalized force on these ``qvel`` addresses (MuJoCo's
        ``qfrc_applied``), differentiated through the same step as ``B`` (so a force on an actuated joint is
        matched exactly).
    """
    import mujoco  # lazy: the rest of smo_gym.control does not need MuJoCo

    if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        # mjd_transitionFD does not support RK4: differentiate the same dynamics with the explicit Euler step
        # (MuJoCo's Euler treats joint damping implicitly, v+ = v + h (M + h B)^-1 f, an O(h) change of B and of
        # the damping terms that RK4 does not make: disabled, so that (A_d - I)/h is the continuous Jacobian)
        import copy

        model = copy.deepcopy(model)
        model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    if method not in ("difference", "logm"):
        raise ValueError(f"expected method to be one of 'difference', 'logm', actual value: {method!r}")
    if data is None:
        d = mujoco.MjData(model)
        if qpos0 is not None:
            d.qpos[:] = np.asarray(qpos0, dtype=float)
        d.qvel[:] = 0.0
    else:
        d = mujoco.MjData(model)
        d.qpos[:], d.qvel[:], d.act[:] = data.qpos, data.qvel, data.act
        d.ctrl[:] = data.ctrl
    if ctrl0 is not None:
        d.ctrl[:] = np.asarray(ctrl0, dtype=float)
    mujoco.mj_forward(model, d)
    nx = 2 * model.nv + model.na
    Ad = np.zeros((nx, nx))
    Bd = np.zeros((nx, model.nu))
    mujoco.mjd_transitionFD(model, d, eps, centered, Ad, Bd, None, None)
    h = model.opt.timestep
    nv = model.nv
    if method == "difference":
        A = (Ad - np.eye(nx)) / h
        B = Bd / h
        # position rows: dq/dt = v exactly (tangent space); the rows of (A_d - I)/h would carry the O(h)
        # artifact h * dv/dx of the semi-implicit Euler update q+ = q + h v+, and B's position rows h * dv/du,
        # which gives the output a spurious relative degree 1 and an invariant zero near -1/h
        A[:nv] = 0.0
        A[:nv, nv : 2 * nv] = np.eye(nv)
        B[:nv] = 0.0
    else:
        ev = np.linalg.eigvals(Ad)
        if np.any((np.abs(ev.imag) < 1e-12) & (ev.real <= 0)):
            raise ValueError(
                f"expected A_d without eigenvalues on the closed negative real axis for the matrix "
                f"logarithm, actual value: eigenvalues {ev}; use method='difference'"
            )
        A = np.real(sla.logm(Ad)) / h
        # integral of e^{As} over [0, h] from the block exponential [[A h, I h], [0, 0]]
        Z = np.zeros((2 * nx, 2 * nx))
        Z[:nx, :nx], Z[:nx, nx:] = A * h, np.eye(nx) * h
        S = sla.expm(Z)[:nx, nx:]
        B = np.linalg.solve(S, Bd)
    if C is None:
        C = np.hstack([np.eye(model.nv), np.zeros((model.nv, model.nv + model.na))])
    if force_dofs is not None:
        if D is not None:
            raise TypeError(f"expected D or force_dofs, actual value: both (force_dofs={force_dofs!r})")
        if method != "difference":
            raise ValueError(f"expected method='difference' with force_dofs, actual value: {method!r}")
        D = _force_input(model, d, np.asarray(force_dofs, dtype=int).reshape(-1), h)
    return LinearPlant(A, B, C, B.copy() if D is None else D)


def _force_input(model, data, dofs: np.ndarray, h: float) -> np.ndarray:
    r"""``D`` for generalized forces on ``dofs`` (``qfrc_applied``), from the same one-step map as ``B``.

    The step is affine in ``qfrc_applied`` (it enters the right-hand side like ``qfrc_actuator``), so one step per
    column with a unit force, minus one without, gives :math:`\partial v^+/\partial w` exactly; it is converted to
    continuous time as ``B`` is (position rows zero), so a force on an actuated joint is exactly matched.
    """
    import mujoco

    nv, nx = model.nv, 2 * model.nv + model.na
    if dofs.size == 0 or dofs.min() < 0 or dofs.max() >= nv:
        raise ValueError(f"expected force_dofs in [0, {nv}), actual value: {dofs.tolist()}")
    d = mujoco.MjData(model)

    def step(force):
        mujoco.mj_copyData(d, model, data)
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[dofs] = force
        mujoco.mj_step(model, d)
        return np.concatenate([d.qvel, d.act])

    base = step(np.zeros(dofs.size))
    Dd = np.zeros((nx, dofs.size))
    for j in range(dofs.size):
        e = np.zeros(dofs.size)
        e[j] = 1.0
        Dd[nv:, j] = step(e) - base
    return Dd / h
