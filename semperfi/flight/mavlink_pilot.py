"""Flies a maneuver over MAVLink as a companion computer commands ArduCopter in GUIDED mode (PX4's OFFBOARD takes the
same SET_POSITION_TARGET_LOCAL_NED stream), and dead-reckons it from the vehicle's own IMU, decoupled from GPS.

Sequence: wait for the vehicle's HEARTBEAT; switch to GUIDED (COMMAND_LONG MAV_CMD_DO_SET_MODE, acknowledged, and
seen in the next HEARTBEAT); stream the maneuver's velocity legs at SETPOINT_HZ of vehicle time (time_boot_ms),
then zero velocity until the vehicle has stopped; give the vehicle back to the mode it was in. The IMU track is the
strapdown integration of SCALED_IMU over the maneuver, from the attitude (ATTITUDE) and the velocity
(LOCAL_POSITION_NED, the autopilot's estimate just before the maneuver, when GPS was still trusted) at its start.
Everything the vehicle sends is checked for being finite; a silent or wrong vehicle is a PilotError after timeout_s.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from .deadreckoning import InsTrack, integrate
from .maneuver import Maneuver

GUIDED = 4
SETPOINT_HZ = 10.0
VELOCITY_ONLY = 0b0000_1101_1100_0111    # type_mask: use vx, vy, vz; ignore position, acceleration, yaw, yaw rate
STOPPED_MPS = 0.2
SETTLE_MAX_S = 6.0
COMMAND_RETRY_S = 1.0                     # a command without an ACK after this is sent again
G_MPS2 = 9.80665


class PilotError(RuntimeError):
    """The vehicle did not answer, refused GUIDED, or sent nonsense."""


@dataclass(frozen=True)
class FlownManeuver:
    ins: InsTrack                  # dead-reckoned from the IMU, relative to the maneuver start (t_s from 0)
    start_time_boot_s: float       # vehicle time of the maneuver start
    reported_ned_m: np.ndarray     # LOCAL_POSITION_NED during the maneuver (the autopilot's view; for the record)
    reported_t_s: np.ndarray


NETWORK_FORMS = ("tcp", "tcpin", "udp", "udpin", "udpout", "udpbcast")


def check_vehicle_url(url: str) -> str:
    """A vehicle address as ArduPilot users type it: tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT (udp: is
    udpin), or a serial device (/dev/ttyACM0, COM3, optionally ,BAUD); ValueError (one line) for anything else."""
    form, _, rest = url.partition(":")
    if form in NETWORK_FORMS:
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"vehicle address {url!r}: expected {form}:HOST:PORT with a port of 1-65535")
        return url
    device, _, baud = url.partition(",")
    if device.startswith("/dev/") or device.upper().startswith("COM"):
        if baud and not (baud.isdigit() and 1200 <= int(baud) <= 4_000_000):
            raise ValueError(f"vehicle address {url!r}: the baud rate after ',' must be 1200 to 4000000")
        try:
            import serial  # noqa: F401 -- pymavlink opens serial ports through pyserial
        except ImportError:
            raise ValueError(f"a serial vehicle ({device}) needs pyserial: pip install pyserial") from None
        return url
    raise ValueError(f"vehicle address {url!r}: expected tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or a "
                     "serial device such as /dev/ttyACM0")


class Pilot:
    def __init__(self, url: str, timeout_s: float = 10.0):
        check_vehicle_url(url)
        self.conn = mavutil.mavlink_connection(url, source_system=250, source_component=191, dialect="common")
        self.timeout_s = timeout_s
        self.target = None

    def close(self) -> None:
        self.conn.close()

    def _recv(self, types, deadline: float):
        while time.monotonic() < deadline:
            try:
                msg = self.conn.recv_match(type=types, blocking=True, timeout=0.1)
            except Exception:   # noqa: BLE001 -- garbage on the wire is skipped, not trusted
                continue
            if msg is not None:
                return msg
        raise PilotError(f"no {types} from the vehicle within {self.timeout_s:g} s")

    def connect(self) -> int:
        """Say hello until the vehicle's HEARTBEAT arrives; returns its custom mode."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            try:
                hb = self._recv("HEARTBEAT", min(deadline, time.monotonic() + 0.5))
                break
            except PilotError:
                if time.monotonic() >= deadline:
                    raise
        self.target = (hb.get_srcSystem(), hb.get_srcComponent())
        return int(hb.custom_mode)

    def set_mode(self, custom_mode: int) -> None:
        """DO_SET_MODE, resent (confirmation counted up) each COMMAND_RETRY_S without an ACK, as the MAVLink command
        protocol has it: a datagram lost on UDP, or drowned in a busy link's telemetry, must not fail the flight."""
        deadline = time.monotonic() + self.timeout_s
        confirmation, ack = 0, None
        while ack is None:
            self.conn.mav.command_long_send(*self.target, mav.MAV_CMD_DO_SET_MODE, min(confirmation, 255),
                                            mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode, 0, 0, 0, 0, 0)
            try:
                ack = self._recv("COMMAND_ACK", min(deadline, time.monotonic() + COMMAND_RETRY_S))
            except PilotError:
                if time.monotonic() >= deadline:
                    raise
            confirmation += 1
        if ack.command != mav.MAV_CMD_DO_SET_MODE or ack.result != mav.MAV_RESULT_ACCEPTED:
            raise PilotError(f"vehicle refused mode {custom_mode} (ack {ack.command}: {ack.result})")
        while self._recv("HEARTBEAT", deadline).custom_mode != custom_mode:
            pass

    def fly(self, maneuver: Maneuver) -> FlownManeuver:
        """Fly the maneuver's legs in GUIDED and return the IMU's track of it."""
        previous = self.connect()
        self.set_mode(GUIDED)
        try:
            return self._fly_legs(maneuver)
        finally:
            self.set_mode(previous)

    def _fly_legs(self, maneuver: Maneuver) -> FlownManeuver:
        ends = np.cumsum([leg.duration_s for leg in maneuver.legs])
        deadline = time.monotonic() + self.timeout_s + 3 * (ends[-1] + SETTLE_MAX_S)
        imu_t, imu_f, imu_w, pos_t, pos = [], [], [], [], []
        start = attitude = vel0 = None
        next_setpoint, stopped_since = 0.0, None
        while True:
            msg = self._recv(["SCALED_IMU", "LOCAL_POSITION_NED", "ATTITUDE"], deadline)
            t_boot = msg.time_boot_ms / 1000.0
            kind = msg.get_type()
            if kind == "ATTITUDE":
                attitude = _finite([msg.roll, msg.pitch, msg.yaw], "ATTITUDE")
                continue
            if kind == "LOCAL_POSITION_NED":
                vel = _finite([msg.vx, msg.vy, msg.vz], "LOCAL_POSITION_NED")
                ned = _finite([msg.x, msg.y, msg.z], "LOCAL_POSITION_NED")
                if start is None:
                    vel0 = vel
                else:
                    pos_t.append(t_boot - start)
                    pos.append(ned)
                    moving = np.linalg.norm(vel) > STOPPED_MPS
                    if t_boot - start > ends[-1]:
                        stopped_since = None if moving else (stopped_since or t_boot)
                        if (stopped_since and t_boot - stopped_since > 0.5) or t_boot - start > ends[-1] + SETTLE_MAX_S:
                            break
                continue
            if start is None:   # SCALED_IMU: the maneuver starts with the first sample once the state is known
                if attitude is None or vel0 is None:
                    continue
                start = t_boot
            t = t_boot - start
            imu_t.append(t)
            imu_f.append(_finite([msg.xacc, msg.yacc, msg.zacc], "SCALED_IMU") * (G_MPS2 / 1000.0))
            imu_w.append(_finite([msg.xgyro, msg.ygyro, msg.zgyro], "SCALED_IMU") / 1000.0)
            if t >= next_setpoint:
                leg = int(np.searchsorted(ends, t, side="right"))
                v = (0.0, 0.0, 0.0) if leg >= len(ends) else \
                    (maneuver.legs[leg].v_north_mps, maneuver.legs[leg].v_east_mps, maneuver.legs[leg].v_down_mps)
                self.conn.mav.set_position_target_local_ned_send(int(t_boot * 1000), *self.target,
                                                                 mav.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY,
                                                                 0, 0, 0, *v, 0, 0, 0, 0, 0)
                next_setpoint += 1.0 / SETPOINT_HZ
        ins = integrate(np.array(imu_t), np.array(imu_f), np.array(imu_w), c_nb0=_c_nb(*attitude), vel0_ned_mps=vel0)
        return FlownManeuver(ins, start, np.array(pos), np.array(pos_t))


def _finite(values, what: str) -> np.ndarray:
    a = np.array(values, dtype=float)
    if not np.all(np.isfinite(a)):
        raise PilotError(f"vehicle sent a non-finite {what}")
    return a


def _c_nb(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body (FRD) to NED rotation from Euler angles (ZYX)."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])
