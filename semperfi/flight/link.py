"""Authenticated link between the flight side and the receiver (TCP).

Schema, version 1.  Each frame on the wire:

    4 bytes  big-endian length N of the rest (N <= MAX_FRAME_BYTES)
    N bytes  = 32-byte HMAC-SHA256(key, body) || body
    body     = UTF-8 JSON object {"v": 1, "type": T, "seq": int, "ts": float (UNIX s), "payload": {...}}

Types, in the order of one identification round:
    "hello"             receiver -> flight  {}   (at once on connecting: the flight side drops a connection that
                                             has not said it, authenticated, within a few seconds)
    "alarm"             receiver -> flight  {"reason": str, "t_s": float, "lines_of_sight": [{"prn": int,
                                             "az_deg": float, "el_deg": float}, ...]}   (the PRNs whose peaks the
                                             maneuver is to decide, seen from the receiver's last fix; at most 32,
                                             absent from older peers: alarm_lines_of_sight checks them)
    "maneuver_request"  flight -> receiver  {"maneuver_id": str, "t_s": float}   (flight has drawn the maneuver
                                             itself; t_s: the vehicle's clock as it sends, which the receiver pairs
                                             with its own sample clock as it reads it -- the two clocks are not
                                             the same on a UAV -- to map the track's times; absent: shared clock)
    "maneuver_done"     flight -> receiver  {"maneuver_id": str, "t_s": [...], "north_m": [...],
                                             "east_m": [...], "down_m": [...], "drift_bound_m": float}
                                             (the IMU track, and how far from the flight it may end: the
                                             identifier's tolerance grows with it; absent: its own 2 m)
    "maneuver_failed"   flight -> receiver  {"why": str}   (the flight side could not fly the maneuver asked for:
                                             the receiver stops waiting for its track at once)
    "verdict"           receiver -> flight  {"maneuver_id": str, "adversarial": bool, "peaks": [...]}
    "heartbeat"         both ways           {}   (every HEARTBEAT_S: a peer silent for SILENT_S is gone)

Each direction keeps its own strictly increasing ``seq``; a receiver of frames rejects a seq not above the last
accepted one (replay) and a timestamp outside +-MAX_SKEW_S of its clock.  The key is pre-shared.  Any malformed,
unauthenticated, replayed, truncated or oversized frame raises LinkError (logged); every read has a deadline (a
LinkPeer's is SILENT_S, kept open by the other end's heartbeats), so a silent or slow peer cannot stall the other
side.
"""
from __future__ import annotations

import hashlib
import hmac
import json
import logging
import math
import socket
import struct
import time

from ..errors import BadInput

VERSION = 1
MAX_FRAME_BYTES = 1 << 20
MAX_SKEW_S = 5.0
LOG_REJECTED_FIRST, LOG_REJECTED_EVERY = 5, 1000
MAX_SEQ_STEP = 1_000_000     # frames a peer may skip at once (it sends a few a minute; a TCP link loses none)
TYPES = {"hello", "alarm", "maneuver_request", "maneuver_done", "maneuver_failed", "verdict", "heartbeat"}
HEARTBEAT_S = 1.0            # how often a LinkPeer says it is there
SILENT_S = 5.0               # a peer that said nothing for this long is gone (hung, or the network is)
MAX_LINES_OF_SIGHT = 32
MAX_WHY_CHARS = 200          # a failure's reason, as sent
MAX_REQUIRED_SPREAD_M = 50.0   # a maneuver under 50 m flown cannot spread further along a line of sight
_MAC = 32
log = logging.getLogger(__name__)


class LinkError(BadInput):
    """The link to the other side failed, or it sent what the protocol does not allow."""


class Codec:
    """Signs outgoing and checks incoming messages for one endpoint."""

    def __init__(self, key: bytes, clock=time.time):
        if len(key) < 16:
            raise ValueError("pre-shared key must be at least 16 bytes")
        self._key = key
        self._clock = clock
        self._seq_out = 0
        self._seq_in = -1
        self.rejected = 0

    def encode(self, msg_type: str, payload: dict) -> bytes:
        if msg_type not in TYPES:
            raise ValueError(f"unknown message type {msg_type!r}")
        self._seq_out += 1
        body = json.dumps({"v": VERSION, "type": msg_type, "seq": self._seq_out, "ts": self._clock(),
                           "payload": payload}, separators=(",", ":")).encode()
        frame = hmac.new(self._key, body, hashlib.sha256).digest() + body
        if len(frame) > MAX_FRAME_BYTES:
            raise ValueError("message too large")
        return struct.pack(">I", len(frame)) + frame

    def decode(self, frame: bytes) -> tuple[str, dict]:
        """Check one frame (without the length prefix); returns (type, payload)."""
        try:
            return self._decode(frame)
        except LinkError as e:
            self.rejected += 1
            # the first few, then one line per LOG_REJECTED_EVERY: a flood of forged frames is no flood of lines
            if self.rejected <= LOG_REJECTED_FIRST or self.rejected % LOG_REJECTED_EVERY == 0:
                log.warning("link: rejected message (%d so far): %s", self.rejected, e)
            raise

    def _decode(self, frame: bytes):
        if len(frame) > MAX_FRAME_BYTES:
            raise LinkError("oversized")
        if len(frame) <= _MAC:
            raise LinkError("truncated")
        mac, body = frame[:_MAC], frame[_MAC:]
        if not hmac.compare_digest(mac, hmac.new(self._key, body, hashlib.sha256).digest()):
            raise LinkError("bad authentication code")
        try:
            msg = json.loads(body.decode("utf-8"))
        except (UnicodeDecodeError, ValueError, RecursionError):   # RecursionError: nesting deeper than the parser
            raise LinkError("malformed body") from None
        if not isinstance(msg, dict) or msg.get("v") != VERSION:
            raise LinkError("wrong schema version")
        seq, ts, t, payload = msg.get("seq"), msg.get("ts"), msg.get("type"), msg.get("payload")
        if (not isinstance(seq, int) or isinstance(seq, bool) or not _number(ts)
                or t not in TYPES or not isinstance(payload, dict)):
            raise LinkError("malformed fields")   # a NaN time stamp would pass any skew test
        if seq <= self._seq_in:
            raise LinkError(f"replayed sequence number {seq}")
        if seq - max(self._seq_in, 0) > MAX_SEQ_STEP:
            # a leap this far ahead, accepted, would make every later honest frame a "replay"
            raise LinkError(f"sequence number {seq} leaps more than {MAX_SEQ_STEP} past the last")
        if abs(self._clock() - ts) > MAX_SKEW_S:
            raise LinkError("stale or future timestamp")
        self._seq_in = seq
        return t, payload


def alarm_lines_of_sight(payload: dict) -> list[tuple[int, float, float]]:
    """The (prn, azimuth deg, elevation deg) an alarm carries (none from an older peer); LinkError if malformed."""
    entries = payload.get("lines_of_sight", [])
    if not isinstance(entries, list) or len(entries) > MAX_LINES_OF_SIGHT:
        raise LinkError(f"lines_of_sight: not a list of at most {MAX_LINES_OF_SIGHT}")
    out = []
    for entry in entries:
        if not isinstance(entry, dict):
            raise LinkError("lines_of_sight: an entry is not an object")
        prn, az, el = entry.get("prn"), entry.get("az_deg"), entry.get("el_deg")
        if not isinstance(prn, int) or isinstance(prn, bool) or not 1 <= prn <= 32:
            raise LinkError("lines_of_sight: prn must be an integer in 1..32")
        if not (_number(az) and _number(el) and 0.0 <= az <= 360.0 and -90.0 <= el <= 90.0):
            raise LinkError("lines_of_sight: az_deg must lie in [0, 360] and el_deg in [-90, 90]")
        out.append((prn, float(az), float(el)))
    if len({prn for prn, _, _ in out}) < len(out):
        raise LinkError("lines_of_sight: a PRN appears twice")
    return out


def alarm_required_spread_m(payload: dict) -> float:
    """How far the receiver needs the maneuver to move along each line of sight (0 from an older peer: no
    requirement); LinkError if malformed."""
    x = payload.get("required_spread_m", 0.0)
    if not (_number(x) and 0.0 <= x <= MAX_REQUIRED_SPREAD_M):
        raise LinkError(f"required_spread_m must lie in [0, {MAX_REQUIRED_SPREAD_M:g}]")
    return float(x)


def _number(x) -> bool:
    """A finite JSON number (json.loads lets NaN and Infinity through; a bool is not a number)."""
    return not isinstance(x, bool) and (isinstance(x, int) or (isinstance(x, float) and math.isfinite(x)))


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise LinkError("truncated: peer closed")
        buf += chunk
    return bytes(buf)


def send(sock: socket.socket, codec: Codec, msg_type: str, payload: dict) -> None:
    sock.sendall(codec.encode(msg_type, payload))


def receive(sock: socket.socket, codec: Codec, timeout_s: float = 5.0) -> tuple[str, dict]:
    """Read one frame; LinkError on anything wrong, including a timeout."""
    sock.settimeout(timeout_s)
    try:
        (n,) = struct.unpack(">I", _recv_exact(sock, 4))
        if n > MAX_FRAME_BYTES:
            log.warning("link: rejected message: oversized (%d bytes)", n)
            raise LinkError("oversized")
        return codec.decode(_recv_exact(sock, n))
    except (socket.timeout, TimeoutError):
        log.warning("link: timed out waiting for a message")
        raise LinkError("timeout") from None


class LinkPeer:
    """One end of the link on a connected TCP socket: send() signs and writes a message; a reader thread checks every
    frame that arrives and queues the good ones for poll(). A frame that fails its check is logged and dropped; a
    stream that loses its framing (oversized length, peer gone) is closed, since it cannot be trusted to resync."""

    def __init__(self, sock: socket.socket, key: bytes):
        import queue
        import threading
        self.sock, self.codec = sock, Codec(key)
        sock.settimeout(SILENT_S)   # the other end's heartbeats come every HEARTBEAT_S: silence this long is a loss
        self.closed: str | None = None
        self._queue: queue.Queue = queue.Queue()
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self._beat = threading.Thread(target=self._heartbeat, daemon=True)
        self._beat.start()

    def _heartbeat(self) -> None:
        while not self._stop.wait(HEARTBEAT_S) and self.closed is None:
            self.send("heartbeat", {})

    @property
    def rejected(self) -> int:
        return self.codec.rejected

    @classmethod
    def connect(cls, host: str, port: int, key: bytes, timeout_s: float = 5.0) -> LinkPeer:
        """The receiver's end: connects, and says an authenticated hello at once (the flight side serves no
        connection that has not)."""
        try:
            sock = socket.create_connection((host, int(port)), timeout=timeout_s)
        except OSError as exc:
            raise LinkError(f"cannot reach the link at {host}:{port}: {exc.strerror or exc}") from None
        peer = cls(sock, key)
        peer.send("hello", {})
        return peer

    def _read(self) -> None:
        while self.closed is None:
            try:
                (n,) = struct.unpack(">I", _recv_exact(self.sock, 4))
                if n > MAX_FRAME_BYTES:
                    raise LinkError("oversized frame: the stream cannot be trusted any more")
                frame = _recv_exact(self.sock, n)
            except (socket.timeout, TimeoutError):
                self.closed = f"the peer was silent for {SILENT_S:g} s (no heartbeat)"
                return
            except (LinkError, OSError) as exc:
                self.closed = str(exc) or type(exc).__name__
                return
            try:
                message = self.codec.decode(frame)
            except LinkError:
                continue          # counted (and logged, throttled) by the codec
            if message[0] != "heartbeat":
                self._queue.put(message)

    def send(self, msg_type: str, payload: dict) -> None:
        with self._send_lock:
            try:
                self.sock.sendall(self.codec.encode(msg_type, payload))
            except OSError as exc:
                self.closed = f"send failed: {exc}"

    def poll(self) -> list[tuple[str, dict]]:
        out = []
        while not self._queue.empty():
            out.append(self._queue.get_nowait())
        return out

    def pending(self) -> bool:
        """Whether a message waits to be read."""
        return not self._queue.empty()

    def wait(self, timeout_s: float) -> tuple[str, dict] | None:
        """The next message, or None after timeout_s (or when the link is closed)."""
        import queue
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def close(self) -> None:
        self.closed = self.closed or "closed"
        self._stop.set()
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
