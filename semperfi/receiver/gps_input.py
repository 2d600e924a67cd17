"""The receiver as an autopilot's GPS: fixes as MAVLink GPS_INPUT (ArduPilot `GPS1_TYPE 14`, PX4's `GPS_INPUT`
too), paced by fix_stream.FixStream (10 Hz on the wall clock, "no fix" once the last one is stale).

What the autopilot is told is only what it may trust: a 3D fix for a fix the receiver calls good (nominal,
recovered, rectified) whose ranges pass the integrity test, so within its protection levels. The accuracies are the
fix's fault-free 1 sigma (from the same weighted least squares the protection levels come from): an autopilot reads
hAcc as 1 sigma -- ArduPilot's EKF weighs each fix by it and will not set its origin or arm while it exceeds 5 m --
and a protection level (a bound on one faulty range's effect, several sigma) there left ArduCopter "waiting for
home" for good on a clean sky (measured on SITL: HPL 14.7 m). While spoofing is suspected and not resolved
(spoofing_detected, recovering) or the fix is otherwise unverified, it gets NO_FIX: a degraded 3D fix with large
accuracies would still be fused and pull the EKF toward the attacker's position, while no fix makes the autopilot's
own failsafes and dead reckoning take over. The moment a fix is recovered it gets the true position again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..address import parse_address
from ..gps import enu_rotation
from .types import Fix, vouched

FIX_NO_FIX, FIX_3D = 1, 3          # GPS_FIX_TYPE (0 would say "no GPS connected")
UERE_M = 5.0               # accuracy per unit of DOP when a fix has no sigma (no integrity computed)
SPEED_ACCURACY_M_S = 0.3   # Doppler velocity at 40-50 dB-Hz: a few cm/s per range, times a DOP of a few
GPS_COMPONENT_ID = 220     # MAV_COMP_ID_GPS
SERIAL_WRITE_TIMEOUT_S = 1.0
_IGNORE_YAW = 0            # GPS_INPUT has no yaw flag: yaw 0 means "unknown"


@dataclass(frozen=True)
class GpsInput:
    """One GPS_INPUT's fields (MAVLink common, units as sent)."""
    time_usec: int
    time_week_ms: int
    time_week: int
    fix_type: int
    lat: int                 # deg * 1e7
    lon: int
    alt: float               # m (the fix's ellipsoidal height: the geoid separation is not applied)
    hdop: float
    vdop: float
    vn: float
    ve: float
    vd: float
    speed_accuracy: float
    horiz_accuracy: float
    vert_accuracy: float
    satellites_visible: int


def gps_input(fix: Fix | None, unix_time_s: float) -> GpsInput:
    """What to tell the autopilot about this fix (None: no fix yet, or the last one is stale)."""
    if fix is None:
        return GpsInput(int(unix_time_s * 1e6), 0, 0, FIX_NO_FIX, 0, 0, 0.0, 99.99, 99.99, 0.0, 0.0, 0.0,
                        99.0, 9999.0, 9999.0, 0)
    enu = enu_rotation(math.radians(fix.lat_deg), math.radians(fix.lon_deg)) @ np.asarray(fix.vel_ecef_m_s, float)
    hacc = fix.h_sigma_m if math.isfinite(fix.h_sigma_m) else UERE_M * fix.hdop
    vacc = fix.v_sigma_m if math.isfinite(fix.v_sigma_m) else UERE_M * fix.vdop
    week_ms = int(round(fix.gps_tow_s * 1e3)) % (604800 * 1000)
    if not vouched(fix):   # the receiver cannot vouch for where it says the vehicle is: nothing to fuse
        return GpsInput(int(unix_time_s * 1e6), week_ms, fix.gps_week, FIX_NO_FIX, 0, 0, 0.0, 99.99, 99.99,
                        0.0, 0.0, 0.0, 99.0, 9999.0, 9999.0, fix.n_sats)
    return GpsInput(int(unix_time_s * 1e6), week_ms, fix.gps_week, FIX_3D, int(round(fix.lat_deg * 1e7)),
                    int(round(fix.lon_deg * 1e7)), float(fix.height_m), float(fix.hdop), float(fix.vdop),
                    float(enu[1]), float(enu[0]), float(-enu[2]), SPEED_ACCURACY_M_S * max(1.0, fix.pdop / 2.0),
                    float(hacc), float(vacc), fix.n_sats)


class MavlinkGpsOut:
    """GPS_INPUT over a MAVLink connection (pymavlink URL: udpout:HOST:PORT, tcp:HOST:PORT, a serial device);
    log_path: every message sent is also a row of this CSV (what the autopilot was told, for evaluation)."""

    LOG_COLUMNS = "unix_time_s,time_week,time_week_ms,fix_type,lat_deg,lon_deg,alt_m,h_acc_m,v_acc_m,satellites\n"

    def __init__(self, url: str, system_id: int = 1, log_path: str | Path | None = None):
        from pymavlink import mavutil
        parse_address(url, "--mavlink-gps")
        try:
            self.conn = mavutil.mavlink_connection(url, source_system=system_id, source_component=GPS_COMPONENT_ID,
                                                   dialect="common", autoreconnect=True)
        except Exception as exc:   # pymavlink raises whatever its transport raises
            raise ValueError(f"cannot open the autopilot's GPS link {url}: {exc}") from None
        port = getattr(self.conn, "port", None)
        if hasattr(port, "write_timeout"):
            port.write_timeout = SERIAL_WRITE_TIMEOUT_S   # pymavlink's sockets are non-blocking: a serial port is not
        self._log = None
        if log_path is not None:
            self._log = open(log_path, "w")
            self._log.write(self.LOG_COLUMNS)

    def send(self, fix: Fix | None, unix_time_s: float) -> None:
        """FixStream's sink: the latest fresh fix (None: none) as one GPS_INPUT."""
        m = gps_input(fix, unix_time_s)
        self.conn.mav.gps_input_send(m.time_usec, 0, _IGNORE_YAW, m.time_week_ms, m.time_week, m.fix_type, m.lat,
                                     m.lon, m.alt, m.hdop, m.vdop, m.vn, m.ve, m.vd, m.speed_accuracy,
                                     m.horiz_accuracy, m.vert_accuracy, m.satellites_visible)
        if self._log is not None:
            self._log.write(f"{unix_time_s:.3f},{m.time_week},{m.time_week_ms},{m.fix_type},{m.lat / 1e7:.7f},"
                            f"{m.lon / 1e7:.7f},{m.alt:.2f},{m.horiz_accuracy:.2f},{m.vert_accuracy:.2f},"
                            f"{m.satellites_visible}\n")
            self._log.flush()

    def close(self) -> None:
        self.conn.close()
        if self._log is not None:
            self._log.close()
