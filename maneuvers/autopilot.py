"""Altitude and speed hold for gear transitions (paper section 3.3), and the bank hold of a level turn.

The elevator holds altitude through a pitch-attitude inner loop; the throttle
holds speed. Gains are scheduled on dynamic pressure so one set works across
the matrix. The hold reads true states: it is part of the flight, not of the
instrumentation. The engine gives it the inertial speed, equal to the true
airspeed in still air; in turbulence the airspeed's gusts, differentiated for
the damping term, would drive the throttle from stop to stop.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class HoldGains:
    """Gains of the hold (units in the names).

    Elevator gains are quoted at ``qbar_ref_psf`` and scale with qbar_ref/qbar.
    """

    theta_deg_per_deg: float = 6.0
    q_deg_per_dps: float = 4.0
    h_deg_per_ft: float = 0.1
    hdot_deg_per_fps: float = 0.5
    h_int_deg_per_ft_s: float = 0.02
    v_per_fps: float = 0.2
    v_int_per_fps_s: float = 0.06
    vdot_per_fps2: float = 0.6
    qbar_ref_psf: float = 150.0
    aileron_per_deg: float = 0.05
    aileron_per_dps: float = 0.1
    rudder_per_deg: float = 0.1


def bank_hold(
    gains: HoldGains, bank_cmd_deg: float, phi_deg: float, p_dps: float, beta_deg: float
) -> tuple[float, float]:
    """Lateral hold of a level turn: aileron to the commanded bank (roll-rate damped), rudder
    against sideslip. JSBSim's convention: a positive aileron or rudder command rolls or yaws right.

    Returns
    -------
    aileron, rudder : float
        Normalised commands, clipped to [-1, 1] [-].
    """
    a = gains.aileron_per_deg * (bank_cmd_deg - phi_deg) - gains.aileron_per_dps * p_dps
    r = -gains.rudder_per_deg * beta_deg
    return min(max(a, -1.0), 1.0), min(max(r, -1.0), 1.0)


class HoldAutopilot:
    """Altitude/speed hold: elevator [deg] and throttle [0-1] commands.

    Parameters
    ----------
    gains : HoldGains
    dt : float
        Time step [s].
    h_ref_ft, v_ref_fps, theta_ref_deg : float
        References: trimmed altitude [ft], speed [ft/s], pitch [deg].
    elevator_trim_deg, throttle_trim : float
        Trimmed elevator [deg] and throttle [-].
    qbar_psf : float
        Trimmed dynamic pressure, for the gain schedule [psf].
    """

    def __init__(
        self,
        gains: HoldGains,
        dt: float,
        h_ref_ft: float,
        v_ref_fps: float,
        theta_ref_deg: float,
        elevator_trim_deg: float,
        throttle_trim: float,
        qbar_psf: float,
    ) -> None:
        self.g = gains
        self.dt = dt
        self.h_ref = h_ref_ft
        self.v_ref = v_ref_fps
        self.theta_ref = theta_ref_deg
        self.de0 = elevator_trim_deg
        self.thr0 = throttle_trim
        self.schedule = gains.qbar_ref_psf / max(qbar_psf, 1.0)
        self.h_int = 0.0
        self.v_int = 0.0
        self.v_prev = v_ref_fps

    def step(self, h_ft: float, hdot_fps: float, v_fps: float, theta_deg: float, q_dps: float) -> tuple[float, float]:
        """One update from the latest states.

        Returns
        -------
        elevator_deg : float
            Elevator command, positive trailing edge down [deg].
        throttle : float
            Throttle command, clipped to [0, 1] [-].
        """
        g = self.g
        e_h = self.h_ref - h_ft
        self.h_int += e_h * self.dt
        theta_cmd = (
            self.theta_ref + g.h_deg_per_ft * e_h - g.hdot_deg_per_fps * hdot_fps + g.h_int_deg_per_ft_s * self.h_int
        )
        pitch = g.theta_deg_per_deg * (theta_cmd - theta_deg) - g.q_deg_per_dps * q_dps
        elevator = self.de0 - self.schedule * pitch

        e_v = self.v_ref - v_fps
        vdot = (v_fps - self.v_prev) / self.dt
        self.v_prev = v_fps
        throttle = self.thr0 + g.v_per_fps * e_v - g.vdot_per_fps2 * vdot
        throttle_i = throttle + g.v_int_per_fps_s * (self.v_int + e_v * self.dt)
        if 0.0 < throttle_i < 1.0:
            self.v_int += e_v * self.dt
        throttle += g.v_int_per_fps_s * self.v_int
        return elevator, min(max(throttle, 0.0), 1.0)
