"""The conventional receiver chain over a stream of samples: acquisition -> tracking -> navigation ->
observables -> PVT, with every step reported as an event and every fix written as it is computed.
"""

import math
from dataclasses import dataclass, field, replace
from typing import Callable, NamedTuple

import numpy as np

from .. import config
from ..gps import (GpsTime, IonoParams, L1_WAVELENGTH_M, SECONDS_PER_WEEK, SPEED_OF_LIGHT_M_S, light_time_range,
                   satellite_clock, satellite_position, satellite_position_velocity, wrap_week_s)
from .acquisition import Caf, DopplerGrid, acquire, is_cross_correlation
from .carried_time import CLOCK_TIME_MAX_AGE_S, Donor, carried, donor, latest_epoch, on_whole_ms
from .config import Integrity
from .navigation import ASSIST_MAX_AGE_S, AssistedNav, NavDecoder
from .pvt import solve
from .rinex_obs import ObsEpoch
from .integrity import IntegrityConfig, SigmaModel
from .interference import Watch
from .tracking import NEXT_SAMPLE, Channel, LoopConfig, initial_state
from .workers import run_each
from .types import Fix, Observation

EPHEMERIS_AGREE_M = 5.0      # two uploads' ephemerides agree to about a metre; further apart, one is not genuine
TYPICAL_FLIGHT_S = 0.075       # first guess of the signals' travel time, to start the receiver clock
# Klobuchar coefficients to use until subframe 4 page 18 (broadcast every 12.5 min) has been decoded: RTKLIB's
# defaults, a typical set; far better than no ionosphere model at all.
FALLBACK_IONO = IonoParams((0.1118e-07, -0.7451e-08, -0.5961e-07, 0.1192e-06),
                           (0.1167e+06, -0.2294e+06, -0.1311e+06, 0.1049e+07))


WARM_RETRY_S = 0.5    # how soon a PRN lost moments ago is searched again, while its next channel can be timed at once:
WARM_RETRY_FOR_S = 10.0   # its lost channel's time carried (DONOR_REACH_S), or the clock's (a time reference) this long


@dataclass
class ChannelRow:
    """What the live channel table shows."""
    prn: int
    state: str
    cn0_dbhz: float
    doppler_hz: float
    code_phase_chips: float
    subframes: int


@dataclass
class RunStats:
    n_fixes: int = 0
    first_fix_t_rx_s: float | None = None
    acquired: set = field(default_factory=set)
    confirmed: set = field(default_factory=set)   # tracked to bit synchronisation: a real, modulated signal
    subframes: int = 0
    parity_errors: int = 0
    samples: int = 0
    cold_searched: int = 0        # PRNs searched cold (not tracked, not lost moments ago), all searches together


class RawObservation(NamedTuple):
    """What a channel says at an epoch, before the fix: its satellite's transmit time and what goes with it."""
    prn: int
    t_sv_s: float            # GPS time of week the signal left the satellite
    doppler_hz: float
    cn0_dbhz: float
    ephemeris: object
    channel: Channel


class Receiver:
    """Feed it consecutive chunks of complex samples; it calls on_fix for every fix and events.emit for events."""

    def __init__(self, cfg: dict, fs_hz: float, if_hz: float = 0.0, assisted: AssistedNav | None = None,
                 on_fix=None, events=None, week_hint: int | None = None, on_observations=None):
        """on_observations(epoch: rinex_obs.ObsEpoch, pos_ecef_m) gets the raw observables of every epoch that made
        a fix, timed by the receiver's clock (for RINEX)."""
        self.cfg, self.fs_hz, self.if_hz = cfg, float(fs_hz), float(if_hz)
        self.assisted, self.on_fix, self.events = assisted, on_fix, events
        self.on_observations = on_observations
        self.week_hint = week_hint
        a, t = cfg["acquisition"], cfg["tracking"]
        self.prns = list(a["prns"]) or list(range(1, 33))
        self.loop = LoopConfig(pll_bw_hz=t["pll_bw_hz"], fll_bw_hz=t["fll_bw_hz"], dll_bw_hz=t["dll_bw_hz"],
                               spacing_chips=t["spacing_chips"], pull_in_ms=t["pull_in_ms"],
                               min_cn0_dbhz=t["min_cn0_dbhz"])
        self.samples_per_ms = int(round(self.fs_hz * 1e-3))
        self.acq_samples = self.samples_per_ms * a["coherent_ms"] * a["noncoherent"]
        self.channels: dict[int, Channel] = {}
        self.decoders: dict[int, NavDecoder] = {}
        self.warm: dict[int, float] = {}            # PRN -> last Doppler, for warm re-acquisition after a loss
        self._lost_at: dict[int, int] = {}          # PRN -> the absolute sample its channel lost lock at
        # PRNs a more sensitive search of these samples elsewhere found absent moments ago (the defence's full search,
        # which looks at every PRN over 40 ms): not searched cold again until it says otherwise
        self.absent_prns: frozenset[int] = frozenset()
        self.subframes_by_prn: dict[int, int] = {}
        self.stats = RunStats()
        self.iono = assisted.iono if assisted else None
        self.utc = None
        self._store = np.empty(0, dtype=np.complex64)   # reused from chunk to chunk; _buf is its filled head
        self._buf = self._store
        self._base = 0                              # absolute index of _buf[0]
        self._next_acq_sample = 0
        self._epoch_period = self.fs_hz / cfg["pvt"]["rate_hz"]
        self._next_epoch = 1                        # measurement epoch count (epoch k at sample k * period)
        self._t_rx0: float | None = None            # receiver clock (GPS s of week) at sample 0
        self._week: int | None = week_hint
        self.last_fix: Fix | None = None
        # PRNs a supervisor (the defence) distrusts: left out of fixes while enough others remain
        self.excluded_prns: set[int] = set()
        self.min_sats_excluding = 5
        # failing that, the PRNs it suspects most (a subset of those): left out while a fix remains possible
        self.suspect_prns: set[int] = set()
        self.min_sats_suspecting = 4
        # and PRNs it trusts less (a range it knows to be biased): left out while this many others remain
        self.distrusted_prns: set[int] = set()
        self.min_sats_distrusting = 6
        self.raim = self._raim_config()
        # a supervisor's pseudorange rectifier (defense.rectifier.Rectifier), and the PRNs it timed at the last epoch
        self.rectifier = None
        self.rectified_prns: set[int] = set()
        # standby channels: another signal of a PRN that a supervisor wants tracked and decoded beside the channel in
        # use, while it decides which of the two is the satellite's; promote() makes one the PRN's channel at once
        self.standby: dict[int, Channel] = {}
        self.standby_decoders: dict[int, NavDecoder] = {}
        # ephemerides decoded on a PRN's earlier channels (a spoofer's peak, in a stealthy attack the same data),
        # used until the PRN's own decoder has one: a replaced channel must not wait 30 s for subframes 1-3
        self.provisional_ephemerides: dict[int, object] = {}
        self._retired: dict[int, NavDecoder] = {}   # the last decoder of a PRN whose channel went, for the next one
        # PRN -> the time a channel that went had read, for the PRN's next channel (receiver/carried_time); and the
        # (channel, code period, its transmit time) that next channel took from it
        self._donors: dict[int, Donor] = {}
        self._carried: dict[int, tuple[Channel, int, float]] = {}
        # the fix whose clock times a channel that has neither its own time nor a donor (a supervisor that tells
        # trusted fixes from spoofed ones gives its last trusted one)
        self.time_reference: Callable[[], Fix | None] = lambda: self.last_fix
        self.interference = Watch(self._emit)   # what the searches find besides GPS, reported when it changes

    # -- events ---------------------------------------------------------------------------------------------
    def _emit(self, kind: str, t_rx_s: float, **fields) -> None:
        if self.events is not None:
            self.events.emit(kind, t_rx_s, **fields)

    # -- acquisition ----------------------------------------------------------------------------------------
    def _search(self, samples: np.ndarray, prns: list[int], center_hz: float = 0.0, span_hz: float | None = None):
        a = self.cfg["acquisition"]
        grid = DopplerGrid.for_coherent(a["coherent_ms"], span_hz or a["doppler_max_hz"], a["doppler_step_hz"],
                                        center_hz)
        cafs = acquire(samples, self.fs_hz, prns, grid, self.if_hz, a["coherent_ms"], a["noncoherent"], a["pfa"],
                       a["max_peaks"], excise=True)
        if cafs:
            self.interference.update(next(iter(cafs.values())).interference,
                                     (self._base + self._buf.size) / self.fs_hz)
        return cafs

    def _is_cross_talk(self, caf: Caf, cafs: dict[int, Caf]) -> bool:
        """A weak peak at the Doppler (mod 1 kHz) of a much stronger PRN is that PRN's cross-correlation."""
        if caf.best.metric >= 4.0 * caf.threshold:   # cross-correlation lies 21 dB down: never a strong peak
            return False
        stronger = [(o.best.doppler_hz, o.best.cn0_dbhz) for o in cafs.values() if o.best and o.prn != caf.prn]
        stronger += [(ch.doppler_at(0), ch.cn0_dbhz) for ch in self.channels.values()]   # signals in track too
        return is_cross_correlation(caf.best.doppler_hz, caf.best.cn0_dbhz, stronger,
                                    self.cfg["acquisition"]["cross_correlation_db"])

    def _acquire(self) -> None:
        start = self._base + self._buf.size - self.acq_samples
        samples = self._buf[-self.acq_samples:]
        t_s = start / self.fs_hz
        free = self.cfg["tracking"]["channels"] - len(self.channels)
        cold = [p for p in self.prns if p not in self.channels and p not in self.warm and p not in self.absent_prns]
        self.stats.cold_searched += len(cold)
        cafs = self._search(samples, cold) if cold else {}
        for prn, doppler in list(self.warm.items()):
            # a PRN a more sensitive search just found nothing of (the defence's full look) is not searched again
            # around where it was lost either: cross-talk channels lost during an attack, twelve of them searched
            # every half second, were a fifth of the receiver's time after a takeover
            if prn not in self.channels and prn not in self.absent_prns:
                cafs.update(self._search(samples, [prn], center_hz=doppler, span_hz=1000.0))
        found = [c for c in cafs.values() if c.best is not None]
        found.sort(key=lambda c: -c.best.metric)
        for caf in found:
            b = caf.best
            if self._is_cross_talk(caf, cafs):
                self._emit("acquisition_rejected", t_s, prn=caf.prn, reason="cross-correlation",
                           code_phase_chips=b.code_phase_chips, doppler_hz=b.doppler_hz, cn0_dbhz=b.cn0_dbhz)
                continue
            self._emit("acquisition", t_s, prn=caf.prn, code_phase_chips=round(b.code_phase_chips, 4),
                       doppler_hz=round(b.doppler_hz, 1), cn0_dbhz=round(b.cn0_dbhz, 1),
                       peak_ratio=round(caf.peak_ratio, 2), peaks=len(caf.peaks))
            self.stats.acquired.add(caf.prn)
            if free <= 0:
                continue
            st = initial_state(b.code_phase_chips, start, b.doppler_hz, self.fs_hz, start)
            self.channels[caf.prn] = Channel(caf.prn, self.fs_hz, self.if_hz, st, self.loop)
            self.decoders[caf.prn] = self._new_decoder(caf.prn)
            self.warm.pop(caf.prn, None)
            free -= 1
            self._emit("tracking_start", t_s, prn=caf.prn)

    # -- the stream -----------------------------------------------------------------------------------------
    def feed(self, chunk: np.ndarray) -> None:
        """Process the next consecutive chunk of samples."""
        self._append(chunk)
        end = self._base + self._buf.size
        self.stats.samples = end
        if end >= self._next_acq_sample and self._buf.size >= self.acq_samples:
            self._acquire()
            every_s = self.cfg["acquisition"]["reacquire_s"]
            if any(self._timed_at_once(prn, end) for prn in self.warm):
                # a PRN lost moments ago whose next channel would have its time at once: searched again soon
                every_s = min(every_s, WARM_RETRY_S)
            self._next_acq_sample = end + int(every_s * self.fs_hz)
        run_each(lambda ch: ch.process(self._buf, self._base), [*self.channels.values(), *self.standby.values()])
        self._decode_standby()
        for prn, ch in list(self.channels.items()):
            self._decode(prn, ch)
            twin = self._cross_talk_source(prn, ch)
            if twin is not None:
                self._emit("cross_correlation", end / self.fs_hz, prn=prn, source_prn=twin,
                           cn0_dbhz=round(float(ch.cn0_dbhz), 1))
                del self.channels[prn]
                self.decoders.pop(prn, None)
                continue
            if not ch.locked:
                self._emit("loss_of_lock", end / self.fs_hz, prn=prn, cn0_dbhz=round(float(ch.cn0_dbhz), 1))
                self.warm[prn] = ch.doppler_at(0)
                self._lost_at[prn] = end
                del self.channels[prn]
                self._retire(prn, self.decoders.pop(prn, None), ch)
                self.search_from(end)
        self._measure()
        keep = max(2 * self.samples_per_ms + 2, self.acq_samples)
        if self._buf.size > keep:
            self._base += self._buf.size - keep
            self._buf = self._buf[-keep:]

    def _timed_at_once(self, prn: int, sample: int) -> bool:
        """Whether a PRN lost moments ago (WARM_RETRY_FOR_S) would be timed as soon as a new channel locks: by its
        lost channel's time while that is carried, else by the receiver's clock."""
        if prn in self._donors and self._donors[prn].reaches(sample, self.fs_hz):
            return True
        return sample - self._lost_at.get(prn, -np.inf) <= WARM_RETRY_FOR_S * self.fs_hz \
            and self.time_reference() is not None

    def _append(self, chunk: np.ndarray) -> None:
        """_buf += chunk in one buffer kept for the whole run: where malloc hands big arrays back to the system
        (glibc's default, unless cli._tune_heap ran), a fresh array per chunk costs a page fault per 4 KiB."""
        kept, n = self._buf.size, self._buf.size + len(chunk)
        if n > self._store.size:
            store = np.empty(max(n, 2 * self._store.size), dtype=np.complex64)
            store[:kept] = self._buf
            self._store = store
        else:
            self._store[:kept] = self._buf   # the kept tail to the front (numpy copies overlapping ranges safely)
        self._store[kept:n] = chunk
        self._buf = self._store[:n]

    def _cross_talk_source(self, prn: int, ch: Channel) -> int | None:
        """The PRN whose much stronger signal this channel is really tracking, through the codes' cross-correlation.

        Cross-correlation of two C/A codes is coherent when their Dopplers differ by a multiple of 1 kHz, and lies
        21 dB or more below the stronger signal; a channel that fits both is not a satellite of its own.
        """
        if ch.pull_in or not np.isfinite(ch.cn0_dbhz):
            return None
        margin = self.cfg["acquisition"]["cross_correlation_db"]
        for other_prn, other in self.channels.items():
            if other_prn != prn and not other.pull_in and is_cross_correlation(
                    ch.doppler_at(0), ch.cn0_dbhz, [(other.doppler_at(0), other.cn0_dbhz)], margin, 20.0):
                return other_prn
        return None

    def drop_channel(self, prn: int, reason: str) -> None:
        """Stop tracking a PRN (its decoder's ephemeris is kept provisionally) and search for it again at once."""
        if prn in self.channels:
            t_s = (self._base + self._buf.size) / self.fs_hz
            self._emit("channel_dropped", t_s, prn=prn, reason=reason)
            del self.channels[prn]
        self._retire(prn, self.decoders.pop(prn, None))
        self.warm.pop(prn, None)
        self.search_from(self._base + self._buf.size)

    def search_from(self, sample: int) -> None:
        """The next acquisition as soon as it has a window of samples from this absolute index on (a PRN dropped,
        or its signal back in the samples from there: a cancellation dropped), not at the next reacquire_s."""
        self._next_acq_sample = min(self._next_acq_sample, int(sample) + self.acq_samples)

    def _retire(self, prn: int, decoder: NavDecoder | None, channel: Channel | None = None) -> None:
        """A decoder whose channel goes: its ephemeris serves provisionally, its subframes seed the PRN's next, and
        after a loss of lock (channel given) the time it read times the PRN's next channel until that one reads its
        own. Not a channel dropped from a peak under cancellation: the time that reaches the legitimate signal from
        the spoofer's is the rectifier's, checked and labelled so."""
        if decoder is None:
            return
        given = donor(channel, decoder) if channel is not None else None
        if given is not None:
            self._donors[prn] = given
        if decoder.ephemeris is not None:
            self.provisional_ephemerides[prn] = decoder.ephemeris
        self._retired[prn] = decoder

    def _new_decoder(self, prn: int) -> NavDecoder:
        dec = NavDecoder(prn, self._week)
        if prn in self._retired:
            dec.adopt(self._retired.pop(prn))
        return dec

    # -- standby channels (a supervisor's second hypothesis) ----------------------------------------------------
    def start_standby(self, prn: int, code_phase_chips: float, peak_sample: float, doppler_hz: float,
                      spacing_chips: float) -> None:
        """Track and decode another signal of a PRN (a peak at code_phase_chips at an absolute sample) beside its
        channel, from the oldest sample still held, with an early-late spacing narrow enough to hold it apart from a
        neighbour more than a chip away."""
        st = initial_state(code_phase_chips, peak_sample, doppler_hz, self.fs_hz, self._base)
        cfg = replace(self.loop, spacing_chips=min(spacing_chips, self.loop.spacing_chips))
        self.standby[prn] = Channel(prn, self.fs_hz, self.if_hz, st, cfg)
        self.standby_decoders[prn] = NavDecoder(prn, self._week)
        self._emit("standby_start", self._base / self.fs_hz, prn=prn, code_phase_chips=round(code_phase_chips, 4),
                   doppler_hz=round(doppler_hz, 1))

    def drop_standby(self, prn: int, reason: str) -> None:
        if self.standby.pop(prn, None) is not None:
            self.standby_decoders.pop(prn, None)
            self._emit("standby_dropped", (self._base + self._buf.size) / self.fs_hz, prn=prn, reason=reason)

    def promote(self, prn: int, reason: str) -> bool:
        """The standby channel becomes the PRN's channel, with what it has decoded (the one it replaces leaves its
        ephemeris behind, provisionally); False when there is none or it has lost lock."""
        ch = self.standby.pop(prn, None)
        dec = self.standby_decoders.pop(prn, None)
        if ch is None or not ch.locked:
            return False
        old = self.decoders.get(prn)
        self._retire(prn, old)
        if old is not None:
            dec.adopt(self._retired.pop(prn))
        self.channels[prn], self.decoders[prn] = ch, dec
        self.warm.pop(prn, None)
        self._emit("channel_promoted", (self._base + self._buf.size) / self.fs_hz, prn=prn, reason=reason,
                   bit_sync=ch.bits.edge_ms is not None, tow=dec.time_anchor is not None,
                   ephemeris=dec.ephemeris is not None)
        return True

    def _decode_standby(self) -> None:
        for prn, ch in list(self.standby.items()):
            if not ch.locked:
                self.drop_standby(prn, "lost lock")
                continue
            soft, first = ch.take_bits()
            if soft.size:
                self.standby_decoders[prn].push_bits(soft, first)

    def _decode(self, prn: int, ch: Channel) -> None:
        if ch.bits.edge_ms is not None and prn not in self.stats.confirmed:
            self.stats.confirmed.add(prn)
            self._emit("bit_sync", ch.st[NEXT_SAMPLE] / self.fs_hz, prn=prn, edge_ms=ch.bits.edge_ms)
        soft, first = ch.take_bits()
        if soft.size == 0:
            return
        # a subframe is reported when it is decoded: its start may lie beyond the channel's history
        t_s = ch.st[NEXT_SAMPLE] / self.fs_hz
        for ev in self.decoders[prn].push_bits(soft, first):
            self.stats.subframes += ev.accepted
            self.subframes_by_prn[prn] = self.subframes_by_prn.get(prn, 0) + ev.accepted
            self.stats.parity_errors += ev.parity_errors
            self._emit("subframe", float(t_s), prn=prn, subframe_id=ev.subframe_id, page=ev.page,
                       tow_s=ev.t_sv_start_s, parity_errors=ev.parity_errors)
        dec = self.decoders[prn]
        if dec.iono is not None and self.iono is None:
            self.iono, self.utc = dec.iono, dec.utc
            self._emit("iono_utc", ch.st[NEXT_SAMPLE] / self.fs_hz, prn=prn)
        if self._week is None and dec.week is not None:
            self._week = dec.week
        if dec.ephemeris is not None and prn in self.provisional_ephemerides:
            self._check_provisional(prn, dec.ephemeris, ch.st[NEXT_SAMPLE] / self.fs_hz)

    def _check_provisional(self, prn: int, own, t_s: float) -> None:
        """The PRN's own ephemeris replaces the provisional one; where the two put the satellite apart, the
        navigation data it was given is not the satellite's: an alarm of its own."""
        other = self.provisional_ephemerides.pop(prn)
        t = own.toe_s
        apart_m = float(np.linalg.norm(satellite_position(own, t) - satellite_position(other, t)))
        clock_m = abs(satellite_clock(own, t)[0] - satellite_clock(other, t)[0]) * SPEED_OF_LIGHT_M_S
        if apart_m > EPHEMERIS_AGREE_M or clock_m > EPHEMERIS_AGREE_M:
            self._emit("ephemeris_mismatch", t_s, prn=prn, position_m=round(apart_m, 1), clock_m=round(clock_m, 1),
                       iode_own=own.iode, iode_provisional=other.iode)

    def ephemeris_at(self, prn: int, tow_s: float):
        """The ephemeris this receiver would use for a PRN at a GPS time (assisted, else decoded), or None."""
        return self._ephemeris(prn, tow_s)

    def _ephemeris(self, prn: int, tow_s: float):
        """Assisted, else the PRN's own decoded one, else one decoded on its earlier channels or on the signal a
        supervisor cancels (the spoofer's, provisional), within the age an ephemeris is good for."""
        if self.assisted is not None:
            eph = self.assisted.ephemeris(prn, GpsTime(self._week, tow_s)) if self._week is not None else None
            if eph is not None:
                return eph
        own = self.decoders[prn].ephemeris if prn in self.decoders else None
        if own is not None:
            return own
        eph = self.provisional_ephemerides.get(prn)
        if eph is None and self.rectifier is not None:
            eph = self.rectifier.ephemeris(prn)
        return eph if eph is not None and abs(wrap_week_s(tow_s - eph.toe_s)) <= ASSIST_MAX_AGE_S else None

    def _measure(self) -> None:
        """Observables and a fix at every measurement epoch the channels have tracked past."""
        if not self.channels:
            return
        tracked_to = min(ch.st[NEXT_SAMPLE] for ch in self.channels.values())   # the slowest channel
        while self._next_epoch * self._epoch_period < tracked_to - self.samples_per_ms:
            sample = self._next_epoch * self._epoch_period
            self._next_epoch += 1
            self._fix_at(sample)

    def observations_at(self, sample: float) -> list[RawObservation]:
        """An observation for every channel that can say its transmit time: from its own navigation message, or from
        the rectifier (a supervisor's) for the PRNs it takes over."""
        out = []
        self.rectified_prns = set()
        for prn, ch in self.channels.items():
            if ch.pull_in:
                continue
            own = self._own_transmit_time(prn, ch, sample)
            if self.rectifier is not None and self.rectifier.wants(prn, own is not None):
                r = self.rectifier.rectify(prn, ch, sample, self._ephemeris, self.predicted_transmit_time)
                own = None if r is None else (r.t_sv_s, r.ephemeris)
                if r is not None:
                    self.rectified_prns.add(prn)
            if own is not None:
                out.append(RawObservation(prn, own[0], ch.doppler_at(sample), float(ch.cn0_dbhz), own[1], ch))
        return out

    def _own_transmit_time(self, prn: int, ch: Channel, sample: float) -> tuple[float, object] | None:
        """(t_sv_s, ephemeris) at a sample from the channel's own time anchor (its HOW), or None."""
        anchor = self.decoders[prn].time_anchor
        if anchor is not None and ch.bits.edge_ms is not None:
            start_bit, t_sv_start = anchor
            ms_ref = ch.ms_of_bit(start_bit)
            self._donors.pop(prn, None)
        else:
            inherited = self._inherited_time(prn, ch)
            if inherited is None:
                return None
            ms_ref, t_sv_start = inherited
        t_sv = ch.transmit_time_at(sample, ms_ref, t_sv_start)
        if t_sv is None:
            return None
        t_sv %= SECONDS_PER_WEEK
        eph = self._ephemeris(prn, t_sv)
        return None if eph is None else (t_sv, eph)

    def _inherited_time(self, prn: int, ch: Channel) -> tuple[int, float] | None:
        """(code period, its transmit time) a channel took from the PRN's previous one, if that one had read it."""
        got = self._carried.get(prn)
        if got is not None and got[0] is ch:
            return got[1], got[2]
        given = self._donors.get(prn)
        anchor = carried(ch, given) if given is not None else None
        if anchor is None:
            return self._clock_time(prn, ch)
        del self._donors[prn]
        sample = float(ch.epoch_sample[anchor[0] % ch.HISTORY_MS])   # the code epoch the time was carried to
        if not self._agrees_with_clock(prn, sample, anchor[1]):
            return None
        self._carried[prn] = (ch, *anchor)
        self._emit("time_inherited", sample / self.fs_hz, prn=prn,
                   gap_s=round((sample - given.epoch_sample) / self.fs_hz, 3))
        return anchor

    def _clock_time(self, prn: int, ch: Channel) -> tuple[int, float] | None:
        """(code period, its transmit time) of a channel from the receiver's clock: what the time reference (a
        fix at most CLOCK_TIME_MAX_AGE_S old) predicts at its latest code epoch, to the whole millisecond."""
        fix, latest = self.time_reference(), latest_epoch(ch)
        if fix is None or latest is None:
            return None
        ms, sample = latest
        age_s = sample / self.fs_hz - fix.t_rx_s
        eph = self._ephemeris(prn, fix.gps_tow_s) if age_s <= CLOCK_TIME_MAX_AGE_S else None
        predicted = self.predicted_transmit_time(eph, sample, fix) if eph is not None else None
        if predicted is None:
            return None
        anchor = on_whole_ms(ms, predicted)
        self._carried[prn] = (ch, *anchor)
        self._emit("time_from_clock", sample / self.fs_hz, prn=prn, fix_age_s=round(age_s, 3))
        return anchor

    def _agrees_with_clock(self, prn: int, sample: float, t_sv_s: float) -> bool:
        """Whether a carried time lies within half a code period of what the last fix's clock predicts (true without a
        fix or an ephemeris: nothing to check against); a whole millisecond away, an event, and it is not taken."""
        eph = self._ephemeris(prn, t_sv_s)
        predicted = self.predicted_transmit_time(eph, sample) if eph is not None else None
        if predicted is None or abs(wrap_week_s(predicted - t_sv_s)) < 5e-4:
            return True
        self._emit("time_inheritance_refused", sample / self.fs_hz, prn=prn,
                   off_ms=round(wrap_week_s(predicted - t_sv_s) * 1e3, 3))
        return False

    def predicted_transmit_time(self, eph, sample: float, fix: Fix | None = None,
                                pos_ecef_m: np.ndarray | None = None) -> float | None:
        """The satellite time a signal received at a sample carries, predicted from a fix's clock (the last fix by
        default) for a position (the fix's by default): coarse time; None before the first fix. Good to the fix's
        errors: a kilometre is 3 us."""
        fix = self.last_fix if fix is None else fix
        if fix is None:
            return None
        dt_s = sample / self.fs_hz - fix.t_rx_s
        gps_s = fix.gps_tow_s + dt_s * (1.0 - fix.clock_drift_m_s / SPEED_OF_LIGHT_M_S)
        pos = fix.pos_ecef_m if pos_ecef_m is None else pos_ecef_m
        _, t_tx, _, _ = light_time_range(lambda t: satellite_position(eph, t),
                                         lambda t: satellite_position_velocity(eph, t), pos, gps_s)
        return float((t_tx + satellite_clock(eph, t_tx)[0]) % SECONDS_PER_WEEK)

    def _smoothed_m(self, ch: Channel, sample: float, pseudorange_m: float) -> float:
        """Carrier-smoothed pseudorange (Hatch filter): the code's noise averaged over smoothing_s, the carrier's
        precise range change carried along. Restarts with every new channel (a loss of lock makes a new one)."""
        window = int(self.cfg["pvt"]["smoothing_s"] * self.cfg["pvt"]["rate_hz"])
        cycles = ch.carrier_cycles_at(sample)
        if window <= 1 or cycles is None:
            return pseudorange_m
        state = getattr(ch, "hatch", None)
        if state is None or abs(pseudorange_m - state[0]) > 300.0:   # first epoch, or a jump: restart
            ch.hatch = (pseudorange_m, cycles, 1)
            return pseudorange_m
        prev, prev_cycles, n = state
        n = min(n + 1, window)
        predicted = prev - L1_WAVELENGTH_M * (cycles - prev_cycles)
        smoothed = pseudorange_m / n + predicted * (n - 1) / n
        ch.hatch = (smoothed, cycles, n)
        return smoothed

    def restart_smoothing(self, prn: int) -> None:
        """Forget a PRN's carrier-smoothing history (its code was disturbed until now)."""
        ch = self.channels.get(prn)
        if ch is not None:
            ch.hatch = None

    def _raim_config(self) -> IntegrityConfig:
        i, t = config.section(self.cfg, "integrity", Integrity), self.cfg["tracking"]
        sigma = SigmaModel(dll_bw_hz=t["dll_bw_hz"], spacing_chips=t["spacing_chips"], integration_s=i.integration_s,
                           smoothing_s=self.cfg["pvt"]["smoothing_s"], floor_m=i.floor_m, atmosphere_m=i.atmosphere_m)
        return IntegrityConfig(pfa=i.pfa, pmd=i.pmd, exclude=i.exclude, max_exclusions=i.max_exclusions, sigma=sigma)

    def _fix_at(self, sample: float) -> None:
        raw = self.observations_at(sample)
        for left_out, enough in ((self.excluded_prns, self.min_sats_excluding),
                                 (self.suspect_prns, self.min_sats_suspecting),
                                 (self.distrusted_prns, self.min_sats_distrusting)):
            kept = [r for r in raw if r.prn not in left_out]
            if len(kept) >= enough:
                raw = kept
        if self._week is None and self.rectifier is not None:
            self._week = self.rectifier.week   # a spoofer's subframe 1 says the week as well as any
        if len(raw) < 4 or self._week is None:   # no GPS time without the week: no fix
            return
        if self._t_rx0 is None:   # start the receiver clock so the pseudoranges come out near 20 000 km
            self._t_rx0 = max(r.t_sv_s for r in raw) + TYPICAL_FLIGHT_S - sample / self.fs_hz
        t_rx = (self._t_rx0 + sample / self.fs_hz) % SECONDS_PER_WEEK
        obs = [Observation(prn, self._smoothed_m(ch, sample, SPEED_OF_LIGHT_M_S * wrap_week_s(t_rx - t_sv)), t_sv,
                           dop, cn0, eph, weight=10 ** (min(cn0, 50.0) / 10) / 10 ** 4.5)
               for prn, t_sv, dop, cn0, eph, ch in raw if np.isfinite(cn0)]
        p = self.cfg["pvt"]
        fix = solve(obs, sample / self.fs_hz, self._week, (self.iono or FALLBACK_IONO) if p["ionosphere"] else None,
                    troposphere=p["troposphere"], prior=self.last_fix, elevation_mask_deg=p["elevation_mask_deg"],
                    raim=self.raim)
        if fix is None:
            return
        if fix.excluded_prns:
            self._emit("raim_exclusion", fix.t_rx_s, prns=list(fix.excluded_prns), raim=fix.raim,
                       test_statistic=fix.test_statistic, n_sats=fix.n_sats)
        self.last_fix = fix
        self.stats.n_fixes += 1
        if self.stats.first_fix_t_rx_s is None:
            self.stats.first_fix_t_rx_s = fix.t_rx_s
            self._emit("first_fix", fix.t_rx_s, lat_deg=fix.lat_deg, lon_deg=fix.lon_deg, n_sats=fix.n_sats)
        if self.on_observations is not None:
            self.on_observations(self._obs_epoch(fix, sample, t_rx, raw), fix.pos_ecef_m)
        if self.on_fix is not None:
            self.on_fix(fix)

    def _obs_epoch(self, fix: Fix, sample: float, t_rx: float, raw) -> ObsEpoch:
        """The epoch's raw (unsmoothed) observables on the receiver's clock. RINEX carrier phase has the sign of the
        range (it grows as the satellite recedes), the opposite of the integrated Doppler."""
        week = fix.gps_week + round((fix.gps_tow_s - t_rx) / SECONDS_PER_WEEK)   # the clock may sit across a rollover
        sats = {}
        for prn, t_sv, dop, cn0, _eph, ch in raw:
            cycles = ch.carrier_cycles_at(sample)
            sats[prn] = (SPEED_OF_LIGHT_M_S * wrap_week_s(t_rx - t_sv), math.nan if cycles is None else -cycles,
                         dop, cn0)
        return ObsEpoch(week, t_rx, sats)

    def channel_rows(self) -> list[ChannelRow]:
        rows = []
        for prn, ch in sorted(self.channels.items()):
            state = "pull-in" if ch.pull_in else ("bit-sync" if ch.bits.edge_ms is None else "tracking")
            if self.decoders[prn].time_anchor is not None:
                state = "nav" if self._ephemeris(prn, self.decoders[prn].time_anchor[1]) is not None else "tow"
            rows.append(ChannelRow(prn, state, float(ch.cn0_dbhz), ch.doppler_at(0), float(ch.st[0]),
                                   self.subframes_by_prn.get(prn, 0)))
        return rows
