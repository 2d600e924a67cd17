"""The grids' process pool (semperfi.eval.pool): a grid stopped from outside stops its workers and the programs they
started, where a plain process pool's workers ran on for the rest of their cells."""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

DEADLINE_S = 30.0

PARENT = textwrap.dedent("""
    import os, subprocess, sys, time
    from pathlib import Path
    from semperfi.eval.pool import worker_pool

    def cell(out, own_session):
        # a cell that starts a program of its own, as the grids' do: in the worker's group (gps-sdr-sim), or in a
        # session of its own that the cell stops on its way out (GNSS-SDR, run_gnss_sdr)
        child = subprocess.Popen(["sleep", "300"], start_new_session=own_session)
        Path(out).write_text(f"{child.pid} {os.getpid()}")
        try:
            child.wait()
        except BaseException:
            child.kill()
            raise

    def next_cell(out):   # queued behind the first: a stopped grid starts no more cells
        Path(out).write_text("ran")

    if __name__ == "__main__":
        try:
            with worker_pool(1) as pool:
                first = pool.submit(cell, sys.argv[1], sys.argv[2] == "own")
                pool.submit(next_cell, sys.argv[1] + ".next")
                first.result()
        except KeyboardInterrupt:
            print("stopped", file=sys.stderr)
            sys.exit(130)
""")


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state != "Z"   # a zombie no one reaped has stopped


def _wait_for(what, deadline_s: float = DEADLINE_S) -> bool:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if what():
            return True
        time.sleep(0.05)
    return False


@pytest.mark.parametrize("session", ["worker's", "own"])
def test_a_grid_sent_sigterm_ends_its_workers_and_the_programs_they_started(tmp_path, session):
    """Also a program in a session of its own: its worker, killed outright, left it running without a parent
    (GNSS-SDR went on with its file after a grid was stopped)."""
    script, marker = tmp_path / "parent.py", tmp_path / "child.pid"
    script.write_text(PARENT)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    parent = subprocess.Popen([sys.executable, str(script), str(marker), session], env=env, stderr=subprocess.PIPE,
                              text=True)
    try:
        assert _wait_for(lambda: marker.is_file() and marker.read_text()), "the worker never started its program"
        child, worker = (int(pid) for pid in marker.read_text().split())
        assert _alive(child)
        parent.send_signal(signal.SIGTERM)
        _, err = parent.communicate(timeout=DEADLINE_S)
    finally:
        if parent.poll() is None:
            parent.kill()
    assert parent.returncode == 130 and err.strip() == "stopped", err
    assert _wait_for(lambda: not _alive(child)), f"the worker's program {child} outlived the grid"
    assert _wait_for(lambda: not _alive(worker)), f"the grid's worker {worker} outlived it"
    assert not Path(f"{marker}.next").exists(), "the stopped grid's worker went on to its next cell"
