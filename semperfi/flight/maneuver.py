"""Pseudorandom maneuver for the Adversarial Peak Identifier (paper section 3.3).

The maneuver is drawn from the operating system's cryptographic source (``secrets``) so an attacker cannot
predict it; it is therefore NOT seeded (the one exception to the project's seeding rule).  A maneuver is a
sequence of constant-velocity legs in the local NED frame, flown under an acceleration limit.  Constraints
(paper): at most 20 s, ends at least 30 m from the start, flies under 50 m, not straight (successive legs turn),
and leaves the 20 m wide no-maneuver corridor (10 m each side) around the current track.  Speed, acceleration, geofence
radius and minimum altitude are configurable; draws violating any constraint are rejected and redrawn.
"""
from __future__ import annotations

import math
import secrets
from dataclasses import dataclass

import numpy as np

_SYS = secrets.SystemRandom()


@dataclass(frozen=True)
class ManeuverLimits:
    max_duration_s: float = 20.0
    min_end_distance_m: float = 30.0
    max_path_m: float = 50.0          # the paper's maneuvers stay under 50 m flown
    corridor_half_width_m: float = 10.0
    max_speed_mps: float = 4.0
    max_accel_mps2: float = 2.5
    max_vertical_speed_mps: float = 1.0
    geofence_radius_m: float = 60.0
    min_altitude_m: float = 10.0
    min_turn_deg: float = 30.0
    min_legs: int = 2
    max_legs: int = 4
    dt_s: float = 0.05

    def __post_init__(self):
        if not (0 < self.max_duration_s <= 20.0):
            raise ValueError("max_duration_s must be in (0, 20]")
        if self.max_speed_mps <= 0 or self.max_accel_mps2 <= 0 or self.dt_s <= 0:
            raise ValueError("speed, acceleration and dt must be positive")
        if self.min_legs < 2 or self.max_legs < self.min_legs:
            raise ValueError("need 2 <= min_legs <= max_legs (a maneuver must turn)")
        if self.max_path_m <= self.min_end_distance_m:
            raise ValueError("max_path_m must exceed min_end_distance_m")
        if self.geofence_radius_m <= self.min_end_distance_m:
            raise ValueError("geofence_radius_m must exceed min_end_distance_m")


@dataclass(frozen=True)
class Leg:
    """Commanded velocity (NED, m/s) held for duration_s."""
    v_north_mps: float
    v_east_mps: float
    v_down_mps: float
    duration_s: float


@dataclass(frozen=True)
class Maneuver:
    legs: tuple[Leg, ...]
    t_s: np.ndarray        # planned trajectory under the acceleration limit, relative to the start
    north_m: np.ndarray
    east_m: np.ndarray
    down_m: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    @property
    def end_distance_m(self) -> float:
        return float(math.hypot(self.north_m[-1], self.east_m[-1]))

    @property
    def path_length_m(self) -> float:
        return float(np.sum(np.sqrt(np.diff(self.north_m) ** 2 + np.diff(self.east_m) ** 2
                                    + np.diff(self.down_m) ** 2)))


def plan_trajectory(legs, limits: ManeuverLimits):
    """Integrate the legs' velocity setpoints under the acceleration limit, then brake to a stop."""
    dt = limits.dt_s
    targets = [np.array([leg.v_north_mps, leg.v_east_mps, leg.v_down_mps]) for leg in legs]
    steps = [int(round(leg.duration_s / dt)) for leg in legs]
    v = np.zeros(3)
    p = np.zeros(3)
    out = [p.copy()]
    a_step = limits.max_accel_mps2 * dt

    def step(target):
        nonlocal v, p
        dv = target - v
        n = np.linalg.norm(dv)
        v = target.copy() if n <= a_step else v + dv * (a_step / n)
        p = p + v * dt
        out.append(p.copy())

    for target, n in zip(targets, steps):
        for _ in range(n):
            step(target)
    while np.linalg.norm(v) > 1e-9:
        step(np.zeros(3))
    pos = np.array(out)
    t = np.arange(len(pos)) * dt
    return t, pos[:, 0], pos[:, 1], pos[:, 2]


def check(m: Maneuver, limits: ManeuverLimits, track_heading_rad: float = 0.0,
          altitude_m: float = 50.0) -> list[str]:
    """Return the violated constraints (empty list when the maneuver is admissible)."""
    bad = []
    if m.duration_s > limits.max_duration_s + 1e-9:
        bad.append("duration")
    if m.end_distance_m < limits.min_end_distance_m:
        bad.append("end distance")
    if m.path_length_m > limits.max_path_m:
        bad.append("path length")
    if np.max(np.hypot(m.north_m, m.east_m)) > limits.geofence_radius_m:
        bad.append("geofence")
    if altitude_m - np.max(m.down_m) < limits.min_altitude_m:
        bad.append("altitude")
    # cross-track distance from the current track line (through the start, along the heading)
    cross_m = -m.north_m * math.sin(track_heading_rad) + m.east_m * math.cos(track_heading_rad)
    if np.max(np.abs(cross_m)) <= limits.corridor_half_width_m:
        bad.append("corridor")
    hv = [np.array([leg.v_north_mps, leg.v_east_mps]) for leg in m.legs]
    turned = any(
        np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b) + 1e-12), -1, 1)))
        >= limits.min_turn_deg for a, b in zip(hv, hv[1:]))
    if not turned:
        bad.append("straight")
    speeds = [math.sqrt(leg.v_north_mps ** 2 + leg.v_east_mps ** 2) for leg in m.legs]
    if max(speeds) > limits.max_speed_mps + 1e-9:
        bad.append("speed")
    return bad


def draw(limits: ManeuverLimits = ManeuverLimits(), track_heading_rad: float = 0.0,
         altitude_m: float = 50.0, max_tries: int = 10000) -> Maneuver:
    """Draw an admissible maneuver from the OS cryptographic source."""
    if altitude_m < limits.min_altitude_m:
        raise ValueError("vehicle below the minimum altitude: no vertical room to maneuver")
    for _ in range(max_tries):
        n_legs = _SYS.randint(limits.min_legs, limits.max_legs)
        # leave time to brake: v/a seconds
        budget_s = limits.max_duration_s - limits.max_speed_mps / limits.max_accel_mps2
        cuts = sorted(_SYS.uniform(0.0, 1.0) for _ in range(n_legs - 1))
        fractions = np.diff([0.0, *cuts, 1.0])
        total_s = _SYS.uniform(0.5, 1.0) * budget_s
        legs = []
        for frac in fractions:
            speed = _SYS.uniform(0.5, 1.0) * limits.max_speed_mps
            heading = _SYS.uniform(0.0, 2 * math.pi)
            v_down = _SYS.uniform(-1.0, 1.0) * limits.max_vertical_speed_mps
            dur = round(float(frac * total_s) / limits.dt_s) * limits.dt_s
            if dur < limits.dt_s:
                break
            legs.append(Leg(speed * math.cos(heading), speed * math.sin(heading), v_down, dur))
        if len(legs) != n_legs:
            continue
        t, n, e, d = plan_trajectory(legs, limits)
        m = Maneuver(tuple(legs), t, n, e, d)
        if not check(m, limits, track_heading_rad, altitude_m):
            return m
    raise RuntimeError("no admissible maneuver found: limits too tight")
