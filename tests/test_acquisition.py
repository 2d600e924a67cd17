"""Acquisition's fast paths against plain numpy references."""

import numpy as np
import pytest

from semperfi.receiver.acquisition import find_peaks, noncoherent_power, second_peak_ratio
from signals import ca_signal


def test_noncoherent_power_equals_numpy():
    rng = np.random.default_rng(3)
    coh = (rng.standard_normal((7, 5, 300)) + 1j * rng.standard_normal((7, 5, 300))).astype(np.complex64)
    assert np.allclose(noncoherent_power(coh), np.mean(np.abs(coh) ** 2, axis=1), rtol=1e-5)


def find_peaks_reference(power, threshold, max_peaks):
    """Every cell against its 8 neighbours (circular in code phase, none beyond the Doppler edges)."""
    out = []
    n_d, n = power.shape
    for r in range(n_d):
        for c in range(n):
            v = power[r, c]
            if v < threshold:
                continue
            if all(v >= power[r + dd, (c + dc) % n] for dd in (-1, 0, 1) for dc in (-1, 0, 1)
                   if (dd or dc) and 0 <= r + dd < n_d):
                out.append((r, c))
    out.sort(key=lambda rc: -power[rc])
    return out[:max_peaks]


def test_find_peaks_equals_its_reference():
    rng = np.random.default_rng(8)
    for _ in range(20):
        power = rng.exponential(1.0, (9, 200)).astype(np.float32)
        for r, c in rng.integers(0, [9, 200], (4, 2)):   # peaks, some on the edges and on the code wrap
            power[r, c] += rng.uniform(5, 30)
        power[0, 199] += 40.0
        want = find_peaks_reference(power, 6.0, 8)
        assert find_peaks(power, 6.0, 8) == want and want


def test_second_peak_ratio_skips_the_peaks_own_code_phases():
    power = np.ones((5, 100), dtype=np.float32)
    power[2, 99] = 50.0
    power[4, 1] = 40.0          # 2 samples away across the wrap: excluded (1.5 chips at 1.023 MSa/s = 2 samples)
    power[0, 50] = 10.0
    assert second_peak_ratio(power, 2, 99, 1.023e6) == 5.0


def test_chi_square_quantiles_equal_scipy_stats():
    from scipy import stats
    from semperfi.receiver.chisquare import chi2_isf, chi2_median, ncx2_noncentrality
    for dof in (1, 2, 5, 10, 40):
        for p in (0.5, 1e-3, 1e-9):
            assert chi2_isf(p, dof) == pytest.approx(stats.chi2.isf(p, dof), rel=1e-9)
        assert chi2_median(dof) == pytest.approx(stats.chi2.median(dof), rel=1e-9)
        thr = chi2_isf(1e-3, dof)    # RAIM's use: the bias a test at this threshold misses with probability 1e-3
        assert stats.ncx2.cdf(thr, dof, ncx2_noncentrality(thr, dof, 1e-3)) == pytest.approx(1e-3, rel=1e-6)


def test_doppler_wipe_by_spectrum_shift_equals_a_wipe_per_bin():
    """Whole-ms blocks: Dopplers k kHz apart share one FFT, shifted by k bins; above 4.096 MSa/s only the central
    bins are kept. Against the plain wipe-off and FFT of each Doppler bin."""
    from semperfi.receiver.acquisition import DopplerGrid, _kept_bins, _wiped_spectra
    rng = np.random.default_rng(5)
    for fs, if_hz in ((2e6, 0.0), (5e6, 1.25e6)):
        n_ms = int(fs / 1e3)
        x = (rng.standard_normal(4 * n_ms) + 1j * rng.standard_normal(4 * n_ms)).astype(np.complex64)
        dopplers = DopplerGrid(130.0, 3000.0, 333.0).khz_periodic().values_hz()
        fast = _wiped_spectra(x, fs, if_hz, dopplers, n_ms, coherent_ms=2, noncoherent=2).copy()
        t = np.arange(x.size) / fs
        for i, f in enumerate(dopplers):
            blocks = np.fft.fft((x * np.exp(-2j * np.pi * (f + if_hz) * t)).reshape(-1, n_ms), axis=1)
            want = np.conj(blocks.reshape(2, 2, n_ms).sum(axis=1))[:, _kept_bins(n_ms)]
            assert np.allclose(fast[i], want, atol=1e-3 * np.abs(want).max()), (fs, f)


def _one_signal(fs_hz, prn, code_phase_chips, doppler_hz, cn0_dbhz, ms, seed):
    """A C/A signal (no data) in unit complex noise, its code phase at the first sample."""
    t = np.arange(int(round(fs_hz * ms * 1e-3))) / fs_hz
    rng = np.random.default_rng(seed)
    noise = (rng.standard_normal(t.size) + 1j * rng.standard_normal(t.size)) / np.sqrt(2)
    return (ca_signal(prn, t, code_phase_chips, doppler_hz, np.sqrt(10 ** (cn0_dbhz / 10) / fs_hz)) + noise
            ).astype(np.complex64)


@pytest.mark.parametrize("fs_hz", [2.6e6, 4e6, 10e6])
def test_a_screen_finds_the_signal_where_the_full_search_does(fs_hz):
    """A quiet look's screen (the guard's): each PRN's search kept to a Doppler window around where it was, over the
    C/A main lobe's 2048 code phases a ms. Inside the window, the same rows as the full search (the same peak); a
    window away from the signal finds nothing there; the main lobe alone puts the peak at the same code phase and
    Doppler, a dB or so lower (2 columns a chip: up to a quarter chip off a column)."""
    from semperfi.receiver import DopplerGrid, acquire
    x = _one_signal(fs_hz, 7, 412.3, 1234.0, 45.0, 20, seed=1)
    grid = DopplerGrid(0.0, 6000.0, 333.0)
    full = acquire(x, fs_hz, [7, 9], grid, 0.0, 2, 10, 1e-3, 8)[7].best
    windowed = acquire(x, fs_hz, [7, 9], grid, 0.0, 2, 10, 1e-3, 8,
                       windows_hz={7: (1234.0 - 1500.0, 1234.0 + 1500.0)})[7].best
    assert full is not None and windowed is not None
    # the same rows and cells; the noise floor is the median of fewer of them
    assert windowed.code_phase_chips == pytest.approx(full.code_phase_chips, abs=1e-6)
    assert windowed.doppler_hz == pytest.approx(full.doppler_hz, abs=1e-3)
    assert windowed.metric == pytest.approx(full.metric, rel=0.05)
    assert abs(full.code_phase_chips - 412.3) < 0.05 and abs(full.doppler_hz - 1234.0) < 60.0
    away = acquire(x, fs_hz, [7], grid, 0.0, 2, 10, 1e-3, 8, windows_hz={7: (-4500.0, -1500.0)})[7]
    assert away.best is None and away.doppler_hz.max() <= -1500.0
    screen = acquire(x, fs_hz, [7], grid, 0.0, 2, 10, 1e-3, 8, most_columns=2048)[7]
    assert screen.code_phase_chips.size == min(2048, int(round(fs_hz * 1e-3)))
    assert abs(screen.best.code_phase_chips - 412.3) < 0.1 and abs(screen.best.doppler_hz - 1234.0) < 60.0
    assert -2.5 < screen.best.cn0_dbhz - full.cn0_dbhz < 0.5
