"""A client of `rtl_tcp`, the server RTL-SDR dongles speak (port 1234): 8-bit unsigned IQ (SigMF `cu8`).

On connect the server sends a 12-byte header: b"RTL0", the tuner type and the gain count (big-endian uint32).
Commands are 5 bytes, struct '>BI': 0x01 centre frequency (Hz), 0x02 sample rate (Hz), 0x03 gain mode
(0 = automatic). The other end may be anything: a wrong header, a silent or slow stream are one ValueError line
each, and a read never waits longer than `timeout_s` for the next bytes.
"""

from __future__ import annotations

import socket
import struct

import numpy as np

from .formats import as_format, decode_items
from .formats import MAX_READ_BYTES

MAGIC = b"RTL0"
HEADER = struct.Struct(">4sII")
COMMAND = struct.Struct(">BI")
SET_FREQUENCY, SET_SAMPLE_RATE, SET_GAIN_MODE = 0x01, 0x02, 0x03
KNOWN_TUNERS = {0: "unknown", 1: "E4000", 2: "FC0012", 3: "FC0013", 4: "FC2580", 5: "R820T", 6: "R828D"}
CU8 = as_format("cu8")


class _Partial(ValueError):
    def __init__(self, message: str, received: bytearray):
        super().__init__(message)
        self.received = bytes(received)


class StreamEnded(ValueError):
    """The server stalled or closed mid-read; `samples` holds the whole samples that did arrive before."""

    def __init__(self, message: str, samples: np.ndarray):
        super().__init__(message)
        self.samples = samples


class RtlTcpSource:
    """Connect, check the header, tune, then `read` whole blocks of complex samples (centred uint8)."""

    def __init__(self, host: str, port: int, fs_hz: float, center_hz: float = 1575.42e6, timeout_s: float = 5.0):
        self.fs_hz, self.if_hz, self.timeout_s = float(fs_hz), 0.0, float(timeout_s)
        self.samples_read = 0
        try:
            self._sock = socket.create_connection((host, int(port)), timeout=self.timeout_s)
        except OSError as exc:
            raise ValueError(f"cannot connect to rtl_tcp at {host}:{port}: {exc.strerror or exc}") from None
        try:
            magic, tuner, gains = HEADER.unpack(self._recv_exactly(HEADER.size, "the rtl_tcp header"))
            if magic != MAGIC:
                raise ValueError(f"{host}:{port} is not an rtl_tcp server (header starts {magic!r}, not {MAGIC!r})")
            if tuner not in KNOWN_TUNERS or gains > 1000:
                raise ValueError(f"rtl_tcp header from {host}:{port} is malformed (tuner {tuner}, {gains} gains)")
            self.tuner = KNOWN_TUNERS[tuner]
            for cmd, value in ((SET_SAMPLE_RATE, round(self.fs_hz)), (SET_FREQUENCY, round(center_hz)),
                               (SET_GAIN_MODE, 0)):
                self._sock.sendall(COMMAND.pack(cmd, value))
        except (ValueError, OSError) as exc:
            self.close()
            raise ValueError(str(exc) if isinstance(exc, ValueError) else f"rtl_tcp {host}:{port}: {exc}") from None

    def _recv_exactly(self, n_bytes: int, what: str) -> bytes:
        buf = bytearray()
        while len(buf) < n_bytes:
            try:
                block = self._sock.recv(min(n_bytes - len(buf), 1 << 20))
            except socket.timeout:
                raise _Partial(f"rtl_tcp stream stalled: nothing for {self.timeout_s:g} s while reading {what} "
                               f"({len(buf)} of {n_bytes} bytes, {self.samples_read} samples before)", buf) from None
            except OSError as exc:   # reset by the server, or the network gone
                raise _Partial(f"rtl_tcp connection failed while reading {what}: {exc.strerror or exc} "
                               f"({len(buf)} of {n_bytes} bytes, {self.samples_read} samples before)", buf) from None
            if not block:
                raise _Partial(f"rtl_tcp server closed the connection while sending {what} "
                               f"({len(buf)} of {n_bytes} bytes, {self.samples_read} samples before)", buf)
            buf += block
        return bytes(buf)

    def read(self, start_sample: int, n_samples: int) -> np.ndarray:
        """Samples [start_sample, start_sample + n) of the stream; a live stream only goes forward."""
        if start_sample < self.samples_read:
            raise ValueError(f"a live stream cannot go back to sample {start_sample} (at {self.samples_read})")
        if (start_sample - self.samples_read + n_samples) * CU8.bytes_per_sample > MAX_READ_BYTES:
            raise ValueError("request too large for a live stream")
        skip = start_sample - self.samples_read
        if skip:
            self._recv_exactly(skip * CU8.bytes_per_sample, "samples to skip")
            self.samples_read += skip
        try:
            raw = self._recv_exactly(n_samples * CU8.bytes_per_sample, f"{n_samples} samples")
        except _Partial as cut:   # what arrived before the stall or the close is signal: hand it on
            whole = len(cut.received) // CU8.bytes_per_sample * CU8.bytes_per_sample
            self.samples_read += whole // CU8.bytes_per_sample
            raise StreamEnded(str(cut), decode_items(np.frombuffer(cut.received[:whole], dtype=np.uint8), CU8)) \
                from None
        self.samples_read += n_samples
        return decode_items(np.frombuffer(raw, dtype=np.uint8), CU8)

    def close(self) -> None:
        try:
            self._sock.close()
        except OSError:
            pass
