"""A whole JSBSim aircraft from an identification (``campaign model``).

The identified eq. (3) point models become the aircraft's lift, drag and pitching moment, each a
JSBSim function of the same regressors about the same reference state, so that at a point's own
condition the aircraft gives ``params x regressors`` of its fit. Between the identified conditions
the point models are blended with weights that are JSBSim tables: linear in Mach between the
conditions of one flap setting, linear in flap between flap settings, equal shares for conditions
flown at the same Mach and flap (other altitudes, repeats); outside the Mach and flap range flown the
nearest condition's model holds. Within a point model the regressors extrapolate as the fit's
polynomial does: no stall, no limit. A gear model from the identification (the nonlinear eq. (9)
one if there is one, else the linear eq. (4) one) adds its gear increments to the gear-up point
models; without one the gear-up and gear-down point models of a condition are blended linearly in
``gear/gear-pos-norm``.

The moments are identified about the CG of the logs (eq. 1): the aircraft's aerodynamic reference
point is that CG, so its PITCH axis is the identified Cm with no transfer. Lateral-directional
terms are nominal (not identified). The thrust is an external force along the body x axis on the
documented thrust line, its magnitude ``external_reactions/thrust/magnitude`` [lbf], which a replay
sets from ``thrust_lbf``; there is no engine and no throttle. The flight controls take the logged
surface positions through the standard properties: ``fcs/elevator-cmd-norm`` moves
``fcs/elevator-pos-rad``, ``fcs/pitch-trim-cmd-norm`` ``fcs/stabilizer-pos-deg``,
``fcs/flap-cmd-norm`` ``fcs/flap-pos-deg`` and ``gear/gear-cmd-norm`` ``gear/gear-pos-norm``.

This module writes XML only; it reads no logs and runs no JSBSim.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from identify.export import gear_effects
from identify.models import COEFFS, REGRESSORS, GearSurface

D2R = math.pi / 180.0
AXIS = {"CL": "LIFT", "CD": "DRAG", "Cm": "PITCH"}
#: The reference-state fields of a point model (identification.json ``reference``).
REFERENCE_FIELDS = ("alpha_deg", "elevator_deg", "stabilizer_deg", "mach")
METHOD_NAMES = {"ee": "equation error", "oe": "output error", "fe": "filter error"}
#: Nominal lateral-directional derivatives [1/rad], not identified: magnitudes typical of a transport
#: aeroplane, enough for it to be stable and damped in roll and yaw and to turn. (axis, name, variables, value)
NOMINAL_LATERAL = (
    ("SIDE", "CYbeta", ("aero/beta-rad",), -0.8),
    ("SIDE", "CYdr", ("fcs/rudder-pos-rad",), 0.15),
    ("ROLL", "Clbeta", ("aero/beta-rad",), -0.1),
    ("ROLL", "Clp", ("aero/bi2vel", "velocities/p-aero-rad_sec"), -0.45),
    ("ROLL", "Clr", ("aero/bi2vel", "velocities/r-aero-rad_sec"), 0.1),
    ("ROLL", "Clda", ("fcs/left-aileron-pos-rad",), 0.1),
    ("YAW", "Cnbeta", ("aero/beta-rad",), 0.12),
    ("YAW", "Cnr", ("aero/bi2vel", "velocities/r-aero-rad_sec"), -0.2),
    ("YAW", "Cndr", ("fcs/rudder-pos-rad",), -0.08),
)
#: Surface ranges of the flight controls at full command [deg]: widened to the logged positions.
ELEVATOR_MAX_DEG, STABILIZER_MAX_DEG, FLAP_MAX_DEG, AILERON_MAX_DEG, RUDDER_MAX_DEG = 30.0, 15.0, 40.0, 20.0, 25.0
#: Where the logs document no span: the span of this aspect ratio [-].
NOMINAL_ASPECT_RATIO = 8.0
#: Where the logs give no roll or yaw inertia (0): these multiples of Iyy [-].
NOMINAL_INERTIA = {"ixx": 0.4, "izz": 1.3}
#: Where no gear transition was logged: the gear's travel time [s], position linear in time.
NOMINAL_GEAR_TRAVEL_S = 10.0
#: Conditions this close are one in the blend: flap [deg], Mach [-].
FLAP_STEP_DEG, MACH_STEP = 0.1, 1e-3


class IdentificationError(ValueError):
    """An identification that cannot make an aircraft; the message names the file and the field."""


@dataclass(frozen=True)
class PointModel:
    """One eq. (3) point model as ``identification.json`` holds it.

    Attributes
    ----------
    point : str
    condition : tuple
        Pressure altitude [ft], Mach [-], flap [deg] of its status point.
    gear_down : bool
    reference : dict
        The reference state of the regressors: ``alpha_deg``, ``elevator_deg``, ``stabilizer_deg`` [deg],
        ``mach`` [-].
    params : dict
        Coefficient -> regressor (``const``, ``dalpha_rad``, ...) -> value; a regressor not excited is absent.
    methods, converged : dict
        Coefficient -> the estimator that made the parameters (``ee``, ``oe``, ``fe``) and whether it converged.
    flown : dict
        Logged channel -> (smallest, largest) over the point's log, for the aircraft's description.
    """

    point: str
    condition: tuple[float, float, float]
    gear_down: bool
    reference: dict[str, float]
    params: dict[str, dict[str, float]]
    methods: dict[str, str]
    converged: dict[str, bool]
    flown: dict[str, tuple[float, float]] = field(default_factory=dict)

    def regressors(self, alpha_deg, qhat_rad, elevator_deg, stabilizer_deg, mach) -> dict[str, np.ndarray]:
        """The eq. (3) regressors about :attr:`reference` [rad, -], as :func:`identify.models.regressors`
        has them, with ``const``."""
        r = self.reference
        da = (np.asarray(alpha_deg, float) - r["alpha_deg"]) * D2R
        return {
            "const": np.ones_like(da),
            "dalpha_rad": da,
            "qhat_rad": np.asarray(qhat_rad, float),
            "delevator_rad": (np.asarray(elevator_deg, float) - r["elevator_deg"]) * D2R,
            "dstabilizer_rad": (np.asarray(stabilizer_deg, float) - r["stabilizer_deg"]) * D2R,
            "dmach": np.asarray(mach, float) - r["mach"],
            "dalpha2_rad2": da**2,
        }

    def fitted(self, coeff: str, regressors: dict[str, np.ndarray]) -> np.ndarray:
        """``params x regressors`` of one coefficient [-]."""
        return sum(v * regressors[k] for k, v in self.params[coeff].items())

    def method_text(self) -> str:
        """How the parameters were estimated, e.g. ``output error (converged)``."""
        parts = sorted(
            {
                f"{METHOD_NAMES.get(self.methods[c], self.methods[c])}{'' if self.converged[c] else ', not converged'}"
                for c in COEFFS
            }
        )
        return "; ".join(parts)


def point_models(doc: dict, where: str) -> list[PointModel]:
    """The point models of a parsed ``identification.json`` (``where`` names the file in errors).
    A point's ``condition`` may be absent: it is then ``None`` and must come from its log.

    Raises
    ------
    IdentificationError
        No point fits, or a point without CL, CD and Cm parameters or a reference state.
    """
    points = doc.get("points") if isinstance(doc, dict) else None
    if not isinstance(points, dict) or not points:
        raise IdentificationError(
            f"{where}: points: no point fits (the aerodynamics a model is made of); "
            "identify logs of excitation manoeuvres first"
        )
    out = []
    for name, p in points.items():
        ref = p.get("reference") if isinstance(p, dict) else None
        if not isinstance(ref, dict) or any(not _number(ref.get(k)) for k in REFERENCE_FIELDS):
            raise IdentificationError(
                f"{where}: points.{name}.reference: missing or not numbers ({', '.join(REFERENCE_FIELDS)})"
            )
        params, methods, converged = {}, {}, {}
        for c in COEFFS:
            fit = p.get(c)
            got = fit.get("params") if isinstance(fit, dict) else None
            if not isinstance(got, dict) or not _number(got.get("const")) or not all(map(_number, got.values())):
                raise IdentificationError(f"{where}: points.{name}.{c}.params: missing or not numbers")
            unknown = set(got) - {"const", *REGRESSORS}
            if unknown:
                raise IdentificationError(f"{where}: points.{name}.{c}.params.{min(unknown)}: not an eq. (3) regressor")
            params[c] = {k: float(v) for k, v in got.items()}
            methods[c] = str(fit.get("method", doc.get("method", "ee")))
            converged[c] = bool(fit.get("converged", True))
        cond = p.get("condition")
        condition = (
            tuple(float(cond[k]) for k in ("alt_ft", "mach", "flap_deg"))
            if isinstance(cond, dict) and all(_number(cond.get(k)) for k in ("alt_ft", "mach", "flap_deg"))
            else None
        )
        out.append(
            PointModel(
                name,
                condition,
                p.get("gear") == "down",
                {k: float(ref[k]) for k in REFERENCE_FIELDS},
                params,
                methods,
                converged,
            )
        )
    return out


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class Airframe:
    """Mass, inertia and geometry for the aircraft file, from the logs' metadata.

    Attributes
    ----------
    S_ft2, cbar_ft, span_ft : float
        Reference area [ft^2], chord and span [ft].
    weight_lb, empty_lb : float
        The logs' mean weight and the lightest [lbf]: the empty weight, a point mass at the CG the rest.
    inertia : dict
        ``ixx``, ``iyy``, ``izz``, ``ixz`` [slug ft^2] about the CG.
    cg_in : tuple
        CG, structural x and z [in]: the aerodynamic reference point too.
    thrust_z_arm_ft : float
        The thrust line's height above the CG [ft].
    nominal : tuple of str
        What the logs did not give and is nominal (``span``, ``ixx``, ``izz``, ``cg``...), each said so.
    """

    S_ft2: float
    cbar_ft: float
    span_ft: float
    weight_lb: float
    empty_lb: float
    inertia: dict[str, float]
    cg_in: tuple[float, float]
    thrust_z_arm_ft: float
    nominal: tuple[str, ...] = ()


@dataclass(frozen=True)
class GearTravel:
    """How ``gear/gear-cmd-norm`` moves ``gear/gear-pos-norm``: the travel time [s] and the position at
    equal fractions of it (from the logged transitions, or linear when ``source`` says nominal)."""

    time_s: float
    position: tuple[float, ...] = (0.0, 1.0)
    source: str = "nominal (no gear transition logged)"


@dataclass(frozen=True)
class Share:
    """One point model's weight in the blend: tent tables over flap and Mach nodes, the gear, a share."""

    flaps: tuple[float, ...]
    flap_index: int
    machs: tuple[float, ...]
    mach_index: int
    gear: str | None  # "up" / "down": linear in gear/gear-pos-norm between the two; None: any gear
    share: float
    offset: dict[str, float] = field(default_factory=dict)  # added to C0 (a gear-down point's gear increment off)


def blend(points: list[PointModel], surface: GearSurface | None = None) -> list[tuple[PointModel, Share]]:
    """The point models the aircraft blends and each one's weight (:class:`Share`).

    With a gear model (``surface``), a condition's gear-up point models carry it and the gear-down ones
    are left out, unless the condition was flown gear down only: then those enter with the gear model's
    increment at gear down (at their reference state) taken off their C0. Without one, gear up and gear
    down are blended linearly in gear position.
    """
    cells: dict[tuple[float, float], dict[str, list[PointModel]]] = defaultdict(lambda: {"up": [], "down": []})
    for p in points:
        _, mach, flap = p.condition
        cells[(round(flap / FLAP_STEP_DEG) * FLAP_STEP_DEG, round(mach / MACH_STEP) * MACH_STEP)][
            "down" if p.gear_down else "up"
        ].append(p)
    flap_keys = sorted({f for f, _ in cells})
    flap_nodes = tuple(
        float(np.mean([p.condition[2] for (f, _), c in cells.items() if f == fk for p in c["up"] + c["down"]]))
        for fk in flap_keys
    )
    out = []
    for i, fk in enumerate(flap_keys):
        mach_keys = sorted(m for f, m in cells if f == fk)
        mach_nodes = tuple(
            float(np.mean([p.condition[1] for p in cells[(fk, mk)]["up"] + cells[(fk, mk)]["down"]]))
            for mk in mach_keys
        )
        for j, mk in enumerate(mach_keys):
            cell = cells[(fk, mk)]
            if surface is not None:
                chosen = [("up", cell["up"])] if cell["up"] else [("down", cell["down"])]
            else:
                chosen = [(g, ps) for g, ps in (("up", cell["up"]), ("down", cell["down"])) if ps]
            both = len(chosen) == 2
            for g, ps in chosen:
                for p in ps:
                    offset = {}
                    if surface is not None and g == "down":
                        r = p.reference
                        offset = {c: -surface(c, 1.0, r["alpha_deg"], r["mach"], p.condition[2]) for c in COEFFS}
                    out.append((p, Share(flap_nodes, i, mach_nodes, j, g if both else None, 1.0 / len(ps), offset)))
    return out


def blend_text(shares: list[tuple[PointModel, Share]], surface_kind: str | None) -> str:
    """How the aircraft interpolates between its point models and what it does outside them."""
    flaps = shares[0][1].flaps
    machs = sorted({m for _, s in shares for m in s.machs})
    cells = {(s.flap_index, s.mach_index) for _, s in shares}
    if len(shares) == 1:
        text = (
            f"One point model ({shares[0][0].point}) at every condition: its regressors about its own "
            "reference state, extrapolated as fitted beyond the states flown."
        )
    elif len(cells) == 1 and not any(s.gear for _, s in shares):
        text = (
            f"{len(shares)} point models of one condition ({', '.join(p.point for p, _ in shares)}): their mean "
            "at every condition, each with its regressors about its own reference state, extrapolated as "
            "fitted beyond the states flown."
        )
    else:
        text = (
            f"{len(shares)} point models blended: linear in Mach between the conditions of each flap setting "
            f"(Mach {', '.join(f'{m:g}' for m in machs)}), linear in flap between flap settings "
            f"({', '.join(f'{f:g}' for f in flaps)} deg), equal shares for models at one Mach and flap; outside "
            "the Mach and flap flown the nearest condition's model holds, and each model's regressors "
            "extrapolate as fitted."
        )
    if surface_kind:
        text += f" Gear: the identified {surface_kind} gear model added to the gear-up models."
    elif any(s.gear for _, s in shares):
        text += " Gear: gear-up and gear-down models blended linearly in gear/gear-pos-norm."
    else:
        text += " Gear: no gear model identified; the models hold at every gear position."
    return text


# ----------------------------------------------------------------------------- XML helpers


def _el(parent: ET.Element, tag: str, text=None, **attrs) -> ET.Element:
    e = ET.SubElement(parent, tag, attrs)
    if text is not None:
        e.text = text if isinstance(text, str) else repr(float(text))
    return e


def _location(parent: ET.Element, name: str | None, x: float, y: float, z: float) -> None:
    loc = _el(parent, "location", unit="IN", **({"name": name} if name else {}))
    for a, v in zip("xyz", (x, y, z)):
        _el(loc, a, v)


def _table(parent: ET.Element, prop: str, rows: list[tuple[float, float]]) -> None:
    t = _el(parent, "table")
    _el(t, "independentVar", prop)
    _el(t, "tableData", "\n" + "\n".join(f"  {float(a)!r} {float(b)!r}" for a, b in rows) + "\n")


def _tent(parent: ET.Element, prop: str, nodes: tuple[float, ...], i: int) -> None:
    """A weight 1 at ``nodes[i]``, falling linearly to 0 at its neighbours (held beyond the ends)."""
    rows = (
        ([(nodes[i - 1], 0.0)] if i > 0 else [])
        + [(nodes[i], 1.0)]
        + ([(nodes[i + 1], 0.0)] if i < len(nodes) - 1 else [])
    )
    _table(parent, prop, rows)


def _prop(parent: ET.Element, name: str) -> None:
    _el(parent, "property", name)


# ----------------------------------------------------------------------------- the aircraft


def _point_functions(aero: ET.Element, k: int, p: PointModel, share: Share) -> dict[str, str]:
    """Per point: its deviations and its three coefficients as functions; their names by coefficient."""
    base = f"aero/function/point-{k}"
    r = p.reference
    used = {reg for c in COEFFS for reg in p.params[c]}
    where = (
        f"{p.point} (gear {'down' if p.gear_down else 'up'}, {p.condition[0]:g} ft, Mach {p.condition[1]:g}, "
        f"flap {p.condition[2]:g} deg)"
    )
    devs = {}
    if used & {"dalpha_rad", "dalpha2_rad2"}:
        devs["dalpha_rad"] = (f"{base}/dalpha-rad", "aero/alpha-rad", r["alpha_deg"] * D2R, None)
    if "delevator_rad" in used:
        devs["delevator_rad"] = (f"{base}/delevator-rad", "fcs/elevator-pos-rad", r["elevator_deg"] * D2R, None)
    if "dstabilizer_rad" in used:
        devs["dstabilizer_rad"] = (f"{base}/dstabilizer-rad", "fcs/stabilizer-pos-deg", r["stabilizer_deg"], D2R)
    if "dmach" in used:
        devs["dmach"] = (f"{base}/dmach", "velocities/mach", r["mach"], None)
    for name, prop, ref, scale in devs.values():
        fn = _el(aero, "function", name=name)
        _el(
            fn, "description", f"{where}: {prop} less its reference value {ref!r}" + (" [deg], in rad" if scale else "")
        )
        holder = fn if scale is None else _el(fn, "product")
        diff = _el(holder, "difference")
        _prop(diff, prop)
        _el(diff, "value", ref)
        if scale is not None:
            _el(holder, "value", scale)
    flown = ", ".join(f"{ch} {lo:.4g} to {hi:.4g}" for ch, (lo, hi) in p.flown.items())
    names = {}
    for c in COEFFS:
        name = f"{base}/{c}"
        names[c] = name
        fn = _el(aero, "function", name=name)
        missing = sorted(set(REGRESSORS) - set(p.params[c]))
        _el(
            fn,
            "description",
            f"{c} of {where}: eq. (3) by {p.method_text()}"
            + (f"; not identifiable, left out: {', '.join(missing)}" if missing else "")
            + (f"; fitted over {flown}" if flown else ""),
        )
        total = _el(fn, "sum")
        _el(total, "value", p.params[c]["const"] + share.offset.get(c, 0.0))
        for reg, v in p.params[c].items():
            if reg == "const":
                continue
            term = _el(total, "product")
            _el(term, "value", v)
            if reg == "qhat_rad":
                _prop(term, "aero/ci2vel")
                _prop(term, "velocities/q-aero-rad_sec")
            elif reg == "dalpha2_rad2":
                _prop(term, devs["dalpha_rad"][0])
                _prop(term, devs["dalpha_rad"][0])
            else:
                _prop(term, devs[reg][0])
        if len(total) == 1:  # the constant alone
            fn.remove(total)
            _el(fn, "value", p.params[c]["const"] + share.offset.get(c, 0.0))
    return names


def _weighted(parent: ET.Element, share: Share, function: str) -> None:
    """``share`` x the tent weights x ``function``, as a product under ``parent``."""
    term = _el(parent, "product")
    if share.share != 1.0:
        _el(term, "value", share.share)
    if len(share.flaps) > 1:
        _tent(term, "fcs/flap-pos-deg", share.flaps, share.flap_index)
    if len(share.machs) > 1:
        _tent(term, "velocities/mach", share.machs, share.mach_index)
    if share.gear is not None:
        _table(term, "gear/gear-pos-norm", [(0.0, 1.0), (1.0, 0.0)] if share.gear == "up" else [(0.0, 0.0), (1.0, 1.0)])
    _prop(term, function)


def _aerodynamics(top: ET.Element, shares, surface: GearSurface | None, surface_kind: str | None, how: str) -> None:
    aero = _el(top, "aerodynamics")
    names = [_point_functions(aero, k, p, s) for k, (p, s) in enumerate(shares, 1)]
    for c in COEFFS:
        fn = _el(aero, "function", name=f"aero/function/{c}-identified")
        _el(fn, "description", f"Identified {c} (about the CG, {'' if c == 'Cm' else 'wind axes, '}eq. 3). {how}")
        if len(shares) == 1 and shares[0][1].share == 1.0 and shares[0][1].gear is None:
            _prop(fn, names[0][c])
            continue
        total = _el(fn, "sum")
        for (p, s), n in zip(shares, names):
            _weighted(total, s, n[c])
    gear = gear_effects(surface, surface_kind, (0.0, 0.0)) if surface is not None else None
    for c in COEFFS:
        axis = _el(aero, "axis", name=AXIS[c])
        fn = _el(axis, "function", name=f"aero/coefficient/{c}-identified")
        _el(fn, "description", f"Identified {c} times qbar S{' cbar' if c == 'Cm' else ''}")
        prod = _el(fn, "product")
        for prop in ("aero/qbar-psf", "metrics/Sw-sqft") + (("metrics/cbarw-ft",) if c == "Cm" else ()):
            _prop(prod, prop)
        _prop(prod, f"aero/function/{c}-identified")
        if gear is not None:
            axis.extend(gear.find(f"axis[@name='{AXIS[c]}']"))
    for name in ("SIDE", "ROLL", "YAW"):
        axis = _el(aero, "axis", name=name)
        for ax, coeff, variables, value in NOMINAL_LATERAL:
            if ax != name:
                continue
            fn = _el(axis, "function", name=f"aero/coefficient/{coeff}-nominal")
            _el(fn, "description", f"{coeff} = {value:g} /rad: nominal, not identified")
            prod = _el(fn, "product")
            for prop in ("aero/qbar-psf", "metrics/Sw-sqft") + (("metrics/bw-ft",) if name != "SIDE" else ()):
                _prop(prod, prop)
            for v in variables:
                _prop(prod, v)
            _el(prod, "value", value)


def _surface(
    channel: ET.Element,
    name: str,
    command: str,
    lo: float,
    hi: float,
    output: str,
    scale: float = 1.0,
    centred: bool = True,
) -> None:
    clip = _el(channel, "summer", name=f"fcs/{name}-cmd-clipped")
    _el(clip, "input", command)
    c = _el(clip, "clipto")
    _el(c, "min", "-1" if centred else "0")
    _el(c, "max", "1")
    s = _el(channel, "aerosurface_scale", name=f"fcs/{name}-pos-calc")
    _el(s, "input", f"fcs/{name}-cmd-clipped")
    if not centred:
        d = _el(s, "domain")
        _el(d, "min", "0")
        _el(d, "max", "1")
        _el(s, "zero_centered", "false")
    r = _el(s, "range")
    _el(r, "min", lo * scale)
    _el(r, "max", hi * scale)
    _el(s, "output", output)


def control_ranges(points: list[PointModel]) -> dict[str, float]:
    """Full-command surface ranges [deg]: the defaults, widened to a tenth beyond the logged positions."""

    def widest(ch: str, default: float) -> float:
        seen = [abs(v) for p in points for v in p.flown.get(ch, ())] + [
            abs(p.condition[2]) for p in points if ch == "flap_deg"
        ]
        return max([default] + [math.ceil(1.1 * v) for v in seen])

    return {
        "elevator": widest("elevator_deg", ELEVATOR_MAX_DEG),
        "stabilizer": widest("stabilizer_deg", STABILIZER_MAX_DEG),
        "flap": widest("flap_deg", FLAP_MAX_DEG),
        "aileron": AILERON_MAX_DEG,
        "rudder": RUDDER_MAX_DEG,
    }


def _flight_controls(top: ET.Element, ranges: dict[str, float], gear: GearTravel) -> None:
    fcs = _el(top, "flight_control", name="logged surface positions")
    pitch = _el(fcs, "channel", name="Pitch")
    e = ranges["elevator"]
    _surface(pitch, "elevator", "fcs/elevator-cmd-norm", -e, e, "fcs/elevator-pos-rad", D2R)
    s = ranges["stabilizer"]
    _surface(pitch, "stabilizer", "fcs/pitch-trim-cmd-norm", -s, s, "fcs/stabilizer-pos-deg")
    lateral = _el(fcs, "channel", name="Roll and yaw (nominal)")
    a = ranges["aileron"]
    _surface(lateral, "aileron", "fcs/aileron-cmd-norm", -a, a, "fcs/left-aileron-pos-rad", D2R)
    right = _el(lateral, "pure_gain", name="fcs/right-aileron-pos-calc")
    _el(right, "input", "fcs/left-aileron-pos-rad")
    _el(right, "gain", "-1")
    _el(right, "output", "fcs/right-aileron-pos-rad")
    r = ranges["rudder"]
    _surface(lateral, "rudder", "fcs/rudder-cmd-norm", -r, r, "fcs/rudder-pos-rad", D2R)
    flaps = _el(fcs, "channel", name="Flaps")
    _surface(flaps, "flap", "fcs/flap-cmd-norm", 0.0, ranges["flap"], "fcs/flap-pos-deg", centred=False)
    gear_ch = _el(fcs, "channel", name="Landing gear")
    kin = _el(gear_ch, "kinematic", name="fcs/gear-travel-norm")
    _el(kin, "input", "gear/gear-cmd-norm")
    trav = _el(kin, "traverse")
    for pos, t in ((0.0, 0.0), (1.0, gear.time_s)):
        st = _el(trav, "setting")
        _el(st, "position", pos)
        _el(st, "time", t)
    shape = _el(gear_ch, "fcs_function", name="fcs/gear-pos-calc")
    f = _el(shape, "function")
    _table(f, "fcs/gear-travel-norm", list(zip(np.linspace(0.0, 1.0, len(gear.position)), gear.position)))
    _el(shape, "output", "gear/gear-pos-norm")


def aircraft_xml(
    name: str,
    points: list[PointModel],
    airframe: Airframe,
    surface: GearSurface | None = None,
    surface_kind: str | None = None,
    gear: GearTravel | None = None,
    source: str = "",
) -> tuple[ET.ElementTree, list[str]]:
    """The aircraft file and what it says of itself (the lines the command prints).

    Parameters
    ----------
    name : str
        The aircraft's name (its file is ``<name>.xml`` in a folder ``<name>``).
    points : list of PointModel
        The identified point models, each with its condition (and ``flown`` ranges, for the text).
    airframe : Airframe
    surface : GearSurface, optional
        A gear model (eq. 4 or eq. 9) to add to the gear-up point models; ``surface_kind`` names it
        (``"linear"`` or ``"nonlinear"``).
    gear : GearTravel, optional
        The gear's travel (default :data:`NOMINAL_GEAR_TRAVEL_S`, linear).
    source : str
        What the aircraft was made from (the identification's folder), for its description.

    Returns
    -------
    tree : xml.etree.ElementTree.ElementTree
    notes : list of str
    """
    gear = gear or GearTravel(NOMINAL_GEAR_TRAVEL_S)
    shares = blend(points, surface)
    how = blend_text(shares, surface_kind if surface is not None else None)
    a = airframe
    cg_x, cg_z = a.cg_in
    methods = sorted({p.method_text() for p in points})
    notes = [
        f"aerodynamics: {len(points)} identified point model(s), eq. (3) by {'; '.join(methods)}",
        f"interpolation: {how}",
        "lateral-directional: nominal, not identified ("
        + ", ".join(f"{c} {v:g}" for _, c, _, v in NOMINAL_LATERAL)
        + " /rad)",
        (
            f"thrust: external force along body x, {a.thrust_z_arm_ft:g} ft above the CG; set "
            "external_reactions/thrust/magnitude [lbf] from thrust_lbf (no engine, no throttle)"
        ),
        f"mass: {a.weight_lb:.0f} lb ({a.empty_lb:.0f} lb empty, the rest a point mass 'payload' at the CG); "
        + ", ".join(f"{k} {v:.6g}" for k, v in a.inertia.items())
        + " slug ft^2",
        (
            f"geometry: S {a.S_ft2:.6g} ft^2, cbar {a.cbar_ft:.6g} ft, span {a.span_ft:.6g} ft; CG and AERORP at "
            f"x {cg_x:g} in, z {cg_z:g} in (the identified Cm is about the CG)"
        ),
        f"gear: travel {gear.time_s:g} s, {gear.source}",
    ]
    if a.nominal:
        notes.append("nominal (not in the logs): " + ", ".join(a.nominal))
    if any(not all(p.converged.values()) for p in points):
        notes.append("caution: not converged: " + ", ".join(p.point for p in points if not all(p.converged.values())))
    top = ET.Element("fdm_config", name=name, version="2.0", release="BETA")
    head = _el(top, "fileheader")
    _el(head, "author", "campaign model (gear-aero-id)")
    _el(head, "description", f"Aircraft identified from flight records{' in ' + source if source else ''}")
    for n in notes:
        _el(head, "note", n)
    metrics = _el(top, "metrics")
    _el(metrics, "wingarea", a.S_ft2, unit="FT2")
    _el(metrics, "wingspan", a.span_ft, unit="FT")
    _el(metrics, "chord", a.cbar_ft, unit="FT")
    _location(metrics, "AERORP", cg_x, 0.0, cg_z)
    _location(metrics, "EYEPOINT", cg_x, 0.0, cg_z)
    _location(metrics, "VRP", 0.0, 0.0, 0.0)
    mass = _el(top, "mass_balance")
    for k in ("ixx", "iyy", "izz", "ixz"):
        _el(mass, k, a.inertia[k], unit="SLUG*FT2")
    _el(mass, "emptywt", a.empty_lb, unit="LBS")
    _location(mass, "CG", cg_x, 0.0, cg_z)
    pm = _el(mass, "pointmass", name="payload")
    _el(pm, "weight", a.weight_lb - a.empty_lb, unit="LBS")
    _location(pm, None, cg_x, 0.0, cg_z)
    ground = _el(top, "ground_reactions")
    # JSBSim needs a contact; one without friction, stiff, under the CG: the aircraft flies
    contact = _el(ground, "contact", type="STRUCTURE", name="BELLY")
    _location(contact, None, cg_x, 0.0, cg_z - 12.0 * max(0.1 * a.span_ft, 1.0))
    for tag, v in (
        ("static_friction", 0.0),
        ("dynamic_friction", 0.0),
        ("spring_coeff", 10.0 * a.weight_lb),
        ("damping_coeff", a.weight_lb),
    ):
        _el(
            contact,
            tag,
            v,
            **(
                {"unit": "LBS/FT"}
                if tag == "spring_coeff"
                else {"unit": "LBS/FT/SEC"}
                if tag == "damping_coeff"
                else {}
            ),
        )
    ext = _el(top, "external_reactions")
    thrust = _el(ext, "force", name="thrust", frame="BODY")
    _location(thrust, None, cg_x, 0.0, cg_z + 12.0 * a.thrust_z_arm_ft)
    d = _el(thrust, "direction")
    for axis, v in zip("xyz", (1.0, 0.0, 0.0)):
        _el(d, axis, v)
    _flight_controls(top, control_ranges(points), gear)
    _aerodynamics(top, shares, surface, surface_kind, how)
    ET.indent(top)
    return ET.ElementTree(top), notes
