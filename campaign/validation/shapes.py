"""A grammar of hidden aerodynamic effects the diagnosis was not built against (test side only:
the diagnosis never sees these files).

An effect is a coefficient (CL, CD or Cm), one variable or a pair, a shape and a size:

- shapes of one variable, on its range normalised to u in [0, 1]: late onset, early saturation,
  bump, dip, step, ramp above a threshold, dead band, and random monotone and non-monotone
  tables of 3 to 8 knots;
- interactions: a shape of the first variable times a linear function of the second
  (gear x flap, gear x alpha, gear x Mach, alpha x Mach), or a shape of each, multiplied;
- a random sign, and a size log-uniform between two multiples of the coefficient's noise floor.

:func:`draw` makes one from a seeded generator; :attr:`Effect.xml` is the effect overlay that
adds it to an aircraft (JSBSim tables on the variables' own properties).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from campaign.validation.hidden import wrap

#: Variable -> (JSBSim property, the range our 737 flies it over on the diagnosis matrices: the default
#: of :func:`draw`, which takes another aircraft's ``ranges`` as flown).
VARIABLES = {
    "gear_norm": ("gear/gear-pos-norm", 0.0, 1.0),
    "alpha_deg": ("aero/alpha-deg", 1.0, 10.0),
    "mach": ("velocities/mach", 0.2, 0.5),
    "flap_deg": ("fcs/flap-pos-deg", 0.0, 30.0),
    "elevator_deg": ("fcs/elevator-pos-deg", -3.0, 3.0),
}
SHAPES = ("late_onset", "early_saturation", "bump", "dip", "step", "ramp_above", "dead_band", "monotone_table", "table")
PAIRS = (("gear_norm", "flap_deg"), ("gear_norm", "alpha_deg"), ("gear_norm", "mach"), ("alpha_deg", "mach"))
#: Noise floors of each coefficient on the diagnosis matrix (tests/hidden.py) with the flight-test
#: profile [-]: the floors its diagnoses reported for smooth terms (errors-in-variables factor
#: included). A drawn effect's size is a multiple of these; outside the range flown it is cut.
FLOOR = {"CL": 1.5e-3, "CD": 1e-3, "Cm": 1.6e-3}


@dataclass(frozen=True)
class Effect:
    """One hidden effect; ``size`` is its peak-to-peak over the variables' ranges [-]."""

    coefficient: str
    variables: tuple[str, ...]
    shape: str
    size: float
    xml: str
    description: str

    @property
    def size_over_floor(self) -> float:
        return self.size / FLOOR[self.coefficient]


def shape(name: str, u: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """A shape on u in [0, 1], scaled to a peak-to-peak of 1, and its parameters in words."""
    u0 = float(rng.uniform(0.3, 0.7))
    if name == "late_onset":
        p = float(rng.uniform(1.5, 3.0))
        y, how = np.clip((u - u0) / (1 - u0), 0, None) ** p, f"zero below {u0:.2f}, then ^{p:.1f}"
    elif name == "early_saturation":
        y, how = np.sin(0.5 * np.pi * np.clip(u / u0, 0, 1)), f"flat beyond {u0:.2f}"
    elif name in ("bump", "dip"):
        w = float(rng.uniform(0.1, 0.25))
        y = np.exp(-0.5 * ((u - u0) / w) ** 2) * (1 if name == "bump" else -1)
        how = f"at {u0:.2f}, width {w:.2f}"
    elif name == "step":
        w = float(rng.uniform(0.01, 0.05))
        y, how = 0.5 * (1 + np.tanh((u - u0) / w)), f"at {u0:.2f}"
    elif name == "ramp_above":
        y, how = np.clip(u - u0, 0, None), f"above {u0:.2f}"
    elif name == "dead_band":
        w = float(rng.uniform(0.1, 0.3))
        y, how = np.clip(np.abs(u - u0) - w / 2, 0, None), f"flat within {u0:.2f} +- {w / 2:.2f}"
    elif name in ("monotone_table", "table"):
        k = int(rng.integers(3, 9))
        knots = np.linspace(0, 1, k)
        vals = np.cumsum(rng.uniform(0, 1, k)) if name == "monotone_table" else rng.uniform(-1, 1, k)
        y, how = np.interp(u, knots, vals), f"{k} knots"
    else:
        raise ValueError(name)
    span = float(np.ptp(y))
    return (y - y.min()) / span if span > 0 else y, how


def _table_1d(prop: str, xs, ys) -> str:
    rows = "\n".join(f"            {x:.6g} {y:.8g}" for x, y in zip(xs, ys))
    return (
        f"        <table>\n          <independentVar>{prop}</independentVar>\n          <tableData>\n{rows}\n"
        f"          </tableData>\n        </table>"
    )


def _table_2d(row_prop: str, col_prop: str, rows, cols, values) -> str:
    lines = (
        "            "
        + " ".join(f"{c:.6g}" for c in cols)
        + "\n"
        + "\n".join(f"            {r:.6g} " + " ".join(f"{v:.8g}" for v in vs) for r, vs in zip(rows, values))
    )
    return (
        f'        <table>\n          <independentVar lookup="row">{row_prop}</independentVar>\n'
        f'          <independentVar lookup="column">{col_prop}</independentVar>\n'
        f"          <tableData>\n{lines}\n          </tableData>\n        </table>"
    )


def draw(
    rng: np.random.Generator,
    low: float = 0.3,
    high: float = 30.0,
    coefficient: str | None = None,
    variables: tuple[str, ...] | None = None,
    name: str | None = None,
    ranges: dict[str, tuple[float, float]] | None = None,
) -> Effect:
    """A random effect: coefficient, one variable or an interaction pair, shape, sign, and a size
    log-uniform from ``low`` to ``high`` times the coefficient's noise floor (:data:`FLOOR`).

    ``ranges`` maps a variable to the (low, high) range the aircraft flies it over, in its own units
    (by default :data:`VARIABLES`'s, our 737's): the shapes are drawn on it, so that they act where the
    aircraft flies and not where only another aircraft does. The random draws are the same for any
    ranges."""
    c = coefficient or str(rng.choice(["CL", "CD", "Cm"]))
    if variables is None:
        variables = PAIRS[int(rng.integers(len(PAIRS)))] if rng.uniform() < 0.3 else (str(rng.choice(list(VARIABLES))),)
    name = name or str(rng.choice(SHAPES))
    size = FLOOR[c] * float(np.exp(rng.uniform(np.log(low), np.log(high))))
    amp = size * float(rng.choice([-1.0, 1.0]))
    v = variables[0]
    span = {k: (ranges or {}).get(k, (lo, hi)) for k, (_, lo, hi) in VARIABLES.items()}
    prop, (lo, hi) = VARIABLES[v][0], span[v]
    n = 41
    x = np.linspace(lo, hi, n)
    y, how = shape(name, np.linspace(0, 1, n), rng)
    if len(variables) == 1:
        body = _table_1d(prop, x, amp * y)
        desc = f"d{c} = {amp:+.4g} * {name}({v}; {how})"
    else:
        w = variables[1]
        prop2, (lo2, hi2) = VARIABLES[w][0], span[w]
        x2 = np.linspace(lo2, hi2, 5)
        second = (x2 - lo2) / (hi2 - lo2)  # 0 at the low end: the effect grows along the second variable
        body = _table_2d(prop, prop2, x, x2, amp * np.outer(y, second))
        desc = f"d{c} = {amp:+.4g} * {name}({v}; {how}) * ({w} - {lo2:g})/{hi2 - lo2:g}"
    return Effect(c, tuple(variables), name, size, wrap(c, body, f"shape-{name}"), desc)
