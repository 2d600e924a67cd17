"""The receiver chain on simulated recordings: acquisition, subframes, ephemerides and fixes against the truth."""

import csv
import json

import numpy as np
import pytest

from semperfi.gps.constants import CA_CHIP_RATE_HZ, L1_HZ
from semperfi.gps.geometry import enu_rotation, geodetic_to_ecef
from semperfi.defense.config import load_config
from semperfi.receiver.run import NoSignal, run_file
from semperfi.sim.constellation import build_constellation
from semperfi.sim.run import simulate_to_file
from semperfi.sim.scenario import load_scenario
from semperfi.sim.truth import read_signal_truth, truth_paths

FS = 2e6
LAT, LON, H = 42.3398, -71.0892, 10.0


def simulate(path, *sets, duration):
    cfg = load_scenario(None, [f"signal.fs_hz={FS}", f"time.duration_s={duration}", *sets])
    simulate_to_file(cfg, path)
    return cfg


def receive(path, out_dir, nav=None, *sets):
    captured = {}
    summary = run_file(path, None, None, None, load_config(None, list(sets)), out_dir, nav,
                       receiver_hook=lambda r: captured.setdefault("receiver", r))
    return summary, captured["receiver"]


def read_fixes(out_dir):
    return list(csv.DictReader(open(out_dir / "fixes.csv")))


def enu_errors(fixes, truth_rows=None):
    """ENU error of each fix against the truth receiver position at the fix's own t_rx_s."""
    truth = {}
    if truth_rows:
        truth = {round(float(r["t_rx_s"]), 3): np.array([float(r[k]) for k in ("x_m", "y_m", "z_m")])
                 for r in truth_rows}
    static = geodetic_to_ecef(np.radians(LAT), np.radians(LON), H)
    rot = enu_rotation(np.radians(LAT), np.radians(LON))
    errs = []
    for f in fixes:
        ref = truth.get(round(float(f["t_rx_s"]), 3), static) if truth_rows else static
        errs.append(rot @ (np.array([float(f[k]) for k in ("x_m", "y_m", "z_m")]) - ref))
    return np.array(errs)


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("static")
    cfg = simulate(d / "s.bin", "constellation.max_satellites=8", duration=40.0)
    summary, receiver = receive(d / "s.bin", d / "out")
    return cfg, d, summary, receiver


def test_every_satellite_is_acquired_at_the_truths_code_phase_and_doppler(static_run):
    cfg, d, _, _ = static_run
    truth = [r for r in read_signal_truth(truth_paths(d / "s.bin")["signals.csv"]) if r["t_rx_s"] == 0.0]
    events = [json.loads(line) for line in open(d / "out" / "events.jsonl")]
    acq = {e["prn"]: e for e in events if e["event"] == "acquisition"}
    assert {int(r["prn"]) for r in truth} <= set(acq)
    for r in truth:
        e = acq[int(r["prn"])]
        expected = (r["code_phase_chips"] + e["t_rx_s"] * CA_CHIP_RATE_HZ * (1 + r["doppler_hz"] / L1_HZ)) % 1023
        assert abs((e["code_phase_chips"] - expected + 511.5) % 1023 - 511.5) < 0.2, (e, expected)
        assert abs(e["doppler_hz"] - r["doppler_hz"]) < 120.0, (e, r["doppler_hz"])


def test_subframes_decode_without_parity_errors_into_the_simulators_ephemerides(static_run):
    cfg, _, summary, receiver = static_run
    assert summary.stats.parity_errors == 0
    assert summary.stats.subframes >= 8 * 4
    sim_ephemerides = build_constellation(cfg).ephemerides
    decoded = {prn: dec.ephemeris for prn, dec in receiver.decoders.items() if dec.ephemeris is not None}
    assert len(decoded) >= 6
    for prn, eph in decoded.items():
        assert eph == sim_ephemerides[prn], f"PRN {prn}: decoded ephemeris differs from the broadcast one"


def test_static_fix_without_assistance_is_within_5_m(static_run):
    _, d, summary, _ = static_run
    fixes = read_fixes(d / "out")
    assert len(fixes) >= 20, f"{len(fixes)} fixes"
    enu = enu_errors(fixes)
    horizontal = np.hypot(enu[:, 0], enu[:, 1])
    assert np.mean(horizontal) < 5.0, f"horizontal error mean {np.mean(horizontal):.2f} m"
    assert np.max(np.abs(enu[:, 2])) < 25.0
    assert all(f["state"] == "nominal" for f in fixes)


def test_rinex_observations_read_back_by_georinex_give_the_same_fixes(static_run):
    """observations.rnx holds raw pseudoranges on the receiver's clock: solved again with the decoded ephemerides they
    land where the receiver's own (carrier-smoothed) fixes are, and the Doppler and C/N0 are the channels'."""
    georinex = pytest.importorskip("georinex", reason="georinex is not installed")
    from semperfi.gps.constants import SPEED_OF_LIGHT_M_S
    from semperfi.receiver.chain import FALLBACK_IONO
    from semperfi.receiver.pvt import solve
    from semperfi.receiver.types import Observation

    _, d, summary, receiver = static_run
    obs = georinex.load(d / "out" / "observations.rnx")
    fixes = read_fixes(d / "out")
    assert obs.time.size == len(fixes) == summary.stats.n_fixes
    ephemerides = {prn: dec.ephemeris for prn, dec in receiver.decoders.items() if dec.ephemeris is not None}
    for k in (0, len(fixes) // 2, len(fixes) - 1):
        fix = fixes[k]
        t = obs.time.values[k]
        tow_rx = (t - np.datetime64("1980-01-06T00:00:00")) / np.timedelta64(1, "ns") * 1e-9 % 604800.0
        sats = [(int(sv[1:]), float(obs["C1C"].sel(sv=sv, time=t)), float(obs["D1C"].sel(sv=sv, time=t)),
                 float(obs["S1C"].sel(sv=sv, time=t))) for sv in obs.sv.values
                if np.isfinite(obs["C1C"].sel(sv=sv, time=t))]
        assert {p for p, *_ in sats} == {int(p) for p in fix["prns"].split()}
        assert all(18e6 < pr < 28e6 and abs(dop) < 6000 and 25 < cn0 < 60 for _, pr, dop, cn0 in sats), sats
        again = solve([Observation(prn, pr, tow_rx - pr / SPEED_OF_LIGHT_M_S, dop, cn0, ephemerides[prn])
                       for prn, pr, dop, cn0 in sats], float(fix["t_rx_s"]), int(fix["gps_week"]), FALLBACK_IONO)
        ours = np.array([float(fix[c]) for c in ("x_m", "y_m", "z_m")])
        assert np.linalg.norm(again.pos_ecef_m - ours) < 5.0, (k, again.pos_ecef_m - ours)
        assert abs(again.clock_bias_m - float(fix["clock_bias_m"])) < 5.0
    from semperfi.gps.constants import L1_WAVELENGTH_M
    for sv in obs.sv.values:   # carrier phase has the sign of the range: over the run it moves as the code does
        c, phase_cycles = obs["C1C"].sel(sv=sv).values, obs["L1C"].sel(sv=sv).values
        ok = np.isfinite(c) & np.isfinite(phase_cycles)
        assert ok.mean() > 0.9, sv
        code_m, phase_m = c[ok][-1] - c[ok][0], L1_WAVELENGTH_M * (phase_cycles[ok][-1] - phase_cycles[ok][0])
        assert abs(code_m - phase_m) < 10.0, (sv, code_m, phase_m)


def test_assisted_static_fix_is_within_5_m_and_quick(tmp_path, brdc_path):
    simulate(tmp_path / "a.bin", f'constellation.rinex="{brdc_path}"', 'time.start="2022-01-01T00:00:27"',
             duration=18.0)
    summary, _ = receive(tmp_path / "a.bin", tmp_path / "out", str(brdc_path))
    assert summary.stats.first_fix_t_rx_s is not None and summary.stats.first_fix_t_rx_s < 16.0
    enu = enu_errors(read_fixes(tmp_path / "out"))
    horizontal = np.hypot(enu[:, 0], enu[:, 1])
    assert np.mean(horizontal) < 5.0, f"horizontal error mean {np.mean(horizontal):.2f} m"


def test_circular_trajectory_at_10_m_s_is_tracked_within_10_m(tmp_path, brdc_path):
    center = geodetic_to_ecef(np.radians(LAT), np.radians(LON), H)
    east, north = enu_rotation(np.radians(LAT), np.radians(LON))[:2]
    t = np.arange(0.0, 20.05, 0.1)
    w = 10.0 / 50.0   # 10 m/s on a 50 m radius
    xyz = center + np.outer(50 * np.cos(w * t), east) + np.outer(50 * np.sin(w * t), north)
    traj = tmp_path / "circle.csv"
    traj.write_text("".join(f"{ti:.1f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n" for ti, p in zip(t, xyz)))
    simulate(tmp_path / "c.bin", f'constellation.rinex="{brdc_path}"', 'time.start="2022-01-01T00:00:27"',
             f'receiver.trajectory="{traj}"', duration=20.0)
    receive(tmp_path / "c.bin", tmp_path / "out", str(brdc_path))
    fixes = read_fixes(tmp_path / "out")
    assert len(fixes) >= 30
    truth = list(csv.DictReader(open(truth_paths(tmp_path / "c.bin")["receiver.csv"])))
    enu = enu_errors(fixes, truth)
    err3d = np.linalg.norm(enu, axis=1)
    assert np.max(np.hypot(enu[:, 0], enu[:, 1])) < 10.0, \
        f"worst horizontal error {np.max(np.hypot(enu[:, 0], enu[:, 1])):.1f} m"
    speeds = [np.hypot(float(f["vx_m_s"]), float(f["vy_m_s"])) for f in fixes]
    assert np.median(np.abs(np.array([np.linalg.norm([float(f[k]) for k in ("vx_m_s", "vy_m_s", "vz_m_s")])
                                      for f in fixes]) - 10.0)) < 0.5
    assert np.mean(err3d) < 15.0 and len(speeds) == len(fixes)


def test_truncated_recording_gives_fixes_to_its_end(static_run, tmp_path):
    _, d, summary, _ = static_run
    data = (d / "s.bin").read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[: int(len(data) * 0.95) // 4 * 4 + 3])   # ends mid-sample
    (tmp_path / "cut.sigmf-meta").write_text((d / "s.sigmf-meta").read_text().replace("s.bin", "cut.bin"))
    short, _ = receive(cut, tmp_path / "out")
    assert short.truncated_bytes == 3
    fixes = read_fixes(tmp_path / "out")
    assert fixes and float(fixes[-1]["t_rx_s"]) > 0.9 * 38.0 - 1.0
    events = [json.loads(line)["event"] for line in open(tmp_path / "out" / "events.jsonl")]
    assert "truncated_input" in events


def test_wrong_sample_rate_says_what_to_check(static_run, tmp_path):
    _, d, _, _ = static_run
    with pytest.raises(ValueError, match="disagrees with SigMF"):   # the sidecar knows better
        run_file(d / "s.bin", "ishort", 2.5e6, 0.0, load_config(), tmp_path / "out")
    bare = tmp_path / "bare.bin"
    bare.write_bytes((d / "s.bin").read_bytes()[: int(4 * FS * 4.0)])   # 4 s, no sidecar
    with pytest.raises(NoSignal, match="--fs"):
        run_file(bare, "ishort", 2.5e6, 0.0, load_config(), tmp_path / "out")
    with pytest.raises(NoSignal, match="--format"):
        run_file(bare, "ibyte", 2e6, 0.0, load_config(), tmp_path / "out2")


def test_a_loss_of_lock_costs_no_subframe_the_next_channel_takes_the_time_on(tmp_path, brdc_path):
    """A second of nothing at 12 s: every channel loses lock. The channels acquired after it take the time the lost
    ones had read (receiver/carried_time), so the fixes come back with the loops (some 1.5 s after the signals), not
    with the next HOW (6 s or more), and as accurate as before. Then 7 s of nothing from 17 s, longer than a lost
    channel's time is carried (DONOR_REACH_S): the channels after it take their whole milliseconds from the receiver's
    clock, what the last fix predicts, and the fixes come back as soon (the next HOW would be at 27 s, read by 33 s)."""
    simulate(tmp_path / "a.bin", f'constellation.rinex="{brdc_path}"', 'time.start="2022-01-01T00:00:27"',
             duration=30.0)
    x = np.fromfile(tmp_path / "a.bin", dtype=np.int16)     # the simulator's ci16_le
    x[int(12.0 * FS) * 2:int(13.0 * FS) * 2] = 0
    x[int(17.0 * FS) * 2:int(24.0 * FS) * 2] = 0
    x.tofile(tmp_path / "a.bin")
    receive(tmp_path / "a.bin", tmp_path / "out", str(brdc_path))
    events = [json.loads(line) for line in open(tmp_path / "out" / "events.jsonl")]
    for start_s in (12.0, 17.0):
        lost = {e["prn"] for e in events if e["event"] == "loss_of_lock" and start_s < e["t_rx_s"] < start_s + 1.5}
        assert len(lost) >= 4, (start_s, lost)
    inherited = [e for e in events if e["event"] == "time_inherited"]
    assert len(inherited) >= 4 and all(0.5 < e["gap_s"] < 5.0 and e["t_rx_s"] < 17.0 for e in inherited), inherited
    clocked = [e for e in events if e["event"] == "time_from_clock"]
    assert len(clocked) >= 4 and all(24.0 < e["t_rx_s"] < 27.0 and 7.0 < e["fix_age_s"] < 10.0
                                     for e in clocked), clocked
    fixes = read_fixes(tmp_path / "out")
    t = np.array([float(f["t_rx_s"]) for f in fixes])
    assert t[t < 12.0].size and t[t > 13.0].size and t[t > 13.0][0] < 15.5, t[t > 11.0][:3]
    assert t[t > 24.0].size and t[t > 24.0][0] < 26.5, t[t > 16.0][:3]
    err = enu_errors([f for f in fixes if float(f["t_rx_s"]) > 13.0])
    assert np.max(np.hypot(err[:, 0], err[:, 1])) < 10.0


def test_a_prn_the_defence_found_absent_is_not_searched_warm_either():
    """A PRN lost moments ago is searched around its last Doppler at every acquisition; once a more sensitive search
    (the defence's full look) found nothing of it, it waits for that search to see it again (cross-talk channels
    lost during an attack, twelve searched every half second, were a fifth of the receiver's time)."""
    from semperfi.receiver.chain import Receiver
    rx = Receiver(load_config(None, []), 2e6)
    rx._buf = np.zeros(rx.acq_samples, dtype=np.complex64)
    searched = []
    rx._search = lambda samples, prns, center_hz=0.0, span_hz=None: searched.extend(prns) or {}
    rx.prns = [5, 7]
    rx.warm = {5: 1200.0, 7: -800.0}
    rx.absent_prns = frozenset({5})
    rx._acquire()
    assert searched == [7]
    rx.absent_prns = frozenset()
    searched.clear()
    rx._acquire()
    assert sorted(searched) == [5, 7]
