"""Claims about live input: samples piped on standard input give the same acquisition as the file they came from,
and a stream that ends early is one clear error line, never a shorter block at the wrong time."""

import io
import subprocess
import sys

import numpy as np
import pytest

from semperfi.iq import IqWriter
from semperfi.iq.source import open_source

FS = 2.048e6


def _recording(path, prn=7, doppler_hz=1250.0, code_phase_chips=100.0, seconds=0.02):
    from semperfi.gps.codes import ca_code
    rng = np.random.default_rng(3)
    n = int(FS * seconds)
    t = np.arange(n) / FS
    chips = np.floor(code_phase_chips + t * 1.023e6).astype(int) % 1023
    x = 0.3 * ca_code(prn)[chips] * np.exp(2j * np.pi * doppler_hz * t) + (rng.standard_normal(n)
                                                                         + 1j * rng.standard_normal(n))
    with IqWriter(path, "ibyte", FS, scale=20.0) as w:
        w.write(x.astype(np.complex64))


def _acquire(args, stdin_path=None):
    stdin = open(stdin_path, "rb") if stdin_path else subprocess.DEVNULL
    try:
        return subprocess.run([sys.executable, "-m", "semperfi.cli", "acquire", *args, "--prn", "5-9"],
                              stdin=stdin, capture_output=True, text=True, timeout=120)
    finally:
        if stdin_path:
            stdin.close()


def test_stdin_gives_the_same_acquisition_as_the_file(tmp_path):
    path = tmp_path / "rec.bin"
    _recording(path)
    from_file = _acquire([str(path)])
    from_pipe = _acquire(["-", "--fs", str(FS), "--format", "ibyte"], stdin_path=path)
    assert from_file.returncode == 0 and from_pipe.returncode == 0, from_pipe.stderr
    assert from_pipe.stdout == from_file.stdout, f"pipe:\n{from_pipe.stdout}\nfile:\n{from_file.stdout}"
    line = [ln for ln in from_pipe.stdout.splitlines() if ln.split()[:1] == ["7"]]
    assert line and abs(float(line[0].split()[1]) - 100.0) < 0.1, f"PRN 7 not at 100 chips: {from_pipe.stdout}"


def test_short_stream_is_one_error_line(tmp_path):
    path = tmp_path / "short.bin"
    path.write_bytes(b"\x01\x02" * 300)
    result = _acquire(["-", "--fs", str(FS), "--format", "ibyte"], stdin_path=path)
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "ended" in lines[0] and "300 of" in lines[0], result.stderr


def test_stdin_needs_format_and_rate():
    result = _acquire(["-"])
    assert result.returncode != 0 and "--format and --fs" in result.stderr


def test_a_stream_read_refuses_hostile_sizes():
    source = open_source("-", "ibyte", FS, stdin=io.BytesIO(b""))
    with pytest.raises(ValueError, match="must be below"):
        source.take(10**12)
