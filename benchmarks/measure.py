"""One way for the benchmarks to time a whole `semperfi` command and the memory it owns."""

import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def semperfi(*args: str) -> tuple[float, float]:
    """Run `python -m semperfi.cli ARGS` in a fresh process: (wall s, peak anonymous resident memory MB).
    Anonymous: the memory the process owns, polled from /proc; a recording's memory-mapped pages are the kernel's
    page cache (a 60 s recording at 10 MSa/s is 2.4 GB of them), which ru_maxrss would count as the process's."""
    cmd = [sys.executable, "-m", "semperfi.cli", *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak_kb = 0
    while proc.poll() is None:
        peak_kb = max(peak_kb, _anon_kb(proc.pid))
        time.sleep(0.02)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {proc.stderr.read().decode(errors='replace').strip()}")
    return wall, peak_kb / 1024


def _anon_kb(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next((int(line.split()[1]) for line in f if line.startswith("RssAnon:")), 0)
    except OSError:        # it ended between the poll and the read
        return 0
