"""Where the receiver's samples come from: a file, standard input (`-`) or an rtl_tcp server
(`rtl_tcp://HOST:PORT`), cut to a window (skip, duration) and, optionally, brought down to a processing rate.

Decimation (fs_out_hz) mixes a signal at an IF to baseband first (a real front end's samples included), then low-passes
and keeps every M-th sample (decimate.StreamDecimator), so a 25 MSa/s recording is processed at, say, 5 MSa/s; the
processing IF is then 0. Times the receiver reports count from the first sample after the skip.

A live stream is watched: when samples arrive slower than the stated rate while the receiver waits for them, or the
receiver falls behind a live stream (whose server then drops samples), the source records a notice with the time and
what happened, because time kept by counting samples is then wrong from that point on. A stream that stops or closes
is a SourceError (a ValueError: one line), raised after the samples that did arrive.
"""

from __future__ import annotations

import os
import select
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import BinaryIO, Iterator

import numpy as np

from ..errors import BadInput

from .decimate import StreamDecimator, decimation_factor
from .formats import MAX_READ_BYTES, SampleFormat, _finite_float, _positive_float, as_format, decode_items
from .reader import open_iq

LIVE_WINDOW_S = 5.0      # wall time over which a live stream's rate is judged
SLOW_FRACTION = 0.9      # arriving below this fraction of the stated rate, while we wait, is a losing stream
WAITING_FRACTION = 0.5   # ... "while we wait": at least this share of the window spent blocked on the stream
LAGGING_FRACTION = 0.98  # consuming below this fraction without waiting: we are behind the live stream
MAX_READ_SAMPLES = 1 << 20   # input samples per read: a 25 MSa/s stream costs 8 MB at a time, not 0.1 s's 20 MB
HUGE_ARRAY_BYTES = 1 << 22   # numpy backs arrays from this size on with transparent huge pages
PIPE_STALL_S = 10.0      # standard input silent this long is lost (as an rtl_tcp stream: its timeout is 5 s)


def chunk_seconds(fs_hz: float, nominal_s: float = 0.1) -> float:
    """nominal_s, or longer so that a chunk of complex64 samples is a huge-page array: each chunk's fresh arrays
    then cost the kernel a few page faults instead of a thousand (a second of system time per minute at 4 MSa/s)."""
    return max(nominal_s, 1.05 * HUGE_ARRAY_BYTES / (8 * fs_hz))


class SourceError(BadInput):
    """The input failed part-way (closed, stalled); the samples before it were delivered."""


@dataclass
class Notice:
    kind: str            # input_slow | input_lagging | nonfinite_samples
    t_s: float           # processing time at which it was seen
    fields: dict = field(default_factory=dict)


class _FileInput:
    """A file's samples, each read's successor read and decoded ahead on a thread of its own while the caller works
    on this one: the decode and the page faults (a second a minute at 10 MSa/s int16, more from a cold disk) leave
    the thread that tracks. The samples are the same whichever thread reads them."""

    def __init__(self, reader):
        self.reader, self.pos = reader, 0
        self._ahead = None      # (position, count, future) of the read expected next
        self._thread: ThreadPoolExecutor | None = None

    def take(self, n: int) -> np.ndarray:
        ahead, self._ahead = self._ahead, None
        if ahead is not None and ahead[:2] == (self.pos, n):
            out = ahead[2].result()
        else:
            if ahead is not None:
                ahead[2].exception()   # a wrong guess (a shorter last read): let it finish, then read anew
            out = self.reader.read(self.pos, n)
        self.reader.release(self.pos, len(out))
        self.pos += len(out)
        if len(out) == n and self.pos < self.reader.n_samples:
            if self._thread is None:
                self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="semperfi-read")
            self._ahead = (self.pos, n, self._thread.submit(self.reader.read, self.pos, n))
        return out

    def close(self) -> None:
        if self._thread is not None:
            self._thread.shutdown(wait=True, cancel_futures=True)
            self._thread, self._ahead = None, None


class _PipeInput:
    """Whole blocks from a byte stream; a partial block at the end is counted in truncated_bytes. A stream that
    stays silent for stall_s (a pipe whose writer hangs) is a SourceError after the samples that did arrive."""

    def __init__(self, stream: BinaryIO, fmt: SampleFormat, stall_s: float = PIPE_STALL_S):
        self.stream, self.fmt, self.truncated_bytes, self.stall_s = stream, fmt, 0, stall_s
        self._leftover = np.empty(0, dtype=np.complex64)   # decoded samples of a block not yet handed out
        try:
            self._fd = stream.fileno()
        except (AttributeError, OSError, ValueError):   # an in-memory stream: it cannot stall
            self._fd = None

    def _read(self, n: int) -> bytes:
        """Up to n bytes, as soon as any are there; b"" at the end of the stream. A real descriptor is read directly
        (never through the stream's buffer, which select cannot see), after waiting at most stall_s for it."""
        if self._fd is None:
            return self.stream.read(n)
        ready, _, _ = select.select([self._fd], [], [], self.stall_s)
        if not ready:
            raise SourceError(f"input stalled: nothing for {self.stall_s:g} s")
        return os.read(self._fd, n)

    def take(self, n: int) -> np.ndarray:
        per, size = self.fmt.samples_per_block, self.fmt.block_bytes
        need = max(0, n - len(self._leftover))
        want = -(-need // per) * size
        raw = bytearray()
        while len(raw) < want:
            block = self._read(want - len(raw))
            if not block:
                break
            raw += block
        whole = len(raw) // size * size
        if whole < len(raw):   # only at the end of the stream: reads above go on until they have whole blocks
            self.truncated_bytes = len(raw) - whole
        fresh = decode_items(np.frombuffer(bytes(raw[:whole]), dtype=self.fmt.item_dtype), self.fmt)
        samples = np.concatenate([self._leftover, fresh]) if len(self._leftover) else fresh
        self._leftover = samples[n:]
        return samples[:n]


class _RtlTcpInput:
    """The server's samples; when it stalls or closes, the samples of the read it cut short are delivered first,
    and the failure at the next take."""

    def __init__(self, source):
        self.source = source
        self._failed: str | None = None

    def take(self, n: int) -> np.ndarray:
        from .rtltcp import StreamEnded
        if self._failed is not None:
            raise SourceError(self._failed)
        try:
            return self.source.read(self.source.samples_read, n)
        except StreamEnded as exc:
            if not exc.samples.size:
                raise SourceError(str(exc)) from None
            self._failed = str(exc)
            return exc.samples
        except ValueError as exc:
            raise SourceError(str(exc)) from None


RTL_FS_RANGES_HZ = ((225e3, 300e3), (900e3, 3.2e6))   # what an RTL2832U samples at


def _rtl_tcp(url: str, fmt, fs_hz, if_hz):
    from .rtltcp import RtlTcpSource
    host, _, port = url[len("rtl_tcp://"):].rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536 or fs_hz is None:
        raise ValueError(f"expected rtl_tcp://HOST:PORT with --fs, got {url!r}")
    fs_hz = _positive_float(fs_hz, "sample rate (--fs)")
    if not any(lo <= fs_hz <= hi for lo, hi in RTL_FS_RANGES_HZ):
        raise ValueError(f"an RTL-SDR samples at 225-300 kHz or 0.9-3.2 MHz, not --fs {fs_hz:g}")
    if fmt is not None and as_format(fmt).name != "cu8":
        raise ValueError(f"rtl_tcp delivers unsigned 8-bit I/Q (cu8): --format {as_format(fmt).name} does not apply")
    if if_hz:
        raise ValueError(f"rtl_tcp is tuned to L1 itself (IF 0): --if {if_hz:g} does not apply")
    return RtlTcpSource(host, int(port), fs_hz)


class SampleSource:
    """Consecutive chunks of complex64 samples at the processing rate `fs_hz` and IF `if_hz`."""

    def __init__(self, spec: str, fmt=None, fs_hz=None, if_hz=None, *, skip_s: float = 0.0,
                 duration_s: float | None = None, fs_out_hz: float | None = None, stdin: BinaryIO | None = None):
        self.spec, self.sidecar, self.truncated_bytes = str(spec), None, 0
        self.live = False
        if self.spec == "-":
            if fmt is None or fs_hz is None:
                raise ValueError("reading samples from standard input needs --format and --fs")
            self.fmt, self.fs_in_hz = as_format(fmt), _positive_float(fs_hz, "sample rate (--fs)")
            self.if_in_hz = _finite_float(if_hz or 0.0, "intermediate frequency (--if)")
            self._input = _PipeInput(stdin or sys.stdin.buffer, self.fmt)
            self.n_available = None
        elif self.spec.startswith("rtl_tcp://"):
            rtl = _rtl_tcp(self.spec, fmt, fs_hz, if_hz)
            self.fmt, self.fs_in_hz, self.if_in_hz = as_format("cu8"), rtl.fs_hz, 0.0
            self._input, self.n_available, self.live = _RtlTcpInput(rtl), None, True
        else:
            reader = open_iq(self.spec, fmt, fs_hz, if_hz)
            self.fmt, self.fs_in_hz, self.if_in_hz = reader.fmt, reader.fs_hz, reader.if_hz
            self.sidecar, self.truncated_bytes = reader.sidecar, reader.truncated_bytes
            self._input, self.n_available = _FileInput(reader), reader.n_samples
        if self.fmt.is_complex and not abs(self.if_in_hz) < self.fs_in_hz / 2:
            raise ValueError(f"complex samples hold frequencies within +-fs/2 ({self.fs_in_hz / 2:g} Hz): --if "
                             f"{self.if_in_hz:g} Hz lies outside")
        if not self.fmt.is_complex and not 0 < abs(self.if_in_hz) < self.fs_in_hz / 2:
            raise ValueError(f"real-valued samples ({self.fmt.name}) need --if between 0 and fs/2 "
                             f"({self.fs_in_hz / 2:g} Hz), got {self.if_in_hz:g} Hz")
        skip_s = _finite_float(skip_s, "--skip")
        if skip_s < 0:
            raise ValueError(f"--skip must not be negative, got {skip_s:g} s")
        if duration_s is not None and not (_finite_float(duration_s, "--duration") > 0):
            raise ValueError(f"--duration must be positive, got {duration_s:g} s")
        self.skip_samples = int(round(skip_s * self.fs_in_hz))
        if self.n_available is not None and self.skip_samples >= self.n_available:
            raise ValueError(f"--skip {skip_s:g} s is past the end of {self.spec} "
                             f"({self.n_available / self.fs_in_hz:.3f} s)")
        self.stop_samples = None if duration_s is None else int(round(duration_s * self.fs_in_hz))
        self.factor = 1 if fs_out_hz is None else decimation_factor(self.fs_in_hz, float(fs_out_hz))
        self.fs_hz = self.fs_in_hz / self.factor
        self.if_hz = 0.0 if self.factor > 1 else self.if_in_hz
        self._decimator = StreamDecimator(self.factor) if self.factor > 1 else None
        self.samples_in = 0        # input samples delivered after the skip
        self.n_samples = 0         # processing samples delivered
        self.notices: list[Notice] = []
        self.nonfinite_samples = 0  # NaN or infinite samples zeroed
        self._skipped = False

    @property
    def real_valued(self) -> bool:
        """Whether the samples delivered are real values at an IF (decimation mixes them to complex baseband)."""
        return not self.fmt.is_complex and self.factor == 1

    @property
    def name(self) -> str:
        return "standard input" if self.spec == "-" else self.spec

    @property
    def expected_samples(self) -> int | None:
        """Processing samples the window holds, when known (a file, or a duration)."""
        n = None if self.n_available is None else self.n_available - self.skip_samples
        if self.stop_samples is not None:
            n = self.stop_samples if n is None else min(n, self.stop_samples)
        return None if n is None else n // self.factor

    @property
    def missing_s(self) -> float:
        """Seconds of the window asked for (--duration) that the input ended before."""
        return 0.0 if self.stop_samples is None else max(self.stop_samples - self.samples_in, 0) / self.fs_in_hz

    def _skip(self) -> None:
        if isinstance(self._input, _FileInput):
            self._input.pos = self.skip_samples
        else:
            left = self.skip_samples
            while left > 0:
                got = len(self._input.take(min(left, MAX_READ_SAMPLES)))
                if got == 0:
                    raise ValueError(f"{self.name} ended while skipping {self.skip_samples} samples")
                left -= got
        self._skipped = True

    def chunks(self, chunk_s: float) -> Iterator[np.ndarray]:
        """Processing-rate chunks of about chunk_s seconds until the window or the input ends."""
        if not self._skipped:
            self._skip()
        step = self.factor * self.fmt.samples_per_block
        n_in = max(step, min(int(round(chunk_s * self.fs_in_hz)), MAX_READ_SAMPLES) // step * step)
        watch = _LiveWatch(self) if self.live else None
        while self.stop_samples is None or self.samples_in < self.stop_samples:
            want = n_in if self.stop_samples is None else min(n_in, self.stop_samples - self.samples_in)
            t_wait = time.perf_counter()
            x = self._input.take(want)
            n_read = len(x)
            if watch is not None:
                watch.waited(time.perf_counter() - t_wait, n_read)
            if n_read == 0:
                break
            if not self.fmt.is_integer:
                x = self._finite(x)
            if self._decimator is not None:
                if self.if_in_hz:
                    x = self._to_baseband(x)
                x = self._decimator.process(x)
            self.samples_in += n_read
            self.n_samples += len(x)
            if len(x):
                yield x
        self.truncated_bytes = getattr(self._input, "truncated_bytes", self.truncated_bytes)

    def _finite(self, x: np.ndarray) -> np.ndarray:
        """Float samples with NaN or infinity in them (a broken converter, a hostile file) zeroed, counted, and
        reported the first time: one would poison every correlation it enters."""
        bad = ~np.isfinite(x)
        if not bad.any():
            return x
        if not self.nonfinite_samples:
            self.notices.append(Notice("nonfinite_samples", self.n_samples / self.fs_hz, {
                "why": f"samples that are NaN or infinite from {self.samples_in / self.fs_in_hz:.3f} s on: zeroed"}))
        self.nonfinite_samples += int(bad.sum())
        x = x.copy()
        x[bad] = 0
        return x

    def _to_baseband(self, x: np.ndarray) -> np.ndarray:
        """Shift L1 from the IF to 0 Hz, the phase running on from chunk to chunk (index in input samples)."""
        k = self.samples_in + np.arange(len(x), dtype=np.float64)
        cycles = np.mod(self.if_in_hz / self.fs_in_hz * k, 1.0)
        return (x * np.exp(-2j * np.pi * cycles).astype(np.complex64)).astype(np.complex64)

    def take(self, n: int) -> np.ndarray:
        """The first n processing samples of the window (acquisition's one look)."""
        limit = MAX_READ_BYTES * self.fmt.samples_per_block // (self.fmt.block_bytes * self.factor)
        if n > limit:   # a hostile --fs must not make one look hold gigabytes
            raise ValueError(f"one read must be below {limit} samples, got {n}")
        parts, got = [], 0
        for chunk in self.chunks(min(1.0, n / self.fs_hz + 1e-3)):
            parts.append(chunk)
            got += len(chunk)
            if got >= n:
                break
        out = np.concatenate(parts)[:n] if parts else np.empty(0, dtype=np.complex64)
        if len(out) < n:
            raise ValueError(f"{self.name} ended after {len(out)} of the {n} samples needed")
        return out

    def close(self) -> None:
        if isinstance(self._input, _FileInput):
            self._input.close()
        src = getattr(self._input, "source", None)
        if src is not None:
            src.close()


class _LiveWatch:
    """Judges a live stream's rate over windows of wall time (see the module's docstring)."""

    def __init__(self, source: SampleSource):
        self.source = source
        self._start, self._waited_s, self._samples = time.perf_counter(), 0.0, 0

    def waited(self, seconds: float, n_samples: int) -> None:
        self._waited_s += seconds
        self._samples += n_samples
        wall = time.perf_counter() - self._start
        if wall < LIVE_WINDOW_S:
            return
        s = self.source
        rate = self._samples / wall
        t_s = s.n_samples / s.fs_hz
        if rate < SLOW_FRACTION * s.fs_in_hz and self._waited_s > WAITING_FRACTION * wall:
            s.notices.append(Notice("input_slow", t_s, {
                "arrival_rate_hz": round(rate), "stated_rate_hz": s.fs_in_hz,
                "why": "the stream delivers fewer samples than its rate: samples are being lost upstream, "
                       "so time counted in samples runs slow from here"}))
        elif rate < LAGGING_FRACTION * s.fs_in_hz and self._waited_s < WAITING_FRACTION * wall:
            s.notices.append(Notice("input_lagging", t_s, {
                "processing_rate_hz": round(rate), "stated_rate_hz": s.fs_in_hz,
                "why": "processing is slower than the live stream: its server drops samples once its buffer "
                       "fills, so time counted in samples goes wrong from here"}))
        self._start, self._waited_s, self._samples = time.perf_counter(), 0.0, 0


def open_source(spec, fmt=None, fs_hz=None, if_hz=None, **window) -> SampleSource:
    """A SampleSource for a path, `-` or rtl_tcp://HOST:PORT (see SampleSource for the window's keywords)."""
    return SampleSource(os.fspath(spec), fmt, fs_hz, if_hz, **window)
