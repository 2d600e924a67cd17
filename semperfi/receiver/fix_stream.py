"""Fixes streamed to a consumer that needs them steadily (an autopilot's GPS input, NMEA to a port).

An autopilot calls its GPS unhealthy when new fixes average more than ~215 ms apart (ArduPilot), so a sender thread
hands one fix on every 1/RATE_HZ on an absolute schedule (no drift, no bursts) however the fixes arrive. The
receiver computes fixes a chunk of samples at a time (several in a burst, then none): each goes out once, in order,
one per period, so the autopilot sees a new fix every period rather than the same one thrice and then a jump; at
most BACKLOG wait (a recording processed faster than real time sends its newest ones, the latency stays bounded);
with nothing new the last one goes again until it is STALE_S old, then "no fix". Nothing waits on the consumer (its
sends have a deadline; a failure is counted, never a hang).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque

from .types import Fix

RATE_HZ = 10.0
STALE_S = 0.5              # a fix this old on the wall clock is no longer the vehicle's position
BACKLOG = 3                # fixes waiting their turn at most: 0.3 s of latency at 10 Hz


class Pacer:
    """Send times on an absolute schedule every period_s: a late send does not push the next ones back, and after
    a long stall (more than a period behind) the schedule restarts from now instead of bursting to catch up."""

    def __init__(self, period_s: float, now_s: float):
        self.period_s = period_s
        self.next_s = now_s

    def wait_s(self, now_s: float) -> float:
        """How long to sleep before the next send."""
        return max(self.next_s - now_s, 0.0)

    def sent(self, now_s: float) -> None:
        self.next_s += self.period_s
        if self.next_s < now_s - self.period_s:
            self.next_s = now_s + self.period_s


class FixStream:
    """`update(fix)` with every fix; a thread hands the next one (in order, each once; the last again when none is
    new; None once it is STALE_S old, or before the first) to send(fix, unix_time_s) every 1/rate_hz until `close()`.
    clock() is the monotonic clock and wall() the UNIX time (injectable for tests, which call step() themselves with
    start=False)."""

    def __init__(self, send, rate_hz: float = RATE_HZ, clock=time.monotonic, wall=time.time, start: bool = True):
        self._send, self._clock, self._wall = send, clock, wall
        self._lock = threading.Lock()
        self._fix: Fix | None = None
        self._fix_at_s = -math.inf
        self._waiting: deque[tuple[Fix, float]] = deque(maxlen=BACKLOG)
        self._stop = threading.Event()
        self.pacer = Pacer(1.0 / rate_hz, clock())
        self.sent = 0
        self.failed = 0
        self._thread = threading.Thread(target=self._run, daemon=True) if start else None
        if self._thread is not None:
            self._thread.start()

    def update(self, fix: Fix) -> None:
        with self._lock:
            self._waiting.append((fix, self._clock()))

    def next(self) -> Fix | None:
        """The fix to send now: the oldest waiting one, else the last sent again; None if that is stale."""
        now = self._clock()
        with self._lock:
            if self._waiting:
                self._fix, self._fix_at_s = self._waiting.popleft()
            return self._fix if now - self._fix_at_s <= STALE_S else None

    def step(self) -> None:
        """One send, on schedule (the thread's loop body)."""
        try:
            self._send(self.next(), self._wall())
            self.sent += 1
        except OSError:   # the other end is gone or full: counted; the next send tries again
            self.failed += 1
        self.pacer.sent(self._clock())

    def _run(self) -> None:
        while not self._stop.wait(self.pacer.wait_s(self._clock())):
            self.step()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
