r"""Block decomposition and LMI tuning of the implicit-Lyapunov-function (ILF) observers of Lopez-Ramirez et al. 2016.

The finite-time observer (6)-(9) and the fixed-time observer (17)-(18) of Lopez-Ramirez, Polyakov, Efimov and
Perruquetti work in the block coordinates of the Appendix: a transformation :math:`\Phi` with

.. math:: \Phi A \Phi^{-1} = F\tilde C + \tilde A,\qquad C\Phi^{-1} = [C_0\ 0\ \cdots\ 0],\qquad
          \tilde C = [I_{n_1}\ 0],

:math:`\tilde A` block-superdiagonal with blocks :math:`A_{i,i+1}\in\mathbb R^{n_i\times n_{i+1}}` of full column
rank. Gains come from the parametric matrix inequalities of Theorem 6 (finite time) and Theorem 10 (fixed time),
made finite by the grids of Proposition 8 and Proposition 11 and refined by Algorithms 9 and 12.

Every design follows the recipe of ``DESIGN.md``: ``symmetric=True`` variables, symmetrised blocks, strict
inequalities as margins ``>> eps * I``, ``solver=cp.CLARABEL`` passed explicitly, ``status == "optimal"`` checked,
and the returned matrices re-verified in NumPy (every LMI at the solution *and* the parametric inequality (14) or
(24) on a grid much denser than the one the solver saw). The NumPy numbers are the certificate the caller gets.

References
----------
.. [LPEP16] F. Lopez-Ramirez, A. Polyakov, D. Efimov and W. Perruquetti, "Finite-time and fixed-time observers
   design via implicit Lyapunov function", European Control Conference (ECC), 2016.
.. [PEP15] A. Polyakov, D. Efimov and W. Perruquetti, "Finite-time and fixed-time stabilization: implicit
   Lyapunov function approach", Automatica 51, 2015.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from .._extras import require
from .._scaling import unit
from .._validation import (
    as_real_array,
    check_bool,
    check_choice,
    check_int_in_range,
    check_nonnegative,
    check_positive,
    check_real_in_range,
)
from .gains import _observability_rank
from .lmi import LMIInfeasibleError  # shared with the switched-gain design of Efimov et al. 2017

__all__ = [
    "LOPEZ_RAMIREZ_2016_DELTA",
    "BlockDecomposition",
    "ILFCertificate",
    "ILFDesign",
    "LMIInfeasibleError",
    "block_decomposition",
    "certify_ilf",
    "dilation",
    "ilf_degrees",
    "ilf_gains",
    "ilf_homogeneity_matrices",
    "xi_finite",
    "xi_fixed",
]

#: the ``delta`` of the finite-time example of Lopez-Ramirez et al. 2016, section V.A: :math:`(1+\sqrt5)/(3+\sqrt5)`
LOPEZ_RAMIREZ_2016_DELTA = (1.0 + np.sqrt(5.0)) / (3.0 + np.sqrt(5.0))


# ----------------------------------------------------------------------------------------------------------------
# block decomposition (Appendix of Lopez-Ramirez et al. 2016)
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BlockDecomposition:
    r"""Block observability form of an observable pair ``(A, C)`` (Lopez-Ramirez et al. 2016, (5), (31), (32)).

    Attributes
    ----------
    Phi : ndarray, shape (n, n)
        Transformation with :math:`\Phi A\Phi^{-1} = F\tilde C + \tilde A` and :math:`C\Phi^{-1} = [C_0\ 0]`.
    F : ndarray, shape (n, n1)
        Output-injection part of the transformed ``A`` (its first block column).
    A_tilde : ndarray, shape (n, n)
        Block-superdiagonal part (5): blocks :math:`A_{i,i+1}` of full column rank, zero elsewhere.
    C0 : ndarray, shape (k, k)
        Nonsingular output block, ``k = n1 = rank(C)``.
    C_tilde : ndarray, shape (k, n)
        :math:`[I_{n_1}\ 0]`.
    block_sizes : tuple of int
        ``(n_1, ..., n_m)``, non-increasing, summing to ``n``.
    O : ndarray, shape (n, n)
        The orthogonal staircase basis (30) (columns); ``None`` when ``Phi`` was supplied by the caller.
    residual : float
        :math:`\|\Phi A\Phi^{-1} - F\tilde C - \tilde A\|_F / \|A\|_F`: what the structure leaves out (rounding
        for a computed ``Phi``; the printing precision for a ``Phi`` copied from a paper).
    """

    Phi: np.ndarray
    F: np.ndarray
    A_tilde: np.ndarray
    C0: np.ndarray
    C_tilde: np.ndarray
    block_sizes: tuple[int, ...]
    O: np.ndarray | None = None
    residual: float = 0.0

    @property
    def n(self) -> int:
        return int(sum(self.block_sizes))

    @property
    def m(self) -> int:
        """Number of blocks (the observability index)."""
        return len(self.block_sizes)

    def blocks(self) -> list[slice]:
        """Index slices of the blocks."""
        edges = np.concatenate([[0], np.cumsum(self.block_sizes)])
        return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=False)]


def _as_matrix(name: str, value, shape=None) -> np.ndarray:
    arr = np.array(as_real_array(name, value))
    if arr.ndim == 1 and shape is not None and len(shape) == 2 and shape[0] == 1:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise ValueError(f"expected {name} to be a 2-D matrix, actual value: shape {arr.shape}")
    if shape is not None:
        for got, want in zip(arr.shape, shape, strict=False):
            if want is not None and got != want:
                raise ValueError(f"expected {name} with shape {shape}, actual value: shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"expected finite entries in {name}, actual value: {arr!r}")
    return arr


def _check_pair(A, C) -> tuple[np.ndarray, np.ndarray]:
    A = _as_matrix("A", A)
    n = A.shape[0]
    if A.shape != (n, n) or n < 1:
        raise ValueError(f"expected A square (n, n), actual value: shape {A.shape}")
    C = _as_matrix("C", C, (1, n) if np.ndim(C) == 1 else (None, n))
    k = C.shape[0]
    if np.linalg.matrix_rank(C) != k:
        raise ValueError(f"expected C of full row rank {k}, actual value: rank {np.linalg.matrix_rank(C)}")
    rank = _observability_rank(A, C)  # from A and C at unit norm: the blocks C A^i scale apart with the units
    if rank < n:
        raise ValueError(f"expected an observable pair (A, C), actual value: observability rank {rank} < {n}")
    return A, C


def _left_inverse(M: np.ndarray) -> np.ndarray:
    """:math:`(M^TM)^{-1}M^T` for a full-column-rank ``M`` (the Appendix's :math:`A_{i,i+1}^+`)."""
    return np.linalg.solve(M.T @ M, M.T)


def _structure(H: np.ndarray, sizes, k: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Split ``H`` into ``F`` (first block column) and block-superdiagonal ``A_tilde``; return the residual."""
    n = H.shape[0]
    edges = np.concatenate([[0], np.cumsum(sizes)])
    F = H[:, :k].copy()
    At = np.zeros((n, n))
    for i in range(len(sizes) - 1):
        r, c = slice(edges[i], edges[i + 1]), slice(edges[i + 1], edges[i + 2])
        At[r, c] = H[r, c]
    rest = H - F @ np.eye(k, n) - At
    return F, At, float(np.linalg.norm(rest))


def block_decomposition(A, C, Phi=None, *, tol: float = 1e-9) -> BlockDecomposition:
    r"""Block decomposition of the Appendix of Lopez-Ramirez et al. 2016.

    Without ``Phi``: the orthogonal staircase (30) (:math:`C_m^\perp = \mathrm{null}(C_m)`,
    :math:`\hat C_m = \mathrm{null}(C_m^{\perp T})`, :math:`A_{m+1} = C_m^{\perp T}A_mC_m^\perp`,
    :math:`C_{m+1} = \hat C_m^TA_mC_m^\perp`) gives a block lower-Hessenberg :math:`\mathcal O^TA\mathcal O` with
    full-column-rank superdiagonal blocks; a block lower-unitriangular :math:`\Phi_b` then clears every block of
    rows ``m, ..., 2`` except the first column, bottom-up and right-to-left, with the left inverses
    :math:`A_{j-1,j}^+` — the elimination that (32) writes in closed form — and :math:`\Phi = \Phi_b\mathcal O^T`.

    With ``Phi`` (e.g. the matrix printed in section V of the paper): ``F``, ``A_tilde`` and ``C0`` are read off
    :math:`\Phi A\Phi^{-1}` and :math:`C\Phi^{-1}`, block sizes from the output rank and the ranks of the
    superdiagonal blocks; ``residual`` then reports how far the supplied ``Phi`` is from exact.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (k, n)
        Full row rank, ``(A, C)`` observable.
    Phi : array_like, shape (n, n), optional
    tol : float
        Relative rank tolerance.

    Returns
    -------
    BlockDecomposition

    Raises
    ------
    TypeError
        A non-number ``tol`` or non-real matrices.
    ValueError
        An empty ``A``, ``tol <= 0``, unobservable pair, rank-deficient ``C``, or a supplied ``Phi`` that is
        singular or does not produce the block structure (relative residual above ``1e-3``).
    """
    tol = check_positive("tol", tol)
    A, C = _check_pair(A, C)
    n, k = A.shape[0], C.shape[0]
    scale = np.linalg.norm(A) or 1.0  # blocks of Phi A Phi^-1 judged against ||A||, whatever its units
    if Phi is not None:
        Phi = _as_matrix("Phi", Phi, (n, n))
        if np.linalg.cond(Phi) > 1e12:
            raise ValueError(f"expected a nonsingular Phi, actual value: condition number {np.linalg.cond(Phi):.3g}")
        Pinv = np.linalg.inv(Phi)
        H = Phi @ A @ Pinv
        CP = C @ Pinv
        if np.linalg.norm(CP[:, k:]) > 1e-3 * np.linalg.norm(CP):
            raise ValueError(
                f"expected C Phi^-1 = [C0 0], actual value: trailing block norm {np.linalg.norm(CP[:, k:]):.3g}"
            )
        sizes = [k]
        while sum(sizes) < n:
            r0 = sum(sizes[:-1])
            blk = H[r0 : r0 + sizes[-1], sum(sizes) :]
            sv = np.linalg.svd(blk, compute_uv=False)
            nxt = int(np.sum(sv > 1e-3 * max(sv[0], 1e-300) + 1e-6 * scale)) if sv.size else 0
            if nxt == 0:
                raise ValueError(
                    "expected Phi A Phi^-1 with full-rank superdiagonal blocks, actual value: a zero "
                    f"block after block sizes {sizes}"
                )
            sizes.append(nxt)
        F, At, res = _structure(H, sizes, k)
        res /= scale
        if res > 1e-3:
            raise ValueError(f"expected Phi A Phi^-1 = F C_tilde + A_tilde, actual value: relative residual {res:.3g}")
        return BlockDecomposition(Phi, F, At, CP[:, :k].copy(), np.eye(k, n), tuple(sizes), None, res)

    # orthogonal staircase (30)
    O = np.eye(n)
    # on A and C at unit norm (the subspaces do not depend on their scale): the tolerance below, absolute under 1 so
    # that a block vanishing in exact arithmetic has rank 0, read every block of a small C (or of a small A, the
    # later Cm) as zero
    Am, Cm = unit(A), unit(C)
    sizes: list[int] = []
    offset = 0
    while True:
        r = int(np.linalg.matrix_rank(Cm, tol=tol * max(np.linalg.norm(Cm), 1.0) * max(Cm.shape)))
        if r == 0:  # pragma: no cover - excluded by the observability check
            raise ValueError(f"expected an observable pair (A, C), actual value: staircase stalls at size {offset}")
        if r == Am.shape[0]:
            sizes.append(r)
            break
        from scipy.linalg import null_space  # lazy: importing scipy.linalg costs ~0.4 s of `import smo_gym`

        Cperp = null_space(Cm, rcond=tol)
        Chat = null_space(Cperp.T, rcond=tol)
        T = np.hstack([Chat, Cperp])
        O[:, offset:] = O[:, offset:] @ T
        sizes.append(r)
        offset += r
        Am, Cm = Cperp.T @ Am @ Cperp, Chat.T @ Am @ Cperp
    H = O.T @ A @ O
    edges = np.concatenate([[0], np.cumsum(sizes)])
    blk = [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=False)]
    m = len(sizes)
    Phib = np.eye(n)
    # clear rows m..2 (0-based m-1..1), columns i..2 (0-based i..1), with row j-1's superdiagonal block
    for i in range(m - 1, 0, -1):
        for j in range(i, 0, -1):
            X = H[blk[i], blk[j]] @ _left_inverse(H[blk[j - 1], blk[j]])
            T = np.eye(n)
            T[blk[i], blk[j - 1]] = -X
            Tinv = np.eye(n)
            Tinv[blk[i], blk[j - 1]] = X
            H = T @ H @ Tinv
            Phib = T @ Phib
    Phi = Phib @ O.T
    H = Phi @ A @ np.linalg.inv(Phi)
    F, At, res = _structure(H, sizes, k)
    res /= scale
    if res > 1e-8:  # pragma: no cover - numerical safeguard
        raise ValueError(f"expected the block form within rounding, actual value: relative residual {res:.3g}")
    C0 = (C @ O)[:, :k]
    return BlockDecomposition(Phi, F, At, C0, np.eye(k, n), tuple(sizes), O, res)


# ----------------------------------------------------------------------------------------------------------------
# homogeneity: degrees, dilations, Xi
# ----------------------------------------------------------------------------------------------------------------
def ilf_degrees(m: int, mu: float) -> np.ndarray:
    r"""Weights (8): :math:`\tilde r_i = i\mu / (1 + (m-1)\mu)`, ``i = 1..m`` (one per block)."""
    m = check_int_in_range("m", m, 1, 10_000)
    mu = check_positive("mu", mu)
    return np.arange(1, m + 1) * mu / (1.0 + (m - 1) * mu)


def _expand(values, sizes) -> np.ndarray:
    return np.repeat(np.asarray(values, dtype=float), sizes, axis=-1)


def dilation(lam, r_blocks, sizes) -> np.ndarray:
    r"""Diagonal of the dilation (4), :math:`D_r(\lambda) = \mathrm{diag}(\lambda^{r_i}I_{n_i})`.

    Shape ``lam.shape + (n,)``.

    ``lam`` may be an array (broadcast); ``lam = 0`` gives zeros (all ``r_i > 0``).
    """
    lam = np.asarray(lam, dtype=float)[..., None]
    return lam ** _expand(r_blocks, sizes)


def ilf_homogeneity_matrices(m: int, mu: float, sizes) -> dict[str, np.ndarray]:
    r"""Diagonals of :math:`H_{\tilde r}` (Prop. 8) and :math:`H_1, H_2` (19).

    .. math:: r_i = (-1)^i\tilde r + \Big[1 + \frac{(-1)^{i+1}\mu}{1+(m-1)\mu}\Big]\mathbf 1,\quad i = 1, 2.
    """
    r = ilf_degrees(m, mu)
    r1 = mu / (1.0 + (m - 1) * mu)
    return {
        "H_r": _expand(r, sizes),
        "H_1": _expand(-r + (1.0 + r1), sizes),
        "H_2": _expand(r + (1.0 - r1), sizes),
    }


def xi_finite(lam, r_blocks, sizes) -> np.ndarray:
    r"""Diagonal of (10), :math:`\Xi(\lambda) = \lambda(D_{\tilde r}(1/\lambda) - I)`.

    That is :math:`\mathrm{diag}(\lambda^{1-\tilde r_i} - \lambda)`, shape ``lam.shape + (n,)``.
    """
    lam = np.asarray(lam, dtype=float)[..., None]
    p = _expand(r_blocks, sizes)
    return lam ** (1.0 - p) - lam


def xi_fixed(i: int, lam, gam, r_blocks, sizes) -> np.ndarray:
    r"""Diagonal of (20), :math:`\bar\Xi_i(\lambda,\gamma) = \frac\lambda2\{D_{\tilde r}(\gamma^{i-1}/\lambda)
    + D_{\tilde r}(\lambda/\gamma^{i-2}) - 2I\}`, ``i = 1, 2``.

    Written as :math:`\frac12(\gamma^{(i-1)r}\lambda^{1-r} + \gamma^{(2-i)r}\lambda^{1+r}) - \lambda` so that
    :math:`\gamma = 0` (used in (29)) is finite.
    """
    lam = np.asarray(lam, dtype=float)[..., None]
    gam = np.asarray(gam, dtype=float)[..., None]
    p = _expand(r_blocks, sizes)
    return 0.5 * (gam ** ((i - 1) * p) * lam ** (1.0 - p) + gam ** ((2 - i) * p) * lam ** (1.0 + p)) - lam


# ----------------------------------------------------------------------------------------------------------------
# LMIs
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ILFCertificate:
    r"""NumPy re-verification of a gain design; ``ok`` is what :func:`ilf_gains` requires before returning.

    Attributes
    ----------
    lmi_margins : dict
        For each LMI (paper numbering), the largest eigenvalue of the matrix that must be negative semidefinite
        (so ``<= tol`` means satisfied).
    parametric_margin : float
        :math:`\max_{\lambda(,\gamma)}\lambda_{\max}(\Xi Z\Xi - P)` over ``dense_points`` points of the
        parameter set of (14) / (24) (``<= tol`` means satisfied).
    dense_points : int
    hurwitz_abscissa : float
        Largest real part of the eigenvalues of :math:`\tilde A + L\tilde C` (negative for a valid design).
    ok : bool
    tol : float
        The tolerance the margins were compared with: the requested one times ``min(1, scale of the matrices)``.
    """

    lmi_margins: dict
    parametric_margin: float
    dense_points: int
    hurwitz_abscissa: float
    ok: bool
    tol: float


@dataclass(frozen=True)
class ILFDesign:
    r"""Result of :func:`ilf_gains`.

    Attributes
    ----------
    L : ndarray, shape (n, k)
        Observer gain (paper's sign convention: :math:`\tilde A + L\tilde C` Hurwitz, entries usually negative).
    P : ndarray, shape (n, n)
        The ILF matrix of (3).
    kind : {"finite", "fixed"}
    mu, delta : float
    alpha : float or None
        Fixed time only: :math:`T_{\max} \le 2(1+(m-1)\mu)/(\alpha\mu)` (Theorem 10).
    decomposition : BlockDecomposition
    grid : ndarray or tuple of ndarray
        The final grid(s) of Algorithm 9 / 12.
    refinements : int
        ``p`` when the loop stopped.
    certificate : ILFCertificate
    variables : dict
        The other matrices of the LMIs (``Z``, ``M``, ...).
    """

    L: np.ndarray
    P: np.ndarray
    kind: str
    mu: float
    delta: float
    alpha: float | None
    decomposition: BlockDecomposition
    grid: object
    refinements: int
    certificate: ILFCertificate
    variables: dict = field(default_factory=dict)
    condition: str = "proposition"

    @property
    def settling_time_bound(self) -> float | None:
        """Theorem 10's :math:`T_{\\max}` for the fixed-time design, ``None`` for finite time (it depends on e(0))."""
        if self.kind != "fixed":
            return None
        m = self.decomposition.m
        return 2.0 * (1.0 + (m - 1) * self.mu) / (self.alpha * self.mu)


def _sym(X):
    cp = require("cvxpy", "design")

    return 0.5 * (X + X.T) if isinstance(X, np.ndarray) else cp.Constant(0.5) * (X + X.T)


def _refine(grid: np.ndarray) -> np.ndarray:
    return np.sort(np.concatenate([grid, 0.5 * (grid[:-1] + grid[1:])]))


def _finite_constraints(v, dec, Hr, grid, delta, eps, numeric=False, proposition=True):
    """The matrices of (11), (12), (13), (15), (16), each required ``<= 0`` (``>= 0`` ones are negated).

    With ``proposition=False`` (15)-(16) are replaced by (14) at the grid points only.
    """
    cp = require("cvxpy", "design")

    bm = np.block if numeric else cp.bmat
    P, Y, Z, M = v["P"], v["Y"], v["Z"], v.get("M")
    n, k = dec.n, dec.C0.shape[0]
    At, Ct = dec.A_tilde, dec.C_tilde
    I, Ik = np.eye(n), np.eye(k)
    E1 = Ct.T @ Ct
    HrM = np.diag(Hr)
    out = {}
    top = P @ At + At.T @ P + Ct.T @ Y.T + Y @ Ct + P + P @ HrM + HrM @ P
    out["(11)"] = bm([[top, P], [P, -Z]])
    out["(12)"] = -bm([[Ik, Y.T], [Y, P]])
    out["(13a)"] = -(P @ HrM + HrM @ P) + eps * I
    out["(13b)"] = -(P - delta * (E1 @ P @ E1)) + eps * I
    out["P>0"] = -P + eps * I
    out["Z>0"] = -Z + eps * I
    xis = xi_finite(grid, Hr_blocks(Hr, dec), dec.block_sizes)
    if not proposition:
        for i in range(len(grid)):
            X = np.diag(xis[i])
            out[f"(14) lambda={grid[i]:.4g}"] = X @ Z @ X - P
        return out
    out["M>0"] = -M + eps * I
    IH = I - HrM
    out["(16)"] = -bm([[IH @ Z + Z @ IH, -Z @ HrM], [-HrM @ Z, M]]) + eps * np.eye(2 * n)
    for i in range(1, len(grid)):
        X = np.diag(xis[i])
        out[f"(15) lambda={grid[i]:.4g}"] = X @ Z @ X + (grid[i] - grid[i - 1]) * M - P + eps * I
    return out


def Hr_blocks(diag_values: np.ndarray, dec: BlockDecomposition) -> np.ndarray:
    """One value per block from a per-coordinate diagonal."""
    return np.array([diag_values[s.start] for s in dec.blocks()])


def _fixed_constraints(v, dec, mu, alpha, beta, lgrid, ggrid, delta, eps, numeric=False, proposition=True):
    """The matrices of (21)-(23) and (25)-(29), each required ``<= 0``.

    With ``proposition=False`` (25)-(29) are replaced by (24) at the grid points only.
    """
    cp = require("cvxpy", "design")

    bm = np.block if numeric else cp.bmat
    n, k = dec.n, dec.C0.shape[0]
    At, Ct = dec.A_tilde, dec.C_tilde
    I, Ik = np.eye(n), np.eye(k)
    E1 = Ct.T @ Ct
    mats = ilf_homogeneity_matrices(dec.m, mu, dec.block_sizes)
    Hr = np.diag(mats["H_r"])
    r = ilf_degrees(dec.m, mu)
    sizes = dec.block_sizes
    P, Y = v["P"], v["Y"]
    out = {}
    out["(22)"] = -bm([[alpha * Ik, Y.T], [Y, P]])
    out["P>0"] = -P + eps * I
    out["(23b)"] = -(P - delta * (E1 @ P @ E1))
    for i in (1, 2):
        Hi = np.diag(mats[f"H_{i}"])
        Z = v[f"Z{i}"]
        top = P @ At + At.T @ P + Ct.T @ Y.T + Y @ Ct + alpha * (P + P @ Hi + Hi @ P)
        out[f"(21) i={i}"] = bm([[top, P], [P, -Z]])
        out[f"(23a) i={i}"] = -(P @ Hi + Hi @ P) + eps * I
        if not proposition:
            out[f"Z{i}>0"] = -Z + eps * I
            for lam in lgrid[1:]:  # lambda = 0 gives Xi = 0; gamma = 0 is the closure of (0, 1]
                for g in ggrid:
                    X = np.diag(xi_fixed(i, lam, g, r, sizes))
                    out[f"(24) i={i} lambda={lam:.4g} gamma={g:.4g}"] = X @ Z @ X - P
            continue
        S, R, M, U = (v[f"{name}{i}"] for name in "SRMU")
        for name, X in (("Z", Z), ("S", S), ("R", R), ("M", M), ("U", U)):
            out[f"{name}{i}>0"] = -X + eps * I
        out[f"(25) i={i}"] = -(S @ Hr + Hr @ S) + eps * I
        out[f"(26) i={i}"] = -bm(
            [
                [2 * Z - Z @ Hr - Hr @ Z, 2 * Z + Z @ Hr - Hr @ Z, 2 * Z - Hr @ Z],
                [2 * Z - Z @ Hr + Hr @ Z, 2 * Z + Z @ Hr + Hr @ Z + S, 2 * Z + Hr @ Z],
                [2 * Z - Z @ Hr, 2 * Z + Z @ Hr, 2 * Z + R],
            ]
        )
        out[f"(27) i={i}"] = -bm([[Z @ Hr + Hr @ Z - beta * Z, Hr @ Z - beta * Z], [Z @ Hr - beta * Z, M - beta * Z]])
        sgn = (-1.0) ** i
        out[f"(28) i={i}"] = -bm([[2 * M + sgn * (Hr @ M + M @ Hr), 2 * M + sgn * Hr @ M], [2 * M + sgn * M @ Hr, U]])
        for j in range(1, len(lgrid)):
            lam, dl = lgrid[j], lgrid[j] - lgrid[j - 1]
            X0 = np.diag(xi_fixed(i, lam, 0.0, r, sizes))
            for s in range(1, len(ggrid)):
                g, gp = ggrid[s], ggrid[s - 1]
                X = np.diag(xi_fixed(i, lam, g, r, sizes))
                D = np.diag(dilation(lam * g ** (2 - i), r, sizes))  # D(lambda / gamma^(i-2))
                w = (g**beta - gp**beta) / (beta * g**beta)
                out[f"(29) i={i} lambda={lam:.4g} gamma={g:.4g}"] = (
                    X @ Z @ X + dl * R + 0.25 * dl * (D @ S @ D) + w * (X0 @ M @ X0 + dl * U) - P + eps * I
                )
    return out


def _max_eig(X) -> float:
    X = np.asarray(X, dtype=float)
    return float(np.max(np.linalg.eigvalsh(0.5 * (X + X.T))))


def _solve(constraints: dict, variables: dict) -> tuple[str, dict]:
    cp = require("cvxpy", "design")

    cons = []
    for M in constraints.values():
        cons.append(_sym(M) << 0)
    problem = cp.Problem(cp.Minimize(0), cons)
    try:
        with warnings.catch_warnings():  # "solution may be inaccurate": the status below says so, and we refine
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:  # pragma: no cover - reported as infeasibility
        return f"solver error: {exc}", {}
    if problem.status != "optimal":
        return str(problem.status), {}
    return "optimal", {name: np.asarray(var.value, dtype=float) for name, var in variables.items()}


def ilf_gains(
    A,
    C,
    mu: float,
    kind: str = "finite",
    *,
    delta: float = LOPEZ_RAMIREZ_2016_DELTA,
    alpha: float | None = None,
    beta: float | None = None,
    eps: float = 1e-6,
    max_refinements: int = 5,
    dense_points: int = 401,
    tol: float = 1e-7,
    decomposition: BlockDecomposition | None = None,
    condition: str = "proposition",
) -> ILFDesign:
    r"""Observer gain of Lopez-Ramirez et al. 2016, Algorithm 9 (``kind="finite"``) or 12 (``kind="fixed"``).

    Finite time (Theorem 6 with Proposition 8): find :math:`P, Z, M \succ 0` and ``Y`` with

    .. math::
        \begin{pmatrix} P\tilde A + \tilde A^TP + \tilde C^TY^T + Y\tilde C + P + PH_{\tilde r} + H_{\tilde r}P & P\\
        P & -Z\end{pmatrix} \preceq 0,\quad
        \begin{pmatrix} I_k & Y^T\\ Y & P\end{pmatrix}\succeq 0,\quad
        PH_{\tilde r} + H_{\tilde r}P\succ 0,\quad P\succ\delta\tilde C^T\tilde CP\tilde C^T\tilde C,

    .. math::
        \Xi(\lambda_i)Z\Xi(\lambda_i) + (\lambda_i-\lambda_{i-1})M \prec P,\quad
        \begin{pmatrix}(I-H_{\tilde r})Z + Z(I-H_{\tilde r}) & -ZH_{\tilde r}\\ -H_{\tilde r}Z & M\end{pmatrix}\succ0

    on the grid :math:`0=\lambda_0<\dots<\lambda_N=\delta^{-1/2}`, halving every interval until feasible
    (Algorithm 9). Fixed time (Theorem 10 with Proposition 11, Algorithm 12): (21)-(23) for ``i = 1, 2`` with
    the rate ``alpha``, (25)-(28), and (29) on the product grid of :math:`\lambda\in(0,\delta^{-1/2}]` and
    :math:`\gamma\in(0,1]`, both refined together. :math:`L = P^{-1}Y`.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (k, n)
    mu : float
        Homogeneity parameter: ``0 < mu <= 1`` for finite time, ``0 < mu < 1`` for fixed time.
    kind : {"finite", "fixed"}
    delta : float
        ``0 < delta < 1``; default the paper's :math:`(1+\sqrt5)/(3+\sqrt5)`.
    alpha : float, optional
        Fixed time only (required): convergence rate, :math:`T_{\max}\le 2(1+(m-1)\mu)/(\alpha\mu)`.
    beta : float, optional
        Fixed time only: the number :math:`\beta>0` of Proposition 11 (it multiplies ``Z`` in (27) and is an
        exponent in (29), so it is fixed, not a decision variable). (27) forces :math:`\beta < 2\tilde r_1`;
        default :math:`\tilde r_1`.
    eps : float
        Margin replacing the strict inequalities.
    max_refinements : int
        Largest ``p`` of the refinement loop before giving up.
    dense_points : int
        Points per parameter axis of the NumPy re-check of (14) / (24).
    tol : float
        Tolerance of the NumPy re-verification, relative to the scale of the matrices (:func:`certify_ilf`).
    decomposition : BlockDecomposition, optional
        Use this (e.g. from the paper's printed ``Phi``) instead of computing one.
    condition : {"proposition", "points"}
        How the parametric inequality (14) / (24) is made finite. ``"proposition"`` (default): the sufficient
        LMIs of Proposition 8 / 11 on the grid, refined while infeasible (Algorithms 9 and 12 as printed).
        ``"points"``: (14) / (24) imposed at the grid points only, refined while the dense NumPy re-check fails
        (the plain gridding the paper describes before Proposition 8). Needed for ``mu = 1``: the weight
        :math:`\tilde r_m = 1` zeroes a diagonal block of (16), which then has no strictly positive solution.

    Returns
    -------
    ILFDesign

    Raises
    ------
    LMIInfeasibleError
        If the LMIs stay infeasible after ``max_refinements`` refinements, or the solver's answer fails the NumPy
        re-verification.
    ValueError, TypeError
        On invalid arguments.

    Notes
    -----
    Read against the scan: (21) prints :math:`P\tilde A + \tilde AP`; the symmetric form :math:`P\tilde A +
    \tilde A^TP` of (11) is used. In (29) the second factor printed :math:`\Xi_i` and :math:`\bar\Xi_i(\lambda,0)`
    are read as :math:`\bar\Xi_i(\lambda_j,\gamma_s)` and :math:`\bar\Xi_i(\lambda_j,0)`. Algorithm 12 prints the
    LMIs of the finite-time case ("(11), (12), (15)"); it means (21), (22), (29). Whatever the reading, the
    returned certificate checks (14) / (24) themselves on a dense grid, so a wrong reading could only make the
    design fail, never return an uncertified gain.

    Measured on the example of section V: Proposition 8 is infeasible for the paper's ``mu = 1`` (provably: with
    :math:`\tilde r_m = 1` the block :math:`(I-H_{\tilde r})Z + Z(I-H_{\tilde r})` of (16) has a zero diagonal
    block, so (16) cannot be positive definite), while ``condition="points"`` certifies a gain close to the
    printed one; Proposition 11 with the default :math:`\beta = \tilde r_1` is feasible for ``mu = 0.5``,
    ``alpha = 32/7`` after three refinements (gains of the printed magnitude).
    """
    cp = require("cvxpy", "design")

    kind = check_choice("kind", kind, ("finite", "fixed"))
    condition = check_choice("condition", condition, ("proposition", "points"))
    mu = check_positive("mu", mu)
    if kind == "finite" and mu > 1.0:
        raise ValueError(f"expected 0 < mu <= 1 for the finite-time observer, actual value: {mu!r}")
    if kind == "fixed" and mu >= 1.0:
        raise ValueError(f"expected 0 < mu < 1 for the fixed-time observer, actual value: {mu!r}")
    delta = check_positive("delta", delta)
    if delta >= 1.0:
        raise ValueError(f"expected 0 < delta < 1, actual value: {delta!r}")
    eps = check_positive("eps", eps)
    dense_points = check_int_in_range("dense_points", dense_points, 2, 100_000)
    max_refinements = check_int_in_range("max_refinements", max_refinements, 0, 12)
    if kind == "fixed" and alpha is None:
        raise ValueError("expected alpha > 0 for the fixed-time design, actual value: None")
    alpha = None if alpha is None else check_positive("alpha", alpha)  # ILFDesign keeps it, even for finite time
    dec = block_decomposition(A, C) if decomposition is None else decomposition
    if not isinstance(dec, BlockDecomposition):
        raise TypeError(f"expected a BlockDecomposition, actual value: {type(decomposition).__name__}")
    if kind == "fixed":
        r1 = float(ilf_degrees(dec.m, mu)[0])
        beta = r1 if beta is None else check_positive("beta", beta)
        if condition == "proposition" and beta >= 2.0 * r1:
            raise ValueError(
                f"expected beta < 2 r_1 = {2 * r1:.4g} (LMI (27) needs Z H + H Z >= beta Z, which fails "
                f"at x = Z^-1 e_1 otherwise), actual value: {beta!r}"
            )
    n, k = dec.n, dec.C0.shape[0]
    proposition = condition == "proposition"
    lgrid = np.array([0.0, delta**-0.5])
    ggrid = np.array([0.0, 1.0])
    if not proposition:  # (14) / (24) at interior points from the start: the end points alone say little
        for _ in range(2):
            lgrid, ggrid = _refine(lgrid), _refine(ggrid)
    status, cert, values = "", None, {}
    for p in range(max_refinements + 1):  # noqa: B007 - p, the refinements made, is reported after the loop
        v = {"P": cp.Variable((n, n), symmetric=True), "Y": cp.Variable((n, k))}
        if kind == "finite":
            v["Z"] = cp.Variable((n, n), symmetric=True)
            if proposition:
                v["M"] = cp.Variable((n, n), symmetric=True)
            Hr = ilf_homogeneity_matrices(dec.m, mu, dec.block_sizes)["H_r"]
            cons = _finite_constraints(v, dec, Hr, lgrid, delta, eps, proposition=proposition)
        else:
            for i in (1, 2):
                for name in "ZSRMU" if proposition else "Z":
                    v[f"{name}{i}"] = cp.Variable((n, n), symmetric=True)
            cons = _fixed_constraints(v, dec, mu, alpha, beta, lgrid, ggrid, delta, eps, proposition=proposition)
        status, values = _solve(cons, v)
        if status == "optimal":
            values = {name: X if name == "Y" else 0.5 * (X + X.T) for name, X in values.items()}
            L = np.linalg.solve(values["P"], values["Y"])
            cert = certify_ilf(
                dec,
                L,
                values,
                kind,
                mu,
                delta,
                alpha,
                beta,
                lgrid,
                ggrid,
                eps,
                dense_points,
                tol,
                proposition=proposition,
            )
            if cert.ok or proposition:
                break
        elif not proposition:
            break  # more grid points only add constraints
        lgrid = _refine(lgrid)
        if kind == "fixed":
            ggrid = _refine(ggrid)
    if status != "optimal":
        raise LMIInfeasibleError(
            f"expected feasible ILF LMIs ({kind}-time, mu={mu}, delta={delta:.4g}"
            + (f", alpha={alpha}" if kind == "fixed" else "")
            + f", condition={condition!r}), actual value: solver status {status!r} with {len(lgrid)} lambda points "
            f"after {p} refinements; try a smaller mu"
            + (" or alpha" if kind == "fixed" else "")
            + (
                ""
                if not proposition or mu < 1
                else " (with mu = 1 the weight r_m = 1 makes (16) infeasible: use condition='points')"
            )
        )
    if not cert.ok:
        raise LMIInfeasibleError(
            f"expected the solver's answer to pass the NumPy re-verification, actual value: LMI margins "
            f"{ {k_: round(v_, 9) for k_, v_ in cert.lmi_margins.items() if v_ > cert.tol} }, parametric margin "
            f"{cert.parametric_margin:.3g} on {cert.dense_points} points, Hurwitz abscissa "
            f"{cert.hurwitz_abscissa:.3g} (after {p} refinements)"
        )
    grid = lgrid if kind == "finite" else (lgrid, ggrid)
    extra = {k_: v_ for k_, v_ in values.items() if k_ != "P"}
    if kind == "fixed":
        extra["beta"] = beta
    return ILFDesign(L, values["P"], kind, mu, delta, alpha, dec, grid, p, cert, extra, condition)


def certify_ilf(
    dec: BlockDecomposition,
    L,
    values: dict,
    kind: str,
    mu: float,
    delta: float,
    alpha,
    beta,
    lgrid,
    ggrid,
    eps: float,
    dense_points: int = 2001,
    tol: float = 1e-7,
    *,
    proposition: bool = True,
) -> ILFCertificate:
    r"""Re-verify an ILF design in NumPy: every LMI at ``values`` and the parametric inequality on a dense grid.

    The LMI matrices are rebuilt with NumPy from the same functions the solver used (with margin ``eps``), so a
    margin ``<= tol`` means the strict inequality holds with at least ``eps - tol`` to spare; (14) / (24) is
    checked on ``dense_points`` points per axis, independently of the solver's grid. ``tol`` is relative to the
    scale of the matrices, ``min(1, largest spectral norm of P, Z, ...)`` (the margins are linear in them), and the
    certificate's ``tol`` is this scaled tolerance.

    Raises
    ------
    TypeError, ValueError
        Arguments of another type, shape or range: ``values`` without a matrix the LMIs need (``M`` for the
        finite-time Proposition 8), non-finite matrices, a grid that is not a 1-D increasing array of finite numbers,
        ``alpha`` missing for the fixed-time design.
    """
    kind = check_choice("kind", kind, ("finite", "fixed"))
    if not isinstance(dec, BlockDecomposition):
        raise TypeError(f"expected a BlockDecomposition, actual value: {type(dec).__name__}")
    delta = check_real_in_range("delta", delta, 0.0, 1.0, low_open=True, high_open=True)
    mu, eps, tol = check_positive("mu", mu), check_positive("eps", eps), check_nonnegative("tol", tol)
    dense_points = check_int_in_range("dense_points", dense_points, 2, 100_000)
    proposition = check_bool("proposition", proposition)
    if kind == "finite":
        names = ("P", "Z", "M") if proposition else ("P", "Z")
    else:
        names = ("P",) + tuple(f"{x}{i}" for i in (1, 2) for x in ("ZSRMU" if proposition else "Z"))
        if alpha is None:
            raise ValueError("expected alpha > 0 for the fixed-time design, actual value: None")
        alpha = check_positive("alpha", alpha)
        beta = check_positive("beta", beta) if proposition else beta
        ggrid = _as_grid("ggrid", ggrid)
    lgrid = _as_grid("lgrid", lgrid)
    if not isinstance(values, dict) or any(name not in values for name in names):
        raise ValueError(
            f"expected values with the matrices {names} of a {kind}-time design, actual value: {values!r:.80}"
        )
    vals = dict(values) | {name: _as_matrix(name, values[name], (dec.n, dec.n)) for name in names}
    L = _as_matrix("L", L, (dec.n, dec.C0.shape[0]))
    vals["Y"] = vals["P"] @ L
    if kind == "finite":
        Hr = ilf_homogeneity_matrices(dec.m, mu, dec.block_sizes)["H_r"]
        mats = _finite_constraints(vals, dec, Hr, lgrid, delta, eps, numeric=True, proposition=proposition)
    else:
        mats = _fixed_constraints(
            vals, dec, mu, alpha, beta, lgrid, ggrid, delta, eps, numeric=True, proposition=proposition
        )
    margins = {name: _max_eig(M) for name, M in mats.items()}
    r = ilf_degrees(dec.m, mu)
    P = vals["P"]
    lam = np.linspace(0.0, delta**-0.5, dense_points)[1:]

    def worst_of(X, Z):  # max over rows x of lambda_max(diag(x) Z diag(x) - P), batched
        S = X[:, :, None] * Z[None] * X[:, None, :] - P[None]
        return float(np.max(np.linalg.eigvalsh(S)))

    if kind == "finite":
        worst = worst_of(xi_finite(lam, r, dec.block_sizes), vals["Z"])
        points = lam.size
    else:
        lam_f, gam_f = np.meshgrid(lam, np.linspace(0.0, 1.0, dense_points)[1:], indexing="ij")
        points = lam_f.size
        worst = max(
            worst_of(xi_fixed(i, lam_f.ravel(), gam_f.ravel(), r, dec.block_sizes), vals[f"Z{i}"]) for i in (1, 2)
        )
    closed = dec.A_tilde + np.asarray(L) @ dec.C_tilde
    abscissa = float(np.max(np.linalg.eigvals(closed).real))
    # the margins are linear in the matrices: an absolute tolerance would pass any design scaled small enough
    tol = tol * min(1.0, max(np.linalg.norm(vals[name], 2) for name in names))
    ok = all(v_ <= tol for v_ in margins.values()) and worst <= tol and abscissa < 0
    return ILFCertificate(margins, float(worst), int(points), abscissa, bool(ok), tol)


def _as_grid(name: str, value) -> np.ndarray:
    """A grid of parameter values as a 1-D float array of finite, non-decreasing entries."""
    grid = as_real_array(name, value)
    if grid.ndim != 1 or grid.size < 2 or not np.all(np.isfinite(grid)) or np.any(np.diff(grid) < 0):
        raise ValueError(
            f"expected {name} as a 1-D increasing grid of at least 2 finite numbers, actual value: {value!r:.80}"
        )
    return grid
