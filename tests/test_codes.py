import numpy as np
import pytest

from semperfi.gps.codes import PRNS, ca_code, first_chips_octal, sampled_code

# IS-GPS-200 Table 3-Ia: first 10 chips of each C/A code, octal.
FIRST_10_CHIPS_OCTAL = {
    1: "1440", 2: "1620", 3: "1710", 4: "1744", 5: "1133", 6: "1455", 7: "1131", 8: "1454", 9: "1626", 10: "1504",
    11: "1642", 12: "1750", 13: "1764", 14: "1772", 15: "1775", 16: "1776", 17: "1156", 18: "1467", 19: "1633",
    20: "1715", 21: "1746", 22: "1763", 23: "1063", 24: "1706", 25: "1743", 26: "1761", 27: "1770", 28: "1774",
    29: "1127", 30: "1453", 31: "1625", 32: "1712",
}


@pytest.mark.parametrize("prn", PRNS)
def test_first_ten_chips_match_the_icd(prn):
    assert first_chips_octal(prn) == FIRST_10_CHIPS_OCTAL[prn]


def test_gold_code_correlation_is_three_valued():
    """Gold codes: periodic auto- and cross-correlation take only the values -1, -65, 63 (and 1023 at zero lag)."""
    spectra = {p: np.fft.fft(ca_code(p).astype(float)) for p in (1, 7, 19, 32)}
    for a in spectra:
        for b in spectra:
            corr = np.round(np.fft.ifft(spectra[a] * np.conj(spectra[b])).real).astype(int)
            allowed = {-1, -65, 63} | ({1023} if a == b else set())
            assert set(corr) <= allowed, (a, b, set(corr) - allowed)
            if a == b:
                assert corr[0] == 1023


def test_sampled_code_starts_at_the_requested_chip():
    fs = 4.092e6  # exactly 4 samples per chip
    rep = sampled_code(5, fs, 4 * 1023, code_phase_chips=100.0)
    assert np.array_equal(rep[::4], np.roll(ca_code(5), -100))


def test_unknown_prn_is_refused():
    with pytest.raises(ValueError, match="PRN 33"):
        ca_code(33)
