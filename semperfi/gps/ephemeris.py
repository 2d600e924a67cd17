"""Broadcast ephemeris, clock and ionosphere/UTC parameters, and the IS-GPS-200 user algorithms on them.

Angles are kept in radians (as RINEX gives them); the LNAV message carries semicircles, converted with the ICD's
value of pi so that encode -> decode is exact.
"""

from dataclasses import dataclass

import numpy as np

from .constants import F_RELATIVISTIC_S_SQRT_M, GM_EARTH_M3_S2, OMEGA_EARTH_RAD_S, SECONDS_PER_WEEK


@dataclass(frozen=True)
class Ephemeris:
    """Subframes 1-3 of one satellite: clock (subframe 1) and Keplerian orbit with harmonic corrections (2-3)."""
    prn: int
    week: int                 # full GPS week number of toe (the message carries it modulo 1024)
    toe_s: float              # time of ephemeris, seconds of week
    toc_s: float              # time of clock, seconds of week
    sqrt_a_sqrt_m: float
    e: float
    i0_rad: float
    omega0_rad: float         # longitude of ascending node at weekly epoch
    omega_rad: float          # argument of perigee
    m0_rad: float
    delta_n_rad_s: float
    idot_rad_s: float
    omega_dot_rad_s: float
    cuc_rad: float
    cus_rad: float
    crc_m: float
    crs_m: float
    cic_rad: float
    cis_rad: float
    af0_s: float
    af1_s_s: float
    af2_s_s2: float
    tgd_s: float
    iode: int
    iodc: int
    health: int = 0
    ura_index: int = 0
    fit_interval_flag: int = 0
    code_on_l2: int = 1
    l2p_data_flag: int = 0


@dataclass(frozen=True)
class IonoParams:
    """Klobuchar coefficients broadcast in subframe 4 page 18 (alpha in s, s/semicircle^n; beta in s, s/sc^n)."""
    alpha: tuple[float, float, float, float]
    beta: tuple[float, float, float, float]


@dataclass(frozen=True)
class UtcParams:
    """GPS-UTC relation from subframe 4 page 18."""
    a0_s: float
    a1_s_s: float
    tot_s: int
    wnt: int                  # week of tot, modulo 256 as broadcast
    delta_t_ls_s: int
    wn_lsf: int
    dn: int
    delta_t_lsf_s: int


def _tk(ephemeris_t_s: float, tow_s):
    """Time from an ephemeris reference epoch, wrapped into +/- half a week."""
    dt = np.asarray(tow_s, dtype=np.float64) - ephemeris_t_s
    return dt - np.round(dt / SECONDS_PER_WEEK) * SECONDS_PER_WEEK


def _eccentric_anomaly(eph: Ephemeris, tk):
    a = eph.sqrt_a_sqrt_m ** 2
    n = np.sqrt(GM_EARTH_M3_S2 / a ** 3) + eph.delta_n_rad_s
    mk = eph.m0_rad + n * tk
    ek = mk.copy() if isinstance(mk, np.ndarray) else np.float64(mk)
    for _ in range(5):                      # Newton: quadratic convergence, 1e-16 rad in 4 steps for e < 0.03
        ek = ek - (ek - eph.e * np.sin(ek) - mk) / (1.0 - eph.e * np.cos(ek))
    return ek, n


def satellite_position(eph: Ephemeris, tow_s):
    """ECEF position (m) at GPS transmit time tow_s; see satellite_position_velocity."""
    return satellite_position_velocity(eph, tow_s, with_velocity=False)[0]


def satellite_position_velocity(eph: Ephemeris, tow_s, with_velocity: bool = True):
    """ECEF position (m) and velocity (m/s) at GPS transmit time tow_s (IS-GPS-200 Table 20-IV).

    The frame is ECEF at the transmit instant; callers rotate it for the signal's flight time.
    Returns arrays of shape (..., 3).
    """
    tk = _tk(eph.toe_s, tow_s)
    ek, n = _eccentric_anomaly(eph, tk)
    a = eph.sqrt_a_sqrt_m ** 2
    e = eph.e
    sin_e, cos_e = np.sin(ek), np.cos(ek)
    one_m_ecos = 1.0 - e * cos_e
    vk = np.arctan2(np.sqrt(1.0 - e * e) * sin_e, cos_e - e)
    phi = vk + eph.omega_rad
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    du = eph.cus_rad * s2 + eph.cuc_rad * c2
    dr = eph.crs_m * s2 + eph.crc_m * c2
    di = eph.cis_rad * s2 + eph.cic_rad * c2
    uk = phi + du
    rk = a * one_m_ecos + dr
    ik = eph.i0_rad + di + eph.idot_rad_s * tk
    xp, yp = rk * np.cos(uk), rk * np.sin(uk)
    omk = eph.omega0_rad + (eph.omega_dot_rad_s - OMEGA_EARTH_RAD_S) * tk - OMEGA_EARTH_RAD_S * eph.toe_s
    sin_o, cos_o, sin_i, cos_i = np.sin(omk), np.cos(omk), np.sin(ik), np.cos(ik)
    pos = np.stack([xp * cos_o - yp * cos_i * sin_o,
                    xp * sin_o + yp * cos_i * cos_o,
                    yp * sin_i], axis=-1)
    if not with_velocity:
        return pos, None

    ek_dot = n / one_m_ecos
    vk_dot = ek_dot * np.sqrt(1.0 - e * e) / one_m_ecos
    ik_dot = eph.idot_rad_s + 2 * vk_dot * (eph.cis_rad * c2 - eph.cic_rad * s2)
    uk_dot = vk_dot + 2 * vk_dot * (eph.cus_rad * c2 - eph.cuc_rad * s2)
    rk_dot = e * a * ek_dot * sin_e + 2 * vk_dot * (eph.crs_m * c2 - eph.crc_m * s2)
    omk_dot = eph.omega_dot_rad_s - OMEGA_EARTH_RAD_S
    xp_dot = rk_dot * np.cos(uk) - yp * uk_dot
    yp_dot = rk_dot * np.sin(uk) + xp * uk_dot
    vel = np.stack([
        -xp * omk_dot * sin_o + xp_dot * cos_o - yp_dot * sin_o * cos_i
        - yp * (omk_dot * cos_o * cos_i - ik_dot * sin_o * sin_i),
        xp * omk_dot * cos_o + xp_dot * sin_o + yp_dot * cos_o * cos_i
        - yp * (omk_dot * sin_o * cos_i + ik_dot * cos_o * sin_i),
        yp_dot * sin_i + yp * ik_dot * cos_i,
    ], axis=-1)
    return pos, vel


def satellite_clock(eph: Ephemeris, tow_s):
    """L1 C/A satellite clock offset (s, group delay included) and drift (s/s) at GPS time tow_s.

    dt_sv = af0 + af1 tk + af2 tk^2 + relativistic term - TGD (IS-GPS-200 20.3.3.3.3.1-2).
    """
    tk_c = _tk(eph.toc_s, tow_s)
    ek, n = _eccentric_anomaly(eph, _tk(eph.toe_s, tow_s))
    rel = F_RELATIVISTIC_S_SQRT_M * eph.e * eph.sqrt_a_sqrt_m * np.sin(ek)
    rel_dot = F_RELATIVISTIC_S_SQRT_M * eph.e * eph.sqrt_a_sqrt_m * np.cos(ek) * n / (1.0 - eph.e * np.cos(ek))
    offset = eph.af0_s + eph.af1_s_s * tk_c + eph.af2_s_s2 * tk_c ** 2 + rel - eph.tgd_s
    drift = eph.af1_s_s + 2 * eph.af2_s_s2 * tk_c + rel_dot
    return offset, drift


def stack_ephemerides(ephemerides) -> Ephemeris:
    """Several satellites' ephemerides as one whose fields are arrays, so the algorithms above vectorise."""
    ephemerides = list(ephemerides)
    fields = Ephemeris.__dataclass_fields__
    return Ephemeris(**{f: np.array([getattr(e, f) for e in ephemerides]) for f in fields})
