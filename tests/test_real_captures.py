"""Claims about real front-end recordings: acquisition finds the satellites an independent receiver finds, and
nothing else.

The captures are PocketSDR's public sample data (github.com/tomojitakasu/PocketSDR, folder sample/, see its
sample/readme.txt), kept in tests/data/pocketsdr/ with their licence ($SEMPERFI_REAL_DATA points elsewhere).

The reference values were produced here by GNSS-SDR 0.0.17 (one run per PRN, Channel0.satellite=PRN,
GPS_L1_CA_PCPS_Acquisition, 4 ms coherent, 25 Hz Doppler step, pfa 1e-3, dump of acq_delay_samples,
acq_doppler_hz and sample_counter): the satellites it found with a test statistic far above its threshold.
"""

import os
from pathlib import Path

import numpy as np
import pytest

from semperfi.gps.constants import CA_CHIP_RATE_HZ
from semperfi.iq import open_iq, with_iq_swap
from semperfi.receiver.acquisition import DopplerGrid, acquire

REAL_DATA = Path(os.environ.get("SEMPERFI_REAL_DATA", Path(__file__).parent / "data" / "pocketsdr"))

IQ_4MHZ = "L1_20211202_084700_4MHz_IQ.bin"    # int8 complex, 4 MSa/s, IF 0, 0.5 s (readme says 100 ms)
REAL_12MHZ = "L1_20211125_004000_12MHz_I.bin"  # int8 real, 12 MSa/s, IF 3 MHz, 0.1 s
REAL_24MHZ = "L1_20211201_054600_24MHz_I.bin"  # int8 real, 24 MSa/s, IF 6 MHz, 0.1 s

# GNSS-SDR on IQ_4MHZ, acquisition block starting at sample 24191: PRN -> (acq_delay_samples, acq_doppler_hz).
GNSS_SDR_IQ_START = 24191
GNSS_SDR_IQ = {16: (3767.999, -2600.0), 18: (2249.999, -2725.0), 26: None, 29: (1462.999, 2200.0),
               31: (968.999, 200.0), 32: (2575.999, 3275.0)}   # 26 was acquired from another start sample

# GNSS-SDR on REAL_12MHZ (fed as x + 0j complex floats with IF 3 MHz through its Freq_Xlating_Fir_Filter, since its
# file source refuses a 0.1 s 'byte' file): PRN -> acq_doppler_hz, the PRNs with a test statistic > 150 (threshold
# 56). Code phases are not compared here: its 31-tap filter delays them by an amount we did not calibrate.
GNSS_SDR_REAL = {2: -2725.0, 5: 150.0, 11: -3275.0, 13: -225.0, 15: 1750.0, 18: 3250.0, 20: -1350.0}


def _capture(name: str) -> Path:
    path = REAL_DATA / name
    if not path.is_file():
        pytest.skip(f"{path} absent: real captures are not in the repository (PocketSDR sample/{name}); "
                    "set SEMPERFI_REAL_DATA to the folder holding them")
    return path


def _acquired(samples, fs_hz, if_hz=0.0, coherent_ms=5, noncoherent=10, step_hz=100.0):
    cafs = acquire(samples, fs_hz, range(1, 33), DopplerGrid(0.0, 6000.0, step_hz), if_hz, coherent_ms, noncoherent,
                   excise=True, tail_threshold=True)
    return {prn: caf for prn, caf in cafs.items() if caf.best is not None}


def _no_false_prn(a: dict, b: dict, where: str, clear_ratio: float = 2.0) -> None:
    """Noise peaks land somewhere new in every window; a satellite clearly found in one window (its peak twice
    the highest cell away from it) is found again in a disjoint one, at the same Doppler."""
    for x, y in ((a, b), (b, a)):
        for prn, caf in x.items():
            if caf.second_peak_ratio >= clear_ratio:
                assert prn in y, f"{where}: PRN {prn} acquired in one window only: {sorted(a)} vs {sorted(b)}"
                d = abs(caf.best.doppler_hz - y[prn].best.doppler_hz)
                assert d < 50.0, f"{where}: PRN {prn} Doppler differs by {d:.0f} Hz between windows"


def test_4mhz_iq_capture_finds_gnss_sdr_satellites_and_no_false_prn():
    # The capture is spectrally inverted (next test): read it with I and Q swapped, so Dopplers are the
    # negatives of GNSS-SDR's (which reads it as stored) and the code phases are the same.
    reader = open_iq(_capture(IQ_4MHZ), with_iq_swap("ibyte"), 4e6)
    fs = reader.fs_hz
    first = _acquired(reader.read(GNSS_SDR_IQ_START, int(0.05 * fs)), fs)
    second = _acquired(reader.read(GNSS_SDR_IQ_START + int(0.25 * fs), int(0.05 * fs)), fs)
    _no_false_prn(first, second, IQ_4MHZ)
    assert set(GNSS_SDR_IQ) <= set(first), f"GNSS-SDR's satellites {sorted(GNSS_SDR_IQ)}, ours {sorted(first)}"
    assert len(first) <= 10, f"{len(first)} PRNs acquired: {sorted(first)}"
    for prn, ref in GNSS_SDR_IQ.items():
        if ref is None:
            continue
        delay_samples, doppler_hz = ref
        best = first[prn].best
        assert abs(best.doppler_hz + doppler_hz) < 50.0, f"PRN {prn}: Doppler {best.doppler_hz:.0f} vs -{doppler_hz}"
        # GNSS-SDR's delay counts one sample more than the code start as we define it (a constant 0.256 chip on
        # every PRN of this file); its delay is in whole samples, ours interpolated.
        ref_chips = (-(delay_samples - 1.0) * CA_CHIP_RATE_HZ / fs) % 1023
        err = (best.code_phase_chips - ref_chips + 511.5) % 1023 - 511.5
        assert abs(err) < 0.1, f"PRN {prn}: code phase {best.code_phase_chips:.3f} vs GNSS-SDR {ref_chips:.3f} chips"
        assert first[prn].second_peak_ratio > 2.0, f"PRN {prn}: second-peak ratio {first[prn].second_peak_ratio}"


def test_4mhz_iq_capture_is_spectrally_inverted_and_iq_swap_rights_it():
    """The code of a satellite drifts at Doppler/1540 chip/s in the direction of its carrier Doppler. In this
    capture it drifts the other way on every satellite: the front end delivers Q/I. --iq-swap rights it."""
    path = _capture(IQ_4MHZ)
    for fmt, sign in (("ibyte", -1.0), (with_iq_swap("ibyte"), 1.0)):
        reader = open_iq(path, fmt, 4e6)
        a = _acquired(reader.read(0, 160_000), 4e6, coherent_ms=4, noncoherent=10)
        b = _acquired(reader.read(1_600_000, 160_000), 4e6, coherent_ms=4, noncoherent=10)
        for prn in (16, 18, 29, 32):
            drift = (b[prn].best.code_phase_chips - a[prn].best.code_phase_chips + 511.5) % 1023 - 511.5
            expected = a[prn].best.doppler_hz / 1540.0 * 0.4
            assert abs(drift - sign * expected) < 0.15, \
                f"{fmt}: PRN {prn} code drift {drift:.3f} chips in 0.4 s, carrier says {expected:+.3f}"


def test_12mhz_real_if_capture_acquires_consistently():
    """Real-valued int8 samples at a 3 MHz IF (PocketSDR's "I" sampling): GNSS-SDR's satellites are found in the
    first and the last 20 ms at its Dopplers, and the clear detections of one window are found in the other."""
    reader = open_iq(_capture(REAL_12MHZ), "byte", 12e6, 3e6)
    fs = reader.fs_hz
    first = _acquired(reader.read(0, int(0.02 * fs)), fs, 3e6, coherent_ms=4, noncoherent=5, step_hz=125.0)
    last = _acquired(reader.read(int(0.06 * fs), int(0.02 * fs)), fs, 3e6, coherent_ms=4, noncoherent=5,
                     step_hz=125.0)
    _no_false_prn(first, last, REAL_12MHZ, clear_ratio=3.0)   # 20 ms windows: weak satellites come and go
    for prn, doppler_hz in GNSS_SDR_REAL.items():
        for window in (first, last):
            assert prn in window, f"GNSS-SDR's PRN {prn} missing: ours {sorted(window)}"
            d = window[prn].best.doppler_hz - doppler_hz
            assert abs(d) < 50.0, f"PRN {prn}: Doppler {window[prn].best.doppler_hz:.0f} vs GNSS-SDR {doppler_hz}"


def test_24mhz_real_capture_decimated_to_4mhz_finds_the_same_satellites():
    """The processing-rate path on a real front end: 24 MSa/s real samples at a 6 MHz IF, mixed to 0 Hz and
    decimated by 6 as they stream, give the satellites a search at the full rate gives, at the same Doppler and
    code phase (the decimator keeps input time: output sample j is input sample 6 j)."""
    from semperfi.iq.source import SampleSource
    path = _capture(REAL_24MHZ)
    n_ms = 20
    full_rate = _acquired(open_iq(path, "byte", 24e6, 6e6).read(0, 24_000 * n_ms), 24e6, 6e6, coherent_ms=4,
                          noncoherent=5, step_hz=125.0)
    source = SampleSource(str(path), "byte", 24e6, 6e6, fs_out_hz=4e6)
    decimated = _acquired(source.take(4_000 * n_ms), 4e6, 0.0, coherent_ms=4, noncoherent=5, step_hz=125.0)
    clear = {prn for prn, caf in full_rate.items() if caf.second_peak_ratio > 3.0}
    assert len(clear) >= 4, f"clear satellites at 24 MSa/s: {sorted(clear)}"
    assert clear <= set(decimated), f"24 MSa/s {sorted(clear)}, decimated {sorted(decimated)}"
    for prn in clear:
        a, b = full_rate[prn].best, decimated[prn].best
        assert abs(a.doppler_hz - b.doppler_hz) < 50.0, (prn, a.doppler_hz, b.doppler_hz)
        assert abs((a.code_phase_chips - b.code_phase_chips + 511.5) % 1023 - 511.5) < 0.1, (prn, a, b)


def test_real_samples_need_an_if_inside_the_band(tmp_path):
    path = tmp_path / "r.bin"
    np.zeros(4000, np.int8).tofile(path)
    with pytest.raises(ValueError, match="--if"):
        open_iq(path, "byte", 4e6)
