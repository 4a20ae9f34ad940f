"""The model structure a time-domain fit estimates (``campaign identify --method oe|fe``).

A structure names, in the log schema's own words, the terms of each coefficient (eq. 3's
regressors), the states integrated, the outputs compared with the measurements and the
inputs fed in. The full longitudinal structure integrates airspeed, alpha, pitch attitude and
pitch rate; the short-period one alpha and pitch rate with airspeed and attitude held at the
record's values (no drag). A user names one in TOML (:func:`load_structure`)::

    states = ["alpha_deg", "q_dps"]
    outputs = ["alpha_deg", "q_dps"]
    inputs = ["elevator_deg"]
    [terms]
    CL = ["const", "dalpha_rad", "qhat_rad", "delevator_rad"]
    Cm = ["const", "dalpha_rad", "qhat_rad", "delevator_rad"]
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from identify.models import COEFFS, REGRESSORS

TERMS = ("const", *REGRESSORS)
#: The state sets a model integrates, by name.
STATE_SETS = {"longitudinal": ("tas_kt", "alpha_deg", "theta_deg", "q_dps"), "short period": ("alpha_deg", "q_dps")}
OUTPUTS = ("tas_kt", "alpha_deg", "theta_deg", "q_dps", "qdot_dps2", "ax_fps2", "az_fps2")
SHORT_PERIOD_OUTPUTS = ("alpha_deg", "q_dps", "qdot_dps2")
INPUTS = ("elevator_deg", "stabilizer_deg", "thrust_lbf")
#: The input a control term needs.
TERM_INPUT = {"delevator_rad": "elevator_deg", "dstabilizer_rad": "stabilizer_deg"}
KEYS = {"states", "outputs", "inputs", "terms"}


class StructureError(ValueError):
    """A structure file that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class Structure:
    """Terms per coefficient, states, outputs and inputs of a time-domain point model.

    Attributes
    ----------
    terms : dict of str to tuple of str
        Eq. (3) regressors (``const``, ``dalpha_rad``, ...) of ``CL``, ``CD`` and ``Cm``; a
        coefficient without terms is not in the model (its equation-error fit stands).
    states, outputs, inputs : tuple of str
        Log-schema channels: the states integrated (:data:`STATE_SETS`), the measurements fitted,
        the measured inputs fed in.
    source : str
        Where it came from: ``"default"`` or the file it was read from.
    left_out : dict of str to str
        ``"<C> <term>"`` -> why the term was left out of this record's fit.
    """

    terms: dict
    states: tuple = STATE_SETS["longitudinal"]
    outputs: tuple = ("tas_kt", "alpha_deg", "theta_deg", "q_dps", "ax_fps2", "az_fps2")
    inputs: tuple = INPUTS
    source: str = "default"
    left_out: dict = field(default_factory=dict)

    @property
    def short_period(self) -> bool:
        return self.states == STATE_SETS["short period"]

    @property
    def fitted(self) -> tuple[str, ...]:
        """The coefficients the model holds (with at least one term)."""
        return tuple(c for c in COEFFS if self.terms.get(c))

    def without(self, coeff: str, term: str, why: str) -> "Structure":
        """The structure with ``term`` of ``coeff`` left out, and why."""
        terms = {**self.terms, coeff: tuple(t for t in self.terms[coeff] if t != term)}
        return replace(self, terms=terms, left_out={**self.left_out, f"{coeff} {term}": why})

    def to_dict(self) -> dict:
        return {
            "source": self.source,
            "states": list(self.states),
            "outputs": list(self.outputs),
            "inputs": list(self.inputs),
            "terms": {c: list(self.terms.get(c, ())) for c in COEFFS},
            "left_out": dict(self.left_out),
        }

    def describe(self) -> str:
        """One line: the states and each coefficient's terms."""
        kind = "short period" if self.short_period else "longitudinal"
        terms = "; ".join(f"{c}: {', '.join(self.terms[c])}" for c in self.fitted)
        return f"{kind} ({', '.join(self.states)}) fitted to {', '.join(self.outputs)}; {terms}"


#: The default: the longitudinal model with lift in alpha, Mach (and alpha's square) and the controls,
#: drag in alpha and Mach, the pitching moment in all of eq. (3)'s terms. Lift and drag take no
#: pitch-rate term: in turbulence it takes the gusts' and the vanes' share and bends the pitch
#: damping. Each fit leaves out the terms its records do not excite, and the lift and drag control
#: and curvature terms on which it and the equation error disagree
#: (:func:`identify.timedomain.supported`, :func:`identify.timedomain.disagreement`).
DEFAULT = Structure(
    {
        "CL": ("const", "dalpha_rad", "delevator_rad", "dstabilizer_rad", "dmach", "dalpha2_rad2"),
        "CD": ("const", "dalpha_rad", "dmach", "dalpha2_rad2"),
        "Cm": TERMS,
    }
)


def load_structure(path: str | Path) -> Structure:
    """A structure from a TOML file (module docstring), checked: unknown keys, terms, states,
    outputs and inputs are named with the file and the key."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as exc:
        raise StructureError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise StructureError(f"{path}: not valid TOML ({exc})") from None
    unknown = sorted(set(doc) - KEYS)
    if unknown:
        raise StructureError(f"{path}: {unknown[0]}: unknown key (expected {', '.join(sorted(KEYS))})")

    def names(key: str, allowed, default) -> tuple[str, ...]:
        value = doc.get(key, default)
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value) or not value:
            raise StructureError(f"{path}: {key}: expected a list of names, found {value!r}")
        bad = [v for v in value if v not in allowed]
        if bad:
            raise StructureError(f"{path}: {key}: {bad[0]!r} is not one of {', '.join(allowed)}")
        return tuple(value)

    states = names("states", OUTPUTS, list(STATE_SETS["longitudinal"]))
    if set(states) not in [set(s) for s in STATE_SETS.values()]:
        raise StructureError(
            f"{path}: states: {states} is neither the longitudinal states "
            f"{list(STATE_SETS['longitudinal'])} nor the short period's {list(STATE_SETS['short period'])}"
        )
    states = next(s for s in STATE_SETS.values() if set(s) == set(states))
    short = states == STATE_SETS["short period"]
    outputs = names(
        "outputs",
        SHORT_PERIOD_OUTPUTS if short else OUTPUTS,
        list(SHORT_PERIOD_OUTPUTS[:2] if short else DEFAULT.outputs),
    )
    inputs = names("inputs", INPUTS, list(INPUTS))
    table = doc.get("terms")
    if not isinstance(table, dict):
        raise StructureError(f"{path}: terms: missing (a table of CL, CD and Cm's terms)")
    bad = sorted(set(table) - set(COEFFS))
    if bad:
        raise StructureError(f"{path}: terms.{bad[0]}: not a coefficient ({', '.join(COEFFS)})")
    terms = {}
    for c in COEFFS:
        value = table.get(c, [])
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise StructureError(f"{path}: terms.{c}: expected a list of terms, found {value!r}")
        odd = [v for v in value if v not in TERMS]
        if odd:
            raise StructureError(f"{path}: terms.{c}: {odd[0]!r} is not one of {', '.join(TERMS)}")
        need = [TERM_INPUT[v] for v in value if v in TERM_INPUT and TERM_INPUT[v] not in inputs]
        if need:
            raise StructureError(f"{path}: terms.{c}: needs the input {need[0]!r}, not in inputs")
        if len(set(value)) < len(value):
            raise StructureError(f"{path}: terms.{c}: a term named twice")
        terms[c] = tuple(value)
    if short and terms["CD"]:
        raise StructureError(f"{path}: terms.CD: the short-period model has no drag (its airspeed is held)")
    if not any(terms.values()):
        raise StructureError(f"{path}: terms: no coefficient has a term")
    for c in COEFFS:
        if terms[c] and "const" not in terms[c]:
            raise StructureError(f"{path}: terms.{c}: needs 'const' (the coefficient at the reference state)")
    return Structure(terms, states, outputs, inputs, str(path))
