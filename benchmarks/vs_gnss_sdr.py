"""SemperFi's receiver and GNSS-SDR on the same simulated recordings, in one run, side by side.

    .venv/bin/python benchmarks/vs_gnss_sdr.py [--duration 90] [--rates 4e6,10e6] [--work DIR]

For each sample rate: a 90 s static file (ishort, 45 dB-Hz, brdc0010.22n ephemerides), then both receivers, each
unassisted; horizontal error (mean, 95th percentile) against the truth, time to first fix, wall time and the ratio
of our wall time to GNSS-SDR's. Needs gnss-sdr (scripts/crosscheck-gnss-sdr installs it).
"""

# Where the time goes (cProfile, `semperfi run` on 40 s at 4 MSa/s ishort, 9 satellites, loaded 2-core machine,
# before issue 10): 17.3 s CPU / 23.8 s wall; tracking.track_kernel 14.2 s (60 %: ~6.7 ns per sample per channel,
# the per-sample float->int code/carrier lookups and the carrier wrap branch), acquisition.acquire 6.2 s cumulative
# (26 %: Doppler wipe-off + FFTs, scipy c2c 1.8 s), Python per chunk (Channel.process, nav, lock) < 1.5 s.
# Correlator micro-benchmark after the fixed-point/float32 kernel: 4.3 ns per sample (from 6.7).


import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from semperfi.eval.crosscheck import fix_times_rx_s, read_truth   # noqa: E402
from semperfi.eval.gnss_sdr import horizontal_errors_m, run_gnss_sdr   # noqa: E402
from semperfi.receiver.run import load_receiver_config, run_file   # noqa: E402
from semperfi.sim.run import simulate_to_file   # noqa: E402
from semperfi.sim.scenario import load_scenario   # noqa: E402

BRDC = REPO.parent / "shared" / "data" / "brdc0010.22n"


def ours(path: Path, out: Path, truth: dict) -> dict:
    t0 = time.perf_counter()
    summary = run_file(path, None, None, None, load_receiver_config(), out)
    wall = time.perf_counter() - t0
    rows = list(csv.DictReader(open(out / "fixes.csv")))
    lat, lon = np.array([float(r["lat_deg"]) for r in rows]), np.array([float(r["lon_deg"]) for r in rows])
    err = _horizontal(lat, lon, truth)
    return {"fixes": len(rows), "mean": err.mean(), "p95": np.percentile(err, 95), "ttff": summary.stats.first_fix_t_rx_s,
            "wall": wall}


def gnss_sdr(path: Path, fs: float, out: Path, truth: dict) -> dict:
    t0 = time.perf_counter()
    fixes = run_gnss_sdr(path, fs, "ishort", 0.0, out, timeout_s=3600)
    wall = time.perf_counter() - t0
    err = horizontal_errors_m(fixes, truth["lat_deg"][0], truth["lon_deg"][0])
    return {"fixes": len(fixes), "mean": err.mean(), "p95": np.percentile(err, 95),
            "ttff": float(fix_times_rx_s(fixes[:1], truth)[0]), "wall": wall}


def _horizontal(lat, lon, truth):
    class F:   # horizontal_errors_m reads lat_deg / lon_deg attributes
        def __init__(self, a, b):
            self.lat_deg, self.lon_deg = a, b
    return horizontal_errors_m([F(a, b) for a, b in zip(lat, lon)], truth["lat_deg"][0], truth["lon_deg"][0])


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--duration", type=float, default=90.0)
    p.add_argument("--rates", default="4e6,10e6")
    p.add_argument("--work", type=Path, default=Path("/tmp/semperfi-vs-gnss-sdr"))
    a = p.parse_args()
    lines = []
    for fs in (float(r) for r in a.rates.split(",")):
        work = a.work / f"{fs / 1e6:g}MSa"
        work.mkdir(parents=True, exist_ok=True)
        data = work / "static.bin"
        if not data.exists():
            cfg = load_scenario(None, [f"signal.fs_hz={fs}", f"time.duration_s={a.duration}",
                                       f'constellation.rinex="{BRDC}"', "constellation.cn0_dbhz=45.0"])
            simulate_to_file(cfg, data)
        truth = read_truth(work / "static.truth-receiver.csv")
        r_gs = gnss_sdr(data, fs, work / "gnss-sdr", truth)
        r_us = ours(data, work / "semperfi", truth)
        lines.append(f"\n{a.duration:g} s static, {fs / 1e6:g} MSa/s ishort, 45 dB-Hz")
        lines.append(f"{'':12}{'fixes':>7}{'mean [m]':>10}{'p95 [m]':>9}{'TTFF [s]':>10}{'wall [s]':>10}")
        for name, r in (("GNSS-SDR", r_gs), ("SemperFi", r_us)):
            lines.append(f"{name:12}{r['fixes']:>7}{r['mean']:>10.2f}{r['p95']:>9.2f}{r['ttff']:>10.1f}{r['wall']:>10.1f}")
        lines.append(f"SemperFi wall time / GNSS-SDR wall time: {r_us['wall'] / r_gs['wall']:.2f}; "
                     f"SemperFi {a.duration / r_us['wall']:.2f}x real time")
        print("\n".join(lines[-5:]), flush=True)


if __name__ == "__main__":
    main()
