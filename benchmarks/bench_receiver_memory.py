"""Peak memory of the receiver over a long recording: it must not grow with duration (samples stream in chunks).

    .venv/bin/python benchmarks/bench_receiver_memory.py [--minutes 10] [--fs 2e6] [--work DIR]

Simulates a static recording (ibyte, to keep the file small), then runs `semperfi run` on its first minute and on
the whole of it in fresh processes, and prints wall time and peak anonymous memory of each.
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import measure   # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--fs", type=float, default=2e6)
    p.add_argument("--work", type=Path, default=Path("/tmp/semperfi-memory"))
    a = p.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    long = a.work / "long.bin"
    if not long.exists():
        wall, mb = measure.semperfi("sim", "-o", str(long), "--fs", str(a.fs), "--format", "ibyte", "--duration",
                                    str(60 * a.minutes))
        print(f"simulating {a.minutes:g} min at {a.fs / 1e6:g} MSa/s: wall {wall:6.1f} s, peak anonymous memory "
              f"{mb:6.0f} MB",
              flush=True)
    short = a.work / "short.bin"
    if not short.exists():   # the first minute, copied without reading the whole file
        with open(long, "rb") as src, open(short, "wb") as dst:
            dst.write(src.read(int(60 * a.fs) * 2))
    for path, label in ((short, "1 min"), (long, f"{a.minutes:g} min")):
        wall, mb = measure.semperfi("run", str(path), "--fs", str(a.fs), "--format", "ibyte",
                                    "--out", str(a.work / path.stem))
        print(f"{label:>7} at {a.fs / 1e6:g} MSa/s: wall {wall:6.1f} s, peak anonymous memory {mb:6.0f} MB",
              flush=True)


if __name__ == "__main__":
    main()
