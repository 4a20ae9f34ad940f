"""The diagnosed discrepancy as JSBSim functions (effects format)."""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from identify.diagnosis import VARIABLES, Diagnosis, Term
from identify.export import AXIS

SCALE = {"CL": ("aero/qbar-psf", "metrics/Sw-sqft"), "CD": ("aero/qbar-psf", "metrics/Sw-sqft"),
         "Cm": ("aero/qbar-psf", "metrics/Sw-sqft", "metrics/cbarw-ft")}


def _fn(axis: ET.Element, name: str, coeff: str, description: str) -> ET.Element:
    fn = ET.SubElement(axis, "function", name=name)
    ET.SubElement(fn, "description").text = description
    prod = ET.SubElement(fn, "product")
    for p in SCALE[coeff]:
        ET.SubElement(prod, "property").text = p
    return prod


def _table_1d(parent: ET.Element, prop: str, xs, ys) -> None:
    t = ET.SubElement(parent, "table")
    ET.SubElement(t, "independentVar").text = prop
    ET.SubElement(t, "tableData").text = "\n" + "\n".join(f"  {float(x)!r} {float(y)!r}" for x, y in zip(xs, ys)) + "\n"


def _table_2d(parent: ET.Element, row: str, col: str, rows, cols, values) -> None:
    t = ET.SubElement(parent, "table")
    ET.SubElement(t, "independentVar", lookup="row").text = row
    ET.SubElement(t, "independentVar", lookup="column").text = col
    lines = ["      " + " ".join(repr(float(c)) for c in cols)]
    lines += [f"  {float(r)!r} " + " ".join(repr(float(v)) for v in vrow) for r, vrow in zip(rows, values)]
    ET.SubElement(t, "tableData").text = "\n" + "\n".join(lines) + "\n"


def _qhat(parent: ET.Element, center: float) -> None:
    d = ET.SubElement(parent, "difference")
    p = ET.SubElement(d, "product")
    ET.SubElement(p, "property").text = "aero/ci2vel"
    ET.SubElement(p, "property").text = "velocities/q-aero-rad_sec"
    ET.SubElement(d, "value").text = repr(float(center))


def _term(prod: ET.Element, t: Term, beta: np.ndarray) -> None:
    if t.kind == "linear":
        v = t.variables[0]
        if VARIABLES[v] is None:
            ET.SubElement(prod, "value").text = repr(float(beta[0]))
            _qhat(prod, t.centers[0])
            return
        lo, hi = t.ranges[0]
        _table_1d(prod, VARIABLES[v], (lo, hi), (beta[0] * (lo - t.centers[0]), beta[0] * (hi - t.centers[0])))
    elif t.kind == "smooth":
        _table_1d(prod, VARIABLES[t.variables[0]], t.knots, np.concatenate([[0.0], beta]))
    elif t.kind == "product":
        (la, ha), (lb, hb) = t.ranges
        ca, cb = t.centers
        ba, bb, bab = beta
        vals = [[ba * (a - ca) + bb * (b - cb) + bab * (a - ca) * (b - cb) for b in (lb, hb)] for a in (la, ha)]
        _table_2d(prod, VARIABLES[t.variables[0]], VARIABLES[t.variables[1]], (la, ha), (lb, hb), vals)
    else:
        lb, hb = t.ranges[1]
        cb = t.centers[1]
        k = len(t.knots) - 1
        main = np.concatenate([[0.0], beta[:k]])
        inter = np.concatenate([[0.0], beta[k:]])
        vals = [[m + w * (lb - cb), m + w * (hb - cb)] for m, w in zip(main, inter)]
        _table_2d(prod, VARIABLES[t.variables[0]], VARIABLES[t.variables[1]], t.knots, (lb, hb), vals)


def extension_effects(diag: Diagnosis) -> ET.Element:
    """Every selected term (and each coefficient's offset) as an ``<effects>`` element."""
    root = ET.Element("effects")
    for c, res in diag.results.items():
        if not res.terms:
            continue
        axis = ET.SubElement(root, "axis", name=AXIS[c])
        prod = _fn(axis, f"aero/coefficient/diag-d{c}-offset", c, f"Diagnosed offset of {c}")
        ET.SubElement(prod, "value").text = repr(float(res.beta[0]))
        for i, t in enumerate(res.terms):
            slug = "-".join(t.variables).replace("_", "")
            prod = _fn(axis, f"aero/coefficient/diag-d{c}-{i}-{t.kind}-{slug}", c,
                       f"Diagnosed discrepancy of {c}: {t.label}")
            _term(prod, t, res.term_beta(t))
    ET.indent(root)
    return root


def write_extension(diag: Diagnosis, path: Path) -> Path:
    root = extension_effects(diag)
    Path(path).write_text("<?xml version=\"1.0\"?>\n<!-- written by campaign diagnose -->\n"
                          + ET.tostring(root, encoding="unicode") + "\n")
    return Path(path)
