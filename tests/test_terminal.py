"""What a person at a terminal sees: each command runs under a pseudo-terminal, draws its live table or progress
bar, and exits 0 (issue 12: the suite never had a terminal, so `semperfi run` crashing on `rich` went unseen)."""
import fcntl
import os
import pty
import struct
import termios
import re
import select
import subprocess
import sys

import pytest

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")
BAR = re.compile(r"\d+% +\d+/\d+")     # the bar's share done and chunks done (semperfi/progress.py)
TABLE_HEADER = "Doppler [Hz]"       # the live channel table's header


def run_in_pty(args, cwd, timeout_s=300):
    """Run `python -m semperfi.cli ARGS` with stdin/stdout/stderr on a pseudo-terminal; (exit code, screen text)."""
    master, slave = pty.openpty()
    # A fresh pty is 0x0; a person's terminal is not, and a bar draws nothing in zero columns.
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    env = dict(os.environ, COLUMNS="120", LINES="40", TERM="xterm-256color")
    proc = subprocess.Popen([sys.executable, "-m", "semperfi.cli", *args], stdin=slave, stdout=slave,
                            stderr=slave, cwd=cwd, env=env, close_fds=True)
    os.close(slave)
    out = bytearray()
    while True:
        ready, _, _ = select.select([master], [], [], timeout_s)
        if not ready:
            proc.kill()
            pytest.fail(f"{args[0]} printed nothing for {timeout_s} s")
        try:
            data = os.read(master, 65536)
        except OSError:          # EIO: the child closed the terminal
            break
        if not data:
            break
        out += data
    os.close(master)
    code = proc.wait(timeout=timeout_s)
    return code, ANSI.sub("", out.decode("utf-8", "replace"))


@pytest.fixture(scope="module")
def signal_file(tmp_path_factory):
    """One short low-rate simulated recording, shared by the tests below."""
    d = tmp_path_factory.mktemp("tty")
    code, screen = run_in_pty(["sim", "-o", str(d / "s.bin"), "--fs", "2e6", "--format", "ibyte",
                               "--duration", "3"], d)
    return d, code, screen


def test_sim_shows_a_progress_bar(signal_file):
    _, code, screen = signal_file
    assert code == 0, screen[-2000:]
    assert BAR.search(screen), f"no progress bar on the terminal:\n{screen[-2000:]}"


def test_run_shows_the_live_channel_table(signal_file):
    d, _, _ = signal_file
    code, screen = run_in_pty(["run", str(d / "s.bin"), "--out", str(d / "run")], d)
    assert code == 0, screen[-2000:]
    assert TABLE_HEADER in screen and "PRN" in screen, f"no live channel table:\n{screen[-2000:]}"


def test_clean_shows_a_progress_bar(signal_file):
    d, _, _ = signal_file
    code, screen = run_in_pty(["clean", str(d / "s.bin"), "-o", str(d / "clean.bin")], d)
    assert code == 0, screen[-2000:]
    assert BAR.search(screen) and "cleaning" in screen, f"no progress bar:\n{screen[-2000:]}"


def test_demo_shows_the_live_table_of_both_receivers(tmp_path):
    """The closed loop's receiver (its own process, reading the world's samples) and the conventional receiver after
    it each draw their table: a person watching the demo sees it run, not a silent minute."""
    code, screen = run_in_pty(["demo", "--out", str(tmp_path / "demo"), "--duration", "3"], tmp_path)
    assert code == 0, screen[-2000:]
    marker = "fixes labelled good"   # printed between the closed loop and the conventional run
    assert marker in screen, screen[-3000:]
    closed_loop, conventional = screen.split(marker, 1)
    assert TABLE_HEADER in closed_loop, f"no live table for the closed loop's receiver:\n{screen[-3000:]}"
    assert TABLE_HEADER in conventional, f"no live table for the conventional receiver:\n{screen[-3000:]}"
