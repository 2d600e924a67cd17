"""The attacker's plan: what position it claims, when, with what power and timing, for which PRNs."""

from dataclasses import dataclass

import numpy as np

from ..gps import ecef_to_geodetic, enu_rotation


@dataclass(frozen=True)
class AttackPlan:
    mode: str                    # static | push | takeover | meaconing | time_push
    start_s: float
    power_advantage_db: float
    prns: tuple[int, ...]        # empty = all visible at the claimed position
    offset_enu_m: np.ndarray     # static offset / meaconer position, relative to the victim's start position
    push_speed_m_s: float
    push_direction_enu: np.ndarray
    push_hold_s: float
    max_offset_m: float
    power_ramp_s: float
    ramp_start_db: float
    time_offset_s: float         # delay common to every spoofed signal (meaconing: the replay delay)
    altered_clock_s: float       # added to the broadcast satellite clock when the attacker alters the data
    carrier_offset_hz: float
    aligned: bool                # seamless takeover: code, Doppler and carrier start on the legitimate twin
    time_push_rate_s_s: float = 0.0  # time_push: the common delay grows this fast (s/s) after push_hold_s
    time_push_ramp_s: float = 0.0    # time_push: seconds over which the rate grows from 0 to time_push_rate_s_s

    @classmethod
    def from_config(cls, a: dict) -> "AttackPlan":
        az = np.radians(a["push_azimuth_deg"])
        mode = a["mode"]
        seamless = mode in ("takeover", "time_push")
        return cls(
            mode=mode, start_s=a["start_s"], power_advantage_db=a["power_advantage_db"], prns=tuple(a["prns"]),
            offset_enu_m=np.array([a["offset_east_m"], a["offset_north_m"], a["offset_up_m"]], dtype=np.float64),
            push_speed_m_s=a["push_speed_m_s"], push_direction_enu=np.array([np.sin(az), np.cos(az), 0.0]),
            push_hold_s=a["push_hold_s"] if seamless else 0.0, max_offset_m=a["max_offset_m"],
            power_ramp_s=a["power_ramp_s"] if seamless else 0.0, ramp_start_db=a["ramp_start_db"],
            time_offset_s={"takeover": 0.0, "time_push": 0.0, "meaconing": a["delay_s"]}.get(mode, a["time_offset_s"]),
            altered_clock_s=a["altered_clock_s"] if a["nav_data"] == "altered" else 0.0,
            carrier_offset_hz=a["carrier_offset_hz"], aligned=seamless,
            time_push_rate_s_s=a["time_push_rate_s_s"] if mode == "time_push" else 0.0,
            time_push_ramp_s=a["time_push_ramp_s"] if mode == "time_push" else 0.0)

    def active(self, t_s: float) -> bool:
        return t_s >= self.start_s

    def advantage_db(self, t_s: float) -> float:
        """Spoofer power over the legitimate signal at t_s (ramped during a takeover)."""
        if self.power_ramp_s <= 0:
            return self.power_advantage_db
        frac = np.clip((t_s - self.start_s) / self.power_ramp_s, 0.0, 1.0)
        return float(self.ramp_start_db + frac * (self.power_advantage_db - self.ramp_start_db))

    def drag_m(self, t_s: float) -> float:
        """How far a push or takeover has dragged the claimed position from the truth."""
        return float(min(self.push_speed_m_s * max(0.0, t_s - self.start_s - self.push_hold_s), self.max_offset_m))

    def delay_s(self, t_s: float) -> float:
        """The delay common to every spoofed signal at t_s. A time push (TEXBAT's): a sample-aligned copy of the sky,
        code and carrier delayed together by rate * (t - start - hold) -- every pseudorange grows alike, the position
        stays and the victim's clock bias walks -- until the delay reaches max_offset_m / c. With a ramp-in the rate
        grows linearly over time_push_ramp_s (a carrier frequency that slides rather than steps: tracking loops
        follow it, a 40 Hz step at 25 ns/s would break their lock)."""
        if self.mode != "time_push":
            return self.time_offset_s
        tau, ramp = max(0.0, t_s - self.start_s - self.push_hold_s), self.time_push_ramp_s
        pushed = self.time_push_rate_s_s * (tau - ramp / 2.0 if tau >= ramp else tau * tau / (2.0 * ramp))
        return self.time_offset_s + min(pushed, self.max_offset_m / 299792458.0)

    def claimed_position(self, t_s: float, true_pos_ecef_m: np.ndarray, start_pos_ecef_m: np.ndarray) -> np.ndarray:
        """The position the spoofed signals are rendered for (meaconing: the meaconer's antenna)."""
        lat, lon, _ = ecef_to_geodetic(start_pos_ecef_m)
        enu_to_ecef = enu_rotation(float(lat), float(lon)).T
        if self.mode == "time_push":
            return true_pos_ecef_m
        if self.mode in ("static", "meaconing"):
            return start_pos_ecef_m + enu_to_ecef @ self.offset_enu_m
        return true_pos_ecef_m + enu_to_ecef @ (self.push_direction_enu * self.drag_m(t_s))
