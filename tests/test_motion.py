"""Receiver motion: 10 Hz trajectory files as gps-sdr-sim reads them, and live driving by a vehicle model."""

import csv

import numpy as np
import pytest

from semperfi.gps.constants import L1_WAVELENGTH_M
from semperfi.gps.geometry import enu_rotation, geodetic_to_ecef
from semperfi.sim.run import simulate_to_file
from semperfi.sim.scenario import load_scenario
from semperfi.sim.simulate import make_live_simulator
from semperfi.sim.truth import read_signal_truth, truth_paths

LAT, LON, H = 42.3398, -71.0892, 10.0


def circle_csv(path, lla: bool, radius_m=100.0, speed_m_s=10.0, duration_s=4.0):
    center = geodetic_to_ecef(np.radians(LAT), np.radians(LON), H)
    enu_to_ecef = enu_rotation(np.radians(LAT), np.radians(LON)).T
    t = np.arange(0, duration_s + 1e-9, 0.1)
    w = speed_m_s / radius_m
    enu = np.stack([radius_m * np.cos(w * t), radius_m * np.sin(w * t), np.zeros_like(t)], axis=1)
    xyz = center + enu @ enu_to_ecef.T
    with open(path, "w") as f:
        for ti, p in zip(t, xyz):
            if lla:
                from semperfi.gps.geometry import ecef_to_geodetic
                la, lo, h = ecef_to_geodetic(p)
                f.write(f"{ti:.1f},{np.degrees(la):.10f},{np.degrees(lo):.10f},{h:.4f}\n")
            else:
                f.write(f"{ti:.1f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n")
    return t, xyz


@pytest.mark.parametrize("lla", [False, True])
def test_trajectory_file_is_followed_and_doppler_matches_pseudorange_rate(tmp_path, lla):
    t, xyz = circle_csv(tmp_path / "traj.csv", lla)
    cfg = load_scenario(None, ["signal.fs_hz=2e6", "time.duration_s=3.0",
                               f'receiver.trajectory="{tmp_path / "traj.csv"}"',
                               f"receiver.trajectory_lla={'true' if lla else 'false'}",
                               "constellation.max_satellites=6", "constellation.ionosphere=false"])
    out = tmp_path / "moving.bin"
    simulate_to_file(cfg, out)
    rx = list(csv.DictReader(open(truth_paths(out)["receiver.csv"])))
    for row in rx:
        i = int(round(float(row["t_rx_s"]) * 10))
        pos = np.array([float(row["x_m"]), float(row["y_m"]), float(row["z_m"])])
        # the clock drift (5e-8) shifts true time by 0.15 us over 3 s: 1.5 um at 10 m/s
        assert np.linalg.norm(pos - xyz[i]) < 0.01, (row["t_rx_s"], np.linalg.norm(pos - xyz[i]))
        assert np.linalg.norm([float(row[k]) for k in ("vx_m_s", "vy_m_s", "vz_m_s")]) == pytest.approx(10.0, rel=1e-3)
    sig = read_signal_truth(truth_paths(out)["signals.csv"])
    for prn in {r["prn"] for r in sig}:
        rows = [r for r in sig if r["prn"] == prn]
        pr = np.array([r["pseudorange_m"] for r in rows])
        ts = np.array([r["t_rx_s"] for r in rows])
        dop = np.array([r["doppler_hz"] for r in rows])
        rate = np.gradient(pr, ts)
        # code and carrier are one: Doppler = -pseudorange rate / wavelength (to the truth log's rounding)
        assert np.max(np.abs(dop[1:-1] + rate[1:-1] / L1_WAVELENGTH_M)) < 2.0


def test_live_motion_moves_the_signals(tmp_path):
    cfg = load_scenario(None, ["signal.fs_hz=2e6", "time.duration_s=1.0", "constellation.max_satellites=4"])
    sim, motion = make_live_simulator(cfg)
    start = motion.state(0.0)[0][0]
    east = enu_rotation(np.radians(LAT), np.radians(LON))[0]
    seen = []
    for i, _ in enumerate(sim.chunks(lambda rx, sigs: seen.append((rx, sigs)), truth_every_s=0.02)):
        t = (i + 1) * 0.02
        motion.set_state(t, start + east * 20.0 * t, east * 20.0)   # 20 m/s east, updated each chunk
    last_rx, _ = seen[-1]
    moved = float(np.dot(last_rx.pos_ecef_m - start, east))
    assert moved == pytest.approx(20.0 * last_rx.t_rx_s, abs=0.05)
    assert np.allclose(last_rx.vel_ecef_m_s, east * 20.0)


def test_trajectory_file_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("0,1,2,3\n0.1,1,2,3\n")
    from semperfi.sim.motion import TrajectoryMotion
    with pytest.raises(ValueError, match="near the Earth"):
        TrajectoryMotion.from_csv(bad)
    bad.write_text("time,x,y,z\nfoo,bar,baz,qux\n")
    with pytest.raises(ValueError, match="numeric"):
        TrajectoryMotion.from_csv(bad)
