"""What an instrument error that rivals an aerodynamic cause does to its verdict.

The rivals are fitted in :mod:`diagnose.separation` (:func:`~diagnose.separation.cause_rivals`); here
the sensor rivals among them are read: an error the data compatibility could not measure that fits
better leaves the cause unconfirmed, and one it measured, within reach, rejects it, unless the cause
is a strong discrepancy that the error does not settle. The thresholds (``settled_se``, ``preferred_se``,
``strong_f``, ``strong_gain``) are :class:`diagnose.config.DiagnosisSettings`', read from
:func:`diagnose.config.current`.
"""

from __future__ import annotations

from diagnose.config import current


def _strong(cause) -> bool:
    """A discrepancy no gate may dismiss outright: F of ``strong_f`` or more and a
    pooled held-out gain of ``strong_gain`` or more. A measured instrument error
    that fits better by less than ``settled_se`` leaves it unconfirmed, not
    rejected (the calibration is ``strong_f``'s)."""
    s = current()
    return cause.evidence.get("F", 0.0) >= s.strong_f and cause.verdict.get("holdout_gain", 0.0) >= s.strong_gain


def instrument_verdict(cause) -> None:
    """The instrument-error rules on a cause's verdict, in place, after its rivals are fitted. An error
    the data compatibility could not measure that fits better leaves it unconfirmed
    (:func:`instrument_preferred`); one it measured, within reach, rejects it
    (:func:`instrument_fits_better`), unless the discrepancy is :func:`_strong` and
    that error does not fit better by ``settled_se``: then it is unconfirmed."""
    s, c = current(), cause
    preferred = instrument_preferred(c)
    if preferred and c.verdict["accepted"]:
        c.verdict.update(accepted=False, unconfirmed=True, reason=preferred)
    within = instrument_fits_better(c)
    if within and (c.verdict["accepted"] or c.verdict.get("unconfirmed")):
        open_ = _strong(c) and not instrument_settles(c)
        c.verdict.update(
            accepted=False,
            unconfirmed=open_,
            reason=within
            + (
                f"; not by the {s.settled_se:g} standard errors that settle it, and the discrepancy itself is strong "
                f"(F = {c.evidence['F']:.4g}, held-out gain x{c.verdict['holdout_gain']:.2f})"
                if open_
                else ""
            ),
        )


def _sensor_rivals(cause, measured: bool) -> tuple[dict, list[dict]]:
    """The cause's instrument-error alternatives the data compatibility measured (``measured``) or could
    not, by (channel, error), and its sensor rivals among them."""
    alts = {
        (a["channel"], a["error"]): a
        for a in cause.evidence.get("sensor_alternatives", [])
        if bool(a.get("unmeasured")) != measured
    }
    return alts, [
        r for r in cause.evidence.get("rivals", []) if r["kind"] == "sensor" and (r["channel"], r["error"]) in alts
    ]


def _settled(r: dict, coefficient: str) -> bool:
    """A sensor rival better by ``settled_se`` overall that the cause's own
    coefficient does not favour the other way by as much."""
    s = current()
    return r["separation_se"] <= -s.settled_se and r["by_coefficient"].get(coefficient, 0.0) < s.settled_se**2


def _better_sensor(cause, measured: bool) -> str:
    """Why a cause is not named (``""`` if nothing says so): the sensor rival that fits the residuals
    best, by ``settled_se`` or more, among the errors the data compatibility
    measured (``measured``) or could not measure. For a measured error, the cause's own coefficient
    must not settle it the other way (:func:`_settled`): the error's signature in the other
    coefficients may fit what no cause there was named for (a thrust scale's remainder in CD made an
    alpha scale 190 standard errors better than a Cm bump in alpha that was there, and that fitted Cm
    46 standard errors better). A measured error that fits better in the cause's own coefficient too
    needs only ``preferred_se``, there and overall."""
    s = current()
    alts, rivals = _sensor_rivals(cause, measured)

    def wins(r: dict) -> bool:
        if not measured:
            return r["separation_se"] <= -s.settled_se
        own = r["by_coefficient"].get(cause.coefficient, 0.0)
        return _settled(r, cause.coefficient) or (r["separation_se"] <= -s.preferred_se and own <= -(s.preferred_se**2))

    better = [r for r in rivals if wins(r)]
    if not better:
        return ""
    r = min(better, key=lambda r: r["separation_se"])
    a = alts[(r["channel"], r["error"])]
    error = f"{r['channel']} {r['error']} {a['needs']:+.3g}"
    if measured:
        return (
            f"an instrument error within the data compatibility's reach fits the residuals better: {error} "
            f"({abs(a['needs_se']):.1f} standard errors; {-r['separation_se']:.1f} standard errors better, "
            f"fitted to CL, CD, Cm and the data compatibility together)"
        )
    return (
        f"an instrument error the data compatibility could not measure fits the residuals better: {error} "
        f"({-r['separation_se']:.1f} standard errors better, fitted to CL, CD and Cm together); "
        f"`campaign plan` designs the flight that measures it"
    )


def instrument_fits_better(cause) -> str:
    """Why a cause is not named: an instrument error the data compatibility measured, at a size within
    its reach (``sensor_alternatives``), fits the residuals of CL, CD and Cm and the compatibility's own
    measurement better, by ``settled_se`` or more, or by ``preferred_se`` there and in the cause's
    own coefficient (``""`` if none does). The aerodynamic cause then explains nothing the instruments do
    not: an A320 null with a 7.2 % alpha-vane scale, corrected as 5.7 %, left a "CD vs elevator" that the
    scale's remainder fitted 8.6 standard errors better; a stock-737 null with a -0.27 deg vane bias,
    corrected 2.6 standard errors off, a "CD vs alpha" that the bias fitted 3.6 better (13 in CD)."""
    return _better_sensor(cause, measured=True)


def instrument_settles(cause) -> bool:
    """Whether a measured instrument error within reach fits better by ``settled_se``
    (:func:`_settled`), not only by ``preferred_se``."""
    return any(_settled(r, cause.coefficient) for r in _sensor_rivals(cause, measured=True)[1])


def instrument_preferred(cause) -> str:
    """Why a cause is not named: an instrument error the data compatibility could not measure fits
    the residuals better, by ``settled_se`` or more (``""`` if none does). The residuals alone
    point to it, and only a measurement of it (`campaign plan`) can confirm either."""
    return _better_sensor(cause, measured=False)
