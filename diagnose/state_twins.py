"""The same term in the model's own states: the rivals a term in CL, or in a control the trim sets, always
has (:func:`diagnose.separation.rival_hypotheses`). The model's tables are written in alpha and Mach; CL is
its output, and the trim sets the elevator and the stabilizer from the states, so a term in either fits
alike to its twin in the states."""

from __future__ import annotations

from diagnose.terms import Term


def in_alpha(term: Term, pool: list[Term]) -> Term | None:
    """The candidate of ``pool`` that is ``term`` with alpha in place of CL (None if there is none, or
    ``term`` is not in CL)."""
    return _replaced(term, "CL", "alpha_deg", pool) if "CL" in term.variables else None


def _replaced(term: Term, old: str, new: str, pool: list[Term]) -> Term | None:
    """The candidate of ``pool`` that is ``term`` with variable ``new`` in place of ``old`` (None if none)."""
    want = tuple(new if v == old else v for v in term.variables)
    same = [t for t in pool if t.kind == term.kind and t.variables == want]
    same = same or [t for t in pool if t.kind == term.kind == "product" and sorted(t.variables) == sorted(want)]
    return same[0] if same else None


def in_alpha_for_mach(term: Term, pool: list[Term]) -> list[Term]:
    """The candidates of ``pool`` in alpha in place of Mach, for a term in Mach and not alpha (none
    otherwise): for a term in Mach alone every candidate in alpha alone, else the same term with alpha in
    place of Mach. Across trimmed conditions alpha falls as Mach rises, and a shape in alpha whose
    variation lies mostly between the conditions fits nearly as well in Mach with fewer columns, so the
    search enters it in Mach; only the variation within each manoeuvre, where alpha moves and Mach does
    not, tells them apart (:func:`diagnose.separation.pair`). An A320 CL table in alpha, 18.7 times its
    floor, was named "CL vs mach", and is named in alpha with this rival. Where
    the manoeuvres do not tell them apart the data may prefer Mach, and Mach stays: an A320 CL step in
    alpha between the conditions' alphas, 17 times its floor, with smooth(alpha) 22.9 standard errors
    behind."""
    if "mach" not in term.variables or "alpha_deg" in term.variables:
        return []
    if term.variables == ("mach",):
        return [t for t in pool if t.variables == ("alpha_deg",)]
    twin = _replaced(term, "mach", "alpha_deg", pool)
    return [twin] if twin is not None else []


def in_alpha_and_mach(term: Term, pool: list[Term]) -> list[Term]:
    """The candidates of ``pool`` in alpha and Mach together, for a term in CL alone (none otherwise).
    Trimmed lift is the weight over the dynamic pressure: across the conditions CL follows Mach as
    well as alpha, and a shape in alpha that Mach scales fits as one in CL (``state_se`` of
    :class:`diagnose.config.DiagnosisSettings`)."""
    if term.variables != ("CL",):
        return []
    return [t for t in pool if set(t.variables) == {"alpha_deg", "mach"}]


#: Controls the trim sets: across trimmed conditions, and through a gear transit under the autopilot's hold,
#: each follows the flow states that set it.
TRIM_SET = ("elevator_deg", "stabilizer_deg")
#: The model's own flow states, which its tables are written in.
FLOW_STATES = ("alpha_deg", "mach")


def in_flow_states(term: Term, pool: list[Term]) -> list[Term]:
    """The candidates of ``pool`` that are ``term`` with alpha, or with Mach, in place of a control the trim
    sets (:data:`TRIM_SET`), for a term in such a control and another variable (none otherwise: a control
    alone is a control derivative). An effect of the gear that grows with alpha acts only while the gear
    moves, when the hold moves the elevator with alpha: an A320 Cm bump in gear times alpha, 17 times its
    floor, was named "Cm vs gear_norm, elevator_deg", gear x alpha 0.8 standard errors behind (a
    drag in gear times alpha alike, 1.7 behind). On 1,130 case records of the
    detection curve, every term in the elevator times another variable with such a rival within 3
    standard errors hid an effect in the rival's variables (three), none a null."""
    controls = [v for v in term.variables if v in TRIM_SET]
    if not controls or len(term.variables) < 2:
        return []
    found = (_replaced(term, controls[0], state, pool) for state in FLOW_STATES if state not in term.variables)
    return [t for t in found if t is not None]


def widened(term: Term, pool: list[Term]) -> list[Term]:
    """The candidates of ``pool`` in alpha and Mach together, for a term in alpha alone or in Mach alone
    (none otherwise). A term whose variables hold the cause's enters second only if it removes 1 % of
    the residual the search began with (:func:`diagnose.stepwise.stepwise`), and a shape in alpha that
    Mach scales is mostly a shape in alpha: an A320 Cm dead band in alpha times Mach, 17.6 times its
    floor, was named "Cm vs alpha_deg" when smooth(alpha) removed 96.1 % of the residual and
    smooth(alpha) x Mach 96.5 %. Such a rival contains the term, so the data
    never prefer the term to it; they prefer the rival by what the other variable adds
    (``wider_se`` of :class:`diagnose.config.DiagnosisSettings`)."""
    if term.variables not in (("alpha_deg",), ("mach",)):
        return []
    return [t for t in pool if set(t.variables) == set(FLOW_STATES)]
