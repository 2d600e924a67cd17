"""Navigation decoding of one channel: frame synchronisation, LNAV subframes, ephemeris, ionosphere/UTC, TOW.

Tracking hands over data bits after its bit synchronisation: soft values (the sum of 20 prompt in-phase
correlations), sign = bit, polarity unknown (the Costas loop's 180 degree ambiguity), each with the channel's bit
count since bit sync. `NavDecoder` finds the subframes in that stream and decodes them with `semperfi.gps.lnav`:

* frame sync: the preamble 10001011 in either polarity, the TLM and HOW words passing parity (with the D29*, D30*
  of the word before when the buffer holds it, else both candidates), the HOW ending in two equal bits (its t bits
  make it end in 00 on the air), subframe ID 1-5, and the same again 300 bits later with the TOW count one higher
  and the next subframe ID (so a preamble-like pattern inside the data is never taken for a subframe start);
* in sync: every 300 bits a subframe, its polarity from its preamble, decoded with the true D29*, D30* of the
  word before it (if the TLM fails with them, e.g. after a polarity change at the subframe boundary, with the 0, 0
  word 10 ends in). A subframe with a word failing parity, a TLM without preamble or a HOW with an impossible ID
  or TOW is reported (parity_errors > 0) and not used. Two such in a row, or one without TLM and HOW, drop sync;
  the search restarts just after the first bad one, and a subframe found again is not reported twice;
* a gap in the bit count drops sync (the bits no longer join up) but keeps the time anchor; a bit count going
  backwards means a new bit synchronisation and drops the anchor too.

Subframes 1-3 of one IODE (from any frames) make the ephemeris; the newest complete set replaces the old one, never
a mixture. Subframe 4 page 18 gives the ionosphere and UTC parameters.

The input is an attacker's signal: the buffer is bounded (`MAX_BUFFER_BITS`), garbage never raises, an orbit no GPS
satellite flies is not taken, and a subframe whose TOW disagrees with the time anchor extrapolated by the bit count
is flagged (`tow_inconsistent`) and not used; the anchor moves to a new time scale only after two consecutive
subframes agree with each other on it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from ..gps import (BITS_PER_SUBFRAME, DecodedSubframe, Ephemeris, GpsTime, IonoParams, PREAMBLE, SECONDS_PER_WEEK,
                   SUBFRAMES_PER_WEEK, UtcParams, check_parity, decode_subframe, ephemeris_from_subframes,
                   iono_utc_from_subframe, week_of_subframe1)

BIT_S = 0.020                         # one LNAV data bit (50 bit/s)
SUBFRAME_HEAD_BITS = 60               # TLM + HOW
PIECE_BITS = 1024                     # input is taken in pieces of at most this many bits
CONFIRM_SUBFRAMES = 2                 # a head is confirmed by another at most this many subframes away
KEEP_BEHIND_BITS = 2 * BITS_PER_SUBFRAME + 2   # in sync: the last two subframes and the two bits before them
MAX_BUFFER_BITS = KEEP_BEHIND_BITS + BITS_PER_SUBFRAME + PIECE_BITS   # the rolling buffer never holds more
TOW_TOLERANCE_S = 1e-3                # TOW vs anchor extrapolated by bit count (both are exact multiples of 20 ms)
ASSIST_MAX_AGE_S = 4 * 3600.0

_PREAMBLE_CODE = int(sum(int(b) << (7 - i) for i, b in enumerate(PREAMBLE)))   # 0x8B
_PREAMBLE_CODE_INVERTED = _PREAMBLE_CODE ^ 0xFF                                  # 0x74


@dataclass(frozen=True)
class SubframeEvent:
    """One subframe found in a channel's bit stream.

    parity_errors > 0: reported so the caller knows, but nothing in it (TOW included) is trusted or used.
    tow_inconsistent: parity is good but the TOW disagrees with the time anchor extrapolated by the bit count
    (a spliced or replayed stream); its data is not used either.
    """
    prn: int
    subframe_id: int
    page: int                 # 1-25 for subframes 4 and 5, 0 for 1-3
    tow_count_next: int       # HOW's truncated TOW count (6 s units) of the next subframe's start
    start_bit_index: int      # channel bit index of this subframe's first (preamble) bit
    parity_errors: int        # words failing parity, or a TLM without preamble / HOW with impossible ID or TOW
    t_sv_start_s: float       # satellite time of week at which the first bit was sent: ((TOW count - 1) * 6) mod week
    tow_inconsistent: bool = False
    inverted: bool = False    # bits arrived with inverted polarity
    subframe: DecodedSubframe | None = field(default=None, compare=False, repr=False)

    @property
    def accepted(self) -> bool:
        return self.parity_errors == 0 and not self.tow_inconsistent


def _plausible(eph: Ephemeris) -> bool:
    """A broadcast GPS orbit (the same bounds the RINEX reader applies); anything else is not used."""
    return 4000.0 < eph.sqrt_a_sqrt_m < 6000.0 and 0.0 <= eph.e < 0.1


def _to_int(bits) -> int:
    value = 0
    for b in bits:
        value = (value << 1) | int(b)
    return value


def _how(word: np.ndarray, d29: int, d30: int) -> tuple[int, int] | None:
    """(TOW count, subframe ID) of a HOW word (30 bits as received, after the previous word's last two), or None when
    its parity, its t bits or its values say it is none."""
    ok, how = check_parity(word, d29, d30)
    if not ok or word[28] != word[29]:    # its t bits make the HOW end in 00 (11 if the TLM came complemented)
        return None
    tow, subframe_id = _to_int(how[:17]), _to_int(how[19:22])
    return (tow, subframe_id) if 1 <= subframe_id <= 5 and tow < SUBFRAMES_PER_WEEK else None


class NavDecoder:
    """The navigation decoder of one tracking channel (see the module docstring)."""

    def __init__(self, prn: int, full_week_hint: int | None = None):
        self.prn = int(prn)
        self.full_week_hint = None if full_week_hint is None else int(full_week_hint)
        self._ephemeris: Ephemeris | None = None
        self._iono: IonoParams | None = None
        self._utc: UtcParams | None = None
        self._week: int | None = None                      # from the newest subframe 1 with good parity
        self._latest: dict[int, DecodedSubframe] = {}      # newest good subframe 1, 2, 3
        self._anchor: tuple[int, float] | None = None
        self._candidate: tuple[int, float] | None = None   # a consistent-with-itself new time scale, not yet trusted
        self._recent: deque[int] = deque(maxlen=8)         # start bits of the latest events (no duplicates)
        self._restart(0)
        self._end: int | None = None                       # channel bit index of the next bit expected (None: any)

    # ------------------------------------------------------------------------------------------ public face

    def adopt(self, other: "NavDecoder") -> None:
        """Take over what an earlier decoder of the same PRN read (subframes 1-3, the week, ionosphere and UTC) where
        this one has read nothing of its own yet: a channel that replaces another (a verdict, a loss of lock)
        completes an ephemeris with the subframes it still lacks, not with a whole new frame (30 s). Its time anchor
        is its own: bit indices belong to a channel."""
        for k, sf in other._latest.items():
            self._latest.setdefault(k, sf)
        self._week = self._week if self._week is not None else other._week
        self._iono, self._utc = self._iono or other._iono, self._utc or other._utc

    @property
    def ephemeris(self) -> Ephemeris | None:
        """The newest complete, consistent set of subframes 1-3 (None until one has been decoded)."""
        return self._ephemeris

    @property
    def week(self) -> int | None:
        """The full GPS week from the newest good subframe 1 (None until one has been decoded): a fix needs it, and
        subframe 1 comes every 30 s, long before a whole ephemeris can when a recording starts just after one."""
        return self._week

    @property
    def iono(self) -> IonoParams | None:
        return self._iono

    @property
    def utc(self) -> UtcParams | None:
        return self._utc

    @property
    def time_anchor(self) -> tuple[int, float] | None:
        """(start_bit_index, t_sv_start_s) of the latest good, time-consistent subframe."""
        return self._anchor

    @property
    def in_sync(self) -> bool:
        return self._sync

    @property
    def buffered_bits(self) -> int:
        return int(self._buf.size)

    def transmit_time_s(self, bit_index: float) -> float | None:
        """Satellite time of week (s) at the start of a channel bit (fractional bits allowed), from the anchor."""
        if self._anchor is None:
            return None
        start, t0 = self._anchor
        return float((t0 + (bit_index - start) * BIT_S) % SECONDS_PER_WEEK)

    def push_bits(self, soft_bits, first_bit_index: int) -> list[SubframeEvent]:
        """Take the next data bits (soft values, sign = bit) starting at the channel's bit index first_bit_index;
        return the subframes completed by them."""
        soft = np.asarray(soft_bits)
        if np.iscomplexobj(soft):
            soft = soft.real
        try:
            soft = soft.astype(np.float64, copy=False).ravel()
        except (TypeError, ValueError):
            raise TypeError(f"soft bits must be numbers, got an array of {soft.dtype}") from None
        first = int(first_bit_index)
        events: list[SubframeEvent] = []
        if soft.size == 0:
            return events
        if self._end is None or first != self._end:
            if self._end is not None and first < self._end:   # a new bit synchronisation: old indices mean nothing
                self._anchor = self._candidate = None
                self._recent.clear()
            self._restart(first)
        with np.errstate(invalid="ignore"):
            for i in range(0, soft.size, PIECE_BITS):
                hard = (soft[i:i + PIECE_BITS] < 0).astype(np.uint8)   # +1 is a 0 bit; NaN reads as 0
                self._buf = np.concatenate([self._buf, hard])
                self._end += hard.size
                self._process(events)
        return events

    # ------------------------------------------------------------------------------------------ machinery

    def _restart(self, first: int) -> None:
        """Forget the bits and the frame sync (not the anchor nor the decoded data); next bit expected: first."""
        self._buf = np.zeros(0, dtype=np.uint8)
        self._buf_start = first
        self._end = first
        self._sync = False
        self._pol = 0
        self._next_sf = first
        self._search_from = first
        self._bad_run = 0
        self._first_bad: int | None = None

    def _bits(self, start: int, n: int, pol: int) -> np.ndarray:
        i = start - self._buf_start
        return self._buf[i:i + n] ^ np.uint8(pol)

    def _process(self, events: list[SubframeEvent]) -> None:
        while True:
            if self._sync:
                self._decode_ready(events)
                if self._sync:
                    break
            elif not self._search():
                break
        keep_from = self._next_sf - KEEP_BEHIND_BITS if self._sync else self._search_from - 2
        cut = keep_from - self._buf_start
        if cut > 0:
            self._buf = self._buf[cut:]
            self._buf_start = keep_from

    # frame sync --------------------------------------------------------------------------------------------

    def _head(self, p: int, pol: int) -> tuple[int, int] | None:
        """(TOW count, subframe ID) if a TLM and HOW start at bit p in polarity pol, else None."""
        w = self._bits(p, SUBFRAME_HEAD_BITS, pol)
        if w.size < SUBFRAME_HEAD_BITS:
            return None
        prevs = [(0, 0), (1, 0)]
        if p - 2 >= self._buf_start:
            prevs.insert(0, tuple(int(b) for b in self._bits(p - 2, 2, pol)))
        for d29, d30 in prevs:
            ok, data = check_parity(w[:30], d29, d30)
            if ok and np.array_equal(data[:8], PREAMBLE):
                break
        else:
            return None
        return _how(w[30:60], int(w[28]), int(w[29]))

    def _how_alone(self, p: int) -> set[tuple[int, int]]:
        """What the HOW of a head starting at bit p may say whatever its TLM suffered (a half-cycle slip of the
        Costas loop, the bits a carrier step garbled): its (TOW count, subframe ID) for each way of the TLM's last
        two bits (D29*, D30*) its parity accepts. Only ever taken with a whole head to confirm it."""
        w = self._bits(p + SUBFRAME_HEAD_BITS // 2, SUBFRAME_HEAD_BITS // 2, 0)
        if w.size < SUBFRAME_HEAD_BITS // 2:
            return set()
        return {h for d29 in (0, 1) for d30 in (0, 1) if (h := _how(w, d29, d30)) is not None}

    def _search(self) -> bool:
        """Scan for a confirmed frame start; True (and in sync) when one is found. A head (TLM and HOW, each with
        good parity) is confirmed by another up to CONFIRM_SUBFRAMES subframes before or after it whose TOW and
        subframe ID follow from its own; of one of the two the HOW alone may do, its TLM broken by a half-cycle slip
        of the Costas loop or the bits a carrier step garbled (a spoofer's carrier stepping beside the tracked one):
        that breaks one head, not the frame.
        A channel with no time yet takes it from the confirmed head at once (the anchor), before its subframe is
        whole."""
        lo = max(self._search_from, self._buf_start)
        hi = self._end - SUBFRAME_HEAD_BITS   # last start whose head is all here
        if hi < lo:
            return False
        seg = self._buf[lo - self._buf_start:hi - self._buf_start + 8].astype(np.int64)
        n = hi - lo + 1
        codes = np.zeros(n, dtype=np.int64)      # the byte starting at each candidate bit
        for j in range(8):
            codes = (codes << 1) | seg[j:j + n]
        for j in np.flatnonzero((codes == _PREAMBLE_CODE) | (codes == _PREAMBLE_CODE_INVERTED)):
            p, pol = lo + int(j), int(codes[j] == _PREAMBLE_CODE_INVERTED)
            others = {k: q for k in (*range(1, CONFIRM_SUBFRAMES + 1), *range(-1, -CONFIRM_SUBFRAMES - 1, -1))
                      if self._buf_start <= (q := p + k * BITS_PER_SUBFRAME) <= self._end - SUBFRAME_HEAD_BITS}
            head = self._head(p, pol)
            if head is not None:
                heads = [(head, False)]
            elif any(self._head(q, pol) is not None for q in others.values()):   # its HOW alone may do
                heads = [(h, True) for h in self._how_alone(p)]
            else:
                continue
            for (tow, subframe_id), damaged in heads:
                for k, q in others.items():
                    want = ((tow + k) % SUBFRAMES_PER_WEEK, (subframe_id - 1 + k) % 5 + 1)
                    if self._head(q, pol) == want or (not damaged and want in self._how_alone(q)):
                        self._sync, self._pol, self._next_sf = True, pol, p
                        self._bad_run, self._first_bad = 0, None
                        if self._anchor is None:   # a time scale already held moves only on whole subframes
                            self._anchor = (p, float((tow - 1) * 6 % SECONDS_PER_WEEK))
                        return True
        # starts that may still be confirmed by a head further on are searched again
        self._search_from = max(lo, self._end - CONFIRM_SUBFRAMES * BITS_PER_SUBFRAME - SUBFRAME_HEAD_BITS + 1)
        return False

    def _lose_sync(self, search_from: int) -> None:
        self._sync = False
        self._search_from = max(search_from, self._buf_start)

    # subframes ---------------------------------------------------------------------------------------------

    def _decode_ready(self, events: list[SubframeEvent]) -> None:
        while self._sync and self._next_sf + BITS_PER_SUBFRAME <= self._end:
            s = self._next_sf
            self._next_sf = s + BITS_PER_SUBFRAME
            raw = self._bits(s, 8, 0)
            miss = [int(np.count_nonzero(raw ^ np.uint8(pol) ^ PREAMBLE)) for pol in (0, 1)]
            if miss[1 - self._pol] < miss[self._pol]:
                self._pol = 1 - self._pol
            bits = self._bits(s, BITS_PER_SUBFRAME, self._pol)
            prevs = [(0, 0), (1, 0)]
            if s - 2 >= self._buf_start:      # the true D29*, D30* first
                prevs.insert(0, tuple(int(b) for b in self._bits(s - 2, 2, self._pol)))
            # The first previous-bit pair giving a valid TLM, else one giving good parity, else the true one.
            (d29, d30), tlm_ok, tlm_valid = prevs[0], False, False
            for cand in prevs:
                ok, data = check_parity(bits[:30], *cand)
                if ok and np.array_equal(data[:8], PREAMBLE):
                    (d29, d30), tlm_ok, tlm_valid = cand, True, True
                    break
                if ok and not tlm_ok:
                    (d29, d30), tlm_ok = cand, True
            how_ok, how = check_parity(bits[30:60], int(bits[28]), int(bits[29]))
            how_valid = how_ok and 1 <= _to_int(how[19:22]) <= 5 and _to_int(how[:17]) < SUBFRAMES_PER_WEEK
            if not tlm_valid and not how_valid:    # no TLM, no HOW: not a subframe, the frame is lost
                self._lose_sync((self._first_bad if self._first_bad is not None else s) + 1)
                return
            sf = decode_subframe(bits, d29, d30)
            # A word with good parity but no preamble, or an impossible subframe ID or TOW, counts as failing.
            errors = sf.parity_errors + (tlm_ok and not tlm_valid) + (how_ok and not how_valid)
            t_sv = float((sf.tow_count_next - 1) * 6 % SECONDS_PER_WEEK)
            inconsistent = False
            if errors:
                self._bad_run += 1
                if self._first_bad is None:
                    self._first_bad = s
            else:
                self._bad_run, self._first_bad = 0, None
                inconsistent = self._check_tow(s, t_sv)
                if not inconsistent:
                    self._use(sf)
            if s not in self._recent:        # a subframe found again after a resync is not reported twice
                self._recent.append(s)
                events.append(SubframeEvent(
                    prn=self.prn, subframe_id=sf.subframe_id, page=sf.page, tow_count_next=sf.tow_count_next,
                    start_bit_index=s, parity_errors=errors, t_sv_start_s=t_sv,
                    tow_inconsistent=inconsistent, inverted=bool(self._pol), subframe=sf))
            if self._bad_run >= 2:
                self._lose_sync(self._first_bad + 1)
                return

    def _check_tow(self, start: int, t_sv: float) -> bool:
        """Move the anchor if t_sv fits it (or a second subframe confirms a new time scale); True if it does not fit."""
        def fits(anchor: tuple[int, float]) -> bool:
            expected = anchor[1] + (start - anchor[0]) * BIT_S
            diff = (t_sv - expected + SECONDS_PER_WEEK / 2) % SECONDS_PER_WEEK - SECONDS_PER_WEEK / 2
            return abs(diff) <= TOW_TOLERANCE_S

        if self._anchor is None or fits(self._anchor):
            self._anchor, self._candidate = (start, t_sv), None
            return False
        if self._candidate is not None and fits(self._candidate):
            self._anchor, self._candidate = (start, t_sv), None     # two consecutive agree: the new time scale
        else:
            self._candidate = (start, t_sv)
        return True

    def _use(self, sf: DecodedSubframe) -> None:
        if sf.subframe_id in (1, 2, 3):
            self._latest[sf.subframe_id] = sf
            if sf.subframe_id == 1:
                self._week = week_of_subframe1(sf, self.full_week_hint)
            if len(self._latest) == 3:
                try:
                    eph = ephemeris_from_subframes(self._latest[1], self._latest[2], self._latest[3], prn=self.prn,
                                                   full_week_hint=self.full_week_hint)
                except (ValueError, ArithmeticError):
                    return                          # IODs differ: keep the old set until a new one is complete
                if _plausible(eph):
                    self._ephemeris = eph
        elif sf.subframe_id == 4 and sf.sv_id == 56:
            try:
                self._iono, self._utc = iono_utc_from_subframe(sf)
            except (ValueError, ArithmeticError):
                pass


class AssistedNav:
    """Ephemerides from outside (a RINEX file, an assistance server): the receiver need not wait for subframes 1-3.

    Transmit time still comes from each channel's HOW (NavDecoder.time_anchor).
    """

    def __init__(self, ephemerides: Iterable[Ephemeris], iono: IonoParams | None = None,
                 utc: UtcParams | None = None, max_age_s: float = ASSIST_MAX_AGE_S):
        self.iono, self.utc, self.max_age_s = iono, utc, float(max_age_s)
        self._by_prn: dict[int, list[Ephemeris]] = {}
        for eph in ephemerides:
            self._by_prn.setdefault(int(eph.prn), []).append(eph)

    @classmethod
    def from_rinex(cls, path: str | Path) -> "AssistedNav":
        """From a RINEX navigation file (ValueError, one line, if it has no usable GPS ephemeris)."""
        from ..iq import read_rinex_nav
        nav = read_rinex_nav(path)
        return cls(nav.ephemerides, nav.iono, nav.utc)

    @property
    def prns(self) -> tuple[int, ...]:
        return tuple(sorted(self._by_prn))

    @property
    def ephemerides(self) -> list[Ephemeris]:
        return [e for ephs in self._by_prn.values() for e in ephs]

    def ephemeris(self, prn: int, t: GpsTime) -> Ephemeris | None:
        """The healthy ephemeris of prn whose toe is nearest to t, within max_age_s; the later toe on a tie."""
        best, best_key = None, None
        for eph in self._by_prn.get(int(prn), ()):
            if eph.health != 0:
                continue
            toe = GpsTime(eph.week, eph.toe_s).seconds
            dt = abs(toe - t.seconds)
            if dt > self.max_age_s:
                continue
            key = (dt, -toe)
            if best_key is None or key < best_key:
                best, best_key = eph, key
        return best
