"""Peak memory of the receiver over a long recording: it must not grow with duration (samples stream in chunks).

    .venv/bin/python benchmarks/bench_receiver_memory.py [--minutes 10] [--fs 2e6] [--work DIR]

Simulates a static recording (ibyte, to keep the file small), then runs `semperfi run` on its first minute and on
the whole of it in fresh processes, and prints wall time and peak RSS of each.
"""

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_child(args: list[str]) -> tuple[float, float]:
    """Wall time and this child's own peak RSS (MB)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "semperfi.cli", *args], cwd=REPO, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise SystemExit(f"semperfi {' '.join(args)} failed")
    return time.perf_counter() - t0, usage.ru_maxrss / 1024


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--fs", type=float, default=2e6)
    p.add_argument("--work", type=Path, default=Path("/tmp/semperfi-memory"))
    a = p.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    long = a.work / "long.bin"
    if not long.exists():
        wall, rss = run_child(["sim", "-o", str(long), "--fs", str(a.fs), "--format", "ibyte", "--duration",
                               str(60 * a.minutes)])
        print(f"simulating {a.minutes:g} min at {a.fs / 1e6:g} MSa/s: wall {wall:6.1f} s, peak RSS {rss:6.0f} MB",
              flush=True)
    short = a.work / "short.bin"
    if not short.exists():   # the first minute, copied without reading the whole file
        with open(long, "rb") as src, open(short, "wb") as dst:
            dst.write(src.read(int(60 * a.fs) * 2))
    for path, label in ((short, "1 min"), (long, f"{a.minutes:g} min")):
        wall, rss = run_child(["run", str(path), "--fs", str(a.fs), "--format", "ibyte",
                               "--out", str(a.work / path.stem)])
        print(f"{label:>7} at {a.fs / 1e6:g} MSa/s: wall {wall:6.1f} s, peak RSS {rss:6.0f} MB", flush=True)


if __name__ == "__main__":
    main()
