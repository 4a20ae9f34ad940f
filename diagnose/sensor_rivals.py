"""What an instrument error that rivals an aerodynamic cause does to its verdict.

The rivals are fitted in :mod:`diagnose.separation` (:func:`~diagnose.separation.cause_rivals`); here
the sensor rivals among them are read: an error the data compatibility could not measure that fits
better leaves the cause unconfirmed, and one it measured, within reach, rejects it, unless the cause
is a strong discrepancy that the error does not settle.
"""
from __future__ import annotations

from diagnose.separation import SETTLED_SE
from diagnose.verdict import STRONG_F, STRONG_GAIN

#: A measured instrument error within reach that fits better than the cause by this many standard errors,
#: both in the cause's own coefficient and overall, rejects it. On the detection curve's case records
#: (about 2,600 simulated campaigns), no cause of a hidden effect had its own coefficient favour such an
#: error by even 1.5 standard errors; three nulls with a vane bias corrected 1-2.6 standard errors off
#: were named for "CD vs alpha" or "CD vs CL" that the bias's remainder fitted 2.5-3.6 better (13 in CD).
PREFERRED_SE = 2.0


def _strong(cause) -> bool:
    """A discrepancy no gate may dismiss outright: F of :data:`~diagnose.verdict.STRONG_F` or more and a
    pooled held-out gain of :data:`~diagnose.verdict.STRONG_GAIN` or more. A measured instrument error
    that fits better by less than :data:`~diagnose.separation.SETTLED_SE` leaves it unconfirmed, not
    rejected: a stock-737 drag table in alpha, 1.3 times its floor (F = 1,337, x1.66), was rejected for a
    -0.08 deg vane bias 2.1 standard errors from the data compatibility's measurement, which fitted
    2.9 standard errors better (fresh seed 9,401,808). On 390 null flights of the detection curve at the
    codes of stops 69-72 (seeds 9,300,150-9,402,159), no candidate this strong was rejected by any rule."""
    return cause.evidence.get("F", 0.0) >= STRONG_F and cause.verdict.get("holdout_gain", 0.0) >= STRONG_GAIN


def instrument_verdict(cause) -> None:
    """The instrument-error rules on a cause's verdict, in place, after its rivals are fitted. An error
    the data compatibility could not measure that fits better leaves it unconfirmed
    (:func:`instrument_preferred`); one it measured, within reach, rejects it
    (:func:`instrument_fits_better`), unless the discrepancy is :func:`_strong` and
    that error does not fit better by :data:`~diagnose.separation.SETTLED_SE`: then it is unconfirmed."""
    c = cause
    preferred = instrument_preferred(c)
    if preferred and c.verdict["accepted"]:
        c.verdict.update(accepted=False, unconfirmed=True, reason=preferred)
    within = instrument_fits_better(c)
    if within and (c.verdict["accepted"] or c.verdict.get("unconfirmed")):
        open_ = _strong(c) and not instrument_settles(c)
        c.verdict.update(accepted=False, unconfirmed=open_, reason=within + (
            f"; not by the {SETTLED_SE:g} standard errors that settle it, and the discrepancy itself is strong "
            f"(F = {c.evidence['F']:.4g}, held-out gain x{c.verdict['holdout_gain']:.2f})" if open_ else ""))


def _sensor_rivals(cause, measured: bool) -> tuple[dict, list[dict]]:
    """The cause's instrument-error alternatives the data compatibility measured (``measured``) or could
    not, by (channel, error), and its sensor rivals among them."""
    alts = {(a["channel"], a["error"]): a for a in cause.evidence.get("sensor_alternatives", [])
            if bool(a.get("unmeasured")) != measured}
    return alts, [r for r in cause.evidence.get("rivals", []) if r["kind"] == "sensor"
                  and (r["channel"], r["error"]) in alts]


def _settled(r: dict, coefficient: str) -> bool:
    """A sensor rival better by :data:`~diagnose.separation.SETTLED_SE` overall that the cause's own
    coefficient does not favour the other way by as much."""
    return r["separation_se"] <= -SETTLED_SE and r["by_coefficient"].get(coefficient, 0.0) < SETTLED_SE ** 2


def _better_sensor(cause, measured: bool) -> str:
    """Why a cause is not named (``""`` if nothing says so): the sensor rival that fits the residuals
    best, by :data:`~diagnose.separation.SETTLED_SE` or more, among the errors the data compatibility
    measured (``measured``) or could not measure. For a measured error, the cause's own coefficient
    must not settle it the other way (:func:`_settled`): the error's signature in the other
    coefficients may fit what no cause there was named for (a thrust scale's remainder in CD made an
    alpha scale 190 standard errors better than a Cm bump in alpha that was there, and that fitted Cm
    46 standard errors better). A measured error that fits better in the cause's own coefficient too
    needs only :data:`PREFERRED_SE`, there and overall."""
    alts, rivals = _sensor_rivals(cause, measured)

    def wins(r: dict) -> bool:
        if not measured:
            return r["separation_se"] <= -SETTLED_SE
        own = r["by_coefficient"].get(cause.coefficient, 0.0)
        return _settled(r, cause.coefficient) or (r["separation_se"] <= -PREFERRED_SE and own <= -PREFERRED_SE ** 2)

    better = [r for r in rivals if wins(r)]
    if not better:
        return ""
    r = min(better, key=lambda r: r["separation_se"])
    a = alts[(r["channel"], r["error"])]
    error = f"{r['channel']} {r['error']} {a['needs']:+.3g}"
    if measured:
        return (f"an instrument error within the data compatibility's reach fits the residuals better: {error} "
                f"({abs(a['needs_se']):.1f} standard errors; {-r['separation_se']:.1f} standard errors better, "
                f"fitted to CL, CD, Cm and the data compatibility together)")
    return (f"an instrument error the data compatibility could not measure fits the residuals better: {error} "
            f"({-r['separation_se']:.1f} standard errors better, fitted to CL, CD and Cm together); "
            f"`campaign plan` designs the flight that measures it")


def instrument_fits_better(cause) -> str:
    """Why a cause is not named: an instrument error the data compatibility measured, at a size within
    its reach (``sensor_alternatives``), fits the residuals of CL, CD and Cm and the compatibility's own
    measurement better, by :data:`SETTLED_SE` or more, or by :data:`PREFERRED_SE` there and in the cause's
    own coefficient (``""`` if none does). The aerodynamic cause then explains nothing the instruments do
    not: an A320 null with a 7.2 % alpha-vane scale, corrected as 5.7 %, left a "CD vs elevator" that the
    scale's remainder fitted 8.6 standard errors better; a stock-737 null with a -0.27 deg vane bias,
    corrected 2.6 standard errors off, a "CD vs alpha" that the bias fitted 3.6 better (13 in CD)."""
    return _better_sensor(cause, measured=True)


def instrument_settles(cause) -> bool:
    """Whether a measured instrument error within reach fits better by :data:`~diagnose.separation.SETTLED_SE`
    (:func:`_settled`), not only by :data:`PREFERRED_SE`."""
    return any(_settled(r, cause.coefficient) for r in _sensor_rivals(cause, measured=True)[1])


def instrument_preferred(cause) -> str:
    """Why a cause is not named: an instrument error the data compatibility could not measure fits
    the residuals better, by :data:`SETTLED_SE` or more (``""`` if none does). The residuals alone
    point to it, and only a measurement of it (`campaign plan`) can confirm either."""
    return _better_sensor(cause, measured=False)
