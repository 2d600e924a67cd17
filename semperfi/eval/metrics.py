"""What a receiver made of a recording whose truth is known, from its own outputs (fixes.csv, events.jsonl): did it
crash, how much of the time it gave a usable position, its errors, the fixes it called good beyond their protection
levels, its time error, and when it raised the alarm, decided and recovered.

The truth is a static place or a 10 Hz motion file (gps-sdr-sim's -u rows: t,x,y,z ECEF), and for the time the GPS
time of the recording's first sample (GPS-SDR-SIM's scenes start at their -t time exactly, on a perfect receiver
clock: the true GPS time of sample t_rx_s is start + t_rx_s). Everything is computed on whole columns.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pymap3d

from ..gps import GPS_EPOCH
from ..receiver import TRUSTED_STATES

SECONDS_PER_WEEK = 604800
DEFENDED_STATES = ("recovered", "rectified")
EPOCH_HZ = 10.0          # the availability grid: the receiver's fix rate
BAD_M = 10.0             # a fix farther than this (horizontal) from the truth is wrong
LAST_S = 10.0


@dataclass(frozen=True)
class Truth:
    """Where the receiver was (lat, lon, height; or a motion file around it) and, when known, the GPS time (week,
    seconds of week) of the recording's first sample."""
    lat_deg: float
    lon_deg: float
    height_m: float
    motion: str = ""
    start_gps: tuple[int, float] | None = None


def gps_time(date: str) -> tuple[int, float]:
    """gps-sdr-sim's -t time ("YYYY/MM/DD,hh:mm:ss", GPS time, no leap seconds) as (GPS week, seconds of week)."""
    s = (datetime.strptime(date, "%Y/%m/%d,%H:%M:%S").replace(tzinfo=timezone.utc) - GPS_EPOCH).total_seconds()
    return int(s // SECONDS_PER_WEEK), float(s % SECONDS_PER_WEEK)


def read_fixes(path: str | Path) -> dict[str, np.ndarray]:
    """fixes.csv as columns: numbers as float arrays (empty cells nan), state (and any other text) as str arrays.
    Columns a receiver does not write (tpl_ns, say) are simply absent."""
    path = Path(path)
    if not path.is_file():
        return {}
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if len(rows) < 2:
        return {name: np.zeros(0) for name in (rows[0] if rows else ())}
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    out = {}
    for i, name in enumerate(header):
        cells = [r[i] for r in body]
        try:
            out[name] = np.array([float(c) if c != "" else math.nan for c in cells])
        except ValueError:
            out[name] = np.array(cells)
    return out


def read_events(path: str | Path) -> list[dict]:
    path = Path(path)
    if not path.is_file():
        return []
    events = []
    for line in path.read_text().splitlines():
        try:
            events.append(json.loads(line))
        except json.JSONDecodeError:     # a line cut short by a crash
            pass
    return events


def truth_ecef(t_s: np.ndarray, truth: Truth) -> np.ndarray:
    """(n, 3) true ECEF position at receiver times t_s: the place, or the motion file interpolated (clamped)."""
    t_s = np.asarray(t_s, dtype=float)
    if truth.motion:
        path = np.loadtxt(truth.motion, delimiter=",", ndmin=2)
        return np.column_stack([np.interp(t_s, path[:, 0], path[:, k]) for k in (1, 2, 3)])
    return np.tile(np.array(pymap3d.geodetic2ecef(truth.lat_deg, truth.lon_deg, truth.height_m)), (t_s.size, 1))


class Errors(NamedTuple):
    """A receiver's position errors against the truth, each an array (m): in the truth's local east/north/up,
    horizontal, vertical (absolute), 3-D, and along and across the truth's horizontal track (across: positive to
    the right of it; both nan where the truth does not move)."""
    east_m: np.ndarray
    north_m: np.ndarray
    up_m: np.ndarray
    horizontal_m: np.ndarray
    vertical_m: np.ndarray
    three_d_m: np.ndarray
    along_m: np.ndarray
    cross_m: np.ndarray

    @property
    def enu(self) -> np.ndarray:
        return np.column_stack([self.east_m, self.north_m, self.up_m])


MOVING_M_S = 0.1          # the truth's track has a direction from this speed on


def errors(pos_ecef_m, true_ecef_m, velocity_ecef_m_s=None) -> Errors:
    """Every error measure of positions against true positions (both (n, 3) ECEF, metres; the true velocity, when
    given, sets the along/cross-track axes), in the local frame at each true position (WGS-84, pymap3d)."""
    pos = np.asarray(pos_ecef_m, dtype=float).reshape(-1, 3)
    true = np.asarray(true_ecef_m, dtype=float).reshape(-1, 3)
    lat, lon, _ = pymap3d.ecef2geodetic(true[:, 0], true[:, 1], true[:, 2])
    d = pos - true
    e, n, u = (np.asarray(c, dtype=float) for c in pymap3d.ecef2enuv(d[:, 0], d[:, 1], d[:, 2], lat, lon))
    along = cross = np.full(e.shape, np.nan)
    if velocity_ecef_m_s is not None:
        v = np.asarray(velocity_ecef_m_s, dtype=float).reshape(-1, 3)
        ve, vn, _ = (np.asarray(c, dtype=float) for c in pymap3d.ecef2enuv(v[:, 0], v[:, 1], v[:, 2], lat, lon))
        speed = np.hypot(ve, vn)
        with np.errstate(invalid="ignore", divide="ignore"):
            ue, un = (np.where(speed > MOVING_M_S, c / speed, np.nan) for c in (ve, vn))
        along, cross = e * ue + n * un, e * un - n * ue
    horizontal = np.hypot(e, n)
    return Errors(e, n, u, horizontal, np.abs(u), np.hypot(horizontal, u), along, cross)


def position_errors(t_s: np.ndarray, pos_ecef_m: np.ndarray, truth: Truth) -> Errors:
    """Every error measure of positions at receiver times t_s against a Truth (its place or motion file)."""
    t_s = np.asarray(t_s, dtype=float)
    velocity = (truth_ecef(t_s + 0.05, truth) - truth_ecef(t_s - 0.05, truth)) / 0.1 if truth.motion else None
    return errors(pos_ecef_m, truth_ecef(t_s, truth), velocity)


def fix_errors(fixes: dict[str, np.ndarray], truth: Truth) -> Errors:
    """position_errors of a fixes.csv read by read_fixes (t_rx_s, x_m, y_m, z_m)."""
    return position_errors(fixes["t_rx_s"], np.column_stack([fixes["x_m"], fixes["y_m"], fixes["z_m"]]), truth)


def time_errors_ns(fixes: dict[str, np.ndarray], start_gps: tuple[int, float]) -> np.ndarray | None:
    """Each fix's GPS time minus the true GPS time of its sample (ns), None without the fixes' GPS time. The week
    and the seconds of week are differenced apart: a GPS time in seconds as one float64 keeps only ~0.2 us."""
    if "gps_week" not in fixes or "gps_tow_s" not in fixes:
        return None
    week, tow = start_gps
    return ((fixes["gps_week"] - week) * SECONDS_PER_WEEK + (fixes["gps_tow_s"] - tow) - fixes["t_rx_s"]) * 1e9


def availability(t_s: np.ndarray, usable: np.ndarray, from_s: float, to_s: float,
                 rate_hz: float = EPOCH_HZ) -> tuple[float, float]:
    """(share of the epochs at rate_hz in [from_s, to_s) that carry a usable fix, longest run of epochs without one
    in seconds); (nan, nan) for an empty span."""
    k0, k1 = math.ceil(from_s * rate_hz - 1e-6), int(round(to_s * rate_hz))
    if k1 <= k0:
        return math.nan, math.nan
    ok = np.zeros(k1 - k0, dtype=bool)
    k = np.round(np.asarray(t_s, dtype=float) * rate_hz).astype(int) - k0
    hit = np.asarray(usable, dtype=bool) & (k >= 0) & (k < ok.size)
    ok[k[hit]] = True
    # the longest run of False: the distances between consecutive True epochs (with sentinels at both ends)
    edges = np.flatnonzero(np.concatenate([[True], ok, [True]]))
    longest = int(np.max(np.diff(edges)) - 1) if edges.size > 1 else ok.size
    return float(np.mean(ok)), longest / rate_hz


def _first(events: list[dict], kind: str) -> float | None:
    return min((float(e["t_rx_s"]) for e in events if e.get("event") == kind), default=None)


def _r(value, digits: int):
    if value is None:
        return None
    value = float(value)
    return None if not math.isfinite(value) else round(value, digits)


def run_metrics(fixes_csv: str | Path, events_jsonl: str | Path, truth: Truth, duration_s: float | None = None,
                clean_first_fix_s: float | None = None, crash: str | None = None, wall_s: float | None = None,
                bad_m: float = BAD_M, last_s: float = LAST_S) -> dict:
    """One run's metrics (JSON-ready: None where a figure does not apply).

    crash: the one-line error of a run that raised (or an internal_error event's); availability and longest_gap_s:
    over the 10 Hz epochs from clean_first_fix_s (the clean recording's first fix; this run's own first fix without
    it) to duration_s (the recording's end; the last fix without it), an epoch being available when it carries a fix
    within bad_m horizontally that is not labelled spoofing_detected; good_availability and longest_good_gap_s: the
    same counting only fixes called good (what an autopilot is given); last_mean_m: the horizontal error over the last
    last_s of the recording; good_*: the fixes called good (TRUSTED_STATES) farther than bad_m, or beyond their
    hpl_m / vpl_m / tpl_ns (columns absent: None); time_err_max_ns: the largest |GPS time error| of a good fix (with a
    time truth), time_err_last_ns: the mean time error of every fix over the last last_s (where a push took it);
    alarm_s, verdict_s (the first identification event), recovered_s (the first recovered or rectified
    fix after the verdict, or after the alarm without one) and verdict_to_recovered_s."""
    f = read_fixes(fixes_csv)
    events = read_events(events_jsonl)
    internal = [e for e in events if e.get("event") == "internal_error"]
    if crash is None and internal:
        e = internal[0]
        crash = str(e.get("error") or e.get("message") or {k: v for k, v in e.items() if k not in ("event",)})
    t = f.get("t_rx_s", np.zeros(0))
    n = int(t.size)
    out: dict = {"crash": crash is not None, "error": crash.splitlines()[0] if crash else None, "fixes": n,
                 "first_fix_s": _r(t[0], 2) if n else None, "clean_first_fix_s": _r(clean_first_fix_s, 2)}
    states = f.get("state", np.full(n, "nominal")).astype(str)
    if n:
        err = fix_errors(f, truth)
        enu, horiz = err.enu, err.horizontal_m
    else:
        enu, horiz = np.zeros((0, 3)), np.zeros(0)
    good = np.isin(states, TRUSTED_STATES)
    end = duration_s if duration_s is not None else (float(t[-1]) + 1.0 / EPOCH_HZ if n else 0.0)
    start = clean_first_fix_s if clean_first_fix_s is not None else (float(t[0]) if n else end)
    avail, gap = availability(t, (horiz <= bad_m) & (states != "spoofing_detected"), start, end)
    last = t >= end - last_s
    good_avail, good_gap = availability(t, (horiz <= bad_m) & good, start, end)
    out |= {"availability": _r(avail, 4), "longest_gap_s": _r(gap, 1),
            "good_availability": _r(good_avail, 4), "longest_good_gap_s": _r(good_gap, 1),
            "last_mean_m": _r(np.mean(horiz[last]), 2) if last.any() else None,
            "max_m": _r(np.max(horiz), 1) if n else None, "last_state": str(states[-1]) if n else None,
            "good_fixes": int(good.sum()), "good_but_wrong": int(np.sum(good & (horiz > bad_m)))}
    for key, err, column in (("good_beyond_hpl", horiz, "hpl_m"), ("good_beyond_vpl", np.abs(enu[:, 2]), "vpl_m")):
        out[key] = int(np.sum(good & (err > f[column]))) if column in f else None   # nan levels compare False
    terr = time_errors_ns(f, truth.start_gps) if truth.start_gps is not None and n else None
    out["time_err_max_ns"] = _r(np.max(np.abs(terr[good])), 1) if terr is not None and good.any() else None
    out["time_err_last_ns"] = _r(np.mean(terr[last]), 1) if terr is not None and last.any() else None
    out["good_beyond_tpl"] = (int(np.sum(good & (np.abs(terr) > f["tpl_ns"])))
                              if terr is not None and "tpl_ns" in f else None)
    alarm, verdict = _first(events, "spoofing_alarm"), _first(events, "identification")
    # what the issue holds a defended receiver to: from the verdict on (before it, which peak is whose is unknown)
    after_verdict = availability(t, (horiz <= bad_m) & (states != "spoofing_detected"), max(start, verdict), end) \
        if verdict is not None else (None, None)
    out |= {"availability_after_verdict": _r(after_verdict[0], 4),
            "longest_gap_after_verdict_s": _r(after_verdict[1], 1)}
    anchor = verdict if verdict is not None else alarm
    recovered = None
    if anchor is not None:
        after = (t >= anchor) & np.isin(states, DEFENDED_STATES)
        recovered = float(t[after][0]) if after.any() else None
    out |= {"alarm_s": _r(alarm, 2), "verdict_s": _r(verdict, 2), "recovered_s": _r(recovered, 2),
            "verdict_to_recovered_s": _r(recovered - anchor, 2) if recovered is not None else None,
            "wall_s": _r(wall_s, 1)}
    return out
