"""What the plug-in filter's start-up replay costs (SpoofGuard's replay_start, REPLAY_MAX_S): the held first seconds
kept raw and cleaned a second time. Both ways in one run, on the same recording.

    .venv/bin/python benchmarks/bench_start_replay.py [--fs 10e6] [--duration 8] [--work DIR]

The scene: 8 satellites, every one spoofed +10 dB from the first sample (synchronized, 1 km east), int16 IQ at --fs.
Reported per way: the wall time and CPU time of the guard over the recording, the peak of memory traced
(tracemalloc: numpy's buffers included), and when the last PRN's cancellation started and the replay ran.
"""

import argparse
import resource
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from semperfi.defense.config import load_config   # noqa: E402
from semperfi.defense.guard import SpoofGuard   # noqa: E402
from semperfi.iq import chunk_seconds, open_iq   # noqa: E402
from semperfi.sim.run import simulate_to_file   # noqa: E402
from semperfi.sim.scenario import load_scenario   # noqa: E402


class _Events:
    def __init__(self):
        self.seen: list[tuple[str, float, dict]] = []

    def emit(self, kind: str, t_s: float, **fields) -> None:
        self.seen.append((kind, t_s, fields))


def clean_once(path: Path, fs: float, replay: bool) -> dict:
    events = _Events()
    guard = SpoofGuard(load_config(None, []), fs, 0.0, events, remove_given_up=True, replay_start=replay)
    reader = open_iq(path)
    step = int(fs * chunk_seconds(fs))
    tracemalloc.start()
    wall, cpu = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_utime
    out = 0
    for first in range(0, reader.n_samples, step):
        out += guard.push(reader.read(first, min(step, reader.n_samples - first))).size
    out += guard.flush().size
    wall, cpu = time.perf_counter() - wall, resource.getrusage(resource.RUSAGE_SELF).ru_utime - cpu
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    starts = [t for kind, t, _ in events.seen if kind == "cancellation_start"]
    replayed = [t for kind, t, _ in events.seen if kind == "start_replayed"]
    return {"wall_s": wall, "cpu_s": cpu, "peak_mb": peak / 2 ** 20, "samples_out": out, "n_in": reader.n_samples,
            "last_start_s": max(starts, default=None), "replayed_s": replayed[0] if replayed else None,
            "cancelled": len(starts)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fs", type=float, default=10e6)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--work", default=None)
    a = ap.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="bench-replay-"))
    path = work / f"replay-{a.fs / 1e6:g}MSa-{a.duration:g}s.bin"
    if not path.exists():
        simulate_to_file(load_scenario(None, [f"signal.fs_hz={a.fs}", f"time.duration_s={a.duration}",
                                              'signal.format="ishort"', "constellation.max_satellites=8",
                                              "attacker.enabled=true", "attacker.power_advantage_db=10.0"]), path)
    clean_once(path, a.fs, False)   # the kernels compiled, the file in the page cache
    for replay in (False, True):
        r = clean_once(path, a.fs, replay)
        print(f"replay_start={replay!s:5}: {a.duration:g} s at {a.fs / 1e6:g} MSa/s in {r['wall_s']:.2f} s wall, "
              f"{r['cpu_s']:.2f} s CPU, traced peak {r['peak_mb']:.0f} MB; {r['cancelled']} cancellations, the last "
              f"started at {r['last_start_s']} s; replayed at {r['replayed_s']} s; {r['samples_out']} of "
              f"{r['n_in']} samples out", flush=True)


if __name__ == "__main__":
    main()
