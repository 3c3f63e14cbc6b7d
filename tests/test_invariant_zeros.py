"""Invariant zeros and strong observability: hand-derived systems, MuJoCo linearizations, SLICOT as the oracle.

The zeros of ``(A, C, D)`` are the finite ``s`` where ``R(s) = [sI - A, -D; C, 0]`` loses rank. Hand-derived cases
come from transfer functions whose numerators are known (controllable canonical form, Gilbert's realization).
For a linearized mechanical system with every position measured, ``x = [q; v]``, ``A = [[0, I], [*, *]]``,
``C = [I, 0]`` and ``D = [0; D_v]``, a kernel vector of ``R(s)`` has ``q = 0`` (output rows), then ``v = s q = 0``
(kinematic rows), then ``D_v w = 0``: there are no finite zeros whenever ``D_v`` has full column rank, whatever
the rest of ``A``. That is what the MuJoCo tests assert, and SLICOT's ``AB08ND`` (through ``slycot``, where it is
installed) is compared with on those models.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from smo_gym import control as c

MUJOCO_V5 = (
    "Ant",
    "HalfCheetah",
    "Hopper",
    "Humanoid",
    "HumanoidStandup",
    "InvertedDoublePendulum",
    "InvertedPendulum",
    "Pusher",
    "Reacher",
    "Swimmer",
    "Walker2d",
)
OWN_ENVS = ("smo_gym/VariableInertia-v0", "smo_gym/TwoLinkArm-v0", "smo_gym/FurutaPendulum-v0")
ENV_IDS = tuple(f"{name}-v5" for name in MUJOCO_V5) + OWN_ENVS
#: the linearizations the earlier random-projection zeros (kept up to |s| = 1e8 * max|entry|) rejected
REJECTED_BEFORE = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Pusher-v5", "smo_gym/VariableInertia-v0")


def controllable_canonical(num, den):
    """``(A, C, D)`` of ``num(s) / den(s)`` (coefficients, highest power first, ``deg num < deg den``)."""
    lead = float(den[0])
    den = np.asarray(den, dtype=float) / lead
    num = np.asarray(num, dtype=float) / lead
    n = den.size - 1
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1] = -den[1:][::-1]
    C = np.zeros((1, n))
    C[0, : num.size] = num[::-1]
    D = np.zeros((n, 1))
    D[-1, 0] = 1.0
    return A, C, D


def gilbert_mimo():
    r"""Gilbert's realization of :math:`G(s) = [[1/(s+1), 2/(s+3)], [1/(s+1), 1/(s+1)]]`.

    :math:`\det G = (1 - s) / ((s+1)^2 (s+3))`; the minors' least common denominator :math:`(s+1)^2(s+3)` has
    degree 3 = n (the realization is minimal), so the zero polynomial is :math:`1 - s`: one zero, at ``s = 1``.
    ``G = R_1/(s+1) + R_3/(s+3)``, ``R_1 = [[1, 0], [1, 1]] = I R_1`` (two states), ``R_3 = [1; 0][0, 2]``.
    """
    A = np.diag([-1.0, -1.0, -3.0])
    D = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 2.0]])
    C = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    return A, C, D


def tall_common_zero(z0):
    """Two outputs, one unknown input: ``[(s - z0)(s + 4); (s - z0)(s + 5)] / ((s + 1)(s + 3)(s + 4))``.

    Both rows vanish together only at ``s = z0`` (the first row's ``s = -4`` is cancelled by the pole, the second
    row's ``s = -5`` is not a root of the first), and the realization is minimal, so the only zero is ``z0``."""
    A, C1, D = controllable_canonical(np.poly([z0, -4.0]), np.poly([-1.0, -3.0, -4.0]))
    _, C2, _ = controllable_canonical(np.poly([z0, -5.0]), np.poly([-1.0, -3.0, -4.0]))
    return A, np.vstack([C1, C2]), D


def badly_scaled(A, C, D, seed=0, spread=4.0):
    """The same system in states scaled by ``10^U(-spread, spread)``, unknown input by 1e-5, outputs by 1e3."""
    rng = np.random.default_rng(seed)
    t = 10.0 ** rng.uniform(-spread, spread, A.shape[0])
    return A * t[None, :] / t[:, None], 1e3 * C * t[None, :], 1e-5 * D / t[:, None]


def assert_same_multiset(z, ref, atol=0.0, rtol=1e-9):
    """As many zeros as ``ref``, each within ``atol + rtol |x|`` of one of the other set, both ways."""
    ref = np.asarray(ref, dtype=complex)
    assert z.size == ref.size, f"{z.size} zeros {z}, expected {ref.size}: {ref}"
    for a, b in ((z, ref), (ref, z)):
        for x in a:
            assert np.min(np.abs(b - x)) <= atol + rtol * abs(x), f"{x} has no partner in {b}"


def relative_rank_gap(A, C, D, s):
    """Smallest over largest singular value of ``R(s)`` (0 where ``R(s)`` loses rank)."""
    n, p, m = A.shape[0], C.shape[0], D.shape[1]
    R = np.block([[s * np.eye(n) - A, -D], [C, np.zeros((p, m))]])
    sv = np.linalg.svd(R, compute_uv=False)
    return sv[-1] / sv[0]


# ---------------------------------------------------------------------------------------------------------------
# hand-derived systems (no slycot needed)
# ---------------------------------------------------------------------------------------------------------------
def test_siso_zeros_are_the_numerator_roots():
    A, C, D = controllable_canonical(np.poly([1.0, -2.0]), np.poly([-1.0, -3.0, -4.0]))
    assert_same_multiset(c.invariant_zeros(A, C, D), [1.0, -2.0])
    # complex pair: s^2 + 2 s + 5 = (s + 1)^2 + 4
    A, C, D = controllable_canonical([1.0, 2.0, 5.0], np.poly([-1.0, -2.0, -3.0, -4.0]))
    assert_same_multiset(c.invariant_zeros(A, C, D), [-1 + 2j, -1 - 2j])


def test_mimo_zero_of_gilbert_realization():
    A, C, D = gilbert_mimo()
    z = c.invariant_zeros(A, C, D)
    assert_same_multiset(z, [1.0])
    # independently: R(s) loses rank at s = 1 and nowhere else we look (poles included)
    assert relative_rank_gap(A, C, D, 1.0) < 1e-14
    for s in (-1.0, -3.0, 0.0, 2.0, 1j):
        assert relative_rank_gap(A, C, D, s) > 1e-3


@pytest.mark.parametrize("z0", [2.0, 1e4])
def test_tall_system_has_only_the_common_zero(z0):
    A, C, D = tall_common_zero(z0)
    assert_same_multiset(c.invariant_zeros(A, C, D), [z0])
    # rows with different zeros have no common one
    A, C1, D = controllable_canonical(np.poly([2.0, -4.0]), np.poly([-1.0, -3.0, -4.0]))
    _, C2, _ = controllable_canonical(np.poly([3.0, -5.0]), np.poly([-1.0, -3.0, -4.0]))
    assert c.invariant_zeros(A, np.vstack([C1, C2]), D).size == 0


def test_unobservable_mode_is_a_zero():
    """A mode no output sees is an (output-decoupling) zero: R(5) [e_3; 0] = 0."""
    A = np.diag([-1.0, -2.0, 5.0])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert_same_multiset(c.invariant_zeros(A, C, np.ones((3, 1))), [5.0])
    # no unknown input at all: the zeros are the unobservable eigenvalues
    assert_same_multiset(c.invariant_zeros(A, C, np.zeros((3, 0))), [5.0])


def test_no_finite_zeros():
    # 1/s^3: relative degree n
    A, C, D = controllable_canonical([1.0], [1.0, 0.0, 0.0, 0.0])
    assert c.invariant_zeros(A, C, D).size == 0
    # a mechanical system with every position measured (see the module docstring), stiff and badly scaled
    rng = np.random.default_rng(3)
    nv, m = 4, 2
    Kv = rng.standard_normal((nv, 2 * nv)) * 10.0 ** rng.uniform(-3, 5, (nv, 1))
    A = np.block([[np.zeros((nv, nv)), np.eye(nv)], [Kv]])
    D = np.vstack([np.zeros((nv, m)), rng.standard_normal((nv, m)) * 10.0 ** rng.uniform(-2, 2, (nv, 1))])
    C = np.hstack([np.eye(nv), np.zeros((nv, nv))])
    assert c.invariant_zeros(A, C, D).size == 0
    assert c.strong_observability(A, C, D).ok


@pytest.mark.parametrize("z0", [1e4, 1e6])
def test_large_genuine_zeros_are_kept(z0):
    """No cut-off on |s|: a zero far outside the poles (-1, -3, -4) is a zero."""
    A, C, D = controllable_canonical(np.poly([z0, -2.0]), np.poly([-1.0, -3.0, -4.0]))
    assert_same_multiset(c.invariant_zeros(A, C, D), [z0, -2.0])
    rep = c.strong_observability(A, C, D)
    assert not rep.ok and "invariant zeros at s = " in rep.reason
    assert_same_multiset(rep.invariant_zeros, [z0, -2.0])


def test_badly_scaled_similar_system_has_the_same_zeros():
    """A diagonal state transformation and input/output units leave the zeros; entries span 2e-9 to 5e7."""
    for system, expected in [
        (controllable_canonical(np.poly([1.0, -2.0]), np.poly([-1.0, -3.0, -4.0, -5.0])), [1.0, -2.0]),
        (gilbert_mimo(), [1.0]),
        (tall_common_zero(2.0), [2.0]),
    ]:
        for seed in range(3):
            A, C, D = badly_scaled(*system, seed=seed)
            assert_same_multiset(c.invariant_zeros(A, C, D), expected, rtol=1e-7)


def test_finite_difference_roundoff_does_not_invent_zeros():
    """A free, unactuated joint leaves rows of roundoff (1e-30) in a finite-difference linearization; balancing
    on them would scale that state by ~1e-15 and lose its kinematics, inventing zeros near 0."""
    rng = np.random.default_rng(7)
    for noise in (1e-30, 1e-20, 1e-12):
        A = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [noise, noise, noise, 0.0], [noise, -1e5, 0.0, -1e3]])
        C = np.hstack([np.eye(2), np.zeros((2, 2))])
        D = np.array([[0.0], [0.0], [noise], [5.0]])
        assert c.invariant_zeros(A, C, D).size == 0
        assert c.strong_observability(A, C, D).ok
    # and random mechanical systems with such joints (D_v keeps full column rank on the actuated ones)
    for _ in range(20):
        nv, m = 5, 2
        Kv = rng.standard_normal((nv, 2 * nv)) * 10.0 ** rng.uniform(-2, 5)
        Dv = rng.standard_normal((nv, m))
        free = np.array([True, False, True, False, False])
        Kv[free] = 10.0 ** rng.uniform(-45, -10) * rng.standard_normal((free.sum(), 2 * nv))
        Dv[free] = 0.0
        A = np.block([[np.zeros((nv, nv)), np.eye(nv)], [Kv]])
        D = np.vstack([np.zeros((nv, m)), Dv])
        C = np.hstack([np.eye(nv), np.zeros((nv, nv))])
        assert c.invariant_zeros(A, C, D).size == 0


def test_stiff_mechanism_with_every_position_measured_is_strongly_observable():
    """Regression: the linearization of smo_gym/VariableInertia-v0 (a bead held on the arm by a stiff equality
    constraint, decoupled at theta = 0) was rejected, its normal rank misjudged at a random s of size max|A|
    (4 < 5) and zeros found at the bead's poles -499.7 +- 12.4j; with both positions measured it has full normal
    rank and no zeros (module docstring), and the cascade accepts it."""
    A = np.array(
        [[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [11.113, 0.0, -0.11351, 0.0], [0.0, -2.4985e5, 0.0, -999.38]]
    )
    D = np.array([[0.0], [0.0], [5.6753], [0.0]])
    C = np.hstack([np.eye(2), np.zeros((2, 2))])
    rep = c.strong_observability(A, C, D)
    assert rep.ok, rep.reason
    assert rep.normal_rank == 5
    assert c.invariant_zeros(A, C, D).size == 0
    c.CascadedHOSMObserver(c.LinearPlant(A, D, C, D), 1e-3, 100.0)
    # measuring the arm only, the bead's poles are genuine zeros (the bead is unobservable from the arm)
    z = c.invariant_zeros(A, C[:1], D)
    assert_same_multiset(z, np.roots([1.0, 999.38, 2.4985e5]), rtol=1e-10)


# ---------------------------------------------------------------------------------------------------------------
# strong_observability takes a plant as the other helpers do; arguments are checked
# ---------------------------------------------------------------------------------------------------------------
def test_strong_observability_accepts_a_plant_or_matrices():
    A, C, D = tall_common_zero(2.0)
    plant = c.LinearPlant(A, np.zeros((3, 1)), C, D)
    from_plant, from_matrices = c.strong_observability(plant), c.strong_observability(A, C, D)
    assert not from_plant.ok and from_plant.reason == from_matrices.reason
    assert_same_multiset(from_plant.invariant_zeros, [2.0])
    assert_same_multiset(c.invariant_zeros(plant), [2.0])
    assert plant.strong_observability().reason == from_plant.reason
    # a vector D is one column
    assert_same_multiset(c.invariant_zeros(A, C, D[:, 0]), [2.0])


def test_bad_arguments_give_typed_errors():
    A, C, D = gilbert_mimo()
    plant = c.LinearPlant(A, D, C, D)
    with pytest.raises(TypeError, match=r"expected strong_observability\(plant\) with a LinearPlant .*actual value"):
        c.strong_observability(A)
    with pytest.raises(TypeError, match=r"expected strong_observability\(plant\) or .*actual value: a LinearPlant"):
        c.strong_observability(plant, C, D)
    with pytest.raises(TypeError, match=r"expected invariant_zeros\(plant\) with a LinearPlant"):
        c.invariant_zeros("plant")
    with pytest.raises(ValueError, match=r"expected C with shape \(\*x3\), actual value: shape \(2, 2\)"):
        c.strong_observability(A, C[:, :2], D)
    with pytest.raises(ValueError, match=r"expected a square A, actual value: shape \(3, 2\)"):
        c.invariant_zeros(A[:, :2], C, D)
    with pytest.raises(ValueError, match="expected finite entries in D"):
        c.invariant_zeros(A, C, np.full((3, 2), np.nan))
    with pytest.raises(TypeError, match="expected A to be an array of real numbers"):
        c.strong_observability([["a", "b"], ["c", "d"]], C, D)
    with pytest.raises(ValueError, match=r"expected tol > 0, actual value: -1"):
        c.invariant_zeros(plant, tol=-1)
    with pytest.raises(ValueError, match=r"expected tol < 1, actual value: 2"):
        c.invariant_zeros(plant, tol=2)
    with pytest.raises(TypeError, match=r"expected tol to be a real number, actual value: 'small'"):
        c.invariant_zeros(plant, tol="small")


# ---------------------------------------------------------------------------------------------------------------
# units decide no verdict: A, C, D scaled by constants; products that vanish exactly stay zero at every scale
# ---------------------------------------------------------------------------------------------------------------
def scalings():
    """``(a, c, d)``: each of ``A``, ``C``, ``D`` scaled alone by 1e-10 and by 1e10, then all three at once."""
    for k in range(3):
        for s in (1e-10, 1e10):
            yield tuple(s if i == k else 1.0 for i in range(3))
    yield from ((1e-10, 1e-10, 1e-10), (1e10, 1e10, 1e10), (1e-10, 1e10, 1e-10), (1e10, 1e-10, 1e10))


def rotated(A, C, D, seed=0):
    """The system in random orthogonal coordinates: products that vanish exactly now hold rounding errors."""
    T = np.linalg.qr(np.random.default_rng(seed).standard_normal(A.shape))[0]
    return T @ A @ T.T, C @ T.T, T @ D


def unit_chains():
    """``x1' = x2, x2' = -x1`` seen by ``y1`` (``w`` never reaches it: relative degree 0, ``c_1 A^j D = 0`` for
    every ``j``); ``x3' = x4, x4' = -x3 - x4 + w`` seen by ``y2`` (relative degree 2): strongly observable."""
    A = np.array([[0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, -1.0, -1.0]])
    return A, np.eye(4)[[0, 2]], np.eye(4)[:, [3]]


def verdicts(A, C, D):
    """Every yes/no and integer answer of strong_observability and relative_degrees."""
    rep = c.strong_observability(A, C, D)
    mol = rep.molinari
    return (
        rep.ok,
        rep.relative_degrees.tolist(),
        c.relative_degrees(A, C, D).tolist(),
        rep.normal_rank,
        rep.weakly_unobservable_dim,
        rep.invariant_zeros.size,
        mol.rank,
        mol.n_derivatives,
        rep.reason.split(" at s =")[0].split(":")[0],
    )


def derivative_stack(A, C, D, x, ws, k):
    """``[y; y'; ...; y^(k)]`` at the state ``x`` with ``w^(j) = ws[j]``: ``y^(i) = C A^i x + sum_j C A^(i-1-j) D
    w^(j)``."""
    P = [np.linalg.matrix_power(A, i) for i in range(k + 1)]
    return np.concatenate([C @ P[i] @ x + sum(C @ P[i - 1 - j] @ D @ ws[j] for j in range(i)) for i in range(k + 1)])


UNIT_SYSTEMS = {
    "strongly observable chain, relative degree 3": controllable_canonical([1.0], np.poly([-1.0, -2.0, -3.0])),
    "zero at -2, relative degree 2": controllable_canonical(np.poly([-2.0]), np.poly([-1.0, -3.0, -4.0])),
    "unstable zero of a MIMO system": gilbert_mimo(),
    "tall system with a common zero": tall_common_zero(2.0),
    "an output w never reaches": unit_chains(),
    "more unknown inputs than outputs": (gilbert_mimo()[0], gilbert_mimo()[1][:1], gilbert_mimo()[2]),
    "dependent unknown inputs": (gilbert_mimo()[0], gilbert_mimo()[1], gilbert_mimo()[2][:, [0, 0]]),
}


@pytest.mark.parametrize("name", UNIT_SYSTEMS)
def test_verdicts_do_not_depend_on_the_units_of_a_c_d(name):
    """Strong observability, relative degrees, normal rank, the number of zeros and Molinari's ranks are invariant
    under A -> a A, C -> c C, D -> d D (a change of the time, output and input units); the zeros scale with ``a``
    and Molinari's relation ``M x = Q Y`` holds for the derivatives of the scaled system's own output."""
    A, C, D = UNIT_SYSTEMS[name]
    ref = verdicts(A, C, D)
    zeros = c.strong_observability(A, C, D).invariant_zeros
    rng = np.random.default_rng(5)
    for a, cc, d in scalings():
        As, Cs, Ds = a * A, cc * C, d * D
        assert verdicts(As, Cs, Ds) == ref, (a, cc, d)
        rep = c.strong_observability(As, Cs, Ds)
        assert_same_multiset(rep.invariant_zeros, a * zeros, rtol=1e-7)
        mol = rep.molinari
        x, ws = rng.standard_normal(A.shape[0]), d * rng.standard_normal((mol.n_derivatives + 1, D.shape[1]))
        Y = derivative_stack(As, Cs, Ds, x, ws, mol.n_derivatives)
        np.testing.assert_allclose(mol.M @ x, mol.Q @ Y, rtol=0, atol=1e-9 * (np.abs(mol.Q) @ np.abs(Y)).max())


def test_a_product_that_vanishes_exactly_has_rank_zero_at_every_scale():
    """``C D = C A D = 0`` in exact arithmetic, rounding errors after an orthogonal change of coordinates: the
    relative degree stays 3 (and 0 for an output ``w`` never reaches) at every scale."""
    chain = rotated(*controllable_canonical([1.0], np.poly([-1.0, -2.0, -3.0])), seed=1)
    blind = rotated(*unit_chains(), seed=2)
    for (A, C, D), degrees in ((chain, [3]), (blind, [0, 2])):
        # rounding errors of the size the rotation leaves, made explicit: whether its own products round to exactly
        # zero depends on the matrix-product kernel (they do with some NumPy builds)
        D = D + 4e-16 * C.sum(axis=0)[:, None] / np.linalg.norm(C.sum(axis=0))
        assert 0.0 < np.abs(C @ D).max() < 1e-15  # the rounding errors the rank decisions must see through
        for a, cc, d in [(1.0, 1.0, 1.0), *scalings()]:
            rep = c.strong_observability(a * A, cc * C, d * D)
            assert rep.ok, (a, cc, d, rep.reason)
            assert rep.relative_degrees.tolist() == degrees, (a, cc, d)
            assert rep.weakly_unobservable_dim == 0 and rep.invariant_zeros.size == 0


# ---------------------------------------------------------------------------------------------------------------
# SLICOT's AB08ND as the oracle
# ---------------------------------------------------------------------------------------------------------------
def slicot_zeros(A, C, D):
    """Finite zeros of ``(A, B=D, C, 0)`` by SLICOT's ``AB08ND`` (with its balancing and default tolerance)."""
    from scipy.linalg import eigvals
    from slycot import ab08nd

    n, p, m = A.shape[0], C.shape[0], D.shape[1]
    nu, *_, Af, Bf = ab08nd(n, m, p, A, D, C, np.zeros((p, m)), equil="S", ldwork=max(1, 8 * (n + m + p) ** 2))
    return eigvals(Af[:nu, :nu], Bf[:nu, :nu]) if nu else np.zeros(0, dtype=complex)


def test_random_systems_agree_with_slicot():
    pytest.importorskip("slycot")
    rng = np.random.default_rng(11)
    total = 0
    for trial in range(60):
        n, p, m = int(rng.integers(1, 10)), int(rng.integers(1, 5)), int(rng.integers(1, 5))
        A, C, D = rng.standard_normal((n, n)), rng.standard_normal((p, n)), rng.standard_normal((n, m))
        if trial % 3 == 1 and np.linalg.matrix_rank(C) < n:  # C D = 0: higher relative degrees
            N = np.linalg.svd(C)[2][np.linalg.matrix_rank(C) :].T
            D = N @ rng.standard_normal((N.shape[1], m))
        if trial % 3 == 2 and n > 2:  # a block no output sees
            k = int(rng.integers(1, n))
            A[:k, k:], C[:, k:] = 0.0, 0.0
        z = c.invariant_zeros(A, C, D)
        total += z.size
        assert_same_multiset(z, slicot_zeros(A, C, D), atol=1e-8, rtol=1e-6)
    assert total > 20  # the comparison is not vacuous


# ---------------------------------------------------------------------------------------------------------------
# the linearization of every MuJoCo v5 environment and of the project's own environments
# ---------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def linearizations():
    """``{env id: (model, plant)}``: ``linearize(model)`` at ``qpos0``, all positions measured, ``D = B``."""
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("mujoco")

    out = {}
    for env_id in ENV_IDS:
        env = gym.make(env_id)
        model = env.unwrapped.model
        out[env_id] = (model, c.linearize(model))
        env.close()
    return out


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_mujoco_linearization_with_all_positions_has_no_zeros(linearizations, env_id):
    model, plant = linearizations[env_id]
    nv, m = model.nv, model.nu
    assert plant.C.shape == (nv, plant.n) and plant.D.shape[1] == m
    # the hand-derived condition (module docstring): kinematic rows, positions measured, D_v of full column rank
    np.testing.assert_array_equal(plant.A[:nv, nv : 2 * nv], np.eye(nv))
    assert np.linalg.matrix_rank(plant.D[nv : 2 * nv]) == m
    start = time.perf_counter()
    z = c.invariant_zeros(plant.A, plant.C, plant.D)
    elapsed = time.perf_counter() - start
    assert z.size == 0, f"{env_id}: spurious zeros {z}"
    assert elapsed < 0.5
    rep = c.strong_observability(plant)
    assert rep.ok, rep.reason
    assert rep.normal_rank == plant.n + m


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_mujoco_linearization_zeros_agree_with_slicot(linearizations, env_id):
    """All positions measured (no zeros), and only the actuated joints' positions measured (square: the zeros are
    the unactuated dofs' zero dynamics, many near 0 for free-floating bases: the absolute tolerance allows for
    those clusters, whose spread grows like the root of the perturbation)."""
    pytest.importorskip("slycot")
    model, plant = linearizations[env_id]
    A, C, D = plant.A, plant.C, plant.D
    assert_same_multiset(c.invariant_zeros(A, C, D), slicot_zeros(A, C, D), atol=1e-5, rtol=1e-6)
    actuated = sorted({int(model.jnt_dofadr[model.actuator_trnid[k, 0]]) for k in range(model.nu)})
    z = c.invariant_zeros(A, C[actuated], D)
    assert_same_multiset(z, slicot_zeros(A, C[actuated], D), atol=1e-5, rtol=1e-6)


@pytest.mark.parametrize("env_id", REJECTED_BEFORE)
def test_cascade_accepts_the_linearizations_it_rejected(linearizations, env_id):
    model, plant = linearizations[env_id]
    obs = c.CascadedHOSMObserver(plant, model.opt.timestep, 100.0)
    assert obs.report.ok and obs.report.invariant_zeros.size == 0
    assert obs.molinari.n_derivatives == 1  # x = [C; CA]^-1 [y; y']: positions and their first derivatives
