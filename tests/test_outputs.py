"""The receiver's outputs: every fix lands in CSV, NMEA, GPX and GeoJSON as it comes, readable at any moment."""

import csv
import json
import math
import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from functools import reduce

import numpy as np
import pytest
from pynmeagps import NMEAReader
from pynmeagps.nmeatypes_core import VALCKSUM

from semperfi.gps.geometry import enu_rotation, geodetic_to_ecef
from semperfi.receiver.outputs import (CSV_COLUMNS, EventLog, OutputWriter, gps_to_utc, nmea_sentences,
                                       write_config)
from semperfi.receiver.types import Fix

GPX_NS = {"g": "http://www.topografix.com/GPX/1/1"}
LAT_DEG, LON_DEG, HEIGHT_M = 42.339812345678, -71.089287654321, 10.0   # digits to spare: rounding shows
WEEK = 2300                     # GPS week 2300 began Sunday 2024-02-04 00:00:00 GPS time
TOW_S = 4 * 86400 + 12.5        # Thursday 2024-02-08 00:00:12.5 GPS = Wednesday 2024-02-07 23:59:54.5 UTC
UTC_FIRST = datetime(2024, 2, 7, 23, 59, 54, 500000, tzinfo=timezone.utc)


def _east_unit_ecef(lat_deg: float, lon_deg: float) -> np.ndarray:
    return enu_rotation(math.radians(lat_deg), math.radians(lon_deg))[0]


def _fix(lat_deg=LAT_DEG, lon_deg=LON_DEG, height_m=HEIGHT_M, t_rx_s=1.0, tow_s=TOW_S, vel_east_m_s=0.0,
         state="nominal", **overrides) -> Fix:
    pos = geodetic_to_ecef(math.radians(lat_deg), math.radians(lon_deg), height_m)
    fields = dict(t_rx_s=t_rx_s, gps_week=WEEK, gps_tow_s=tow_s, pos_ecef_m=pos,
                  vel_ecef_m_s=vel_east_m_s * _east_unit_ecef(lat_deg, lon_deg),
                  clock_bias_m=12345.678, clock_drift_m_s=-0.4321, lat_deg=lat_deg, lon_deg=lon_deg,
                  height_m=height_m, n_sats=7, prns=(3, 7, 12, 19, 22, 25, 31), pdop=1.87, hdop=0.93,
                  vdop=1.62, residual_rms_m=2.345, state=state)
    fields.update(overrides)
    return Fix(**fields)


def _track() -> list[Fix]:
    """A fix at rest, then one a second later 10 m east, moving east at 10 m/s."""
    first = _fix()
    pos2 = first.pos_ecef_m + 10.0 * _east_unit_ecef(LAT_DEG, LON_DEG)
    # geodetic of the moved point, to first order: 10 m east is 10 / (R cos lat) rad of longitude
    r_east_m = 6388838.0   # prime-vertical radius at 42.34 deg
    lon2 = LON_DEG + math.degrees(10.0 / (r_east_m * math.cos(math.radians(LAT_DEG))))
    second = _fix(lon_deg=lon2, t_rx_s=2.0, tow_s=TOW_S + 1.0, vel_east_m_s=10.0, pos_ecef_m=pos2,
                  n_sats=8, prns=(3, 7, 12, 19, 22, 25, 31, 32), hdop=1.05, state="spoofing_detected")
    return [first, second]


def _write(tmp_path, fixes, **kwargs) -> OutputWriter:
    with OutputWriter(tmp_path, **kwargs) as out:
        for f in fixes:
            out.write(f)
    return out


def test_gps_to_utc_subtracts_leap_seconds_across_midnight():
    assert gps_to_utc(WEEK, TOW_S) == UTC_FIRST, gps_to_utc(WEEK, TOW_S)
    assert gps_to_utc(WEEK, TOW_S, leap_s=17) == datetime(2024, 2, 7, 23, 59, 55, 500000, tzinfo=timezone.utc)
    assert gps_to_utc(0, 0.0, leap_s=0) == datetime(1980, 1, 6, tzinfo=timezone.utc)
    assert gps_to_utc(WEEK, TOW_S).tzinfo is not None
    with pytest.raises(ValueError):
        gps_to_utc(WEEK, 604800.0)


def test_csv_round_trips_every_fix_to_a_nanodegree(tmp_path):
    fixes = _track()
    _write(tmp_path, fixes, formats=("csv",))
    with open(tmp_path / "fixes.csv", newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames) == CSV_COLUMNS
        rows = list(reader)
    assert len(rows) == 2, rows
    for fix, row in zip(fixes, rows):
        for name in ("lat_deg", "lon_deg"):
            assert abs(float(row[name]) - getattr(fix, name)) < 1e-9, (name, row[name], getattr(fix, name))
        assert abs(float(row["height_m"]) - fix.height_m) < 1e-3
        for i, axis in enumerate("xyz"):
            assert abs(float(row[f"{axis}_m"]) - fix.pos_ecef_m[i]) < 1e-3, (axis, row[f"{axis}_m"])
            assert abs(float(row[f"v{axis}_m_s"]) - fix.vel_ecef_m_s[i]) < 1e-3
        assert abs(float(row["gps_tow_s"]) - fix.gps_tow_s) < 1e-9
        assert abs(float(row["t_rx_s"]) - fix.t_rx_s) < 1e-9
        assert int(row["gps_week"]) == WEEK and int(row["n_sats"]) == fix.n_sats
        assert abs(float(row["clock_bias_m"]) - fix.clock_bias_m) < 1e-3
        assert abs(float(row["hdop"]) - fix.hdop) < 1e-3 and abs(float(row["pdop"]) - fix.pdop) < 1e-3
        assert tuple(int(p) for p in row["prns"].split()) == fix.prns
        assert row["state"] == fix.state


def _nmea_lines(path) -> list[bytes]:
    data = path.read_bytes()
    assert data.endswith(b"\r\n"), data[-10:]
    return [line + b"\r\n" for line in data.split(b"\r\n") if line]


def test_nmea_gga_rmc_parse_back_with_position_time_and_velocity(tmp_path):
    fixes = _track()
    _write(tmp_path, fixes, formats=("nmea",))
    lines = _nmea_lines(tmp_path / "fixes.nmea")
    assert [line[:6] for line in lines] == [b"$GPGGA", b"$GPRMC"] * 2, lines
    for line in lines:   # the checksum is the XOR of everything between $ and *, checked by hand and by the parser
        body, checksum = line[1:].rstrip(b"\r\n").split(b"*")
        assert f"{reduce(lambda a, b: a ^ b, body):02X}".encode() == checksum, line
    parsed = [NMEAReader.parse(line, validate=VALCKSUM) for line in lines]
    for i, fix in enumerate(fixes):
        gga, rmc = parsed[2 * i], parsed[2 * i + 1]
        utc = gps_to_utc(WEEK, fix.gps_tow_s)
        for msg in (gga, rmc):
            # 1e-6 deg is the claim; the 7-decimal minutes (high-precision NMEA) actually hold it to ~1e-9 deg
            assert abs(msg.lat - fix.lat_deg) < 1e-8 and abs(msg.lon - fix.lon_deg) < 1e-8, (msg, fix)
            assert msg.time == utc.time().replace(tzinfo=None), (msg.time, utc)
        # a fix the receiver distrusts (the second: spoofing_detected) is marked invalid for a plain NMEA consumer
        good = fix.state != "spoofing_detected"
        assert gga.quality == int(good) and gga.numSV == fix.n_sats and abs(gga.HDOP - fix.hdop) < 0.01, gga
        assert abs(gga.alt - fix.height_m) < 1e-3 and gga.sep == 0.0, gga   # ellipsoidal height, no geoid
        assert rmc.status == ("A" if good else "V") and rmc.date == utc.date(), rmc
    assert parsed[0].time.second == 54 and parsed[0].time.microsecond == 500000, parsed[0].time   # GPS - 18 s
    assert parsed[1].date == UTC_FIRST.date(), parsed[1].date                                  # still 7 Feb in UTC
    moving = parsed[3]
    assert abs(moving.spd - 10.0 * 3600 / 1852) < 1e-3, f"speed {moving.spd} kn, expected 19.438 kn (10 m/s)"
    assert abs(moving.cog - 90.0) < 0.01, f"course {moving.cog} deg, expected 90 (due east)"
    assert parsed[1].spd == 0.0 and parsed[1].cog == "", parsed[1]   # at rest: no course


def test_nmea_time_follows_the_leap_second_parameter():
    gga, _ = nmea_sentences(_fix(), leap_s=17)
    assert NMEAReader.parse(gga, validate=VALCKSUM).time.second == 55


def test_nmea_time_is_rounded_to_the_hundredth_not_truncated():
    gga, _ = nmea_sentences(_fix(tow_s=TOW_S + 0.496))   # 23:59:54.996 UTC reads 23:59:55.00, not 54.99
    t = NMEAReader.parse(gga, validate=VALCKSUM).time
    assert (t.second, t.microsecond) == (55, 0), t


def test_gpx_and_geojson_parse_with_every_point(tmp_path):
    fixes = _track()
    _write(tmp_path, fixes, formats=("gpx", "geojson"))
    trkpts = ET.parse(tmp_path / "fixes.gpx").getroot().findall("g:trk/g:trkseg/g:trkpt", GPX_NS)
    assert len(trkpts) == 2, ET.tostring(ET.parse(tmp_path / "fixes.gpx").getroot())
    for fix, pt in zip(fixes, trkpts):
        assert abs(float(pt.get("lat")) - fix.lat_deg) < 1e-9 and abs(float(pt.get("lon")) - fix.lon_deg) < 1e-9
        assert abs(float(pt.find("g:ele", GPX_NS).text) - fix.height_m) < 1e-3
        when = datetime.fromisoformat(pt.find("g:time", GPX_NS).text.replace("Z", "+00:00"))
        assert when == gps_to_utc(WEEK, fix.gps_tow_s), when
        assert pt.find("g:type", GPX_NS).text == fix.state
    doc = json.loads((tmp_path / "fixes.geojson").read_text())
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == 2, doc
    for fix, feature in zip(fixes, doc["features"]):
        lon, lat, h = feature["geometry"]["coordinates"]
        assert feature["geometry"]["type"] == "Point"
        assert abs(lat - fix.lat_deg) < 1e-9 and abs(lon - fix.lon_deg) < 1e-9 and abs(h - fix.height_m) < 1e-3
        props = feature["properties"]
        assert props["n_sats"] == fix.n_sats and props["state"] == fix.state and props["pdop"] == fix.pdop
        assert props["t_rx_s"] == fix.t_rx_s and props["gps_tow_s"] == fix.gps_tow_s


def test_every_file_is_complete_while_the_writer_is_still_open(tmp_path):
    """A run killed after two fixes leaves two fixes in every file, each file parseable as it stands."""
    fixes = _track()
    out = OutputWriter(tmp_path)
    try:
        for n, fix in enumerate(fixes, start=1):
            out.write(fix)
            out.emit("fix", fix.t_rx_s, n=n)
            with open(tmp_path / "fixes.csv", newline="") as f:
                assert len(list(csv.DictReader(f))) == n
            assert len(_nmea_lines(tmp_path / "fixes.nmea")) == 2 * n
            gpx = ET.parse(tmp_path / "fixes.gpx").getroot()
            assert len(gpx.findall("g:trk/g:trkseg/g:trkpt", GPX_NS)) == n
            assert len(json.loads((tmp_path / "fixes.geojson").read_text())["features"]) == n
            assert len((tmp_path / "events.jsonl").read_text().splitlines()) == n
    finally:
        out.close()
    assert len(json.loads((tmp_path / "fixes.geojson").read_text())["features"]) == 2   # close() kept them
    assert len(ET.parse(tmp_path / "fixes.gpx").getroot().findall(".//g:trkpt", GPX_NS)) == 2


def test_an_exception_inside_the_run_still_leaves_complete_files(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with OutputWriter(tmp_path) as out:
            out.write(_fix())
            raise KeyboardInterrupt
    assert len(json.loads((tmp_path / "fixes.geojson").read_text())["features"]) == 1
    assert len(ET.parse(tmp_path / "fixes.gpx").getroot().findall(".//g:trkpt", GPX_NS)) == 1


def test_events_are_json_lines_with_numpy_values_made_plain(tmp_path):
    def strict(text):   # NaN/Infinity are not JSON: a strict reader must not meet them
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c} in {text}"))

    with EventLog(tmp_path / "events.jsonl") as log:
        log.emit("acquired", np.float64(0.125), prn=np.int64(7), doppler_hz=np.float32(-1250.5),
                 code_phase_chips=np.array([511.25]), locked=np.bool_(True), cn0_dbhz=float("nan"),
                 peaks=[np.int32(1), 2.5])
        log.emit("subframe", 6.02, prn=7, subframe_id=1, words=np.arange(3, dtype=np.uint32))
        assert len((tmp_path / "events.jsonl").read_text().splitlines()) == 2   # flushed before close
    lines = [strict(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert lines[0] == {"t_rx_s": 0.125, "event": "acquired", "prn": 7, "doppler_hz": -1250.5,
                        "code_phase_chips": [511.25], "locked": True, "cn0_dbhz": None, "peaks": [1, 2.5]}, lines[0]
    assert list(lines[0])[:2] == ["t_rx_s", "event"]
    assert lines[1]["words"] == [0, 1, 2] and lines[1]["event"] == "subframe"
    with EventLog(tmp_path / "e2.jsonl") as log:
        with pytest.raises(ValueError):
            log.emit("bad", float("nan"))
        with pytest.raises(ValueError):
            log.emit("bad", 1.0, thing=object())


@pytest.mark.parametrize("field, value", [("lat_deg", float("nan")), ("height_m", float("inf")),
                                          ("pos_ecef_m", np.array([1.0, np.nan, 2.0])),
                                          ("hdop", float("nan")), ("gps_tow_s", 604800.0),
                                          ("time_state", "fine"), ("tpl_ns", -1.0)])
def test_a_bad_fix_is_refused_in_one_line_and_writes_nothing(tmp_path, field, value):
    with OutputWriter(tmp_path) as out:
        out.write(_fix())
        with pytest.raises(ValueError) as err:
            out.write(_fix(**{field: value}))
        assert field in str(err.value) and "\n" not in str(err.value), str(err.value)
        out.write(_track()[1])
    with open(tmp_path / "fixes.csv", newline="") as f:
        assert len(list(csv.DictReader(f))) == 2
    assert len(_nmea_lines(tmp_path / "fixes.nmea")) == 4
    assert len(json.loads((tmp_path / "fixes.geojson").read_text())["features"]) == 2


def test_formats_can_be_chosen_and_unknown_ones_are_refused(tmp_path):
    _write(tmp_path / "a", [_fix()], formats=("csv",))
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["events.jsonl", "fixes.csv"]
    with pytest.raises(ValueError, match="kml"):
        OutputWriter(tmp_path / "b", formats=("csv", "kml"))
    with pytest.raises(ValueError):
        OutputWriter(tmp_path / "c", leap_s=18.5)


def test_write_config_saves_the_effective_configuration(tmp_path):
    text = '[receiver]\nsampling_frequency_hz = 4000000.0\nitem_type = "ishort"\n'
    path = write_config(tmp_path / "run", text)
    assert path == tmp_path / "run" / "config.toml" and path.read_text() == text
    with pytest.raises(ValueError):
        write_config(tmp_path, "this is = = not toml")


def test_the_time_protection_level_and_time_state_are_in_csv_and_geojson(tmp_path):
    fixes = [_fix(tpl_ns=71.25, time_state="nominal"), _fix(t_rx_s=2.0, tow_s=TOW_S + 1.0, time_state="holdover",
                                                            tpl_ns=312.5), _fix(t_rx_s=3.0, tow_s=TOW_S + 2.0)]
    _write(tmp_path, fixes, formats=("csv", "geojson"))
    rows = list(csv.DictReader(open(tmp_path / "fixes.csv", newline="")))
    assert [r["time_state"] for r in rows] == ["nominal", "holdover", "unverified"]
    assert [r["tpl_ns"] for r in rows] == ["71.25", "312.50", "nan"]   # nan: no redundancy, no bound
    props = [f["properties"] for f in json.loads((tmp_path / "fixes.geojson").read_text())["features"]]
    assert [p["time_state"] for p in props] == ["nominal", "holdover", "unverified"]
    assert props[1]["tpl_ns"] == 312.5 and props[2]["tpl_ns"] is None
