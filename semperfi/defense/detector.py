"""Spoofing detection from auxiliary correlation peaks (the paper's detector, after SPREE).

Every acquisition is examined: for each PRN, a second peak above the detection threshold, more than a set
separation (500 ns by default) from the main one, and neither a sidelobe of the main peak's own code nor another
PRN's signal seen through cross-correlation, is an auxiliary peak. Two signals closer than a chip merge into one
CAF maximum, so the main peak is also tested for a second path underneath it (twopath). Peaks are followed from one
acquisition to the next, so a seamless takeover raises the alarm when the separation crosses the threshold.
"""

from dataclasses import dataclass, field

import numpy as np

from ..gps.constants import CA_CHIP_RATE_HZ, L1_HZ
from ..receiver.acquisition import Caf, Peak, is_cross_correlation
from .twopath import two_path_test


@dataclass(frozen=True)
class DetectorConfig:
    separation_s: float = 500e-9
    sidelobe_margin_db: float = 20.0      # C/A autocorrelation sidelobes lie 24 dB below the main peak
    cross_correlation_db: float = 10.0     # a peak this much weaker than another PRN at its Doppler (mod 1 kHz)
    confirmations: int = 2                # consecutive examinations that must see the pair
    two_path: bool = True
    two_path_pfa: float = 1e-4

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
                "separation_chips": round(self.separation_chips, 3), "separation_ns": round(self.separation_chips / CA_CHIP_RATE_HZ * 1e9, 1),
                "found_by": self.source}


def chips_apart(a: float, b: float) -> float:
    return abs((a - b + 511.5) % 1023 - 511.5)


def auxiliary_peaks(caf: Caf, cafs: dict[int, Caf], cfg: DetectorConfig) -> list[PeakPair]:
    """Auxiliary peaks in one PRN's CAF, judged against its main peak and the other PRNs' signals."""
    if caf.best is None:
        return []
    main = caf.best
    others = [(c.best.doppler_hz, c.best.cn0_dbhz) for p, c in cafs.items() if p != caf.prn and c.best is not None]
    floor_metric = main.metric * 10 ** (-cfg.sidelobe_margin_db / 10)
    pairs = []
    for p in caf.peaks[1:]:
        sep = chips_apart(p.code_phase_chips, main.code_phase_chips)
        if sep <= cfg.separation_chips or p.metric < floor_metric:
            continue
        if is_cross_correlation(p.doppler_hz, p.cn0_dbhz, others, cfg.cross_correlation_db):
            continue
        pairs.append(PeakPair(caf.prn, main, p, sep, "caf"))
    return pairs


def hidden_pair(samples: np.ndarray, fs_hz: float, if_hz: float, main: Peak, cfg: DetectorConfig) -> PeakPair | None:
    """A second signal under the main peak, more than the separation away (None when there is none)."""
    fit = two_path_test(samples, fs_hz, main.prn, main.code_phase_chips, main.doppler_hz, if_hz, pfa=cfg.two_path_pfa)
    if not fit.significant or fit.separation_chips <= cfg.separation_chips:
        return None
    # the two peaks' metrics, apportioned from the main peak's by the fitted power ratio
    ratio = 10 ** (fit.power_ratio_db / 10)
    strong = Peak(main.prn, fit.code_phase_chips, main.doppler_hz, main.metric / (1 + ratio),
                  main.cn0_dbhz - 10 * np.log10(1 + ratio))
    weak = Peak(main.prn, fit.second_code_phase_chips, main.doppler_hz, strong.metric * ratio,
                strong.cn0_dbhz + fit.power_ratio_db)
    return PeakPair(main.prn, strong, weak, fit.separation_chips, "two_path")


@dataclass
class _Track:
    code_phase_chips: float   # at t_s
    doppler_hz: float
    t_s: float
    first_seen_s: float


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
                best = _Track(p.code_phase_chips, p.doppler_hz, t_s, t_s)
                known.append(best)
            best.code_phase_chips, best.doppler_hz, best.t_s = p.code_phase_chips, p.doppler_hz, t_s
            matched.append(best)
        self.tracks[prn] = [tr for tr in known if tr in matched or t_s - tr.t_s < 10.0]
        return matched

    def examine(self, cafs: dict[int, Caf], t_s: float, samples: np.ndarray | None = None) -> list[Alarm]:
        """One acquisition's verdict: alarms for PRNs whose pair has now been seen cfg.confirmations times."""
        alarms = []
        for prn, caf in cafs.items():
            if caf.best is None:
                continue
            pairs = auxiliary_peaks(caf, cafs, self.cfg)
            if not pairs and self.cfg.two_path and samples is not None:
                hidden = hidden_pair(samples, self.fs_hz, self.if_hz, caf.best, self.cfg)
                pairs = [hidden] if hidden else []
            peaks = [caf.best] + [p.auxiliary for p in pairs]
            tracks = self._follow(prn, [pairs[0].main, pairs[0].auxiliary] if pairs else peaks[:1], t_s)
            if not pairs:
                self.streak[prn] = 0
                continue
            self.streak[prn] = self.streak.get(prn, 0) + 1
            if self.streak[prn] >= self.cfg.confirmations and prn not in self.alarmed:
                self.alarmed.add(prn)
                older = min(tracks, key=lambda tr: tr.first_seen_s)
                newer = max(tracks, key=lambda tr: tr.first_seen_s)
                newcomer = newer.code_phase_chips if newer.first_seen_s > older.first_seen_s else None
                alarms.append(Alarm(t_s, prn, pairs[0], newcomer))
        return alarms
