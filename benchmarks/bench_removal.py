"""What taking a PRN out costs: its remainder removed by projection (canceller.RemovalTrack: the code at 41 lags fitted
and subtracted per period) against one more lone replica (what a removal was before), timed in one run.

    .venv/bin/python benchmarks/bench_removal.py [--fs 2.6e6] [--seconds 4] [--repeat 3]

The scene: a spoofer 15 dB over its twin 0.5 chip off (ideal chips), cancelled jointly at stage 0, its twin taken out
at stage 1 from 1 s on. Reported: the CPU time and wall time of the canceller over the scene, each way, and the
difference per second of signal removed (the lags' Gram for every phase of a sample, computed once per removal, in
it).
"""

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np   # noqa: E402

from semperfi.defense.canceller import Canceller   # noqa: E402
from semperfi.gps import CA_CHIP_RATE_HZ, L1_HZ, ca_code   # noqa: E402
from semperfi.receiver.acquisition import Peak   # noqa: E402

PRN, CP, DOPPLER, TWIN_CHIPS, ADVANTAGE_DB, CN0_DBHZ, REMOVED_AT_S = 8, 400.0, -2100.0, 0.5, 15.0, 45.0, 1.0


def scene(fs_hz: float, seconds: float) -> np.ndarray:
    rng = np.random.default_rng(1)
    t = np.arange(int(seconds * fs_hz)) / fs_hz
    amplitude = np.sqrt(2 * 10 ** (CN0_DBHZ / 10) / fs_hz)
    x = (rng.standard_normal(t.size) + 1j * rng.standard_normal(t.size)).astype(np.complex64)
    for cp, gain, phase in ((CP, 10 ** (ADVANTAGE_DB / 20), 1.9), (CP + TWIN_CHIPS, 1.0, 0.3)):
        chips = cp + t * CA_CHIP_RATE_HZ * (1 + DOPPLER / L1_HZ)
        x += (amplitude * gain * ca_code(PRN)[np.floor(chips).astype(np.int64) % 1023]
              * np.exp(1j * (2 * np.pi * DOPPLER * t + phase))).astype(np.complex64)
    return x


def cancel(x: np.ndarray, fs_hz: float, projection: bool) -> tuple[float, float]:
    c = Canceller(fs_hz)
    spoofer = c.cancel(Peak(PRN, CP, DOPPLER, 0.0, 0.0), 0, 0, legit_code_phase_chips=CP + TWIN_CHIPS)
    step, removed = int(0.05 * fs_hz), False
    wall, cpu = time.perf_counter(), time.process_time()
    for i in range(0, x.size, step):
        if not removed and i >= REMOVED_AT_S * fs_hz:
            at = i - 2 * step
            chips = float((spoofer.channel.code_phase_at(at) + spoofer.legit_offset_chips) % 1023)
            c.cancel(Peak(PRN, chips, spoofer.channel.doppler_at(0), 0.0, 0.0), at, 1, removal=projection)
            removed = True
        c.push(x[i:i + step])
    c.flush()
    return time.process_time() - cpu, time.perf_counter() - wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fs", type=float, default=2.6e6)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    x = scene(a.fs, a.seconds)
    cancel(x[:int(0.5 * a.fs)], a.fs, True)   # the kernels compiled
    best = {}
    for _ in range(a.repeat):
        for projection in (False, True):
            cpu, wall = cancel(x, a.fs, projection)
            best[projection] = min(best.get(projection, (np.inf, np.inf)), (cpu, wall))
    removed_s = a.seconds - REMOVED_AT_S
    for projection, name in ((False, "one more lone replica"), (True, "projection (RemovalTrack)")):
        cpu, wall = best[projection]
        print(f"{name:28s}: {cpu:6.2f} s CPU, {wall:6.2f} s wall for {a.seconds:g} s at {a.fs / 1e6:g} MSa/s "
              f"(best of {a.repeat})")
    extra = best[True][0] - best[False][0]
    print(f"the projection's cost: {extra:.2f} s CPU more, {extra / removed_s:.3f} s of CPU per second removed")


if __name__ == "__main__":
    main()
