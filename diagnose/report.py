"""What ``campaign diagnose`` writes: ``diagnosis.json``'s document and ``diagnosis.txt``."""

from __future__ import annotations

from diagnose.result import Diagnosis
from diagnose.windows import STATE_FIT_S
from infra.provenance import tool


def document(diag: Diagnosis, data: dict, model: str) -> dict:
    """``diagnosis.json`` before the extension, the gain and the plots are added.

    Parameters
    ----------
    diag : Diagnosis
    data : dict
        ``path``, ``logs`` (how many), ``train`` and ``held_out`` (their paths).
    model : str
        The model aircraft folder.
    """
    return {
        "tool": tool(),
        "discrepancy": diag.discrepancy,
        "verdict": (
            "discrepancy"
            if diag.causes
            else "discrepancy, cause not confirmed"
            if diag.discrepancy
            else "no significant discrepancy"
        ),
        "causes": [c.to_dict() for c in diag.causes],
        "unconfirmed": [c.to_dict() for c in diag.unconfirmed],
        "rejected": [c.to_dict() for c in diag.rejected],
        "largest_rejected": None if diag.discrepancy else diag.largest_rejected(),
        "extension": None,
        "extension_xml": None,
        "gain": {},
        "alternatives": {c: r.alternatives for c, r in diag.results.items()},
        "noise_estimated": diag.noise,
        "data_compatibility": diag.compat.to_dict() if diag.compat else None,
        "unset_inputs": [{"property": u.name, "held_at": u.value} for u in diag.unset],
        "flown_together": diag.together,
        "moved_together": diag.moved_together,
        "instrument_accuracy": diag.instruments.to_dict() if diag.instruments else None,
        "held_out_check": diag.held_out_check,
        "rivals": diag.rivals,
        "whole_readings": diag.whole_readings,
        "data": data,
        "model": model,
        "plotted_logs": [],
        "settings": diag.settings.to_dict(),
    }


def _names(files: list[str], n: int = 3) -> str:
    return ", ".join(files[:n]) + (f" and {len(files) - n} more" if len(files) > n else "")


def summary(diag: Diagnosis, doc: dict) -> str:
    """``diagnosis.txt``: the diagnosis's summary, the data compatibility and the gain."""
    lines = [
        "Diagnosis",
        "=========",
        "",
        (f"data: {doc['data']['path']} ({doc['data']['logs']} logs, {len(doc['data']['held_out'])} held out)"),
        f"model: {doc['model']}",
        "",
    ]
    lines.append(diag.summary())
    if diag.compat is not None:
        lines += ["", diag.compat.summary()]
    g = doc.get("gain")
    if g:
        lines += [
            "",
            f"Gain on {len(g['held_out_logs'])} held-out manoeuvres ({_names(g['held_out_logs'])}).",
            (
                f"Residual RMS where the first aerodynamic cause ({g['cause']}) acts, "
                f"{len(g['cause_exercised_in'])} of them ({_names(g['cause_exercised_in'])}):"
            ),
        ]
        for c, v in g["residual_rms"].items():
            w = g["residual_rms_all_held_out"][c]
            lines.append(
                f"  {c}: {v['before']:.3g} -> {v['after']:.3g}  (x{v['gain']:.1f}); over every held-out "
                f"manoeuvre {w['before']:.3g} -> {w['after']:.3g} (x{w['gain']:.1f})"
            )
        lines.append("Replays of the held-out manoeuvres (same start, same inputs), worst error:")
        for ch, v in g["replay_max_error"].items():
            lines.append(f"  replay max error {ch}: {v['before']:.3g} -> {v['after']:.3g}  (x{v['gain']:.1f})")
        most = g.get("replay_moved_most")
        if most:
            v = g["replay_where_acts"][most]
            lines.append(
                f"Where the cause acts, the extension moves the replays most in {most} "
                f"({g['replay_moved'][most]:.2f} of its tolerance): worst error {v['before']:.3g} -> "
                f"{v['after']:.3g}  (x{v['gain']:.1f})"
            )
        lines += ["", f"extension: {doc['extension']} (functions in {doc['extension_xml']})"]
    r = doc.get("refine")
    if r and r.get("error"):
        lines += ["", f"Refinement by output error failed: {r['error']}"]
    elif r:
        lines += [
            "",
            (
                f"Refined by output error through replays of {len(r['fitted_logs'])} fitted logs "
                f"({r['iterations']} iterations{'' if r['converged'] else ', not converged'}); term scales:"
            ),
        ]
        lines += [f"  {k}: {v:.3f} +- {r['se_coloured'][k]:.3f}" for k, v in r["scales"].items()]
        gr = r["gain"]
        lines.append(
            f"Gain where the cause acts, equation-error extension -> refined: residual x{g['residual_gain']:.2f}"
            f" -> x{gr['residual_gain']:.2f}; replay worst error:"
        )
        for ch, v in gr["replay_max_error"].items():
            lines.append(f"  {ch}: x{g['replay_max_error'][ch]['gain']:.2f} -> x{v['gain']:.2f}")
        lines.append(f"refined extension: {r['extension']} (functions in {r['extension_xml']})")
        if r.get("caveat"):
            lines.append(f"caveat: {r['caveat']}")
    wind = doc.get("wind", {})
    if wind:
        n_wind = sum(w["replayed_in"] == "measured wind" for w in wind.values())
        lines += [
            "",
            f"Held-out replays: {n_wind} of {len(wind)} flown in the wind measured in their log"
            + (
                ""
                if n_wind == len(wind)
                else " (the others in still air: "
                + "; ".join(sorted({w["why"] for w in wind.values() if w["replayed_in"] == "still air"}))
                + ")"
            )
            + "; the replay errors and their floor below",
        ]
        lines += _start_lines(doc.get("replay_starts", {}))
    b = doc.get("bands")
    if b:
        lines += [
            "",
            (
                f"Monte Carlo bands ({next(iter(b.values()))['draws']} draws of the extension from its "
                "covariance), held-out replays where the cause acts:"
            ),
        ]
        lines += [
            f"  {k}: Part 60 pass probability {v['pass_probability']:.2f}; a held-back draw inside the band "
            f"{100 * v['held_back_draw_inside']:.0f} % of the time"
            for k, v in b.items()
        ]
    n = len(doc["plotted_logs"])
    if n and n < len(doc["data"]["held_out"]):
        lines.append(
            f"plots: the overview and {n} of the {len(doc['data']['held_out'])} held-out manoeuvres "
            f"({'where the first cause acts' if g else 'with the largest residuals'}; --plots all: every one)"
        )
    return "\n".join(lines) + "\n"


#: How an offset flown by a held-out replay is written: (name, unit, format).
_OFFSETS = {
    "elevator_deg": ("elevator", "deg", "+.3f"),
    "stabilizer_deg": ("stabilizer", "deg", "+.3f"),
    "thrust_lbf": ("thrust", "lbf", "+.0f"),
}


def _start_lines(starts: dict) -> list[str]:
    """Each held-out replay's start: how far the log was from the steady flight it is trimmed in, and the trim
    offsets its model replay flew (``diagnosis.json`` ``replay_starts``)."""
    if not starts:
        return []
    lines = [
        "Replay starts: how far each log's first seconds are from steady flight (an aircraft from campaign model "
        "is trimmed in that flight, one with engines in the steady flight nearest to it), and the offsets flown"
    ]
    for name, note in starts.items():
        st = note["start"]
        span = max(st["head_s"], STATE_FIT_S)
        text = (
            f"  {name}: airspeed {st.get('accel_fps2', 0.0):+.2f} ft/s^2, pitch attitude {st.get('theta_rate_dps', 0.0):+.2f} deg/s "
            f"over its first {span:.1f} s; "
        )
        off = {k: v for k, v in ((note.get("model") or {}).get("offsets") or {}).items() if v}
        if "model" not in note:
            text += "not flown"
        elif off:
            text += (
                "the model flies its trim plus the measured changes (trim - measured: "
                + ", ".join(f"{_OFFSETS[k][0]} {v:{_OFFSETS[k][2]}} {_OFFSETS[k][1]}" for k, v in off.items())
                + ")"
            )
        else:
            text += "the model flies the controls and thrust as measured"
        lines.append(text)
    return lines
