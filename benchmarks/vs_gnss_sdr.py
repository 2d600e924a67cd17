"""SemperFi's receiver and GNSS-SDR on the same simulated recordings, in one run, side by side.

    .venv/bin/python benchmarks/vs_gnss_sdr.py [--duration 60] [--rates 2.6e6,4e6,10e6] [--repeat 2] [--work DIR]

For each sample rate: a static recording (ishort, 45 dB-Hz, the brdc0010.22n ephemerides), then both receivers as
whole commands (`semperfi run --defense off`, and gnss-sdr through semperfi.eval.gnss_sdr), each unassisted and free
to use every core, each timed `--repeat` times (best and all times printed: the machine is small and shared).
Reports the horizontal error (mean, 95th percentile) against the truth, the time to first fix, the wall times and
their ratio. Needs gnss-sdr (scripts/crosscheck-gnss-sdr installs it). The recordings are kept in --work.
"""

# Where the time went (cProfile, 60 s at 4 MSa/s ishort, 9 satellites, before issue 10: 29.0 s wall, GNSS-SDR
# 17.4 s): tracking's correlator 14 s (6.5 ns per sample per channel: three code gathers and a carrier table per
# sample, which LLVM cannot vectorise), acquisition 2.8 s (per-PRN temporaries of 6 MB, 3x3 peak search over the
# whole CAF), 7.6 s of system time (page faults on per-chunk arrays), 2.2 s start-up (scipy.stats, scipy.signal).
# After: the code-bank correlator (1.1 ns), channels on both cores, acquisition without temporaries, lazy imports.


import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from semperfi.eval.crosscheck import fix_times_rx_s, read_truth   # noqa: E402
from semperfi.eval.gnss_sdr import horizontal_errors_m, run_gnss_sdr   # noqa: E402
from semperfi.eval.metrics import Truth, fix_errors, read_fixes   # noqa: E402
from semperfi.sim.run import simulate_to_file   # noqa: E402
from semperfi.sim.scenario import load_scenario   # noqa: E402

BRDC = REPO.parent / "shared" / "data" / "brdc0010.22n"


def timed(fn, repeat: int):
    walls, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - t0)
    return result, walls


def ours(path: Path, out: Path, truth: dict, repeat: int) -> dict:
    cmd = [sys.executable, "-m", "semperfi.cli", "run", str(path), "--defense", "off", "--out", str(out)]
    _, walls = timed(lambda: subprocess.run(cmd, cwd=REPO, check=True, stdout=subprocess.DEVNULL), repeat)
    fixes = read_fixes(out / "fixes.csv")
    err = fix_errors(fixes, Truth(truth["lat_deg"][0], truth["lon_deg"][0], truth["height_m"][0])).horizontal_m
    return {"fixes": err.size, "mean": err.mean(), "p95": np.percentile(err, 95), "ttff": float(fixes["t_rx_s"][0]),
            "walls": walls}


def gnss_sdr(path: Path, fs: float, out: Path, truth: dict, repeat: int) -> dict:
    fixes, walls = timed(lambda: run_gnss_sdr(path, fs, "ishort", 0.0, out, timeout_s=3600), repeat)
    err = horizontal_errors_m(fixes, truth["lat_deg"][0], truth["lon_deg"][0])
    return {"fixes": len(fixes), "mean": err.mean(), "p95": np.percentile(err, 95),
            "ttff": float(fix_times_rx_s(fixes[:1], truth)[0]), "walls": walls}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--rates", default="2.6e6,4e6,10e6")
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--work", type=Path, default=Path("/tmp/semperfi-vs-gnss-sdr"))
    a = p.parse_args()
    for fs in (float(r) for r in a.rates.split(",")):
        work = a.work / f"{fs / 1e6:g}MSa-{a.duration:g}s"
        work.mkdir(parents=True, exist_ok=True)
        data = work / "static.bin"
        if not data.exists():
            cfg = load_scenario(None, [f"signal.fs_hz={fs}", f"time.duration_s={a.duration}",
                                       f'constellation.rinex="{BRDC}"', "constellation.cn0_dbhz=45.0"])
            simulate_to_file(cfg, data)
        truth = read_truth(work / "static.truth-receiver.csv")
        r_gs = gnss_sdr(data, fs, work / "gnss-sdr", truth, a.repeat)
        r_us = ours(data, work / "semperfi", truth, a.repeat)
        lines = [f"\n{a.duration:g} s static, {fs / 1e6:g} MSa/s ishort, 45 dB-Hz",
                 f"{'':12}{'fixes':>7}{'mean [m]':>10}{'p95 [m]':>9}{'TTFF [s]':>10}{'wall [s]':>10}  all walls"]
        for name, r in (("GNSS-SDR", r_gs), ("SemperFi", r_us)):
            lines.append(f"{name:12}{r['fixes']:>7}{r['mean']:>10.2f}{r['p95']:>9.2f}{r['ttff']:>10.1f}"
                         f"{min(r['walls']):>10.1f}  {', '.join(f'{w:.1f}' for w in r['walls'])}")
        lines.append(f"GNSS-SDR wall time / SemperFi wall time: {min(r_gs['walls']) / min(r_us['walls']):.2f} "
                     f"(best of {a.repeat} each); SemperFi {a.duration / min(r_us['walls']):.1f}x real time")
        print("\n".join(lines), flush=True)


if __name__ == "__main__":
    main()
