"""Parallel code phase search (PCPS): the whole cross-ambiguity function of each PRN, and every peak in it.

The defence looks past the strongest peak, so acquisition keeps the full CAF and reports all local maxima above a
threshold set from a stated false-alarm probability.
"""

import functools
from dataclasses import dataclass
from typing import Iterable

import numpy as np
import scipy.fft
from numba import njit

from ..gps import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, CA_CODE_PERIOD_S, L1_HZ, UNUSED_G2_DELAYS, ca_code, gold_code
from .chisquare import chi2_isf, chi2_median
from .interference import NONE, Interference, excise_narrowband
from .workers import cores, run_each, scratch


@dataclass(frozen=True)
class DopplerGrid:
    center_hz: float = 0.0
    max_hz: float = 5000.0
    step_hz: float = 250.0

    @classmethod
    def for_coherent(cls, coherent_ms: int, max_hz: float, step_hz: float = 0.0, center_hz: float = 0.0
                     ) -> "DopplerGrid":
        """The grid for a coherent integration: step_hz 0 means two thirds of 1 / coherent time (a signal between
        two bins loses under 1.7 dB)."""
        return cls(center_hz, max_hz, step_hz or 2.0 / 3.0 / (coherent_ms * 1e-3))

    def values_hz(self) -> np.ndarray:
        n = int(np.floor(self.max_hz / self.step_hz + 1e-9))
        return self.center_hz + self.step_hz * np.arange(-n, n + 1)

    def khz_periodic(self) -> "DopplerGrid":
        """The same grid with its step nudged (by under 2 %) to divide 1 kHz, when that is possible: its bins then
        repeat their offsets modulo 1 kHz, which lets acquisition share one FFT among them (333 Hz -> 1/3 kHz)."""
        per_khz = round(1e3 / self.step_hz)
        step = 1e3 / per_khz if per_khz >= 1 else self.step_hz
        if abs(step - self.step_hz) > 0.02 * self.step_hz:
            return self
        return DopplerGrid(self.center_hz, self.max_hz * step / self.step_hz, step)


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
    power: np.ndarray | None  # mean over non-coherent sums of |R|^2 / sigma^2; None where nothing was detected (or
                              # not asked for)
    threshold: float          # detection threshold on power
    coherent_s: float
    peaks: tuple[Peak, ...]
    second_peak_ratio: float = 0.0   # best peak over the highest cell away from its code phase (1.5 chips)
    interference: Interference = NONE   # what the search block held besides noise and GPS (excised when asked)
    mean_power: float = 1.0          # the CAF's mean (its noise floor, about 1)

    @property
    def best(self) -> Peak | None:
        return self.peaks[0] if self.peaks else None

    @property
    def peak_ratio(self) -> float:
        """Strongest peak over the CAF's noise floor outside it (the classic acquisition metric)."""
        return self.peaks[0].metric / self.mean_power if self.peaks else 0.0


def is_cross_correlation(doppler_hz: float, cn0_dbhz: float, stronger: Iterable[tuple[float, float]],
                         margin_db: float, tolerance_hz: float = 200.0) -> bool:
    """Whether a peak is another PRN's signal seen through the codes' cross-correlation.

    C/A cross-correlation is coherent when two Dopplers differ by a multiple of 1 kHz and lies 21 dB or more below
    the stronger signal; stronger holds the (Doppler, C/N0) of the other signals present.
    """
    return any(cn0 - cn0_dbhz > margin_db and abs((dop - doppler_hz + 500.0) % 1000.0 - 500.0) < tolerance_hz
               for dop, cn0 in stronger)


MAX_CAF_COLUMNS = 4096    # code phases per CAF row: above 4.096 MSa/s the spectra keep the central 4.096 MHz


def caf_columns(n_ms: int, most: int = MAX_CAF_COLUMNS) -> int:
    """Code phases per ms the CAF resolves: every sample up to `most`, then a band-limited correlation (the C/A
    code's power beyond +-2 MHz is under 5 %: a loss of 0.1 dB for a CAF 2.5x cheaper at 10 MSa/s)."""
    return min(n_ms, most)


def _kept_bins(n_ms: int, most: int = MAX_CAF_COLUMNS) -> np.ndarray:
    """FFT bins (of a 1 ms block, 1 kHz apart) inside the CAF's band, in inverse-FFT order."""
    n_cols = caf_columns(n_ms, most)
    half = n_cols // 2
    return np.r_[0:n_cols - half, n_ms - half:n_ms]


# Codes no satellite transmits (keys below 1): their CAFs hold everything in a block that is not a satellite.
REFERENCE_KEYS = tuple(-i for i in range(1, len(UNUSED_G2_DELAYS) + 1))


def _code(key: int) -> np.ndarray:
    return ca_code(key) if key > 0 else gold_code(UNUSED_G2_DELAYS[-key - 1])


@functools.lru_cache(maxsize=64)
def _local_replica_fft(key: int, n: int, fs_hz: float, most: int = MAX_CAF_COLUMNS) -> np.ndarray:
    """The sampled code's spectrum in the CAF's band (cached: every look of every examination asks for the same);
    key is a PRN, or one of REFERENCE_KEYS."""
    chips = np.floor(np.arange(n) * CA_CHIP_RATE_HZ / fs_hz).astype(np.int64) % CA_CODE_LENGTH_CHIPS
    spectrum = scipy.fft.fft(_code(key)[chips].astype(np.complex64))[_kept_bins(n, most)]
    spectrum.flags.writeable = False
    return spectrum


def _whole_ms(fs_hz: float, n_ms: int) -> bool:
    """Whether a block of n_ms samples is exactly one code period (then Dopplers k kHz apart share FFTs)."""
    return abs(fs_hz * CA_CODE_PERIOD_S - n_ms) < 1e-9 * n_ms


def _wiped_spectra(x: np.ndarray, fs_hz: float, if_hz: float, dopplers: np.ndarray, n_ms: int, coherent_ms: int,
                   noncoherent: int, most: int = MAX_CAF_COLUMNS) -> np.ndarray:
    """conj(spectrum) of each coherent sum of 1 ms blocks after each Doppler's wipe-off: (Doppler, look, bin).

    When a block is exactly 1 ms of samples, a Doppler k kHz away turns each block's carrier by whole cycles, and
    its wipe-off is a shift of the block's spectrum by k bins: one FFT per block per distinct Doppler mod 1 kHz
    (3 for 333 Hz bins) instead of one per Doppler bin. The coherent sum of a replica's correlations is the
    correlation of the summed spectra (the transform is linear).
    """
    kept = _kept_bins(n_ms, most)
    spectra = scratch("acquisition spectra", (dopplers.size, noncoherent, kept.size), np.complex64)
    t_block = np.arange(n_ms) / fs_hz
    t_starts = np.arange(coherent_ms * noncoherent) * n_ms / fs_hz

    def block_sums(f_hz):
        # one block's carrier, turned by each block's start phase: a block's exponentials, not the whole run's
        w = -2j * np.pi * f_hz
        carrier = np.exp(w * t_starts).astype(np.complex64)[:, None] * np.exp(w * t_block).astype(np.complex64)
        blocks = scipy.fft.fft(x.reshape(-1, n_ms) * carrier, axis=1, overwrite_x=True, workers=cores())
        return blocks.reshape(noncoherent, coherent_ms, n_ms).sum(axis=1)

    if not _whole_ms(fs_hz, n_ms):
        for i, f in enumerate(dopplers):
            spectra[i] = np.conj(block_sums(f + if_hz)[:, kept])
        return spectra
    khz = np.floor((dopplers + if_hz) / 1e3).astype(np.int64)
    fraction_hz = np.round(dopplers + if_hz - 1e3 * khz, 6)
    for frac in np.unique(fraction_hz):
        sums = block_sums(frac)
        for i in np.nonzero(fraction_hz == frac)[0]:
            spectra[i] = np.conj(sums[:, (kept + khz[i]) % n_ms])
    return spectra


def second_peak_ratio(power: np.ndarray, row: int, col: int, fs_hz: float, exclude_chips: float = 1.5) -> float:
    """The main peak over the highest CAF cell more than `exclude_chips` from its code phase (any Doppler): a real
    signal stands alone (ratio well above 1); noise and spurs give a second peak nearly as high (ratio ~1)."""
    n = power.shape[1]
    half = int(np.ceil(exclude_chips * fs_hz / CA_CHIP_RATE_HZ))
    rest = power.max(axis=0)
    rest[(col + np.arange(-half, half + 1)) % n] = -np.inf
    top = rest.max()
    return float(power[row, col] / top) if np.isfinite(top) and top > 0 else float("inf")


def _threshold(pfa: float, n_cells: int, n_noncoherent: int) -> float:
    """Threshold on mean |R|^2/sigma^2 over K looks so that the whole search has false-alarm probability pfa."""
    pfa_cell = -np.expm1(np.log1p(-pfa) / n_cells)
    return float(chi2_isf(pfa_cell, 2 * n_noncoherent) / (2 * n_noncoherent))


def _tail_level(power: np.ndarray, pfa_cell: float) -> float:
    """The level cells like these exceed with probability pfa_cell: the 99 % and 99.9 % quantiles extrapolated as
    an exponential tail (for chi-square noise a little above the exact level: conservative)."""
    q1, q2 = np.quantile(power, [0.99, 0.999])
    return float(q2 + (q2 - q1) * np.log(1e-3 / pfa_cell) / np.log(10.0))


def _empirical_threshold(power: np.ndarray, pfa_cell: float, dopplers_hz: np.ndarray, coherent_s: float) -> float:
    """The level a CAF's own noise exceeds with probability pfa_cell, from its tail. Real captures have heavier
    tails than the chi-square theory (other satellites' cross-correlation, quantisation, interference left after
    excision); a few signal cells cannot move these quantiles. Rows within 1.5 / coherent time of the strongest
    cell are left out: they hold that signal's own code sidelobes, which would hide a weaker signal of the same PRN
    (the spoofing case)."""
    top_row = np.unravel_index(int(np.argmax(power)), power.shape)[0]
    far = np.abs(dopplers_hz - dopplers_hz[top_row]) > 1.5 / coherent_s
    if far.sum() >= 3:
        power = power[far]
    return _tail_level(power, pfa_cell)


def _interp(y_minus: float, y0: float, y_plus: float) -> float:
    """Offset in bins of a parabola's vertex through three points."""
    den = y_minus - 2 * y0 + y_plus
    return 0.0 if den >= 0 else float(np.clip(0.5 * (y_minus - y_plus) / den, -0.5, 0.5))


def find_peaks(power: np.ndarray, threshold: float, max_peaks: int) -> list[tuple[int, int]]:
    """Local maxima (3x3, circular in code phase) above threshold, strongest first."""
    rows, cols = np.nonzero(power >= threshold)   # few cells: only they are compared with their neighbours
    value = power[rows, cols]
    is_max = np.ones(rows.size, dtype=bool)
    for dd in (-1, 0, 1):
        r = rows + dd
        inside = (r >= 0) & (r < power.shape[0])   # beyond the Doppler edges: no neighbour
        for dc in (-1, 0, 1):
            if dd or dc:
                c = (cols + dc) % power.shape[1]
                is_max[inside] &= value[inside] >= power[r[inside], c[inside]]
    rows, cols = rows[is_max], cols[is_max]
    order = np.argsort(-power[rows, cols], kind="stable")[:max_peaks]
    return [(int(rows[i]), int(cols[i])) for i in order]


MEDIAN_STRIDE = 4
# Doppler rows correlated at once: each thread's buffer is this many rows of every look, not the whole grid (37 rows
# of 2 ms x 20 at 10 MSa/s: 24 MB a thread)
ROWS_AT_ONCE = 8


@njit(cache=True, nogil=True)
def noncoherent_power(coh):
    """|coh|^2 averaged over axis 1 of a (Doppler, look, code phase) array: float32 (Doppler, code phase)."""
    n_d, n_k, n = coh.shape
    out = np.zeros((n_d, n), dtype=np.float32)
    for d in range(n_d):
        for k in range(n_k):
            for i in range(n):
                v = coh[d, k, i]
                out[d, i] += v.real * v.real + v.imag * v.imag
    return out / np.float32(n_k)


def acquire(samples: np.ndarray, fs_hz: float, prns: Iterable[int], grid: DopplerGrid = DopplerGrid(),
            if_hz: float = 0.0, coherent_ms: int = 1, noncoherent: int = 1, pfa: float = 1e-3,
            max_peaks: int = 8, excise: bool = False,
            tail_threshold: bool = False, windows_hz: dict[int, tuple[float, float]] | None = None,
            most_columns: int = MAX_CAF_COLUMNS, keep_power: bool = True) -> dict[int, Caf]:
    """Search each PRN over the Doppler grid and every code phase.

    windows_hz: PRN -> (lowest, highest) Doppler: that PRN's search keeps only the grid's rows inside (a look around
    a signal known to be there costs a quarter of one over every Doppler); the threshold stays the whole grid's.
    most_columns: the CAF's code phases per ms at most (caf_columns; 2048 keeps the C/A main lobe: a screen).
    keep_power: a CAF with peaks keeps its |R|^2 (for plots); a caller that only reads peaks says False.

    Uses coherent_ms * noncoherent ms of samples from the start; with `excise`, DC and narrowband lines are
    excised first (`interference.excise_narrowband`), and when there were any, the threshold is at least the tail
    of the CAFs of codes no satellite sends (REFERENCE_KEYS) at the false-alarm rate: what is left of interference
    (its sidebands, quantisation products, a tone so strong nothing else was recorded) correlates with those codes
    as with every PRN, so it can no longer pass for a satellite. The noise floor sigma^2 is the CAF's median (with
    `tail_threshold`, per Doppler row, robust to what is left of interference near one Doppler). With
    `tail_threshold` the threshold is also at least the CAF's own empirical tail at the false-alarm rate
    (`_empirical_threshold`): what holds the rate on real captures, where strong satellites' cross-correlation
    fattens the tail.
    """
    if not 1 <= coherent_ms <= 20 or noncoherent < 1:
        raise ValueError("acquisition wants 1-20 ms coherent and at least one non-coherent sum")
    n_ms = int(round(fs_hz * CA_CODE_PERIOD_S))
    need = n_ms * coherent_ms * noncoherent
    if samples.size < need:
        raise ValueError(f"acquisition needs {need} samples ({coherent_ms * noncoherent} ms), got {samples.size}")
    x = np.asarray(samples[:need], dtype=np.complex64)
    interference = NONE
    if excise:
        x, interference = excise_narrowband(x, fs_hz, if_hz, n_ms)
    if _whole_ms(fs_hz, n_ms):
        grid = grid.khz_periodic()
    all_dopplers = grid.values_hz()
    n_cols = caf_columns(n_ms, most_columns)
    code_chips = np.arange(n_cols) * CA_CODE_LENGTH_CHIPS / n_cols
    thr_theory = _threshold(pfa, all_dopplers.size * n_cols, noncoherent)
    pfa_cell = -np.expm1(np.log1p(-pfa) / (all_dopplers.size * n_cols))
    chi_median = chi2_median(2 * noncoherent) / (2 * noncoherent)
    spectra = _wiped_spectra(x, fs_hz, if_hz, all_dopplers, n_ms, coherent_ms, noncoherent, most_columns)
    prns = list(prns)
    fft_workers = 1 if len(prns) > 1 else cores()   # several PRNs: one per thread

    def power_of(key: int, rows=slice(None)) -> np.ndarray:
        """|R|^2 over the noise floor for one code (over the Doppler rows given)."""
        wiped = spectra[rows]
        code = _local_replica_fft(key, n_ms, fs_hz, most_columns)
        raw = np.empty(wiped.shape[::2], dtype=np.float32)
        for r in range(0, wiped.shape[0], ROWS_AT_ONCE):   # a few rows' correlations at a time: bounded memory
            part = wiped[r:r + ROWS_AT_ONCE]
            work = np.multiply(part, code, out=scratch("acquisition", part.shape, np.complex64))
            raw[r:r + part.shape[0]] = noncoherent_power(scipy.fft.ifft(work, axis=2, overwrite_x=True,
                                                                        workers=fft_workers))
        # the noise floor from every MEDIAN_STRIDE-th code phase: the same median to a fraction of a percent
        sample = raw[:, ::MEDIAN_STRIDE]
        sigma2 = (np.median(sample, axis=1, keepdims=True) if tail_threshold else np.median(sample)) / chi_median
        # a window of zeros (a front end's dropout, a gap filled by the reader) has no floor: nothing is found in it
        sigma2 = np.maximum(np.asarray(sigma2, dtype=np.float32), np.finfo(np.float32).tiny)
        return raw / sigma2

    thr_floor = thr_theory
    if interference.jamming:   # nothing under it is a satellite: no search
        return {prn: Caf(prn, all_dopplers, code_chips, None, np.inf, coherent_ms * CA_CODE_PERIOD_S, (), 0.0,
                         interference) for prn in prns}
    if interference.present:
        references = run_each(power_of, list(REFERENCE_KEYS))
        thr_floor = max(thr_floor, _tail_level(np.concatenate([r.ravel() for r in references]), pfa_cell))

    def caf_of(prn: int) -> Caf:
        rows, dopplers = slice(None), all_dopplers
        if windows_hz and prn in windows_hz:
            lo, hi = windows_hz[prn]
            inside = np.nonzero((all_dopplers >= lo) & (all_dopplers <= hi))[0]
            if inside.size:
                rows, dopplers = slice(inside[0], inside[-1] + 1), all_dopplers[inside[0]:inside[-1] + 1]
        power = power_of(prn, rows)
        thr = thr_floor
        if tail_threshold:
            thr = max(thr, _empirical_threshold(power, pfa_cell, dopplers, coherent_ms * CA_CODE_PERIOD_S))
        peaks = []
        for row, col in find_peaks(power, thr, max_peaks):
            dc = _interp(np.sqrt(power[row, col - 1]), np.sqrt(power[row, col]),
                         np.sqrt(power[row, (col + 1) % n_cols]))
            dd = 0.0
            if 0 < row < dopplers.size - 1:
                dd = _interp(power[row - 1, col], power[row, col], power[row + 1, col])
            snr = max(float(power[row, col]) - 1.0, 1e-3)
            doppler_hz = float(dopplers[row] + dd * grid.step_hz)
            # The peak sits where the code is at mid-block; the code runs fast by doppler/1540 chip/s, so step
            # back half a block to the first sample (0.17 chip at 2.6 kHz over 200 ms).
            chips = (col + dc) * CA_CODE_LENGTH_CHIPS / n_cols \
                - 0.5 * need / fs_hz * doppler_hz * CA_CHIP_RATE_HZ / L1_HZ
            peaks.append(Peak(prn, float(chips % CA_CODE_LENGTH_CHIPS), doppler_hz, float(power[row, col]),
                              float(10 * np.log10(snr / (coherent_ms * CA_CODE_PERIOD_S)))))
        ratio2 = second_peak_ratio(power, *np.unravel_index(int(np.argmax(power)), power.shape),
                                   n_cols / CA_CODE_PERIOD_S)
        # 32 PRNs' CAFs at 5 MSa/s would hold 24 MB: only the detections keep theirs (for plots)
        kept = power if peaks and keep_power else None
        return Caf(prn, dopplers, code_chips, kept, thr, coherent_ms * CA_CODE_PERIOD_S, tuple(peaks), ratio2,
                   interference, float(np.mean(power)))

    return dict(zip(prns, run_each(caf_of, prns)))
