"""Plain data passed between the receiver's blocks."""

from dataclasses import dataclass

import numpy as np

from ..gps import Ephemeris


@dataclass(frozen=True)
class Observation:
    """One satellite's measurement at a common reception instant."""
    prn: int
    pseudorange_m: float      # c * (t_rx - t_sv): receiver clock bias included, no corrections applied
    t_sv_s: float             # transmit time read from the signal (satellite clock), GPS seconds of week
    doppler_hz: float         # carrier Doppler (positive when the satellite approaches)
    cn0_dbhz: float
    ephemeris: Ephemeris
    weight: float = 1.0       # relative weight for least squares (e.g. from C/N0 and elevation)


# the states that call a fix good: a wrong position must never carry one of them
TRUSTED_STATES = ("nominal", "recovered", "rectified")
# the time of a fix (gps_tow_s, clock_bias_m), apart from its position: nominal (RAIM and the clock model agree: the
# error is within tpl_ns), holdover (the clock model alarmed: the time is the model's prediction, within tpl_ns),
# unverified (nothing checked a delay common to every range: no common-mode bound)
TIME_STATES = ("nominal", "holdover", "unverified")
TIME_TRUSTED = ("nominal", "holdover")


@dataclass(frozen=True)
class Fix:
    """A position/velocity/time solution."""
    t_rx_s: float             # receiver time: seconds since the first sample of the input
    gps_week: int
    gps_tow_s: float          # GPS time of the fix (receiver clock bias removed)
    pos_ecef_m: np.ndarray
    vel_ecef_m_s: np.ndarray
    clock_bias_m: float       # c * receiver clock bias
    clock_drift_m_s: float    # c * receiver clock drift
    lat_deg: float
    lon_deg: float
    height_m: float
    n_sats: int
    prns: tuple[int, ...]
    pdop: float
    hdop: float
    vdop: float
    residual_rms_m: float
    # nominal | unverified; the defence's: spoofing_detected | recovering | recovered | rectified
    state: str = "nominal"
    raim: str = "unverifiable"  # pass | fail | excluded | unverifiable (integrity.py); only pass/excluded are trusted
    excluded_prns: tuple[int, ...] = ()   # ranges RAIM excluded from this fix
    test_statistic: float = float("nan")  # weighted residual sum of squares (chi-square distributed when clean)
    hpl_m: float = float("nan")           # horizontal / vertical protection levels (nan without redundancy)
    vpl_m: float = float("nan")
    # time protection level (ns): the clock error this fix's time is bounded by. From the receiver: RAIM's (one faulty
    # range; a common delay is outside it); the defence's clock guard widens it by what its clock model could miss,
    # or replaces it in holdover (defense/clock_guard.py)
    tpl_ns: float = float("nan")
    clock_sigma_ns: float = float("nan")  # 1 sigma of the clock bias, fault-free (the clock model's measurement noise)
    h_sigma_m: float = float("nan")       # 1 sigma horizontal / vertical position error, fault-free (an accuracy
    v_sigma_m: float = float("nan")       # estimate; the protection levels bound a faulty range's error)
    time_state: str = "unverified"  # nominal | holdover | unverified (TIME_STATES): whether tpl_ns bounds the time


def vouched(fix: Fix) -> bool:
    """Whether a fix may be handed on as a position to use (an autopilot's GPS, a valid NMEA fix): called good, and
    its ranges not failing the integrity test."""
    return fix.state in TRUSTED_STATES and fix.raim != "fail"
