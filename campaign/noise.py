"""Sensor noise and turbulence profiles for the measured channels.

``flight-test`` uses one-sigma levels typical of flight-test instrumentation
(air-data boom, INS/AHRS, servo-accelerometers, control-position transducers);
see the README table. Noise is added after the flight, from a seeded generator,
so it never disturbs the flight itself. A profile may also switch on JSBSim's
MIL-F-8785C turbulence (seeded through ``atmosphere/randomseed``); none does yet.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class NoiseProfile:
    """One-sigma sensor noise per log column and a turbulence level."""

    name: str
    sigma: dict = field(default_factory=dict)
    turbulence_w20_fps: float = 0.0
    turbulence_severity: int = 0


FLIGHT_TEST_SIGMA = {
    "alt_ft": 2.0,
    "tas_kt": 0.2,
    "ias_kt": 0.2,
    "mach": 0.0003,
    "alpha_deg": 0.05,
    "beta_deg": 0.05,
    "theta_deg": 0.02,
    "phi_deg": 0.02,
    "p_dps": 0.02,
    "q_dps": 0.02,
    "r_dps": 0.02,
    "qdot_dps2": 0.1,
    "ax_fps2": 0.03,
    "ay_fps2": 0.03,
    "az_fps2": 0.03,
    "qbar_psf": 0.1,
    "thrust_lbf": 50.0,
    "elevator_deg": 0.02,
    "stabilizer_deg": 0.02,
    "throttle_norm": 0.001,
}

NOISE_PROFILES: dict[str, NoiseProfile] = {
    "none": NoiseProfile("none"),
    # JSBSim's MIL-F-8785C turbulence gave gusts of ~20 kt at 2000 ft even at its
    # lightest severity here, so the flight-test profile carries sensor noise only.
    "flight-test": NoiseProfile("flight-test", FLIGHT_TEST_SIGMA),
}


def add_sensor_noise(df: pd.DataFrame, profile: NoiseProfile, rng: np.random.Generator) -> pd.DataFrame:
    """Return ``df`` with white Gaussian noise added per the profile's sigmas."""
    if not profile.sigma:
        return df
    out = df.copy()
    for col in sorted(profile.sigma):
        if col in out:
            out[col] = out[col] + rng.normal(0.0, profile.sigma[col], len(out))
    return out
