"""The receiver with SemperFi's defence in front of it: the spoof guard cleans the samples, the conventional chain
receives them, and every fix says what it is built on (nominal, spoofing_detected, recovering, recovered).
"""

from dataclasses import replace

import numpy as np

from ..gps import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, L1_HZ, SPEED_OF_LIGHT_M_S, chips_apart, chips_offset
from ..receiver import Fix, Peak, Receiver, TRUSTED_STATES, trusted
from .beat import WINDOW_MS as BEAT_WINDOW_MS, two_carriers
from .canceller import JOINT_WITHIN_CHIPS, biased_twin
from .clock_guard import ClockGuard
from .continuity import Continuity
from .guard import SpoofGuard
from .maneuver_id import LinkedManeuver, ManeuverIdentifier, sky
from .policy import POWER_MARGIN_DB
from .rectifier import Rectifier


MAX_RECOVERED_RESIDUAL_M = 30.0
# A channel started this recently (past its pull-in) gives a range still settling: its code loop and its carrier
# smoothing start from the acquisition's code phase (ArduCopter SITL, a takeover: the eight channels acquired again at
# the verdict gave the first fixes called recovered 8-10.7 m off, 4-4.4 m of residual rms, 6 m a second later). Their
# fixes are recovering meanwhile; a standby channel the verdict promotes has long settled.
RECOVERED_SETTLE_S = 1.0
TWIN_SPACING_CHIPS = 0.1   # the early-late spacing of a legitimate channel with a spoofer within a chip
TWIN_MEASURE_REACH_CHIPS = JOINT_WITHIN_CHIPS + 0.5   # a twin measured this far off has left the two-path tracker
BEAT_CHECK_S = 0.25
# a PRN released by the verdict for a fresh look is alarmed and decided again within a few looks: its standby waits
STANDBY_GRACE_S = 10.0
# a standby channel follows the peak the chain does not, while a verdict is awaited: with its early-late pair 0.2 chip
# apart, a neighbour more than 1.2 chip away (its correlation a triangle a chip wide) does not pull it; closer pairs
# are left to the canceller's two-path tracker after the verdict (a standby found that close is not promoted)
STANDBY_SPACING_CHIPS = 0.2
STANDBY_MIN_SEPARATION_CHIPS = JOINT_WITHIN_CHIPS
STANDBY_APART_CHIPS = 0.5


def _code_phases(channels: dict, sample: float) -> dict[int, float]:
    """Each channel's code phase at an absolute sample, for those whose history holds it."""
    chips = {prn: ch.code_phase_at(sample) for prn, ch in channels.items()}
    return {prn: c for prn, c in chips.items() if c is not None}


class DefendedReceiver:
    def __init__(self, cfg: dict, fs_hz: float, if_hz: float = 0.0, assisted=None, on_fix=None, events=None,
                 week_hint: int | None = None, imu_track=None, on_observations=None, flight_link=None):
        """imu_track: an INS-only track (identifier.ImuTrack) with a maneuver in it, for the Adversarial Peak
        Identifier on a recording; flight_link: the link to a live flight side (send/poll), which flies a maneuver
        on request and sends its IMU track back."""
        self.on_fix, self.events = on_fix, events
        maneuver = ManeuverIdentifier(imu_track, fs_hz, if_hz) if imu_track is not None else \
            LinkedManeuver(flight_link, fs_hz, if_hz, ready=lambda: self.inner.last_fix is not None,
                           sky=self._sky) if flight_link is not None else None
        self.guard = SpoofGuard(cfg, fs_hz, if_hz, events, on_cancel=self._on_cancel,
                                on_release=lambda prn, sample: self.inner.search_from(sample), maneuver=maneuver,
                                nav_context=lambda: (self.inner.ephemeris_at, self.inner.last_fix),
                                continuing=self._continuing if imu_track is not None else None)
        self.inner = Receiver(cfg, fs_hz, if_hz, assisted, on_fix=self._label, events=events, week_hint=week_hint,
                              on_observations=on_observations)
        self.inner.min_sats_distrusting = 4 + self.guard.d["min_redundancy"]
        # a channel without its own time is timed by the clock of the last fix before the alarm or called good since
        # (a spoofed fix's clock may be anything the attacker made it)
        self._time_fix: Fix | None = None
        self.inner.time_reference = lambda: self._time_fix
        self.clock = ClockGuard(self.guard)   # time integrity: the clock model's alarm and the fixes' time_state
        if self.guard.d["mode"] == "full" and self.guard.d["rectify"] != "off":
            self.inner.rectifier = Rectifier(self.guard.d["rectify"], week_hint)
        self._rectifying: set[int] = set()
        self._standby_until: dict[int, float] = {}   # PRN -> the sample its standby channel is kept to
        # the INS carries the last nominal fix's ranges forward: which peak continues them (a takeover's spoofer
        # leaves them); a maneuver's track from the flight link comes only after an alarm, too late to anchor
        self.continuity = Continuity(fs_hz, self.guard.d["separation_ns"] * 1e-9 * SPEED_OF_LIGHT_M_S, imu_track) \
            if imu_track is not None and self.guard.d["mode"] == "full" else None
        self.first_recovered_t_s: float | None = None
        self._next_beat_check = 0

    def _sky(self) -> list[dict]:
        """The lines of sight of every PRN the maneuver will decide: the tracked ones and the alarmed ones."""
        return sky(set(self.inner.channels) | self.guard.alarmed_prns, self.inner.ephemeris_at, self.inner.last_fix)

    @property
    def stats(self):
        return self.inner.stats

    @property
    def last_fix(self):
        return self.inner.last_fix

    @property
    def interference(self):
        return self.inner.interference

    def channel_rows(self):
        return self.inner.channel_rows()

    def feed(self, chunk: np.ndarray) -> None:
        if self.guard.d["mode"] == "off" and self.guard.maneuver is None:
            self.inner.feed(chunk)   # the conventional receiver: the guard would only copy the samples through
            return
        self.guard.extra_prns = set(self.inner.channels)
        cleaned = self.guard.push(chunk)
        if self.guard.alarm_t_s is not None and self.guard.d["mode"] == "full":
            # once the attack is known, fixes are built from resolved PRNs only, while enough of them remain
            self._watch_twins()
            if self.continuity is not None:
                self._identify_by_continuity()
            self.inner.excluded_prns = {p for p in self.inner.channels if not self.guard.resolved(p)}
            # too few resolved: a fix from the PRNs whose spoofer is at least under cancellation (a guess's fix,
            # recovering at best) rather than one mixing in a single peak that may be a spoofer's with its twin unseen
            self.inner.suspect_prns = {p for p in self.inner.channels if self.guard.suspect(p)}
        if self.inner.rectifier is not None:
            self.inner.rectifier.update(self.guard.canceller)
        self.inner.absent_prns = self.guard.absent_now()   # one search of the sky, not two: and what that search
        if self.guard.sky_interference is not None:        # found besides GPS is the chain's to tell
            self.inner.interference.update(*self.guard.sky_interference)
        self.inner.feed(cleaned)
        if self.guard.d["mode"] == "full":
            self._follow_hypotheses()
        if self.guard.d["mode"] != "off" and self.inner.stats.samples >= self._next_beat_check:
            self._next_beat_check = self.inner.stats.samples + int(BEAT_CHECK_S * self.inner.fs_hz)
            self._check_beats()

    def _watch_twins(self) -> None:
        """A legitimate channel within a chip of its spoofer tracks under the spoofer's cancellation residual, which
        pulls its early-late balance like a multipath: it narrows its correlator (the residual's pull shrinks with
        the spacing), and its range is left out of the fixes while enough others remain when the spoofer is much the
        stronger (a fix that still needs it is not called recovered)."""
        self.inner.distrusted_prns = set()
        for prn, ch in self.inner.channels.items():
            if not ch.pull_in and self.guard.resolved(prn):
                self._measure_twin(prn, ch)
            twin = self.guard.close_twin(prn)
            if twin is None:
                continue
            if ch.cfg.spacing_chips > TWIN_SPACING_CHIPS:
                ch.cfg = replace(ch.cfg, spacing_chips=TWIN_SPACING_CHIPS)
            if biased_twin(*twin):
                self.inner.distrusted_prns.add(prn)

    def _measure_twin(self, prn: int, ch) -> None:
        """The legitimate channel, tracking the cleaned samples, says where the twin is: its latest code epoch
        against the spoofer's code phase at that sample. The canceller's two-path fit, weak on a twin much weaker
        than its spoofer and within half a chip, drifts away from it on its own."""
        epoch = ch.latest_epoch_sample
        for tr, spoofer_chips in self.guard.spoofers_at(prn, epoch):
            offset = chips_offset(0.0, spoofer_chips)
            if tr.legit_offset_chips is not None and abs(offset) < TWIN_MEASURE_REACH_CHIPS:
                tr.legit_offset_chips = offset

    def _identify_by_continuity(self) -> None:
        """A PRN whose cancelled peak was a guess is decided when exactly one of its two peaks -- the legitimate
        channel's on the cleaned samples, the cancelled spoofer's -- continues the range of the last nominal fix."""
        g = self.guard
        known = {p: ch for p, ch in self.inner.channels.items() if g.resolved(p) and not ch.pull_in and ch.ms > 1}
        if len(known) >= 4 and self._anchored():
            # a code period before the oldest latest epoch: every channel has epochs on both sides of it
            sample = min(ch.latest_epoch_sample for ch in known.values()) - \
                self.inner.fs_hz * 1e-3
            self.continuity.refine(sample, _code_phases(known, sample), self._predicted_chips)
        for prn in sorted(g.guessed & set(g.cancel_started) & g.verified):
            ch, tr = self.inner.channels.get(prn), g.canceller.stages[0].tracks.get(prn) if g.canceller.stages else None
            if ch is None or ch.pull_in or tr is None or prn in g.gave_up:
                continue
            epoch = ch.latest_epoch_sample
            spoofer_chips = tr.channel.code_phase_at(epoch)
            if spoofer_chips is None:
                continue
            legit = self._continuing(prn, epoch, (0.0, spoofer_chips))
            if legit is not None:
                g.identified(prn, cancelled_is_attacker=legit == 0, t_s=epoch / self.inner.fs_hz)

    def _continuing(self, prn: int, sample: float, chips: tuple[float, float]) -> int | None:
        """Which of a pair's code phases (at an absolute sample) continues the last nominal fix's range."""
        if not self._anchored():
            return None
        return self.continuity.legitimate(prn, sample, chips, self._predicted_chips)

    def _anchored(self) -> bool:
        """Whether continuity has an anchor (chosen at the first call after the alarm)."""
        if self.continuity is None or self.guard.alarm_t_s is None:
            return False
        if self.continuity.anchor is None:
            self.continuity.freeze(self.guard.alarm_t_s, self._predicted_chips)
        return self.continuity.anchor is not None

    def _predicted_chips(self, prn: int, sample: float, fix: Fix, pos_ecef_m) -> float | None:
        """The code phase a fix's clock predicts at a sample for a receiver at a position."""
        eph = self.inner.ephemeris_at(prn, fix.gps_tow_s)
        t_sv = None if eph is None else self.inner.predicted_transmit_time(eph, sample, fix, pos_ecef_m)
        return None if t_sv is None else (t_sv * 1e3 % 1.0) * 1023.0

    def _check_beats(self) -> None:
        """Two carriers under a tracked peak (beat), on two PRNs or more (one, once the attack is known): a spoofer
        parting from the legitimate signals it was aligned with."""
        beats = {}
        for prn, ch in self.inner.channels.items():
            if ch.pull_in or ch.ms < ch.cfg.pull_in_ms + BEAT_WINDOW_MS:
                continue
            f_hz = two_carriers(ch.prompt[np.arange(ch.ms - BEAT_WINDOW_MS, ch.ms) % ch.HISTORY_MS])
            if f_hz is not None:
                beats[prn] = f_hz
        if len(beats) >= (1 if self.guard.alarm_t_s is not None else 2):
            self.guard.beat_alarm(beats, self.inner.stats.samples / self.inner.fs_hz)

    def finish(self) -> None:
        self.inner.feed(self.guard.flush())
        self.guard.finish()

    def _follow_hypotheses(self) -> None:
        """While a PRN awaits the maneuver's verdict, the chain tracks one of its two peaks and a standby channel the
        other, bit-synchronised and decoding its own time and ephemeris: whichever the verdict names legitimate is
        ready at once, not re-acquired and read again for tens of seconds. A standby that slid onto the chain's peak
        follows nothing of its own and goes."""
        inner, g = self.inner, self.guard
        for prn in list(inner.standby):
            ch, sb = inner.channels.get(prn), inner.standby[prn]
            if prn in g.awaiting:
                self._standby_until[prn] = inner.stats.samples + STANDBY_GRACE_S * inner.fs_hz
            if inner.stats.samples > self._standby_until.get(prn, 0) or prn in g.cancel_started or g.resolved(prn):
                inner.drop_standby(prn, "no verdict awaited")
            elif ch is not None and not sb.pull_in and self._same_peak(ch, sb):
                inner.drop_standby(prn, "on the same peak as the channel")
        if g.attacker_stronger is not None and g.look_sample is not None:
            self._decide_by_power()
        for prn, (main, aux, sample) in g.awaiting_pairs.items():
            ch = inner.channels.get(prn)
            if prn in inner.standby or ch is None or ch.pull_in:
                continue
            here = ch.code_phase_at(sample)
            if here is None or chips_apart(main.code_phase_chips, aux.code_phase_chips) < STANDBY_MIN_SEPARATION_CHIPS:
                continue
            on_main = chips_apart(here, main.code_phase_chips) <= chips_apart(here, aux.code_phase_chips)
            other = aux if on_main else main
            if chips_apart(here, other.code_phase_chips) >= STANDBY_MIN_SEPARATION_CHIPS:
                inner.start_standby(prn, other.code_phase_chips, sample, other.doppler_hz, STANDBY_SPACING_CHIPS)

    def _decide_by_power(self) -> None:
        """A PRN the verdict released for a fresh look, its two peaks still followed (the chain's channel and the
        standby), is decided at once by the power relation the maneuver established: the stronger channel is the
        attacker's if the attacker was the stronger."""
        inner, g = self.inner, self.guard
        for prn, sb in list(inner.standby.items()):
            ch = inner.channels.get(prn)
            if ch is None or ch.pull_in or sb.pull_in or prn in g.awaiting or prn in g.cancel_started:
                continue
            gap_db = float(ch.cn0_dbhz - sb.cn0_dbhz)
            if not abs(gap_db) >= POWER_MARGIN_DB:
                continue
            adv, legit = (ch, sb) if (gap_db > 0) == g.attacker_stronger else (sb, ch)
            sample = g.look_sample
            g.cancel_by_power(prn, self._peak_of(adv, sample), self._peak_of(legit, sample), sample / inner.fs_hz)

    def _peak_of(self, ch, sample: int) -> Peak:
        """A channel's signal as a peak at an absolute sample (its code carried from its latest epoch)."""
        step = CA_CHIP_RATE_HZ * (1.0 + ch.doppler_at(0) / L1_HZ) / self.inner.fs_hz
        chips = ((sample - ch.latest_epoch_sample) * step) % CA_CODE_LENGTH_CHIPS
        return Peak(ch.prn, float(chips), ch.doppler_at(0), 0.0, float(ch.cn0_dbhz))

    def _same_peak(self, a, b) -> bool:
        """Whether two channels of a PRN track the same peak: their code phases a code period before the older of
        their latest epochs (both histories hold it)."""
        sample = min(a.latest_epoch_sample, b.latest_epoch_sample) - self.inner.fs_hz * 1e-3
        pa, pb = a.code_phase_at(sample), b.code_phase_at(sample)
        return pa is not None and pb is not None and chips_apart(pa, pb) < STANDBY_APART_CHIPS

    def _on_cancel(self, prn: int, peak, peak_sample: int) -> None:
        """A peak of a PRN is being cancelled: if the chain tracks it, its standby channel (on the other peak) takes
        over at once, else the chain searches for the legitimate one; a standby on the cancelled peak goes.

        The chain runs on cleaned samples, a little behind the raw ones the peak was found in: the peak's code
        phase is carried to each channel's latest code epoch (where the channel's own code phase is 0)."""
        inner = self.inner
        sb = inner.standby.get(prn)
        if sb is not None and sb.ms > 0 and self._chips_from_peak(sb, peak, peak_sample) < STANDBY_MIN_SEPARATION_CHIPS:
            # on the cancelled peak, or near enough that the spoofer pulled its loop: the two-path tracker's turn
            inner.drop_standby(prn, "within a chip of the peak under cancellation")
            sb = None
        ch = inner.channels.get(prn)
        if ch is not None and ch.ms > 0 and self._chips_from_peak(ch, peak, peak_sample) < 0.6:
            if inner.rectifier is not None:
                inner.rectifier.inherit(prn, ch, inner.decoders.get(prn))
            if sb is None or not inner.promote(prn, "the peak it tracked is being cancelled"):
                inner.drop_channel(prn, "tracking the peak under cancellation")
        elif ch is None and sb is not None:
            inner.promote(prn, "the PRN had no channel")
        elif ch is not None:
            # the legitimate signal's code was pulled by the spoofer beside it until now: its carrier smoothing
            # would carry that bias for its whole window
            inner.restart_smoothing(prn)

    def _chips_from_peak(self, ch, peak, peak_sample: int) -> float:
        """How far (chips) a channel is from a peak, at its latest code epoch."""
        epoch = ch.latest_epoch_sample
        step = CA_CHIP_RATE_HZ * (1.0 + peak.doppler_hz / L1_HZ) / self.inner.fs_hz
        return chips_apart((peak.code_phase_chips + (epoch - peak_sample) * step) % CA_CODE_LENGTH_CHIPS, 0.0)

    def _label(self, fix: Fix) -> None:
        """What a fix is built on. Before any alarm it is nominal when its ranges pass the integrity test (RAIM),
        else unverified (they disagree, or there are too few to check). After an alarm it is spoofing_detected
        (detect only, or a PRN in it neither resolved nor under cancellation nor found merged with its legitimate
        twin -- the attacker's signal aligned with it, under the examination's watch for the two to part: its range
        may still be the attacker's anywhere), then recovering until every PRN it uses is resolved (verified clean
        after cancellation, or examined and found to hold one signal) and its ranges pass the integrity test with
        redundancy to spare: a mix of legitimate and spoofed ranges, or a fix that cannot be checked, is never
        recovered. A PRN whose cancelled peak was chosen by assumption (the stronger one, with no earlier lock or
        maneuver to say so) is not resolved: the attacker sets its own power, and if the assumption is wrong the
        legitimate signal is the one cancelled and the range left is the attacker's -- when every PRN is so,
        consistent with the others, and wrong. A fix that would be recovered but times a range by its spoofer's
        navigation message (the rectifier) is rectified."""
        g = self.guard
        rectified = set(fix.prns) & self.inner.rectified_prns
        self._note_rectified(rectified, fix.t_rx_s)
        if g.alarm_t_s is None:
            state = "nominal" if trusted(fix.raim) else "unverified"
            if fix.raim == "fail":
                g.ranges_disagree(fix.t_rx_s)
            if state == "nominal" and self.continuity is not None:
                sample = fix.t_rx_s * self.inner.fs_hz
                # every locked channel, not only the fix's: one below the mask or still without its own time has a
                # range to carry forward too
                locked = {p: ch for p, ch in self.inner.channels.items() if not ch.pull_in}
                self.continuity.note(fix, _code_phases(locked, sample))
        elif g.d["mode"] != "full" or any(g.suspect(p) for p in fix.prns):
            state = "spoofing_detected"
        else:
            checked = (trusted(fix.raim) and fix.n_sats - 4 >= g.d["min_redundancy"]
                       and fix.residual_rms_m < MAX_RECOVERED_RESIDUAL_M)
            unbiased = not set(fix.prns) & self.inner.distrusted_prns
            state = "recovered" if checked and unbiased and self._settled(fix.prns) \
                and all(g.resolved(p) for p in fix.prns) else "recovering"
            if state == "recovered" and rectified:
                state = "rectified"
        if g.alarm_t_s is None or state in TRUSTED_STATES:
            self._time_fix = fix
        if state in ("recovered", "rectified") and self.first_recovered_t_s is None:
            self.first_recovered_t_s = fix.t_rx_s
            if self.events is not None:
                self.events.emit("recovered", fix.t_rx_s, time_to_recover_s=round(fix.t_rx_s - g.alarm_t_s, 2),
                                 state=state)
        if self.on_fix is not None:
            self.on_fix(self.clock.check(replace(fix, state=state), self._unvouched_ns(fix, state)))

    def _settled(self, prns) -> bool:
        """Whether every channel of these PRNs has tracked RECOVERED_SETTLE_S past its pull-in."""
        channels = [self.inner.channels.get(p) for p in prns]
        return all(ch is None or ch.ms >= ch.cfg.pull_in_ms + RECOVERED_SETTLE_S * 1e3 for ch in channels)

    def _unvouched_ns(self, fix: Fix, state: str) -> float:
        """How far a fix's ranges may all be off together by what the defence has not resolved (its time's share,
        defense/clock_guard): nothing when its position is good or no attack is known, the merged separation when
        every PRN not resolved is known to lie within it of its twin, else unbounded (they may be the attacker's)."""
        g = self.guard
        if state in TRUSTED_STATES or g.alarm_t_s is None:
            return 0.0
        if set(fix.prns) & self.inner.distrusted_prns or not all(g.resolved(p) or g.within_merged(p, fix.t_rx_s)
                                                                 for p in fix.prns):
            return float("inf")
        return g.detector.cfg.merged_separation_chips / CA_CHIP_RATE_HZ * 1e9

    def _note_rectified(self, prns: set[int], t_s: float) -> None:
        """An event when a PRN's range starts or stops being timed by its spoofer's navigation message."""
        if self.events is not None and prns != self._rectifying:
            self.events.emit("rectifier", t_s, started=sorted(prns - self._rectifying),
                             stopped=sorted(self._rectifying - prns), refused=dict(self.inner.rectifier.refused))
        self._rectifying = prns
