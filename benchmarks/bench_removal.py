"""What taking a PRN out costs: its remainder removed by projection (canceller.RemovalTrack: the code at 41 lags fitted
and subtracted per period) against one more lone replica (what a removal was before), timed in one run.

    .venv/bin/python benchmarks/bench_removal.py [--repeat 3]

The scene is tests/test_removal.py's: a spoofer 15 dB over its twin 0.5 chip off, behind a 1 MHz front end at 2.6
MSa/s, 4 s; the spoofer cancelled jointly at stage 0, the twin taken out at stage 1 from 1.2 s on. Reported: the CPU
time and wall time of the canceller over the scene each way, and the difference per second of signal removed (the
lags' Gram for every phase of a sample, computed once per removal, in it).
"""

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

import numpy as np   # noqa: E402

from test_removal import DURATION_S, FS, REMOVED_AT_S, _cleaned, _scene   # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    x, _ = _scene()
    _cleaned(x[:int(1.5 * FS)], True)   # the kernels compiled
    best = {}
    for _ in range(a.repeat):
        for projection in (False, True):
            cpu, wall = time.process_time(), time.perf_counter()
            _cleaned(x, projection)
            took = (time.process_time() - cpu, time.perf_counter() - wall)
            best[projection] = min(best.get(projection, (np.inf, np.inf)), took)
    for projection, name in ((False, "one more lone replica"), (True, "projection (RemovalTrack)")):
        cpu, wall = best[projection]
        print(f"{name:28s}: {cpu:6.2f} s CPU, {wall:6.2f} s wall for {DURATION_S:g} s at {FS / 1e6:g} MSa/s "
              f"(best of {a.repeat})")
    extra = best[True][0] - best[False][0]
    print(f"the projection's cost: {extra:.2f} s CPU more, {extra / (DURATION_S - REMOVED_AT_S):.3f} s of CPU per "
          "second removed")


if __name__ == "__main__":
    main()
