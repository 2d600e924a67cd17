"""What the flight side asks the vehicle to stream, and the latest of it: one link's view of the vehicle.

ArduPilot streams nothing on a fresh link (its stream rates default to 0, and SCALED_IMU/HIGHRES_IMU belong to no
stream group); PX4 streams a profile. Both answer MAV_CMD_SET_MESSAGE_INTERVAL, which sets one message's rate on
the link it arrived on, so the flight side asks for exactly what it reads, on its own link.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mav

from ..errors import BadInput

IMU_HZ = 50.0
# the rates asked for: message name -> Hz of vehicle time
STREAMS_HZ = {
    "HIGHRES_IMU": IMU_HZ,          # float m/s^2 and rad/s: SCALED_IMU's 1 mrad/s steps hide a drifting gyro
    "ATTITUDE": IMU_HZ,             # the autopilot's attitude and its bias-corrected rates (gyro bias, in the hover)
    "LOCAL_POSITION_NED": 10.0,     # the autopilot's position and velocity: obedience, geofence, start velocity
    "GLOBAL_POSITION_INT": 5.0,     # height above home
    "EXTENDED_SYS_STATE": 2.0,      # landed or in the air
}
# asked for too, but a vehicle may refuse them: whether the autopilot has a GPS fix (without one, the maneuver is
# flown on attitude targets: mavlink_pilot)
OPTIONAL_STREAMS_HZ = {"GPS_RAW_INT": 2.0}
IMU_FALLBACK = "SCALED_IMU"         # for a vehicle that refuses HIGHRES_IMU (mG, mrad/s)
MSG_ID = {name: getattr(mav, f"MAVLINK_MSG_ID_{name}") for name in (*STREAMS_HZ, *OPTIONAL_STREAMS_HZ, IMU_FALLBACK)}
GPS_FIX_3D = 3
G_MPS2 = 9.80665


class TelemetryError(BadInput):
    """The vehicle sent a value that cannot be (non-finite)."""


@dataclass
class Telemetry:
    """The latest of each stream, in SI units and vehicle time (boot seconds)."""
    armed: bool | None = None
    custom_mode: int | None = None
    landed_state: int | None = None            # MAV_LANDED_STATE_*; None until EXTENDED_SYS_STATE arrives
    gps_fix_type: int | None = None            # GPS_FIX_TYPE of the autopilot's GPS; None until GPS_RAW_INT arrives
    height_above_home_m: float | None = None
    pos_ned_m: np.ndarray | None = None
    vel_ned_mps: np.ndarray | None = None
    pos_t_s: float | None = None
    attitude_rpy_rad: np.ndarray | None = None
    attitude_rates_rps: np.ndarray | None = None
    attitude_t_s: float | None = None
    last_seen_s: dict = field(default_factory=dict)   # message name -> wall clock (time.monotonic) it last came

    def update(self, msg, now_s: float):
        """Take one message in; returns (t_s, accel_mps2, gyro_rps) for an IMU sample, else None."""
        kind = msg.get_type()
        self.last_seen_s[kind] = now_s
        if kind == "HEARTBEAT":
            self.armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = int(msg.custom_mode)
        elif kind == "EXTENDED_SYS_STATE":
            self.landed_state = int(msg.landed_state)
        elif kind == "GPS_RAW_INT":
            self.gps_fix_type = int(msg.fix_type)
        elif kind == "GLOBAL_POSITION_INT":
            self.height_above_home_m = float(_finite([msg.relative_alt / 1000.0], kind)[0])
        elif kind == "LOCAL_POSITION_NED":
            self.pos_ned_m = _finite([msg.x, msg.y, msg.z], kind)
            self.vel_ned_mps = _finite([msg.vx, msg.vy, msg.vz], kind)
            self.pos_t_s = msg.time_boot_ms / 1000.0
        elif kind == "ATTITUDE":
            self.attitude_rpy_rad = _finite([msg.roll, msg.pitch, msg.yaw], kind)
            self.attitude_rates_rps = _finite([msg.rollspeed, msg.pitchspeed, msg.yawspeed], kind)
            self.attitude_t_s = msg.time_boot_ms / 1000.0
        elif kind == "HIGHRES_IMU":
            return (msg.time_usec / 1e6, _finite([msg.xacc, msg.yacc, msg.zacc], kind),
                    _finite([msg.xgyro, msg.ygyro, msg.zgyro], kind))
        elif kind == "SCALED_IMU":
            return (msg.time_boot_ms / 1000.0, _finite([msg.xacc, msg.yacc, msg.zacc], kind) * (G_MPS2 / 1000.0),
                    _finite([msg.xgyro, msg.ygyro, msg.zgyro], kind) / 1000.0)
        return None

    @property
    def airborne(self) -> bool:
        """In the air by the vehicle's own word (EXTENDED_SYS_STATE), or by its height when it does not say."""
        if self.landed_state not in (None, mav.MAV_LANDED_STATE_UNDEFINED):
            return self.landed_state in (mav.MAV_LANDED_STATE_IN_AIR, mav.MAV_LANDED_STATE_TAKEOFF,
                                         mav.MAV_LANDED_STATE_LANDING)
        return self.height_above_home_m is not None and self.height_above_home_m > 1.0

    @property
    def positioned(self) -> bool:
        """The autopilot has a 3D GPS fix (or does not say: a vehicle that streams no GPS_RAW_INT)."""
        return self.gps_fix_type is None or self.gps_fix_type >= GPS_FIX_3D

    @property
    def heading_rad(self) -> float:
        return float(self.attitude_rpy_rad[2]) if self.attitude_rpy_rad is not None else 0.0

    @property
    def track_heading_rad(self) -> float:
        """The direction of travel (the maneuver must leave its corridor); the heading when hovering."""
        v = self.vel_ned_mps
        if v is None or math.hypot(v[0], v[1]) < 0.5:
            return self.heading_rad
        return math.atan2(v[1], v[0])


def _finite(values, what: str) -> np.ndarray:
    a = np.array(values, dtype=float)
    if not np.all(np.isfinite(a)):
        raise TelemetryError(f"vehicle sent a non-finite {what}")
    return a


def c_nb(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body (FRD) to NED rotation from Euler angles (ZYX)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    """The attitude (ZYX Euler angles) as MAVLink's quaternion [w, x, y, z], the rotation c_nb is the matrix of."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]
