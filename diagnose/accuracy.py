"""The instruments' accuracy the diagnosis takes: declared, a stated default, or estimated from the logs.

Logs a campaign flew carry no declaration: the white-noise level of each channel is estimated from the
logs (:func:`diagnose.noise_floor.channel_noise`) and the instrument errors' reach is what the data
compatibility left uncertain; the thresholds were calibrated that way. Measured data (a log with
``imported`` in its metadata: ``campaign import``, or :func:`gearaero.log_from_frame`) are not our
simulation: their noise is not white, and an instrument error the manoeuvres cannot excite is not
measured at all. For them the instrumentation's specified accuracy (the import map's ``[accuracy]``,
``instrument_accuracy`` in the metadata) sets the noise floor and the reach, and where a channel has
none, the settings' ``default_accuracy`` does: the noise of each channel is the larger of its
specification and its estimate, and every bias, scale factor and delay the data compatibility did not
measure may be as large as specified (``reach_se`` standard errors of the reach).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from diagnose.config import current

#: The error kinds of a specification and the key each is given under.
ERRORS = (("bias", "bias"), ("scale", "scale"), ("delay", "delay_s"))


@dataclass(frozen=True)
class Instrumentation:
    """What the diagnosis takes the instruments' accuracy to be.

    Attributes
    ----------
    source : {"estimated", "declared", "default", "declared and default"}
        Where it comes from: estimated from the logs (logs a campaign flew), the import map's
        declaration, the settings' stated default, or both (channels without a declaration).
    spec : dict
        Channel -> ``noise`` and ``bias`` [channel unit], ``scale`` [-], ``delay_s`` [s]; empty when estimated.
    declared : tuple of str
        The channels whose specification was declared.
    """

    source: str
    spec: dict = field(default_factory=dict)
    declared: tuple = ()

    def noise(self, estimated: dict[str, float]) -> dict[str, float]:
        """Each channel's noise level (1 sigma) [channel unit]: the larger of its specification and its
        estimate from the logs (the estimate alone where nothing is specified)."""
        out = dict(estimated)
        for ch, s in self.spec.items():
            if "noise" in s and ch in out:
                out[ch] = max(out[ch], float(s["noise"]))
        return out

    def unmeasured(
        self, measured: list[tuple[str, str]], present: set[str], reach_se: float
    ) -> tuple[list[tuple[str, str]], np.ndarray]:
        """The specified instrument errors the data compatibility did not measure, as (channel, error), and a
        diagonal covariance that puts the specified bound at ``reach_se`` standard errors.

        Parameters
        ----------
        measured : list of (channel, error)
            The errors the data compatibility estimated (its uncertainty holds them already).
        present : set of str
            The channels the logs hold.
        reach_se : float
            The reach's radius [standard errors].
        """
        names, var = [], []
        for ch in sorted(self.spec):
            if ch not in present:
                continue
            for error, key in ERRORS:
                bound = float(self.spec[ch].get(key, 0.0))
                if bound > 0 and (ch, error) not in measured:
                    names.append((ch, error))
                    var.append((bound / reach_se) ** 2)
        return names, np.diag(var) if var else np.zeros((0, 0))

    def to_dict(self) -> dict:
        """As ``diagnosis.json`` holds it (``instrument_accuracy``)."""
        return {"source": self.source, "text": self.text(), "declared": list(self.declared), "spec": self.spec}

    def text(self) -> str:
        """One sentence for the report."""
        if self.source == "estimated":
            return (
                "estimated from the logs (each channel's white noise from its second differences; the "
                "instrument errors the data compatibility left uncertain): logs a campaign flew"
            )
        parts = []
        if self.declared:
            parts.append(f"declared in the import map for {', '.join(self.declared)}")
        rest = sorted(set(self.spec) - set(self.declared))
        if rest:
            which = "every channel" if not self.declared else ", ".join(rest)
            parts.append(
                f"the stated default for measured data for {which} (no [accuracy] in the import map; "
                f"DiagnosisSettings.default_accuracy)"
            )
        return (
            "; ".join(parts) + ": the noise floor draws each channel's noise at the larger of its specification "
            "and the logs' estimate, and the instrument errors' reach takes every bias, scale factor and delay "
            "the data compatibility did not measure to be as large as specified"
        )


def instrumentation(logs) -> Instrumentation:
    """The instruments' accuracy of a set of logs (see the module's docstring).

    Parameters
    ----------
    logs : list of Log
        The fitted and held-out logs together.
    """
    measured = [lg for lg in logs if "imported" in lg.meta]
    if not measured:
        return Instrumentation("estimated")
    declared: dict[str, dict[str, float]] = {}
    for lg in measured:
        for ch, s in (lg.meta.get("instrument_accuracy") or {}).items():
            into = declared.setdefault(ch, {})
            for k, v in s.items():
                into[k] = max(into.get(k, 0.0), float(v))
    present = set().union(*(set(lg.data.columns) for lg in measured))
    default = {ch: dict(s) for ch, s in current().default_accuracy.items() if ch in present and ch not in declared}
    spec = {**default, **declared}
    source = "declared and default" if declared and default else "declared" if declared else "default"
    return Instrumentation(source, spec, tuple(sorted(declared)))
