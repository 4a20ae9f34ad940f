"""Every decision threshold of the diagnosis in one object (:class:`DiagnosisSettings`).

:func:`diagnose.diagnosis.diagnose` takes one (None: the defaults, what ships) and makes it
:func:`current` while it runs; each decision reads its threshold there. The data compatibility's own
thresholds are :class:`identify.compat.CompatSettings`, the field ``compat``: they travel with the
parameters the compatibility estimates, into the worker processes that correct the logs. No other
threshold is read in a worker process. The result (:class:`diagnose.result.Diagnosis`) keeps the
settings it was made with, and ``diagnosis.json`` records them.

Each field is documented once, here: its unit, what it guards and how its value was calibrated
(:func:`infra.settings.setting`); the class's docstring and the table of the documentation
(``docs/method/diagnosis.md``) are made from that.
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field

from identify.compat.config import CompatSettings
from infra.settings import doc, documented, setting

#: The simulated flights most thresholds were calibrated on.
NULLS = (
    "simulated null flights (no aerodynamic effect hidden) of our 737, the stock JSBSim 737 and the A320 "
    "in 1.5 and 3 ft/s turbulence, sensor errors in a fifth"
)


@documented
@dataclass(frozen=True)
class DiagnosisSettings:
    """The diagnosis's decision thresholds; the defaults are what ships. "Simulated case records" are
    diagnoses of campaigns flown on our 737, the stock JSBSim 737 and the A320 through flight-test
    instruments in turbulence, with a hidden aerodynamic effect of random shape and size, a sensor error,
    or nothing (a null)."""

    # ---- the stepwise search and its candidates
    alpha_in: float = setting(
        1e-6,
        "-",
        "The significance level: a term enters the stepwise search only if its partial F-test (on the "
        "effective number of independent samples of the autocorrelated residual) has a p-value below it, "
        "leaves when its removal test no longer does, and a cause is named only if its own test passes it.",
    )
    min_reduction: float = setting(
        0.01,
        "-",
        "A term enters only if it removes at least this share of the residual sum of squares (about its mean) "
        "the search began with; a chosen term leaves when it no longer removes half of it.",
    )
    max_terms: int = setting(6, "-", "The most terms the stepwise search chooses for one coefficient.")
    rival_f_ratio: float = setting(
        0.5,
        "-",
        "A significant candidate in other variables whose F statistic is at least this share of the entering "
        "term's is that term's rival (``hardly_separated_from``): fitted in its place when the rivals are "
        "separated.",
    )
    min_std: dict = field(
        default_factory=lambda: {
            "gear_norm": 0.05,
            "alpha_deg": 0.1,
            "mach": 0.002,
            "flap_deg": 0.5,
            "elevator_deg": 0.1,
            "stabilizer_deg": 0.1,
            "qhat_rad": 1e-5,
            "adothat_rad": 1e-5,
            "CL": 0.01,
        },
        metadata=doc(
            "variable unit",
            "A variable must vary at least this much (standard deviation over the fitted data) to be a candidate; "
            "a held-out log exercises a cause where one of its variables varies this much (the gain).",
        ),
    )
    knot_quantiles: int = setting(
        21,
        "-",
        "A smooth term's knot candidates are its variable's quantiles at this many evenly spaced levels, 0 "
        "and 1 included, thinned to `min_knot_spacing`.",
    )
    min_knot_spacing: float = setting(
        0.1,
        "-",
        "A smooth term's knots are at least this share of the variable's range apart: a narrow interval "
        "inside a cluster of trimmed values is excited by sensor noise alone (errors-in-variables).",
    )
    tail_levels: tuple = setting(
        (0.005, 0.01, 0.02, 0.03, 0.97, 0.98, 0.99, 0.995),
        "-",
        "A chosen smooth term is refined with knots at these quantiles of its variable, beyond the outer "
        "quantile knots, where they fit better at `alpha_in`: in the tails the data are the manoeuvres' "
        "sparse excursions, and one interval may span a sixth of the range.",
        "On the A320, which trims at -4 to -25 deg of elevator, a drag step above -3 deg that only the Mach "
        "0.5 doublets' upswings reach (2 % of the samples, 50 times the noise in them) left 26 % of the "
        "residual on the quantile knots and was not named. Offered as candidates of their own instead of "
        "refinements, the wider terms took the place of others near their floor and beside vane and thrust "
        "errors: on simulated case records, 4 effects lost and 1 gained.",
    )
    tail_spacing: float = setting(
        0.02,
        "-",
        "A tail knot's least distance from every other knot, as a share of the variable's range: the tails "
        "hold no trimmed clusters that sensor noise alone could excite.",
    )

    # ---- the noise floor and the instrument errors' reach
    noise_realizations: int = setting(
        20,
        "-",
        "Realizations of instrument noise alone pushed through the whole residual computation; a cause's "
        "noise floor is the largest size its own terms reach on them, times its variables' "
        "errors-in-variables factor (one more realization exceeds the largest of n about once in n + 1).",
    )
    reach_se: float = setting(
        2.0,
        "standard errors",
        "The instrument errors the data compatibility may have left are taken as plausible up to this many "
        "of its standard errors (Mahalanobis) from what the logs hold as measured: what they can make of a "
        "cause's shape is taken off before the cause is compared with its noise floor.",
    )

    # ---- the verdict: held-out data
    replicate_gain: float = setting(
        1.2,
        "-",
        "A cause must make the residuals this much smaller (RMS ratio) on data it was not fitted on, where it "
        "acts: each log left out in turn and predicted from every other, its own condition's repeats among "
        "them, pooled over the logs. Repeats are independent flights: what they share is in the data, what "
        "one flight's turbulence made they do not share.",
        f"On 300 {NULLS}, 52 candidates were significant, beyond their noise floor and beyond the instrument "
        "errors' reach; with no sensor error none gained more than x1.164, and only alpha-vane scales the "
        "data compatibility left partly uncorrected gained more (x1.2-4.3). On the same verdicts this rule "
        "names a cause on 3 of the nulls and on 31 of 36 effects 3-10 times their floor; whole conditions "
        "left out in turn at x1.05 would name 9 and 28.",
    )
    departs_gain: float = setting(
        1.5,
        "-",
        "Or the same gain this large counted only on the rows where the cause departs from the model by "
        "`departs_share` of its size: a cause that acts for a few seconds of a log (a lift bump during the "
        "gear's travel, a drag ramp above an elevator angle the doublets reach at their peaks) is diluted by "
        "the rest of the log.",
        "A Cm bump in the gear's travel gained x1.16 over its gear extensions and x2.58 where it departs. Of "
        "the candidates otherwise passing on 367 simulated null flights the largest gained x1.33 there, and "
        "x1.36 on 155 more; counted there in place of the whole logs, the rule would need about x1.35 and "
        "lose causes the whole logs confirm at x1.2-1.35.",
    )
    departs_share: float = setting(
        0.2,
        "-",
        "The share of a cause's size by which it must depart from the model for a row to count in `departs_gain`.",
    )
    acting_share: float = setting(
        0.05,
        "-",
        "A log sees a cause where its contribution departs from the model (each term is zero at its "
        "reference: a smooth term's first knot, a linear term's centre) by this share of the cause's size: a "
        "tolerance for nonzero.",
        "Small because a smooth term's reference is its variable's lowest value: at 0.2 a quadratic drag rise "
        "with Mach acted at the highest of three Mach numbers only, and no condition could test it.",
    )
    refuted_gain: float = setting(
        1.0,
        "-",
        "A cause at one condition only that `strong_over_floor` or `clear_over_floor` would name unconfirmed "
        "is rejected when its repeats refute it: each log of that condition left out in turn is predicted "
        "worse with it than without (a gain below this, over the logs and where it departs).",
        "On about 3,000 simulated case records one such candidate was named on a null: an A320 drag in gear x "
        "flap at its flap-15 condition in 3 ft/s, 18 times its floor, x0.876. The 12 that were the effect "
        "gained x1.04-1.18. The rule of `held_out_f` does not ask this: one of its calibrated hits gained "
        "x0.98.",
    )

    # ---- the verdict: strength
    strong_over_floor: float = setting(
        10.0,
        "-",
        "A cause this many times its noise floor beyond what instrument errors make is strong: rows a "
        "held-out fit extrapolates may only confirm it; acting at one condition only (or at none that can be "
        "left out), neither confirmed nor refuted by its repeats, it is a discrepancy whose cause the data "
        "cannot confirm; such causes are listed first. Beyond it the size over the floor says how sure a "
        "discrepancy is, not which is larger.",
        "Ordered by the size over the floor alone, a smooth(mach) 28 times its floor that took 28 % of the "
        "drag residual came before a stock-737 drag dead band in the elevator 16.7 times its floor that took "
        "96 %. Among causes this strong the one that explains most of its coefficient's residual comes first: "
        "on 2,900 simulated effect records that order named such cases right, and no effect from three times "
        "its floor wrong that the size had named right.",
    )
    strong_f: float = setting(
        1e3,
        "-",
        "A cause with this F statistic is strong for the rows a held-out fit extrapolates; at one condition "
        "only and `clear_over_floor` times its floor, a discrepancy the data cannot confirm; with a held-out "
        "gain of `strong_gain`, a measured instrument error that fits better by less than `settled_se` "
        "leaves it unconfirmed instead of rejecting it.",
        "On 390 simulated null flights no candidate this strong (with `strong_gain`) was rejected by any rule. "
        "A stock-737 drag table in alpha, 1.3 times its floor (F = 1,337, x1.66), was otherwise rejected for a "
        "-0.08 deg vane bias 2.1 standard errors from the data compatibility's measurement that fitted 2.9 "
        "standard errors better.",
    )
    clear_over_floor: float = setting(
        3.0,
        "-",
        "At one condition only, a cause this many times its floor with an F of `strong_f` is a discrepancy "
        "the data cannot confirm, and so is an aerodynamic cause this many times its floor with an F of "
        "`held_out_f` that only held-out data fail.",
    )
    held_out_f: float = setting(
        300.0,
        "-",
        "An aerodynamic cause with this F statistic, `clear_over_floor` times its floor beyond instrument "
        "errors, that only held-out data fail, is a discrepancy all the same in a shape the data do not "
        "confirm (unconfirmed, kept out of the extension).",
        f"On 310 {NULLS}, the candidates held-out data alone rejected had an F of 73 at most (10.4 times "
        "their floor at an F of 54), whatever their size. Of 1,240 effects, 10 such candidates 10 times their "
        "floor were the effect (an A320 Cm dip in Mach at F 2,869 and x1.14 with each log left out; a "
        "stock-737 Cm step in the elevator that removed 74 % of the residual at F 482 and x0.98) and 3 were "
        "not, all three beside an uncorrected 97 ms alpha-vane delay. At 3 times the floor in place of 10, "
        "1,540 effect records gained 8 candidates that were the effect (a stock-737 CL table in the "
        "elevator at F 358 and 5.8 times its floor among them) and one that was not (Cm in CL for a Cm dead "
        "band in alpha, 9.6 times), and the nulls none.",
    )
    one_condition_f: float = setting(
        60.0,
        "-",
        "A cause at one condition only is named unconfirmed only with this F statistic: the noise floor holds "
        "instrument noise, not one flight's turbulence, and a term in the one flap setting of a condition "
        "fits what that condition's turbulence leaves in the residual as a level.",
        "On 3,466 simulated case records (680 nulls) the single-condition candidates `strong_over_floor` "
        "times their floor that were not the effect were four drags in flap or gear x flap in 3 ft/s at an F "
        "of 29-46 (one on a null), 11-26 times their floor; the 12 that were the effect (Cm in flap or gear "
        "x flap) had an F of 80-498. On two further sets of records it fired on no case; one such drag at the "
        "A320's flap 15 in 3 ft/s had an F of 250. That class was eq. (1)'s: the drag measured without the "
        "share of the side force sideslip turbulence makes, which identify.coefficients takes into account; "
        "this bound and `refuted_gain` were measured on records whose drag left that share out.",
    )
    strong_gain: float = setting(
        1.5,
        "-",
        "A pooled held-out gain (conditions left out in turn) that marks a cause's fit against the terms "
        "chosen before it alone, the stepwise search's own order; that names a cause `strong_over_floor` "
        "times its floor whose whole size instrument errors could make as a discrepancy all the same "
        "(unconfirmed); and that, with `strong_f`, keeps a measured instrument error that fits better by "
        "less than `settled_se` from rejecting a cause.",
    )
    alone_share: float = setting(
        0.5,
        "-",
        "A cause tested against the terms chosen before it alone must be at least this share of its size so: "
        "one part of a cancelling pair is much larger in the joint fit than alone (a vane scale's moment "
        "against alpha, 466 times its floor beside the moment against CL, on a stock-737 null).",
    )

    # ---- the verdict: instrument errors beside a cause
    measured_pct: float = setting(
        90.0,
        "%",
        "A cause that an instrument error the data compatibility measured, at least `reach_se` standard "
        "errors from none, and left uncorrected makes whole (this share of its variance, at a size within "
        "`reach_se` of the measurement) is that error, not a discrepancy of the model, however large: two "
        "independent measurements agree.",
        "A +0.265 deg vane bias measured as +0.257 +- 0.10 deg made a drag rise in alpha 12 times its floor on "
        "a simulated stock-737 null flight; it needed +0.271.",
    )
    measured_channel_se: float = setting(
        5.0,
        "standard errors",
        "So is a cause such an error makes at `measured_pct`, whatever is left of it, when the data "
        "compatibility measured its channel's errors together this far from none (Mahalanobis; "
        "`compat.apply_z`, what it would correct on the kinematics' word alone) and split them between errors "
        "none of which it corrected.",
        "A vane's bias and scale are confounded over the few trim alphas flown: a +0.282 deg bias was "
        "measured as +0.097 +- 0.12 deg and a 4.0 +- 2.1 % scale, 5.5 standard errors from none together, and "
        "the drag in alpha x Mach it made was named on a simulated stock-737 null in 3 ft/s, 1.8 times its "
        "floor beyond the errors within reach; the bias alone made 99 % of it at +0.268 deg. Of 16 simulated "
        "effects 3-10 times their floor, which a margin over the floor in its place would lose, the 11 whose "
        "cause an alpha-vane error could make at all had the vane's errors 0.3-1.8 standard errors from none "
        "together. The distance alone is not the rule: on a null in 3 ft/s with no sensor error the "
        'kinematics put the vane\'s errors 6.8 from none together, beside a "CD vs mach" the held-out logs '
        "had rejected already.",
    )
    sensor_alternative_pct: float = setting(
        50.0,
        "%",
        "An instrument error that alone explains this share of a cause's variance is named beside it "
        "(``sensor_alternatives``) ...",
    )
    sensor_alternative_se: float = setting(
        5.0,
        "standard errors",
        "... if the size it needs is within this many of the data compatibility's standard errors of what the "
        "logs hold as measured.",
    )
    unmeasured_plausible: dict = field(
        default_factory=lambda: {"delay": 0.2, "scale": 0.1, "bias": 1.0},
        metadata=doc(
            "s, -, channel unit",
            "... or, for an error the data compatibility could not measure, if the size it needs is within these.",
        ),
    )

    # ---- sensor causes and the arbitration between instrument errors and aerodynamic causes
    sensor_effect: float = setting(
        1e-4,
        "-",
        "A correction the data compatibility made is named as a sensor cause only if it moves a coefficient "
        "at least this much (the sensor cause's floor), and if it is `compat.apply_z` standard errors from 0 "
        "or the aerodynamic residuals chose it.",
    )
    sensor_min_gain: float = setting(
        1.02,
        "-",
        "... and only if the held-out residuals get this much smaller (RMS ratio) corrected. "
        "`replicate_gain`'s calibration on null flights covered aerodynamic causes only.",
    )
    corroborated_gain: float = setting(
        1.1,
        "-",
        "A correction the kinematics leave undecided (confounded, or between `compat.candidate_z` and "
        "`compat.apply_z`) or a vane delay timed by the residuals is applied only if the residuals get at "
        "least this much smaller (RMS) with it, on the fitted and on the held-out logs; a refinement only "
        "one coefficient's causes needed needs another coefficient's residual this much smaller as its "
        "second witness.",
    )
    refined_worse: float = setting(
        1.1,
        "-",
        "A correction the residuals chose or refined stands only if no other coefficient's residual RMS grows "
        "by more than this factor with it (about its mean where two coefficients or more needed it): an "
        "instrument error moves every coefficient along its own derivative.",
        "A lift change with alpha on a model whose drag follows CL squared looks like a vane scale in CL and "
        "CD; corrected as one, it cut CL's residual 3-fold and grew CD's 6-fold. An A320 lift change in alpha "
        "x Mach with no instrument error had the CL residual take a -1.8 % vane scale (x1.48, x1.92 held "
        "out) while Cm's residual grew 2.1-fold about its mean with it.",
    )
    agree_pct: float = setting(
        80.0,
        "%",
        "An instrument error the significant aerodynamic causes (above their noise floor) of two coefficients "
        "or more each owe this share of their variance to ...",
    )
    agree_ratio: float = setting(1.5, "-", "... at sizes this close (largest over smallest, same sign) ...")
    agree_se: float = setting(
        3.5,
        "standard errors",
        "... and within this many of the data compatibility's standard errors of its own estimate, is an "
        "instrument error: the residuals refine the correction and the diagnosis runs again, instead of "
        "naming aerodynamic causes.",
        "The 99th percentile of the kinematics' own alpha-vane errors, in standard errors, on 373 simulated "
        "campaigns in 1.5 and 3 ft/s (3.3 for the bias, 3.6 for the scale; 2.5 was their 95th). At 2.5 an "
        "A320 vane scale of 5.3 %, corrected as 8.6 +- 1.1 %, was not refined to the 5.5 % all three "
        'residuals needed (2.8 standard errors away), and "Cm vs alpha" was named on a null.',
    )
    agree_all_se: float = setting(
        5.3,
        "standard errors",
        "... or within this many when all three coefficients agree: three aerodynamic errors that mimic the "
        "same instrument error at the same size are far rarer than two.",
        "The 99.9th percentile of those errors: a jackknife over about a dozen logs makes them t-distributed, "
        "and their 95th and 99th percentiles (2.5 and 3.6) fit 9 degrees of freedom scaled by 1.1. A 4.2 % "
        "A320 vane scale in 3 ft/s, measured as 1.2 +- 0.75 %, that CL, CD and Cm each put at 3.0-4.5 % (3.8 "
        'standard errors away, median 4.0 %), named "Cm vs alpha" on a null at `agree_se`.',
    )

    # ---- rival explanations
    settled_se: float = setting(
        5.0,
        "standard errors",
        "A rival explanation is settled when the data separate it from the cause by this many standard "
        "errors (the likelihood ratio, diagnose.separation); below, `campaign plan` designs the flights that "
        "would settle it. A sensor rival the data compatibility could not measure that fits better by this "
        "much leaves the cause unconfirmed; a measured one within reach rejects it, unless the cause's own "
        "coefficient favours the cause by as much.",
    )
    preferred_se: float = setting(
        2.0,
        "standard errors",
        "A measured instrument error within reach that fits better than the cause by this many standard "
        "errors, both in the cause's own coefficient and overall, rejects it.",
        "On about 2,600 simulated campaigns no cause of a hidden effect had its own coefficient favour such an "
        "error by even 1.5; three nulls with a vane bias corrected 1-2.6 standard errors off were named for "
        '"CD vs alpha" or "CD vs CL", which the bias\'s remainder fitted 2.5-3.6 better (13 in CD).',
    )
    swap_se: float = setting(
        3.0,
        "standard errors",
        "An aerodynamic rival the data prefer by this many standard errors replaces the cause's term, settled "
        "or not: the better-fitting of two explanations is named, the other stays its rival.",
        "Two terms that fit equally well are this far apart by chance about once in 700 (one-sided normal). "
        'At 5, a CD step in gear x Mach on the stock 737, beside a thrust-deck error, stayed "CD vs gear, CL" '
        "though gear x Mach fitted 4.4 standard errors better in its place; on 750 simulated case records "
        "the most any named cause that was right had an aerodynamic rival ahead of it was 1.9.",
    )
    state_se: float = setting(
        2.0,
        "standard errors",
        "A term in the lift coefficient, or in a control the trim sets times another variable, gives way to "
        "the same term in the model's own states (alpha, Mach) unless the data prefer it by this many "
        "standard errors: within one configuration CL follows alpha, across conditions it follows Mach, and "
        "the trim sets the controls from the states.",
        "Two terms that fit equally well are 2 apart by chance about once in 40. On about 4,000 simulated "
        "case records eleven named terms in CL had such a rival within 2 standard errors: nine hid an effect "
        "with a variable the rival names and the term does not (seven in gear x Mach or alpha x Mach), two "
        "one they name alike; none was a null. On 1,130 records every term in the elevator times another "
        "variable with such a rival within 3 standard errors hid an effect in the rival's variables (three), "
        "none a null.",
    )
    wider_se: float = setting(
        5.0,
        "standard errors",
        "A term in alpha alone or Mach alone gives way to one in both if the data prefer that by this many "
        "standard errors, both to the term and to the term with twice its knots.",
        "The wider rival's extra columns fit noise too: what is left once their number is taken off scatters "
        "as a chi-square with that many degrees of freedom (12 to 24 here), which passes 3 standard errors "
        "about once in 20 and 5 about once in 1,000 to 5,000.",
    )

    # ---- rounds
    swap_rounds: int = setting(
        3,
        "-",
        "Rounds of rival swaps at most: a term that gave way is judged again against its own rivals, which "
        "its predecessor did not have.",
        "An A320 Cm table in alpha growing with Mach entered as linear(mach), gave way to quadratic(CL) 8.0 "
        "standard errors better, and alpha x Mach then fitted 6.4 better than that: three rounds.",
    )
    drop_rounds: int = setting(
        2,
        "-",
        "Rounds at most of judging a coefficient's causes again without the terms of its causes that fell "
        "(each cause is judged on the fit it is reported with): one judged again may fall in turn.",
    )

    # ---- cautions
    held_out_ratio: float = setting(
        3.0,
        "-",
        "A held-out log that leaves this many times the residual RMS of the worst fitted log, once the fit's "
        "prediction is taken off, is told in the summary: a discrepancy the named causes do not carry acts "
        "there. It decides nothing.",
        "On 180 simulated case records the 60 nulls' ratios were at most 1.02 in any coefficient; a held-out "
        "condition at a lower dynamic pressure than every fitted one leaves more noise (1.3 at 0.74 of the "
        "lowest fitted dynamic pressure). Of 120 effects, 2 hits were told (3.05 and 4.41) and 2 more came "
        'between 2 and 3 (a miss at 2.72, a hit at 2.18); an A320 drag step in the elevator named "CD vs '
        'mach" from fitted logs that fly it as a function of Mach left 25.4.',
    )

    # ---- measured data (logs not flown by a campaign)
    default_accuracy: dict = field(
        default_factory=lambda: {
            "alt_ft": {"noise": 2.0, "bias": 20.0, "scale": 0.005, "delay_s": 0.1},
            "tas_kt": {"noise": 0.3, "bias": 2.0, "scale": 0.01, "delay_s": 0.1},
            "alpha_deg": {"noise": 0.05, "bias": 0.3, "scale": 0.03, "delay_s": 0.05},
            "beta_deg": {"noise": 0.05, "bias": 0.3, "scale": 0.03, "delay_s": 0.05},
            "theta_deg": {"noise": 0.02, "bias": 0.1, "scale": 0.005, "delay_s": 0.02},
            "phi_deg": {"noise": 0.02, "bias": 0.1, "scale": 0.005, "delay_s": 0.02},
            "p_dps": {"noise": 0.05, "bias": 0.1, "scale": 0.01, "delay_s": 0.02},
            "q_dps": {"noise": 0.05, "bias": 0.1, "scale": 0.01, "delay_s": 0.02},
            "r_dps": {"noise": 0.05, "bias": 0.1, "scale": 0.01, "delay_s": 0.02},
            "ax_fps2": {"noise": 0.03, "bias": 0.1, "scale": 0.005, "delay_s": 0.02},
            "ay_fps2": {"noise": 0.03, "bias": 0.1, "scale": 0.005, "delay_s": 0.02},
            "az_fps2": {"noise": 0.03, "bias": 0.1, "scale": 0.005, "delay_s": 0.02},
            "thrust_lbf": {"scale": 0.05},
            "elevator_deg": {"noise": 0.05, "bias": 0.2, "scale": 0.02, "delay_s": 0.02},
            "stabilizer_deg": {"noise": 0.02, "bias": 0.1, "scale": 0.02},
        },
        metadata=doc(
            "channel unit, -, s",
            "The instruments' accuracy the diagnosis takes for measured data (a log ``campaign import`` or "
            "``log_from_frame`` made) on a channel whose map declares none (``[accuracy]``): white noise "
            "(1 sigma), and the largest bias, scale-factor error and delay. The noise floor draws each channel's "
            "noise at the larger of this and the logs' own estimate; every error the data compatibility did not "
            "measure may be this large (:mod:`diagnose.accuracy`).",
            "A stated conservative default, not a measurement: typical specifications of a transport aircraft's "
            "flight-test instrumentation (air-data vanes calibrated to 0.3 deg and 3 %, attitude and rate gyros, "
            "servo accelerometers of 0.003 g, an engine deck's thrust to 5 %), at the loose end. On the DLR ATTAS "
            "and HFB-320 records the logs' own white-noise estimates are 3 to 10 times smaller (alpha 0.005 deg on "
            "ATTAS): a floor from them alone holds none of the coloured noise and unmodelled dynamics of real data.",
        ),
    )
    finding_plausible: dict = field(
        default_factory=lambda: {
            "scale": 0.2,
            "delay": 0.5,
            "deg": 3.0,
            "deg/s": 1.0,
            "ft/s^2": 1.0,
            "kt": 10.0,
            "ft": 100.0,
        },
        metadata=doc(
            "-, s, channel unit",
            "A sensor cause is named only within what an instrument of its kind can be off: a scale-factor error "
            "within +-20 %, a delay under 0.5 s, a bias within these per unit (a vane a few degrees). Beyond, the "
            "estimate is reported as a reading the data do not support (an engine deck 225 % wrong is not a "
            "measurement: the thrust's signature stands in for something else).",
            "Physical bounds, not fitted: the largest errors of installed, calibrated flight-test instruments.",
        ),
    )
    flown_together_corr: float = setting(
        0.8,
        "-",
        "Two candidate variables whose correlation over the fitted samples is at least this (in magnitude), "
        "and over their variation within the logs at least `flown_together_within`, are flown together: a "
        'cause in one of them is "confounded", its reading in the other beside it as a rival (a slow '
        "deceleration moves alpha and Mach together), and ``campaign plan`` designs the flight that "
        "separates them.",
        "Four level decelerations of our 737 through the flight-test profile (alpha and Mach): -0.98 over "
        "the samples; the DLR ATTAS's two quasi-steady stall records, a slow deceleration through the "
        "stall with the elevator pulled: alpha and Mach -0.856 and -0.851 over the samples fitted, either "
        "record fitted (-0.88 over the raw records; -0.89 by rank, 0.88 to 0.90 as a smooth function of "
        "one another: no measure of a curved dependence reaches 0.9 either), where a Cm cause led by Mach "
        "was named without this caution at 0.9. The largest on simulated data: 0.71 over the samples on "
        "the paper matrix (the stabilizer and Mach; 0.46 over the samples and within the logs both, the "
        "elevator and the pitch rate), 0.42 and 0.31 on the diagnosis matrix of our 737 and the A320; "
        "the HFB-320 record 0.71 (alpha and the elevator). 0.8 sits 0.05 below the stall records and 0.09 "
        "above the simulated matrices.",
    )
    flown_together_within: float = setting(
        0.8,
        "-",
        "... and within the logs (each log's mean taken off): a pair that moves together across the logs only "
        "(a trimmed control and the state that sets it) is separated by the manoeuvres within them.",
        "The four decelerations: -0.87 within the logs (turbulence moves alpha at one Mach); the paper "
        "matrix: 0.50 at most (the elevator and the pitch rate); the A320's diagnosis matrix, whose trim ties "
        "the elevator to alpha at -0.97 over the samples: -0.29 within.",
    )
    held_out_worse: float = setting(
        0.95,
        "-",
        "A cause is not confirmed, and stays out of the extension, if its terms make its coefficient's residual "
        "on the held-out logs worse: the residual RMS without its terms (the coefficient's other terms "
        "refitted) over the RMS with them below this. It is reported unconfirmed, not rejected: held-out logs "
        "that do not fly where the cause acts test the extension's level there, not the cause.",
        "180 random cases of the detection curve (150 hidden effects, 30 nulls): "
        "of the 91 named causes that were the hidden effect, the ratio was 0.97 at least (5th percentile "
        "0.998); 5 more hidden effects fell to 0.04-0.55 (mach x alpha shapes, held out where their fit "
        "extrapolates), hence unconfirmed rather than rejected. The one false cause named had 2.8: on "
        "simulated data the rule separates nothing; it is the guard against an extension that measured data "
        "held out contradict (an ATTAS pitching-moment extension at x0.61).",
    )

    # ---- the data compatibility
    compat: CompatSettings = field(default_factory=CompatSettings)

    def to_dict(self) -> dict:
        """The settings as JSON (``compat`` nested)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict | None) -> DiagnosisSettings:
        """The inverse of :meth:`to_dict`; a missing or unknown key takes or is left to the default (None:
        the defaults)."""
        d = dict(d or {})
        names = {f.name for f in dataclasses.fields(cls)} - {"compat"}
        compat_names = {f.name for f in dataclasses.fields(CompatSettings)}
        tuples = {f.name for f in dataclasses.fields(cls) if isinstance(f.default, tuple)}
        kw = {k: tuple(v) if k in tuples else v for k, v in d.items() if k in names}
        return cls(
            **kw, compat=CompatSettings(**{k: v for k, v in (d.get("compat") or {}).items() if k in compat_names})
        )


#: What ships.
DEFAULTS = DiagnosisSettings()
_ACTIVE: ContextVar[DiagnosisSettings] = ContextVar("diagnosis_settings", default=DEFAULTS)


def recorded(doc: dict) -> DiagnosisSettings:
    """The settings a diagnosis was made with, from its ``diagnosis.json`` document (``settings``; the
    defaults where it records none)."""
    return DiagnosisSettings.from_dict(doc.get("settings"))


def current() -> DiagnosisSettings:
    """The settings of the diagnosis running in this context (:func:`using`), else the defaults."""
    return _ACTIVE.get()


@contextmanager
def using(settings: DiagnosisSettings | None):
    """Make ``settings`` (None: the defaults) :func:`current` within the ``with`` block.

    Raises
    ------
    TypeError
        If ``settings`` is not a :class:`DiagnosisSettings`.
    """
    settings = DEFAULTS if settings is None else settings
    if not isinstance(settings, DiagnosisSettings):
        raise TypeError(f"settings: a diagnose.config.DiagnosisSettings, not {type(settings).__name__}")
    token = _ACTIVE.set(settings)
    try:
        yield settings
    finally:
        _ACTIVE.reset(token)
