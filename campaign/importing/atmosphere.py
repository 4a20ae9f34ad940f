"""The standard atmosphere of imported data: Mach, calibrated airspeed and dynamic pressure from true
airspeed and pressure altitude (ambiance, ISA 1993)."""

from __future__ import annotations

import numpy as np


def isa(alt_ft: np.ndarray):
    """ISA pressure [Pa], temperature [K], density [kg/m^3] and speed of sound [m/s] at a
    pressure altitude (geopotential) [ft]."""
    from ambiance import Atmosphere

    h_geop = np.clip(np.asarray(alt_ft, float) * 0.3048, -5000.0, 80000.0)
    atm = Atmosphere(Atmosphere.geop2geom_height(h_geop))
    return atm.pressure, atm.temperature, atm.density, atm.speed_of_sound


def air_data(alt_ft: np.ndarray, tas_kt: np.ndarray) -> dict[str, np.ndarray]:
    """Mach, calibrated airspeed [kt] and dynamic pressure [psf] from true airspeed and pressure
    altitude, in the standard atmosphere (ISA temperature: a 10 K warmer day makes Mach 1.7 %
    smaller)."""
    from campaign.importing.importer import ureg

    u = ureg()
    p, t, rho, a = isa(alt_ft)
    v = np.asarray(tas_kt, float) * u.Quantity(1.0, "knot").to("m/s").magnitude
    mach = v / a
    qbar = 0.5 * rho * v**2 * u.Quantity(1.0, "Pa").to("force_pound / foot ** 2").magnitude
    p0, a0 = 101325.0, 340.29398803
    qc = p * ((1.0 + 0.2 * mach**2) ** 3.5 - 1.0)  # subsonic pitot impact pressure
    cas = a0 * np.sqrt(5.0 * ((qc / p0 + 1.0) ** (2.0 / 7.0) - 1.0))
    return {"mach": mach, "qbar_psf": qbar, "ias_kt": cas / u.Quantity(1.0, "knot").to("m/s").magnitude}
