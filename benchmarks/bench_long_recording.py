"""A TEXBAT-class recording end to end: `semperfi run` on a 25 MSa/s complex int16 file of several GB, decimated to
a processing rate as it streams. Prints the fixes' error, the wall time, the input throughput and the run's peak RSS.

    .venv/bin/python benchmarks/bench_long_recording.py [--seconds 30] [--fs 25e6] [--fs-out 5e6]
                                                         [--nav ../shared/data/brdc0010.22n] [--work DIR] [--keep]

The recording is our simulator's (8 satellites, 45 dB-Hz, static receiver; from the RINEX file's satellites when
--nav is given, and then the run is assisted, so fixes come within seconds). The run is a fresh process; its peak
RSS is its own VmHWM, read as it exits.
"""

import argparse
import csv
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
LAT, LON, H = 42.3398, -71.0892, 10.0   # the simulator's default receiver

CHILD = """
import sys
from semperfi.cli import main
try:
    main(sys.argv[1:], standalone_mode=False)
finally:
    hwm = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM'))
    print(f'peak RSS {hwm / 1024:.0f} MB', file=sys.stderr)
"""


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--fs", type=float, default=25e6)
    p.add_argument("--fs-out", type=float, default=5e6)
    p.add_argument("--nav", type=Path, default=REPO.parent / "shared" / "data" / "brdc0010.22n")
    p.add_argument("--work", type=Path, default=Path("/tmp/semperfi-long"))
    p.add_argument("--keep", action="store_true")
    a = p.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    path = a.work / f"long_{a.fs / 1e6:g}msps_ishort.bin"
    semperfi = [sys.executable, "-m", "semperfi.cli"]
    sets = ["--set", "constellation.max_satellites=8"]
    nav = []
    if a.nav.is_file():
        sets += ["--set", f'constellation.rinex="{a.nav}"', "--set", 'time.start="2022-01-01T00:00:27"']
        nav = ["--nav", str(a.nav)]
    try:
        t0 = time.perf_counter()
        subprocess.run(semperfi + ["sim", "-o", str(path), "--fs", str(a.fs), "--duration", str(a.seconds),
                                   "--format", "ishort", *sets], check=True, cwd=REPO, stdout=subprocess.DEVNULL)
        print(f"simulated {path.stat().st_size / 1e9:.2f} GB ({a.seconds:g} s at {a.fs / 1e6:g} MSa/s ishort) in "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
        out = a.work / "run"
        t0 = time.perf_counter()
        run = subprocess.run([sys.executable, "-c", CHILD, "run", str(path), "--fs-out", str(a.fs_out),
                              "--defense", "off", "--out", str(out), *nav], cwd=REPO, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        print(run.stdout.strip())
        print(run.stderr.strip())
        if run.returncode != 0:
            raise SystemExit("the run failed")
        from semperfi.gps.geometry import enu_rotation, geodetic_to_ecef
        truth = geodetic_to_ecef(np.radians(LAT), np.radians(LON), H)
        rot = enu_rotation(np.radians(LAT), np.radians(LON))
        fixes = list(csv.DictReader(open(out / "fixes.csv")))
        enu = np.array([rot @ (np.array([float(f[k]) for k in ("x_m", "y_m", "z_m")]) - truth) for f in fixes])
        n_in = a.seconds * a.fs
        print(f"run: {len(fixes)} fixes, horizontal error mean {np.mean(np.hypot(enu[:, 0], enu[:, 1])):.2f} m; "
              f"wall {wall:.1f} s, {n_in / wall / 1e6:.1f} MSa/s in ({a.seconds / wall:.2f}x real time) at "
              f"{a.fs_out / 1e6:g} MSa/s processing")
    finally:
        if not a.keep and path.exists():
            path.unlink()


if __name__ == "__main__":
    main()
