"""Signals received stronger than any satellite's can be: a strong attacker's, whatever else is seen of them.

Every C/A signal raises the floor every other correlator sees by its power spectral density at the band centre,
about its power / 1.023 MHz (the cross-correlation averages 1/1023 of the power per code period). The C/N0 a receiver
measures is therefore against N0 plus the other signals, and it cannot exceed ~1.023 MHz / (n - 1) however strong
they are (about 50 dB-Hz with a dozen signals). Inverting that gives each signal's C/N0 against the thermal floor:

    true_i = apparent_i / (1 - sum_{j != i} apparent_j / 1.023 MHz)

A dozen legitimate signals at 45 dB-Hz make the sum ~0.4; a +15 dB attacker on a dozen PRNs pushes it past 1 (the
measured C/N0s saturate, and the inverse is clamped). The satellites' signals reach the ground at 55 dB-Hz at most;
a signal far above that is the attacker's, and its legitimate twin is hidden in the attacker's multiple-access
interference until it is cancelled (the legitimate twin, measured against the same raised floor, stays plausible).
"""

import math

from ..gps import CA_CHIP_RATE_HZ
from ..receiver import Peak

MAX_PLAUSIBLE_CN0_DBHZ = 58.0   # the strongest GPS L1 C/A signal on the ground is ~55 dB-Hz
MIN_IMPLAUSIBLE_PRNS = 4        # an attacker that moves a position needs four PRNs or more
MIN_FREE_FLOOR = 0.05           # the thermal share of the floor is not resolved below 5 % (13 dB of interference)


def thermal_cn0_dbhz(apparent_dbhz: dict[int, float]) -> dict[int, float]:
    """Each signal's C/N0 against the thermal floor, from the C/N0s measured against the floor all of them raise."""
    linear = {prn: 10 ** (v / 10) for prn, v in apparent_dbhz.items()}
    total = sum(linear.values()) / CA_CHIP_RATE_HZ
    return {prn: v + 10 * math.log10(1.0 / max(1.0 - (total - linear[prn] / CA_CHIP_RATE_HZ), MIN_FREE_FLOOR))
            for prn, v in apparent_dbhz.items()}


def implausible_peaks(peaks: dict[int, Peak], max_cn0_dbhz: float = MAX_PLAUSIBLE_CN0_DBHZ) -> dict[int, float]:
    """PRN -> thermal C/N0 of the peaks too strong to be a satellite's, when MIN_IMPLAUSIBLE_PRNS or more are;
    peaks: each PRN's strongest peak that is a signal of its own (not another PRN's cross-talk)."""
    thermal = thermal_cn0_dbhz({prn: p.cn0_dbhz for prn, p in peaks.items()})
    strong = {prn: round(v, 1) for prn, v in thermal.items() if v > max_cn0_dbhz}
    return strong if len(strong) >= MIN_IMPLAUSIBLE_PRNS else {}
