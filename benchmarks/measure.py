"""One way for the benchmarks to time a whole `semperfi` command and the memory it owns."""

import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def semperfi(*args: str) -> tuple[float, float]:
    """Run `python -m semperfi.cli ARGS` in a fresh process: (wall s, peak anonymous resident memory MB).
    Anonymous: the memory the process owns, polled from /proc; a recording's memory-mapped pages are the kernel's
    page cache (a 60 s recording at 10 MSa/s is 2.4 GB of them), which ru_maxrss would count as the process's."""
    wall, mb, _ = semperfi_cpu(*args)
    return wall, mb


def semperfi_cpu(*args: str) -> tuple[float, float, float]:
    """semperfi(), and the CPU seconds (user + system) the process and its threads used: on a small shared machine
    the wall time of one command drifts by 10-30 % from one minute to the next, its CPU time far less."""
    cmd = [sys.executable, "-m", "semperfi.cli", *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak_kb = 0
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        peak_kb = max(peak_kb, _anon_kb(proc.pid))
        time.sleep(0.02)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)   # reaped here, with its resource usage
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {proc.stderr.read().decode(errors='replace').strip()}")
    proc.stderr.close()
    return wall, peak_kb / 1024, usage.ru_utime + usage.ru_stime


def _anon_kb(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next((int(line.split()[1]) for line in f if line.startswith("RssAnon:")), 0)
    except OSError:        # it ended between the poll and the read
        return 0
