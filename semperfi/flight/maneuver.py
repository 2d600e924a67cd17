"""Pseudorandom maneuver for the Adversarial Peak Identifier (paper section 3.3).

The maneuver is drawn from the operating system's cryptographic source (``secrets``) so an attacker cannot
predict it; the product therefore never seeds it (the one exception to the project's seeding rule: only tests pass
a seeded ``rng``).  A maneuver is a
sequence of constant-velocity legs in the local NED frame, flown under an acceleration limit.  Constraints
(paper): at most 20 s, ends at least 30 m from the start, flies under 50 m, not straight (successive legs turn),
and leaves the 20 m wide no-maneuver corridor (10 m each side) around the current track.  Speed, acceleration, geofence
radius and altitude band are configurable; draws violating any constraint are rejected and redrawn.

Given the lines of sight of the satellites the receiver asks about, a draw is also rejected unless it moves the
vehicle far enough along every one of them for the identifier to decide its peaks (required_spread_m, which the
receiver sends with its alarm); after max_tries shapes without one, the draw whose weakest line of sight moved most
is flown.
"""
from __future__ import annotations

import math
import secrets
from dataclasses import dataclass

import numpy as np

_SYS = secrets.SystemRandom()
TURNS = 36   # headings each drawn shape is tried at (and flipped up/down): the draw is alike at every heading
_HEADING_DEPENDENT = {"corridor", "altitude"}   # the only constraints turning or flipping a shape can change


@dataclass(frozen=True)
class ManeuverLimits:
    max_duration_s: float = 20.0
    min_end_distance_m: float = 30.0
    max_path_m: float = 50.0          # the paper's maneuvers stay under 50 m flown
    corridor_half_width_m: float = 10.0
    max_speed_mps: float = 4.0
    max_accel_mps2: float = 2.5
    # a satellite near the zenith sees only vertical motion: a 15 m climb spreads 15/sqrt(12) = 4.3 m along it, 10 s
    # at 1.5 m/s (ArduCopter's default descent rate, under its climb rate); at 1 m/s only the whole maneuver would do
    max_vertical_speed_mps: float = 1.5
    geofence_radius_m: float = 60.0
    min_altitude_m: float = 10.0
    max_altitude_m: float = 120.0     # the usual ceiling for small unmanned aircraft
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
        if self.max_altitude_m <= self.min_altitude_m:
            raise ValueError("max_altitude_m must exceed min_altitude_m")


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
    dt, a_step = limits.dt_s, limits.max_accel_mps2 * limits.dt_s
    v = np.zeros(3)
    velocities = [np.zeros((0, 3))]
    for leg in legs:
        target = np.array([leg.v_north_mps, leg.v_east_mps, leg.v_down_mps])
        ramp = _ramp(v, target, a_step, int(round(leg.duration_s / dt)))
        velocities.append(ramp)
        v = ramp[-1] if len(ramp) else v
    velocities.append(_ramp(v, np.zeros(3), a_step))
    pos = np.vstack([np.zeros((1, 3)), np.cumsum(np.vstack(velocities) * dt, axis=0)])
    t = np.arange(len(pos)) * dt
    return t, pos[:, 0], pos[:, 1], pos[:, 2]


def _ramp(v0: np.ndarray, target: np.ndarray, a_step: float, steps: int | None = None) -> np.ndarray:
    """The velocity at each step moving straight from v0 to target, by a_step a step at most, for `steps` steps
    (None: until it is reached)."""
    gap = float(np.linalg.norm(target - v0))
    if steps is None:
        steps = max(0, math.ceil((gap - 1e-9) / a_step))
    reached = np.minimum(np.arange(1, steps + 1) * a_step / gap, 1.0) if gap > 0 else np.ones(steps)
    return v0 + reached[:, None] * (target - v0)


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
    if altitude_m - np.max(m.down_m) < limits.min_altitude_m or altitude_m - np.min(m.down_m) > limits.max_altitude_m:
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


def unit_ned(az_deg: float, el_deg: float) -> np.ndarray:
    """The unit line of sight (NED) to a satellite at this azimuth and elevation."""
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])


def spread_m(m: Maneuver, lines_of_sight) -> np.ndarray:
    """The rms about its mean of the maneuver's displacement along each unit line of sight (..., 3): what the
    identifier's signature will see of it."""
    u = np.asarray(lines_of_sight, float)
    u = u.reshape(-1, 3) if u.ndim < 2 else u
    return np.sqrt(np.maximum(np.einsum("...i,ij,...j->...", u, _covariance(m), u), 0.0))


def _covariance(m: Maneuver) -> np.ndarray:
    p = np.column_stack([m.north_m, m.east_m, m.down_m])
    p = p - p.mean(axis=0)
    return p.T @ p / len(p)


def _turned(m: Maneuver, heading_rad: float, flip: int) -> Maneuver:
    """The same maneuver turned by heading_rad about the vertical, and upside down if flip is -1."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    legs = tuple(Leg(c * leg.v_north_mps - s * leg.v_east_mps, s * leg.v_north_mps + c * leg.v_east_mps,
                     flip * leg.v_down_mps, leg.duration_s) for leg in m.legs)
    return Maneuver(legs, m.t_s, c * m.north_m - s * m.east_m, s * m.north_m + c * m.east_m, flip * m.down_m)


def _weakest_spreads_m(m: Maneuver, u: np.ndarray, headings_rad: np.ndarray) -> np.ndarray:
    """The smallest spread over the lines of sight u of the maneuver turned by each heading, upright then upside down
    (2 x len(headings_rad)): the lines of sight are turned back instead, the maneuver planned once."""
    if not len(u):
        return np.full(2 * len(headings_rad), np.inf)
    c, s = np.cos(headings_rad)[:, None], np.sin(headings_rad)[:, None]
    north, east = c * u[:, 0] + s * u[:, 1], -s * u[:, 0] + c * u[:, 1]
    seen = [np.stack([north, east, np.broadcast_to(flip * u[:, 2], north.shape)], axis=-1) for flip in (1, -1)]
    return spread_m(m, np.concatenate(seen)).min(axis=1)


def _shape(rng, limits: ManeuverLimits) -> Maneuver | None:
    """Random legs planned under the limits (None: a leg came out shorter than a step)."""
    n_legs = rng.randint(limits.min_legs, limits.max_legs)
    # leave time to brake: v/a seconds
    budget_s = limits.max_duration_s - limits.max_speed_mps / limits.max_accel_mps2
    cuts = sorted(rng.uniform(0.0, 1.0) for _ in range(n_legs - 1))
    fractions = np.diff([0.0, *cuts, 1.0])
    total_s = rng.uniform(0.5, 1.0) * budget_s
    legs = []
    for frac in fractions:
        speed = rng.uniform(0.5, 1.0) * limits.max_speed_mps
        heading = rng.uniform(0.0, 2 * math.pi)
        v_down = rng.uniform(-1.0, 1.0) * limits.max_vertical_speed_mps
        dur = round(float(frac * total_s) / limits.dt_s) * limits.dt_s
        if dur < limits.dt_s:
            return None
        legs.append(Leg(speed * math.cos(heading), speed * math.sin(heading), v_down, dur))
    return Maneuver(tuple(legs), *plan_trajectory(legs, limits))


def draw(limits: ManeuverLimits = ManeuverLimits(), track_heading_rad: float = 0.0,
         altitude_m: float = 50.0, max_tries: int = 1000, lines_of_sight=(), required_spread_m: float = 0.0,
         rng=None) -> Maneuver:
    """Draw an admissible maneuver from the OS cryptographic source (rng: a random.Random for tests only).

    lines_of_sight: unit vectors (NED) to the satellites the receiver asks about; the maneuver must spread at least
    required_spread_m (the receiver's identifier says how much) along each (spread_m), else after max_tries shapes
    the best one drawn is returned."""
    rng = _SYS if rng is None else rng
    if not limits.min_altitude_m <= altitude_m <= limits.max_altitude_m:
        raise ValueError("vehicle outside the altitude band: no vertical room to maneuver")
    u = np.reshape(np.asarray(lines_of_sight, float), (-1, 3))
    best, best_m = -math.inf, None
    for _ in range(max_tries):
        shape = _shape(rng, limits)
        if shape is None or set(check(shape, limits, track_heading_rad, altitude_m)) - _HEADING_DEPENDENT:
            continue
        # every heading and sense of this shape is as likely a draw as the shape itself: try them in random order
        headings = rng.uniform(0.0, 2 * math.pi) + np.arange(TURNS) * (2 * math.pi / TURNS)
        weakest = _weakest_spreads_m(shape, u, headings)
        for k in sorted(range(len(weakest)), key=lambda _: rng.random()):
            if weakest[k] < required_spread_m and weakest[k] <= best:
                continue
            m = _turned(shape, float(headings[k % TURNS]), 1 if k < TURNS else -1)
            if check(m, limits, track_heading_rad, altitude_m):
                continue
            if weakest[k] >= required_spread_m:
                return m
            best, best_m = weakest[k], m
    if best_m is None:
        raise RuntimeError("no admissible maneuver found: limits too tight")
    return best_m
