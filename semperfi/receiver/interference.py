"""Narrowband interference: found in the spectrum of an acquisition block, reported, and excised before the search.

A CW jammer, a front end's clock spur or its DC offset puts its power in a few spectral lines. GPS lies below the
noise and spreads over the whole band, so at a block's resolution (1 / its length) no GPS line stands above the
noise floor: a line that does is interference. Its correlation with a C/A code is flat in code phase and sits on
every PRN at once, so left in it makes PRNs look acquired that are not there.
"""

from dataclasses import dataclass

import numpy as np
import scipy.fft

EXCISE_DB = 13.0          # a bin this far above its local noise floor is a spur (noise does it with p = e^-20)
EXCISE_MAX_FRACTION = 0.02   # more flagged bins than this is not narrowband: nothing is excised
COMB_MIN_MS = 20          # the 1 kHz comb is notched only in blocks this long (it costs 3 bins in N ms)
COMB_RATIO = 1.3          # mean comb-bin power over the rest that says "1 ms periodic interference"
MAX_LINES_REPORTED = 8
# Interference this much stronger than the whole band's noise (J/N) denies GPS: with a C/A code's ~30 dB of CW
# rejection and excision's notch depth limited by the ADC's few bits, what is left under it is the interference's
# own quantisation and sidebands, not the noise GPS rides on (COTS receivers lose lock at 40-50 dB).
JAMMING_JN_DB = 50.0
# A line weaker than this (its J/N) is left alone: GPS signals have lines too, up to 21 dB under their power (a
# +20 dB spoofer over a 45 dB-Hz sky at 2 MSa/s: -19 dB each, dozens of them), and notching a strong spoofer's
# lines blurs the twins under it that the defence looks for. A tone that harms a satellite is stronger.
REPORT_JN_DB = -10.0
JN_SHOWN_MAX_DB = 90.0    # beyond this a ratio only says the recording has no noise floor


@dataclass(frozen=True)
class Line:
    offset_hz: float      # from the band's centre (the IF): a tone at L1 + offset_hz
    jn_db: float          # its power over the noise power of the whole recorded band (J/N)


@dataclass(frozen=True)
class Interference:
    """What one block's spectrum held besides noise and GPS."""
    lines: tuple[Line, ...] = ()
    excised_bins: int = 0     # spectral bins zeroed (DC and the lines, with two neighbours each side)
    wideband: bool = False    # too much of the band flagged to excise: left in, and reported
    comb: bool = False        # a 1 kHz comb (interference repeating every millisecond) notched
    jn_db: float = -np.inf    # all the flagged lines' power over the band's noise

    @property
    def present(self) -> bool:
        """Worth excising and reporting, and a search threshold that the interference's remains cannot pass."""
        return bool(self.lines) and self.lines[0].jn_db >= REPORT_JN_DB or self.comb or self.jamming

    @property
    def jamming(self) -> bool:
        """Strong enough to deny GPS: nothing found under it is a satellite."""
        return self.jn_db >= JAMMING_JN_DB

    def describe(self) -> str:
        parts = [f"a tone at {line.offset_hz / 1e3:+.1f} kHz ({_jn_text(line.jn_db)})" for line in self.lines[:3]]
        if len(self.lines) > 3:
            parts.append(f"{len(self.lines) - 3} weaker lines")
        if self.comb:
            parts.append("a 1 kHz comb")
        if self.wideband:
            parts.append("lines over more than 2 % of the band, not excised")
        kind = "jamming" if self.jamming else "narrowband interference"
        return f"{kind} ({_jn_text(self.jn_db)} in all): " + ", ".join(parts)

    def fields(self) -> dict:
        """For an `interference` event."""
        return {"tones_hz": [round(line.offset_hz, 1) for line in self.lines],
                "jn_db": [round(min(line.jn_db, JN_SHOWN_MAX_DB), 1) for line in self.lines],
                "total_jn_db": round(min(self.jn_db, JN_SHOWN_MAX_DB), 1), "jamming": self.jamming,
                "excised_bins": self.excised_bins, "wideband": self.wideband, "comb": self.comb}


def _jn_text(jn_db: float) -> str:
    return f"J/N > {JN_SHOWN_MAX_DB:.0f} dB" if jn_db > JN_SHOWN_MAX_DB else f"J/N {jn_db:.0f} dB"


NONE = Interference()


def _local_floor_reference(p: np.ndarray) -> np.ndarray:
    """Each bin's noise floor: the median of its 64th of the band (robust to a few spur bins), as an exponential
    bin's mean."""
    n = p.size
    n_seg = 64 if n >= 64 * 16 else 1
    edges = np.linspace(0, n, n_seg + 1).astype(np.int64)
    floor = np.empty(n)
    for lo, hi in zip(edges[:-1], edges[1:]):
        floor[lo:hi] = np.median(p[lo:hi]) / np.log(2.0)
    return floor


def _local_floor(p: np.ndarray) -> np.ndarray:
    """_local_floor_reference in one median over the 64 equal parts when the band divides into them (a look's whole
    milliseconds do): 64 medians a look were 4 % of a defended run's time, on its main thread."""
    n = p.size
    if n < 64 * 16 or n % 64:
        return _local_floor_reference(p)
    return np.repeat(np.median(p.reshape(64, n // 64), axis=1) / np.log(2.0), n // 64)


def _db(ratio: float) -> float:
    return float(10 * np.log10(max(ratio, 1e-300)))


def _lines(p: np.ndarray, floor: np.ndarray, flagged: np.ndarray, fs_hz: float, if_hz: float,
           real_input: bool) -> tuple[tuple[Line, ...], float]:
    """The flagged bins as lines (runs of adjacent bins), strongest first, with their power over the band's noise;
    and all of them together over that noise (dB)."""
    n = p.size
    idx = np.nonzero(flagged)[0]
    if idx.size == 0:
        return (), -np.inf
    freqs = np.fft.fftfreq(n, 1.0 / fs_hz)
    noise = max(float(floor.sum()), 1e-300)   # a noiseless recording has none: its J/N is "beyond any shown"
    excess = np.maximum(p - floor, 0.0)
    runs = np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1)
    lines = []
    for run in runs:
        peak = run[np.argmax(p[run])]
        if real_input and freqs[peak] < 0:   # a real signal's spectrum is its own mirror: one line per tone
            continue
        lines.append((float(excess[run].sum()), float(freqs[peak] - if_hz)))
    lines.sort(key=lambda line: -line[0])
    shown = tuple(Line(offset_hz, _db(power / noise)) for power, offset_hz in lines[:MAX_LINES_REPORTED])
    return shown, _db(float(excess[idx].sum()) / noise)


def excise_narrowband(x: np.ndarray, fs_hz: float, if_hz: float = 0.0, samples_per_ms: int | None = None,
                      threshold_db: float = EXCISE_DB) -> tuple[np.ndarray, Interference]:
    """Zero the DC offset and narrowband lines of a block of samples in the frequency domain, and say what they were.

    When there is interference worth the name (`Interference.present`: a line REPORT_JN_DB strong, a comb,
    jamming), bins EXCISE_DB over the local floor and their two neighbours each side are zeroed, and the DC bin;
    when more than 2 % of bins would go, nothing is (that is not narrowband) and the interference is called wideband.

    Interference that repeats every millisecond (a USB frame clock) lives on a comb of lines at multiples of 1 kHz
    and correlates with every code at Dopplers of k kHz. When the block is whole milliseconds, at least COMB_MIN_MS
    long, and those comb bins hold clearly more power than the rest, the comb and its neighbours are zeroed: 3 bins
    in N, a loss of 3/N of a satellite's power.
    """
    n = x.size
    spec = scipy.fft.fft(x)
    p = (spec.real ** 2 + spec.imag ** 2).astype(np.float64)
    floor = _local_floor(p)
    lines = p > floor * 10 ** (threshold_db / 10)
    bad = lines.copy()
    bad[0] = True   # DC: an offset there never carries GPS (Doppler 0 of a baseband signal is its centre)
    for shift in (1, 2):
        bad |= np.roll(bad, shift) | np.roll(bad, -shift)
    wideband = bool(bad.sum() > EXCISE_MAX_FRACTION * n)
    if wideband:
        bad[:] = False
    comb = False
    if samples_per_ms and n % samples_per_ms == 0 and n // samples_per_ms >= COMB_MIN_MS:
        teeth = np.zeros(n, dtype=bool)
        teeth[::n // samples_per_ms] = True
        if np.mean(p[teeth] / floor[teeth]) > COMB_RATIO * np.mean(p[~teeth] / floor[~teeth]):
            comb = True
            bad |= teeth | np.roll(teeth, 1) | np.roll(teeth, -1)
    shown, jn_db = _lines(p, floor, lines, fs_hz, if_hz, not np.any(x.imag))
    found = Interference(shown, int(bad.sum()), wideband, comb, jn_db)
    if not found.present or not bad.any():
        return x, found
    spec[bad] = 0
    return scipy.fft.ifft(spec).astype(np.complex64), found


class Watch:
    """Tells what interference a stream holds when that changes (a tone comes, goes or moves by 1 kHz, jamming
    starts or stops): an `interference` event, or `interference_ended`; `now` is the current description."""

    def __init__(self, emit):
        self._emit = emit
        self._key: tuple = ()
        self.now: str | None = None

    def update(self, found: Interference, t_s: float) -> None:
        key = (tuple(round(line.offset_hz, -3) for line in found.lines), found.jamming, found.wideband,
               found.comb) if found.present else ()
        if key == self._key:
            return
        self._key = key
        self.now = found.describe() if found.present else None
        if found.present:
            self._emit("interference", t_s, **found.fields())
        else:
            self._emit("interference_ended", t_s)


LOOK_MS = 10              # a look's block: 100 Hz bins
LOOK_EVERY_S = 1.0


class Monitor:
    """Looks at a stream's samples once a second for interference (where no acquisition does it on the way)."""

    def __init__(self, fs_hz: float, if_hz: float, emit):
        self.fs_hz, self.if_hz = fs_hz, if_hz
        self.watch = Watch(emit)
        self._spm = int(round(fs_hz * 1e-3))
        self._seen = 0
        self._next = 0

    def push(self, chunk: np.ndarray) -> None:
        n = LOOK_MS * self._spm
        if self._seen + chunk.size >= self._next + n and chunk.size >= n:
            start = max(self._next - self._seen, 0) if self._next - self._seen + n <= chunk.size else chunk.size - n
            _, found = excise_narrowband(np.asarray(chunk[start:start + n], dtype=np.complex64), self.fs_hz,
                                         self.if_hz, self._spm)
            self.watch.update(found, (self._seen + start) / self.fs_hz)
            self._next = self._seen + start + int(LOOK_EVERY_S * self.fs_hz)
        self._seen += chunk.size
