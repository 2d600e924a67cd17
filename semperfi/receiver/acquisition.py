"""Parallel code phase search (PCPS): the whole cross-ambiguity function of each PRN, and every peak in it.

The defence looks past the strongest peak, so acquisition keeps the full CAF and reports all local maxima above a
threshold set from a stated false-alarm probability.
"""

from dataclasses import dataclass
from typing import Iterable

import numpy as np
import scipy.fft
from scipy import stats

from ..gps.codes import ca_code
from ..gps.constants import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, CA_CODE_PERIOD_S


@dataclass(frozen=True)
class DopplerGrid:
    center_hz: float = 0.0
    max_hz: float = 5000.0
    step_hz: float = 250.0

    def values_hz(self) -> np.ndarray:
        n = int(np.floor(self.max_hz / self.step_hz + 1e-9))
        return self.center_hz + self.step_hz * np.arange(-n, n + 1)


@dataclass(frozen=True)
class Peak:
    """One local maximum of a PRN's cross-ambiguity function."""
    prn: int
    code_phase_chips: float   # chip of the code at the first sample, sub-sample interpolated
    doppler_hz: float         # interpolated between grid bins
    metric: float             # peak power over the noise floor (|R|^2 / sigma^2)
    cn0_dbhz: float


@dataclass(frozen=True)
class Caf:
    """|R|^2 over Doppler (rows) and code phase (columns, one per sample of a code period), noise normalised."""
    prn: int
    doppler_hz: np.ndarray
    code_phase_chips: np.ndarray
    power: np.ndarray         # mean over non-coherent sums of |R|^2 / sigma^2
    threshold: float          # detection threshold on power
    coherent_s: float
    peaks: tuple[Peak, ...]

    @property
    def best(self) -> Peak | None:
        return self.peaks[0] if self.peaks else None

    @property
    def peak_ratio(self) -> float:
        """Strongest peak over the CAF's noise floor outside it (the classic acquisition metric)."""
        return self.peaks[0].metric / float(np.mean(self.power)) if self.peaks else 0.0


def is_cross_correlation(doppler_hz: float, cn0_dbhz: float, stronger: Iterable[tuple[float, float]],
                         margin_db: float, tolerance_hz: float = 200.0) -> bool:
    """Whether a peak is another PRN's signal seen through the codes' cross-correlation.

    C/A cross-correlation is coherent when two Dopplers differ by a multiple of 1 kHz and lies 21 dB or more below
    the stronger signal; stronger holds the (Doppler, C/N0) of the other signals present.
    """
    return any(cn0 - cn0_dbhz > margin_db and abs((dop - doppler_hz + 500.0) % 1000.0 - 500.0) < tolerance_hz
               for dop, cn0 in stronger)


def _local_replica_fft(prn: int, n: int, fs_hz: float) -> np.ndarray:
    chips = np.floor(np.arange(n) * CA_CHIP_RATE_HZ / fs_hz).astype(np.int64) % CA_CODE_LENGTH_CHIPS
    return scipy.fft.fft(ca_code(prn)[chips].astype(np.complex64))


def _threshold(pfa: float, n_cells: int, n_noncoherent: int) -> float:
    """Threshold on mean |R|^2/sigma^2 over K looks so that the whole search has false-alarm probability pfa."""
    pfa_cell = -np.expm1(np.log1p(-pfa) / n_cells)
    return float(stats.chi2.isf(pfa_cell, 2 * n_noncoherent) / (2 * n_noncoherent))


def _interp(y_minus: float, y0: float, y_plus: float) -> float:
    """Offset in bins of a parabola's vertex through three points."""
    den = y_minus - 2 * y0 + y_plus
    return 0.0 if den >= 0 else float(np.clip(0.5 * (y_minus - y_plus) / den, -0.5, 0.5))


def find_peaks(power: np.ndarray, threshold: float, max_peaks: int) -> list[tuple[int, int]]:
    """Local maxima (3x3, circular in code phase) above threshold, strongest first."""
    padded = np.pad(power, ((1, 1), (0, 0)), constant_values=-np.inf)
    is_max = power >= threshold
    for dd in (-1, 0, 1):
        shifted_d = padded[1 + dd: padded.shape[0] - 1 + dd]
        for dc in (-1, 0, 1):
            if dd or dc:
                is_max &= power >= np.roll(shifted_d, dc, axis=1)
    rows, cols = np.nonzero(is_max)
    order = np.argsort(-power[rows, cols], kind="stable")[:max_peaks]
    return [(int(rows[i]), int(cols[i])) for i in order]


def acquire(samples: np.ndarray, fs_hz: float, prns: Iterable[int], grid: DopplerGrid = DopplerGrid(),
            if_hz: float = 0.0, coherent_ms: int = 1, noncoherent: int = 1, pfa: float = 1e-3,
            max_peaks: int = 8) -> dict[int, Caf]:
    """Search each PRN over the Doppler grid and every code phase.

    Uses coherent_ms * noncoherent ms of samples from the start. The noise floor sigma^2 is taken from the CAF's
    median, robust to the few cells that hold signal.
    """
    if not 1 <= coherent_ms <= 20 or noncoherent < 1:
        raise ValueError("acquisition wants 1-20 ms coherent and at least one non-coherent sum")
    n_ms = int(round(fs_hz * CA_CODE_PERIOD_S))
    need = n_ms * coherent_ms * noncoherent
    if samples.size < need:
        raise ValueError(f"acquisition needs {need} samples ({coherent_ms * noncoherent} ms), got {samples.size}")
    x = np.asarray(samples[:need], dtype=np.complex64)
    t = np.arange(need) / fs_hz
    dopplers = grid.values_hz()
    code_chips = np.arange(n_ms) * CA_CHIP_RATE_HZ / fs_hz
    thr = _threshold(pfa, dopplers.size * n_ms, noncoherent)
    chi_median = stats.chi2.median(2 * noncoherent) / (2 * noncoherent)
    # The Doppler wipe-off is shared by all PRNs: FFT each 1 ms block once per Doppler bin.
    spectra = np.empty((dopplers.size, coherent_ms * noncoherent, n_ms), dtype=np.complex64)
    for i, f in enumerate(dopplers):
        wiped = x * np.exp(-2j * np.pi * (f + if_hz) * t).astype(np.complex64)
        spectra[i] = scipy.fft.fft(wiped.reshape(-1, n_ms), axis=1)
    result = {}
    for prn in prns:
        replica = _local_replica_fft(prn, n_ms, fs_hz)
        r = scipy.fft.ifft(np.conj(spectra) * replica, axis=2)
        coh = r.reshape(dopplers.size, noncoherent, coherent_ms, n_ms).sum(axis=2)
        raw = np.mean(np.abs(coh) ** 2, axis=1)
        sigma2 = float(np.median(raw)) / chi_median
        power = (raw / sigma2).astype(np.float32)
        peaks = []
        for row, col in find_peaks(power, thr, max_peaks):
            dc = _interp(np.sqrt(power[row, col - 1]), np.sqrt(power[row, col]), np.sqrt(power[row, (col + 1) % n_ms]))
            dd = 0.0
            if 0 < row < dopplers.size - 1:
                dd = _interp(power[row - 1, col], power[row, col], power[row + 1, col])
            snr = max(float(power[row, col]) - 1.0, 1e-3)
            peaks.append(Peak(prn, float((col + dc) * CA_CHIP_RATE_HZ / fs_hz % CA_CODE_LENGTH_CHIPS),
                              float(dopplers[row] + dd * grid.step_hz), float(power[row, col]),
                              float(10 * np.log10(snr / (coherent_ms * CA_CODE_PERIOD_S)))))
        result[prn] = Caf(prn, dopplers, code_chips, power, thr, coherent_ms * CA_CODE_PERIOD_S, tuple(peaks))
    return result
