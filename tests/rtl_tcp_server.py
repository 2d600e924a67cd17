"""A local rtl_tcp replay server for tests: serves one client once on 127.0.0.1 and stops by itself."""

import socket
import struct
import threading
import time

HEADER = b"RTL0" + struct.pack(">II", 5, 29)   # R820T, 29 gains


def serve_once(payload: bytes, header: bytes = HEADER, stall_after: int | None = None,
               close_after: int | None = None, bytes_per_s: float | None = None):
    """Header, then payload: stopping after stall_after bytes without closing (a stall), or closing after
    close_after bytes (a lost stream), paced at bytes_per_s if given. Returns (port, thread, commands)."""
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
            got = b""
            try:
                while len(got) < 15:   # the client's three 5-byte commands
                    block = conn.recv(15 - len(got))
                    if not block:
                        break
                    got += block
            except OSError:
                pass
            commands.append(got)
            cut = stall_after if stall_after is not None else close_after
            body = payload if cut is None else payload[:cut]
            conn.settimeout(120)   # the client may take its time over acquisition before reading on
            try:
                if bytes_per_s is None:
                    conn.sendall(body)
                else:
                    step = max(1, int(bytes_per_s / 20))
                    for i in range(0, len(body), step):
                        conn.sendall(body[i:i + step])
                        time.sleep(0.05)
                if close_after is None:
                    conn.settimeout(2.0)
                    conn.recv(1)   # silent until the client hangs up (or 2 s pass): a stall, then gone
            except OSError:
                pass
        srv.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return srv.getsockname()[1], thread, commands
