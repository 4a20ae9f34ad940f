"""Orthogonal phase-optimized multisines (Morelli, "Multiple input design for real-time
parameter estimation in the frequency domain", IFAC SYSID 2003).

Each input is a sum of harmonics of ``1 / T`` in a band; the inputs share the band's harmonics by
interleaving, so they are mutually orthogonal over ``T``. Phases start from Schroeder's, are
then optimized for a low relative peak factor (the clipping iteration of Van der Ouderaa et
al., "Peak factor minimization using a time-frequency domain swapping algorithm", IEEE Trans.
Instrum. Meas. 1988), and finally every phase moves by one time shift per input so that the
input starts, and so ends, at zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from maneuvers.signals import Signal


def relative_peak_factor(u: np.ndarray) -> float:
    """``(max - min) / (2 sqrt(2) rms)``: 1 for a single sinusoid [-]."""
    rms = float(np.sqrt(np.mean(u**2)))
    return float(np.ptp(u)) / (2.0 * np.sqrt(2.0) * rms) if rms > 0 else float("inf")


def share_harmonics(k_lo: int, k_hi: int, inputs: int) -> list[tuple[int, ...]]:
    """Harmonic indices ``k_lo..k_hi`` dealt out to ``inputs`` inputs in turn (interleaved)."""
    ks = np.arange(k_lo, k_hi + 1)
    return [tuple(int(k) for k in ks[j::inputs]) for j in range(inputs)]


def schroeder_phases(n: int) -> np.ndarray:
    """Schroeder's phases for ``n`` equal-power harmonics [rad]."""
    k = np.arange(1, n + 1)
    return -np.pi * k * (k - 1) / n


def _synth(ks: np.ndarray, amps: np.ndarray, phases: np.ndarray, t_over_T: np.ndarray) -> np.ndarray:
    """``sum_k amps_k sin(2 pi k t/T + phases_k)``, harmonic by harmonic: each sample's value does
    not depend on which others are computed with it."""
    out = np.zeros(len(t_over_T))
    for k, a, p in zip(ks, amps, phases):
        out = out + a * np.sin(2 * np.pi * k * t_over_T + p)
    return out


@lru_cache(maxsize=64)
def optimized_phases(ks: tuple[int, ...], starts: int = 12) -> tuple[tuple[float, ...], float]:
    """Phases of equal-amplitude harmonics ``ks`` of ``1/T`` with a low relative peak factor, shifted
    so that the signal starts (and ends) at zero; and that peak factor.

    From Schroeder's phases and from ``starts - 1`` seeded random ones, each first improved by the
    clipping iteration (clip the signal, keep the phases of the clipped signal's harmonics), then
    polished by L-BFGS on the signal's 64-norm (a smooth stand-in for its peak); the best by the
    exact peak factor, before or after the polish, wins.
    """
    from scipy.optimize import minimize

    k = np.asarray(ks, dtype=float)
    amps = np.ones(len(k))
    samples = max(512, 32 * int(k.max()))
    t = np.arange(samples) / samples
    arg0 = 2 * np.pi * np.outer(t, k)
    basis = np.exp(-1j * arg0)
    p = 64.0

    def norm(phases: np.ndarray) -> tuple[float, np.ndarray]:
        arg = arg0 + phases
        u = np.sin(arg) @ amps
        scale = np.max(np.abs(u))
        w = np.abs(u / scale) ** (p - 1) * np.sign(u)
        m = float(np.mean(np.abs(u / scale) ** p))
        f = scale * m ** (1 / p)
        return f, f / (scale * m) * (w @ (np.cos(arg) * amps)) / len(t)

    rng = np.random.default_rng(len(k))
    best, best_rpf = None, np.inf
    for s in range(starts):
        phases = schroeder_phases(len(k)) if s == 0 else rng.uniform(-np.pi, np.pi, len(k))
        for level in np.linspace(0.85, 0.97, 30):
            u = _synth(k, amps, phases, t)
            c = np.clip(u, -level * np.max(np.abs(u)), level * np.max(np.abs(u)))
            phases = np.angle(c @ basis) + np.pi / 2  # sin(x + p) = Re(-i exp(i(x + p)))
        for cand in (phases, minimize(norm, phases, jac=True, method="L-BFGS-B").x):
            rpf = relative_peak_factor(_synth(k, amps, cand, t))
            if rpf < best_rpf:
                best, best_rpf = cand, rpf
    phases = _zero_start(k, amps, best, t)
    return tuple(float(p) for p in phases), relative_peak_factor(_synth(k, amps, phases, np.arange(4096) / 4096))


def _zero_start(k: np.ndarray, amps: np.ndarray, phases: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The phases shifted in time to the zero crossing of the signal nearest its start."""
    u = _synth(k, amps, phases, t)
    cross = np.flatnonzero(np.sign(u[:-1]) != np.sign(u[1:]))
    if not cross.size:
        return phases
    i = int(cross[0])
    tau = t[i] + (t[i + 1] - t[i]) * u[i] / (u[i] - u[i + 1])  # linear between the samples
    for _ in range(3):  # Newton on the exact sum
        val = float(np.sin(2 * np.pi * k * tau + phases) @ amps)
        der = float((2 * np.pi * k * np.cos(2 * np.pi * k * tau + phases)) @ amps)
        tau -= val / der
    return phases + 2 * np.pi * k * tau


@dataclass(frozen=True)
class MultisineSignal(Signal):
    """``peak * sum_k sin(2 pi k (k_step - start) dt / T + phase_k) / norm`` over ``start <= k_step <
    start + n``, zero elsewhere.

    Parameters
    ----------
    start, n : int
        First step and length [steps].
    dt_s : float
        Time step [s].
    harmonics : tuple of int
        Harmonic indices of ``1 / T``, ``T = n dt_s``.
    phases : tuple of float
        [rad]
    peak : float
        The signal's largest absolute value [signal units].
    norm : float
        The unit sum's largest absolute value over the steps.
    """

    start: int
    n: int
    dt_s: float
    harmonics: tuple[int, ...]
    phases: tuple[float, ...]
    peak: float
    norm: float

    def series(self, start: int, stop: int) -> np.ndarray:
        k = np.arange(start, stop)
        on = (k >= self.start) & (k < self.start + self.n)
        t = (k[on] - self.start) / self.n
        out = np.zeros(len(k))
        out[on] = (
            self.peak
            * _synth(np.asarray(self.harmonics, float), np.ones(len(self.harmonics)), np.asarray(self.phases), t)
            / self.norm
        )
        return out

    def value(self, k: int) -> float:
        return float(self.series(k, k + 1)[0])


def multisine_signals(
    n: int, dt_s: float, f_lo_hz: float, f_hi_hz: float, peaks: tuple[float, ...], start: int = 0
) -> tuple[list[MultisineSignal], list[float]]:
    """One orthogonal multisine per entry of ``peaks`` over ``n`` steps from ``start``, with the
    harmonics of ``1 / (n dt_s)`` in ``[f_lo_hz, f_hi_hz]`` interleaved between them; and their
    relative peak factors."""
    T = n * dt_s
    k_lo, k_hi = max(1, int(np.ceil(f_lo_hz * T - 1e-9))), int(np.floor(f_hi_hz * T + 1e-9))
    if k_hi - k_lo + 1 < 2 * len(peaks):
        raise ValueError(
            f"the band {f_lo_hz:g}-{f_hi_hz:g} Hz holds {max(k_hi - k_lo + 1, 0)} harmonics of "
            f"1/{T:g} s: fewer than 2 per input; widen it or lengthen duration_s"
        )
    out, rpfs = [], []
    t = np.arange(n) / n
    for ks, peak in zip(share_harmonics(k_lo, k_hi, len(peaks)), peaks):
        phases, _ = optimized_phases(ks)
        u = _synth(np.asarray(ks, float), np.ones(len(ks)), np.asarray(phases), t)
        out.append(MultisineSignal(start, n, dt_s, ks, phases, float(peak), float(np.max(np.abs(u)))))
        rpfs.append(relative_peak_factor(u))
    return out, rpfs
