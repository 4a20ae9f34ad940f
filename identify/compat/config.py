"""The data compatibility's decision thresholds: which instrument errors the logs can identify, which
estimates are corrected, and which are plausible at all (:class:`CompatSettings`).

:func:`identify.compat.estimate` takes them (None: the defaults) and hands them to every
:class:`~identify.compat.result.Parameter` it estimates, whose ``correctable`` and ``applied`` read
them wherever the result goes, worker processes included.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from infra.settings import doc, documented, setting


@documented
@dataclass(frozen=True)
class CompatSettings:
    """The data compatibility's decision thresholds (:mod:`identify.compat`); the defaults are what ships."""

    apply_z: float = setting(
        5.0,
        "standard errors",
        "A correction this many standard errors from 0 is applied on the kinematics' word alone; from "
        "`candidate_z` on, only if other evidence chooses it. The diagnosis names a correction made as a "
        "sensor cause from this distance too (or when the aerodynamic residuals chose it).",
        "Between `candidate_z` and this an estimate needs other evidence: with few logs as the "
        "jackknife's clusters the standard error is itself uncertain, and on simulated null campaigns in "
        "turbulence it came out 4 times too small in 1 of 6.",
    )
    candidate_z: float = setting(
        2.5,
        "standard errors",
        "An estimate this many standard errors from 0 (larger than `matters`, within `plausible`) is a "
        "candidate correction: applied only if other evidence (the aerodynamic residuals) chooses it.",
        "About the 95th percentile of the kinematics' own alpha-vane errors on simulated campaigns: an error that "
        "is not there becomes a candidate in about 1 of 20, and the residuals must then corroborate it. At "
        "3, an A320 alpha-vane scale of 7.2 %, measured as 5.7 +- 2.2 % in 3 ft/s, was never tried, and the "
        "model's own lift table, steep between two breakpoints, hid it from the instrument errors' reach.",
    )
    max_vif: float = setting(
        100.0,
        "-",
        "Above this variance inflation an instrument error is confounded with another: the most inflated is "
        "estimated with its partner held at 0, and the partner with it held at 0 (neither applied unless "
        "other evidence chooses one).",
        "A variance inflation of 100 makes a standard error 10 times that of the error estimated alone.",
    )
    matters: dict = field(
        default_factory=lambda: {
            "deg": 0.005,
            "kt": 0.5,
            "ft/s^2": 0.01,
            "deg/s": 0.005,
            "-": 0.005,
            "s": 0.01,
            "ft": 2.0,
        },
        metadata=doc(
            "channel unit",
            "The smallest correction worth applying, by the error's unit (a scale factor's is -, a time shift's "
            "s): below it, what the data hold is the kinematic model's own mismatch, not an instrument error.",
            "The mismatch perfect JSBSim logs leave: the Earth's rotation, 0.004 deg/s in the roll gyro; "
            "JSBSim's half-frame timing, 4 ms; 0.2 % in airspeed.",
        ),
    )
    plausible: dict = field(
        default_factory=lambda: {"deg": 5.0, "kt": 20.0, "ft/s^2": 1.0, "deg/s": 1.0, "-": 0.3, "s": 0.5, "ft": 200.0},
        metadata=doc(
            "channel unit",
            "The largest plausible instrument error, by unit: a larger estimate is a reconstruction gone wrong "
            "and is not applied, and the errors the diagnosis takes as possibly left in the corrected data are "
            "capped here.",
            "The kinematics hardly measure a sideslip vane's bias in longitudinal manoeuvres (+- 10 deg): "
            "uncapped, a -19 deg bias within 2 of those standard errors made, through the wind axes, all of a "
            "drag onset with flap 5.9 times its noise floor on our 737 in 3 ft/s, and nothing was named.",
        ),
    )
    scale_span: dict = field(
        default_factory=lambda: {"theta_deg": 2.0, "alpha_deg": 1.0, "tas_kt": 5.0},
        metadata=doc(
            "channel unit",
            "The span a longitudinal channel's reconstruction must cover in the manoeuvres before its scale "
            "factor is estimated; its time shift needs the channel's rate to vary (standard deviation) by a "
            "quarter of it per second. Turbulence moves the measured signal, not the reconstruction.",
        ),
    )
    lateral_span_deg: dict = field(
        default_factory=lambda: {"beta_deg": 4.0, "phi_deg": 10.0},
        metadata=doc(
            "deg",
            "The span sideslip and bank must cover (a lateral manoeuvre) before their scale factors and time "
            "shifts are estimated, and before a sideslip bias is told from a lateral velocity offset and a bank "
            "bias from the lateral accelerometer's bias through gravity.",
            "Light turbulence alone moves sideslip and bank by about 2 deg.",
        ),
    )
    theta_bias_span_deg: float = setting(
        15.0,
        "deg",
        "The span of pitch attitude a pitch-angle bias needs to be told from the longitudinal "
        "accelerometer's bias through gravity.",
    )
    turn_span_deg: float = setting(
        60.0,
        "deg",
        "The heading change a log needs for an airspeed scale and bias to be told from a steady wind (a wind "
        "fixed in the Earth's axes, seen from several headings).",
    )
    pitch_rate_std_dps: float = setting(
        0.5,
        "deg/s",
        "The pitch rate must vary (standard deviation) this much before the air-data head's distance ahead "
        "of the CG is estimated (a boom's vane reads alpha - q x / V).",
    )
    one_log_segment_s: float = setting(
        4.0,
        "s",
        "One log alone (the jackknife's clusters are logs) is cut into segments at least this long, each "
        "reconstructed from its own initial state, and they stand in for the logs.",
        "About the correlation time of Dryden's vertical gust (1,750 ft at 420 ft/s, 4.2 s). On 60 single "
        "logs of our 737 in the flight-test profile's turbulence with perfect instruments "
        "(``benchmarks/one_log_compat.py``: doublets of 22 s, multisines of 28 s and level turns of 190 s, "
        "20 turbulence draws each), segments of 8 s, two or three in the short logs, applied a vane correction that was not "
        "there to 7 of them, one at 214 standard errors: so few clusters misjudge the turbulence's spread. "
        "Segments of 4 s applied one (a 0.37 deg vane bias and a -9 % scale at 6.8 standard errors, a "
        "multisine in 6 segments), and its air-data errors' standard errors came out so wide (a vane scale's "
        "+- 24 % on the ATTAS record) that a 20 % lift slope missing from a model fell within them: from one "
        "log, the errors the air data's turbulence holds (air data, accelerometers, attitude biases) are not "
        "estimated, and the diagnosis takes them as large as specified.",
    )
    one_log_segments: int = setting(
        4,
        "-",
        "The fewest segments one log is reconstructed in: a shorter log gets no reconstruction.",
        "A jackknife over 2 or 3 clusters is what applied the false corrections of `one_log_segment_s`; the "
        "doublets of 22 s, in 5 segments, applied none.",
    )
    attitude_jump_deg: float = setting(
        20.0,
        "deg",
        "An attitude channel (pitch, bank, heading) that moves more than this in one sample beyond what the "
        "gyros turn it by, after the full turns of a heading are unwrapped, is no measurement of the attitude: "
        "the reconstruction does not use it (a heading), or does not run (pitch, bank), and says where it jumps.",
        "Physical, not fitted: the gyros' own errors move an attitude by a thousandth of this in a sample. A "
        "DLR ATTAS stall record's heading jumps by 180 deg where the gyros turn it by 0.02 deg; read as a "
        "heading, it made a 10.9 deg/s pitch-gyro bias, where the record without it gives +0.41 deg/s.",
    )
    turbulent_fps: float = setting(
        0.5,
        "ft/s",
        "Above this RMS vertical gust in the reconstruction the air-data time shifts are not estimated by "
        "the kinematics: the aircraft's answer to the gusts biases them (the diagnosis times the vanes from "
        "the aerodynamic residuals instead).",
        "On null flights in 1.5 ft/s turbulence the kinematics put the alpha vane's time shift at +15 to "
        "+45 ms, with none there.",
    )
