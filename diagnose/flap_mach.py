"""Settings the conditions flown never vary apart: the flap angle and the Mach number each condition sets.

Join each flap angle to the Mach numbers it is flown at. Where that splits the conditions into two
groups or more that share neither a flap angle nor a Mach number (a matrix that flies flap 30 at Mach 0.2
only and flap 0 at Mach 0.3 to 0.5), the flap angle is a function of Mach over the data:
an effect of the flap angle fits as one of Mach, and an effect of Mach that is one level over each
group's Mach numbers fits as the flap's. The diagnosis names one of them by what the other lacks, and
the data cannot say which: on such a matrix, effects in Mach 3.6 to 28 times their floor were named
"CL vs flap_deg" or "Cm vs flap_deg" in four simulated cases.
Within one group no effect of either is a function of the other, unless it is one level over the group.
"""

from __future__ import annotations

import numpy as np

#: Flap angles [deg] and Mach numbers [-] are compared at these steps: an imported log's flap angle is the
#: mean of its measured channel (0.04 deg in one log, 0.06 in the next), its Mach number snapped to 0.01.
FLAP_STEP_DEG = 1.0
MACH_STEP = 0.01


def _key(mach: float, flap: float) -> tuple[float, float]:
    return (
        round(round(float(mach) / MACH_STEP) * MACH_STEP, 6),
        round(round(float(flap) / FLAP_STEP_DEG) * FLAP_STEP_DEG, 6),
    )


def groups(conditions) -> list[tuple[list[float], list[float]]]:
    """The conditions' flap angles and Mach numbers in groups that share neither: each a (flap angles [deg],
    Mach numbers [-]) pair, sorted by their lowest Mach number.

    Parameters
    ----------
    conditions : iterable of (alt_ft, mach, flap_deg)
        Conditions [ft, -, deg].
    """
    pairs = {_key(m, f) for _, m, f in conditions}
    out: list[tuple[set, set]] = []
    for mach, flap in pairs:
        joined = [g for g in out if flap in g[0] or mach in g[1]]
        merged = ({flap}.union(*(g[0] for g in joined)), {mach}.union(*(g[1] for g in joined)))
        out = [g for g in out if g not in joined] + [merged]
    return sorted(((sorted(f), sorted(m)) for f, m in out), key=lambda g: g[1][0])


def flown_together(conditions) -> dict | None:
    """The flap angles and Mach numbers in :func:`groups`, if there are two groups or more; else None.

    Parameters
    ----------
    conditions : iterable of (alt_ft, mach, flap_deg)
        The conditions of the logs [ft, -, deg].

    Returns
    -------
    dict or None
        ``variables`` (flap_deg, mach), ``groups`` (each ``{"flap_deg": [...], "mach": [...]}`` [deg, -])
        and ``text``, one sentence for the report.
    """
    found = groups(conditions)
    if len(found) < 2:
        return None
    listed = "; ".join(
        f"flap {', '.join(f'{f:g}' for f in fs)} deg only at Mach {', '.join(f'{m:g}' for m in ms)}" for fs, ms in found
    )
    text = (
        f"flap and Mach flown together ({listed}): over these data an effect of the flap angle fits as one "
        f"of Mach, and an effect of Mach that is one level over each of these sets of Mach numbers as the "
        f"flap's; a flap angle flown at a Mach number of another set tells them apart"
    )
    return {
        "variables": ["flap_deg", "mach"],
        "groups": [{"flap_deg": fs, "mach": ms} for fs, ms in found],
        "text": text,
    }


def level_share(contribution: np.ndarray, log: np.ndarray, conditions: list, together: dict) -> float:
    """The share [-] of a cause's contribution (its variance over the samples) that one level per group of
    :func:`flown_together` makes: the part an effect of the other setting would make alike.

    Parameters
    ----------
    contribution : ndarray
        The cause's contribution at each sample [-].
    log : ndarray of int
        Each sample's log, an index into ``conditions``.
    conditions : list of (alt_ft, mach, flap_deg)
        Each log's condition [ft, -, deg].
    together : dict
        :func:`flown_together`'s answer for them.
    """
    which = {}
    for i, (_, m, f) in enumerate(conditions):
        mach, flap = _key(m, f)
        which[i] = next(j for j, g in enumerate(together["groups"]) if flap in g["flap_deg"] and mach in g["mach"])
    g = np.array([which[int(i)] for i in log])
    y = np.asarray(contribution, float) - float(np.mean(contribution))
    ss = float(y @ y)
    if ss <= 0.0:
        return 0.0
    means = np.zeros(len(together["groups"]))
    np.add.at(means, g, y)
    means /= np.maximum(np.bincount(g, minlength=len(means)), 1)
    return float(means[g] @ means[g]) / ss
