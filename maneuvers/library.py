"""Flight-test manoeuvres of the reference paper (section 3).

A manoeuvre is a frozen, picklable description. :meth:`Maneuver.program`
turns it into step-indexed signals for a given time step.
"""

from __future__ import annotations

import numpy as np

from dataclasses import dataclass, replace, fields

from maneuvers.signals import Constant, Sampled, Signal, Step, multistep


@dataclass(frozen=True)
class Program:
    """Step-indexed signals of one manoeuvre at one time step.

    Attributes
    ----------
    elevator_deg : Signal
        Elevator input added to the trim (or to the hold) [deg].
    stabilizer_deg : Signal
        Stabilizer input added to the trim [deg].
    gear_cmd : Signal or None
        Gear command, 0 up, 1 down [-]; None holds the gear where it was trimmed.
    hold : bool
        Whether the altitude/speed hold flies the manoeuvre.
    n_steps : int
        Length of a manoeuvre without gear travel [steps].
    post_travel_steps : int or None
        For gear transitions: steps flown after the gear completes its travel;
        the manoeuvre then ends ``post_travel_steps`` after completion.
    max_steps : int
        Hard limit [steps].
    throttle : Signal or None
        Throttle input added to the trim [-]; with the hold, the hold flies the elevator only.
    wind_fps : ndarray or None
        A prescribed wind, shape (steps, 3), north, east, down [ft/s] (a replay in the wind
        measured in the data), flown instead of the instrument profile's turbulence.
    bank_deg : Signal or None
        Commanded bank angle, positive right wing down [deg]: the bank hold
        (:func:`maneuvers.autopilot.bank_hold`) flies the ailerons and rudder; None leaves them
        at the trim.
    """

    elevator_deg: Signal
    stabilizer_deg: Signal
    gear_cmd: Signal | None
    hold: bool
    n_steps: int
    post_travel_steps: int | None
    max_steps: int
    throttle: Signal | None = None
    wind_fps: np.ndarray | None = None
    bank_deg: Signal | None = None


class Maneuver:
    """Base class of the manoeuvres."""

    name: str = ""

    def gear_initial(self, point_gear_down: bool) -> float:
        """Gear position at trim [-], given the status point's gear."""
        return 1.0 if point_gear_down else 0.0

    def program(self, dt: float, amplitude_scale: float = 1.0) -> Program:  # pragma: no cover
        raise NotImplementedError

    def at_trim(self, tas_fps: float, gravity_fps2: float) -> "Maneuver":
        """This manoeuvre as flown from a trim at ``tas_fps`` [ft/s] (most do not depend on it)."""
        return self


def _check_amplitudes(elevator_deg: float, stabilizer_deg: float) -> None:
    """Elevator in (0, 10] deg and stabilizer in [0, 5] deg, or ValueError naming the field."""
    if not 0 < elevator_deg <= 10.0:
        raise ValueError(f"amplitude_deg must be in (0, 10] deg, not {elevator_deg}")
    if not 0 <= stabilizer_deg <= 5.0:
        raise ValueError(f"stabilizer_amplitude_deg must be in [0, 5] deg, not {stabilizer_deg}")


def _steps(seconds: float, dt: float) -> int:
    return int(round(seconds / dt))


@dataclass(frozen=True)
class Doublet2311(Maneuver):
    """Longitudinal stick 2-3-1-1 on the elevator (paper section 3.1-3.2).

    Pull for 2 units, push 3, pull 1, push 1; the gear stays as the status
    point has it; controls are otherwise frozen at trim. A second, smaller
    2-3-1-1 on the stabilizer follows after ``gap_s``: without it the
    stabilizer derivatives are not identifiable, and the gear-up and gear-down
    trims (which differ in stabilizer) cannot be compared at one reference.

    Parameters
    ----------
    amplitude_deg : float
        Elevator amplitude with a full stall margin [deg]; the engine scales it
        by the point's stall margin.
    unit_s : float
        Length of one unit of the 2-3-1-1 [s].
    lead_s, tail_s : float
        Trimmed flight before and free response after the inputs [s].
    stabilizer_amplitude_deg : float
        Stabilizer 2-3-1-1 amplitude with a full stall margin [deg]; 0 omits it.
    gap_s : float
        Free response between the elevator and the stabilizer inputs [s].
    """

    amplitude_deg: float = 3.0
    unit_s: float = 1.0
    lead_s: float = 2.0
    tail_s: float = 8.0
    stabilizer_amplitude_deg: float = 1.0
    gap_s: float = 4.0
    name: str = "doublet"

    def __post_init__(self) -> None:
        _check_amplitudes(self.amplitude_deg, self.stabilizer_amplitude_deg)

    def program(self, dt: float, amplitude_scale: float = 1.0) -> Program:
        a = self.amplitude_deg * amplitude_scale
        u = _steps(self.unit_s, dt)
        lead = _steps(self.lead_s, dt)
        pulses = (2 * u, 3 * u, u, u)
        # JSBSim convention: negative elevator is trailing edge up (pull).
        elevator = multistep(lead, pulses, (-a, a, -a, a))
        n = lead + 7 * u
        stabilizer: Signal = Constant(0.0)
        if self.stabilizer_amplitude_deg > 0:
            h = self.stabilizer_amplitude_deg * amplitude_scale
            n += _steps(self.gap_s, dt)
            stabilizer = multistep(n, pulses, (-h, h, -h, h))
            n += 7 * u
        n += _steps(self.tail_s, dt)
        return Program(elevator, stabilizer, None, False, n, None, n)


@dataclass(frozen=True)
class GearTransition(Maneuver):
    """Gear extension or retraction under the altitude/speed hold (section 3.3).

    Parameters
    ----------
    direction : {"extend", "retract"}
    pre_s : float
        Trimmed flight before the gear command [s].
    post_s : float
        Flight after the gear completes its travel [s].
    hold : bool
        Fly under the autopilot hold (True) or with controls frozen (False).
    max_travel_s : float
        Give up if the gear has not finished after this long [s].
    """

    direction: str = "extend"
    pre_s: float = 5.0
    post_s: float = 15.0
    hold: bool = True
    max_travel_s: float = 60.0

    def __post_init__(self) -> None:
        if self.direction not in ("extend", "retract"):
            raise ValueError(f"direction must be 'extend' or 'retract', not {self.direction!r}")

    @property
    def name(self) -> str:  # type: ignore[override]
        return "gear_extension" if self.direction == "extend" else "gear_retraction"

    def gear_initial(self, point_gear_down: bool) -> float:
        return 0.0 if self.direction == "extend" else 1.0

    @property
    def gear_final(self) -> float:
        """Gear position at the end of the travel [-]."""
        return 1.0 if self.direction == "extend" else 0.0

    def program(self, dt: float, amplitude_scale: float = 1.0) -> Program:
        pre = _steps(self.pre_s, dt)
        start = self.gear_initial(False)
        gear: Signal = Constant(start) + Step(pre, self.gear_final - start)
        post = _steps(self.post_s, dt)
        return Program(
            Constant(0.0), Constant(0.0), gear, self.hold, pre + post, post, pre + _steps(self.max_travel_s, dt) + post
        )


@dataclass(frozen=True)
class Recorded(Maneuver):
    """Recorded control inputs replayed open loop, as offsets from the trim.

    Parameters
    ----------
    gear_start : float
        Gear position at trim [-].
    elevator_deg, stabilizer_deg, throttle : tuple of float
        Offsets from their first recorded value, one per step [deg, deg, -].
    gear_cmd : tuple of float
        Gear command per step [-].
    name : str
    dt_s : float, optional
        Sample interval of the recording [s]. When it is not the simulation's step, the
        inputs are resampled onto that step (linear between samples, the gear command held),
        so a 50 Hz recording plays over its own duration at 120 Hz. None: one value per step.
    wind_n_fps, wind_e_fps, wind_d_fps : tuple of float, optional
        The wind to fly in, per recorded sample [ft/s] (resampled like the inputs).
    """

    gear_start: float
    elevator_deg: tuple[float, ...]
    stabilizer_deg: tuple[float, ...]
    throttle: tuple[float, ...]
    gear_cmd: tuple[float, ...]
    name: str = "recorded"
    dt_s: float | None = None
    wind_n_fps: tuple[float, ...] | None = None
    wind_e_fps: tuple[float, ...] | None = None
    wind_d_fps: tuple[float, ...] | None = None

    def gear_initial(self, point_gear_down: bool) -> float:
        return self.gear_start

    def program(self, dt: float, amplitude_scale: float = 1.0) -> Program:
        wind = (self.wind_n_fps, self.wind_e_fps, self.wind_d_fps) if self.wind_n_fps is not None else ()
        signals = (self.elevator_deg, self.stabilizer_deg, self.gear_cmd, self.throttle, *wind)
        if self.dt_s is not None and abs(self.dt_s - dt) > 1e-9 * dt:
            t_rec = np.arange(len(self.elevator_deg)) * self.dt_s
            t_sim = np.arange(int(round(t_rec[-1] / dt)) + 1) * dt
            held = np.searchsorted(t_rec, t_sim + 1e-9 * dt, side="right") - 1
            signals = tuple(
                tuple(np.asarray(s, dtype=float)[held])
                if i == 2  # the gear command: held
                else tuple(np.interp(t_sim, t_rec, s))
                for i, s in enumerate(signals)
            )
        elevator, stabilizer, gear, throttle = signals[:4]
        n = len(elevator)
        return Program(
            Sampled(elevator),
            Sampled(stabilizer),
            Sampled(gear),
            False,
            n,
            None,
            n,
            Sampled(throttle),
            np.column_stack(signals[4:]) if wind else None,
        )


@dataclass(frozen=True)
class Multisine(Maneuver):
    """Orthogonal phase-optimized multisines on the elevator and the stabilizer together (Morelli;
    :mod:`maneuvers.multisine`).

    The harmonics of ``1 / duration_s`` in ``[f_lo_hz, f_hi_hz]`` are dealt out to the two inputs
    by interleaving; each input starts and ends at zero, and its peak is its amplitude, scaled by
    the point's stall margin like the 2-3-1-1's.

    Parameters
    ----------
    amplitude_deg : float
        Elevator peak with a full stall margin [deg].
    stabilizer_amplitude_deg : float
        Stabilizer peak with a full stall margin [deg]; 0: the elevator alone gets every harmonic.
    duration_s : float
        Length of the inputs, ``T`` [s].
    f_lo_hz, f_hi_hz : float
        The band [Hz]. It should cover the short period and not much more: on our 737 the energy
        above about 0.5 Hz moves alpha and q little (``benchmarks/multisine_information.py``),
        below 0.1 Hz it drives the phugoid.
    lead_s, tail_s : float
        Trimmed flight before and free response after the inputs [s].
    """

    amplitude_deg: float = 3.0
    stabilizer_amplitude_deg: float = 1.0
    duration_s: float = 18.0
    f_lo_hz: float = 0.1
    f_hi_hz: float = 0.5
    lead_s: float = 2.0
    tail_s: float = 8.0
    name: str = "multisine"

    def __post_init__(self) -> None:
        _check_amplitudes(self.amplitude_deg, self.stabilizer_amplitude_deg)
        if not 0 < self.f_lo_hz < self.f_hi_hz <= 5.0:
            raise ValueError(f"the band must satisfy 0 < f_lo_hz < f_hi_hz <= 5 Hz, not {self.f_lo_hz}-{self.f_hi_hz}")
        inputs = 2 if self.stabilizer_amplitude_deg > 0 else 1
        harmonics = (
            int(np.floor(self.f_hi_hz * self.duration_s + 1e-9))
            - max(1, int(np.ceil(self.f_lo_hz * self.duration_s - 1e-9)))
            + 1
        )
        if harmonics < 2 * inputs:
            raise ValueError(
                f"the band {self.f_lo_hz:g}-{self.f_hi_hz:g} Hz holds {max(harmonics, 0)} harmonics "
                f"of 1/{self.duration_s:g} s: fewer than 2 per input (widen it or lengthen duration_s)"
            )

    def program(self, dt: float, amplitude_scale: float = 1.0) -> Program:
        from maneuvers.multisine import multisine_signals

        lead, n = _steps(self.lead_s, dt), _steps(self.duration_s, dt)
        peaks = (self.amplitude_deg * amplitude_scale,)
        if self.stabilizer_amplitude_deg > 0:
            peaks += (self.stabilizer_amplitude_deg * amplitude_scale,)
        signals, _ = multisine_signals(n, dt, self.f_lo_hz, self.f_hi_hz, peaks, start=lead)
        stabilizer = signals[1] if len(signals) > 1 else Constant(0.0)
        total = lead + n + _steps(self.tail_s, dt)
        return Program(signals[0], stabilizer, None, False, total, None, total)


@dataclass(frozen=True)
class LevelTurn(Maneuver):
    """A steady level turn under the altitude/speed hold and the bank hold: the heading change
    that lets the data compatibility tell an airspeed scale or bias from a steady wind (a full
    circle makes a constant error along the track orthogonal to any steady wind).

    Parameters
    ----------
    bank_deg : float
        Bank angle of the turn, positive right [deg].
    heading_deg : float
        Heading change the turn aims at [deg]: the time at full bank follows from the trimmed
        airspeed, ``g tan(bank) / V`` of turn rate (:meth:`at_trim`).
    roll_s : float
        Roll-in and roll-out, each a ramp of the bank command [s].
    turn_s : float
        Time at the full bank [s]; 0 (the default): from ``heading_deg`` at the trimmed speed.
    lead_s, tail_s : float
        Wings-level flight before the roll-in and after the roll-out [s].
    """

    name = "level_turn"
    bank_deg: float = 25.0
    heading_deg: float = 360.0
    roll_s: float = 5.0
    turn_s: float = 0.0
    lead_s: float = 2.0
    tail_s: float = 5.0

    def __post_init__(self) -> None:
        if not 0.0 < abs(self.bank_deg) <= 25.0:
            raise ValueError(
                f"bank_deg must be within 0 < |bank| <= 25 deg (the envelope stops at 30), not {self.bank_deg!r}"
            )
        if not 0.0 < self.heading_deg <= 720.0:
            raise ValueError(f"heading_deg must be within 0 < heading <= 720 deg, not {self.heading_deg!r}")
        if self.roll_s <= 0 or self.turn_s < 0:
            raise ValueError("roll_s must be > 0 and turn_s >= 0")

    def at_trim(self, tas_fps: float, gravity_fps2: float) -> "LevelTurn":
        if self.turn_s:
            return self
        rate = gravity_fps2 * np.tan(np.radians(abs(self.bank_deg))) / tas_fps  # [rad/s]
        # each ramp turns about half as much as its time at full bank would
        return replace(self, turn_s=max(np.radians(self.heading_deg) / rate - self.roll_s, 1.0))

    def program(self, dt: float, amplitude_scale: float = 1.0) -> Program:
        if not self.turn_s:
            raise ValueError("level_turn: the time at full bank is set from the trim (at_trim) or by turn_s")
        lead, roll, turn, tail = (_steps(x, dt) for x in (self.lead_s, self.roll_s, self.turn_s, self.tail_s))
        k = np.arange(lead + 2 * roll + turn + tail, dtype=float)
        up = np.clip((k - lead) / roll, 0.0, 1.0)
        down = np.clip((k - lead - roll - turn) / roll, 0.0, 1.0)
        bank = Sampled(tuple(self.bank_deg * (up - down)))
        return Program(Constant(0.0), Constant(0.0), None, True, len(k), None, len(k), bank_deg=bank)


@dataclass(frozen=True)
class Deceleration(Maneuver):
    """A level deceleration: the throttle eased back while the altitude hold flies the elevator, so that
    the speed decays and alpha rises with it (alpha and Mach move together: a stall approach, a speed
    sweep). The elevator hold is the gear transitions' (:class:`maneuvers.autopilot.HoldAutopilot`); the
    speed loop is off.

    Parameters
    ----------
    throttle_cut : float
        How far the throttle comes back from the trim, over ``ramp_s``, then held [-] (at most to idle).
    lead_s : float
        Trimmed flight before the throttle moves [s].
    ramp_s : float
        The throttle's ramp [s].
    duration_s : float
        Flight after the ramp [s].
    """

    name = "deceleration"
    throttle_cut: float = 0.3
    lead_s: float = 2.0
    ramp_s: float = 2.0
    duration_s: float = 40.0

    def __post_init__(self) -> None:
        if not 0.0 < self.throttle_cut <= 1.0:
            raise ValueError(f"throttle_cut must be within 0 < cut <= 1, not {self.throttle_cut!r}")
        if self.lead_s < 0 or self.ramp_s <= 0 or self.duration_s <= 0:
            raise ValueError("lead_s must be >= 0, ramp_s and duration_s > 0")

    def program(self, dt: float, amplitude_scale: float = 1.0) -> Program:
        lead, ramp, rest = (_steps(x, dt) for x in (self.lead_s, self.ramp_s, self.duration_s))
        k = np.arange(lead + ramp + rest, dtype=float)
        throttle = Sampled(tuple(-self.throttle_cut * np.clip((k - lead) / ramp, 0.0, 1.0)))
        return Program(Constant(0.0), Constant(0.0), None, True, len(k), None, len(k), throttle=throttle)


MANEUVERS: dict[str, type[Maneuver]] = {
    "doublet": Doublet2311,
    "multisine": Multisine,
    "gear_extension": GearTransition,
    "gear_retraction": GearTransition,
    "level_turn": LevelTurn,
    "deceleration": Deceleration,
}


def maneuver_parameters(name: str) -> set[str]:
    """Names of the parameters a manoeuvre accepts (for matrix validation)."""
    cls = MANEUVERS[name]
    return {f.name for f in fields(cls)} - {"name", "direction"}


def make_maneuver(name: str, **params) -> Maneuver:
    """Build a manoeuvre by its matrix name with optional parameters."""
    if name not in MANEUVERS:
        raise KeyError(name)
    if name == "gear_extension":
        return GearTransition(direction="extend", **params)
    if name == "gear_retraction":
        return GearTransition(direction="retract", **params)
    return MANEUVERS[name](**params)
