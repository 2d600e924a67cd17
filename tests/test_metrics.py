"""The issue-22 grid's metrics (semperfi.eval.metrics) on synthetic fixes whose answers are known, and the time
push's fractional delay (semperfi.eval.xgen.delayed_scene) on band-limited noise. No generator needed."""

import csv
import itertools
import json

import numpy as np
import pymap3d
import pytest

from semperfi.eval.metrics import (Truth, availability, errors, gps_time, position_errors, run_metrics,
                                   time_errors_ns)
from semperfi.eval.xgen import F_L1_HZ, delayed_scene, scene_reader

LAT, LON, H = 42.3398, -71.0892, 10.0
START = gps_time("2022/01/01,00:00:00")


def write_fixes(path, t, east_m, state="nominal", hpl=5.0, vpl=8.0, up_m=0.0, time_err_ns=0.0, tpl=None):
    """fixes.csv rows (the receiver's columns, tpl_ns when given) at receiver times t, east_m off the truth."""
    t = np.asarray(t, dtype=float)
    n = t.size
    given = {"east": east_m, "state": state, "hpl": hpl, "vpl": vpl, "up": up_m, "terr": time_err_ns, "tpl": tpl}
    cols = {k: np.broadcast_to(np.asarray(v, dtype=object), (n,)) for k, v in given.items()}
    header = ["t_rx_s", "gps_week", "gps_tow_s", "x_m", "y_m", "z_m", "state", "hpl_m", "vpl_m"]
    header += ["tpl_ns"] if tpl is not None else []
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for i in range(n):
            x, y, z = pymap3d.enu2ecef(float(cols["east"][i]), 0.0, float(cols["up"][i]), LAT, LON, H)
            tow = START[1] + t[i] + float(cols["terr"][i]) * 1e-9
            row = [f"{t[i]:.9f}", START[0], f"{tow:.9f}", f"{x:.4f}", f"{y:.4f}", f"{z:.4f}", cols["state"][i],
                   cols["hpl"][i], cols["vpl"][i]]
            w.writerow(row + ([cols["tpl"][i]] if tpl is not None else []))
    return path


def write_events(path, *events):
    path.write_text("".join(json.dumps({"t_rx_s": t, "event": kind, **fields}) + "\n" for t, kind, fields in events))
    return path


TRUTH = Truth(LAT, LON, H, start_gps=START)


@pytest.mark.parametrize("heading_deg", [0.0, 90.0, 225.0])
def test_every_error_measure_of_one_offset(heading_deg):
    """3 m east, 4 m north, 2 m down of a vehicle heading `heading_deg`: 5 m horizontal, 2 m vertical, sqrt(29) in
    3-D, and the along/cross-track split of the same 5 m by the heading (cross positive to the right)."""
    true = np.array(pymap3d.geodetic2ecef(LAT, LON, H))[None]
    pos = np.array(pymap3d.enu2ecef(3.0, 4.0, -2.0, LAT, LON, H))[None]
    h = np.radians(heading_deg)
    v = np.array(pymap3d.enu2uvw(5.0 * np.sin(h), 5.0 * np.cos(h), 0.0, LAT, LON))[None]
    e = errors(pos, true, v)
    assert (e.east_m[0], e.north_m[0], e.up_m[0]) == pytest.approx((3.0, 4.0, -2.0), abs=1e-6)
    assert (e.horizontal_m[0], e.vertical_m[0], e.three_d_m[0]) == pytest.approx((5.0, 2.0, 29 ** 0.5), abs=1e-6)
    assert e.along_m[0] == pytest.approx(3.0 * np.sin(h) + 4.0 * np.cos(h), abs=1e-6)
    assert e.cross_m[0] == pytest.approx(3.0 * np.cos(h) - 4.0 * np.sin(h), abs=1e-6)
    assert np.isnan(errors(pos, true).along_m[0])          # a truth that does not move has no track


def test_position_errors_take_the_track_from_a_motion_file(tmp_path):
    """A receiver flying north at 5 m/s, fixes 2 m to its right: 2 m across, nothing along, at every fix."""
    t = np.arange(0.0, 10.01, 0.1)
    track = np.column_stack([t, *pymap3d.enu2ecef(0.0 * t, 5.0 * t, 0.0 * t, LAT, LON, H)])
    motion = tmp_path / "m.csv"
    np.savetxt(motion, track, delimiter=",")
    fixes = np.column_stack(pymap3d.enu2ecef(2.0 + 0 * t, 5.0 * t, 0.0 * t, LAT, LON, H))[10:90]
    e = position_errors(t[10:90], fixes, Truth(LAT, LON, H, str(motion)))
    assert np.allclose(e.cross_m, 2.0, atol=1e-3) and np.allclose(e.along_m, 0.0, atol=1e-3)


def test_availability_counts_epochs_and_the_longest_gap():
    t = np.round(np.arange(100, 300) / 10, 1)            # fixes 10.0 .. 29.9 s
    usable = np.ones(t.size, dtype=bool)
    usable[(t >= 15.0) & (t < 17.5)] = False             # 25 epochs unusable
    share, gap = availability(t, usable, 10.0, 30.0)
    assert share == pytest.approx(175 / 200) and gap == pytest.approx(2.5)
    # from 5 s (a clean first fix earlier than this run's): the 5 s before the first fix are a gap too
    share, gap = availability(t, usable, 5.0, 30.0)
    assert share == pytest.approx(175 / 250) and gap == pytest.approx(5.0)
    # the recording runs on 10 s past the last fix: the end is a gap
    share, gap = availability(t, usable, 10.0, 40.0)
    assert share == pytest.approx(175 / 300) and gap == pytest.approx(10.0)
    assert availability(t, np.zeros(t.size, bool), 10.0, 30.0) == (0.0, pytest.approx(20.0))
    assert np.isnan(availability(t, usable, 30.0, 30.0)[0])


def test_run_metrics_availability_excludes_wrong_and_spoofing_detected_fixes(tmp_path):
    t = np.round(np.arange(50, 400) / 10, 1)             # 5.0 .. 39.9 s
    east = np.where((t >= 20.0) & (t < 22.0), 50.0, 1.0)  # 2 s dragged 50 m east
    state = np.where((t >= 30.0) & (t < 33.0), "spoofing_detected", "nominal")
    fixes = write_fixes(tmp_path / "fixes.csv", t, east, state)
    events = write_events(tmp_path / "events.jsonl")
    m = run_metrics(fixes, events, TRUTH, duration_s=40.0, clean_first_fix_s=5.0)
    assert m["crash"] is False and m["error"] is None and m["fixes"] == t.size
    assert m["availability"] == pytest.approx((350 - 20 - 30) / 350, abs=1e-4)
    assert m["longest_gap_s"] == pytest.approx(3.0)
    # what an autopilot is given: the good fixes only (spoofing_detected is not good, nor a wrong nominal one)
    assert m["good_availability"] == pytest.approx(m["availability"], abs=1e-4)
    recovering = write_fixes(tmp_path / "fixes2.csv", t, east,
                             np.where((t >= 25.0) & (state == "nominal"), "recovering", state))
    m2 = run_metrics(recovering, events, TRUTH, duration_s=40.0, clean_first_fix_s=5.0)
    assert m2["availability"] == pytest.approx(m["availability"], abs=1e-4)
    assert m2["good_availability"] == pytest.approx((200 - 20) / 350, abs=1e-4)
    assert m2["longest_good_gap_s"] == pytest.approx(15.0)
    assert m["last_mean_m"] == pytest.approx(1.0, abs=1e-3)
    assert m["good_but_wrong"] == 20            # the dragged fixes, called nominal
    assert m["good_beyond_hpl"] == 20           # 50 m > 5 m; 1 m < 5 m
    assert m["good_fixes"] == t.size - 30


def test_run_metrics_counts_good_fixes_beyond_their_protection_levels(tmp_path):
    t = np.round(np.arange(100, 200) / 10, 1)
    hpl = np.where(t < 12.0, 0.5, 5.0)                    # 20 fixes whose 1 m error is beyond their HPL
    vpl = np.where(t >= 19.0, 1.0, 8.0)                   # 10 fixes whose 3 m up error is beyond their VPL
    state = np.where((t >= 11.0) & (t < 11.5), "recovering", "recovered")   # 5 of the 20 not called good
    up = np.full(t.size, 3.0)
    terr = np.where(t >= 15.0, 80.0, -20.0)               # ns; 50 fixes beyond a 50 ns TPL
    fixes = write_fixes(tmp_path / "fixes.csv", t, 1.0, state, hpl, vpl, up, terr, tpl=50.0)
    m = run_metrics(fixes, write_events(tmp_path / "events.jsonl"), TRUTH, duration_s=20.0, clean_first_fix_s=10.0)
    assert m["good_beyond_hpl"] == 15
    assert m["good_beyond_vpl"] == 10
    assert m["good_beyond_tpl"] == 50
    assert m["time_err_max_ns"] == pytest.approx(80.0, abs=0.5)
    assert m["time_err_last_ns"] == pytest.approx(30.0, abs=0.5)       # the mean of every fix of the last 10 s
    # a nan protection level (no redundancy) is no violation; without tpl_ns (or a time truth) there is no count
    fixes = write_fixes(tmp_path / "nan.csv", t, 100.0, hpl="", vpl="")
    m = run_metrics(fixes, tmp_path / "none.jsonl", Truth(LAT, LON, H), duration_s=20.0)
    assert m["good_beyond_hpl"] == 0 and m["good_beyond_vpl"] == 0 and m["good_but_wrong"] == t.size
    assert m["good_beyond_tpl"] is None and m["time_err_max_ns"] is None


def test_time_errors_hold_nanoseconds_a_week_into_gps_time(tmp_path):
    t = np.array([13.2, 13.3])
    f = {"t_rx_s": t, "gps_week": np.full(2, START[0]), "gps_tow_s": START[1] + t + np.array([-5e-9, 12e-9])}
    assert time_errors_ns(f, START) == pytest.approx([-5.0, 12.0], abs=0.05)
    assert gps_time("2022/01/01,00:04:07") == (2190, 518647.0)


def test_run_metrics_times_the_alarm_the_verdict_and_the_recovery(tmp_path):
    t = np.round(np.arange(100, 400) / 10, 1)
    state = np.select([t < 20.0, t < 31.5], ["nominal", "recovering"], "recovered")
    state[(t >= 25.0) & (t < 25.5)] = "rectified"        # before the verdict: not the recovery after it
    fixes = write_fixes(tmp_path / "fixes.csv", t, 1.0, state)
    events = write_events(tmp_path / "events.jsonl", (20.05, "spoofing_alarm", {}), (28.0, "identification", {}),
                          (29.0, "identification", {}), (31.5, "recovered", {"time_to_recover_s": 11.45}))
    m = run_metrics(fixes, events, TRUTH, duration_s=40.0, wall_s=12.34)
    assert (m["alarm_s"], m["verdict_s"], m["recovered_s"], m["verdict_to_recovered_s"]) == (20.05, 28.0, 31.5, 3.5)
    assert m["wall_s"] == 12.3
    # no maneuver, no verdict: from the alarm (the rectified fixes at 25 s come first then)
    events = write_events(tmp_path / "alarm.jsonl", (20.05, "spoofing_alarm", {}))
    m = run_metrics(fixes, events, TRUTH, duration_s=40.0)
    assert m["verdict_s"] is None and m["recovered_s"] == 25.0 and m["verdict_to_recovered_s"] == 4.95


def test_run_metrics_records_a_crash_and_measures_what_was_written(tmp_path):
    t = np.round(np.arange(100, 150) / 10, 1)            # the receiver died at 15 s of 40
    fixes = write_fixes(tmp_path / "fixes.csv", t, 1.0)
    m = run_metrics(fixes, write_events(tmp_path / "events.jsonl"), TRUTH, duration_s=40.0, clean_first_fix_s=10.0,
                    crash="TypeError: unsupported operand type(s) for *: 'NoneType' and 'int'\n  more")
    assert m["crash"] is True and m["error"].startswith("TypeError") and "\n" not in m["error"]
    assert m["availability"] == pytest.approx(50 / 300, abs=1e-4) and m["longest_gap_s"] == pytest.approx(25.0)
    assert m["last_mean_m"] is None                       # no fix in the last 10 s
    events = write_events(tmp_path / "internal.jsonl", (12.0, "internal_error", {"error": "ValueError: boom"}))
    m = run_metrics(fixes, events, TRUTH, duration_s=40.0)
    assert m["crash"] is True and m["error"] == "ValueError: boom"
    m = run_metrics(tmp_path / "missing.csv", tmp_path / "missing.jsonl", TRUTH, duration_s=40.0,
                    clean_first_fix_s=10.0, crash="RuntimeError: at start")
    assert m["fixes"] == 0 and m["availability"] == 0.0 and m["longest_gap_s"] == pytest.approx(30.0)


def test_run_metrics_follows_a_motion_file(tmp_path):
    """The truth moves east at 5 m/s; fixes on the path are right, a static fix is wrong once it has moved 10 m."""
    t_path = np.arange(0, 401) / 10
    ecef = np.column_stack(pymap3d.enu2ecef(5.0 * t_path, 0.0 * t_path, 0.0 * t_path, LAT, LON, H))
    motion = tmp_path / "motion.csv"
    np.savetxt(motion, np.column_stack([t_path, ecef]), delimiter=",", fmt="%.4f")
    t = np.round(np.arange(100, 400) / 10, 1) + 0.05      # between two rows: interpolated
    fixes = write_fixes(tmp_path / "fixes.csv", t, 5.0 * t)
    m = run_metrics(fixes, tmp_path / "none.jsonl", Truth(LAT, LON, H, str(motion)), duration_s=40.0)
    assert m["max_m"] < 0.01 and m["good_but_wrong"] == 0
    fixes = write_fixes(tmp_path / "still.csv", t, 50.0)  # at the path's 10 s point all along
    m = run_metrics(fixes, tmp_path / "none.jsonl", Truth(LAT, LON, H, str(motion)), duration_s=40.0)
    assert m["good_but_wrong"] == int(np.sum(np.abs(5.0 * t - 50.0) > 10.0))


def _band_limited_noise(n, fs_hz, seed=3, band=0.4):
    rng = np.random.default_rng(seed)
    x = np.fft.fft(rng.standard_normal(n) + 1j * rng.standard_normal(n))
    x[np.abs(np.fft.fftfreq(n, 1 / fs_hz)) > band * fs_hz] = 0.0
    return np.fft.ifft(x)


def _delay_of(x, y, fs_hz, up=32):
    """y's delay behind x (s) from the peak of their cross-correlation (upsampled, parabolic), and its phase."""
    c = np.conj(np.fft.fft(x)) * np.fft.fft(y)
    n = len(x)
    padded = np.zeros(n * up, dtype=complex)
    padded[:n // 2], padded[-(n // 2):] = c[:n // 2], c[-(n // 2):]
    r = np.fft.ifft(padded)
    k = int(np.argmax(np.abs(r)))
    a, b, d = np.abs(r[k - 1]), np.abs(r[k]), np.abs(r[(k + 1) % r.size])
    lag = k + 0.5 * (a - d) / (a - 2 * b + d)
    lag = lag if lag < r.size / 2 else lag - r.size
    return lag / up / fs_hz, np.angle(r[k])


def _int16_scene(x):
    return np.round(np.column_stack([x.real, x.imag]).ravel() * 1000).astype(np.int16)


@pytest.mark.parametrize("delay_ns", [0.0, 123.4, 1234.5, 2999.0])
def test_a_fixed_delay_correlates_with_the_original_at_that_delay(delay_ns):
    """Band-limited noise delayed by a known fraction of a sample: the cross-correlation peaks at that delay within
    1 ns and its phase is the carrier's -2 pi f_L1 d."""
    fs = 2.6e6
    a = _int16_scene(_band_limited_noise(int(0.03 * fs), fs))
    read = scene_reader(a)
    x = read(0, a.size // 2)
    y = delayed_scene(read, 0, x.size, fs, lambda t: np.full_like(t, delay_ns * 1e-9))
    inner = slice(1000, x.size - 1000)
    d, phase = _delay_of(x[inner], y[inner], fs)
    assert abs(d * 1e9 - delay_ns) < 1.0, d * 1e9
    expected = -2 * np.pi * F_L1_HZ * delay_ns * 1e-9
    assert abs(np.angle(np.exp(1j * (phase - expected)))) < 0.01, (phase, expected)


def test_a_growing_delay_is_the_ramp_asked_for_block_after_block():
    """A push at 2 us/s from 20 ms, made in 1 ms sub-blocks over three calls (as the mixer's blocks): in each 10 ms
    window the copy, its carrier rotation undone, lags the original by the ramp's mid-window value within 1 ns."""
    fs, rate, t0 = 2.6e6, 2e-6, 0.02
    a = _int16_scene(_band_limited_noise(int(0.2 * fs), fs, seed=5))
    read = scene_reader(a)
    x = read(0, a.size // 2)

    def delay(t):
        return rate * np.clip(t - t0, 0.0, None)
    edges = [0, 123457, 300001, x.size]
    y = np.concatenate([delayed_scene(read, s, e - s, fs, delay) for s, e in itertools.pairwise(edges)])
    t = np.arange(x.size) / fs
    y = y * np.exp(2j * np.pi * F_L1_HZ * delay(t))
    for w0 in (0.005, 0.05, 0.1, 0.15, 0.18):
        win = slice(int(w0 * fs), int((w0 + 0.01) * fs))
        d, _ = _delay_of(x[win], y[win], fs)
        assert abs(d - delay(w0 + 0.005)) < 1e-9, (w0, d * 1e9, delay(w0 + 0.005) * 1e9)
