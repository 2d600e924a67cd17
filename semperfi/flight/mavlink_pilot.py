"""Flies a maneuver over MAVLink as a companion computer commands ArduCopter in GUIDED mode (PX4's OFFBOARD takes the
same SET_POSITION_TARGET_LOCAL_NED stream), and dead-reckons it from the vehicle's own IMU, decoupled from GPS.

When the autopilot has no GPS fix (GPS_RAW_INT: SemperFi, its GPS, withholds the position while spoofing is
suspected), GUIDED is no place to be: ArduCopter's EKF dead-reckons ~7 s and then its EKF failsafe lands the vehicle
(measured on SITL, which aborted the maneuver). Then the maneuver is flown in GUIDED_NOGPS, which needs no position:
SET_ATTITUDE_TARGET (thrust 0.5: hold the barometric altitude) on a velocity loop the flight side closes on its own
strapdown INS, started from the hover's biases at the maneuver start; the hovers hold the attitude level. After
the maneuver the vehicle is held level until the autopilot has a position again (regain), then given back.

Sequence: wait for the vehicle's HEARTBEAT; ask for the streams it reads (telemetry.STREAMS_HZ, on this link);
refuse a vehicle that is disarmed, on the ground or too low (prepare); switch to GUIDED (acknowledged, and seen in a
HEARTBEAT); hover HOVER_S with the heading held, measuring the IMU's biases (deadreckoning.hover_bias); stream the
maneuver's velocity legs at SETPOINT_HZ of vehicle time with the heading still held (ArduCopter otherwise turns to
face its travel); zero velocity until the vehicle has stopped; hover again to see how the gyro's bias drifted; give
the vehicle back to the mode it was in.
Throughout, the vehicle must stay armed, in GUIDED, above the safe height, inside the geofence, and follow the
setpoints; when it does not, the maneuver is aborted (ManeuverAborted, one line): zero velocity and the previous
mode back (unless a pilot or a failsafe took the vehicle out of GUIDED: theirs stands).
The IMU track is the strapdown integration of the maneuver's IMU samples from the autopilot's attitude and velocity
at its start, its biases taken off.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from ..address import parse_address
from ..errors import BadInput
from .deadreckoning import (HoverBias, InsTrack, Strapdown, bias_between, hover_bias, integrate,
                            track_error_bound_m)
from .maneuver import Maneuver, ManeuverLimits
from .telemetry import (G_MPS2, IMU_FALLBACK, MSG_ID, OPTIONAL_STREAMS_HZ, STREAMS_HZ, Telemetry, TelemetryError,
                        c_nb, quaternion)

GUIDED = 4
GUIDED_NOGPS = 20
LAND = 9
MODE_NAMES = {GUIDED: "GUIDED", GUIDED_NOGPS: "GUIDED_NOGPS"}
SETPOINT_HZ = 10.0
VELOCITY_AND_YAW = 0b0000_1001_1100_0111  # type_mask: use vx, vy, vz and yaw; ignore position, accel, yaw rate
ATTITUDE_ONLY = 0b0000_0111               # SET_ATTITUDE_TARGET type_mask: ignore the body rates
ATTITUDE_HZ = 25.0
# the velocity loop closed on the INS in GUIDED_NOGPS: acceleration = gain x velocity error + integral gain x its
# integral (a level multicopter is slowed by drag: without it SITL flew 8-12 m short of a 15 s plan), under a tilt
# limit
VELOCITY_GAIN_PER_S = 1.0
VELOCITY_INTEGRAL_GAIN_PER_S2 = 0.4
INTEGRAL_MAX_MPS2 = 1.5
INTEGRATE_BELOW_MPS = 1.0
MAX_TILT_ACCEL_MPS2 = 3.0                 # ~17 deg
# ArduCopter's thrust in GUIDED_NOGPS is a climb rate: 0.5 none, 1 WPNAV_SPEED_UP, 0 WPNAV_SPEED_DN (their defaults)
CLIMB_MPS, DESCENT_MPS = 2.5, 1.5
REGAIN_TRY_S = 1.0                        # how often the mode before the maneuver is asked for again (regain)
# What the link heard lately is kept (a reader thread takes every message in, whether or not anyone waits for it), so
# that when the autopilot loses its GPS the flight side still has the last GPS-aided seconds to calibrate by.
INBOX_MAX = 8000                          # messages not yet taken (~60 s of the streams asked for)
HISTORY_S = 45.0                          # the IMU, attitude, position and GPS state kept, vehicle time
# calibration before the GPS was lost: two windows of the GPS-aided flight, CAL_WINDOW_S each, their mid-times
# CAL_SPAN_S apart (the gyro's drift between them), ending CAL_MARGIN_S before the first report of no fix (a takeover
# drags the fix for up to a second before SemperFi alarms: ArduCopter SITL, +3 dB at 10 m/s, alarmed 0.5-0.7 s into
# the drag; its EKF's velocity is the INS's start)
CAL_WINDOW_S = 5.0
CAL_SPAN_S = 15.0
CAL_MARGIN_S = 2.0
DRIFT_TURNED_RPS2 = 1e-5                  # the drift between the windows changed this much: it is no line
# a drift read from two windows beyond this is the windows' error (a takeoff's, a climb's), not the gyro's: SITL's
# drifts by 0.025 mrad/s^2 at most; read across a climb, 1.2 mrad/s^2 put an INS 50 m off and aborted a maneuver
DRIFT_MAX_RPS2 = 1e-4
OUTAGE_S = 1.5                            # a GPS back within this is no outage to fly a maneuver without GPS in
HOVER_S = 3.0                             # the bias-measuring hovers before and after the maneuver (vehicle time)
HOVER_MAX_SPEED_MPS = 1.0                 # a vehicle drifting faster than this in a zero-velocity hover disobeys
STILL_MPS = 0.5                           # the hover starts once the vehicle has been this slow for STILL_S
STILL_S = 0.5
STOPPED_MPS = 0.2
SETTLE_MAX_S = 6.0
# Without GPS the autopilot's velocity is its EKF's dead reckoning, good for a few seconds: ArduCopter SITL stopped
# aiding 7-15 s after the loss, and its velocity then read 2.9 m/s on a vehicle held level (a second maneuver after
# an aborted one: "does not hold still", twice). Beyond AUTOPILOT_DR_S it is not used: the vehicle is held level
# LEVEL_SETTLE_S (its drag stops it; no wind in the model) and taken as still for the hover's calibration.
AUTOPILOT_DR_S = 5.0
LEVEL_SETTLE_S = 8.0
HOVER_TRIES = 3                           # a hover stirred up (a gust; the EKF correcting itself as GPS comes back:
                                          # measured on ArduCopter SITL) is settled and tried again this often
COMMAND_RETRY_S = 1.0                     # a command without an ACK after this is sent again
OBEY_TOLERANCE_MPS = 1.5                  # reported velocity this far from the plan's ...
OBEY_GRACE_S = 2.0                        # ... for this long (vehicle time) is disobedience
# In GUIDED_NOGPS the velocity loop is the flight side's own, on its INS, under its tilt limit: where it lags the plan
# (ArduCopter SITL at x1: 1.6-4.0 m/s off for 4 s, three maneuvers of one flight aborted, the vehicle landed) the
# autopilot has not disobeyed, and the INS track still holds the motion flown, which is what the identifier compares.
# What the autopilot is asked there is an attitude: it disobeys when its reported tilt stays off the target's.
OBEY_TILT_TOLERANCE_RAD = math.radians(8.0)
HEIGHT_MARGIN_M = 2.0                     # below the limits' minimum height by this much: abort


class PilotError(BadInput):
    """The vehicle did not answer, refused, is not fit to maneuver, or sent nonsense."""


class Restless(PilotError):
    """The vehicle moved in a hover that was to hold it still."""


class ManeuverAborted(PilotError):
    """The maneuver was stopped part-way (the vehicle given back to its mode); the reason is the message."""


@dataclass(frozen=True)
class VehicleStatus:
    """What a maneuver is drawn for."""
    height_above_home_m: float
    heading_rad: float
    track_heading_rad: float
    custom_mode: int


@dataclass(frozen=True)
class FlownManeuver:
    ins: InsTrack                  # dead-reckoned from the IMU, relative to the maneuver start (t_s from 0)
    start_time_boot_s: float       # vehicle time of the maneuver start
    reported_ned_m: np.ndarray     # LOCAL_POSITION_NED during the maneuver (the autopilot's view; for the record)
    reported_t_s: np.ndarray
    bias: HoverBias                # what the hover measured and the track took off
    without_gps: bool = False      # flown in GUIDED_NOGPS: the autopilot had no GPS fix
    bound_without_gps: bool = False    # its biases measured in a hover without GPS: the looser error bound
    ins_age_s: float = 0.0         # how long the INS had run at the start (started before the GPS was lost)

    @property
    def error_bound_m(self) -> float:
        """How far the track may be from the truth at its end, both from the maneuver's start
        (deadreckoning.track_error_bound_m)."""
        return track_error_bound_m(float(self.ins.t_s[-1] - self.ins.t_s[0]), self.ins_age_s, self.bound_without_gps,
                                   drift_carried=self.ins_age_s > 0)


def check_vehicle_url(url: str) -> str:
    """A vehicle address as ArduPilot users type it (address.parse_address); ValueError (one line) otherwise."""
    parse_address(url, "vehicle address")
    return url


class Pilot:
    """One MAVLink link to one vehicle. timeout_s bounds every wait for an answer and every silence of a stream."""

    def __init__(self, url: str, timeout_s: float = 10.0, limits: ManeuverLimits | None = None):
        check_vehicle_url(url)
        try:
            self.conn = mavutil.mavlink_connection(url, source_system=250, source_component=191, dialect="common")
        except Exception as exc:   # noqa: BLE001 -- pymavlink raises anything from a refused TCP connect on
            raise PilotError(f"cannot open {url}: {exc}") from None
        self.timeout_s = timeout_s
        self.limits = limits or ManeuverLimits()
        self.target = None
        self.imu_stream = "HIGHRES_IMU"
        self.tm = Telemetry()
        self._imu: list = []        # (t_s, accel, gyro) as they come, while recording
        self._att: list = []        # (t_s, rpy, rates)
        self._pos: list = []        # (t_s, ned, vel)
        self._recording = False
        n = int(HISTORY_S * max(STREAMS_HZ.values()) * 1.2)
        self._history = {"imu": collections.deque(maxlen=n), "att": collections.deque(maxlen=n),
                         "pos": collections.deque(maxlen=n), "gps": collections.deque(maxlen=n)}
        self._inbox: collections.deque = collections.deque(maxlen=INBOX_MAX)
        self._arrived = threading.Condition()
        self._closing = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self._asked = False
        self._optional: set = set()
        self._watcher: threading.Thread | None = None
        self.flying_mode = GUIDED   # GUIDED_NOGPS when the autopilot has no GPS fix (fly)
        self.return_mode: int | None = None   # the mode to give back once the autopilot has a position (regain)
        self._held_since_s: float | None = None   # vehicle time the hold after the last maneuver began (regain)
        self._unaided = False   # flying without GPS past the autopilot's dead reckoning (AUTOPILOT_DR_S)
        self._ins: Strapdown | None = None    # steering in GUIDED_NOGPS, from the maneuver start
        self._steer_integral = np.zeros(2)    # the velocity loop's integral, and when it was last updated
        self._steered_s: float | None = None
        self._asked_tilt_rad: tuple[float, float] | None = None   # the last attitude target's (roll, pitch)
        self._ins_p0 = np.zeros(3)
        self._ins_log: list = []    # (t_s, ned, vel) of the INS, as _pos is of the autopilot

    def close(self) -> None:
        self._closing.set()   # a watcher still connecting gives up at its next message wait
        if self._watcher is not None:
            self._watcher.join(2.0)
        self._reader.join(2.0)
        self.conn.close()

    # -- receiving ---------------------------------------------------------------------------------------------
    def _read(self) -> None:
        """The reader thread: every message into the inbox with its arrival time (the oldest dropped beyond
        INBOX_MAX: what nobody took for a minute is history, not news)."""
        while not self._closing.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.2)
            except Exception:   # noqa: BLE001 -- garbage on the wire is skipped, not trusted; a closed link idles
                time.sleep(0.01)
                continue
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            with self._arrived:
                self._inbox.append((time.monotonic(), msg))
                self._arrived.notify()

    def _next(self, deadline: float, waiting_for: str, since: float):
        """The next message (telemetry updated, IMU and attitude recorded), or PilotError at the deadline, naming
        what was awaited and for how long it truly was."""
        while True:
            now = time.monotonic()
            if now >= deadline or self._closing.is_set():
                raise PilotError(f"no {waiting_for} from the vehicle in {now - since:.1f} s")
            with self._arrived:
                if not self._inbox:
                    self._arrived.wait(min(0.2, deadline - now))
                    continue
                arrived, msg = self._inbox.popleft()
            if self.target is not None and (msg.get_srcSystem() != self.target[0] or (
                    msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() != self.target[1])):
                # another system on the link (a ground station), or a camera's HEARTBEAT, is not the autopilot
                continue
            try:
                imu = self.tm.update(msg, arrived)
            except TelemetryError as exc:
                raise PilotError(str(exc)) from None
            self._keep(self._history, msg, imu)
            if self._recording:
                self._keep({"imu": self._imu, "att": self._att, "pos": self._pos}, msg, imu)
            return msg

    def _catch_up(self) -> None:
        """Take in everything the link heard while nobody waited (the companion between alarms): the telemetry
        and the history then stand as of now, and the next message awaited is a fresh one."""
        with self._arrived:
            backlog = len(self._inbox)
        since = time.monotonic()
        for _ in range(backlog):
            self._next(since + self.timeout_s, "message", since)

    def _keep(self, into: dict, msg, imu) -> None:
        """The message into its list of into (imu, att, pos; gps where there is one): the history, or a flight's
        record."""
        kind = msg.get_type()
        if imu is not None and kind == self.imu_stream:
            if not into["imu"] or imu[0] > into["imu"][-1][0]:   # a repeated timestamp adds nothing
                into["imu"].append(imu)
        elif kind == "ATTITUDE":
            into["att"].append((self.tm.attitude_t_s, self.tm.attitude_rpy_rad, self.tm.attitude_rates_rps))
        elif kind == "LOCAL_POSITION_NED":
            into["pos"].append((self.tm.pos_t_s, self.tm.pos_ned_m, self.tm.vel_ned_mps))
        elif kind == "GPS_RAW_INT" and "gps" in into and self.tm.attitude_t_s is not None:
            into["gps"].append((self.tm.attitude_t_s, self.tm.positioned))   # its own time is not boot time

    def _wait_for(self, kinds, what: str, timeout_s: float | None = None, accept=lambda msg: True):
        since = time.monotonic()
        deadline = since + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            msg = self._next(deadline, what, since)
            if msg.get_type() in kinds and accept(msg):
                return msg

    # -- commands ----------------------------------------------------------------------------------------------
    def connect(self) -> int:
        """Say hello until the vehicle's HEARTBEAT arrives; returns its custom mode."""
        since = time.monotonic()
        deadline = since + self.timeout_s
        while True:
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            try:
                hb = self._next(min(deadline, time.monotonic() + 0.5), "HEARTBEAT", since)
            except PilotError:
                if time.monotonic() >= deadline:
                    raise PilotError(f"no HEARTBEAT from the vehicle in {time.monotonic() - since:.1f} s") from None
                continue
            if hb.get_type() == "HEARTBEAT" and hb.type != mav.MAV_TYPE_GCS:
                break
        self.target = (hb.get_srcSystem(), hb.get_srcComponent())
        return int(hb.custom_mode)

    def command(self, command: int, *params: float) -> int:
        """COMMAND_LONG, resent (confirmation counted up) each COMMAND_RETRY_S without its ACK, as the MAVLink
        command protocol has it; returns the ACK's result."""
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        since = time.monotonic()
        deadline = since + self.timeout_s
        for confirmation in range(256):
            self.conn.mav.command_long_send(*self.target, command, confirmation, *p)
            retry = min(deadline, time.monotonic() + COMMAND_RETRY_S)
            try:
                while True:
                    ack = self._next(retry, "COMMAND_ACK", since)
                    if ack.get_type() == "COMMAND_ACK" and ack.command == command:
                        return int(ack.result)
            except PilotError:
                if time.monotonic() >= deadline:
                    raise PilotError(f"no COMMAND_ACK for command {command} from the vehicle in "
                                     f"{time.monotonic() - since:.1f} s") from None
        raise PilotError(f"command {command} was never acknowledged")

    def watch(self) -> None:
        """Connect and ask for the streams on a thread of its own, waiting for none of them (a vehicle on the
        ground may not stream a position yet): from then on the link's last HISTORY_S are kept, so that a maneuver
        flown after the autopilot lost its GPS is calibrated on the GPS-aided flight before it (the companion
        watches from the start). prepare() waits for it; what it could not do, prepare() does."""
        def connect_and_ask():
            try:
                self.connect()
                self._ask_streams()
            except PilotError:
                pass
        self._watcher = threading.Thread(target=connect_and_ask, daemon=True)
        self._watcher.start()

    def request_streams(self) -> None:
        """SET_MESSAGE_INTERVAL for each stream read (HIGHRES_IMU, or SCALED_IMU from a vehicle refusing it), then
        wait until every one has arrived."""
        self._ask_streams()
        self._await_streams()

    def _ask_streams(self) -> None:
        for name, hz in STREAMS_HZ.items():
            result = self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, MSG_ID[name], 1e6 / hz)
            if result != mav.MAV_RESULT_ACCEPTED and name == "HIGHRES_IMU":
                self.imu_stream = IMU_FALLBACK
                result = self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, MSG_ID[IMU_FALLBACK], 1e6 / hz)
                name = IMU_FALLBACK
            if result != mav.MAV_RESULT_ACCEPTED:
                raise PilotError(f"vehicle refused to stream {name} (MAV_RESULT {result})")
        accepted = mav.MAV_RESULT_ACCEPTED
        self._optional = {name for name, hz in OPTIONAL_STREAMS_HZ.items()
                          if self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, MSG_ID[name], 1e6 / hz) == accepted}
        self._asked = True

    def _await_streams(self) -> None:
        wanted = {self.imu_stream, *(n for n in STREAMS_HZ if n != "HIGHRES_IMU"), *self._optional}
        if not self.tm.positioned:
            wanted.discard("LOCAL_POSITION_NED")   # ArduCopter sends none once its EKF has no position
        asked = time.monotonic()
        seen = set()
        deadline = asked + self.timeout_s
        while not wanted <= seen:
            try:
                seen.add(self._next(deadline, "stream", asked).get_type())
            except PilotError:
                missing = ", ".join(sorted(wanted - seen))
                raise PilotError(f"the vehicle acknowledged but did not stream {missing} in "
                                 f"{time.monotonic() - asked:.1f} s") from None

    def prepare(self) -> VehicleStatus:
        """Connect, ask for the streams and check the vehicle can maneuver: armed, in the air, high enough."""
        if self._watcher is not None:
            self._watcher.join()   # its waits have their deadlines
            self._watcher = None
        self._catch_up()
        if self.target is None:
            self.connect()
        if not self.tm.armed:   # said first: a vehicle on the bench may never stream a position
            raise PilotError("vehicle is disarmed: arm it and take off before a maneuver")
        if not self._asked:
            self._ask_streams()
        self._await_streams()
        self._wait_for({"HEARTBEAT"}, "HEARTBEAT")   # armed state and mode as of now
        tm, low = self.tm, self.limits.min_altitude_m
        if not tm.armed:
            raise PilotError("vehicle is disarmed: arm it and take off before a maneuver")
        if not tm.airborne:
            raise PilotError(f"vehicle is not in the air (landed state {tm.landed_state}, "
                             f"{tm.height_above_home_m:.1f} m above home)")
        if tm.height_above_home_m < low:
            raise PilotError(f"vehicle is {tm.height_above_home_m:.1f} m above home, under the {low:g} m a "
                             "maneuver needs")
        return VehicleStatus(tm.height_above_home_m, tm.heading_rad, tm.track_heading_rad, tm.custom_mode)

    def set_mode(self, custom_mode: int) -> None:
        """DO_SET_MODE, acknowledged and then seen in a HEARTBEAT."""
        result = self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise PilotError(f"vehicle refused mode {custom_mode} (MAV_RESULT {result})")
        self._wait_for({"HEARTBEAT"}, f"HEARTBEAT in mode {custom_mode}",
                       accept=lambda hb: hb.custom_mode == custom_mode)

    # -- flying ------------------------------------------------------------------------------------------------
    def fly(self, maneuver: Maneuver) -> FlownManeuver:
        """Fly the maneuver's legs in GUIDED (GUIDED_NOGPS when the autopilot has no GPS fix) and return the IMU's
        track of it (prepare() first, or here)."""
        if self.target is None:
            self.prepare()
        self._catch_up()
        height = self.tm.height_above_home_m
        lowest = height - float(np.max(maneuver.down_m))
        if lowest < self.limits.min_altitude_m - HEIGHT_MARGIN_M:
            raise PilotError(f"the maneuver would take the vehicle down to {lowest:.1f} m above home")
        previous = self.return_mode if self.return_mode is not None else self.tm.custom_mode
        self.return_mode = self._held_since_s = None   # a hold after an aborted maneuver ends in this one
        self.flying_mode = GUIDED if self._positioned_soon() else GUIDED_NOGPS
        self.set_mode(self.flying_mode)
        try:
            flown = self._fly_legs(maneuver)
        except PilotError as exc:
            self._hold()
            raise ManeuverAborted(f"maneuver aborted: {exc}{self._give_back(previous)}") from None
        finally:
            self._ins = None   # an INS is good for a maneuver, not for holding the vehicle afterwards
        self._give_back(previous)
        return flown

    def _positioned_soon(self) -> bool:
        """Whether the autopilot has its GPS, waiting OUTAGE_S for it to come back: SemperFi withholds a fix for a
        moment when continuity decides at once (ArduCopter SITL, a static attacker: 0.1-1.3 s), and a maneuver
        begun without GPS would then be calibrated on that blink."""
        if self.tm.positioned:
            return True
        # OUTAGE_S of vehicle time (its ATTITUDE's clock): counted on the wall clock, SITL at x5 waited 7.5 s of
        # its time, and the INS, started before the loss, was that much older (tracks 2-10 m off, against 0.1-3.4)
        since = self.tm.attitude_t_s
        self._wait_for({"GPS_RAW_INT", "ATTITUDE"}, "GPS_RAW_INT or ATTITUDE",
                       accept=lambda msg: self.tm.positioned or since is None
                       or self.tm.attitude_t_s - since >= OUTAGE_S)
        return self.tm.positioned

    def _give_back(self, previous: int) -> str:
        """The mode the vehicle was in, unless someone else (a pilot on the radio, a failsafe) has taken it out of
        the flying mode meanwhile: the flight side does not fight them. Returns what was done, for an abort's
        message. A mode that needs a position the autopilot does not have yet is left to regain()."""
        if self.tm.custom_mode != self.flying_mode:
            return f"; left in mode {self.tm.custom_mode}"
        if previous != self.flying_mode:
            try:
                self.set_mode(previous)
            except PilotError as exc:
                if self.flying_mode != GUIDED_NOGPS:
                    return f"; mode {previous} not restored: {exc}"
                self.return_mode = previous
                return f"; held level in GUIDED_NOGPS until the autopilot has a position for mode {previous}"
        return f"; back in mode {previous}"

    def regain(self, timeout_s: float, interrupt=lambda: False) -> bool:
        """After a maneuver flown without a position: hold the vehicle level in GUIDED_NOGPS until the autopilot has
        a GPS fix and takes back the mode it was in (asked each REGAIN_TRY_S); timeout_s after the maneuver (counted
        across calls), LAND (the safe end without a position, as ArduPilot's own failsafe would choose) and
        PilotError. False when interrupt() said to stop holding (the receiver asks for another maneuver), the hold
        not over."""
        if self.return_mode is None:
            return True
        self._imu, self._att, self._pos = [], [], []
        self._recording = True
        try:
            now = self._imu_time_now()
            since = self._held_since_s = now if self._held_since_s is None else self._held_since_s
            while True:
                asked = self._imu[-1][0]
                if self.tm.positioned and self._regained():
                    return True
                if asked - since > timeout_s:
                    self.return_mode = None
                    self.set_mode(LAND)
                    raise PilotError(f"the autopilot had no position {timeout_s:g} s after the maneuver: landing")
                if interrupt():
                    return False
                self._stream(lambda t: np.zeros(3), self.tm.heading_rad, until=lambda t: t - asked >= REGAIN_TRY_S,
                             guard=lambda t: self._fit())
        finally:
            self._recording = False

    def _regained(self) -> bool:
        try:
            self.set_mode(self.return_mode)
        except PilotError:
            return False   # its EKF has not taken the fix yet
        self.return_mode = self._held_since_s = None
        return True

    def _fly_legs(self, maneuver: Maneuver) -> FlownManeuver:
        yaw = self.tm.heading_rad
        self._imu, self._att, self._pos, self._ins_log = [], [], [], []
        calibration = self._calibration_before_loss() if self.flying_mode == GUIDED_NOGPS else None
        if calibration is not None and not self._worth_it(calibration[1], calibration[-1][-1][0], maneuver):
            calibration = None   # too old: a second maneuver after one aborted, its INS started before the first
        if calibration is not None:
            return self._fly_on_ins(maneuver, yaw, *calibration)
        self._unaided = self.flying_mode == GUIDED_NOGPS and self._without_gps_s() > AUTOPILOT_DR_S
        self._recording = True
        try:
            before, before_t = self._hover_until_still(yaw)
            start = self._imu[-1][0]
            c0, v0 = c_nb(*self.tm.attitude_rpy_rad), self._velocity().copy()
            p0 = self.tm.pos_ned_m.copy()
            first = len(self._imu) - 1
            if self.flying_mode == GUIDED_NOGPS:
                self._steer_by_ins(self._imu[-1], c0, v0, before, p0)
            self._legs_and_stop(maneuver, yaw, start, p0)
            last = len(self._imu)
            if self.flying_mode == GUIDED_NOGPS:
                # no second hover: the autopilot's attitude, which it measures the gyro against, has no GPS to
                # steady it by then (SITL: a drift of 0.6 mrad/s per second read from it, the track 7 m off)
                bias = before
            else:
                after, after_t = self._hover(yaw)
                bias = bias_between(before, after, before_t, after_t, start)
        finally:
            self._recording = self._unaided = False
        imu = self._imu[first:last]
        t = np.array([s[0] for s in imu]) - start
        ins = integrate(t, np.array([s[1] for s in imu]), np.array([s[2] for s in imu]), c_nb0=c0,
                        vel0_ned_mps=v0, bias=bias)
        return FlownManeuver(ins, start, *self._reported(start, imu[-1][0], p0), bias,
                             self.flying_mode == GUIDED_NOGPS, bound_without_gps=self.flying_mode == GUIDED_NOGPS)

    def _without_gps_s(self) -> float:
        """How long the autopilot has been without a GPS fix, as far as the link's history shows (0: it has one, or
        the history does not show it losing it)."""
        gps = list(self._history["gps"])   # GPS_RAW_INT comes slower than the IMU: this reaches back minutes
        since = next((t for t, positioned in reversed(gps) if positioned), None)
        return 0.0 if since is None else gps[-1][0] - since

    def _reported(self, start: float, end: float, p0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The autopilot's positions (LOCAL_POSITION_NED) from start to end, from p0 (none without a position)."""
        pos = [(pt - start, ned) for pt, ned, _ in self._pos if start <= pt <= end]
        return np.array([p for _, p in pos]).reshape(-1, 3) - p0, np.array([pt for pt, _ in pos])

    def _calibration_before_loss(self):
        """From the link's history: the IMU's biases over the last GPS-aided seconds before the autopilot reported
        no fix (two windows CAL_SPAN_S apart, or the later alone), and the autopilot's attitude, velocity and
        position at their end, CAL_MARGIN_S before the loss (a spoofer dragging the fix before the alarm bends the
        very last of them). None when the history does not hold them (the GPS was lost before the link was
        watched, or not lost at all)."""
        h = {k: list(v) for k, v in self._history.items()}
        lost = None
        for t, positioned in reversed(h["gps"]):
            if positioned:
                break
            lost = t
        if lost is None or not any(positioned for _, positioned in h["gps"]):
            return None
        end = lost - CAL_MARGIN_S
        late = self._window(h, end - CAL_WINDOW_S, end)
        if late is None:
            return None
        early = self._window(h, end - CAL_SPAN_S - CAL_WINDOW_S, end - CAL_SPAN_S)
        earliest = self._window(h, end - 2 * CAL_SPAN_S - CAL_WINDOW_S, end - 2 * CAL_SPAN_S)
        bias = late[0] if early is None else bias_between(early[0], late[0], early[1], late[1], end)
        if np.any(np.abs(bias.gyro_drift_rps2) > DRIFT_MAX_RPS2):
            bias = late[0]
        if early is not None and earliest is not None:
            before = bias_between(earliest[0], early[0], earliest[1], early[1], end).gyro_drift_rps2
            if np.any(np.abs(bias.gyro_drift_rps2 - before) > DRIFT_TURNED_RPS2):
                # the drift turned (ArduCopter SITL's gyro drifts in a triangle wave): carried on as a line it
                # would tilt the track most; near the turn the bias stands still, on average
                bias = late[0]
        at = [a for a in h["att"] if a[0] <= end][-1]
        pos = np.array([(pt, *ned, *vel) for pt, ned, vel in h["pos"]])
        state = [float(np.interp(end, pos[:, 0], pos[:, k])) for k in range(1, 7)]
        since_end = [s for s in h["imu"] if s[0] >= end]
        if not since_end:
            return None
        return bias, end, c_nb(*at[1]), np.array(state[3:]), np.array(state[:3]), since_end

    @staticmethod
    def _worth_it(calibrated_s: float, now_s: float, maneuver: Maneuver) -> bool:
        """Whether an INS started at calibrated_s (vehicle time; now_s now) bounds the maneuver's track tighter than
        a hover without GPS would: its errors grow with the cube of its age and beyond."""
        length_s = maneuver.duration_s + SETTLE_MAX_S
        age_s = now_s - calibrated_s
        return track_error_bound_m(length_s, age_s, drift_carried=True) <= \
            track_error_bound_m(length_s, without_gps=True)

    @staticmethod
    def _window(h: dict, t0: float, t1: float):
        """hover_bias over the history from t0 to t1 and its mid-time; None when the history does not cover it."""
        imu = [s for s in h["imu"] if t0 <= s[0] <= t1]
        att = [a for a in h["att"] if t0 - 0.1 <= a[0] <= t1 + 0.1]
        pos = [p for p in h["pos"] if t0 - 0.2 <= p[0] <= t1 + 0.2]
        if len(imu) < 0.8 * (t1 - t0) * STREAMS_HZ["HIGHRES_IMU"] or len(att) < 10 or len(pos) < 2 or \
                pos[0][0] > t0 or pos[-1][0] < t1:
            return None
        try:
            bias = hover_bias([s[0] for s in imu], [s[1] for s in imu], [s[2] for s in imu], [a[0] for a in att],
                              [a[1] for a in att], [p[0] for p in pos], [p[2] for p in pos])
        except ValueError:
            return None
        return bias, 0.5 * (imu[0][0] + imu[-1][0])

    def _fly_on_ins(self, maneuver: Maneuver, yaw: float, bias: HoverBias, end: float, c0, v0, p0,
                    since_end: list) -> FlownManeuver:
        """The maneuver without GPS, on an INS started where the GPS-aided flight ended (the link's history): no
        hover needed, its biases are known; settled, flown and stopped on the INS's velocity. The track is the
        INS's own, from the maneuver's start."""
        first = since_end[0]
        self._steer_by_ins(first, c0, v0, bias, p0)
        for t, f, w in since_end[1:]:
            self._ins.step(t, f, w)
        self._recording = True
        try:
            self._settle(yaw)
            start = self._ins.t_s
            at_start = len(self._ins_log)
            p_start, v_start = self._position().copy(), self._ins.vel_ned_mps.copy()
            self._legs_and_stop(maneuver, yaw, start, p_start)
        finally:
            self._recording = False
        log = [(start, p_start, v_start)] + self._ins_log[at_start:]
        ins = InsTrack(np.array([e[0] for e in log]) - start, np.array([e[1] for e in log]) - p_start,
                       np.array([e[2] for e in log]))
        t = ins.t_s
        return FlownManeuver(ins, start, *self._reported(start, start + t[-1], p_start), bias, True,
                             ins_age_s=start - first[0])

    def _steer_by_ins(self, sample: tuple, c0, v0, bias: HoverBias, p0: np.ndarray) -> None:
        """A fresh INS to steer by, from the IMU sample (t, accel, gyro) with attitude c0 and velocity v0 there (its
        positions from p0, the autopilot's frame), and a fresh velocity loop."""
        self._ins = Strapdown(sample[0], sample[1], sample[2], c0, v0, bias)
        self._ins_p0 = p0
        self._steer_integral, self._steered_s = np.zeros(2), None

    def _legs_and_stop(self, maneuver: Maneuver, yaw: float, start: float, p0: np.ndarray) -> None:
        """The maneuver's legs from vehicle time start (the geofence around p0), then zero velocity until stopped."""
        plan = _PlannedVelocity(maneuver)
        self._obey_since, self._asked_tilt_rad = None, None
        self._stream(lambda t: self._asked_velocity(plan, t - start), yaw,
                     until=lambda t: t >= start + maneuver.duration_s,
                     guard=lambda t: self._maneuvering(t - start, plan, p0),
                     acceleration=lambda t: plan.acceleration(t - start))
        stopped = {}
        # what the integral learnt was the drag at speed: kept, it would hold the vehicle at I / gain off zero
        self._steer_integral = np.zeros(2)
        self._stream(lambda t: np.zeros(3), yaw,
                     until=lambda t: self._stopped(t, start + maneuver.duration_s, stopped),
                     guard=lambda t: self._maneuvering(None, plan, p0))

    def _hover_until_still(self, yaw_rad: float) -> tuple[HoverBias, float]:
        """The hover before the maneuver, tried HOVER_TRIES times if the vehicle would not keep still."""
        for _ in range(HOVER_TRIES - 1):
            try:
                return self._hover(yaw_rad)
            except Restless:
                pass   # _hover settles it again first
        return self._hover(yaw_rad)

    def _hover(self, yaw_rad: float) -> tuple[HoverBias, float]:
        """Zero velocity with the heading held for HOVER_S; the IMU's biases it measured, and its mid-time. Its
        velocities are the INS's once one steers (the autopilot's are then dead-reckoned, or held at zero)."""
        self._settle(yaw_rad)
        velocities = self._pos if self._ins is None else self._ins_log
        i0, a0, p0 = len(self._imu), len(self._att), len(velocities)
        t0 = self._hover_t0 = self._imu_time_now()
        self._stream(lambda t: np.zeros(3), yaw_rad, until=lambda t: t >= t0 + HOVER_S, guard=self._hovering)
        imu, att, pos = self._imu[max(i0 - 1, 0):], self._att[a0:], velocities[max(p0 - 1, 0):]
        if self._unaided:   # still, as far as anyone knows (the settle held it level long enough)
            pos = [(imu[0][0], None, np.zeros(3)), (imu[-1][0], None, np.zeros(3))]
        if len(pos) < 2:
            raise PilotError(f"no velocity during the {HOVER_S:g} s hover")
        try:
            bias = hover_bias([s[0] for s in imu], [s[1] for s in imu], [s[2] for s in imu], [a[0] for a in att],
                              [a[1] for a in att], [p[0] for p in pos], [p[2] for p in pos])
        except ValueError as exc:
            raise PilotError(f"hover: {exc}") from None
        return bias, 0.5 * (imu[0][0] + imu[-1][0])

    def _settle(self, yaw_rad: float) -> None:
        """Zero velocity until the vehicle is still (a hover that is still braking measures its braking, not the
        IMU's biases), for SETTLE_MAX_S at most."""
        t0 = self._hover_t0 = self._imu_time_now()
        state = {}
        if self._unaided:   # nothing tells it is still: level, for its drag to stop it
            self._stream(lambda t: np.zeros(3), yaw_rad, until=lambda t: t >= t0 + LEVEL_SETTLE_S,
                         guard=lambda t: self._fit())
            return

        def still(t: float) -> bool:
            if self._stopped(t, math.inf, state, STILL_MPS):
                return True
            if t - t0 > SETTLE_MAX_S:
                raise PilotError(f"vehicle does not hold still ({np.linalg.norm(self._velocity()):.1f} m/s after "
                                 f"{SETTLE_MAX_S:g} s of zero velocity)")
            return False
        self._stream(lambda t: np.zeros(3), yaw_rad, until=still, guard=lambda t: self._fit())

    def _imu_time_now(self) -> float:
        """The vehicle time of the next IMU sample."""
        self._wait_for({self.imu_stream}, self.imu_stream)
        return self._imu[-1][0]

    def _stream(self, velocity, yaw_rad: float, until, guard, acceleration=None) -> None:
        """Send velocity(t) with the heading held at SETPOINT_HZ of IMU time until until(t), guard(t) checking each
        IMU sample; every stream must keep coming (a silence of timeout_s is an error). In GUIDED_NOGPS: attitude
        targets at ATTITUDE_HZ (_attitude_for)."""
        next_s = -math.inf
        while True:
            self._wait_for({self.imu_stream}, self.imu_stream)
            t, f, w = self._imu[-1]
            if self._ins is not None and t > self._ins.t_s:
                self._ins.step(t, f, w)
                self._ins_log.append((t, self._ins_p0 + self._ins.pos_ned_m, self._ins.vel_ned_mps))
            self._check_streams()
            guard(t)
            if until(t):
                return
            if t < next_s:
                continue
            v = velocity(t)
            if self.flying_mode == GUIDED_NOGPS:
                ahead = None if acceleration is None else acceleration(t)
                self._send_attitude(t, *self._attitude_for(v, yaw_rad, ahead))
                next_s = t + 1.0 / ATTITUDE_HZ
            else:
                self.conn.mav.set_position_target_local_ned_send(int(t * 1000) & 0xFFFFFFFF, *self.target,
                                                                 mav.MAV_FRAME_LOCAL_NED, VELOCITY_AND_YAW,
                                                                 0, 0, 0, *v, 0, 0, 0, yaw_rad, 0)
                next_s = t + 1.0 / SETPOINT_HZ

    def _asked_velocity(self, plan: _PlannedVelocity, t_man_s: float) -> np.ndarray:
        """ArduCopter's GUIDED takes the legs' velocities and shapes them under its own acceleration limit; a
        velocity loop of the flight side's own is given the plan's shaped velocity instead (a step would wind up its
        integral and overshoot the leg's end)."""
        return plan.velocity(t_man_s) if self.flying_mode == GUIDED_NOGPS else plan.setpoint(t_man_s)

    def _attitude_for(self, velocity_ned_mps: np.ndarray, yaw_rad: float, accel_ned_mps2=None
                      ) -> tuple[float, float, float, float]:
        """(roll, pitch, yaw, thrust) for GUIDED_NOGPS: the tilt whose thrust gives the acceleration the velocity
        loop on the INS asks for, the heading held, the thrust as the climb rate asked; level with no INS (the
        hover before the maneuver: a level multicopter holds its velocity but for drag)."""
        climb = -float(velocity_ned_mps[2])
        thrust = 0.5 + 0.5 * max(-1.0, min(1.0, climb / (CLIMB_MPS if climb > 0 else DESCENT_MPS)))
        if self._ins is None:
            return 0.0, 0.0, yaw_rad, thrust
        error = np.asarray(velocity_ned_mps[:2], float) - self._ins.vel_ned_mps[:2]
        if self._steered_s is not None and math.hypot(*error) < INTEGRATE_BELOW_MPS:   # no windup in a transient
            self._steer_integral = np.clip(self._steer_integral + VELOCITY_INTEGRAL_GAIN_PER_S2 * error
                                           * (self._ins.t_s - self._steered_s), -INTEGRAL_MAX_MPS2, INTEGRAL_MAX_MPS2)
        self._steered_s = self._ins.t_s
        a = VELOCITY_GAIN_PER_S * error + self._steer_integral
        if accel_ned_mps2 is not None:   # the plan's own acceleration, ahead of the error it would otherwise leave
            a = a + np.asarray(accel_ned_mps2, float)[:2]
        norm = math.hypot(*a)
        if norm > MAX_TILT_ACCEL_MPS2:
            a *= MAX_TILT_ACCEL_MPS2 / norm
        forward = math.cos(yaw_rad) * a[0] + math.sin(yaw_rad) * a[1]
        right = -math.sin(yaw_rad) * a[0] + math.cos(yaw_rad) * a[1]
        pitch = -math.atan2(forward, G_MPS2)      # nose down to speed up forward
        roll = math.atan2(right * math.cos(pitch), G_MPS2)
        return roll, pitch, yaw_rad, thrust

    def _send_attitude(self, t_s: float, roll: float, pitch: float, yaw: float, thrust: float) -> None:
        self._asked_tilt_rad = (roll, pitch)
        self.conn.mav.set_attitude_target_send(int(t_s * 1000) & 0xFFFFFFFF, *self.target, ATTITUDE_ONLY,
                                               quaternion(roll, pitch, yaw), 0, 0, 0, thrust)

    def _velocity(self) -> np.ndarray:
        """The vehicle's velocity as the flight side knows it: its INS's while one steers, else the autopilot's (none
        known, zero, once the autopilot's own dead reckoning is past trusting)."""
        if self._ins is not None:
            return self._ins.vel_ned_mps
        return np.zeros(3) if self._unaided else self.tm.vel_ned_mps

    def _position(self) -> np.ndarray:
        return self.tm.pos_ned_m if self._ins is None else self._ins_p0 + self._ins.pos_ned_m

    def _check_streams(self) -> None:
        now = time.monotonic()
        for name in ("ATTITUDE", "GLOBAL_POSITION_INT", "HEARTBEAT") + (("LOCAL_POSITION_NED",)
                                                                     if self.flying_mode == GUIDED else ()):
            silent = now - self.tm.last_seen_s.get(name, now)
            if silent > self.timeout_s:
                raise PilotError(f"no {name} from the vehicle in {silent:.1f} s")

    def _fit(self) -> None:
        tm = self.tm
        if not tm.armed:
            raise PilotError("vehicle disarmed")
        if tm.custom_mode != self.flying_mode:
            raise PilotError(f"vehicle left {MODE_NAMES[self.flying_mode]} (now mode {tm.custom_mode}): a pilot or a "
                             "failsafe took over")
        low = self.limits.min_altitude_m - HEIGHT_MARGIN_M
        if tm.height_above_home_m < low:
            raise PilotError(f"vehicle down to {tm.height_above_home_m:.1f} m above home (safe height {low:g} m)")

    def _hovering(self, t: float) -> None:
        self._fit()
        speed = float(np.linalg.norm(self._velocity()))
        if speed > HOVER_MAX_SPEED_MPS and self._imu[-1][0] - self._hover_t0 > 1.5:
            raise Restless(f"vehicle does not hold still ({speed:.1f} m/s with zero velocity asked)")

    def _maneuvering(self, t_man: float | None, plan: _PlannedVelocity, p0: np.ndarray) -> None:
        self._fit()
        out_m = math.hypot(*(self._position()[:2] - p0[:2]))
        if out_m > self.limits.geofence_radius_m:
            raise PilotError(f"vehicle {out_m:.0f} m from the start, outside the {self.limits.geofence_radius_m:g} m "
                             "geofence")
        if t_man is None:
            return
        if self.flying_mode == GUIDED_NOGPS:
            asked, seen = self._asked_tilt_rad, self.tm.attitude_rpy_rad
            off = 0.0 if asked is None or seen is None else max(abs(a - r) for a, r in zip(asked, seen[:2]))
            within, what = off <= OBEY_TILT_TOLERANCE_RAD, f"{math.degrees(off):.0f} deg off the attitude targets"
        else:
            off = float(np.linalg.norm(self._velocity() - plan.velocity(t_man)))
            within, what = off <= OBEY_TOLERANCE_MPS, f"{off:.1f} m/s off the plan"
        if within:
            self._obey_since = None
        elif self._obey_since is None:
            self._obey_since = t_man
        elif t_man - self._obey_since > OBEY_GRACE_S:
            raise PilotError(f"vehicle does not follow the setpoints ({what} for {t_man - self._obey_since:.1f} s)")

    def _stopped(self, t: float, plan_end_s: float, state: dict, below_mps: float = STOPPED_MPS) -> bool:
        # an INS's vertical velocity drifts with the accelerometer's bias; the autopilot holds the height by its
        # barometer meanwhile, so a vehicle steered by the INS has stopped when it has stopped horizontally
        moving = float(np.linalg.norm(self._velocity()[:2 if self._ins is not None else 3])) > below_mps
        state["since"] = None if moving else (state.get("since") or t)
        return (state["since"] is not None and t - state["since"] > STILL_S) or t - plan_end_s > SETTLE_MAX_S

    def _hold(self) -> None:
        """Zero velocity, heading free (level, in GUIDED_NOGPS): a few setpoints so the vehicle stops whatever it
        was told last."""
        for _ in range(3):
            if self.flying_mode == GUIDED_NOGPS:
                self._send_attitude(0.0, 0.0, 0.0, self.tm.heading_rad, 0.5)
                continue
            self.conn.mav.set_position_target_local_ned_send(0, *self.target, mav.MAV_FRAME_LOCAL_NED,
                                                             VELOCITY_AND_YAW | 0b0100_0000_0000,
                                                             0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)


class _PlannedVelocity:
    """The maneuver's velocity legs as setpoints, and the velocity its plan (under the acceleration limit) has."""

    def __init__(self, maneuver: Maneuver):
        self.legs = maneuver.legs
        self.ends_s = np.cumsum([leg.duration_s for leg in maneuver.legs])
        self.t_s = maneuver.t_s
        pos = np.column_stack([maneuver.north_m, maneuver.east_m, maneuver.down_m])
        self.vel = np.gradient(pos, maneuver.t_s, axis=0)
        self.acc = np.gradient(self.vel, maneuver.t_s, axis=0)

    def setpoint(self, t_s: float) -> np.ndarray:
        k = int(np.searchsorted(self.ends_s, t_s, side="right"))
        if k >= len(self.legs):
            return np.zeros(3)
        leg = self.legs[k]
        return np.array([leg.v_north_mps, leg.v_east_mps, leg.v_down_mps])

    def velocity(self, t_s: float) -> np.ndarray:
        return np.array([np.interp(t_s, self.t_s, self.vel[:, k]) for k in range(3)])

    def acceleration(self, t_s: float) -> np.ndarray:
        return np.array([np.interp(t_s, self.t_s, self.acc[:, k]) for k in range(3)])
