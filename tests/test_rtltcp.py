"""Claims about the rtl_tcp client, against a local replay server on 127.0.0.1 that stops by itself."""

import socket
import struct
import threading

import numpy as np
import pytest

from semperfi.iq.rtltcp import RtlTcpSource


def _server(payload: bytes, header: bytes = b"RTL0" + struct.pack(">II", 5, 29), stall_after: int | None = None):
    """Serve one client once: header, then payload (stopping after stall_after bytes without closing)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(10)
    commands = []

    def run():
        try:
            conn, _ = srv.accept()
        except OSError:
            return
        with conn:
            conn.sendall(header)
            conn.settimeout(1)
            try:
                commands.append(conn.recv(15))
            except OSError:
                pass
            body = payload if stall_after is None else payload[:stall_after]
            try:
                conn.sendall(body)
                if stall_after is not None:
                    threading.Event().wait(2.0)   # silent, then gone
            except OSError:
                pass
        srv.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return srv.getsockname()[1], thread, commands


def test_replayed_stream_arrives_centred_and_tuned():
    rng = np.random.default_rng(5)
    raw = rng.integers(0, 256, size=2 * 4000, dtype=np.uint8)
    port, thread, commands = _server(raw.tobytes())
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
    port, thread, _ = _server(b"", header=b"HTTP/1.1 200")
    with pytest.raises(ValueError, match="not an rtl_tcp server"):
        RtlTcpSource("127.0.0.1", port, 2.048e6, timeout_s=3)
    thread.join(5)


def test_stalled_stream_is_a_clear_error_not_a_short_block():
    port, thread, _ = _server(bytes(8000), stall_after=1000)
    src = RtlTcpSource("127.0.0.1", port, 2.048e6, timeout_s=0.5)
    with pytest.raises(ValueError, match="stalled|closed"):
        src.read(0, 4000)
    src.close()
    thread.join(5)
