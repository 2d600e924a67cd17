"""ArduPilot's ArduCopter SITL, a real autopilot, as a child process, and an observer on its first link: what the
closed loop with an autopilot (`semperfi demo --autopilot`), scripts/sitl-fly and the SITL tests share.

Sitl starts the binary (its ports are TCP 5760 + 10 x instance for serial0, +2 serial1, +3 serial2), with
copter.parm from beside it and any extra parameters, at a chosen home. The Observer holds serial0: it arms, takes
off, climbs, and records SIM_STATE -- the simulator's truth, for the world and for evaluation, never for the
receiver or the flight side -- tagged with the vehicle time (time_boot_ms of the ATTITUDE just before it).
"""
from __future__ import annotations

import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pymap3d
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

GUIDED = 4
# an alarm comes in cruise, not the moment the vehicle reaches its height: straight off the takeoff's climb the EKF
# is still correcting its attitude, which the hover then takes for gyro bias (measured: 2.4 m instead of ~1 m)
CRUISE_S = 10.0


class Sitl:
    """ArduCopter SITL as a child process (killed on stop)."""

    def __init__(self, instance: int = 5, speedup: float = 1.0, workdir=None, binary: str | Path = "arducopter",
                 params: dict | None = None, home: tuple[float, float, float] | None = None):
        """binary: the arducopter SITL executable (ArduPilot's copter.parm beside it is loaded first, if there);
        params: parameters over those (e.g. {"GPS1_TYPE": 14}: its GPS from MAVLink GPS_INPUT);
        home: (lat_deg, lon_deg, altitude_m) where it starts (default: ArduPilot's, CMAC in Canberra)."""
        self.instance, self.speedup, self.binary, self.params = instance, speedup, Path(binary), params or {}
        self.home = home
        self._tmp = None if workdir else tempfile.TemporaryDirectory(prefix="sitl-")
        self.workdir = Path(workdir or self._tmp.name)
        self.proc: subprocess.Popen | None = None

    def port(self, serial: int) -> int:
        return 5760 + 10 * self.instance + {0: 0, 1: 2, 2: 3}[serial]

    def url(self, serial: int) -> str:
        return f"tcp:127.0.0.1:{self.port(serial)}"

    def start(self) -> Sitl:
        self.workdir.mkdir(parents=True, exist_ok=True)
        parm = self.binary.parent / "copter.parm"
        defaults = [str(parm)] if parm.is_file() else []
        if self.params:
            extra = self.workdir / "extra.parm"
            extra.write_text("".join(f"{k} {v}\n" for k, v in self.params.items()))
            defaults.append(str(extra))
        args = [str(self.binary), "--model", "quad", "--speedup", f"{self.speedup:g}", "-w", f"-I{self.instance}"]
        if defaults:
            args += ["--defaults", ",".join(defaults)]
        if self.home is not None:
            args += ["--home", "{:.8f},{:.8f},{:.2f},0".format(*self.home)]
        with open(self.workdir / "sitl.log", "w") as log:   # the child keeps its own descriptor
            self.proc = subprocess.Popen(args, cwd=self.workdir, stdout=log, stderr=subprocess.STDOUT)
        return self

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


class Observer:
    """The script's link (serial0): arms, takes off and climbs; a thread reads everything it sends (so nothing on
    it goes stale), keeping the mode, arming, height and the SIM_STATE truth."""

    def __init__(self, url: str, timeout_s: float = 30.0, speedup: float = 1.0):
        self.speedup = speedup
        deadline = time.monotonic() + timeout_s
        while True:   # SITL opens its ports a moment after it starts
            try:
                self.conn = mavutil.mavlink_connection(url, source_system=255, dialect="ardupilotmega",
                                                       autoreconnect=False)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"SITL did not open {url} in {timeout_s:g} s") from None
                time.sleep(0.5)
        if self.conn.wait_heartbeat(timeout=timeout_s) is None:
            raise RuntimeError(f"no HEARTBEAT on {url} in {timeout_s:g} s")
        # SIM_STATE: (t_boot_s, lat, lon, alt, roll, pitch, yaw, gyro xyz, accel xyz, velocity north east down)
        self.truth: list[tuple] = []
        self.texts: list[tuple[float | None, str]] = []   # STATUSTEXT: (t_boot_s, text)
        self.gps_fix_type = None                          # GPS_RAW_INT's, when streamed
        self.height_m = None
        self.lat_lon_e7 = (0, 0)
        self.custom_mode = None
        self.armed = None
        self._acks: list = []
        self._beat = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def command(self, command: int, *params: float, timeout_s: float = 5.0) -> int | None:
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        with self._lock:
            self._acks.clear()
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                for ack in self._acks:
                    if ack.command == command:
                        return int(ack.result)
            time.sleep(0.01)
        return None

    def streams(self, hz: float = 50.0, extra: tuple[int, ...] = ()) -> None:
        """SIM_STATE, ATTITUDE and GLOBAL_POSITION_INT (and the extra message ids) at hz."""
        for msg_id in (mav.MAVLINK_MSG_ID_SIM_STATE, mav.MAVLINK_MSG_ID_ATTITUDE,
                       mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, *extra):
            if self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz) != mav.MAV_RESULT_ACCEPTED:
                raise RuntimeError(f"SITL refused to stream message {msg_id}")

    def _heartbeat(self, timeout_s: float = 3.0):
        """Wait for the next HEARTBEAT; (custom_mode, armed)."""
        self._beat = None
        deadline = time.monotonic() + timeout_s
        while self._beat is None and time.monotonic() < deadline:
            time.sleep(0.02)
        return self._beat

    def arm(self, timeout_s: float = 180.0) -> float:
        """GUIDED and armed, as a fresh HEARTBEAT says, retried until the EKF has settled; returns the seconds it
        took (SITL may accept GUIDED early and fall back to STABILIZE)."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            beat = self._heartbeat()
            if beat is None:
                continue
            mode, armed = beat
            if mode != GUIDED:
                self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
            elif not armed:
                self.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            else:
                return time.monotonic() - t0
            time.sleep(0.5 / self.speedup)
        raise RuntimeError(f"SITL was not armed in GUIDED after {timeout_s:g} s")

    def takeoff(self, altitude_m: float, timeout_s: float = 120.0) -> None:
        """Armed, GUIDED, and up to altitude_m (re-armed if it disarmed itself on the ground meanwhile)."""
        for _ in range(3):
            self.arm()
            if self.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m) == mav.MAV_RESULT_ACCEPTED:
                return self.wait_height(altitude_m, timeout_s)
        raise RuntimeError("SITL refused the takeoff")

    def wait_height(self, altitude_m: float, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.height_m is not None and abs(self.height_m - altitude_m) < 1.0:
                time.sleep(2.0 / self.speedup)   # let it settle
                return
            time.sleep(0.05)
        raise RuntimeError(f"SITL did not reach {altitude_m:g} m in {timeout_s:g} s")

    def climb_to(self, altitude_m: float, timeout_s: float = 60.0) -> None:
        """Back to the flying height between maneuvers (GUIDED position target, this link)."""
        lat, lon = self.lat_lon_e7
        self.conn.mav.set_position_target_global_int_send(0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                          0b0000_1101_1111_1000, lat, lon, altitude_m,
                                                          0, 0, 0, 0, 0, 0, 0, 0)
        self.wait_height(altitude_m, timeout_s)

    def set_speedup(self, speedup: float) -> None:
        """SITL's speed from now on (SIM_SPEEDUP, taken at run time)."""
        with self._lock:   # the world's thread sends this while the loop's commands go out
            self.conn.mav.param_set_send(1, 1, b"SIM_SPEEDUP", float(speedup), mav.MAV_PARAM_TYPE_REAL32)

    def set_mode(self, custom_mode: int) -> None:
        """Ask for a mode (no wait: with the recording thread on, the ACK is the thread's)."""
        self.conn.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                        custom_mode, 0, 0, 0, 0, 0)

    def wait_mode(self, custom_mode: int, timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.custom_mode == custom_mode:
                return True
            time.sleep(0.05)
        return False

    def _run(self) -> None:
        t_boot = None
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.2)
            except Exception:   # noqa: BLE001 -- the link went down with SITL
                return
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "ATTITUDE":
                t_boot = msg.time_boot_ms / 1000.0
            elif kind == "HEARTBEAT" and msg.get_srcSystem() == 1 and msg.get_srcComponent() == 1:
                self.custom_mode = int(msg.custom_mode)
                self.armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
                self._beat = (self.custom_mode, self.armed)
            elif kind == "COMMAND_ACK":
                with self._lock:
                    self._acks.append(msg)
            elif kind == "GLOBAL_POSITION_INT":
                self.height_m = msg.relative_alt / 1000.0
                self.lat_lon_e7 = (msg.lat, msg.lon)
            elif kind == "SIM_STATE" and t_boot is not None:
                with self._lock:
                    self.truth.append((t_boot, msg.lat_int / 1e7, msg.lon_int / 1e7, msg.alt, msg.roll, msg.pitch,
                                       msg.yaw, msg.xgyro, msg.ygyro, msg.zgyro, msg.xacc, msg.yacc, msg.zacc,
                                       msg.vn, msg.ve, msg.vd))
            elif kind == "STATUSTEXT":
                self.texts.append((t_boot, str(msg.text)))
            elif kind == "GPS_RAW_INT":
                self.gps_fix_type = int(msg.fix_type)

    def truth_ned(self, t0_s: float, t1_s: float):
        """SIM_STATE from t0_s to t1_s (vehicle boot seconds) in NED metres from where it was at t0_s."""
        with self._lock:
            tr = np.array(self.truth)
        tr = tr[np.r_[True, np.diff(tr[:, 0]) > 0]]
        ref = [np.interp(t0_s, tr[:, 0], tr[:, k]) for k in (1, 2, 3)]
        sel = (tr[:, 0] >= t0_s) & (tr[:, 0] <= t1_s)
        n, e, d = pymap3d.geodetic2ned(tr[sel, 1], tr[sel, 2], tr[sel, 3], *ref)
        return tr[sel, 0] - t0_s, np.column_stack([n, e, d])

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        self.conn.close()
