"""A simulated multicopter behind a MAVLink endpoint (pymavlink, UDP on loopback), standing in for ArduCopter.

It listens on UDP HOST:PORT and answers the last peer that sent it valid MAVLink (the ground station or companion
computer); every datagram is parsed on its own, so garbage in one cannot swallow the frames of the next. It starts
airborne, armed and holding position (LOITER) at `altitude_m` (or, airborne=False, disarmed on the ground, where it
accepts GUIDED and ignores setpoints, as ArduCopter does); like ArduCopter it obeys SET_POSITION_TARGET_LOCAL_NED
(velocity or position, MAV_FRAME_LOCAL_NED, and the heading when its yaw is not masked; without one it turns to
face its travel) only in GUIDED mode, set with SET_MODE or COMMAND_LONG MAV_CMD_DO_SET_MODE (custom mode 4), and
holds position when velocity setpoints stop for SETPOINT_TIMEOUT_S. Like ArduCopter it sends only HEARTBEAT (1 Hz)
until asked: MAV_CMD_SET_MESSAGE_INTERVAL sets the rate of HIGHRES_IMU, SCALED_IMU (mG, mrad/s), ATTITUDE,
LOCAL_POSITION_NED, GLOBAL_POSITION_INT, EXTENDED_SYS_STATE and GPS_RAW_INT (at most PHYSICS_HZ), all from the true
state and the IMU error model (which tilts, turns and drifts as SITL's does: multicopter.py).

Its GPS can be taken away (`gps_fix_type` below 3), as SemperFi withholds the position from an autopilot while
spoofing is suspected: then, as ArduCopter, it refuses the modes that need a position (GUIDED, LOITER, RTL), its
reported position and velocity are dead-reckoned for NO_GPS_DEAD_RECKONING_S and then frozen (the EKF's constant
position), and GUIDED_NOGPS flies SET_ATTITUDE_TARGET: the tilt gives the acceleration, the thrust is a climb rate
(0.5 none), and without a target for SETPOINT_TIMEOUT_S it holds level.

The other end is assumed hostile: undecodable bytes, bad CRCs, non-finite or out-of-frame setpoints and unknown
commands are counted in `rejected` (and logged), never acted on, and never stop the loop. Time runs `time_scale`
times faster than the wall clock (tests fly a 20 s maneuver in a second or two), slower when the machine is busy;
`time_boot_ms` is vehicle time.
"""

from __future__ import annotations

import collections
import logging
import math
import socket
import struct
import threading
import time

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import common as mav

from semperfi.flight import GRAVITY_NED_MPS2

from .multicopter import ImuErrors, Multicopter, VehicleParams, attitude

log = logging.getLogger(__name__)

PHYSICS_HZ = 50                    # one physics step per IMU sample: the fastest any stream goes
HEARTBEAT_EVERY = 50               # 1 Hz, the one message sent unasked
STREAMABLE = {mav.MAVLINK_MSG_ID_HIGHRES_IMU, mav.MAVLINK_MSG_ID_SCALED_IMU, mav.MAVLINK_MSG_ID_ATTITUDE,
              mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
              mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, mav.MAVLINK_MSG_ID_GPS_RAW_INT}
MODES = {"STABILIZE": 0, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9, "GUIDED_NOGPS": 20}   # ArduCopter's
NEED_POSITION = {MODES["GUIDED"], MODES["LOITER"], MODES["RTL"]}
NO_GPS_DEAD_RECKONING_S = 7.0      # ArduCopter SITL's EKF: then "stopped aiding"
CLIMB_MPS, DESCENT_MPS = 2.5, 1.5  # GUIDED_NOGPS thrust 1 and 0 (WPNAV_SPEED_UP, WPNAV_SPEED_DN)
LEVEL_DRAG_PER_S = 0.3             # a level multicopter slows by drag
SETPOINT_TIMEOUT_S = 3.0           # ArduCopter stops after 3 s without a velocity command
MAX_SPEED_MPS = 10.0
POSITION_GAIN_PER_S = 1.0          # a position setpoint becomes a velocity command toward it
G_MPS2 = 9.80665
_IGNORE_POSITION = 0b111           # type_mask bits 0-2: ignore x, y, z
_IGNORE_VELOCITY = 0b111000        # bits 3-5: ignore vx, vy, vz
_IGNORE_YAW = 0b100_0000_0000      # bit 10


class MavlinkVehicle:
    """Run with `start()` (a thread) or `run(stop_event)`; `close()` stops it."""

    def __init__(self, port: int, host: str = "127.0.0.1", seed: int = 0, origin=(42.3398, -71.0892, 10.0),
                 altitude_m: float = 50.0, heading_rad: float = 0.0, time_scale: float = 1.0,
                 params=VehicleParams(), imu=ImuErrors(), airborne: bool = True):
        if not (0 < time_scale <= 100):
            raise ValueError(f"time_scale must be in (0, 100], got {time_scale}")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.setblocking(False)
        self.peer = None   # where telemetry goes: the last address that sent valid MAVLink
        self.mav = mav.MAVLink(self, srcSystem=1, srcComponent=1)
        self.origin = origin
        self.vehicle = Multicopter(seed, heading_rad, params, imu,
                                   pos_ned_m=(0.0, 0.0, -altitude_m if airborne else 0.0))
        self.time_scale = float(time_scale)
        self.mode = MODES["LOITER"] if airborne else MODES["STABILIZE"]
        self.armed = airborne
        self.on_ground = not airborne          # it never takes off: the flight side must refuse it
        self.every: dict[int, int] = {}        # message id -> physics steps between sends (asked for)
        self.t_s = 0.0
        self._k = 0
        self.rejected = 0
        self.setpoints = 0
        self._target_vel = np.zeros(3)
        self._target_yaw: float | None = None
        self._target_pos: np.ndarray | None = self.vehicle.pos_ned_m.copy()   # LOITER holds where it is
        self._last_setpoint_s = -math.inf
        self.gps_fix_type = 3                  # set below 3 to take the autopilot's GPS away
        self._gps_lost_s: float | None = None
        self._reported = (self.vehicle.pos_ned_m.copy(), np.zeros(3))   # the EKF's view without GPS
        self._attitude_target: tuple[np.ndarray, float] | None = None   # (c_nb, thrust) in GUIDED_NOGPS
        self.attitude_targets = 0
        self.truth = collections.deque(maxlen=600 * PHYSICS_HZ)   # (t_s, position NED), the last 10 min: tests
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- loop --------------------------------------------------------------------------------------------------
    def start(self) -> MavlinkVehicle:
        self._thread = threading.Thread(target=self.run, args=(self._stop,), daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        self.sock.close()

    def write(self, frame: bytes) -> None:
        """pymavlink's output: a frame to the ground station, once there is one."""
        if self.peer is not None:
            try:
                self.sock.sendto(frame, self.peer)
            except OSError:
                pass   # it went away

    def run(self, stop: threading.Event) -> None:
        """Step in (scaled) real time until stop is set. Starved of the CPU, the vehicle's time stalls with its peer's
        rather than racing to catch up: a burst of steps would fly seconds of vehicle time (at x20) on setpoints its
        pilot, starved too, had no turn to update, and flood the pilot's socket."""
        wall0 = time.monotonic()
        step_wall_s = 1.0 / (PHYSICS_HZ * self.time_scale)
        while not stop.is_set():
            self.step()
            lag = wall0 + self.t_s / self.time_scale - time.monotonic()
            if lag > 0:
                time.sleep(lag)
            elif lag < -step_wall_s:
                wall0 -= lag + step_wall_s   # behind by more than a step: the time lost is not made up

    def step(self) -> None:
        """One physics step (1 / PHYSICS_HZ of vehicle time): what came in, the motion, what goes out. The closed
        loop's world calls it as its signal time advances, so the vehicle's time is the signal's."""
        self._receive()
        if self.on_ground:
            accel, gyro = self.vehicle.rest(1.0 / PHYSICS_HZ)
        elif self.mode == MODES["GUIDED_NOGPS"]:
            accel, yaw = self._tilt_command()
            accel, gyro = self.vehicle.step(np.zeros(3), 1.0 / PHYSICS_HZ, yaw, accel_ned_mps2=accel)
        else:
            velocity, yaw = self._command()
            accel, gyro = self.vehicle.step(velocity, 1.0 / PHYSICS_HZ, yaw)
        self._k += 1
        self.t_s = self._k / PHYSICS_HZ
        self.truth.append((self.t_s, self.vehicle.pos_ned_m.copy()))
        self._send(self._k, accel, gyro)

    def _tilt_command(self) -> tuple[np.ndarray, float]:
        """GUIDED_NOGPS: the acceleration the attitude target's tilt gives, the climb rate its thrust asks for (and
        drag); level with no climb once targets stop."""
        v = self.vehicle
        if self._attitude_target is None or self.t_s - self._last_setpoint_s > SETPOINT_TIMEOUT_S:
            c, thrust = attitude(-GRAVITY_NED_MPS2, v.heading_rad), 0.5
        else:
            c, thrust = self._attitude_target
        climb = (thrust - 0.5) * 2 * (CLIMB_MPS if thrust > 0.5 else DESCENT_MPS)
        down = v.params.velocity_gain_per_s * (-climb - v.vel_ned_mps[2])
        along = (G_MPS2 - down) / c[2, 2]          # the thrust whose vertical part gives that
        accel = np.array([-c[0, 2] * along, -c[1, 2] * along, down])
        accel[:2] -= LEVEL_DRAG_PER_S * v.vel_ned_mps[:2]
        return accel, math.atan2(c[1, 0], c[0, 0])

    def _command(self) -> tuple[np.ndarray, float | None]:
        """The velocity and heading the autopilot commands now: the GUIDED velocity (until it times out) or toward
        a position; the heading commanded, else None (face the travel) in GUIDED and the heading held otherwise."""
        v = self.vehicle
        yaw = self._target_yaw if self.mode == MODES["GUIDED"] else v.heading_rad
        if self.mode == MODES["GUIDED"] and self._target_pos is None:
            if self.t_s - self._last_setpoint_s <= SETPOINT_TIMEOUT_S:
                return self._target_vel, yaw
            self._target_pos = v.pos_ned_m.copy()   # hold where the commands stopped
        if self._target_pos is None:
            self._target_pos = v.pos_ned_m.copy()
        cmd = POSITION_GAIN_PER_S * (self._target_pos - v.pos_ned_m)
        speed = np.linalg.norm(cmd)
        return (cmd if speed <= MAX_SPEED_MPS else cmd * (MAX_SPEED_MPS / speed)), yaw

    # -- what comes in -----------------------------------------------------------------------------------------
    def _reject(self, why: str) -> None:
        self.rejected += 1
        log.warning("vehicle: rejected %s", why)

    def _receive(self) -> None:
        for _ in range(1000):   # a flood cannot hold the loop for ever: the rest waits for the next step
            try:
                data, address = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            parser = mav.MAVLink(None)
            parser.robust_parsing = True
            try:
                messages = parser.parse_buffer(data) or []
            except Exception as exc:   # noqa: BLE001 -- a hostile peer's bytes may break the parser in any way
                self._reject(f"undecodable datagram ({type(exc).__name__})")
                continue
            for msg in messages:
                if msg.get_type() == "BAD_DATA":
                    self._reject("bytes that are not MAVLink (or a bad CRC)")
                    continue
                self.peer = address
                kind = msg.get_type()
                if kind == "SET_MODE":
                    self._set_mode(msg.custom_mode)
                elif kind == "COMMAND_LONG":
                    self._command_long(msg)
                elif kind == "SET_POSITION_TARGET_LOCAL_NED":
                    self._setpoint(msg)
                elif kind == "SET_ATTITUDE_TARGET":
                    self._attitude(msg)
            if not messages and data:
                self._reject("a datagram with no complete MAVLink frame")

    def _set_mode(self, custom_mode) -> bool:
        if custom_mode not in MODES.values():
            self._reject(f"mode {custom_mode!r}")
            return False
        if custom_mode in NEED_POSITION and self.gps_fix_type < 3:
            return False   # ArduCopter: "Mode change to GUIDED failed: requires position"
        if custom_mode != self.mode:
            self._target_pos = self.vehicle.pos_ned_m.copy() if custom_mode != MODES["GUIDED"] else None
            self._target_vel = np.zeros(3)
            self._target_yaw = None
            self._attitude_target = None
            self._last_setpoint_s = -math.inf
        self.mode = int(custom_mode)
        return True

    def _command_long(self, msg) -> None:
        if msg.command == mav.MAV_CMD_DO_SET_MODE:
            ok = math.isfinite(msg.param2) and msg.param2 == int(msg.param2) and self._set_mode(int(msg.param2))
        elif msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            # no disarm aloft
            ok = msg.param1 in (0.0, 1.0) and (msg.param1 == 1.0 or self.vehicle.pos_ned_m[2] > -0.5)
            self.armed = self.armed if not ok else msg.param1 == 1.0
        elif msg.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            ok = self._interval(msg.param1, msg.param2)
            if ok is None:
                self._reject(f"an interval for message {msg.param1!r}")
                self.mav.command_ack_send(msg.command, mav.MAV_RESULT_UNSUPPORTED)
                return
        else:
            self._reject(f"command {msg.command}")
            self.mav.command_ack_send(msg.command, mav.MAV_RESULT_UNSUPPORTED)
            return
        self.mav.command_ack_send(msg.command, mav.MAV_RESULT_ACCEPTED if ok else mav.MAV_RESULT_DENIED)

    def _interval(self, msg_id: float, interval_us: float) -> bool | None:
        """A stream's rate: interval_us > 0 sets it (at most PHYSICS_HZ), -1 stops it, 0 is the default (off, as
        ArduPilot's stream rates are); None for a message it cannot send."""
        if not (math.isfinite(msg_id) and int(msg_id) in STREAMABLE and math.isfinite(interval_us)):
            return None
        if interval_us > 0:
            self.every[int(msg_id)] = max(1, int(round(interval_us * 1e-6 * PHYSICS_HZ)))
        elif interval_us in (0, -1):
            self.every.pop(int(msg_id), None)
        else:
            return False
        return True

    def _due(self, k: int, msg_id: int) -> bool:
        every = self.every.get(msg_id)
        return every is not None and k % every == 0

    def _setpoint(self, msg) -> None:
        if self.on_ground:
            return self._reject("setpoint on the ground")   # ArduCopter ignores them until it has taken off
        if self.mode != MODES["GUIDED"] or not self.armed:
            return self._reject("setpoint outside GUIDED mode")
        if msg.coordinate_frame != mav.MAV_FRAME_LOCAL_NED:
            return self._reject(f"setpoint in frame {msg.coordinate_frame}")
        pos = np.array([msg.x, msg.y, msg.z], float)
        vel = np.array([msg.vx, msg.vy, msg.vz], float)
        use_pos, use_vel = not msg.type_mask & _IGNORE_POSITION, not msg.type_mask & _IGNORE_VELOCITY
        if not (use_pos or use_vel) or not np.all(np.isfinite(pos if use_pos else vel)):
            return self._reject("setpoint with nothing usable or a non-finite value")
        yaw = float(msg.yaw)
        self._target_yaw = yaw if not msg.type_mask & _IGNORE_YAW and math.isfinite(yaw) else None
        if use_pos:
            self._target_pos = pos
        else:
            speed = np.linalg.norm(vel)
            self._target_vel = vel if speed <= MAX_SPEED_MPS else vel * (MAX_SPEED_MPS / speed)
            self._target_pos = None
        self._last_setpoint_s = self.t_s
        self.setpoints += 1

    def _attitude(self, msg) -> None:
        if self.on_ground or self.mode != MODES["GUIDED_NOGPS"] or not self.armed:
            return self._reject("attitude target outside GUIDED_NOGPS in the air")
        q = np.array(msg.q, float)
        if not (np.all(np.isfinite(q)) and 0.9 < np.linalg.norm(q) < 1.1 and math.isfinite(msg.thrust)):
            return self._reject("attitude target with a non-finite or non-unit quaternion")
        w, x, y, z = q / np.linalg.norm(q)
        c = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        if c[2, 2] < math.cos(math.radians(45)):
            return self._reject("attitude target tilted beyond 45 deg")
        self._attitude_target = (c, min(1.0, max(0.0, float(msg.thrust))))
        self._last_setpoint_s = self.t_s
        self.attitude_targets += 1

    def _ekf_view(self) -> tuple[np.ndarray, np.ndarray]:
        """The position and velocity the autopilot reports: the truth with GPS; without it, dead-reckoned (true here)
        for NO_GPS_DEAD_RECKONING_S, then frozen with zero velocity."""
        v = self.vehicle
        if self.gps_fix_type >= 3:
            self._gps_lost_s = None
        elif self._gps_lost_s is None:
            self._gps_lost_s = self.t_s
        if self._gps_lost_s is None or self.t_s - self._gps_lost_s < NO_GPS_DEAD_RECKONING_S:
            self._reported = (v.pos_ned_m.copy(), v.vel_ned_mps.copy())
            return self._reported
        return self._reported[0], np.zeros(3)

    # -- what goes out -----------------------------------------------------------------------------------------
    def _send(self, k: int, accel_mps2: np.ndarray, gyro_rps: np.ndarray) -> None:
        m, v = self.mav, self.vehicle
        ms = int(round(self.t_s * 1000))
        try:
            if k % HEARTBEAT_EVERY == 1:
                base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
                m.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.mode,
                                 mav.MAV_STATE_ACTIVE)
            (n, e, _), (vn, ve, vd) = self._ekf_view()
            d = v.pos_ned_m[2]   # the barometer's, with or without GPS
            if self._due(k, mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT):
                lat, lon, alt = pymap3d.ned2geodetic(n, e, d, *self.origin)
                hdg = int(round(math.degrees(v.heading_rad) * 100)) % 36000
                m.global_position_int_send(ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1e3)),
                                           int(round(-d * 1e3)), *(int(round(c * 100)) for c in (vn, ve, vd)), hdg)
            if self._due(k, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED):
                m.local_position_ned_send(ms, n, e, d, vn, ve, vd)
            if self._due(k, mav.MAVLINK_MSG_ID_ATTITUDE):
                m.attitude_send(ms, *v.roll_pitch_yaw_rad, *v.rates_body_rps)   # the autopilot's view: true here
            if self._due(k, mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE):
                m.extended_sys_state_send(mav.MAV_VTOL_STATE_UNDEFINED, mav.MAV_LANDED_STATE_ON_GROUND
                                          if self.on_ground else mav.MAV_LANDED_STATE_IN_AIR)
            if self._due(k, mav.MAVLINK_MSG_ID_GPS_RAW_INT):
                lat, lon, alt = pymap3d.ned2geodetic(*v.pos_ned_m, *self.origin)
                fixed = self.gps_fix_type >= 3
                m.gps_raw_int_send(int(round(self.t_s * 1e6)), self.gps_fix_type, int(round(lat * 1e7)) * fixed,
                                   int(round(lon * 1e7)) * fixed, int(round(alt * 1e3)) * fixed, 80 if fixed else 9999,
                                   120 if fixed else 9999, 0, 0, 12 if fixed else 0)
            if self._due(k, mav.MAVLINK_MSG_ID_HIGHRES_IMU):
                m.highres_imu_send(int(round(self.t_s * 1e6)), *accel_mps2.tolist(), *gyro_rps.tolist(),
                                   0, 0, 0, 0, 0, 0, 0, 0b111111)
            if self._due(k, mav.MAVLINK_MSG_ID_SCALED_IMU):
                acc_mg = np.clip(np.round(accel_mps2 / G_MPS2 * 1000), -32768, 32767).astype(int)
                gyro_mrad = np.clip(np.round(gyro_rps * 1000), -32768, 32767).astype(int)
                m.scaled_imu_send(ms, *acc_mg.tolist(), *gyro_mrad.tolist(), 0, 0, 0, 0)
        except (OSError, struct.error):
            pass   # no ground station yet, or a value out of a field's range (not sent)
