"""``scripts/bench_accuracy.py``: the hindsight oracles its summary compares ``auto`` with."""

import numpy as np
from conftest import load_script


def test_joint_oracles_choose_and_blend_per_joint():
    """Joint 0: the first observer is best, the second no help (a multiple of the same error: the best blend is
    the first alone). Joint 1: two observers with opposite halves of the same error; either alone has RMSE 1, their
    equal blend cancels it. The third observer is never among the two best. Checked against the closed forms."""
    oracles = load_script("bench_accuracy").joint_oracles
    rng = np.random.default_rng(3)
    e = rng.standard_normal(4000)
    e /= np.sqrt(np.mean(e**2))
    a = np.stack([0.5 * e, e], axis=1)
    b = np.stack([1.0 * e, -e], axis=1)
    c = np.stack([3.0 * e, 3.0 * e], axis=1)
    per_joint, blend = oracles([c, a, b])
    assert abs(per_joint - np.sqrt((0.5**2 + 1.0) / 2)) < 1e-12
    assert abs(blend - np.sqrt(0.5**2 / 2)) < 1e-12
    # correlated but not identical errors: the blend is the least-squares weight, never worse than the best alone
    f = 0.8 * e + 0.6 * rng.standard_normal(4000)
    per_joint, blend = oracles([e[:, None], f[:, None]])
    w = np.clip(np.dot(f, f - e) / np.dot(f - e, f - e), 0, 1)
    assert abs(blend - np.sqrt(np.mean((w * e + (1 - w) * f) ** 2))) < 1e-12
    assert blend <= per_joint == min(np.sqrt(np.mean(e**2)), np.sqrt(np.mean(f**2)))
    assert blend < per_joint - 0.05  # half-correlated errors: blending gains
