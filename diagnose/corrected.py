"""The measured logs as the data compatibility corrects them: the one place a correction is applied.

Every later stage of the diagnosis asks :class:`Corrected` for the logs or their residual
data under a correction (a :class:`identify.compat.CompatResult`, or None for the raw logs)
and receives corrected data. The arbitration between instrument errors and aerodynamic causes
asks for the same corrections many times (a trial, the correction undone, the delays timed);
each residual frame is computed once per correction and reused.
"""

from __future__ import annotations

from collections.abc import Callable

import pandas as pd

from diagnose.residuals import COEFFS, residual_data
from identify.compat import CompatResult
from identify.logs import Log


class Corrected:
    """The fitted and held-out logs, raw, and what a correction makes of them.

    Parameters
    ----------
    train, held : list of Log
        The logs fitted on and the logs held out, as measured.
    evaluator : ModelEvaluator
        The model under test (its ``jobs`` spread the residuals over worker processes).
    step : int or None
        Thinning of the residual data (:func:`diagnose.residuals.kept`).
    """

    def __init__(self, train: list[Log], held: list[Log], evaluator, step: int | None = None) -> None:
        self.train, self.held = list(train), list(held)
        self.evaluator, self.step = evaluator, step
        self._memo: dict[tuple, dict[tuple, pd.DataFrame]] = {}
        self._once: dict[tuple, object] = {}

    def raw(self, held: bool = False) -> list[Log]:
        """The logs as measured."""
        return self.held if held else self.train

    def logs(self, compat: CompatResult | None, held: bool = False) -> list[Log]:
        """The logs corrected by ``compat`` (as measured if None)."""
        raw = self.raw(held)
        return raw if compat is None else [compat.correct(lg) for lg in raw]

    def residuals(
        self, compat: CompatResult | None, held: bool = False, delays: tuple = (), wait: bool = True
    ) -> pd.DataFrame | Callable[[], pd.DataFrame]:
        """:func:`diagnose.residuals.residual_data` of the logs corrected by ``compat``, each
        correction computed once (the workers correct the logs they evaluate). A frame with
        the delay signatures of ``delays`` (channels) serves a request without them. With
        ``wait=False`` a callable that returns the frame comes back, the workers computing
        it meanwhile."""
        raw = self.raw(held)
        correct = None if compat is None else compat.correct
        key = (None if compat is None else compat.correction_key(), held)
        done = self._memo.setdefault(key, {})
        for have in list(done):
            if set(delays) <= set(have):
                extra = [f"{ch.split('_')[0]}delay_{c}" for ch in set(have) - set(delays) for c in COEFFS]

                def kept(have: tuple = have, extra: list = extra) -> pd.DataFrame:
                    return _frame(done, have).drop(columns=extra)

                return kept() if wait else kept
        # kept while the workers compute it: a later request of the same correction waits for the same frame
        done[tuple(delays)] = residual_data(raw, self.evaluator, self.step, delays, wait=False, correct=correct)

        def finished() -> pd.DataFrame:
            return _frame(done, tuple(delays)).copy()

        return finished() if wait else finished

    def ahead(self, compat: CompatResult | None, held: bool = False, delays: tuple = ()) -> None:
        """Start the workers on :meth:`residuals` of a correction that will be asked for, and go on."""
        self.residuals(compat, held, delays, wait=False)

    def once(self, key: tuple, compute: Callable[[], object]) -> object:
        """``compute()``, computed once per ``key`` (hashable, naming the correction it depends on)
        while the diagnosis lasts: what several trials ask of the same corrected data."""
        if key not in self._once:
            self._once[key] = compute()
        return self._once[key]

    def keep(self, compat: CompatResult | None) -> None:
        """Drop the residual frames of the trials not made: every correction but ``compat`` and ``compat``
        with one of its corrections undone (what :func:`diagnose.arbitration.compat_causes` asks for)."""
        kept = {None if compat is None else compat.correction_key()}
        kept |= {compat.without(p.name).correction_key() for p in compat.applied} if compat is not None else set()
        for k in [k for k in self._memo if k[0] not in kept]:
            del self._memo[k]

    def forget(self) -> None:
        """Drop the residual frames and results kept (the diagnosis is over)."""
        self._memo.clear()
        self._once.clear()


def _frame(done: dict, have: tuple) -> pd.DataFrame:
    """The frame ``done[have]``, waited for if the workers are still computing it (a callable)."""
    if not isinstance(done[have], pd.DataFrame):
        done[have] = done[have]()
    return done[have]
