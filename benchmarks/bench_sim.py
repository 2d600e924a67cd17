"""Simulator speed and memory: seconds to render 10 s at 4 MSa/s with 10 legitimate and 10 spoofed satellites,
and peak RSS for two durations (it must not grow with duration: the simulator streams chunks).

    .venv/bin/python benchmarks/bench_sim.py [--fs 4e6] [--repeat 2]

Each measurement runs in a fresh process pinned to one core (numba compile time excluded by a warm-up).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def child(duration_s: float, fs_hz: float, out: str) -> None:
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    from semperfi.iq import IqWriter
    from semperfi.sim.scenario import load_scenario
    from semperfi.sim.simulate import Simulator

    sets = [f"signal.fs_hz={fs_hz}", "constellation.max_satellites=10", "attacker.enabled=true"]
    for _ in Simulator(load_scenario(None, sets + ["time.duration_s=0.04"])).chunks():
        pass   # warm-up: numba compilation and caches
    sim = Simulator(load_scenario(None, sets + [f"time.duration_s={duration_s}"]))
    n_legit = sum(s.source == "legit" for s in sim.signals)
    n_spoof = sum(s.source == "spoof" for s in sim.signals)
    t0 = time.perf_counter()
    with IqWriter(out, "ishort", fs_hz) as w:
        for chunk in sim.chunks():
            w.write(chunk)
    wall = time.perf_counter() - t0
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"duration_s": duration_s, "wall_s": wall, "rss_mb": rss_mb, "legit": n_legit, "spoof": n_spoof}))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--fs", type=float, default=4e6)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--child", type=float)
    p.add_argument("--out")
    a = p.parse_args()
    if a.child:
        child(a.child, a.fs, a.out)
        return
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "bench.bin")
        results = []
        for duration in [10.0] * a.repeat + [40.0]:
            r = subprocess.run([sys.executable, __file__, "--child", str(duration), "--fs", str(a.fs), "--out", out],
                               capture_output=True, text=True, check=True)
            results.append(json.loads(r.stdout))
    for r in results:
        print(f"{r['duration_s']:>5.0f} s of signal at {a.fs / 1e6:g} MSa/s, "
              f"{r['legit']} legit + {r['spoof']} spoofed: {r['wall_s']:6.2f} s wall on one core "
              f"({r['duration_s'] / r['wall_s']:.2f}x real time), peak RSS {r['rss_mb']:.0f} MB")


if __name__ == "__main__":
    main()
