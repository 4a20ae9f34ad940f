"""Composable input signals evaluated by integer step index."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class Signal:
    """Base class: a scalar input as a function of the step index ``k``.

    Subclasses implement :meth:`value`. Signals add with ``+`` and scale with
    ``*`` by a float, so a manoeuvre is built from a few small pieces.
    """

    def value(self, k: int) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def __call__(self, k: int) -> float:
        return self.value(k)

    def series(self, start: int, stop: int) -> np.ndarray:
        """The values at steps ``start <= k < stop``, equal to :meth:`value`'s bit for bit.

        Subclasses vectorise it; this fallback calls :meth:`value` step by step.
        """
        return np.array([self.value(k) for k in range(start, stop)], dtype=float)

    def __add__(self, other: "Signal") -> "Signal":
        return Sum((self, other))

    def __mul__(self, gain: float) -> "Signal":
        return Scaled(self, float(gain))

    __rmul__ = __mul__


@dataclass(frozen=True)
class Constant(Signal):
    """A constant level."""

    level: float = 0.0

    def value(self, k: int) -> float:
        return self.level

    def series(self, start: int, stop: int) -> np.ndarray:
        return np.full(max(stop - start, 0), self.level, dtype=float)


@dataclass(frozen=True)
class Step(Signal):
    """``amplitude`` for ``start <= k < stop`` [steps], zero elsewhere.

    ``stop=None`` holds the step for ever.
    """

    start: int
    amplitude: float
    stop: int | None = None

    def value(self, k: int) -> float:
        if k < self.start or (self.stop is not None and k >= self.stop):
            return 0.0
        return self.amplitude

    def series(self, start: int, stop: int) -> np.ndarray:
        k = np.arange(start, stop)
        on = (k >= self.start) & ((k < self.stop) if self.stop is not None else True)
        return np.where(on, float(self.amplitude), 0.0)


@dataclass(frozen=True)
class Sum(Signal):
    """The sum of several signals."""

    terms: tuple[Signal, ...]

    def value(self, k: int) -> float:
        return sum(t.value(k) for t in self.terms)

    def series(self, start: int, stop: int) -> np.ndarray:
        out = np.zeros(max(stop - start, 0))
        for t in self.terms:  # in order, as sum() adds
            out = out + t.series(start, stop)
        return out


@dataclass(frozen=True)
class Scaled(Signal):
    """A signal times a constant gain."""

    signal: Signal
    gain: float

    def value(self, k: int) -> float:
        return self.gain * self.signal.value(k)

    def series(self, start: int, stop: int) -> np.ndarray:
        return self.gain * self.signal.series(start, stop)


@dataclass(frozen=True)
class Sampled(Signal):
    """A recorded signal: ``values[k]``, held at its last value after the end."""

    values: tuple[float, ...]

    def value(self, k: int) -> float:
        return self.values[min(k, len(self.values) - 1)]

    def series(self, start: int, stop: int) -> np.ndarray:
        v = np.asarray(self.values, dtype=float)
        return v[np.minimum(np.arange(start, stop), len(v) - 1)]


def multistep(start: int, durations: tuple[int, ...], levels: tuple[float, ...]) -> Signal:
    """Consecutive pulses: ``levels[i]`` held for ``durations[i]`` steps.

    Parameters
    ----------
    start : int
        Step index of the first pulse [steps].
    durations : tuple of int
        Length of each pulse [steps].
    levels : tuple of float
        Level of each pulse [signal units].
    """
    if len(durations) != len(levels):
        raise ValueError("durations and levels differ in length")
    pulses = []
    k = start
    for n, level in zip(durations, levels):
        pulses.append(Step(k, level, k + n))
        k += n
    return Sum(tuple(pulses))
