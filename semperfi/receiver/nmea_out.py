"""Fixes as NMEA (GGA, RMC) to a port: a TCP peer (tcp:HOST:PORT), a UDP one (udpout:HOST:PORT) or a serial device
(an autopilot's NMEA GPS input, `GPS1_TYPE 5` on ArduPilot; gpsd; a logger). Paced by fix_stream.FixStream. A fix the
receiver cannot vouch for goes out marked invalid (outputs.nmea_sentences), so the consumer does not use it.

Every write has a deadline (WRITE_TIMEOUT_S); a lost TCP peer is reconnected at most every RECONNECT_S, and the
failures in between are counted by the stream, never waited on.
"""

from __future__ import annotations

import socket
import time

from ..address import parse_address
from .outputs import nmea_sentences
from .types import Fix

WRITE_TIMEOUT_S = 1.0
RECONNECT_S = 2.0


class NmeaOut:
    def __init__(self, url: str, clock=time.monotonic):
        self.address = parse_address(url, "--nmea-out")
        a = self.address
        if a.form not in ("tcp", "udpout", "serial"):
            raise ValueError(f"--nmea-out {url!r}: NMEA goes to tcp:HOST:PORT, udpout:HOST:PORT or a serial device")
        self._clock = clock
        self._conn = None
        self._next_try_s = -float("inf")
        self._connect()   # a wrong address is a user's mistake, said at once

    def _connect(self) -> None:
        a = self.address
        self._next_try_s = self._clock() + RECONNECT_S
        if a.form == "serial":
            try:
                import serial
                self._conn = serial.Serial(a.device, a.baud, write_timeout=WRITE_TIMEOUT_S)
            except (ImportError, OSError, ValueError) as exc:
                raise ValueError(f"--nmea-out {a.device}: {exc}") from None
            return
        try:
            if a.form == "tcp":
                self._conn = socket.create_connection((a.host, a.port), timeout=WRITE_TIMEOUT_S)
            else:
                self._conn = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self._conn.connect((a.host, a.port))
            self._conn.settimeout(WRITE_TIMEOUT_S)
        except OSError as exc:
            raise ValueError(f"--nmea-out {a.host}:{a.port}: {exc.strerror or exc}") from None

    def send(self, fix: Fix | None, unix_time_s: float) -> None:
        """FixStream's sink: GGA and RMC of the latest fresh fix (nothing while there is none)."""
        if fix is None:
            return
        if self._conn is None:
            if self._clock() < self._next_try_s:
                raise OSError("the NMEA peer is gone")
            try:
                self._connect()
            except ValueError as exc:
                raise OSError(str(exc)) from None
        data = b"".join(nmea_sentences(fix))
        try:
            if self.address.form == "serial":
                self._conn.write(data)
            else:
                self._conn.sendall(data)
        except OSError:
            self.close()
            raise

    def close(self) -> None:
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass
            self._conn = None
