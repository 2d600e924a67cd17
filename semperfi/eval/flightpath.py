"""A recorded flight for the Adversarial Peak Identifier: hover, a maneuver, hover again -- the receiver's true
trajectory as a 10 Hz motion file (gps-sdr-sim's `-u` format, also our simulator's `receiver.trajectory`), and the
INS-only track a drifting inertial unit would have logged (`semperfi run --imu`).
"""

from pathlib import Path

import numpy as np

from ..flight import Leg, ManeuverLimits, plan_trajectory
from ..gps import enu_rotation, geodetic_to_ecef

MOTION_DT_S = 0.1
# a maneuver within the paper's constraints: about 15 s, ending ~35 m from its start, turning twice
DEFAULT_LEGS = (Leg(3.0, 0.0, 0.0, 4.0), Leg(0.0, 3.0, 0.0, 4.0), Leg(-1.5, 2.5, 0.0, 4.0))


def hover_maneuver_hover(hover_before_s: float, hover_after_s: float, legs=DEFAULT_LEGS):
    """(t_s, ned_m (n, 3)) at MOTION_DT_S: still, then the legs under the acceleration limit, then still."""
    _, north, east, down = plan_trajectory(legs, ManeuverLimits(dt_s=MOTION_DT_S))
    path = np.column_stack([north, east, down])
    before = int(round(hover_before_s / MOTION_DT_S))
    after = int(round(hover_after_s / MOTION_DT_S))
    ned = np.vstack([np.zeros((before, 3)), path, np.repeat(path[-1:], after, axis=0)])
    return np.arange(len(ned)) * MOTION_DT_S, ned


def write_motion_csv(path: Path, t_s: np.ndarray, ned_m: np.ndarray, lat_deg: float, lon_deg: float,
                     height_m: float) -> Path:
    """t_s,x,y,z (ECEF metres) per row: the NED path around a geodetic origin."""
    origin = geodetic_to_ecef(np.radians(lat_deg), np.radians(lon_deg), height_m)
    enu = np.column_stack([ned_m[:, 1], ned_m[:, 0], -ned_m[:, 2]])
    ecef = origin + enu @ enu_rotation(np.radians(lat_deg), np.radians(lon_deg))
    np.savetxt(path, np.column_stack([t_s, ecef]), fmt=["%.1f", "%.4f", "%.4f", "%.4f"], delimiter=",")
    return path


def ins_track(t_s: np.ndarray, ned_m: np.ndarray, seed: int, accel_bias_mps2: float = 0.005,
              velocity_random_walk_mps_rt_s: float = 0.005, origin_m=(120.0, -40.0, 3.0)) -> np.ndarray:
    """What an INS alone would have logged: the truth plus a drift (a constant accelerometer bias per axis, drawn
    with this standard deviation, and a velocity random walk, seeded), from an arbitrary origin. The defaults, a
    MEMS unit's 0.5 mg, drift 1-3 m over a 20 s maneuver after 10 s of hover."""
    rng = np.random.default_rng(seed)
    dt = float(np.median(np.diff(t_s)))
    t = (t_s - t_s[0])[:, None]
    bias = rng.standard_normal(3) * accel_bias_mps2
    walk = np.cumsum(rng.standard_normal(ned_m.shape) * velocity_random_walk_mps_rt_s * np.sqrt(dt), axis=0)
    return ned_m + np.asarray(origin_m) + 0.5 * bias * t ** 2 + np.cumsum(walk * dt, axis=0)
