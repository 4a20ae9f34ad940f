"""Settings the conditions flown never vary apart: the flap angle and the Mach number each condition sets.

Where every Mach number is flown at one flap angle only (our 737 at flap 30 only at Mach 0.2, flap 0 at
Mach 0.3 to 0.5), the flap angle is a function of Mach over the data: an effect of the flap angle fits as
a step in Mach between the flap angles' Mach numbers, and an effect of Mach below the clean Mach numbers
as the flap's. The diagnosis then names one of them by what the other lacks, and the data cannot say
which (a lift saturating in Mach, 4 to 28 times its floor, was named "CL vs flap_deg" or "Cm vs flap_deg"
on four seeds of the detection curve before its matrix flew flap 30 at Mach 0.3 too). Only a flight of
one flap angle at another's Mach number tells them apart.
"""
from __future__ import annotations


def _mach(m: float) -> str:
    return f"{m:.3g}"


def flown_together(conditions) -> dict | None:
    """The flap angles and the Mach numbers they are flown at, if each Mach number is flown at one flap
    angle only and more than one flap angle is flown; else None.

    Parameters
    ----------
    conditions : iterable of (alt_ft, mach, flap_deg)
        The conditions of the logs [ft, -, deg].

    Returns
    -------
    dict or None
        ``variables`` (flap_deg, mach), ``mach_by_flap`` (each flap angle [deg] with its Mach numbers [-],
        as ``{"flap_deg", "mach"}``) and ``text``, one sentence for the report.
    """
    by_flap: dict[float, set[float]] = {}
    for _, mach, flap in conditions:
        by_flap.setdefault(round(float(flap), 1), set()).add(round(float(mach), 3))
    if len(by_flap) < 2:
        return None
    every = [m for ms in by_flap.values() for m in ms]
    if len(every) != len(set(every)):
        return None  # a Mach number flown at two flap angles: the flap's effect and Mach's differ there
    order = sorted(by_flap, key=lambda f: min(by_flap[f]))
    listed = "; ".join(f"flap {f:g} deg at Mach {', '.join(_mach(m) for m in sorted(by_flap[f]))} only" for f in order)
    text = (f"flap and Mach flown together ({listed}): over these data an effect of the flap angle fits as one "
            f"of Mach, and one of Mach between the flap angles' Mach numbers as the flap's; a flap angle flown "
            f"at a Mach number another is flown at tells them apart")
    return {"variables": ["flap_deg", "mach"], "mach_by_flap": [{"flap_deg": f, "mach": sorted(by_flap[f])} for f in order], "text": text}
