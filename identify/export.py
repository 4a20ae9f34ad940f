"""Export identified gear models as JSBSim XML, and merge them into an aircraft.

The file uses the effects format (``<effects><axis name=...><function>``), so
``campaign --effects FILE`` flies it too. :func:`merge_into_aircraft` writes a
copy of a model aircraft with its own gear terms (aero functions that read
``gear/gear-pos-norm``) replaced by the identified ones.
"""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from identify.models import COEFFS, DESIGNS, GearSurface

AXIS = {"CL": "LIFT", "CD": "DRAG", "Cm": "PITCH"}
GEAR = "gear/gear-pos-norm"


def function_name(kind: str, coeff: str) -> str:
    return f"aero/coefficient/id-{kind}-d{coeff}-gear"


def _prop(parent: ET.Element, name: str) -> None:
    ET.SubElement(parent, "property").text = name


def _value(parent: ET.Element, v: float) -> None:
    ET.SubElement(parent, "value").text = repr(float(v))


def _flap_weight(parent: ET.Element, flaps: list[int], i: int) -> None:
    if len(flaps) == 1:
        _value(parent, 1.0)
        return
    table = ET.SubElement(parent, "table")
    ET.SubElement(table, "independentVar").text = "fcs/flap-pos-deg"
    pts = []
    if i > 0:
        pts.append((flaps[i - 1], 0.0))
    pts.append((flaps[i], 1.0))
    if i < len(flaps) - 1:
        pts.append((flaps[i + 1], 0.0))
    ET.SubElement(table, "tableData").text = "\n" + "\n".join(f"  {f} {w}" for f, w in pts) + "\n"


def _surface_table(parent: ET.Element, s: GearSurface, flap: int, coeff: str) -> None:
    (a_lo, a_hi), (m_lo, m_hi) = s.table_range(flap)
    names = DESIGNS[s.designs[(flap, coeff)]]
    beta = s.coef[(flap, coeff)]

    def at(a: float, m: float) -> np.ndarray:
        return beta @ np.array([{"const": 1.0, "alpha": a, "mach": m}[t] for t in names])

    table = ET.SubElement(parent, "table")
    ET.SubElement(table, "independentVar", lookup="row").text = GEAR
    ET.SubElement(table, "independentVar", lookup="column").text = "aero/alpha-deg"
    ET.SubElement(table, "independentVar", lookup="table").text = "velocities/mach"
    for m in (m_lo, m_hi):
        lines = [f"        {a_lo!r} {a_hi!r}"]
        lo, hi = at(a_lo, m), at(a_hi, m)
        for g, v0, v1 in zip(s.grid, lo, hi):
            lines.append(f"  {float(g)!r} {float(v0)!r} {float(v1)!r}")
        ET.SubElement(table, "tableData", breakPoint=repr(float(m))).text = "\n" + "\n".join(lines) + "\n"


def gear_effects(surface: GearSurface, kind: str, arm_ft: tuple[float, float]) -> ET.Element:
    """The identified gear increments as an ``<effects>`` element.

    Parameters
    ----------
    surface : GearSurface
    kind : str
        ``"linear"`` or ``"nonlinear"``, for the function names.
    arm_ft : (float, float)
        AERORP aft of and above the CG, structural x and z [ft]. The identified
        Cm is about the CG; JSBSim transfers the lift and drag increments from
        AERORP, so the pitching function adds that transfer back:
        ``x (dCL cos a + dCD sin a) + z (dCL sin a - dCD cos a)`` per cbar.
    """
    root = ET.Element("effects")
    for coeff in COEFFS:
        axis = ET.SubElement(root, "axis", name=AXIS[coeff])
        fn = ET.SubElement(axis, "function", name=function_name(kind, coeff))
        ET.SubElement(
            fn, "description"
        ).text = f"Identified {kind} landing-gear increment of {coeff} (eq. {'4' if kind == 'linear' else '9'})"
        top = ET.SubElement(fn, "sum") if coeff == "Cm" else fn
        prod = ET.SubElement(top, "product")
        _prop(prod, "aero/qbar-psf")
        _prop(prod, "metrics/Sw-sqft")
        if coeff == "Cm":
            _prop(prod, "metrics/cbarw-ft")
        total = ET.SubElement(prod, "sum")
        for i, flap in enumerate(surface.flaps):
            term = ET.SubElement(total, "product")
            _flap_weight(term, surface.flaps, i)
            _surface_table(term, surface, flap, coeff)
        if coeff == "Cm":
            # the lift and drag functions are forces: (arm / cbar) * force / (qbar S) * qbar S cbar = arm * force
            for arm, terms in (
                (arm_ft[0], (("CL", "cos", 1.0), ("CD", "sin", 1.0))),
                (arm_ft[1], (("CL", "sin", 1.0), ("CD", "cos", -1.0))),
            ):
                if arm == 0.0:
                    continue
                transfer = ET.SubElement(top, "product")
                _value(transfer, arm)
                both = ET.SubElement(transfer, "sum")
                for c, trig, sign in terms:
                    p = ET.SubElement(both, "product")
                    if sign < 0:
                        _value(p, sign)
                    _prop(p, function_name(kind, c))
                    _prop(ET.SubElement(p, trig), "aero/alpha-rad")
    ET.indent(root)
    return root


def write_effects(surface: GearSurface, kind: str, arm_ft: tuple[float, float], path: Path) -> Path:
    root = gear_effects(surface, kind, arm_ft)
    Path(path).write_text(
        f'<?xml version="1.0"?>\n<!-- written by campaign identify -->\n{ET.tostring(root, encoding="unicode")}\n'
    )
    return Path(path)


def merge_into_aircraft(model_dir: Path, effects_path: Path, out_root: Path, replace_gear: bool = True) -> Path:
    """Copy a model aircraft, adding an effects file's functions to its aero axes.

    With ``replace_gear`` the model's own gear terms (aero functions that read
    ``gear/gear-pos-norm``) are removed first.

    Returns
    -------
    Path
        The new aircraft folder ``out_root/<name>``.
    """
    model_dir = Path(model_dir)
    name = model_dir.name
    dest = Path(out_root) / name
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(model_dir, dest, ignore=shutil.ignore_patterns("effects", "__pycache__"))
    xml = dest / f"{name}.xml"
    tree = ET.parse(xml)
    aero = tree.getroot().find("aerodynamics")
    axes = {a.get("name"): a for a in aero.findall("axis")}
    for axis in axes.values() if replace_gear else ():
        for fn in list(axis.findall("function")):
            if any(p.text and p.text.strip() == GEAR for p in fn.iter("property")) or any(
                v.text and v.text.strip() == GEAR for v in fn.iter("independentVar")
            ):
                axis.remove(fn)
    for axis_el in ET.parse(effects_path).getroot():
        axis = axes.get(axis_el.get("name"))
        if axis is None:
            axis = ET.SubElement(aero, "axis", name=axis_el.get("name"))
            axes[axis_el.get("name")] = axis
        for fn in axis_el:
            axis.append(fn)
    tree.write(xml, xml_declaration=True, encoding="unicode")
    return dest
