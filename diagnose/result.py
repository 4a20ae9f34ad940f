"""The diagnosis's result and its text summary."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from diagnose.accuracy import Instrumentation
from diagnose.causes import Cause
from diagnose.config import DiagnosisSettings, using
from diagnose.flap_mach import flown_together, level_share
from diagnose.held_out import held_out_check, told_text
from diagnose.stepwise import StepwiseResult
from diagnose.together import clusters, confounded_text
from diagnose.verdict import rank
from identify.compat import CompatResult


def _left(alternative: dict) -> str:
    """Where the data compatibility puts an instrument error in the logs as corrected."""
    left = alternative.get("left", 0.0)
    if left:
        return f"{left:+.3g} +- {alternative['se']:.2g}, measured and left uncorrected"
    return f"0 +- {alternative['se']:.2g} after correction"


def _where(rival: dict) -> str:
    """Where the data reject a rival most: the coefficients (or the data compatibility) holding most
    of the likelihood ratio."""
    by = {k: v for k, v in rival.get("by_coefficient", {}).items() if v > 0}
    total = sum(by.values()) or 1.0
    return ", ".join(
        f"{k} {100 * v / total:.0f} %" for k, v in sorted(by.items(), key=lambda kv: -kv[1]) if v >= 0.1 * total
    )


@dataclass
class Diagnosis:
    """The result: residuals, stepwise fits, the causes named and those rejected.

    Attributes
    ----------
    data : DataFrame
        Residual data of the logs fitted on.
    held : DataFrame or None
        Residual data of the held-out logs (``log``: an index into ``held_logs``).
    results : dict
        Coefficient -> :class:`StepwiseResult`, refitted on the accepted causes' terms.
    causes : list of Cause
        Accepted causes, best first.
    rejected : list of Cause
        Candidates that failed the verdict, with the reason.
    noise : dict
        Channel noise levels estimated from the logs.
    unset : list
        Inputs of the model's aerodynamics that no log channel sets.
    compat : CompatResult or None
        The data compatibility (instrument errors estimated and corrected first).
    logs, held_logs : list of Log
        The logs fitted on and held out, as corrected.
    rivals : list of dict
        Each named aero cause against each rival explanation (:func:`diagnose.separation.pair`).
    whole_readings : dict
        Coefficient -> the terms a replacement split into causes that did not all stand, for the
        coefficients searched again without splitting and read whole.
    settings : DiagnosisSettings
        The decision thresholds it was made with; its text and checks read them too.
    instruments : Instrumentation or None
        The instruments' accuracy it took (:func:`diagnose.accuracy.instrumentation`).
    moved_together : list of dict
        Candidate variables the fitted logs move together (:func:`diagnose.together.flown_together`).
    """

    data: pd.DataFrame
    results: dict[str, StepwiseResult]
    causes: list[Cause]
    rejected: list[Cause] = field(default_factory=list)
    held: pd.DataFrame | None = None
    noise: dict = field(default_factory=dict)
    unset: list = field(default_factory=list)
    first_step: dict = field(default_factory=dict)
    compat: CompatResult | None = None
    logs: list = field(default_factory=list)
    held_logs: list = field(default_factory=list)
    rivals: list = field(default_factory=list)
    whole_readings: dict = field(default_factory=dict)
    settings: DiagnosisSettings = field(default_factory=DiagnosisSettings)
    instruments: Instrumentation | None = None
    moved_together: list = field(default_factory=list)

    @property
    def discrepancy(self) -> bool:
        """Causes named, or a discrepancy whose cause these data cannot confirm (:attr:`unconfirmed`)."""
        return bool(self.causes or self.unconfirmed)

    @property
    def unconfirmed(self) -> list[Cause]:
        """Aero candidates significant and beyond what instrument noise and errors make that held-out data
        cannot confirm (they act at a single condition) or do not, strong ones (``held_out_f`` of :attr:`settings`),
        and those whose terms make the held-out logs worse (``held_out_worse``); none is in the extension."""
        return [c for c in self.rejected if c.verdict.get("unconfirmed")]

    @property
    def together(self) -> dict | None:
        """The flap angles and Mach numbers if the logs fitted on never vary them apart
        (:func:`diagnose.flap_mach.flown_together`), else None."""
        return flown_together([lg.condition for lg in self.logs])

    @property
    def held_out_check(self) -> dict:
        """What each held-out log leaves of each coefficient beside the fitted logs
        (:func:`diagnose.held_out.held_out_check`); empty without held-out logs."""
        return held_out_check(
            self.data,
            self.held,
            self.results,
            [lg.path for lg in self.logs],
            [lg.path for lg in self.held_logs],
            self.settings.held_out_ratio,
        )

    def _level_note(self, c: Cause, together: dict) -> str:
        """For a cause in the flap angle or in Mach (not both) over logs that fly them together: how much of
        it one level per group of settings makes, the part an effect of the other would make alike."""
        other = [v for v in together["variables"] if v not in c.variables]
        res = self.results.get(c.coefficient)
        if len(other) != 1 or res is None or not set(c.terms) <= set(res.terms):
            return ""
        contrib = sum(t.design(self.data) @ res.term_beta(t) for t in c.terms)
        share = level_share(contrib, self.data["log"].to_numpy(), [lg.condition for lg in self.logs], together)
        return (
            f"   caution: flap and Mach are flown together in these data (above): {100 * share:.0f} % of it is "
            f"one level per set of flap angles and Mach numbers, which an effect of {other[0]} would make alike"
        )

    @property
    def aero_causes(self) -> list[Cause]:
        """The accepted causes in the aerodynamics (the extension holds these)."""
        return [c for c in self.causes if c.kind == "aero"]

    def predict(self, coefficient: str, frame: pd.DataFrame) -> np.ndarray:
        """The fitted discrepancy of one coefficient at the states of ``frame``."""
        res = self.results[coefficient]
        return res.predict(frame) if res.terms else np.zeros(len(frame))

    def largest_rejected(self) -> dict:
        """The strongest candidate that was not named, and why."""
        if self.rejected:
            c = max(self.rejected, key=lambda c: c.verdict["size_over_floor"])
            return {
                "candidate": c.label,
                "size": c.size,
                "peak": c.peak,
                "reason": c.verdict["reason"],
                "evidence": {
                    k: c.evidence[k] for k in ("F", "p_value", "log10_p", "rss_reduction_pct") if k in c.evidence
                },
                "noise_floor": c.verdict["noise_floor"],
                "holdout_gain": c.verdict["holdout_gain"],
            }
        best = min(self.first_step.items(), key=lambda kv: (kv[1]["log10_p"], -kv[1]["F"]), default=None)
        if best is None:
            return {}
        c, a = best
        s = self.settings
        why = (
            f"not significant (p = {a['p_value']:.2g}, needs < {s.alpha_in:g})"
            if a["p_value"] >= s.alpha_in
            else f"removes only {a['rss_reduction_pct']:.2f} % of the residual (needs {100 * s.min_reduction:g} %)"
        )
        return {
            "candidate": f"{c} vs {a['term']}",
            "reason": why,
            "evidence": {k: a[k] for k in ("F", "p_value", "log10_p", "rss_reduction_pct")},
        }

    def summary(self) -> str:
        """The diagnosis in words (``diagnosis.txt``), by :attr:`settings`."""
        with using(self.settings):
            return self._summary()

    def _summary(self) -> str:  # noqa: C901
        lines = []
        if self.compat is not None and self.compat.applied:
            lines.append(
                "Data corrected for instrument errors (data compatibility): "
                + ", ".join(f"{p.name} {p.estimate:+.4g} +- {p.se:.2g} {p.unit}" for p in self.compat.applied)
            )
        if self.unset:
            lines.append("Not set from the logs (held, as in level flight): " + ", ".join(map(str, self.unset)))
        if self.instruments is not None and self.instruments.source != "estimated":
            lines.append(f"Instrument accuracy: {self.instruments.text()}.")
        together = self.together
        if together:
            lines.append(f"Caution: {together['text']}.")
        for group in clusters(self.moved_together):
            corr = ", ".join(
                f"{p['variables'][0]}/{p['variables'][1]} {p['corr']:+.2f}"
                for p in self.moved_together
                if set(p["variables"]) <= set(group)
            )
            lines.append(
                f"Caution: {', '.join(group[:-1])} and {group[-1]} flown together, across the fitted logs and within them "
                f"(correlation {corr}): an effect of one fits as one of the other; a cause in one is "
                f"confounded, its reading in the other beside it as a rival"
            )
        if not self.causes and not self.unconfirmed:
            lines.append("No significant discrepancy.")
            big = self.largest_rejected()
            if big:
                lines.append(f"   largest candidate: {big['candidate']}: {big['reason']}")
        top = min((rank(c.verdict) for c in self.aero_causes), default=(3, 0, 0.0))
        unsure = [
            f"Discrepancy, cause not confirmed: {c.label}: {c.shape}; peak {c.peak:.4g}; F = {c.evidence['F']:.4g}; "
            f"size {c.size:.3g} against a noise floor of {c.verdict['noise_floor']:.3g}; {c.verdict['reason']}"
            for c in self.unconfirmed
        ]
        larger = [rank(c.verdict) < top for c in self.unconfirmed]  # listed in rank order
        lines += [u for u, big in zip(unsure, larger) if big]
        for i, c in enumerate(self.causes, 1):
            e, v = c.evidence, c.verdict
            if c.kind == "sensor" and not c.terms:
                lines.append(
                    f"{i}. {c.label}: {c.estimate:+.4g} +- {c.se:.2g} {v.get('unit', '')} "
                    f"({e['z']:.1f} standard errors, data compatibility); moves {c.coefficient} by up to "
                    f"{c.size:.3g}; held-out gain x{v['holdout_gain']:.2f} once corrected"
                )
                if e.get("chosen_because"):
                    lines.append(f"   {e['chosen_because']}")
                continue
            if c.kind == "sensor":
                lines.append(
                    f"{i}. {c.label}: {c.estimate:+.4g} +- {c.se:.2g} (its signature in the {c.coefficient} "
                    f"residual: F = {e['F']:.4g}, removes {e['rss_reduction_pct']:.1f} %); size {c.size:.3g} "
                    f"against a noise floor of {v['noise_floor']:.3g}; held-out gain x{v['holdout_gain']:.2f}"
                )
                for a in e.get("hardly_separated_from", []):
                    lines.append(
                        f"   caution: the data hardly separate it from {a['term']} "
                        f"(F = {a['F']:.4g}, {100 * a['F_ratio']:.0f} % of the chosen term's)"
                    )
                continue
            p = (
                f"p = {e['p_value']:.2g}"
                if e["p_value"] > 0
                else f"p = 1e{e['log10_p']:.0f}"
                if np.isfinite(e.get("log10_p", np.nan))
                else "p < 1e-300"
            )
            made = (
                f", instrument errors could make {v['instrument_errors_make']:.3g} of it"
                if v.get("instrument_errors_make")
                else ""
            )
            lines.append(
                f"{i}. {c.label}: {c.shape}; peak {c.peak:.4g}; "
                f"F = {e['F']:.4g} on {e['dof'][0]} and {e['dof'][1]:.0f} dof, {p}, "
                f"removes {e['rss_reduction_pct']:.1f} % of the residual; size {c.size:.3g} against a "
                f"noise floor of {v['noise_floor']:.3g}{made}; held-out gain x{v['holdout_gain']:.2f}"
                + (f", x{v['replicate_gain']:.2f} with each log left out" if "replicate_gain" in v else "")
                + (
                    f" (x{v['replicate_gain_where_departs']:.2f} where it departs from the model)"
                    if np.isfinite(v.get("replicate_gain_where_departs", np.nan))
                    else ""
                )
            )
            note = self._level_note(c, together) if together else ""
            lines += [note] if note else []
            if e.get("confounded"):
                lines.append(confounded_text(e["confounded"]))
            rivals = {(r["term"] or r["rival"]): r for r in e.get("rivals", [])}
            settled = {k: r for k, r in rivals.items() if r["separation_se"] >= self.settings.settled_se}
            for a in e.get("hardly_separated_from", []):
                if a["term"] in rivals:  # judged below, on the final fits
                    continue
                lines.append(
                    f"   caution: the data hardly separate it from {a['term']} "
                    f"(F = {a['F']:.4g}, {100 * a['F_ratio']:.0f} % of the chosen term's)"
                )
            for a in e.get("sensor_alternatives", []):
                r = settled.get(f"{a['channel']} {a['error']}")
                if r is not None:
                    lines.append(
                        f"   not a sensor: {a['channel']} {a['error']} {a['needs']:+.3g} would make "
                        f"{a['explains_pct']:.0f} % of it in {c.coefficient} alone; fitted to CL, CD, Cm and "
                        f"the data compatibility together, these data reject it at {r['separation_se']:.1f} "
                        f"standard errors ({_where(r)} of the evidence)"
                    )
                    continue
                if a.get("declared"):
                    lines.append(
                        f"   or a sensor: {a['channel']} {a['error']} {a['needs']:+.3g} would make "
                        f"{a['explains_pct']:.0f} % of it; the data compatibility did not measure that error, "
                        f"and the instruments' accuracy allows it (up to {a['se'] * self.settings.reach_se:.3g})"
                    )
                    continue
                if a.get("unmeasured"):
                    lines.append(
                        f"   or a sensor: {a['channel']} {a['error']} {a['needs']:+.3g} would make "
                        f"{a['explains_pct']:.0f} % of it; the data compatibility could not measure that "
                        f"error in these data, so they cannot tell the two apart"
                    )
                    continue
                lines.append(
                    f"   or a sensor: {a['channel']} {a['error']} {a['needs']:+.3g} would make "
                    f"{a['explains_pct']:.0f} % of it; the data compatibility puts that error at "
                    f"{_left(a)} ({abs(a['needs_se']):.1f} standard errors away)"
                )
            for r in e.get("rivals", []):
                if r["separation_se"] < self.settings.settled_se:
                    lines.append(
                        f"   rival {r['rival']}: these data separate it from the cause by only "
                        f"{r['separation_se']:+.1f} standard errors (`campaign plan` designs the flights "
                        f"that would settle it)"
                    )
        lines += [u for u, big in zip(unsure, larger) if not big]
        lines += [f"Caution: {t}." for t in told_text(self.held_out_check)]
        if self.causes and self.rejected:
            lines.append("Rejected: " + "; ".join(f"{c.label} ({c.verdict['reason']})" for c in self.rejected))
        lines.append("")
        for c, res in self.results.items():
            lines.append(
                f"{c}: residual RMS {res.rms_before:.3g} -> {res.rms_after:.3g} with "
                f"{', '.join(t.label for t in res.terms) or 'no term'} (N_eff {res.n_eff:.0f})"
            )
            lines.append(
                "   alternatives at the first step: "
                + "; ".join(f"{a['term']} F={a['F']:.3g}" for a in res.alternatives[:5])
            )
            if c in self.whole_readings:
                lines.append(
                    f"   read whole: the search's replacement split {', '.join(self.whole_readings[c])} into "
                    f"causes that did not all stand"
                )
        return "\n".join(lines)
