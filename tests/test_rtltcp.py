"""Claims about the rtl_tcp client, against a local replay server on 127.0.0.1 that stops by itself."""

import struct

import numpy as np
import pytest

from semperfi.iq.rtltcp import RtlTcpSource

from rtl_tcp_server import serve_once


def test_replayed_stream_arrives_centred_and_tuned():
    rng = np.random.default_rng(5)
    raw = rng.integers(0, 256, size=2 * 4000, dtype=np.uint8)
    port, thread, commands = serve_once(raw.tobytes())
    src = RtlTcpSource("127.0.0.1", port, 2.048e6, timeout_s=3)
    x = src.read(1000, 2000)
    src.close()
    thread.join(5)
    want = (raw[2000:6000].astype(np.float32) - 127.5).view(np.complex64)
    assert np.array_equal(x, want), "samples differ from what the server sent"
    assert src.tuner == "R820T"
    sent = commands[0]
    assert struct.unpack(">BI", sent[:5]) == (0x02, 2048000) and struct.unpack(">BI", sent[5:10]) == (0x01, 1575420000)


def test_not_an_rtl_tcp_server_is_one_error():
    port, thread, _ = serve_once(b"", header=b"HTTP/1.1 200")
    with pytest.raises(ValueError, match="not an rtl_tcp server"):
        RtlTcpSource("127.0.0.1", port, 2.048e6, timeout_s=3)
    thread.join(5)


def test_stalled_stream_is_a_clear_error_not_a_short_block():
    port, thread, _ = serve_once(bytes(8000), stall_after=1000)
    src = RtlTcpSource("127.0.0.1", port, 2.048e6, timeout_s=0.5)
    with pytest.raises(ValueError, match="stalled|closed"):
        src.read(0, 4000)
    src.close()
    thread.join(5)


@pytest.mark.parametrize("cut", ["stall_after", "close_after"])
def test_the_samples_before_a_stall_or_a_close_are_delivered_then_the_error(cut):
    """Issue 23, item 8: the read a stall or a close cut short was thrown away (up to a quarter second of signal)."""
    from semperfi.iq.source import SampleSource, SourceError
    rng = np.random.default_rng(8)
    raw = rng.integers(0, 256, size=2 * 300_001, dtype=np.uint8)   # 300,000.5 samples: the half one is dropped
    port, thread, _ = serve_once(raw.tobytes(), **{cut: raw.size - 1})
    source = SampleSource(f"rtl_tcp://127.0.0.1:{port}", fs_hz=1.2e6)
    source._input.source.timeout_s = 0.5
    got = []
    with pytest.raises(SourceError, match="stalled|closed"):
        for chunk in source.chunks(0.1):   # 2.5 reads: the third is cut short
            got.append(chunk)
    source.close()
    thread.join(5)
    want = (raw[:600_000].astype(np.float32) - 127.5).view(np.complex64)
    assert np.array_equal(np.concatenate(got), want)


@pytest.mark.parametrize("args, message", [
    (dict(fs_hz=0.0), "sample rate"), (dict(fs_hz=-2e6), "sample rate"), (dict(fs_hz=1e12), "RTL-SDR samples"),
    (dict(fs_hz=2.048e6, fmt="ishort"), "cu8"), (dict(fs_hz=2.048e6, if_hz=4e5), "IF 0")])
def test_options_an_rtl_sdr_cannot_honour_are_refused_before_connecting(args, message):
    from semperfi.iq.source import SampleSource
    with pytest.raises(ValueError, match=message):   # port 9 (discard): nothing is ever connected to
        SampleSource("rtl_tcp://127.0.0.1:9", **args)


def test_acquire_over_rtl_tcp_end_to_end(tmp_path):
    """A recording replayed by a local rtl_tcp server: `semperfi acquire rtl_tcp://...` finds its satellite."""
    import subprocess
    import sys
    from semperfi.gps.codes import ca_code
    fs = 2.048e6
    n = int(fs * 0.012)
    t = np.arange(n) / fs
    chips = np.floor(300.0 + t * 1.023e6).astype(int) % 1023
    rng = np.random.default_rng(9)
    x = (0.4 * ca_code(11)[chips] * np.exp(2j * np.pi * -2100.0 * t)
         + rng.standard_normal(n) + 1j * rng.standard_normal(n))
    iq = np.empty(2 * n, dtype=np.uint8)
    iq[0::2] = np.clip(np.rint(127.5 + 25 * x.real), 0, 255)
    iq[1::2] = np.clip(np.rint(127.5 + 25 * x.imag), 0, 255)
    port, thread, _ = serve_once(iq.tobytes())
    result = subprocess.run([sys.executable, "-m", "semperfi.cli", "acquire", f"rtl_tcp://127.0.0.1:{port}",
                             "--fs", str(fs), "--prn", "9-13"], capture_output=True, text=True, timeout=120)
    thread.join(5)
    assert result.returncode == 0, result.stderr
    rows = {int(ln.split()[0]): ln.split() for ln in result.stdout.splitlines()[1:]}
    assert list(rows) == [11], f"expected PRN 11 only:\n{result.stdout}"
    assert abs(float(rows[11][1]) - 300.0) < 0.1 and abs(float(rows[11][3]) + 2100.0) < 50, result.stdout
