"""Exact rescalings for rank decisions: scaling by a power of two rounds no entry.

A rank decision on a product such as ``C A^k D`` must judge its singular values against the size of its rounding
errors, ``||C|| ||A||^k ||D||``, not against the product's own norm (a product that vanishes in exact arithmetic,
entries ``1e-17``, would have full rank) nor against 1 (a small but genuine one, ``1e-10 C``, would have rank 0).
Bringing each factor to unit norm first, with :func:`unit`, does that, and leaves no verdict depending on units.
The control library (:mod:`smo_gym.control`) and the gain design (:mod:`smo_gym.design`) both decide ranks so.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pow2", "unit"]


def pow2(x) -> np.ndarray:
    """The powers of two nearest to ``x`` (1 where ``x`` is 0 or not finite): scalings that round no entry."""
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x) & (x > 0)
    return np.where(ok, 2.0 ** np.round(np.log2(np.where(ok, x, 1.0))), 1.0)


def unit(M: np.ndarray) -> np.ndarray:
    """``M`` scaled to Frobenius norm in ``[1/sqrt 2, sqrt 2]`` by a power of two (exact; a zero ``M`` unchanged)."""
    return M / pow2(np.linalg.norm(M))
