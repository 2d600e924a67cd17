"""`semperfi demo`: the built-in scenario end to end, no files needed: the closed loop, then a conventional receiver.

A multicopter hovering in Boston, a synthesized constellation, and an attacker 1 km east at +6 dB from the first
sample, synchronized to GPS time. Three processes, as on a UAV: the world (the vehicle behind MAVLink, and the
signals rendered from where it truly is), SemperFi's receiver (reading the world's samples), and the flight side (the
link server, flying maneuvers over MAVLink). The receiver alarms, waits for a maneuver rather than guess which peak
is the attacker's, asks the flight side for one once it has a fix, follows every peak through it, and the IMU track
that comes back decides them; the spoofer is cancelled and the receiver fixes the vehicle's true position. A
conventional receiver on the same samples (the world keeps a copy) follows the spoofer.
"""

import math
from pathlib import Path
from typing import Iterator

import numpy as np

from ..defense import SpoofGuard, load_config
from ..receiver import DopplerGrid, TRUSTED_STATES, acquire, plot_before_after, run_file
from ..gps import enu_rotation, geodetic_to_ecef
from ..iq import open_iq
from ..sim import load_scenario
from .metrics import Truth, fix_errors, read_fixes

BEFORE_AFTER_LAG_S = 2.0   # the before/after look comes this long after the first cancellation: settled, verified

def _horizontal_errors_m(fixes_csv: Path, lat_deg: float, lon_deg: float, height_m: float) -> np.ndarray:
    f = read_fixes(fixes_csv)
    if not f or not f["t_rx_s"].size:
        return np.empty(0)
    return fix_errors(f, Truth(lat_deg, lon_deg, height_m)).horizontal_m


def _before_after_plot(path: Path, cfg: dict, out_png: Path, at_s: float) -> None:
    """The CAFs of a few spoofed PRNs at at_s, before and after the spoof guard (run on the recording up to there,
    a chunk at a time: only the look's samples are kept)."""
    reader = open_iq(path)
    fs = reader.fs_hz
    guard = SpoofGuard(cfg, fs, reader.if_hz)
    at, look, chunk = int(at_s * fs), int(0.01 * fs), int(0.1 * fs)
    raw = cleaned = None
    done = 0
    for first in range(0, min(reader.n_samples, at + look + chunk), chunk):
        x = reader.read(first, chunk)
        if first <= at < first + x.size:
            raw = x[at - first:at - first + look]
        out = guard.push(x)
        if done <= at < done + out.size:
            cleaned = out[at - done:at - done + look]
        done += out.size
    if raw is None or cleaned is None or raw.size < look or cleaned.size < look:
        return
    marks = {}
    for prn in sorted(guard.cancel_started):
        track = next((st.tracks[prn] for st in guard.canceller.stages if prn in st.tracks), None)
        around = track.channel.epoch_around(at) if track is not None else None
        if around is not None:   # where the receiver had the spoofer, and the legitimate signal beside it
            spoof = (around[1] * 1023.0) % 1023.0
            legit = None if track.legit_offset_chips is None else (spoof + track.legit_offset_chips) % 1023.0
            marks[prn] = (spoof, legit)
    prns = sorted(marks, key=lambda p: abs(marks[p][1] - marks[p][0]) if marks[p][1] is not None else 99)[:4]
    grid = DopplerGrid(0.0, 6000.0, 333.0)
    if not prns:
        return
    before = acquire(raw, fs, prns, grid, coherent_ms=2, noncoherent=5)
    after = acquire(cleaned, fs, prns, grid, coherent_ms=2, noncoherent=5)
    plot_before_after([before[p] for p in prns], [after[p] for p in prns], marks, out_png,
                      f"acquisition before (top) and after (bottom) cancellation, t = {at_s:.1f} s")


def run_demo(out_dir: str | Path, duration_s: float, sets: list[str], progress: bool = False) -> Iterator[str]:
    from .closed_loop import CLOSED_LOOP_SETTINGS, run_closed_loop

    out_dir = Path(out_dir)
    cfg = load_scenario(None, CLOSED_LOOP_SETTINGS + [f"time.duration_s={duration_s}"] + sets)
    r = cfg["receiver"]
    yield (f"closed loop, {duration_s:g} s at {cfg['signal']['fs_hz'] / 1e6:g} MSa/s: vehicle hovering at "
           f"{r['lat_deg']:.4f}, {r['lon_deg']:.4f}; {_attacker_line(cfg['attacker'])}; "
           "world, receiver and flight side in three processes (pipe, authenticated link, MAVLink)")
    loop = run_closed_loop(out_dir, duration_s, sets, tee=True, show=progress)
    for error in loop.errors:
        yield f"error: {error}"
    alarm = loop.first("spoofing_alarm")
    if alarm:
        yield (f"SemperFi: spoofing alarm at t = {alarm['t_rx_s']:.2f} s; the receiver waits for a maneuver instead of "
               f"guessing which peak is the attacker's")
    asked, drawn, done = (loop.first(k, "flight") for k in ("alarm", "maneuver_drawn", "maneuver_done"))
    if asked and drawn and done:
        yield (f"flight side: asked at t = {asked['payload']['t_s']:.1f} s (on the alarm, once the receiver had a "
               f"fix); maneuver of "
               f"{drawn['legs']} legs drawn from the OS's cryptographic source, flown over MAVLink in GUIDED from "
               f"t = {done['start_s']:.1f} to {done['end_s']:.1f} s: {drawn['duration_s']:.1f} s, "
               f"{drawn['path_m']:.1f} m flown, ending {drawn['end_distance_m']:.1f} m from its start "
               f"(paper: 10-20 s, under 50 m)")
    verdict = loop.first("verdict", "flight")
    if verdict:
        peaks = verdict["payload"]["peaks"]
        adversarial = sorted({p["prn"] for p in peaks if p["decided"] and p["adversarial"]})
        legit = sorted({p["prn"] for p in peaks if p["decided"] and not p["adversarial"]})
        yield (f"identification: peaks that do not follow the vehicle's motion on PRNs {adversarial}; peaks that do on "
               f"PRNs {legit}; {sum(not p['decided'] for p in peaks)} undecided")
    summary = loop.first("defense_summary") or {}
    t, err = loop.fix_errors_m("recovered")
    if len(t):
        yield (f"SemperFi: cancelled PRNs {summary.get('cancelled')}; {len(t)} recovered fixes from t = {t[0]:.1f} s, "
               f"{np.mean(err):.2f} m from the vehicle's true position (max {np.max(err):.2f} m)")
    else:
        t_r, err_r = loop.fix_errors_m("recovering")
        yield ("SemperFi: no recovered fix yet" + (f"; {len(t_r)} fixes still recovering (a cancellation not yet "
               f"verified), {np.mean(err_r):.1f} m from the truth" if len(t_r) else "")
               + " (run longer: --duration 100)")
    beyond = sum(int(np.sum(loop.fix_errors_m(s)[1] > loop.fix_levels_m(s))) for s in TRUSTED_STATES)
    far = sum(int(np.sum(loop.fix_errors_m(s)[1] > 10.0)) for s in TRUSTED_STATES)
    yield (f"fixes labelled good (nominal, recovered, rectified) beyond their horizontal protection level: {beyond}; "
           f"farther than 10 m from the truth: {far}")
    for prn, stages in sorted(summary.get("attenuation_db", {}).items(), key=lambda kv: int(kv[0])):
        values = [v for st in stages for v in st["attenuation_db"]]
        yield f"  PRN {int(prn):>2}: spoofer attenuated by {values[-1] if values else '?'} dB"
    receiver_cfg = load_config(None, [])
    data = out_dir / "world.bin"
    run_file(data, None, None, None, receiver_cfg, out_dir / "conventional", live=progress)
    spoofed = _horizontal_errors_m(out_dir / "conventional" / "fixes.csv", r["lat_deg"], r["lon_deg"], r["height_m"])
    yield (f"conventional receiver on the same samples: {spoofed.size} fixes, {np.mean(spoofed):.0f} m from the truth "
           "(spoofed)" if spoofed.size else "conventional receiver: no fix")
    _tracks_plot(loop, r, out_dir / "tracks.png")
    plots = "tracks.png"
    cancelled = loop.first("cancellation_start")
    if cancelled is not None:
        _before_after_plot(data, load_config(None, ['defense.mode="full"']),
                           out_dir / "acquisition-before-after.png", cancelled["t_rx_s"] + BEFORE_AFTER_LAG_S)
        plots += ", acquisition-before-after.png"
    yield (f"outputs in {out_dir}: receiver/ (fixes.csv, NMEA, GPX, GeoJSON, RINEX, events.jsonl), flight.jsonl, "
           f"truth.csv, conventional/, {plots}")


def _attacker_line(a: dict) -> str:
    """The scenario's attacker in a few words, as the user set it."""
    if not a["enabled"]:
        return "no attacker"
    when = "from the first sample" if a["start_s"] == 0 else f"switched on at t = {a['start_s']:g} s"
    what = {"static": f"claiming a position {math.hypot(a['offset_east_m'], a['offset_north_m']):g} m away",
            "push": f"pushing the position off at {a['push_speed_m_s']:g} m/s",
            "takeover": f"a seamless takeover, aligned for {a['push_hold_s']:g} s, then dragging the position off at "
                        f"{a['push_speed_m_s']:g} m/s",
            "meaconing": f"meaconing with a {a['delay_s'] * 1e6:g} us delay"}[a["mode"]]
    return f"attacker {what}, {a['power_advantage_db']:+g} dB, {when}"


def _tracks_plot(loop, r: dict, out_png: Path) -> None:
    """North-east tracks: the vehicle's truth, SemperFi's fixes by state, the IMU track of the maneuver."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    origin = geodetic_to_ecef(np.radians(r["lat_deg"]), np.radians(r["lon_deg"]), r["height_m"])
    rot = enu_rotation(np.radians(r["lat_deg"]), np.radians(r["lon_deg"]))
    fig, ax = plt.subplots(figsize=(7, 6))
    truth = np.array([[float(x["east_m"]), float(x["north_m"])] for x in loop.truth])
    ax.plot(truth[:, 0], truth[:, 1], color="k", lw=2, label="truth")
    for state, color in (("spoofing_detected", "tab:red"), ("recovering", "tab:orange"), ("recovered", "tab:green"),
                         ("nominal", "tab:blue")):
        rows = [f for f in loop.fixes if f["state"] == state]
        if rows:
            enu = (np.array([[float(f[k]) for k in ("x_m", "y_m", "z_m")] for f in rows]) - origin) @ rot.T
            near = np.hypot(enu[:, 0], enu[:, 1]) < 200   # the spoofed fixes sit 1 km east: noted, not drawn
            ax.scatter(enu[near, 0], enu[near, 1], s=4, color=color,
                       label=f"GPS fixes: {state} ({len(rows) - int(near.sum())} beyond 200 m not shown)")
    done = loop.first("maneuver_done", "flight")
    if done:
        t0 = done["track"]["t_s"][0]
        t_truth = np.array([float(x["t_s"]) for x in loop.truth])
        at = np.array([np.interp(t0, t_truth, truth[:, k]) for k in range(2)])
        e, n = np.array(done["track"]["east_m"]), np.array(done["track"]["north_m"])
        ax.plot(at[0] + e - e[0], at[1] + n - n[0], color="tab:purple", ls="--", label="IMU track (maneuver)")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal")
    ax.legend(fontsize=7, loc="best")
    ax.set_title("closed loop: the vehicle, its GPS fixes and its IMU")
    fig.tight_layout()
    fig.savefig(out_png, dpi=120)
    plt.close(fig)
