"""Low-power peaking-free observer (Astolfi et al. 2018) against the standard high-gain observer (2).

Two measurements, printed as tables (``python scripts/compare_low_power.py``):

1. Peaking: the transient peak of every estimate after a reset at zero error in the value and an error of order
   one in the derivatives, for ``ell`` in {10, 100, 1000}, with the power law ``peak ~ ell^p`` fitted per estimate.
   The standard observer's ``xhat_i`` peaks like ``ell^(i-1)``; the peaking-free one's stay bounded.
2. Noise: steady-state RMS errors of every estimate under high-frequency measurement noise, at *equal convergence
   rate* (same ``ell``: with the default coefficients both observers have every error eigenvalue at ``-ell``).
"""

from __future__ import annotations

import argparse

import numpy as np

from smo_gym.observers import HighGain, LowPowerHighGain

ELLS = (10.0, 100.0, 1000.0)


def derivatives(t: np.ndarray, n: int) -> np.ndarray:
    """``(f, f', ..., f^(n-1))`` of ``f(t) = sin(t + 1)``, shape ``t.shape + (n,)``."""
    return np.stack([np.sin(t + 1.0 + k * np.pi / 2) for k in range(n)], axis=-1)


def transient_peaks(observer_cls, ell: float, order: int, **kwargs) -> np.ndarray:
    """``max_t |xhat_i(t)|`` over ``[0, 20/ell]`` (step ``1e-3/ell``) from a zero initial state; shape (order + 1,)."""
    h = 1e-3 / ell
    t = np.arange(0.0, 20.0 / ell, h)
    y = derivatives(t, 1)[:, 0]
    obs = observer_cls(dt=h, gain=ell, order=order, **kwargs)
    first = obs.reset(np.zeros(1))
    z = np.concatenate([first[None], obs.run(y[1:, None])])[:, 0]
    return np.abs(z).max(axis=0)


def peaking_exponents(order: int, bound: float = 1.5) -> dict[str, np.ndarray]:
    """Peaks for ``ELLS`` and the fitted exponents ``p_i`` of ``peak_i ~ ell^p_i`` (least squares in log-log)."""
    out = {}
    for name, cls, kw in (("high-gain", HighGain, {}), ("low-power-high-gain", LowPowerHighGain, {"bounds": bound})):
        peaks = np.array([transient_peaks(cls, ell, order, **kw) for ell in ELLS])
        slope = np.polyfit(np.log(ELLS), np.log(peaks), 1)[0]
        out[name] = {"peaks": peaks, "exponents": slope}
    return out


def noise_errors(
    order: int, ell: float = 50.0, noise: str = "white", amplitude: float = 1e-3, h: float = 1e-4, seed: int = 0
) -> dict[str, np.ndarray]:
    """Steady-state RMS error of every estimate on [1, 2] s with measurement noise, at equal convergence rate.

    Returns, per observer, ``{"total": RMS of xhat - x, "noise": RMS of xhat(noisy y) - xhat(clean y)}`` (the
    second is the part due to the noise alone; the first adds the lag error of order ``|f^(n)| / ell``).
    ``noise``: ``"white"`` (Gaussian, std ``amplitude``, one sample per step) or ``"sine"`` (``amplitude *
    sin(20 ell t)``).
    """
    t = np.arange(0.0, 2.0, h)
    x = derivatives(t, order + 1)
    if noise == "white":
        v = amplitude * np.random.default_rng(seed).standard_normal(t.size)
    else:
        v = amplitude * np.sin(20.0 * ell * t)
    y = x[:, 0] + v
    out = {}
    ss = t >= 1.0
    for name, make in (
        ("high-gain", lambda: HighGain(dt=h, gain=ell, order=order)),
        ("low-power-high-gain", lambda: LowPowerHighGain(dt=h, gain=ell, order=order, bounds=2.0)),
    ):
        z = {}
        for key, signal in (("noisy", y), ("clean", x[:, 0])):
            obs = make()
            first = obs.reset(signal[:1])
            z[key] = np.concatenate([first[None], obs.run(signal[1:, None])])[:, 0]
        out[name] = {
            "total": np.sqrt(np.mean((z["noisy"][ss] - x[ss]) ** 2, axis=0)),
            "noise": np.sqrt(np.mean((z["noisy"][ss] - z["clean"][ss]) ** 2, axis=0)),
        }
    return out


def main() -> None:
    np.set_printoptions(precision=3, suppress=False)
    print("Transient peaks max|xhat_i| (f = sin(t + 1), zero initial state), ell =", ELLS)
    for order in (2, 3):
        res = peaking_exponents(order)
        for name, r in res.items():
            print(f"  n = {order + 1} {name:>20}: exponents p_i = {np.round(r['exponents'], 2)}")
            for ell, p in zip(ELLS, r["peaks"], strict=False):
                print(f"  {'':>27} ell = {ell:6.0f}: peaks = {p}")
    print("Steady-state RMS error of xhat_1..xhat_n under noise 1e-3 (ell = 50, both with all poles at -ell):")
    print("total error, and in brackets the part due to the noise alone")
    for order in (1, 2, 3):
        for noise in ("white", "sine"):
            res = noise_errors(order, noise=noise)
            print(
                f"  n = {order + 1}, {noise:>5} noise: "
                + "; ".join(f"{k}: {v['total']} [{v['noise']}]" for k, v in res.items())
            )


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()  # no options; --help says what runs
    main()
