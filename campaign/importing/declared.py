"""What an import map declares beyond the channels: the local gravity, the instrumentation's accuracy
per channel, and where one measured file holds several records.

A flight-test department specifies each instrument's accuracy (white noise, largest bias, largest
scale-factor error, largest time delay); the map carries that specification into each log's metadata
(``instrument_accuracy``), where the diagnosis draws its noise floor and the instrument errors' reach
from it. The local gravity goes into ``gravity_fps2``, which the data compatibility and the time-domain
estimators use in place of the standard 32.174 ft/s^2.
"""

from __future__ import annotations

import math

import numpy as np

from campaign.errors import UserError

#: The keys of ``[accuracy.<channel>]``: ``noise`` and ``bias`` in the channel's unit, ``scale`` [-], ``delay`` [s].
ACCURACY_KEYS = ("noise", "bias", "scale", "delay")
#: Largest scale-factor error and delay [-, s] an accuracy specification may declare.
MAX_SCALE, MAX_DELAY_S = 0.5, 2.0
#: Local gravity a map may declare [ft/s^2]: 9.7 to 9.9 m/s^2 (the Earth's surface and the altitudes
#: aeroplanes fly at).
GRAVITY_RANGE_FPS2 = (9.7 / 0.3048, 9.9 / 0.3048)
#: The channels an accuracy may be declared for: those the diagnosis draws noise and instrument errors in.
ACCURATE = (
    "alt_ft",
    "tas_kt",
    "mach",
    "alpha_deg",
    "beta_deg",
    "theta_deg",
    "phi_deg",
    "p_dps",
    "q_dps",
    "r_dps",
    "ax_fps2",
    "ay_fps2",
    "az_fps2",
    "qbar_psf",
    "thrust_lbf",
    "elevator_deg",
    "stabilizer_deg",
    "flap_deg",
)


def normal_gravity_fps2(latitude_deg: float, alt_ft: float) -> float:
    """The WGS84 normal gravity at a latitude and height above the ellipsoid [ft/s^2].

    Somigliana's closed form at the surface and the second-order free-air correction of the
    NIMA TR8350.2 (eq. 4-3); a pressure altitude taken as the height is off by the day's departure
    from the standard atmosphere, 1e-6 g per 10 ft.

    Parameters
    ----------
    latitude_deg : float
        Geodetic latitude [deg].
    alt_ft : float
        Height above the ellipsoid [ft].
    """
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    g0 = 9.7803253359 * (1.0 + 0.00193185265241 * s2) / math.sqrt(1.0 - 0.00669437999013 * s2)
    a, f, m = 6378137.0, 1.0 / 298.257223563, 0.00344978650684
    h = alt_ft * 0.3048
    g = g0 * (1.0 - 2.0 / a * (1.0 + f + m - 2.0 * f * s2) * h + 3.0 / a**2 * h**2)
    return g / 0.3048


def check_gravity(path: str, where: str, g_fps2: float, written=None) -> float:
    """A declared gravity [ft/s^2] within :data:`GRAVITY_RANGE_FPS2`, or a one-line error naming what was
    ``written`` in the map and how it was read (a bare number is in ft/s^2)."""
    lo, hi = GRAVITY_RANGE_FPS2
    if not (math.isfinite(g_fps2) and lo <= g_fps2 <= hi):
        value = f"{g_fps2 * 0.3048:.4g} m/s^2"
        if isinstance(written, (int, float)):
            value = f"{written!r} (a number without a unit is in ft/s^2: {value})"
        raise UserError(f"{path}: {where}: {value} is not a local gravity (must be within 9.7..9.9 m/s^2)")
    return g_fps2


def parse_accuracy(path: str, table, quantity, schema_unit) -> dict[str, dict[str, float]]:
    """The ``[accuracy]`` section: per channel, ``noise`` (1 sigma) and ``bias`` (largest) in the channel's
    unit, ``scale`` (largest scale-factor error) [-], ``delay`` (largest) [s].

    Parameters
    ----------
    path : str
        The map (named in errors).
    table : dict
        The section as TOML gives it: channel -> {key: value}.
    quantity : callable
        ``quantity(path, where, value, unit)``: a number or ``"number unit"`` in ``unit``.
    schema_unit : callable
        A schema column's unit.

    Returns
    -------
    dict
        Channel -> {``noise``, ``bias``, ``scale``, ``delay_s``}, only the keys given.
    """
    out = {}
    for ch, spec in table.items():
        where = f"accuracy.{ch}"
        if ch not in ACCURATE:
            raise UserError(f"{path}: {where}: an accuracy applies to a measured channel ({', '.join(ACCURATE)})")
        if not isinstance(spec, dict) or not spec:
            raise UserError(f"{path}: {where}: expected a table of {', '.join(ACCURACY_KEYS)}")
        bad = sorted(set(spec) - set(ACCURACY_KEYS))
        if bad:
            raise UserError(f"{path}: {where}.{bad[0]}: unknown key (allowed: {', '.join(ACCURACY_KEYS)})")
        got = {}
        for key, value in spec.items():
            unit = {"scale": "dimensionless", "delay": "second"}.get(key, schema_unit(ch))
            x = quantity(path, f"{where}.{key}", value, unit)
            top = {"scale": MAX_SCALE, "delay": MAX_DELAY_S}.get(key, math.inf)
            if not (0.0 <= x <= top):
                rng = f"0..{top:g}" if math.isfinite(top) else "0 or more"
                raise UserError(f"{path}: {where}.{key}: {x:g} is not an instrument's accuracy (must be {rng})")
            got["delay_s" if key == "delay" else key] = x
        out[ch] = got
    return out


def parse_records(path: str, table) -> tuple[float, ...]:
    """``[records] split_s = [...]``: the times [s, from the file's first sample] at which one file is cut
    into records, each its own log; increasing and positive."""
    bad = sorted(set(table) - {"split_s"})
    if bad:
        raise UserError(f"{path}: records.{bad[0]}: unknown key (allowed: split_s)")
    cuts = table.get("split_s", [])
    if (
        not isinstance(cuts, list)
        or not cuts
        or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in cuts)
    ):
        raise UserError(f"{path}: records.split_s: expected a list of times [s] to cut the file at")
    cuts = [float(c) for c in cuts]
    if not all(math.isfinite(c) and c > 0 for c in cuts) or any(b <= a for a, b in zip(cuts, cuts[1:])):
        raise UserError(f"{path}: records.split_s: {cuts} must be finite, positive and increasing")
    return tuple(cuts)


def windows(source, t_s: np.ndarray, cuts: tuple[float, ...]) -> list[np.ndarray]:
    """The rows of each record: the file cut at ``cuts`` [s from its first sample]; each record at least
    ten samples, or a one-line error naming the file."""
    t0 = t_s - t_s[0]
    edges = [-math.inf, *cuts, math.inf]
    out = []
    for k, (a, b) in enumerate(zip(edges, edges[1:]), 1):
        rows = np.flatnonzero((t0 >= a) & (t0 < b))
        if len(rows) < 10:
            raise UserError(
                f"{source}: records.split_s: record {k} ({max(a, 0.0):g} to {min(b, t0[-1]):g} s) holds "
                f"{len(rows)} samples, fewer than 10"
            )
        out.append(rows)
    return out
