"""Spoofing detection from auxiliary correlation peaks (the paper's detector, after SPREE).

Every acquisition is examined: for each PRN, a second peak above the detection threshold, more than a set
separation (500 ns by default) from the main one, and neither a sidelobe of the main peak's own code nor another
PRN's signal seen through cross-correlation, is an auxiliary peak. Two signals closer than a chip merge into one
CAF maximum, so the main peak is also tested for a second path underneath it (twopath). Peaks are followed from one
acquisition to the next, so a seamless takeover raises the alarm when the separation crosses the threshold.
"""

import functools
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from ..gps import CA_CHIP_RATE_HZ, L1_HZ, ca_code, chips_apart
from ..receiver import Caf, Peak, run_each
from .twopath import float_code, two_path_test


@dataclass(frozen=True)
class DetectorConfig:
    separation_s: float = 500e-9
    sidelobe_margin_db: float = 20.0      # C/A autocorrelation sidelobes lie 24 dB below the main peak
    cross_correlation_metric: float = 16.0  # peaks stronger than this many detection thresholds are never cross-talk
    # Peaks weaker than this many detection thresholds are not examined: with many strong signals present, their
    # summed cross-correlations make a field of structured interference whose maxima sit just above a threshold
    # set for white noise. A legitimate signal at 40 dB-Hz or more, and any spoofer that matters, is stronger.
    min_peak_thresholds: float = 3.0
    confirmations: int = 2                # consecutive examinations that must see the pair
    two_path: bool = True
    two_path_pfa: float = 1e-4
    # Once the attack is known to be present (any PRN alarmed), every PRN is examined at the highest sensitivity: a
    # second signal closer than `separation_s` (down to what the two-path fit can resolve) is the attacker's until
    # it is resolved, found with a longer window and a laxer false-alarm rate (a false alarm now costs a
    # cancellation that verification undoes, a miss costs a spoofed range in a fix labelled recovered).
    sensitive_separation_chips: float = 0.2
    sensitive_two_path_pfa: float = 1e-3
    # A fitted second path weaker than this is not a signal of its own: at high C/N0 the one-path model's own
    # mismatch (the delay grid's step, the front end's filtering) is significant against the noise, and a second
    # path absorbs it. A spoofer that matters is at most ~10 dB weaker than the legitimate signal.
    two_path_min_ratio_db: float = -13.0
    # A PRN whose attacker was found aligned with its twin (merged) is alarmed again only once the two have parted
    # this far: closer, the fit's separation is its minimum spacing's (biased up from the true one), the canceller
    # cannot take the two apart, and what it leaves is further off than the merged peak was. Meanwhile the range is
    # within this of the twin's (the position of a time push, a common delay, not at all).
    merged_separation_chips: float = 0.5

    @property
    def separation_chips(self) -> float:
        return self.separation_s * CA_CHIP_RATE_HZ


@dataclass(frozen=True)
class PeakPair:
    """A PRN's main peak and an auxiliary one."""
    prn: int
    main: Peak
    auxiliary: Peak
    separation_chips: float
    source: str                           # caf | two_path

    def as_event(self) -> dict:
        def peak(p: Peak) -> dict:
            return {"code_phase_chips": round(p.code_phase_chips, 4), "doppler_hz": round(p.doppler_hz, 1),
                    "metric": round(p.metric, 2), "cn0_dbhz": round(p.cn0_dbhz, 1)}
        return {"prn": self.prn, "main": peak(self.main), "auxiliary": peak(self.auxiliary),
                "separation_chips": round(self.separation_chips, 3),
                "separation_ns": round(self.separation_chips / CA_CHIP_RATE_HZ * 1e9, 1),
                "found_by": self.source}


# A peak is cross-talk when the stronger signals' summed cross-talk is this share of its power or more: what is left
# is then no stronger than what is explained. Measured (tests/test_crosstalk_twopath.py, eight 55 dB-Hz signals
# beside a 45 dB-Hz PRN): cross-talk "paths" are explained for 0.7-1.1 of their fitted power, a real second signal
# 3 dB down for 0.1-0.4.
CROSS_TALK_SHARE = 0.5
# The two codes' cross-correlation is computed at no more than this rate (an integer fraction of the receiver's), its
# cost otherwise growing with the rate: a pair's power at 4-5 samples a chip differs from 40's by ~20 % (median over
# random pairs; their mean by 3 %), inside the share's margin above (0.7-1.1 against 0.1-0.4)
CROSS_TALK_MAX_RATE_HZ = 4 * CA_CHIP_RATE_HZ


def auxiliary_peaks(caf: Caf, cafs: dict[int, Caf], cfg: DetectorConfig, fs_hz: float,
                    block_s: float | None = None) -> list[PeakPair]:
    """Auxiliary peaks in one PRN's CAF, judged against its main peak and the other PRNs' signals (block_s: see
    is_cross_talk)."""
    if not examinable(caf.best, caf, cafs, cfg, fs_hz, block_s):
        return []
    main = caf.best
    floor_metric = main.metric * 10 ** (-cfg.sidelobe_margin_db / 10)
    pairs = []
    for p in caf.peaks[1:]:
        sep = chips_apart(p.code_phase_chips, main.code_phase_chips)
        if sep > cfg.separation_chips and p.metric >= floor_metric and examinable(p, caf, cafs, cfg, fs_hz, block_s):
            pairs.append(PeakPair(caf.prn, main, p, sep, "caf"))
    return pairs


def examinable(peak: Peak | None, caf: Caf, cafs: dict[int, Caf], cfg: DetectorConfig, fs_hz: float,
               block_s: float | None = None) -> bool:
    return (peak is not None and peak.metric >= cfg.min_peak_thresholds * caf.threshold
            and not is_cross_talk(peak, caf, cafs, cfg, fs_hz, block_s))


def is_cross_talk(peak: Peak, caf: Caf, cafs: dict[int, Caf], cfg: DetectorConfig, fs_hz: float,
                  block_s: float | None = None) -> bool:
    """Whether a peak is explained by another PRN's signal seen through the two codes' cross-correlation.

    The cross-correlation of two C/A codes at given code phases and Dopplers is deterministic: it is computed for
    each stronger signal present, their powers summed and compared with the peak's (a peak that they explain for
    CROSS_TALK_SHARE or more is cross-talk). Strong peaks are never cross-talk: cross-correlation lies 21 dB down or
    more.

    block_s: the correlation's coherent length when it is not the CAF's -- the two-path fit takes each 1 ms block's
    amplitude apart, so a stronger signal 100 Hz away, which a 40 ms coherent sum averages out, still leaks into
    every block of it: the cross-correlation's power is then the mean over blocks of this length. Also the bound for
    a long coherent CAF: a stronger signal's data bit flips inside its blocks undo the averaging out.
    """
    if peak.metric >= cfg.cross_correlation_metric * caf.threshold:
        return False
    fs_hz /= max(1, int(fs_hz // CROSS_TALK_MAX_RATE_HZ))
    n = int(round(fs_hz * caf.coherent_s))
    k = n if block_s is None else max(1, min(n, int(round(fs_hz * block_s))))
    leaked = 0.0    # the stronger signals' summed cross-talk (their phases are unrelated: powers add)
    for prn, other in cafs.items():
        b = other.best
        if prn == caf.prn or b is None or b.metric <= peak.metric:
            continue
        leaked += b.metric * cross_power(peak, b, fs_hz, n, k)
    return leaked >= peak.metric * CROSS_TALK_SHARE


@functools.lru_cache(maxsize=4096)
def cross_power(mine: Peak, other: Peak, fs_hz: float, n: int, k: int) -> float:
    """The mean over blocks of k samples (n // k of them) of |<mine's signal, other's signal>|^2 / k^2: how much of
    the other signal's power a correlation with mine's replica sees (cached: a look asks the same of its peaks for
    the guard's present PRNs, its screen, the power rule and the detector)."""
    return _cross_power_kernel(float_code(mine.prn), mine.code_phase_chips, _chips_per_sample(mine, fs_hz),
                               float_code(other.prn), other.code_phase_chips, _chips_per_sample(other, fs_hz),
                               2 * np.pi * (other.doppler_hz - mine.doppler_hz) / fs_hz, n - n % k, k)


def load_kernels(fs_hz: float) -> None:
    """The examinations' numba kernels loaded from numba's cache, on a tiny input: their first call costs 0.2-0.5 s
    each, which a defended start-up's first look would otherwise wait for (called beside it, on a thread aside)."""
    k = int(round(fs_hz * 1e-3))
    noise = np.random.default_rng(0).standard_normal(2 * k).astype(np.complex64)
    two_path_test(noise, fs_hz, 1, 0.0, 0.0, n_blocks=2)
    _cross_power_kernel(float_code(1), 0.0, 0.5, float_code(2), 0.0, 0.5, 0.1, 2 * k, k)


def cross_power_reference(mine: Peak, other: Peak, fs_hz: float, n: int, k: int) -> float:
    """The same with plain numpy (slow; for tests)."""
    n -= n % k
    t = np.arange(n) / fs_hz
    products = np.conj(_signal(mine, t)) * _signal(other, t)
    return float(np.mean(np.abs(np.sum(products.reshape(-1, k), axis=1) / k) ** 2))


def _chips_per_sample(p: Peak, fs_hz: float) -> float:
    return CA_CHIP_RATE_HZ * (1 + p.doppler_hz / L1_HZ) / fs_hz


def _signal(p: Peak, t_s: np.ndarray) -> np.ndarray:
    chips = np.floor(p.code_phase_chips + t_s * CA_CHIP_RATE_HZ * (1 + p.doppler_hz / L1_HZ)).astype(np.int64) % 1023
    return ca_code(p.prn)[chips] * np.exp(2j * np.pi * p.doppler_hz * t_s)


@njit(cache=True, nogil=True)
def _cross_power_kernel(code_a, chip0_a, rate_a, code_b, chip0_b, rate_b, dphase, n, k):
    """cross_power's sums: a block's magnitude does not depend on the carrier's phase at its start, so the difference
    carrier is a phasor turned sample by sample from 1 in each block (no exponential per sample)."""
    total = 0.0
    dc, ds = np.cos(dphase), np.sin(dphase)
    # whole code periods taken off the chip indices as they pass (a chip or less a sample), not a remainder each
    wrap_a = (np.int64(np.floor(chip0_a)) // 1023) * 1023
    wrap_b = (np.int64(np.floor(chip0_b)) // 1023) * 1023
    for b in range(n // k):
        re, im, c, s = 0.0, 0.0, 1.0, 0.0
        for t in range(b * k, (b + 1) * k):
            ia = np.int64(np.floor(chip0_a + t * rate_a)) - wrap_a
            while ia >= 1023:
                wrap_a += 1023
                ia -= 1023
            ib = np.int64(np.floor(chip0_b + t * rate_b)) - wrap_b
            while ib >= 1023:
                wrap_b += 1023
                ib -= 1023
            v = code_a[ia] * code_b[ib]
            re += v * c
            im += v * s
            c, s = c * dc - s * ds, c * ds + s * dc
        total += (re * re + im * im) / (k * k)
    return total / (n // k)


def in_units_of(caf: Caf, cafs: dict[int, Caf]) -> dict[int, Caf]:
    """The CAFs with their peaks' metrics as `caf`'s coherent length would see them: a signal's |R|^2 / sigma^2 grows
    with the coherent length, and cross-talk is judged by comparing metrics."""
    def scaled(other: Caf) -> Caf:
        k = caf.coherent_s / other.coherent_s
        return replace(other, peaks=tuple(replace(p, metric=p.metric * k) for p in other.peaks))
    return {prn: scaled(other) for prn, other in cafs.items()}


TWO_PATH_MARGIN_CHIPS = 0.1
TWO_PATH_BLOCK_S = 1e-3     # the two-path fit's blocks (twopath: one complex amplitude per code period)
# What a one-path model misses of a strong lone signal (its delay between the fit's grid points, a front end's
# filtering) a second path absorbs within 0.4 chip of it: measured on 50-56 dB-Hz lone signals over 100 ms, sampled
# rectangular chips and a 2 MHz front end alike, second paths 9-23 dB down at 0.2-0.4 chip, significant; none
# significant further out. A deep fit's second path from here on is a signal down to the sidelobe margin.
DEEP_TWO_PATH_MIN_CHIPS = 0.5


def hidden_pair(samples: np.ndarray, fs_hz: float, if_hz: float, main: Peak, cfg: DetectorConfig,
                sensitive: bool = False, deep: bool = False) -> PeakPair | None:
    """A second signal under the main peak, more than the separation away (None when there is none).

    deep: a long window's fit (a look under a known attack), where a second path further than
    DEEP_TWO_PATH_MIN_CHIPS from the main one counts down to the sidelobe margin rather than two_path_min_ratio_db."""
    n_blocks = int(samples.size // round(fs_hz * TWO_PATH_BLOCK_S))
    fit = two_path_test(samples, fs_hz, main.prn, main.code_phase_chips, main.doppler_hz, if_hz, n_blocks=n_blocks,
                        pfa=cfg.sensitive_two_path_pfa if sensitive or deep else cfg.two_path_pfa)
    # the fit's 0.05-chip delay grid and the noise can place a 500 ns echo a little further: a margin of
    # TWO_PATH_MARGIN_CHIPS keeps such an echo from the alarm until the attack is known
    separation = cfg.sensitive_separation_chips if sensitive else cfg.separation_chips + TWO_PATH_MARGIN_CHIPS
    floor_db = -cfg.sidelobe_margin_db if deep and fit.separation_chips >= DEEP_TWO_PATH_MIN_CHIPS \
        else cfg.two_path_min_ratio_db
    if not fit.significant or fit.separation_chips <= separation or fit.power_ratio_db < floor_db:
        return None
    # the two peaks' metrics, apportioned from the main peak's by the fitted power ratio
    ratio = 10 ** (fit.power_ratio_db / 10)
    strong = Peak(main.prn, fit.code_phase_chips, main.doppler_hz, main.metric / (1 + ratio),
                  main.cn0_dbhz - 10 * np.log10(1 + ratio))
    weak = Peak(main.prn, fit.second_code_phase_chips, main.doppler_hz, strong.metric * ratio,
                strong.cn0_dbhz + fit.power_ratio_db)
    return PeakPair(main.prn, strong, weak, fit.separation_chips, "two_path")


NEWCOMER_AFTER_S = 5.0
NEWCOMER_MAX_WEAKER_DB = 6.0   # a newcomer further below the incumbent is as likely a legitimate signal surfacing
# A peak first seen this close to the incumbent may have emerged from under it: in a seamless takeover the spoofer
# starts aligned with the legitimate signal, the receiver's lock follows the stronger of the two as they part, and
# the peak left behind -- the "newcomer" -- is the legitimate one.
NEWCOMER_MIN_GAP_CHIPS = 1.5


@dataclass
class _Track:
    code_phase_chips: float   # at t_s
    doppler_hz: float
    t_s: float
    first_seen_s: float
    looks: int = 0
    first_gap_chips: float = float("inf")   # how far from the PRN's other peak it was when first seen


@dataclass
class Alarm:
    t_s: float
    prn: int
    pair: PeakPair
    newcomer_code_phase_chips: float | None   # the peak that appeared later, when peaks were followed from before


@dataclass
class SpoofingDetector:
    """Examines acquisitions as they come and follows every PRN's peaks from one to the next."""
    fs_hz: float
    if_hz: float = 0.0
    cfg: DetectorConfig = field(default_factory=DetectorConfig)

    def __post_init__(self):
        self.tracks: dict[int, list[_Track]] = {}
        self.streak: dict[int, int] = {}
        self.alarmed: set[int] = set()
        self.merged: set[int] = set()            # PRNs whose attacker is aligned with the twin (the guard says: merge)
        # merged PRNs whose twin is known to lie closer than merged_separation_chips whatever the fit says (the
        # guard says: hold; a time push's beat gives their separation, the fit this close only its own minimum spacing)
        self.held: set[int] = set()
        self.first_alarm_s: float | None = None
        self.suspected = False                   # the guard's: the receiver's ranges disagree, no alarm yet
        self.single_looks: dict[int, int] = {}   # PRN -> consecutive sensitive looks that found one signal only
        self.close: dict[int, PeakPair] = {}     # PRN -> a second signal under its peak, closer than the separation

    def _follow(self, prn: int, peaks: list[Peak], t_s: float) -> list[_Track]:
        """Match peaks to the PRN's known tracks (code phase propagated with its Doppler), keep the new ones."""
        known = self.tracks.setdefault(prn, [])
        matched = []
        for p in peaks:
            best = None
            for tr in known:
                rate = CA_CHIP_RATE_HZ * tr.doppler_hz / L1_HZ   # code Doppler, chips/s beyond the nominal rate
                predicted = (tr.code_phase_chips + (t_s - tr.t_s) * (CA_CHIP_RATE_HZ + rate)) % 1023
                if chips_apart(predicted, p.code_phase_chips) < 0.5 and abs(tr.doppler_hz - p.doppler_hz) < 300:
                    best = tr
                    break
            if best is None:
                gap = min((chips_apart(p.code_phase_chips, q.code_phase_chips) for q in peaks if q is not p),
                          default=float("inf"))
                best = _Track(p.code_phase_chips, p.doppler_hz, t_s, t_s, first_gap_chips=gap)
                known.append(best)
            best.code_phase_chips, best.doppler_hz, best.t_s = p.code_phase_chips, p.doppler_hz, t_s
            best.looks += 1
            matched.append(best)
        self.tracks[prn] = [tr for tr in known if tr in matched or t_s - tr.t_s < 10.0]
        return matched

    def predates_attack(self, prn: int) -> bool:
        """Whether this PRN's peak, as last seen, is one the receiver had alone for a while before the first alarm:
        a single signal is then the legitimate one. With the attacker there from the first look, no peak is."""
        known = self.tracks.get(prn, [])
        if self.first_alarm_s is None or not known:
            return False
        latest = max(tr.t_s for tr in known)
        return any(tr.t_s == latest and self.first_alarm_s - tr.first_seen_s >= NEWCOMER_AFTER_S for tr in known)

    @property
    def sensitive(self) -> bool:
        """The attack is known to be present, or suspected: every PRN is examined at the highest sensitivity."""
        return self.first_alarm_s is not None or self.suspected

    def pending(self) -> bool:
        """Whether a pair has been seen that is still to be confirmed (an alarmed PRN's was)."""
        return any(n for prn, n in self.streak.items() if prn not in self.alarmed)

    # What the guard tells the detector: its sets change only through these.

    def attack_known(self, t_s: float) -> None:
        """The attack is known from t_s (the first such time is kept), by an alarm or by what the guard saw (a beat,
        the clock): every PRN is examined at the highest sensitivity."""
        if self.first_alarm_s is None:
            self.first_alarm_s = t_s

    def raise_alarm(self, prn: int, t_s: float) -> None:
        """A PRN alarmed by another test (the attacker's power): not examined for pairs while under cancellation."""
        self.alarmed.add(prn)
        self.attack_known(t_s)

    def clear_alarm(self, prn: int) -> None:
        """A PRN examined for pairs again (its cancellation dropped or lost): the streak it had is kept, so the pair
        seen again at the next look alarms at once."""
        self.alarmed.discard(prn)

    def examine_afresh(self, prn: int) -> None:
        """A PRN examined for pairs again whose peaks have moved since its alarm: its pair is confirmed anew."""
        self.alarmed.discard(prn)
        self.streak[prn] = 0

    def merge(self, prn: int) -> None:
        """The PRN's attacker is aligned with its twin: no pair alarms it until the two have parted by
        cfg.merged_separation_chips."""
        self.merged.add(prn)

    def unmerge(self, prn: int) -> None:
        """The PRN has alarmed: its pairs are judged like any other's."""
        self.merged.discard(prn)

    def hold(self, prns: set[int]) -> None:
        """The merged PRNs whose twin lies closer than the merged separation whatever the fit says, from this look
        on: no pair alarms them."""
        self.held = set(prns)

    def _pairs_of(self, cafs: dict[int, Caf], alarmed) -> dict[int, list[PeakPair] | None]:
        """Each PRN examined (not alarmed: under cancellation, the canceller's verification follows it): its CAF's
        pairs, None when it cannot be examined (too weak, or explained as cross-talk)."""
        return {prn: auxiliary_peaks(caf, cafs, self.cfg, self.fs_hz)
                if examinable(caf.best, caf, cafs, self.cfg, self.fs_hz) else None
                for prn, caf in cafs.items() if prn not in alarmed}

    @staticmethod
    def _fit_key(main: Peak, sensitive: bool, samples: np.ndarray) -> tuple:
        return main, sensitive, samples.size, samples.__array_interface__["data"][0]

    def fits(self, cafs: dict[int, Caf], samples: np.ndarray, sensitive: bool, alarmed) -> dict:
        """The two-path fits examine() will want of these CAFs (the PRNs showing one peak), computed ahead of it, on
        another thread: they read nothing of the detector but what is passed (alarmed: its alarmed PRNs then)."""
        if not self.cfg.two_path:
            return {}
        to_fit = [p for p, pairs in self._pairs_of(cafs, alarmed).items() if pairs == []]
        return dict(zip((self._fit_key(cafs[p].best, sensitive, samples) for p in to_fit), run_each(
            lambda p: hidden_pair(samples, self.fs_hz, self.if_hz, cafs[p].best, self.cfg, sensitive), to_fit)))

    def examine(self, cafs: dict[int, Caf], t_s: float, samples: np.ndarray | None = None,
                fits: dict | None = None) -> list[Alarm]:
        """One acquisition's verdict: alarms for PRNs whose pair has now been seen cfg.confirmations times (fits:
        two-path fits computed ahead, self.fits; those it lacks are fitted here).

        A PRN that cannot be examined (too weak, or explained as cross-talk) counts as not examined: its single-look
        streak starts again."""
        alarms = []
        sensitive = self.sensitive
        pairs_of = {}   # the PRNs examined: their CAF's pairs
        for prn, pairs in self._pairs_of(cafs, self.alarmed).items():
            if pairs is None:
                self.single_looks[prn] = 0
            else:
                pairs_of[prn] = pairs
        # the two-path fits of the PRNs showing one peak, on every core (each fit is the same on any thread)
        to_fit = [p for p, pairs in pairs_of.items() if not pairs] if self.cfg.two_path and samples is not None else []
        ahead = fits or {}

        def fit(p: int) -> PeakPair | None:
            key = self._fit_key(cafs[p].best, sensitive, samples)
            return ahead[key] if key in ahead else hidden_pair(samples, self.fs_hz, self.if_hz, cafs[p].best,
                                                               self.cfg, sensitive)
        fits = dict(zip(to_fit, run_each(fit, to_fit)))
        for prn, pairs in pairs_of.items():
            caf = cafs[prn]
            if prn in fits:
                hidden = fits[prn]
                # the fit takes each 1 ms block apart: a stronger PRN's cross-talk into the blocks is a second path
                # to it (seen on GPS-SDR-SIM: 42 dB-Hz PRNs beside 60 dB-Hz spoofers, a "path" 12 dB down)
                pairs = [hidden] if hidden and not is_cross_talk(hidden.auxiliary, caf, cafs, self.cfg, self.fs_hz,
                                                                 block_s=TWO_PATH_BLOCK_S) else []
            if prn in self.merged and pairs and (pairs[0].separation_chips < self.cfg.merged_separation_chips
                                                 or prn in self.held):
                pairs = []
            peaks = [caf.best] + [p.auxiliary for p in pairs]
            tracks = self._follow(prn, [pairs[0].main, pairs[0].auxiliary] if pairs else peaks[:1], t_s)
            if not pairs:
                self.streak[prn] = 0
                self.close.pop(prn, None)
                self.single_looks[prn] = self.single_looks.get(prn, 0) + 1 if sensitive and samples is not None else 0
                continue
            self.single_looks[prn] = 0
            if pairs[0].separation_chips <= self.cfg.separation_chips:
                # a second signal closer than the alarm's separation, seen once the attack is known: the attacker's
                # until resolved (the canceller estimates both signals jointly)
                self.close[prn] = pairs[0]
            else:
                self.close.pop(prn, None)
            self.streak[prn] = self.streak.get(prn, 0) + 1
            if self.streak[prn] >= self.cfg.confirmations and prn not in self.alarmed:
                older = min(tracks, key=lambda tr: tr.first_seen_s)
                newer = max(tracks, key=lambda tr: tr.first_seen_s)
                # A newcomer only when the other peak had been there alone for a while (NEWCOMER_AFTER_S, three
                # looks or more) and this one is new: a weak legitimate peak that comes and goes under a strong
                # spoofer must not pass for one.
                # And only when the attack began after that: once any PRN has raised the alarm near the start, a
                # peak found later is more likely a legitimate signal surfacing than a new spoofer.
                first_alarm = self.first_alarm_s if self.first_alarm_s is not None else t_s
                settled = (first_alarm - older.first_seen_s >= NEWCOMER_AFTER_S and older.looks - newer.looks >= 3
                           and newer.first_gap_chips >= NEWCOMER_MIN_GAP_CHIPS)
                # And not when the newcomer is far weaker than the incumbent: a legitimate signal surfacing from under
                # a strong spoofer that was there from power-on looks exactly like that (seen on GPS-SDR-SIM: +10 dB
                # from the first sample, the legitimate twins found 7 s later, cancelled as newcomers).
                pair = pairs[0]
                new_peak, old_peak = sorted((pair.main, pair.auxiliary), key=lambda p: chips_apart(
                    p.code_phase_chips, newer.code_phase_chips))
                weaker_db = 10 * np.log10(max(old_peak.metric, 1e-9) / max(new_peak.metric, 1e-9))
                newcomer = newer.code_phase_chips if settled and weaker_db <= NEWCOMER_MAX_WEAKER_DB else None
                alarms.append(Alarm(t_s, prn, pairs[0], newcomer))
                self.raise_alarm(prn, t_s)
        return alarms
