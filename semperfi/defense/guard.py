"""The spoof guard: a stream of samples in, the same stream with the attacker's signals cancelled out.

    raw chunk --> [detector: periodic re-acquisition on raw samples] --alarm--> policy --> canceller
              --> canceller (SIC stages, verified by re-acquisition on the cleaned samples) --> cleaned chunk

Used in front of the receiver chain (DefendedReceiver) and on its own as the plug-in filter (semperfi clean).
"""

from dataclasses import dataclass, replace

import numpy as np

from ..gps import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, L1_HZ, chips_apart, chips_offset
from ..receiver import DopplerGrid, Peak, acquire, run_aside
from .beat import BIN_HZ, WINDOW_MS as BEAT_WINDOW_MS, common_beat
from .canceller import JOINT_WITHIN_CHIPS, Canceller, CancellerConfig, biased_twin, caf_amplitude, refine_peak
from .detector import (TWO_PATH_BLOCK_S, Alarm, DetectorConfig, SpoofingDetector, auxiliary_peaks, examinable,
                       hidden_pair, in_units_of, is_cross_talk, load_kernels)
from .power import MAX_PLAUSIBLE_CN0_DBHZ, implausible_peaks
from .policy import POWER_MARGIN_DB, Choice, by_power, choose, gap_db, parse_policy, power_relation

WINDOW_MS = 40     # samples kept for examinations: acquisition looks at all 40 ms, the two-path test at the first 20
                   # (all 40 once the attack is known: the highest sensitivity)
# 2 ms x 20 non-coherent: a strong attacker's signals on a dozen PRNs (+10 dB: more power than the noise in the band)
# raise the floor every correlation sees by ~4 dB, and a 45 dB-Hz legitimate twin, 10 dB under its spoofer, stands at
# 1.5-4 detection thresholds in 10 ms (under the examinable 3 on most PRNs: no alarm at all in a GPS-SDR-SIM
# recording) and at 3-7 in 40 ms
EXAMINE_NONCOHERENT = 20
# While nothing at all has been seen of an attack, half of that (2 ms x 10): enough to see any spoofer that matters
# (a 38 dB-Hz peak stands at ~5 detection thresholds); what it sees is decided on a full look of the same samples
QUIET_NONCOHERENT = 10
QUIET_POWER_MARGIN_DB = 3.0   # a quiet look's signals this close to the power rule are looked at in full
# A quiet look searches each PRN seen before within this of its last Doppler (a quarter of the grid's rows): a
# spoofer of a signal in track is within a few hertz of it (synchronized), a clock's 1 ppm away (1.6 kHz: its edge
# shows in the window and is decided on a full look), or anywhere at the full searches every full_search_every_s
QUIET_SPAN_HZ = 1500.0
# and over the C/A code's main lobe alone (2048 code phases a ms: +-1.02 MHz, 0.5 dB of its power; 2 columns a chip,
# interpolated): at 4 MSa/s and up half the cost of every column, and whatever it sees is looked at in full
QUIET_COLUMNS = 2048
# a peak this far from a cancelled spoofer's code phase, or further, is not its residual (the acquisition's code phase
# is good to a few hundredths of a chip on a dominant peak)
TWIN_MIN_CHIPS = 0.15
TWIN_MATCH_CHIPS = 0.25   # an examination's code phase (2 ms coherent, interpolated) against the tracked twin's
# What a cancellation on power leaves counts as a signal from this many detection thresholds on. Measured on
# GPS-SDR-SIM: nine +10 dB spoofers cancelled leave maxima of 1.15-1.5 thresholds where their twins lie inside them
# (aligned: nothing is left); +20 dB spoofers 500 m off leave their real twins at 2.6 thresholds and more. Below it
# the PRN is taken as merged, its range the attacker's within half a chip: never a good fix.
LEFT_MIN_THRESHOLDS = 2.0
# the plug-in filter judges a twin once its track has measured this many attenuation windows, on the latest: the
# first spans the settling (GPS-SDR-SIM, flying, +15 dB: a twin judged on it, 15.1 dB under its spoofer, was given
# up), and behind a front end the second too. There the first three windows average 24.9, 25.6 and 26.6 dB, the next
# 26.5 and 26.4 (287 tracks, GPS-SDR-SIM behind 1 MHz), where ideal chips hold 28.7, 28.9, 29.0 from the first. Flying,
# 500 m, +15 dB: PRN 1's windows 23.9, 30.8, 33.8, 35.2 dB, its twin 0.56 chip under a spoofer 15.9 dB stronger,
# given up on the second by 0.1 dB: GNSS-SDR behind the filter, that satellite taken away, was within 5 m in 3 of 7
# runs. Judged on the third it is kept (its range 0.1 m off), and GNSS-SDR was within 5 m in 5 of 5 runs.
JUDGED_AFTER_WINDOWS = 3
# a replica on the weaker of two paths is started again on the stronger once it has measured this many (the first
# spans the settling; the sooner the better, the spoofer is in the output until then)
SWAPPED_AFTER_WINDOWS = 2
RELEASE_MARGIN_S = 2e-3   # a dropped cancellation leaves the samples cleaned this much later (held-back period)
# Once an attack is known, a PRN with one peak is looked at longer, around its own Doppler: its twin may lie beside a
# spoofer it is too weak to show next to in 2 ms x 20 under a dozen spoofers' interference (GPS-SDR-SIM, path loss,
# +6 dB: a 35.8 dB-Hz twin 2.9 chips from its spoofer was found after 22 s, and `clean` passed that spoofer through
# until then). 10 ms x 10 on the cleaned samples sees a 36 dB-Hz twin at ~16 dB per coherent block. A peak found so
# alarms when a look within DEEP_MEMORY_S found it as far from the main one (TWIN_MATCH_CHIPS): a twin keeps its
# offset from its spoofer (a flying receiver's moves 0.02 chip/s at most), while what a dozen +15 dB spoofers'
# cross-talk and bit flips raise moves with their code phases. Near the look's floor a twin shows on some looks only:
# GPS-SDR-SIM, flying, 3 km, +15 dB, PRN 10's twin (34.5-36.7 dB-Hz, 26-33 Hz off its spoofer, between the look's
# Doppler bins) was over it on 4 of 13 looks, never two in a row, and held to the next look alone its spoofer passed
# through `clean` for 14 s.
DEEP_MEMORY_S = 5.0
DEEP_COHERENT_MS = 10
DEEP_NONCOHERENT = 10
# A twin's Doppler is within a few hertz of a static spoofer's, tens of hertz off a flying receiver's (5 m/s: 26-33
# Hz; one further off is for the full searches). Bins 25 Hz apart (10 ms lose 0.2 dB between them, 50 Hz apart 0.9
# dB) found the flying receiver's twin above at 3.8 s, but a static one's never in 19 s (with 50 Hz: 8 s): they split
# the spoofer's own Doppler sidelobes (+-150 Hz, 38-39 dB-Hz) into more peaks, and the twin fell off the peaks kept
DEEP_SPAN_HZ = 250.0
DEEP_STEP_HZ = 50.0
DEEP_CROSS_TALK_BLOCK_S = 1e-3   # cross-talk judged per code period (is_cross_talk): the strong signals' bit flips
# The longer look's two-path fit (a fit is 8-35 ms of CPU a PRN at 2.6-10 MSa/s) only under a peak this strong: a twin
# more than the fit's regular floor (13 dB) under a weaker one is under 30 dB-Hz, which 100 ms cannot resolve
DEEP_FIT_MIN_CN0_DBHZ = 43.0
BEAT_STALE_S = 1.0     # a time push's beat unseen on a PRN this long: its separation is no longer known
COMMON_WAIT_S = 1.0    # a beat on a few PRNs alike, no alarm yet: how long the others have to show it too
MAX_SWAPS = 2          # a PRN whose cancelled peak is found legitimate this often is given up
MAX_REMOVALS = 3       # a PRN taken out is taken out again this often at most, each time its removal ends
# an alarm's peak and a cleaned signal's strongest are one signal when they lie this close, in chips from their
# spoofer (a flying receiver's twin moves 0.017 chip/s against a static attacker's: 0.1 chip in the ~5 s between)
SAME_PEAK_CHIPS = 0.3
REMOVED_REMAINDER = "given up: what is left of it is cancelled too, the satellite left out of the output"
REMOVED_SPOOFER = "given up before any stage took it on: its spoofer is taken out as one path (a twin apart stays)"
REMOVED_REMNANT = ("what is left under its spoofer is taken out: a front end's rounding of chips stronger than any "
                   "satellite's, no twin; its legitimate signal apart stays in the output")
# A cancellation that assumed the stronger of two peaks the attacker's whose settled joint track finds its twin this
# much stronger than what its replica follows has its replica on the weaker signal: a close pair whose rounded peaks
# merge, the twin hint on the wrong side, the loops drawn onto the other path (GPS-SDR-SIM behind 1 MHz, static, 500 m,
# +10 dB: PRN 7's replica on the legitimate signal, its "twin" the spoofer 10 dB stronger, the PRN then given up as a
# biased twin). It is started again on the stronger path, once.
ROLES_SWAPPED_DB = 3.0
ABSENT_MARGIN_S = 1.0  # a full search's absent PRNs stand this long past the next one's due time (then: search again)
SUSPECT_FOR_S = 10.0   # ranges that disagree, no alarm yet: how long every look stays at the highest sensitivity
EXAMINE_MAX_PEAKS = 16  # a strong spoofer's Doppler and code sidelobes are local maxima too: room for its twin


# A quiet sky's screen is applied this long after it was due, computed meanwhile beside the receiver's work on the
# next samples (its search and fits, a look's whole cost, then take no time of their own); under examine_every_s, so
# that a pair a screen finds is confirmed when it would have been
LOOK_APPLIED_AFTER_S = 0.3

# The plug-in filter under an attack seen at the start holds its output this long at most, cancelling meanwhile for its
# looks, then cleans the held samples again from the first with every spoofer known by then (replay_start): the looks
# that find a weak satellite's spoofer search the samples cleaned of the stronger ones, so its alarm comes 0.4-1.1 s
# after theirs (GPS-SDR-SIM, 1 km, +10 dB: five PRNs at 0.8 and 1.4 s), and each had passed whole until then -- a
# receiver behind locked on it, then lost the satellite. Memory: the held raw samples (2 s at 10 MSa/s: 160 MB)
REPLAY_MAX_S = 2.0


@dataclass(frozen=True, eq=False)
class _LookPlan:
    x: np.ndarray             # the window searched
    first: int                # its first sample's absolute index
    seen: int                 # raw samples received when the look was due
    full: bool                # every PRN searched
    prns: tuple
    screen: bool              # a screen first (quiet or settled), looked at in full when it sees anything
    windows_hz: dict | None   # a screen's Doppler window of each PRN (a screen), or an attack's look's
    quiet: bool               # nothing seen of an attack
    carried: dict | None      # a quiet sky's fits-only look: the last search's CAFs, carried to this window
    sensitive: bool
    alarmed: frozenset        # the detector's alarmed PRNs (not fitted)


class _Tail:
    """The newest n samples of a stream, joined only when a look asks for them: a view of the last chunk's tail
    when it holds them all, else the parts joined. Keeping a window joined at every chunk copied it each time (the
    deep looks' 100 ms is a chunk's length: 8 MB a chunk at 10 MSa/s, for a look once a second). Keeps views of
    what it is given, which are never written to afterwards (SpoofGuard.push)."""

    def __init__(self, n: int):
        self.n = n
        self.clear()

    def clear(self) -> None:
        self._parts: list[np.ndarray] = []
        self._total = 0
        self._joined: np.ndarray | None = None

    def push(self, new: np.ndarray) -> None:
        if new.size == 0:
            return
        self._parts.append(new)
        self._total += new.size
        self._joined = None
        while self._total - self._parts[0].size >= self.n:   # the oldest part is not needed for the last n
            self._total -= self._parts.pop(0).size

    @property
    def size(self) -> int:
        return min(self._total, self.n)

    def array(self) -> np.ndarray:
        if self._joined is None:
            last = self._parts[-1] if self._parts else np.empty(0, dtype=np.complex64)
            self._joined = last[-self.n:] if last.size >= self.n else np.concatenate(self._parts)[-self.n:]
        return self._joined


class SpoofGuard:
    def __init__(self, cfg: dict, fs_hz: float, if_hz: float = 0.0, events=None, on_cancel=None, on_release=None,
                 maneuver=None, nav_context=None, real_samples: bool = False, continuing=None,
                 remove_given_up: bool = False, replay_start: bool = False):
        """maneuver: a ManeuverIdentifier (an INS track with a maneuver in it), whose verdicts replace the policy's
        guesses; nav_context() -> (ephemeris_of(prn, tow_s), a recent fix) for its lines of sight.
        real_samples: the samples are real values at an IF (their output must stay real and free of both images).
        remove_given_up: what is left of a PRN given up is cancelled too (the plug-in filter: the receiver behind it
        cannot be told to leave the satellite out).
        replay_start: under an attack seen at the start, the start's output is held and cleaned again with every
        spoofer alarmed by then (REPLAY_MAX_S; the plug-in filter, whose receiver sees each spoofer left whole)."""
        self.cfg, self.d = cfg, cfg["defense"]
        if self.d["mode"] not in ("off", "detect", "full"):
            raise ValueError(f"--defense wants off, detect or full; got '{self.d['mode']}'")
        self.policy, self.policy_prns = parse_policy(self.d["adversarial"])
        self.fs_hz, self.if_hz, self.events, self.on_cancel = float(fs_hz), float(if_hz), events, on_cancel
        # on_release(prn, sample): a cancellation dropped, the PRN's signal back in the cleaned samples from there
        self.on_release = on_release
        self.detector = SpoofingDetector(fs_hz, if_hz, DetectorConfig(separation_s=self.d["separation_ns"] * 1e-9,
                                                                      confirmations=self.d["confirmations"]))
        if self.d["mode"] != "off":   # while the first look searches (at 2.6 MSa/s, a tenth of a clean minute's cost)
            run_aside(load_kernels, self.fs_hz)
        self.canceller = Canceller(fs_hz, if_hz, CancellerConfig(max_stages=self.d["max_iterations"],
                                                                 real_samples=real_samples))
        self.window = int(round(fs_hz * 1e-3)) * WINDOW_MS
        self._raw = _Tail(self.window)                   # the newest raw samples, for examinations
        self._clean = _Tail(self.window)                 # the newest cleaned samples, for verification
        self.deep_window = int(round(fs_hz * 1e-3)) * DEEP_COHERENT_MS * DEEP_NONCOHERENT
        self._deep = _Tail(self.deep_window)               # the newest cleaned samples, for the longer looks
        self._deep_under: frozenset = frozenset()        # the PRNs cancelled while they were cleaned
        self._deep_seen: dict[int, list[tuple[float, float]]] = {}   # PRN -> (t_s, offset chips) of the second
        # peaks the longer looks saw over DEEP_MEMORY_S
        self._seen = 0                                   # raw samples received
        self._cleaned = 0                                # cleaned samples produced
        self._next_exam = 0
        self._next_full = 0
        self._suspect_until = 0                          # samples: looks at the highest sensitivity until then
        self.absent_prns: frozenset[int] = frozenset()   # what the latest full search found nothing of ...
        self._absent_until = 0                           # ... and until when that stands
        self.sky_interference = None                     # (what it found besides GPS, when), for the chain to tell
        self.present_prns: set[int] = set()
        self.alarm_t_s: float | None = None
        self.alarmed_prns: set[int] = set()
        self.cancel_started: dict[int, float] = {}       # PRN -> t_s of its first cancellation
        self.verified: set[int] = set()                  # PRNs whose legitimate peak dominates after cancellation
        self.pending_verify: dict[int, tuple[float, object, int]] = {}  # PRN -> (when, adversarial peak, stage)
        self.gave_up: dict[int, str] = {}
        self.remove_given_up = remove_given_up
        self.removed: set[int] = set()                   # PRNs given up and taken out whole (remove_given_up)
        self.remnants: set[int] = set()                  # PRNs whose spoofer's remnant is taken out, not the PRN
        self._removals: dict[int, int] = {}              # how often each was (taken out again: _keep_removed)
        self._twin_judged: set[int] = set()              # verified PRNs whose twin the plug-in filter has judged
        # PRNs whose alarm showed the legitimate peak apart (chips from the spoofer) while the two-path fit found a
        # twin under the spoofer's peak, which is followed instead (_start_cancelling); and where the strongest peak
        # of a verified PRN's cleaned signal lay (chips from the spoofer): _rounding_twin
        self._seen_apart: dict[int, float] = {}
        self._strongest_apart: dict[int, float] = {}
        self._assumed_stronger: set[int] = set()         # PRNs cancelled on the guess that the stronger peak is it
        self._stronger_than_sky: set[int] = set()        # ... and on power: stronger than any satellite's signal
        self._roles_swapped: set[int] = set()            # ... restarted on their twin, the stronger (ROLES_SWAPPED_DB)
        # PRNs cancelled on power alone (no legitimate peak in sight); those whose cancellation takes everything away
        # are merged (the property)
        self._blind: set[int] = set()
        # PRNs whose attacker's peak was chosen by an assumption (the stronger one, the later one, a user's list), not
        # known: the attacker controls its power and delay, so what is cancelled may be the legitimate signal
        self.guessed: set[int] = set()
        self.extra_prns: set[int] = set()                # PRNs the user of the guard wants examined too
        self.maneuver, self.nav_context = maneuver, nav_context
        # continuing(prn, sample, (chips_a, chips_b)) -> 0 | 1 | None: which of two code phases continues the range
        # tracked before the attack (defense/continuity); a PRN whose cancelled peak it found legitimate is swapped
        self.continuing, self.swapped = continuing, {}
        self.awaiting: dict[int, Alarm] = {}             # alarmed PRNs whose attacker's peak the maneuver will name
        # the awaiting PRNs' two peaks at the latest look: (main, auxiliary, the absolute sample their code phases hold)
        self.awaiting_pairs: dict[int, tuple] = {}
        self.attacker_stronger: bool | None = None       # what the maneuver showed of the attacker's power, if clear
        self.maneuver_legit: set[int] = set()            # PRNs whose only peak the maneuver showed to follow the motion
        self._inference = ""
        # PRN -> the attacker's peak's power over its twin's (dB), where continuity named the attacker's peak (it
        # appeared after the receiver had the other): the power relation to fall back on when no maneuver decides
        self._newcomer_gaps_db: dict[int, float] = {}
        self._guess_gaps_db: dict[int, float] = {}       # a guessed cancellation: its peak over the other (dB)
        # a spoofer was seen parting from signals it had been aligned with: a PRN's lone peak that predates the
        # attack may still be the two merged
        self.takeover = False
        # a beat shared by the PRNs (beat.common_beat): a time push's, and the PRNs merged because of it
        self.push_beat_hz: float | None = None
        self._merged_by_beat: set[int] = set()
        self._first_beat_s: float | None = None
        self._push_onset_s: float | None = None
        self._beat_seen_s: dict[int, float] = {}         # merged PRN -> when its beat was last seen the common one
        self._startup_samples = int(self.d["startup_s"] * fs_hz)
        self._held: list[np.ndarray] = []
        self.replay_start = replay_start
        self._replaying = False   # the start's raw samples held (and cleaned meanwhile for the looks), to clean again
        self._replay_until = int(REPLAY_MAX_S * fs_hz)
        self._last_cafs: dict = {}
        self._last_look_first = -1
        self._looked: tuple[np.ndarray, int] | None = None   # the window the latest examination searched
        self._searched: tuple[int, dict] | None = None      # a quiet search's first sample and CAFs, for the next fit
        self._pending: tuple[_LookPlan, object] | None = None   # a look computed aside: its plan, its future
        self._chip_shape_told = False
        self._apply_after = int(LOOK_APPLIED_AFTER_S * fs_hz)

    def _emit(self, kind: str, t_s: float, **fields) -> None:
        if self.events is not None:
            self.events.emit(kind, t_s, **fields)

    # -- the stream -----------------------------------------------------------------------------------------
    def push(self, chunk: np.ndarray) -> np.ndarray:
        """Samples in; the cleaned samples out (in order, a little behind: cancellation holds back a code period).
        The guard keeps views of the chunk and of what it returns: neither may be written to afterwards."""
        chunk = np.asarray(chunk, dtype=np.complex64)
        self._seen += chunk.size
        self._raw.push(chunk)
        if self.maneuver is not None:
            self.maneuver.push(chunk)
            if self.maneuver.due_to_end(self._seen / self.fs_hz):
                self._identify(self._seen / self.fs_hz)
            for kind, fields in self.maneuver.news():
                self._emit(kind, self._seen / self.fs_hz, **fields)
            self._retry_maneuver(self._seen / self.fs_hz)
        if self._pending is not None and self._seen >= self._pending[0].seen + self._apply_after:
            self._apply_pending()
        self.detector.suspected = self._seen < self._suspect_until
        starting = self.d["mode"] != "off" and self._seen < self._startup_samples
        if (self.d["mode"] != "off" and self._pending is None and self._seen >= self._next_exam
                and self._raw.size >= self.window):
            plan = self._plan()
            if not starting and self.maneuver is None and plan.quiet:
                # a quiet sky's screen: computed aside while the next samples are received, applied
                # LOOK_APPLIED_AFTER_S after it was due (a pair it finds is confirmed examine_every_s after it was
                # due, as before). Not under attack: there the canceller keeps both cores busy, and a look beside it
                # cost more CPU than it saved wall time (GPS-SDR-SIM, 10 MSa/s, every PRN spoofed: 42-45 s against
                # 41 s a minute)
                self._pending = (plan, run_aside(self._compute, plan))
            else:
                self._apply(plan, *self._compute(plan, ahead=False))
                self._schedule(plan.seen)
        if starting:                      # hold the first samples until the first looks have decided
            self._held.append(chunk)
            return np.empty(0, dtype=np.complex64)
        if self._held and not self._replaying:   # the start-up's end: its samples go to the canceller
            self._replaying = self.replay_start and self._attack_at_start()
            self._held.append(chunk)
            chunk = np.concatenate(self._held)
            if not self._replaying:
                self._held = []
        elif self._replaying:
            self._held.append(chunk)
        cleaned = self.canceller.push(chunk)
        self._tell_chip_shape()
        self._forget_lost(self._seen / self.fs_hz)
        self._keep_removed(self._seen / self.fs_hz)
        self._keep_cleaned(cleaned)
        self._verify()
        if self._replaying:
            if not self._replay_due():
                return np.empty(0, dtype=np.complex64)
            cleaned = self._replay()
        return cleaned

    def _keep_cleaned(self, cleaned: np.ndarray) -> None:
        """Cleaned samples counted and kept for the looks and verifications that read them."""
        self._cleaned += cleaned.size
        self._clean.push(cleaned)
        if self.alarmed_prns:
            under = frozenset(self.canceller.prns)
            if under != self._deep_under:    # a look mixing two sets of cancellations would see a spoofer's edge
                self._deep.clear()
                self._deep_under = under
            self._deep.push(cleaned)

    def _attack_at_start(self) -> bool:
        """Anything seen of an attack by the end of the start-up's looks: an alarm, a pair to confirm."""
        return bool(self.alarmed_prns or self.detector.sensitive or self.detector.pending())

    def _replay_due(self) -> bool:
        """The held start cleaned again now: every satellite found is cancelled (or given up), the looks saw no
        attack after all, or REPLAY_MAX_S is reached."""
        return (self._seen >= self._replay_until or not self._attack_at_start()
                or self.present_prns <= self.canceller.prns | self.gave_up.keys())

    def _replay(self) -> np.ndarray:
        """The held start cleaned again from its first sample, by every track known now (Canceller.restart); the
        samples the looks and verifications read are those."""
        held, self._held, self._replaying = self._held, [], False
        self.canceller.restart()
        # chunk by chunk, as they came: the tracks' loops and twin estimates settle per buffer as on a live stream,
        # and no buffer is 2 s long (at 25 MSa/s, 400 MB and a copy per joint track)
        cleaned = np.concatenate([self.canceller.push(part) for part in held])
        self._cleaned = 0
        self._clean.clear()
        self._deep.clear()
        self._keep_cleaned(cleaned)
        self._emit("start_replayed", self._seen / self.fs_hz, held_s=round(self._seen / self.fs_hz, 3),
                   prns=sorted(self.canceller.prns))
        return cleaned

    def _tell_chip_shape(self) -> None:
        """The front end's chip shape, once the canceller has measured it (chip_shape): an event."""
        meter = self.canceller.front_end
        if meter.done and not self._chip_shape_told:
            self._chip_shape_told = True
            self._emit("chip_shape", self._seen / self.fs_hz, **meter.as_event())

    def _quiet(self) -> bool:
        """Nothing at all seen of an attack (the most common case there is): no alarm, no pair waiting for its
        confirmation, past the start-up looks."""
        return not (self.detector.sensitive or self.detector.pending() or self._seen < self._startup_samples)

    def _settled(self) -> bool:
        """An attack known and dealt with: every PRN alarmed is cancelled and verified clean (or given up), and
        nothing waits on the next looks (a verification, a pair to confirm, a close second signal, a merged pair to
        part, a push's beat, a takeover's lone peaks, a maneuver)."""
        # a close second signal waits on the looks only on a PRN not alarmed (an alarmed one's is being cancelled);
        # a takeover's lone peaks are the PRNs it has not alarmed yet (their twins may still be merged under them);
        # a maneuver that is asked for or under way has its peaks followed at every look. Was: any close pair ever
        # seen, any maneuver object (a live flight side's link) and any takeover at all kept every look full for
        # good after a takeover's recovery on ArduCopter SITL
        return (self.alarm_t_s is not None and not self.pending_verify and not self.awaiting
                and not self.detector.pending() and not self.detector.close.keys() - self.alarmed_prns
                and not self.merged and self.push_beat_hz is None
                and not (self.takeover and self.present_prns - self.alarmed_prns - self.gave_up.keys())
                and not (self.maneuver is not None and self.maneuver.expected())
                and all(p in self.verified or p in self.gave_up for p in self.alarmed_prns))

    def flush(self) -> np.ndarray:
        """The samples still held back, at the end of the stream."""
        if self._pending is not None:
            self._apply_pending()
        if self._replaying:
            cleaned = np.concatenate([self._replay(), self.canceller.flush()])
            self._cleaned = cleaned.size
            return cleaned
        held = np.concatenate(self._held) if self._held else np.empty(0, dtype=np.complex64)
        self._held = []
        cleaned = np.concatenate([self.canceller.push(held), self.canceller.flush()])
        self._cleaned += cleaned.size
        return cleaned

    def _acquire(self, window: np.ndarray, prns, center_hz: float, span_hz: float,
                 noncoherent: int = EXAMINE_NONCOHERENT, **screen):
        """Every examination's search: the window's 2 ms x noncoherent, 333 Hz bins (screen: a quiet look's
        Doppler windows and columns, acquisition.acquire)."""
        a = self.cfg["acquisition"]
        n = int(round(self.fs_hz * 1e-3)) * 2 * noncoherent
        return acquire(window[:n], self.fs_hz, prns, DopplerGrid(center_hz, span_hz, 333.0),
                       self.if_hz, 2, noncoherent, a["pfa"], max(EXAMINE_MAX_PEAKS, a["max_peaks"]),
                       excise=True, keep_power=False, **screen)   # a tone is no satellite, nor a spoofer

    def _around_last(self, prns, with_twins: bool = False) -> dict[int, tuple[float, float]]:
        """Each PRN's Doppler window from the last search that saw it: QUIET_SPAN_HZ about its main peak (a quiet
        look's), and with_twins about the second peaks paired with it too (an attack's look between full searches:
        a third of the grid's rows, the search being most of a look's cost under attack; a peak further off shows
        at the full searches, every full_search_every_s)."""
        out = {}
        for prn in prns:
            caf = self._last_cafs.get(prn)
            if caf is None or caf.best is None:
                continue
            pairs = auxiliary_peaks(caf, self._last_cafs, self.detector.cfg, self.fs_hz) if with_twins else []
            dopplers = [caf.best.doppler_hz] + [pair.auxiliary.doppler_hz for pair in pairs]
            out[prn] = (min(dopplers) - QUIET_SPAN_HZ, max(dopplers) + QUIET_SPAN_HZ)
        return out

    def absent_now(self) -> frozenset[int]:
        """The PRNs the latest full search (every PRN, 20-40 ms: more sensitive than the chain's) found nothing of,
        while it is recent enough to stand for the chain's own cold search of the same samples."""
        return self.absent_prns if self._seen < self._absent_until else frozenset()

    def _look(self) -> tuple[np.ndarray, int]:
        """The window an examination searches, and its first sample's absolute index. Once spoofed signals are
        being cancelled, the cleaned one: a strong attacker's signals on a dozen PRNs raise the floor every
        correlation sees (their multiple-access interference: at +15 dB, a 45 dB-Hz legitimate twin looks like
        36 dB-Hz, and their cross-correlations make peaks as strong as it); cancelling them lowers the floor for the
        PRNs still to examine -- the paper's multi-stage attenuation. The raw window while the cleaned one has not
        moved on since the last look (the canceller holds samples while its loops settle), and when a maneuver
        starts (its followers go on in the raw stream, and follow the attacker's peaks too)."""
        first = self._cleaned - self._clean.size
        raw_first = self._seen - self.window
        if self.maneuver is not None and self.maneuver.due_to_start(raw_first / self.fs_hz):
            return self._raw.array(), raw_first
        if self.canceller.prns and self._clean.size >= self.window and first > self._last_look_first:
            self._last_look_first = first
            return self._clean.array(), first
        return self._raw.array(), raw_first

    def _schedule(self, seen: int) -> None:
        """The next look, after one applied that was due at `seen` raw samples."""
        every = (0.1 if seen < self._startup_samples else self.d["quiet_examine_every_s"] if self._quiet()
                 else self.d["settled_examine_every_s"] if self._settled() else self.d["examine_every_s"])
        self._next_exam = seen + int(every * self.fs_hz)

    def _apply_pending(self) -> None:
        """The look computed aside, applied now (its results waited for if need be)."""
        (plan, future), self._pending = self._pending, None
        self._apply(plan, *future.result())
        self._schedule(plan.seen)

    def _plan(self) -> _LookPlan:
        """What the look due now searches, decided from the guard's state now; the search and fits themselves
        (_compute) read nothing else, so they may run on another thread while that state moves on."""
        x, first = self._look()
        t_s = first / self.fs_hz
        full = self._seen >= self._next_full or not self.present_prns
        searched, self._searched = self._searched, None
        quiet = self._quiet()
        due = self.maneuver is not None and self.maneuver.due_to_start(t_s)
        if full:
            self._next_full = self._seen + int(self.d["full_search_every_s"] * self.fs_hz)
        prns = tuple(range(1, 33)) if full else tuple(sorted(self.present_prns | self.extra_prns))
        carried = None
        if searched is not None and not full and quiet and not due:
            carried = self._carried(first, *searched)
        # nothing seen (past the start-up's first look, which sees every PRN in full), or an attack dealt with and
        # nothing waiting: a screen, and a full look at what it sees
        calm = not (self.detector.sensitive or self.detector.pending()) and bool(
            self.present_prns or self._seen >= self._startup_samples)
        screen = calm or self._settled()
        windows = None if full else self._around_last(prns, with_twins=not screen)
        return _LookPlan(x, first, self._seen, full, prns, screen, windows, quiet, carried,
                         self.detector.sensitive, frozenset(self.detector.alarmed))

    def _compute(self, plan: _LookPlan, ahead: bool = True) -> tuple[dict, dict]:
        """The look's CAFs, and (ahead: computed aside) the two-path fits the detector will want of them."""
        if plan.carried is not None:
            cafs = plan.carried
        else:
            span_hz = self.cfg["acquisition"]["doppler_max_hz"]
            cafs = None
            if plan.screen:
                cafs = self._acquire(plan.x, plan.prns, 0.0, span_hz, QUIET_NONCOHERENT,
                                     windows_hz=plan.windows_hz, most_columns=QUIET_COLUMNS)
            if cafs is None:
                cafs = self._acquire(plan.x, plan.prns, 0.0, span_hz, EXAMINE_NONCOHERENT, windows_hz=plan.windows_hz)
            elif self._worth_a_full_look(cafs):
                cafs = self._acquire(plan.x, plan.prns, 0.0, span_hz, EXAMINE_NONCOHERENT)
        samples = self._fitted(plan.x, plan.sensitive and plan.carried is None)
        return cafs, self.detector.fits(cafs, samples, plan.sensitive, plan.alarmed) if ahead else {}

    def _fitted(self, x: np.ndarray, sensitive: bool) -> np.ndarray:
        """The samples a look's two-path fits take: all 40 ms once the attack is known, else the first 20."""
        return x if sensitive else x[:self.window // 2]

    def _carried(self, first: int, searched_first: int, cafs: dict) -> dict:
        """A quiet sky's every other look: no search, the two-path fits alone, around the peaks the last search
        found, carried to this window by their own Doppler (a 30 Hz error moves one 0.04 chip in 2 s; the fit spans
        +/-2 chips). A takeover's hidden pair is fitted at every look, as before; a second peak elsewhere and the
        power rule are seen at every search, every other look (the search is the larger part of a look's cost)."""
        dt_s = (first - searched_first) / self.fs_hz

        def carried(p: Peak) -> Peak:
            advance = dt_s * CA_CHIP_RATE_HZ * (1.0 + p.doppler_hz / L1_HZ)
            return replace(p, code_phase_chips=float((p.code_phase_chips + advance) % CA_CODE_LENGTH_CHIPS))
        return {prn: replace(caf, peaks=tuple(map(carried, caf.peaks))) for prn, caf in cafs.items()}

    def _apply(self, plan: _LookPlan, cafs: dict, fits: dict) -> None:
        """What a look saw, acted on: alarms, cancellations, the PRNs present (fits: computed ahead, by key)."""
        x, first = plan.x, plan.first
        self._looked = (x, first)
        t_s = first / self.fs_hz
        if plan.carried is None:   # a search (not the fits alone): what it found of the sky
            if plan.full:
                self.absent_prns = frozenset(p for p, c in cafs.items() if c.best is None)
                self.sky_interference = (next(iter(cafs.values())).interference, t_s)
                self._absent_until = plan.seen + int((self.d["full_search_every_s"] + ABSENT_MARGIN_S) * self.fs_hz)
            # a strong attacker's cross-talk puts peaks on absent PRNs: examining them every look would cost the most
            peaks = self._examinable_peaks(cafs)
            self.present_prns |= peaks.keys()
            self._last_cafs.update(cafs)
            if self.maneuver is not None and self.maneuver.due_to_start(t_s):
                self._follow_through_maneuver(cafs)
            self._check_power(peaks, t_s)
            self.detector.hold(self._held_by_beat(t_s))
        # the fits alone are a quiet sky's: never sensitive
        sensitive = self.detector.sensitive and plan.carried is None
        for alarm in self.detector.examine(cafs, t_s, self._fitted(x, sensitive), fits):
            self._alarm(alarm.prn, t_s, alarm.pair.as_event())
            if self.d["mode"] == "full":
                self._on_alarm(alarm, t_s)
        if plan.carried is not None:
            return
        self._look_deeper(cafs)
        self._note_awaiting_pairs(cafs, first)
        if plan.quiet and self._quiet():
            self._searched = (first, cafs)

    def _worth_a_full_look(self, cafs: dict) -> bool:
        """Whether a quiet look saw anything to decide on: a second peak, or signals near the power rule. Decisions
        are made on full looks of the same samples only: the power rule's thermal C/N0s sum every examinable
        signal, and a shorter look finds fewer of them examinable (GPS-SDR-SIM, a +10 dB aligned push: 0.7 dB lower,
        four of nine spoofers under the rule)."""
        peaks = self._examinable_peaks(cafs)
        return bool(implausible_peaks(peaks, MAX_PLAUSIBLE_CN0_DBHZ - QUIET_POWER_MARGIN_DB)) or any(
            auxiliary_peaks(cafs[p], cafs, self.detector.cfg, self.fs_hz) for p in peaks)

    def _look_deeper(self, cafs: dict) -> None:
        """Under a known attack, each PRN showing one peak and not yet alarmed: a longer look at the cleaned samples
        around its Doppler (DEEP_*) for a second peak, which alarms it like any other."""
        if not self.alarmed_prns or self._deep.size < self.deep_window:
            return
        first = self._cleaned - self._deep.size
        t_s = first / self.fs_hz
        window = self._deep.array()
        looked, self._looked = self._looked, (window, first)
        a = self.cfg["acquisition"]
        for prn in sorted(self.present_prns - self.alarmed_prns - self.canceller.prns - set(self.awaiting)
                          - set(self.gave_up)):
            caf = cafs.get(prn)
            if caf is None or caf.best is None or auxiliary_peaks(caf, cafs, self.detector.cfg, self.fs_hz):
                continue
            grid = DopplerGrid(caf.best.doppler_hz, DEEP_SPAN_HZ, DEEP_STEP_HZ)
            deep = acquire(window, self.fs_hz, [prn], grid, self.if_hz, DEEP_COHERENT_MS, DEEP_NONCOHERENT,
                           a["pfa"], EXAMINE_MAX_PEAKS, excise=True, tail_threshold=True)[prn]
            beside = {**in_units_of(deep, cafs), prn: deep}
            pairs = auxiliary_peaks(deep, beside, self.detector.cfg, self.fs_hz, block_s=DEEP_CROSS_TALK_BLOCK_S) \
                or self._deep_fit(window, deep, beside)
            offsets = [chips_offset(p.auxiliary.code_phase_chips, p.main.code_phase_chips) for p in pairs]
            seen = [(t, o) for t, o in self._deep_seen.get(prn, []) if t_s - t <= DEEP_MEMORY_S]
            again = [p for p, o in zip(pairs, offsets) if any(abs(o - s) < TWIN_MATCH_CHIPS for _, s in seen)]
            self._deep_seen[prn] = seen + [(t_s, o) for o in offsets]
            if not again:
                continue
            pair = replace(again[0], source="deep")
            self._alarm(prn, t_s, pair.as_event())
            if self.d["mode"] == "full":
                self._on_alarm(Alarm(t_s, prn, pair, None), t_s)
        self._looked = looked

    def _deep_fit(self, window: np.ndarray, deep, beside: dict) -> list:
        """A twin too close under its spoofer's peak for the longer look's CAF to show it apart, from the two-path
        fit over that look's samples (GPS-SDR-SIM, path loss, +15 dB, 500 m: a twin 14.6 dB under its spoofer 1 chip
        off, under the fit's regular floor and at 1-3 detection thresholds in the CAF beside the spoofer's sidelobes,
        so that spoofer went through `clean` for the whole minute, 320 m off)."""
        cfg = self.detector.cfg
        main = deep.best
        if main is None or main.cn0_dbhz < DEEP_FIT_MIN_CN0_DBHZ or not examinable(main, deep, beside, cfg, self.fs_hz,
                                                                                    DEEP_CROSS_TALK_BLOCK_S):
            return []
        pair = hidden_pair(window, self.fs_hz, self.if_hz, main, cfg, deep=True)
        if pair is None or is_cross_talk(pair.auxiliary, deep, beside, cfg, self.fs_hz, block_s=TWO_PATH_BLOCK_S):
            return []
        return [pair]

    def _note_awaiting_pairs(self, cafs: dict, first: int) -> None:
        """Where the two peaks of each PRN awaiting a verdict are now (the receiver follows both until it comes)."""
        self.awaiting_pairs = {p: v for p, v in self.awaiting_pairs.items() if p in self.awaiting}
        for prn in self.awaiting:
            caf = cafs.get(prn)
            pairs = auxiliary_peaks(caf, cafs, self.detector.cfg, self.fs_hz) if caf is not None and caf.best else []
            if pairs:
                self.awaiting_pairs[prn] = (pairs[0].main, pairs[0].auxiliary, first)

    def _examinable_peaks(self, cafs: dict) -> dict:
        """PRN -> its strongest peak, for the PRNs whose peak is a signal of its own (strong enough, not cross-talk)."""
        return {p: c.best for p, c in cafs.items() if examinable(c.best, c, cafs, self.detector.cfg, self.fs_hz)}

    def _check_power(self, peaks: dict, t_s: float) -> None:
        """Peaks received stronger than any satellite's signal can be are the attacker's: alarm and cancel them
        (not a guess), so that the legitimate twins hidden in the attacker's interference surface in the cleaned
        samples the next looks search. peaks: the look's examinable peaks (_examinable_peaks)."""
        for prn, cn0_dbhz in implausible_peaks(peaks).items():
            if prn in self.detector.alarmed or prn in self.merged:   # merged: known, watched for the two to part
                continue
            self.detector.raise_alarm(prn, t_s)
            peak = peaks[prn]
            self._alarm(prn, t_s, {"found_by": "power", "thermal_cn0_dbhz": cn0_dbhz,
                                   "code_phase_chips": round(peak.code_phase_chips, 4),
                                   "doppler_hz": round(peak.doppler_hz, 1)})
            if self.d["mode"] == "full":
                self._start_cancelling(prn, t_s, Choice(peak, None, False, f"received at {cn0_dbhz} dB-Hz against the "
                                                        "thermal floor: stronger than any satellite's signal"),
                                       implausible=True)

    def beat_alarm(self, beats: dict[int, float], t_s: float) -> None:
        """Two carriers under the receiver's tracked peaks (beat): the attack is known, those PRNs are not resolved,
        and every PRN is examined at the highest sensitivity from now on, for the two peaks to part. The PRNs sharing
        one beat (beat.common_beat: a delay common to all, a time push) are merged with their twins, the others'
        spoofers move the position; a merged PRN whose beat leaves the common one is no longer merged. A few PRNs
        sharing a beat, before any alarm, wait up to COMMON_WAIT_S for the others to show it too."""
        common_hz, common = common_beat(beats, self.push_beat_hz)
        alike = max(beats.values()) - min(beats.values()) <= BIN_HZ
        if common_hz is None and self.alarm_t_s is None and alike:
            self._first_beat_s = t_s if self._first_beat_s is None else self._first_beat_s
            if t_s - self._first_beat_s < COMMON_WAIT_S:
                return
        if common_hz is not None and self.push_beat_hz is None:
            self._push_onset_s = t_s - BEAT_WINDOW_MS * 1e-3   # the beat filled the window it was found in
            self._emit("common_beat", t_s, beat_hz=round(common_hz, 1), prns=sorted(common),
                       push_ns_s=round(common_hz / L1_HZ * 1e9, 1))
        self.push_beat_hz = common_hz
        self._beat_seen_s.update(dict.fromkeys(common, t_s))
        for prn, f_hz in beats.items():
            if prn in self.alarmed_prns:
                if prn in self.merged and prn in common:
                    self._merged_by_beat.add(prn)   # merged already (on power): the push's beat says how far apart
                elif prn in self.merged and prn in self._merged_by_beat:
                    self._merged_by_beat.discard(prn)
                    self._alarm(prn, t_s, {"found_by": "beat", "beat_hz": round(f_hz, 1), "common": False})
                continue
            self.takeover = True
            self.detector.attack_known(t_s)
            self._alarm(prn, t_s, {"found_by": "beat", "beat_hz": round(f_hz, 1), "common": prn in common})
            if prn in common:
                self.detector.merge(prn)
                self._merged_by_beat.add(prn)

    def _held_by_beat(self, t_s: float) -> set[int]:
        """The PRNs merged with a time push's beat while the push has moved their spoofers less than the merged
        separation from their twins (its rate times the time since it began): the two-path fit this close says only
        its own minimum spacing, and a cancellation on it would take the twin apart."""
        if self._push_onset_s is None:
            return set()
        chips_per_s = self.push_beat_hz / L1_HZ * CA_CHIP_RATE_HZ
        if chips_per_s * (t_s - self._push_onset_s) >= self.detector.cfg.merged_separation_chips:
            return set()
        return self._merged_by_beat & self.merged

    def within_merged(self, prn: int, t_s: float) -> bool:
        """Whether a PRN's range is known to lie within the merged separation of its twin's: merged, and either
        watched by the fit (it alarms past that separation) or, held from it, still beating with the push (the
        beat gone, the separation is no longer known: the attacker may have stopped, or moves the code alone)."""
        return prn in self.merged and (prn not in self.detector.held
                                       or t_s - self._beat_seen_s.get(prn, -np.inf) <= BEAT_STALE_S)

    def ranges_disagree(self, t_s: float) -> None:
        """The receiver's ranges failed the integrity test beyond one faulty range, before any alarm: a sky that
        mixes an attacker's signals with legitimate ones is one (a spoofer on from power-on, its twins merged under
        its peaks, some channels on each: 5 of 8 ranges agreeing 186 m off). No PRN is named; the next looks, from
        now, examine every PRN at the highest sensitivity for SUSPECT_FOR_S (multipath alone is the other cause)."""
        if self.alarm_t_s is None and self._seen >= self._suspect_until:
            self._next_exam = min(self._next_exam, self._seen)
            self._emit("ranges_disagree", t_s, examine_for_s=SUSPECT_FOR_S)
        self._suspect_until = self._seen + int(SUSPECT_FOR_S * self.fs_hz)

    def clock_alarm(self, t_s: float, event: dict) -> None:
        """The receiver clock moved as its oscillator cannot (defense/clock_guard): every range delayed alike, a
        seamless takeover's time push. No PRN is named (the attack alarm, alarm_t_s, stays the peaks'): it is the
        evidence of a takeover, and every PRN is examined at the highest sensitivity for the peaks to part."""
        self.takeover = True
        self.detector.attack_known(t_s)
        self._emit("clock_alarm", t_s, **event)

    def _alarm(self, prn: int, t_s: float, event: dict) -> None:
        """An alarm on a PRN, whatever raised it (the event's fields say what)."""
        self.alarmed_prns.add(prn)
        self.detector.unmerge(prn)
        if self.alarm_t_s is None:
            self.alarm_t_s = t_s
        self._emit("spoofing_alarm", t_s, **{"prn": prn, **event})

    def _on_alarm(self, alarm: Alarm, t_s: float) -> None:
        """Cancel the attacker's peak; when that would be a guess and a maneuver is still to come, wait for it."""
        if alarm.prn in self._merged_by_beat and self.policy == "auto":
            # its twin parted under a time push: any one side on every PRN gives the true position, so the same
            # side on every PRN, whatever their powers
            choice = choose(alarm, "later")
        else:
            choice = choose(alarm, self.policy, self.policy_prns)
        if choice is not None and choice.guessed and self.attacker_stronger is not None:
            choice = by_power(alarm, self.attacker_stronger, self._inference)
        if choice is not None and choice.guessed and self.continuing is not None:
            pair = (alarm.pair.main, alarm.pair.auxiliary)
            legit = self.continuing(alarm.prn, self._looked[1], tuple(p.code_phase_chips for p in pair))
            if legit is not None:
                choice = Choice(pair[1 - legit], pair[legit], False, "the other peak continues the ranges of the last "
                                                                     "nominal fix (INS)")
        if choice is not None and choice.guessed and self.maneuver is not None and self.maneuver.pending(t_s):
            self.maneuver.request(t_s, alarm.prn)
            self.awaiting[alarm.prn] = alarm
            self._emit("identification_pending", t_s, prn=alarm.prn, maneuver_s=self.maneuver.window_s)
            return
        if choice is not None and not choice.guessed and alarm.newcomer_code_phase_chips is not None \
                and choice.legitimate is not None:
            self._newcomer_gaps_db[alarm.prn] = gap_db(choice.adversarial, choice.legitimate)
        elif choice is not None and choice.guessed and (stronger := power_relation(self._newcomer_gaps_db)) is not None:
            why = (f"inferred: on the {len(self._newcomer_gaps_db)} PRNs where the attacker's peak appeared after the "
                   f"receiver had the other, it was the {'stronger' if stronger else 'weaker'}")
            choice = by_power(alarm, stronger, why)
        self._start_cancelling(alarm.prn, t_s, choice)

    def _retry_maneuver(self, t_s: float) -> None:
        """Cancellations made on a guess after a failed maneuver: a fresh one is asked for, to judge them."""
        live = sorted(p for p in self.guessed if p in self.cancel_started)
        if live and self.maneuver.retry(t_s):
            self.maneuver.request(t_s, live[0])
            self._emit("maneuver_retry", t_s, attempt=self.maneuver.attempts, guessed=live)

    def _follow_through_maneuver(self, cafs: dict) -> None:
        """The maneuver begins: follow both peaks of every PRN awaiting a verdict, and every other PRN's peak."""
        peaks = {}
        for prn, caf in cafs.items():
            if caf.best is None or (prn not in self.awaiting and prn not in self.extra_prns):
                continue   # the receiver's own PRNs only: a strong attacker's cross-talk makes peaks on absent ones
            pairs = auxiliary_peaks(caf, cafs, self.detector.cfg, self.fs_hz) if prn in self.awaiting else []
            peaks[prn] = [pairs[0].main, pairs[0].auxiliary] if pairs else [caf.best]
        self.maneuver.start(peaks, self._seen - self.window, self._raw.array())
        self._emit("maneuver_follow", (self._seen - self.window) / self.fs_hz, followers=len(self.maneuver.followers))

    def _identify(self, t_s: float) -> None:
        """The maneuver is over: cancel each awaiting PRN's peak that did not follow the vehicle's motion. A PRN
        left undecided falls back on the policy's guess; a lone peak that did not follow the motion is the
        attacker's with no legitimate twin in sight: its PRN is kept out of the fixes."""
        ephemeris_of, fix = self.nav_context() if self.nav_context is not None else (None, None)
        ident = self.maneuver.identify(ephemeris_of, fix)
        self._emit("identification", t_s, verdicts=[
            {"prn": v.prn, "peak": v.peak_id, "adversarial": v.adversarial, "decided": v.decided,
             "score": round(v.score, 2), "reason": v.reason} for v in ident.verdicts])
        now = self._seen - self.window
        self._looked = (self._raw.array(), now)
        one_peak = {v.prn: v for v in ident.verdicts if v.decided and (v.prn, 1) not in ident.followers}
        judged_gaps_db = {}   # a judged guess's two peaks: which was the attacker's, and how much stronger
        for prn, v in one_peak.items():
            if prn in self.cancel_started:
                gap = self._guess_gaps_db.get(prn)
                right = self._judge_cancelled(prn, ident.followers[(prn, 0)], v.adversarial, t_s)
                if right is not None and gap is not None:
                    judged_gaps_db[prn] = gap if right else -gap
            elif prn not in self.awaiting and v.adversarial:
                self.gave_up[prn] = "identified as the attacker's (maneuver), no legitimate twin found"
            elif prn not in self.awaiting:
                self.maneuver_legit.add(prn)
        decided = {}   # PRN -> (attacker's follower, the other): one peak shown not to follow, its twin shown to
        flagged = {}   # also the PRNs where one peak was shown not to follow and the other was not flagged
        for prn in self.awaiting:
            verdict = {v.peak_id: v for v in ident.verdicts if v.prn == prn}
            if len(verdict) != 2:
                continue
            adv = [k for k, v in verdict.items() if v.decided and v.adversarial]
            if len(adv) != 1:
                continue
            pair = (ident.followers[(prn, adv[0])], ident.followers[(prn, 1 - adv[0])])
            flagged[prn] = pair
            if verdict[1 - adv[0]].decided:
                decided[prn] = pair
        # the followers' C/N0 over the whole maneuver, not one look's peak metrics, says which was the stronger; the
        # one-sided PRNs count too: a legitimate peak wrongly flagged would show the opposite sign and stop it. A PRN
        # followed on one peak (its twin merged under it) had the stronger one followed: its alarm's pair says by how
        # much
        gaps_db = {prn: adv.mean_cn0_dbhz() - legit.mean_cn0_dbhz() for prn, (adv, legit) in flagged.items()}
        for prn, v in one_peak.items():
            if prn in self.awaiting:
                pair = self.awaiting[prn].pair
                gap = abs(gap_db(pair.main, pair.auxiliary))
                gaps_db[prn] = gap if v.adversarial else -gap
        # guesses judged (a maneuver after a failed one): a wrong guess is swapped and its PRN alarmed afresh, where
        # the relation they show decides it (was: guessed wrong again, the fixes on the attacker's peaks to the end)
        gaps_db.update(judged_gaps_db)
        self._emit("attacker_power", t_s, gaps_db={prn: round(g, 1) for prn, g in gaps_db.items()})
        self.attacker_stronger = power_relation(gaps_db)
        if self.attacker_stronger is not None:
            self._inference = (f"inferred: on the {len(gaps_db)} PRNs the maneuver decided, the attacker's peak was "
                               f"the {'stronger' if self.attacker_stronger else 'weaker'}")
        for prn, alarm in list(self.awaiting.items()):
            del self.awaiting[prn]
            if prn in one_peak:
                choice = self._one_peak_choice(ident.followers[(prn, 0)].peak_at(now), one_peak[prn].adversarial)
            else:
                adv, legit, reason = self._verdict_pair(prn, decided, flagged, ident.followers)
                adv_now, legit_now = (adv.peak_at(now), legit.peak_at(now)) if adv is not None else (None, None)
                choice = Choice(adv_now, legit_now, False, reason) if None not in (adv_now, legit_now) else None
            if choice is not None:
                self._start_cancelling(prn, t_s, choice)
            else:   # examined afresh: its peaks have moved since the alarm
                self.alarmed_prns.discard(prn)
                self.detector.examine_afresh(prn)

    def _one_peak_choice(self, followed: Peak | None, adversarial: bool) -> Choice | None:
        """An awaiting PRN followed on one peak, its twin merged under it: the peak the maneuver decided is the
        stronger path, the other one is found by the two-path fit around it (when the followed one is the attacker's,
        by _start_cancelling, as for any spoofer hiding a twin)."""
        if followed is None:
            return None
        if adversarial:
            return Choice(followed, None, False, "maneuver: the peak followed does not follow the vehicle's motion "
                                                 "(its twin merged under it)")
        twin = self._hidden_twin(self._looked[0], followed)
        if twin is None:
            return None
        return Choice(replace(followed, code_phase_chips=twin), followed, False,
                      "maneuver: the peak followed follows the vehicle's motion; the attacker's is the other path "
                      "under it")

    def _judge_cancelled(self, prn: int, follower, adversarial: bool, t_s: float) -> bool | None:
        """A PRN cancelled on a guess before the maneuver, its raw peak followed through it: the verdict says whether
        the guess was right (the followed peak is the cancelled one and did not follow the vehicle, or is the
        other one and did). The two are compared at the cancelled track's latest code epoch: the canceller runs
        behind the raw stream, so the look's sample is not yet in its history. Nothing compared, nothing judged.
        Returns whether the guess was right (None: not judged)."""
        if prn not in self.guessed:
            return None
        # at its latest epoch, a track's code phase is 0 by definition
        followed = [follower.peak_at(tr.channel.latest_epoch_sample) for tr in self._tracks(prn) if tr.channel.ms > 1]
        at = [chips_apart(f.code_phase_chips, 0.0) < 0.5 for f in followed if f is not None]
        if at:
            self.identified(prn, any(at) == adversarial, t_s, "maneuver: the peak followed through it")
            return any(at) == adversarial
        return None

    def _verdict_pair(self, prn: int, decided: dict, flagged: dict, followers: dict):
        """(the attacker's follower, the legitimate one's, why) for an awaiting PRN at the verdict, or Nones: decided
        by the maneuver (both peaks, or the one shown not to follow), else by the power relation the maneuver
        established on the others -- at once, not at a later alarm, so that the receiver never waits for it."""
        if prn in decided:
            return (*decided[prn], "maneuver: the other peak follows the vehicle's motion, this one does not")
        if prn in flagged:
            return (*flagged[prn], "maneuver: this peak does not follow the vehicle's motion")
        pair = followers.get((prn, 0)), followers.get((prn, 1))
        if self.attacker_stronger is None or None in pair:
            return None, None, ""
        gap = pair[0].mean_cn0_dbhz() - pair[1].mean_cn0_dbhz()
        if not abs(gap) >= POWER_MARGIN_DB:   # NaN too: no power relation to apply
            return None, None, ""
        adv = 0 if (gap > 0) == self.attacker_stronger else 1
        return pair[adv], pair[1 - adv], self._inference

    def cancel_by_power(self, prn: int, adversarial: Peak, legitimate: Peak, t_s: float) -> None:
        """A PRN the verdict left to a fresh look, decided now by the power relation the maneuver established (the
        receiver's two channels on it say which peak is the stronger); the peaks' code phases hold at the latest
        look's first sample."""
        if self.attacker_stronger is None or prn in self.cancel_started or prn in self.gave_up or prn in self.awaiting:
            return
        self.alarmed_prns.add(prn)
        self.detector.raise_alarm(prn, t_s)   # the attack known already: the maneuver that decided it followed one
        self._start_cancelling(prn, t_s, Choice(adversarial, legitimate, False, self._inference))

    @property
    def merged(self) -> set[int]:
        """PRNs whose attacker's signal holds the legitimate one within it (aligned in code and carrier): left to the
        receiver, which tracks the two merged (the range within the detector's merged_separation_chips of the
        legitimate one until it alarms: fixes on it are recovering, never good). The detector keeps them, for its
        pairs not to alarm them until the two part; the guard changes them through detector.merge and unmerge."""
        return self.detector.merged

    @property
    def look_sample(self) -> int | None:
        """The absolute sample where the latest look's code phases hold (None before the first look)."""
        return None if self._looked is None else self._looked[1]

    def _start_cancelling(self, prn: int, t_s: float, choice: Choice | None, implausible: bool = False) -> None:
        """implausible: the attacker's peak received stronger than any satellite's (power.py), where a front end's
        rounding of its chips looks like a second path to the two-path fit (Canceller.cancel's defer_twin)."""
        if choice is None:
            return
        x, peak_sample = self._looked
        if sum(len(s.tracks) for s in self.canceller.stages) >= self.d["max_tracks"]:
            self._refuse(prn, "too many spoofed signals at once", choice.adversarial, peak_sample, t_s, REMOVED_SPOOFER)
            return
        peak = refine_peak(x[:self.window // 4], self.fs_hz, self.if_hz, choice.adversarial)
        if choice.legitimate is not None and chips_apart(peak.code_phase_chips, choice.legitimate.code_phase_chips) < \
                chips_apart(choice.adversarial.code_phase_chips, choice.legitimate.code_phase_chips) / 2:
            # the refinement slid onto the legitimate path (a weaker attacker's under it): its Doppler only
            peak = replace(peak, code_phase_chips=choice.adversarial.code_phase_chips)
        amplitude = caf_amplitude(x, self.fs_hz, self.if_hz, peak.prn, peak.code_phase_chips, peak.doppler_hz)
        legit = None if choice.legitimate is None else choice.legitimate.code_phase_chips
        hidden = None
        self._seen_apart.pop(prn, None)
        if legit is None or chips_apart(legit, peak.code_phase_chips) >= JOINT_WITHIN_CHIPS:
            hidden = self._hidden_twin(x, peak)
            if hidden is not None and legit is not None:
                self._seen_apart[prn] = chips_offset(legit, peak.code_phase_chips)
            legit = legit if hidden is None else hidden
        stage = self._stages(prn)
        if self.canceller.cancel(peak, peak_sample, stage, legit, defer_twin=implausible) is None:
            self._refuse(prn, f"still spoofed after {stage} SIC iterations", peak, peak_sample, t_s, REMOVED_SPOOFER)
            return
        self.cancel_started.setdefault(prn, t_s)
        if implausible:
            self._stronger_than_sky.add(prn)
        if choice.guessed:
            self.guessed.add(prn)
            if choice.legitimate is not None:
                self._guess_gaps_db[prn] = gap_db(choice.adversarial, choice.legitimate)
            if choice.legitimate is None or choice.adversarial.metric >= choice.legitimate.metric:
                self._assumed_stronger.add(prn)
        if choice.legitimate is None and not choice.guessed and stage == 0:
            self._blind.add(prn)
        self.pending_verify[prn] = (t_s + self.d["verify_after_s"], peak, stage)
        self._emit("cancellation_start", t_s, prn=prn, stage=stage, guessed=choice.guessed, reason=choice.reason,
                   adversarial_code_phase_chips=round(peak.code_phase_chips, 4),
                   adversarial_doppler_hz=round(peak.doppler_hz, 1), amplitude_estimate=amplitude,
                   legitimate_code_phase_chips=None if legit is None else round(legit, 4),
                   **({} if hidden is None else {"twin_found_by": "two_path"}))
        if self.on_cancel is not None:
            self.on_cancel(prn, peak, peak_sample)

    def _refuse(self, prn: int, reason: str, dominant: Peak, sample: int, t_s: float,
                removed_as: str = REMOVED_REMAINDER) -> None:
        """A PRN whose spoofer no stage may cancel (the bound on stages or on tracks) is given up; the plug-in filter
        takes out what still dominates it, so that a receiver behind it locks onto neither that nor an attacker's
        signal left whole (refused before any stage took it on). A removal is one track past max_tracks, at most one
        per PRN at a time: a spoofer left whole is the harm max_tracks must not buy."""
        self.gave_up[prn] = reason
        self._emit("cancellation_refused", t_s, prn=prn, reason=reason)
        if self.remove_given_up:
            self._remove(prn, dominant, sample, t_s, removed_as)

    def _stages(self, prn: int) -> int:
        """How many SIC stages cancel a PRN (the index of its next one)."""
        return sum(1 for s in self.canceller.stages if prn in s.tracks)

    def _hidden_twin(self, x: np.ndarray, peak: Peak) -> float | None:
        """The code phase of a second signal within JOINT_WITHIN_CHIPS under the attacker's peak (at x's first
        sample), found by the two-path fit, when the alarm's pair did not hold one so close: a strong spoofer hides a
        twin that near, and a peak further off that the CAF showed (a cross-talk or noise maximum, when the spoofer
        is only 500 m off) is no reason to cancel it alone -- its tracking, pulled by the twin's correlation, carves
        an echo into the twin that biases every receiver behind (GPS-SDR-SIM, 500 m, +10 dB: 37-62 m on one PRN)."""
        pair = hidden_pair(x, self.fs_hz, self.if_hz, peak, self.detector.cfg, sensitive=True)
        if pair is None:
            return None
        caf = self._last_cafs.get(peak.prn)
        if caf is not None and is_cross_talk(pair.auxiliary, caf, self._last_cafs, self.detector.cfg, self.fs_hz,
                                             block_s=TWO_PATH_BLOCK_S):
            return None
        twin = max((pair.main, pair.auxiliary), key=lambda p: chips_apart(p.code_phase_chips, peak.code_phase_chips))
        return twin.code_phase_chips if chips_apart(twin.code_phase_chips, peak.code_phase_chips) < JOINT_WITHIN_CHIPS \
            else None

    def _verify(self) -> None:
        """SIC: once a stage has settled, re-acquire its PRN on the cleaned signal. If the cancelled peak still
        dominates, cancel what is left of it in another stage; if another auxiliary peak remains (an attacker with
        several copies), cancel the one the policy names; else the PRN is clean. Bounded by max_iterations."""
        t_s = self._cleaned / self.fs_hz
        first = self._cleaned - self._clean.size          # absolute index of the cleaned window's first sample
        for prn, (when, peak, stage) in list(self.pending_verify.items()):
            if t_s < when or self._clean.size < self.window:
                continue
            del self.pending_verify[prn]
            # this PRN around the attacker's Doppler; the others as last examined, so that what is left can be told
            # from their cross-correlation
            cafs = dict(self._last_cafs)
            cafs.update(self._acquire(self._clean.array(), [prn], peak.doppler_hz, 2000.0))
            caf, target, reason = cafs[prn], None, ""
            # a peak of the field of near-threshold maxima that the cancelled strong signals' residues raise, or
            # cross-talk, is no signal of this PRN's left
            left = (caf.best is not None and caf.best.metric >= LEFT_MIN_THRESHOLDS * caf.threshold
                    and not is_cross_talk(caf.best, caf, cafs, self.detector.cfg, self.fs_hz))
            if not left and stage == 0 and prn in self._blind:
                self._left_merged(prn, t_s)
                continue
            if caf.best is not None and self._still_dominates(prn, caf.best.code_phase_chips, first):
                target, reason = caf.best, "the cancelled peak still dominates"
            elif caf.best is not None and self._at_twin(prn, caf.best.code_phase_chips, first):
                pass   # the legitimate twin dominates where the two-path tracker holds it: under a strong attacker
                       # the spoofers still to cancel raise peaks (their multiple-access interference) that the
                       # policy would pair with it, and 'the stronger is the attacker's' would then cancel the twin
            else:
                pairs = auxiliary_peaks(caf, cafs, self.detector.cfg, self.fs_hz)
                if pairs:
                    choice = choose(Alarm(t_s, prn, pairs[0], None), self.policy, self.policy_prns)
                    if choice is not None:
                        target, reason = choice.adversarial, "another auxiliary peak remains: " + choice.reason
                        if choice.guessed:
                            self.guessed.add(prn)
            apart = None if caf.best is None else self._from_spoofer(prn, caf.best.code_phase_chips, first)
            self._emit("sic_iteration", t_s, prn=prn, stage=stage, legitimate_dominates=target is None,
                       strongest_code_phase_chips=None if caf.best is None else round(caf.best.code_phase_chips, 4),
                       strongest_offset_chips=None if apart is None else round(apart, 3),
                       attenuation_db=self.canceller.report().get(prn), next=reason or None)
            if target is None:
                self.verified.add(prn)
                if left and apart is not None:
                    self._strongest_apart[prn] = apart
            elif self.canceller.cancel(target, first, stage + 1) is None:
                self._refuse(prn, f"{reason} after {stage + 1} SIC iterations (the bound)", target, first, t_s)
            else:
                self.pending_verify[prn] = (t_s + self.d["verify_after_s"], target, stage + 1)
        self._swap_weaker_replicas(first, t_s)
        if self.remove_given_up:
            self._remove_biased_twins(first, t_s)

    def _swap_weaker_replicas(self, sample: int, t_s: float) -> None:
        """A cancellation guessed on the stronger peak, or started on a peak stronger than any satellite's, whose
        first stage's settled joint track follows the weaker of the two (its twin ROLES_SWAPPED_DB stronger) is
        started again on its twin, the old replica's place its twin, and the later stages dropped with it: they were
        added because the spoofer still dominated (GPS-SDR-SIM behind 1 MHz, static, 500 m, +10 dB: PRN 7's stage 0 on
        the legitimate signal, stages 1 and 2 on the spoofer, the PRN then given up and its removal lost, the spoofer
        left in the output). Once a PRN, when its twin is judged and before."""
        stronger = (self._assumed_stronger & self.guessed) | self._stronger_than_sky
        for prn in sorted(stronger - self._roles_swapped - self._twin_judged - set(self.gave_up)):
            tr = self.canceller.stages[0].tracks.get(prn) if self.canceller.stages else None
            if tr is None:
                continue
            # judged once settled, the chips' shape known, before its twin is (_remove_biased_twins): before the
            # shape, a front end's rounding fitted on ideal chips' model passes for a twin as strong as its spoofer or
            # stronger (GPS-SDR-SIM behind 1 MHz, 3 km, +3 dB: four PRNs' replicas moved onto such phantoms in their
            # first second, two spoofers left in the output)
            if not tr.settled or len(tr.attenuation_db) < SWAPPED_AFTER_WINDOWS or not self.canceller.front_end.done:
                continue
            if tr.twin_advantage_db is None or tr.twin_advantage_db > -ROLES_SWAPPED_DB:
                continue
            twin = self._twin_peak(tr, sample)
            if twin is None:
                continue
            replica_chips = tr.channel.code_phase_at(sample)
            self._roles_swapped.add(prn)
            self.canceller.drop(prn)
            self.canceller.cancel(twin, sample, 0, replica_chips)
            self._emit("roles_swapped", t_s, prn=prn, twin_advantage_db=round(tr.twin_advantage_db, 1),
                       code_phase_chips=round(twin.code_phase_chips, 4),
                       reason="the replica followed the weaker of the two paths: started again on the stronger")

    def _remove_biased_twins(self, sample: int, t_s: float) -> None:
        """The plug-in filter's verified PRNs whose legitimate twin lies too close under a much stronger spoofer
        (canceller.biased_twin): a receiver behind it would take the twin's range biased by what is left of the
        spoofer, so the PRN is given up and the twin taken out too (the receiver does without the satellite).

        Judged once, when the PRN's tracks first have their estimates (settled, and JUDGED_AFTER_WINDOWS windows of
        their attenuation measured: at settling a twin's offset may still be 0.1 chip off, GPS-SDR-SIM +20 dB, -0.61
        for -0.48): a satellite taken away later, while a receiver behind tracks it, is the worse harm (GNSS-SDR
        kept a channel on what was left for seconds and put it in its fixes: flying GPS-SDR-SIM, 500 m, +10 and +15
        dB, twins drifting toward their spoofers given up 39 and 54 s in, 44 and 111 m off over the last 10 s)."""
        for prn in sorted(self.verified - self.removed - set(self.gave_up) - self._twin_judged):
            tracks = self._tracks(prn)
            if not tracks or not all(tr.settled and len(tr.attenuation_db) >= JUDGED_AFTER_WINDOWS for tr in tracks):
                continue
            self._twin_judged.add(prn)
            twin = self.close_twin(prn)
            if twin is None or not biased_twin(*twin):
                continue
            if self._rounding_twin(prn, twin[1], t_s):
                continue
            remainder = self._at_twin_of(prn, sample)
            if remainder is None:
                continue
            legitimate = self._legitimate_apart(prn)
            if legitimate is not None:
                self._remove(prn, remainder, sample, t_s, legitimate_offset_chips=legitimate)
                continue
            self._refuse(prn, f"its legitimate twin lies {abs(twin[1]):.2f} chip under a spoofer {twin[0]:.1f} dB "
                              "stronger: its range would stay biased", remainder, sample, t_s)

    def _from_spoofer(self, prn: int, code_phase_chips: float, sample: int) -> float | None:
        """How far a code phase at an absolute sample lies from the PRN's spoofer, as its first stage's track holds
        it (chips; None without one)."""
        tr = self.canceller.stages[0].tracks.get(prn) if self.canceller.stages else None
        spoofer = None if tr is None else tr.channel.code_phase_at(sample)
        return None if spoofer is None else chips_offset(code_phase_chips, spoofer)

    def _rounding_twin(self, prn: int, twin_chips: float, t_s: float) -> bool:
        """Whether a close twin is taken for a front end's rounding of the spoofer's own chips, not given up for: the
        chips found rounded, the PRN's alarm showed its legitimate peak apart (beyond JOINT_WITHIN_CHIPS) while the
        two-path fit, on ideal chips' model, found this one under the spoofer's peak, and the PRN's strongest peak on
        the cleaned signal is that one again (within SAME_PEAK_CHIPS), not the twin. A PRN has one legitimate signal;
        behind 1 MHz such a fit places the rounding 0.2-0.3 chip off (GPS-SDR-SIM, static, 3 km, +3 and +6 dB: PRN 14's
        legitimate signal 7.2 chips apart at 40 dB-Hz), and giving it up called the PRN removed while its legitimate
        signal, unbiased, stayed in the output (our receiver behind the filter: 0.06 m). An alarm's far peak alone is
        no proof: under a strong spoofer 500 m off it was a maximum of the noise or of cross-talk (36 dB-Hz, 144 and
        462 chips away, the twin 0.38 chip off)."""
        apart, strongest = self._seen_apart.get(prn), self._strongest_apart.get(prn)
        if apart is None or strongest is None or not self._chips_found_rounded() \
                or abs(strongest - apart) > SAME_PEAK_CHIPS:
            return False
        self._emit("twin_doubted", t_s, prn=prn, twin_offset_chips=round(float(twin_chips), 3),
                   legitimate_offset_chips=round(apart, 3),
                   reason="the close twin is taken for the front end's rounding of the spoofer's chips: the alarm "
                          "showed the legitimate signal apart")
        return True

    def _legitimate_apart(self, prn: int) -> float | None:
        """Where a PRN's legitimate signal lies from its spoofer (chips) when its close twin is no signal but the
        rounding of chips stronger than any satellite's: the chips found rounded, the spoofer cancelled on its power
        alone (no alarm's pair to show the legitimate peak), and the PRN's strongest peak on the cleaned signal beyond
        JOINT_WITHIN_CHIPS of it -- the twin is left in the cleaned signal, so a legitimate one that near would be the
        strongest. What the two-path fit followed there is what the shape's fit left of the spoofer (GPS-SDR-SIM behind
        1 MHz, static, 3 km, +15 dB: PRN 17's "twin" 0.59 chip and 25.5 dB under a 58 dB-Hz spoofer). It is taken out
        all the same, a signal a receiver could lock onto, but the PRN is not given up: called removed, its
        legitimate signal stayed in the output, unbiased (both receivers behind the filter: 0.24 m). None otherwise."""
        strongest = self._strongest_apart.get(prn)
        if prn not in self._stronger_than_sky or prn in self._seen_apart or strongest is None \
                or not self._chips_found_rounded() or abs(strongest) < JOINT_WITHIN_CHIPS:
            return None
        return strongest

    def _chips_found_rounded(self) -> bool:
        """Whether the chip-shape meter has measured the chips, and found them rounded by a front end."""
        meter = self.canceller.front_end
        return meter.done and not meter.shape.rectangular

    def _at_twin_of(self, prn: int, sample: int) -> Peak | None:
        """Where a PRN's legitimate twin is at an absolute sample, seen from the track that holds it against the
        strongest spoofer (close_twin's): another of its tracks may hold a twin that is no signal (a track whose
        'twin' took its spoofer's power, 12 dB over it: GPS-SDR-SIM behind 1 MHz, static, 500 m, +15 dB, PRN 1,
        whose removal went to the place of a spoofer a later stage had cancelled, lost its lock there and ended)."""
        tracks = [tr for tr in self._tracks(prn) if tr.twin_advantage_db is not None]
        if not tracks:
            return None
        return self._twin_peak(max(tracks, key=lambda t: t.twin_advantage_db), sample)

    @staticmethod
    def _twin_peak(tr, sample: int) -> Peak | None:
        """Where a joint track's legitimate twin is at an absolute sample."""
        spoofer_chips = tr.channel.code_phase_at(sample)
        if spoofer_chips is None:
            return None
        return Peak(tr.prn, float((spoofer_chips + tr.legit_offset_chips) % CA_CODE_LENGTH_CHIPS),
                    tr.channel.doppler_at(0), 0.0, 0.0)

    def _keep_removed(self, t_s: float) -> None:
        """A PRN taken out whose removal track lost what it followed (and ended) is taken out again, at its twin as
        the tracks hold it now, up to MAX_REMOVALS times; its output would hold the satellite again otherwise. Past
        that it is removed no more, and says so (`removal_failed`, the summary's gave_up): it was still listed as
        removed while the output held it (GPS-SDR-SIM behind 1 MHz, flying, 500 m, +10 dB, before Canceller.remove)."""
        for prn in sorted(self.removed | self.remnants):
            if self.canceller.removing(prn):
                continue
            if self._removals.get(prn, 0) >= MAX_REMOVALS:
                if prn in self.remnants:
                    self.remnants.discard(prn)
                    reason = "its spoofer's remnant could not be held: it stays in the output"
                else:
                    self.removed.discard(prn)
                    self.gave_up[prn] += "; its removal could not hold: what is left of it stays in the output"
                    reason = self.gave_up[prn]
                self._emit("removal_failed", t_s, prn=prn, removals=self._removals[prn], reason=reason)
                continue
            sample = self._cleaned - self._clean.size    # within every stage's history (the cleaned window's)
            remainder = self._at_twin_of(prn, sample)
            self._removals[prn] = self._removals.get(prn, 0) + 1
            placed = remainder is not None and self.canceller.remove(remainder, sample) is not None
            self._emit("removal_lost", t_s, prn=prn, restarted=placed,
                       code_phase_chips=None if remainder is None else round(remainder.code_phase_chips, 4))

    def _remove(self, prn: int, remainder: Peak, sample: int, t_s: float, reason: str = REMOVED_REMAINDER,
                legitimate_offset_chips: float | None = None) -> None:
        """A PRN given up whose remainder still dominates where its spoofer was: that remainder (the legitimate twin
        merged with what the stages left of the spoofer) is taken out too, so that a receiver behind the plug-in
        filter does without the satellite rather than take a biased range from it (Canceller.remove: where the
        removal goes, and which of the PRN's stages give way to it). Given the legitimate signal's offset, what is
        taken out is the spoofer's remnant alone, and the PRN is kept (`remnant_removed`: _legitimate_apart)."""
        if self.canceller.remove(remainder, sample) is None:
            return
        self._removals[prn] = 1
        if legitimate_offset_chips is None:
            self.removed.add(prn)
            self._emit("prn_removed", t_s, prn=prn, code_phase_chips=round(remainder.code_phase_chips, 4),
                       reason=reason)
        else:
            self.remnants.add(prn)
            self._emit("remnant_removed", t_s, prn=prn, code_phase_chips=round(remainder.code_phase_chips, 4),
                       legitimate_offset_chips=round(legitimate_offset_chips, 3), reason=REMOVED_REMNANT)

    def _left_merged(self, prn: int, t_s: float) -> None:
        """A cancellation on power alone left no signal at all: the legitimate one went with the attacker's, aligned
        within it. Cancelling it would leave the receiver without the satellite; the PRN stays alarmed, uncancelled,
        and is examined again at the highest sensitivity (two-path) for the two to part: its next alarm is decided
        like any other."""
        self._release(prn)
        del self.cancel_started[prn]
        self._blind.discard(prn)
        self.detector.merge(prn)
        self.detector.clear_alarm(prn)
        self._emit("cancellation_dropped", t_s, prn=prn, reason="nothing left after cancellation: the attacker's "
                   "signal carries the legitimate one, aligned")

    def _release(self, prn: int) -> None:
        self.canceller.drop(prn)
        if self.on_release is not None:   # the samples cleaned from now on (the canceller holds a code period back)
            self.on_release(prn, self._cleaned + int(self.fs_hz * RELEASE_MARGIN_S))

    def identified(self, prn: int, cancelled_is_attacker: bool, t_s: float,
                   reason: str = "continuity with the last nominal fix (INS)") -> None:
        """A test decided a guessed PRN: the cancelled peak was the attacker's (no longer a guess), or it was the
        legitimate one -- what the receiver tracks there is the attacker's: the cancellation is dropped and the PRN
        examined afresh (its next alarm is decided by the same test), given up after MAX_SWAPS."""
        if cancelled_is_attacker:
            self.guessed.discard(prn)
        elif self.swapped.get(prn, 0) >= MAX_SWAPS:
            self.gave_up[prn] = ("the cancelled peak continues the ranges of the last nominal fix: "
                                 "it is the legitimate one")
        else:
            self.swapped[prn] = self.swapped.get(prn, 0) + 1
            self._release(prn)
            self.guessed.discard(prn)
            self._forget(prn)
        then = "known" if cancelled_is_attacker else "given up" if prn in self.gave_up else "cancellation dropped"
        self._emit("identification", t_s, verdicts=[{"prn": prn, "adversarial": cancelled_is_attacker, "decided": True,
                                                     "reason": reason,
                                                     "then": then}])

    def resolved(self, prn: int) -> bool:
        """Whether a PRN is known to carry the legitimate signal only: alarmed, cancelled and verified clean with its
        cancellation still running, the cancelled peak known to be the attacker's (not assumed); or, never alarmed,
        examined at the highest sensitivity (after the attack became known) and found to hold a single signal in the
        last two looks."""
        if prn in self.gave_up or (prn in self.guessed and prn in self.cancel_started):
            return False
        if prn in self.alarmed_prns:
            return prn in self.verified and prn not in self.pending_verify
        single = self.detector.single_looks.get(prn, 0) >= 2 and prn not in self.detector.close
        # one signal is the legitimate one only if it was there before the attack, or the maneuver showed it follows
        # the vehicle: a spoofer on from power-on, its legitimate twin too weak to see, is one signal too; and after a
        # takeover, so are the two merged
        return single and (prn in self.maneuver_legit or (self.detector.predates_attack(prn) and not self.takeover))

    def suspect(self, prn: int) -> bool:
        """Whether a PRN's range may be the attacker's anywhere: neither resolved, nor under cancellation, nor found
        merged with its legitimate twin (its single peak may be a spoofer's whose twin is unseen)."""
        return not (self.resolved(prn) or prn in self.cancel_started or prn in self.merged)

    def close_twin(self, prn: int) -> tuple[float, float, float | None] | None:
        """(how much stronger than its legitimate twin the spoofer is in dB, the twin's offset in chips, the
        attenuation its cancellation achieved lately in dB or None) when the two lie within JOINT_WITHIN_CHIPS, from
        the strongest of the PRN's tracks; None when none is so close (canceller.biased_twin takes these)."""
        twins = [(tr.twin_advantage_db, tr.legit_offset_chips, tr.latest_attenuation_db) for tr in self._tracks(prn)
                 if tr.twin_advantage_db is not None]
        return max(twins, key=lambda t: t[0]) if twins else None

    def _forget_lost(self, t_s: float) -> None:
        """A PRN whose every cancellation track lost the spoofer is examined afresh: alarmed again if the spoofer is
        still there (its verification no longer holds)."""
        for prn in [p for p in self.cancel_started if p not in self.canceller.prns]:
            self._forget(prn)
            self._emit("cancellation_lost", t_s, prn=prn)

    def _forget(self, prn: int) -> None:
        del self.cancel_started[prn]
        self.verified.discard(prn)
        self.pending_verify.pop(prn, None)
        self.alarmed_prns.discard(prn)
        self.detector.clear_alarm(prn)

    def _still_dominates(self, prn: int, code_phase_chips: float, sample: int) -> bool:
        """Whether the strongest peak left at a code phase (at an absolute sample) is what remains of a cancelled
        spoofer: within 0.6 chip of it, and not the legitimate twin, known or surfacing. A twin found now within
        JOINT_WITHIN_CHIPS (a strong attacker's hid it until cancelled) is handed to the track: the two-path tracker
        follows both from then on."""
        for tr, spoofer_chips in self.spoofers_at(prn, sample):
            offset = chips_offset(code_phase_chips, spoofer_chips)
            if tr.legit_offset_chips is None and TWIN_MIN_CHIPS < abs(offset) < JOINT_WITHIN_CHIPS:
                tr.legit_offset_chips = offset
            twin = tr.legit_offset_chips
            if abs(offset) < 0.6 and (twin is None or abs(offset) <= abs(offset - twin)):
                return True
        return False

    def _at_twin(self, prn: int, code_phase_chips: float, sample: int) -> bool:
        """Whether a code phase (at an absolute sample) is where a cancelled spoofer's known legitimate twin is."""
        return any(tr.legit_offset_chips is not None and
                   abs(chips_offset(code_phase_chips, spoofer_chips) - tr.legit_offset_chips) < TWIN_MATCH_CHIPS
                   for tr, spoofer_chips in self.spoofers_at(prn, sample))

    def spoofers_at(self, prn: int, sample: float):
        """(track, the cancelled spoofer's code phase) at an absolute sample, for each of a PRN's tracks that
        holds it."""
        for tr in self._tracks(prn):
            spoofer_chips = tr.channel.code_phase_at(sample)
            if spoofer_chips is not None:
                yield tr, spoofer_chips

    def _tracks(self, prn: int) -> list:
        """A PRN's cancellation tracks, one for each SIC stage that holds it."""
        return [tr for st in self.canceller.stages if (tr := st.tracks.get(prn)) is not None]

    def account(self) -> str | None:
        """One line for the user on what the defence saw, None when it saw no attack."""
        if self.alarm_t_s is None and not self.takeover:
            return None
        prns = " ".join(map(str, sorted(self.alarmed_prns)))
        parts = [f"spoofing alarmed at t = {self.alarm_t_s:.1f} s on PRNs {prns}" if self.alarm_t_s is not None
                 else "the clock moved as no oscillator does (a time push)"]
        if self.push_beat_hz is not None:
            parts.append(f"a time push ({self.push_beat_hz / L1_HZ * 1e9:.0f} ns/s on every PRN alike): the position "
                         "holds, the time does not")
        if self.cancel_started:
            parts.append(f"cancelled {' '.join(map(str, sorted(self.cancel_started)))}"
                         + (f" ({len(self.guessed)} on a guess)" if self.guessed else ""))
        if self.gave_up:
            parts.append(f"given up {' '.join(map(str, sorted(self.gave_up)))}")
        return "; ".join(parts)

    def finish(self) -> None:
        """At the end of the stream: what the canceller achieved, and what was given up."""
        if self._pending is not None:
            self._apply_pending()
        t_s = self._seen / self.fs_hz
        self._emit("defense_summary", t_s, alarms=sorted(self.alarmed_prns), cancelled=sorted(self.cancel_started),
                   verified=sorted(self.verified), gave_up=self.gave_up, removed=sorted(self.removed),
                   remnants_removed=sorted(self.remnants),
                   attenuation_db=self.canceller.report(),
                   resolved=sorted(p for p in self.present_prns | self.extra_prns if self.resolved(p)),
                   guessed=sorted(self.guessed), merged=sorted(self.merged),
                   suspect_close=sorted(self.detector.close))
