"""Where the receiver's results go: fixes as CSV, NMEA, GPX and GeoJSON, events as JSON lines, the run's config.

Everything is written as it is computed and flushed at once, so a run that is cut short (Ctrl-C, a truncated
recording, a crash) keeps every fix it computed. GPX and GeoJSON need a closing; rather than leaving it to
close(), each is written with its closing already in place after every fix, and the next fix overwrites the
closing (seek back, write the point, write the closing again). So every flushed state of those files is a
complete, parseable document, not only the one close() leaves.

    with OutputWriter(Path("out/run1")) as out:
        out.emit("acquired", 0.12, prn=7, doppler_hz=-1250.0)
        for fix in pvt_fixes:
            out.write(fix)
        out.leap_s = 18          # once the broadcast Delta t_LS has been decoded
"""

import csv
import dataclasses
import datetime as _dt
import enum
import io
import json
import math
import os
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any, BinaryIO, TextIO
from xml.sax.saxutils import escape

import numpy as np
from pynmeagps import NMEAMessage
from pynmeagps.nmeatypes_core import GET

from ..gps import GPS_EPOCH, SECONDS_PER_WEEK, enu_rotation
from .types import TIME_STATES, Fix, vouched
from .integrity import RAIM_STATES
from .rinex_obs import ObsEpoch, RinexObsWriter

DEFAULT_LEAP_S = 18               # GPS - UTC since 2017-01-01; the receiver passes the broadcast value once decoded
FORMATS = ("csv", "nmea", "gpx", "geojson", "rinex")
KNOTS_PER_M_S = 3600.0 / 1852.0   # the international nautical mile is exactly 1852 m
COURSE_MIN_SPEED_M_S = 0.1        # below this the direction of a noisy velocity means nothing: course left empty

CSV_COLUMNS = ("t_rx_s", "gps_week", "gps_tow_s", "lat_deg", "lon_deg", "height_m", "x_m", "y_m", "z_m",
               "vx_m_s", "vy_m_s", "vz_m_s", "clock_bias_m", "clock_drift_m_s", "n_sats", "pdop", "hdop", "vdop",
               "residual_rms_m", "prns", "state", "raim", "excluded_prns", "test_statistic", "hpl_m",
               "vpl_m", "tpl_ns", "time_state")

_GPX_HEADER = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<gpx version="1.1" creator="semperfi" xmlns="http://www.topografix.com/GPX/1/1"'
    ' xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'
    ' xsi:schemaLocation="http://www.topografix.com/GPX/1/1 http://www.topografix.com/GPX/1/1/gpx.xsd">\n'
    '<trk><name>semperfi</name><trkseg>\n'
)
_GPX_TRAILER = "</trkseg></trk>\n</gpx>\n"
_GEOJSON_HEADER = '{"type": "FeatureCollection", "features": ['
_GEOJSON_TRAILER = "\n]}\n"


# ---------------------------------------------------------------------------------------------------- time

def _leap_s_checked(leap_s: Any) -> int:
    """GPS - UTC in whole seconds; the broadcast Delta t_LS is an 8-bit signed count."""
    try:
        value = float(leap_s)
    except (TypeError, ValueError):
        raise ValueError(f"leap_s must be a whole number of seconds, got {leap_s!r}") from None
    if not value.is_integer() or not -128 <= value <= 127:
        raise ValueError(f"leap_s must be a whole number of seconds in [-128, 127], got {leap_s!r}")
    return int(value)


def gps_to_utc(week: int, tow_s: float, leap_s: int = DEFAULT_LEAP_S) -> _dt.datetime:
    """UTC (timezone-aware, microsecond resolution) of a GPS week and time of week; UTC = GPS - leap_s."""
    if isinstance(week, bool) or not float(week).is_integer() or week < 0:
        raise ValueError(f"gps week must be a non-negative integer, got {week!r}")
    if not math.isfinite(tow_s) or not 0.0 <= tow_s < SECONDS_PER_WEEK:
        raise ValueError(f"gps_tow_s must be in [0, {SECONDS_PER_WEEK}) s, got {tow_s!r}")
    leap = _leap_s_checked(leap_s)
    # whole days/seconds and the fraction kept apart so a float of ~1e9 s never costs microseconds
    whole_s, frac_s = divmod(float(tow_s), 1.0)
    return (GPS_EPOCH + _dt.timedelta(weeks=int(week), seconds=int(whole_s) - leap)
            + _dt.timedelta(microseconds=round(frac_s * 1e6)))


def _iso_utc(when: _dt.datetime) -> str:
    """ISO 8601 with milliseconds and a Z, as GPX readers expect."""
    return when.strftime("%Y-%m-%dT%H:%M:%S.") + f"{when.microsecond // 1000:03d}Z"


# ------------------------------------------------------------------------------------------ validation

def _check_fix(fix: Fix) -> tuple[np.ndarray, np.ndarray]:
    """Refuse a fix no output could represent honestly; returns its position and velocity as float arrays."""
    if not isinstance(fix, Fix):
        raise ValueError(f"expected a Fix, got {type(fix).__name__}")
    where = f"fix at t_rx_s={fix.t_rx_s!r}"
    scalars = {f.name: getattr(fix, f.name) for f in dataclasses.fields(Fix)
               if f.name not in ("pos_ecef_m", "vel_ecef_m_s", "prns", "state", "raim", "excluded_prns",
                                 "test_statistic", "hpl_m", "vpl_m", "tpl_ns", "time_state", "clock_sigma_ns",
                                 "h_sigma_m", "v_sigma_m")}
    # RAIM values are nan without redundancy
    for name, value in scalars.items():
        try:
            finite = math.isfinite(value)
        except TypeError:
            raise ValueError(f"{where}: {name} is {value!r}, not a number") from None
        if not finite:
            raise ValueError(f"{where}: {name} is {value!r}, not finite")
    vectors = []
    for name in ("pos_ecef_m", "vel_ecef_m_s"):
        v = np.asarray(getattr(fix, name), dtype=np.float64)
        if v.shape != (3,):
            raise ValueError(f"{where}: {name} must have 3 components, got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{where}: {name} is {v.tolist()}, not finite")
        vectors.append(v)
    if not -90.0 <= fix.lat_deg <= 90.0 or not -180.0 <= fix.lon_deg <= 180.0:
        raise ValueError(f"{where}: lat/lon {fix.lat_deg}, {fix.lon_deg} deg out of range")
    if not float(fix.gps_week).is_integer() or fix.gps_week < 0:
        raise ValueError(f"{where}: gps_week {fix.gps_week!r} is not a non-negative integer")
    if not 0.0 <= fix.gps_tow_s < SECONDS_PER_WEEK:
        raise ValueError(f"{where}: gps_tow_s {fix.gps_tow_s!r} out of [0, {SECONDS_PER_WEEK})")
    if not float(fix.n_sats).is_integer() or fix.n_sats < 0:
        raise ValueError(f"{where}: n_sats {fix.n_sats!r} is not a non-negative integer")
    if fix.raim not in RAIM_STATES:
        raise ValueError(f"{where}: raim {fix.raim!r} is not one of {RAIM_STATES}")
    if not all(isinstance(p, (int, np.integer)) and not isinstance(p, bool) for p in fix.prns):
        raise ValueError(f"{where}: prns {fix.prns!r} must be integers")
    if not isinstance(fix.state, str) or not fix.state or any(c in fix.state for c in ",\r\n\"<>&"):
        raise ValueError(f"{where}: state {fix.state!r} must be a plain non-empty word")
    if fix.time_state not in TIME_STATES:
        raise ValueError(f"{where}: time_state {fix.time_state!r} is not one of {TIME_STATES}")
    if not isinstance(fix.tpl_ns, (int, float, np.floating)) or fix.tpl_ns < 0:
        raise ValueError(f"{where}: tpl_ns {fix.tpl_ns!r} must be a non-negative number or nan")
    return vectors[0], vectors[1]


# ------------------------------------------------------------------------------------------ formatting

def _csv_row(fix: Fix, pos: np.ndarray, vel: np.ndarray) -> list[str]:
    # 1e-10 deg is 11 um on the ground, 1e-4 m is a tenth of a millimetre: the CSV never limits the solution
    return [f"{fix.t_rx_s:.9f}", str(int(fix.gps_week)), f"{fix.gps_tow_s:.9f}",
            f"{fix.lat_deg:.10f}", f"{fix.lon_deg:.10f}", f"{fix.height_m:.4f}",
            *(f"{c:.4f}" for c in pos), *(f"{c:.4f}" for c in vel),
            f"{fix.clock_bias_m:.4f}", f"{fix.clock_drift_m_s:.4f}", str(int(fix.n_sats)),
            f"{fix.pdop:.3f}", f"{fix.hdop:.3f}", f"{fix.vdop:.3f}", f"{fix.residual_rms_m:.4f}",
            " ".join(str(int(p)) for p in fix.prns), fix.state, fix.raim,
            " ".join(str(int(p)) for p in fix.excluded_prns), f"{fix.test_statistic:.4f}", f"{fix.hpl_m:.3f}",
            f"{fix.vpl_m:.3f}", f"{fix.tpl_ns:.2f}", fix.time_state]


def horizontal_velocity(fix: Fix) -> tuple[float, float]:
    """(speed over ground m/s, course over ground deg from true north, clockwise) from the ECEF velocity."""
    enu = enu_rotation(math.radians(fix.lat_deg), math.radians(fix.lon_deg)) @ np.asarray(fix.vel_ecef_m_s, float)
    speed_m_s = float(math.hypot(enu[0], enu[1]))
    course_deg = float(math.degrees(math.atan2(enu[0], enu[1])) % 360.0)
    return speed_m_s, course_deg


# NMEA 4.10 navigational status: S safe, C caution, U unsafe, V not valid. The defence's state maps onto it so a
# plain NMEA consumer can see that the receiver distrusts its own solution.
_NAV_STATUS = {"nominal": "S", "recovered": "S", "rectified": "C", "recovering": "C", "unverified": "U",
               "spoofing_detected": "U"}


def nmea_sentences(fix: Fix, leap_s: int = DEFAULT_LEAP_S) -> tuple[bytes, bytes]:
    """GGA and RMC (talker GP) for a fix, each a full sentence with checksum and CRLF. A fix the receiver cannot
    vouch for (spoofing suspected, integrity failed) is marked invalid (GGA quality 0, RMC status V): a plain NMEA
    consumer, an autopilot's among them, must not use it."""
    _check_fix(fix)
    good = vouched(fix)
    # NMEA time has two decimals and pynmeagps truncates; round to 10 ms first so 12.999999 s reads 13.00
    tow_cs = round(fix.gps_tow_s * 100.0) / 100.0
    week = int(fix.gps_week)
    if tow_cs >= SECONDS_PER_WEEK:
        week, tow_cs = week + 1, tow_cs - SECONDS_PER_WEEK
    utc = gps_to_utc(week, tow_cs, leap_s)
    # GGA wants altitude above mean sea level plus the geoid separation. We carry no geoid model, so, as GNSS-SDR
    # does, the separation is 0 and the altitude field holds the height above the WGS 84 ellipsoid.
    gga = NMEAMessage("GP", "GGA", GET, hpnmeamode=True,
                      time=utc.time(), lat=fix.lat_deg, lon=fix.lon_deg, quality=1 if good else 0,
                      numSV=int(fix.n_sats),
                      HDOP=round(float(fix.hdop), 2), alt=round(float(fix.height_m), 3), altUnit="M",
                      sep=0.0, sepUnit="M", diffAge="", diffStation="")
    speed_m_s, course_deg = horizontal_velocity(fix)
    rmc = NMEAMessage("GP", "RMC", GET, hpnmeamode=True,
                      time=utc.time(), status="A" if good else "V", lat=fix.lat_deg, lon=fix.lon_deg,
                      spd=round(speed_m_s * KNOTS_PER_M_S, 3),
                      cog=round(course_deg, 2) if speed_m_s >= COURSE_MIN_SPEED_M_S else "",
                      date=utc.date(), mv="", mvEW="", posMode="A",
                      navStatus=_NAV_STATUS.get(fix.state, "V"))
    return gga.serialize(), rmc.serialize()


def _gpx_trkpt(fix: Fix, utc: _dt.datetime) -> str:
    # child order is the one GPX 1.1's wptType sequence prescribes (ele, time, ..., type, fix, sat, hdop, vdop, pdop)
    return (f'<trkpt lat="{fix.lat_deg:.10f}" lon="{fix.lon_deg:.10f}"><ele>{fix.height_m:.4f}</ele>'
            f"<time>{_iso_utc(utc)}</time><type>{escape(fix.state)}</type><fix>3d</fix>"
            f"<sat>{int(fix.n_sats)}</sat><hdop>{fix.hdop:.3f}</hdop><vdop>{fix.vdop:.3f}</vdop>"
            f"<pdop>{fix.pdop:.3f}</pdop></trkpt>\n")


def _geojson_feature(fix: Fix, utc: _dt.datetime) -> str:
    # RFC 7946: positions are [lon, lat, height above the WGS 84 ellipsoid], which is exactly what a fix carries
    feature = {
        "type": "Feature",
        "geometry": {"type": "Point",
                     "coordinates": [round(fix.lon_deg, 10), round(fix.lat_deg, 10), round(fix.height_m, 4)]},
        "properties": {"t_rx_s": fix.t_rx_s, "gps_week": int(fix.gps_week), "gps_tow_s": fix.gps_tow_s,
                       "time_utc": _iso_utc(utc), "n_sats": int(fix.n_sats), "prns": [int(p) for p in fix.prns],
                       "pdop": fix.pdop, "hdop": fix.hdop, "vdop": fix.vdop, "state": fix.state,
                       "time_state": fix.time_state, "tpl_ns": fix.tpl_ns},
    }
    return json.dumps(_to_json(feature), allow_nan=False)


# ------------------------------------------------------------------------------------------ events

def _to_json(value: Any) -> Any:
    """Plain JSON values from numpy scalars/arrays, tuples, paths, dates; non-finite floats become null."""
    if isinstance(value, np.ndarray):
        return _to_json(value.tolist())
    if isinstance(value, np.generic):
        return _to_json(value.item())
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None   # NaN/Infinity are not JSON; strict readers reject them
    if isinstance(value, complex):
        return [_to_json(value.real), _to_json(value.imag)]
    if isinstance(value, dict):
        return {str(k): _to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [_to_json(v) for v in value]
    if isinstance(value, enum.Enum):
        return _to_json(value.value)
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (_dt.datetime, _dt.date)):
        return value.isoformat()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _to_json({f.name: getattr(value, f.name) for f in dataclasses.fields(value)})
    raise ValueError(f"cannot write a {type(value).__name__} to JSON: {value!r}")


class EventLog:
    """A JSON-lines log of what the receiver did (acquisitions, locks, losses, subframes, alarms), one per line."""

    def __init__(self, path: Path, fsync: bool = False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fsync = fsync
        self._file: TextIO | None = open(self.path, "w", encoding="utf-8")
        self.n_events = 0

    def emit(self, kind: str, t_rx_s: float, **fields: Any) -> None:
        """Write {"t_rx_s": ..., "event": kind, **fields} as one line and flush it."""
        if self._file is None:
            raise ValueError(f"event log {self.path} is closed")
        if not isinstance(kind, str) or not kind:
            raise ValueError(f"event kind must be a non-empty string, got {kind!r}")
        try:
            t = float(t_rx_s)
        except (TypeError, ValueError):
            raise ValueError(f"event {kind!r}: t_rx_s must be a number, got {t_rx_s!r}") from None
        if not math.isfinite(t):
            raise ValueError(f"event {kind!r}: t_rx_s is {t_rx_s!r}, not finite")
        if "event" in fields:
            raise ValueError(f"event {kind!r}: 'event' is reserved for the kind, rename the field")
        line = json.dumps({"t_rx_s": t, "event": kind, **_to_json(fields)}, allow_nan=False)
        self._file.write(line + "\n")
        _flush(self._file, self._fsync)
        self.n_events += 1

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> "EventLog":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


# ------------------------------------------------------------------------------------------ files

def _flush(f: io.IOBase, fsync: bool) -> None:
    f.flush()
    if fsync:   # flush survives a crash of this process; fsync also survives the machine losing power
        os.fsync(f.fileno())


class _ClosedDocument:
    """A text document whose closing is always on disk: each append overwrites the closing and rewrites it."""

    def __init__(self, path: Path, header: str, trailer: str, fsync: bool):
        self._file: BinaryIO = open(path, "wb")
        self._trailer = trailer.encode("utf-8")
        self._fsync = fsync
        self._file.write(header.encode("utf-8"))
        self._body_end = self._file.tell()
        self._commit()

    def append(self, text: str) -> None:
        self._file.seek(self._body_end)
        self._file.write(text.encode("utf-8"))
        self._body_end = self._file.tell()
        self._commit()

    def _commit(self) -> None:
        # the new body plus the closing is always longer than the closing it overwrites, so nothing stale remains
        self._file.write(self._trailer)
        _flush(self._file, self._fsync)

    def close(self) -> None:
        self._file.seek(self._body_end)
        self._file.write(self._trailer)
        self._file.truncate()
        self._file.close()


def write_config(out_dir: Path, text: str) -> Path:
    """Write the run's effective configuration to out_dir/config.toml (refused if it is not valid TOML)."""
    if not isinstance(text, str):
        raise ValueError(f"configuration must be TOML text, got {type(text).__name__}")
    try:
        tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"effective configuration is not valid TOML: {err}") from None
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "config.toml"
    path.write_text(text if text.endswith("\n") or not text else text + "\n", encoding="utf-8")
    return path


class OutputWriter:
    """Writes every fix to the chosen formats as it arrives, and events to events.jsonl; flushes each write.

    Files in out_dir: fixes.csv, fixes.nmea (GGA + RMC), fixes.gpx (GPX 1.1 track), fixes.geojson
    (FeatureCollection of Points, one Feature per line), observations.rnx (RINEX 3 C1C L1C D1C S1C, through
    write_observations), events.jsonl. All are complete documents after every
    write; close() (or leaving the with-block, also on an exception) only closes the files.
    leap_s (GPS - UTC, s) is used for NMEA/GPX/GeoJSON times; set it when the broadcast value is decoded.
    """

    def __init__(self, out_dir: Path, formats: Iterable[str] = FORMATS, leap_s: int = DEFAULT_LEAP_S,
                 fsync: bool = False):
        if isinstance(formats, str):
            formats = (formats,)
        self.formats = tuple(dict.fromkeys(formats))
        unknown = [f for f in self.formats if f not in FORMATS]
        if unknown:
            raise ValueError(f"unknown output format(s) {', '.join(map(repr, unknown))}; "
                             f"choose from {', '.join(FORMATS)}")
        self.leap_s = leap_s
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._fsync = fsync
        self.n_fixes = 0
        self.paths: dict[str, Path] = {}
        self._csv_file: TextIO | None = None
        self._nmea_file: BinaryIO | None = None
        self._gpx: _ClosedDocument | None = None
        self._geojson: _ClosedDocument | None = None
        self._rinex: RinexObsWriter | None = None
        self._closed = False
        try:
            self.events = EventLog(self.out_dir / "events.jsonl", fsync=fsync)
            self.paths["events"] = self.events.path
            if "csv" in self.formats:
                self.paths["csv"] = self.out_dir / "fixes.csv"
                self._csv_file = open(self.paths["csv"], "w", encoding="utf-8", newline="")
                self._csv = csv.writer(self._csv_file, lineterminator="\n")
                self._csv.writerow(CSV_COLUMNS)
                _flush(self._csv_file, fsync)
            if "nmea" in self.formats:
                self.paths["nmea"] = self.out_dir / "fixes.nmea"
                self._nmea_file = open(self.paths["nmea"], "wb")
            if "gpx" in self.formats:
                self.paths["gpx"] = self.out_dir / "fixes.gpx"
                self._gpx = _ClosedDocument(self.paths["gpx"], _GPX_HEADER, _GPX_TRAILER, fsync)
            if "geojson" in self.formats:
                self.paths["geojson"] = self.out_dir / "fixes.geojson"
                self._geojson = _ClosedDocument(self.paths["geojson"], _GEOJSON_HEADER, _GEOJSON_TRAILER, fsync)
            if "rinex" in self.formats:
                self.paths["rinex"] = self.out_dir / "observations.rnx"
                self._rinex = RinexObsWriter(self.paths["rinex"])
        except BaseException:
            self.close()
            raise

    @property
    def leap_s(self) -> int:
        """GPS - UTC in seconds used to time-stamp the outputs."""
        return self._leap_s

    @leap_s.setter
    def leap_s(self, value: int) -> None:
        self._leap_s = _leap_s_checked(value)

    def write(self, fix: Fix) -> None:
        """Append one fix to every format and flush; a bad fix is refused before any file is touched."""
        if self._closed:
            raise ValueError(f"output writer for {self.out_dir} is closed")
        pos, vel = _check_fix(fix)
        utc = gps_to_utc(int(fix.gps_week), fix.gps_tow_s, self._leap_s)
        # everything is formatted first, so a formatting error cannot leave one file a fix ahead of another
        row = _csv_row(fix, pos, vel) if self._csv_file else None
        nmea = b"".join(nmea_sentences(fix, self._leap_s)) if self._nmea_file else None
        trkpt = _gpx_trkpt(fix, utc) if self._gpx else None
        feature = _geojson_feature(fix, utc) if self._geojson else None
        if row is not None:
            self._csv.writerow(row)
            _flush(self._csv_file, self._fsync)
        if nmea is not None:
            self._nmea_file.write(nmea)
            _flush(self._nmea_file, self._fsync)
        if trkpt is not None:
            self._gpx.append(trkpt)
        if feature is not None:
            self._geojson.append(("\n" if self.n_fixes == 0 else ",\n") + feature)
        self.n_fixes += 1

    def write_observations(self, epoch: ObsEpoch, approx_xyz_m) -> None:
        """Append one epoch of observables to observations.rnx (when that format is chosen)."""
        if self._rinex is not None:
            self._rinex.write(epoch, tuple(float(v) for v in approx_xyz_m))

    def emit(self, kind: str, t_rx_s: float, **fields: Any) -> None:
        """Log an event to events.jsonl (see EventLog.emit)."""
        self.events.emit(kind, t_rx_s, **fields)

    def close(self) -> None:
        """Close every file; each is left a complete document. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        for closer in (getattr(self, "events", None), self._csv_file, self._nmea_file, self._gpx, self._geojson,
                       self._rinex):
            if closer is not None:
                closer.close()

    def __enter__(self) -> "OutputWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
