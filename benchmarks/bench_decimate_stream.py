"""Streaming a TEXBAT-class recording: peak memory and throughput of read + anti-alias decimation.

    .venv/bin/python benchmarks/bench_decimate_stream.py [--gb 3] [--fs 25e6] [--out-fs 5e6] [--work DIR] [--keep]

Writes a complex int16 (ishort) file of --gb gigabytes at --fs (noise plus a tone, in 64 MB pieces), then, in a
fresh process, streams it through IqReader chunks and StreamDecimator to --out-fs, and prints the child's wall
time, input throughput (MSa/s) and its own peak RSS (VmHWM). The file is deleted afterwards unless --keep.
"""

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def write_file(path: Path, gigabytes: float, fs_hz: float) -> int:
    n_total = int(gigabytes * 1e9) // 4
    piece = 1 << 24   # samples per write: 64 MB of ishort
    rng = np.random.default_rng(7)
    with open(path, "wb") as f:
        for start in range(0, n_total, piece):
            n = min(piece, n_total - start)
            iq = rng.integers(-300, 300, size=2 * n, dtype=np.int16)
            t = (start + np.arange(n)) / fs_hz
            iq[0::2] += (200 * np.cos(2 * np.pi * 1.0e6 * t)).astype(np.int16)
            iq[1::2] += (200 * np.sin(2 * np.pi * 1.0e6 * t)).astype(np.int16)
            f.write(iq.tobytes())
    return n_total


def child(path: str, fs_hz: float, out_fs_hz: float) -> None:
    from semperfi.iq.reader import IqReader
    from semperfi.iq.decimate import StreamDecimator, decimation_factor

    reader = IqReader(path, "ishort", fs_hz, chunk_samples=1 << 20)
    dec = StreamDecimator(decimation_factor(fs_hz, out_fs_hz))
    n_out, power = 0, 0.0
    for chunk in reader.chunks():
        y = dec.process(chunk)
        n_out += y.size
        power += float(np.vdot(y, y).real)
    # VmHWM is this process image's own peak (ru_maxrss from wait4 would include the parent's size at fork).
    hwm_kb = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM"))
    print(f"{reader.n_samples} in, {n_out} out, mean power {power / max(n_out, 1):.1f}, "
          f"peak RSS {hwm_kb / 1024:.0f} MB")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--gb", type=float, default=3.0)
    p.add_argument("--fs", type=float, default=25e6)
    p.add_argument("--out-fs", type=float, default=5e6)
    p.add_argument("--work", type=Path, default=Path("/tmp/semperfi-decimate"))
    p.add_argument("--keep", action="store_true")
    p.add_argument("--child", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.child:
        child(a.child, a.fs, a.out_fs)
        return
    a.work.mkdir(parents=True, exist_ok=True)
    path = a.work / "texbat_like_25msps_ishort.bin"
    try:
        t0 = time.perf_counter()
        n = write_file(path, a.gb, a.fs)
        print(f"wrote {path} ({path.stat().st_size / 1e9:.2f} GB, {n / a.fs:.1f} s at {a.fs / 1e6:g} MSa/s) "
              f"in {time.perf_counter() - t0:.1f} s", flush=True)
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, __file__, "--child", str(path), "--fs", str(a.fs),
                                 "--out-fs", str(a.out_fs)], cwd=REPO)
        status = proc.wait()
        wall = time.perf_counter() - t0
        if status != 0:
            raise SystemExit("streaming child failed")
        print(f"streamed {n / a.fs:.1f} s of {a.fs / 1e6:g} MSa/s ishort to {a.out_fs / 1e6:g} MSa/s: "
              f"wall {wall:.1f} s, {n / wall / 1e6:.1f} MSa/s in ({n / a.fs / wall:.2f}x real time); "
              "the child's peak RSS is printed above")
    finally:
        if not a.keep and path.exists():
            path.unlink()


if __name__ == "__main__":
    main()
