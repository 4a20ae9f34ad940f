"""The diagnosed discrepancy as JSBSim functions (effects format)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np

from diagnose.residuals import VARIABLES
from diagnose.result import Diagnosis
from diagnose.terms import RATES, Term, sensor_of
from identify.export import AXIS

#: Points per table on a variable exported through another property (CL through CL^2).
DENSE = 41

SCALE = {
    "CL": ("aero/qbar-psf", "metrics/Sw-sqft"),
    "CD": ("aero/qbar-psf", "metrics/Sw-sqft"),
    "Cm": ("aero/qbar-psf", "metrics/Sw-sqft", "metrics/cbarw-ft"),
}


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


def _rate(parent: ET.Element, variable: str, center: float) -> None:
    """``cbar/2V * rate - center`` of a normalised rate (:data:`diagnose.terms.RATES`)."""
    d = ET.SubElement(parent, "difference")
    p = ET.SubElement(d, "product")
    ET.SubElement(p, "property").text = "aero/ci2vel"
    ET.SubElement(p, "property").text = RATES[variable]
    ET.SubElement(d, "value").text = repr(float(center))


def _axis(variable: str, points) -> tuple[str, np.ndarray, np.ndarray]:
    """The property a table on ``variable`` reads, its breakpoints, and the variable's value at each.

    CL has no JSBSim property of its own: its tables read ``aero/cl-squared`` (the
    lift coefficient is positive over the data, :func:`candidate_terms` sees to it),
    with breakpoints dense enough that the table is linear in CL between them.
    """
    points = np.asarray(points, dtype=float)
    if variable != "CL":
        return VARIABLES[variable], points, points
    cl = np.unique(np.concatenate([points, np.linspace(points.min(), points.max(), DENSE)]))
    return VARIABLES[variable], cl**2, cl


def _term(prod: ET.Element, t: Term, beta: np.ndarray) -> None:
    if t.kind == "linear":
        v = t.variables[0]
        if v in RATES:
            ET.SubElement(prod, "value").text = repr(float(beta[0]))
            _rate(prod, v, t.centers[0])
            return
        prop, bp, x = _axis(v, t.ranges[0])
        _table_1d(prod, prop, bp, beta[0] * (x - t.centers[0]))
    elif t.kind == "quadratic":
        lo, hi = t.ranges[0]
        prop, bp, x = _axis(t.variables[0], np.linspace(lo, hi, DENSE))
        _table_1d(prod, prop, bp, beta[0] * (x - t.centers[0]) + beta[1] * (x - t.centers[0]) ** 2)
    elif t.kind == "smooth":
        prop, bp, x = _axis(t.variables[0], t.knots)
        _table_1d(prod, prop, bp, np.interp(x, t.knots, np.concatenate([[0.0], beta])))
    elif t.kind == "product":
        (pa, bpa, xa), (pb, bpb, xb) = _axis(t.variables[0], t.ranges[0]), _axis(t.variables[1], t.ranges[1])
        ca, cb = t.centers
        ba, bb, bab = beta
        vals = [[ba * (a - ca) + bb * (b - cb) + bab * (a - ca) * (b - cb) for b in xb] for a in xa]
        _table_2d(prod, pa, pb, bpa, bpb, vals)
    else:
        pb, bpb, xb = _axis(t.variables[1], t.ranges[1])
        cb = t.centers[1]
        k = len(t.knots) - 1
        main = np.concatenate([[0.0], beta[:k]])
        inter = np.concatenate([[0.0], beta[k:]])
        vals = [[m + w * (b - cb) for b in xb] for m, w in zip(main, inter)]
        _table_2d(prod, VARIABLES[t.variables[0]], pb, t.knots, bpb, vals)


def aero_terms(diag: Diagnosis) -> list[tuple[str, int, Term]]:
    """The extension's terms, ``(coefficient, index, term)``, in the order they are written."""
    return [
        (c, i, t)
        for c, res in diag.results.items()
        for i, t in enumerate([t for t in res.terms if not sensor_of(t.variables[0])])
    ]


def term_name(c: str, i: int, t: Term) -> str:
    """A term's name in the extension (its JSBSim function is ``aero/coefficient/diag-<name>``)."""
    return f"d{c}-{i}-{t.kind}-{'-'.join(t.variables).replace('_', '')}"


def scaled(diag: Diagnosis, scales: dict[str, float]) -> Diagnosis:
    """The diagnosis with each named term (:func:`term_name`) multiplied by its scale."""
    results = {}
    for c, res in diag.results.items():
        beta = res.beta.copy()
        at = 1
        aero = [t for t in res.terms if not sensor_of(t.variables[0])]
        for t in res.terms:
            if t in aero:
                beta[at : at + t.width] *= scales.get(term_name(c, aero.index(t), t), 1.0)
            at += t.width
        results[c] = replace(res, beta=beta)
    return replace(diag, results=results)


def extension_effects(diag: Diagnosis) -> ET.Element:
    """Every selected term (and each coefficient's offset) as an ``<effects>`` element."""
    root = ET.Element("effects")
    for c, res in diag.results.items():
        aero = [t for t in res.terms if not sensor_of(t.variables[0])]
        if not aero:
            continue
        axis = ET.SubElement(root, "axis", name=AXIS[c])
        prod = _fn(axis, f"aero/coefficient/diag-d{c}-offset", c, f"Diagnosed offset of {c}")
        ET.SubElement(prod, "value").text = repr(float(res.beta[0]))
        for i, t in enumerate(aero):
            prod = _fn(
                axis, f"aero/coefficient/diag-{term_name(c, i, t)}", c, f"Diagnosed discrepancy of {c}: {t.label}"
            )
            _term(prod, t, res.term_beta(t))
    ET.indent(root)
    return root


def write_extension(diag: Diagnosis, path: Path) -> Path:
    root = extension_effects(diag)
    Path(path).write_text(
        '<?xml version="1.0"?>\n<!-- written by campaign diagnose -->\n' + ET.tostring(root, encoding="unicode") + "\n"
    )
    return Path(path)
