"""The satellites in the sky: broadcast ephemerides from a RINEX file, or a synthesized GPS-like constellation.

Every ephemeris is passed through the LNAV quantization, so the orbits the simulator renders are exactly the ones
its navigation message carries.
"""

from dataclasses import dataclass, replace
from datetime import datetime

import numpy as np

from ..gps import Ephemeris, GpsTime, IonoParams, UtcParams, quantize_ephemeris
from ..iq import read_rinex_nav

# Broadcast Klobuchar coefficients of a quiet day (those of brdc0010.22n), used when no file gives any.
DEFAULT_IONO = IonoParams((1.211e-08, -7.451e-09, -5.960e-08, 1.192e-07), (1.167e5, -2.458e5, -6.554e4, 1.114e6))
DEFAULT_START = "2024-06-01T12:00:00"
SYNTH_SEED = 2022


@dataclass(frozen=True)
class Constellation:
    """One ephemeris per PRN, valid around the scenario, with the broadcast ionosphere and UTC parameters."""
    ephemerides: dict[int, Ephemeris]
    iono: IonoParams
    utc: UtcParams
    start: GpsTime


def _default_utc(week: int) -> UtcParams:
    return UtcParams(a0_s=0.0, a1_s_s=0.0, tot_s=0, wnt=week % 256, delta_t_ls_s=18, wn_lsf=week % 256, dn=7,
                     delta_t_lsf_s=18)


def _parse_start(text: str) -> GpsTime:
    try:
        return GpsTime.from_datetime(datetime.fromisoformat(text))
    except ValueError:
        raise ValueError(f"time.start = '{text}' is not a date like 2022-01-01T00:00:00") from None


def synthesize(start: GpsTime, n_satellites: int = 31) -> dict[int, Ephemeris]:
    """A GPS-like constellation: 6 planes at 55 deg, half-sidereal-day orbits, plausible clocks."""
    rng = np.random.default_rng(SYNTH_SEED)
    toe_s = float(np.floor(start.tow_s / 7200.0) * 7200.0)
    ephemerides = {}
    for i in range(n_satellites):
        plane, slot = i % 6, i // 6
        prn = i + 1
        eph = Ephemeris(
            prn=prn, week=start.week, toe_s=toe_s, toc_s=toe_s,
            sqrt_a_sqrt_m=5153.6 + rng.uniform(-0.5, 0.5), e=rng.uniform(0.001, 0.02),
            i0_rad=np.radians(55.0 + rng.uniform(-1.5, 1.5)),
            omega0_rad=float(np.angle(np.exp(1j * (np.radians(60.0 * plane + 17.0) - 0.2)))),
            omega_rad=rng.uniform(-np.pi, np.pi),
            m0_rad=float(np.angle(np.exp(1j * (np.radians(360.0 / 6 * slot + 13.0 * plane) + rng.uniform(-0.2, 0.2))))),
            delta_n_rad_s=rng.uniform(3.5e-9, 5.0e-9), idot_rad_s=rng.uniform(-4e-10, 4e-10),
            omega_dot_rad_s=rng.uniform(-8.5e-9, -7.8e-9),
            cuc_rad=rng.uniform(-8e-6, 8e-6), cus_rad=rng.uniform(-8e-6, 8e-6), crc_m=rng.uniform(150.0, 350.0),
            crs_m=rng.uniform(-150.0, 150.0), cic_rad=rng.uniform(-2e-7, 2e-7), cis_rad=rng.uniform(-2e-7, 2e-7),
            af0_s=rng.uniform(-5e-4, 5e-4), af1_s_s=rng.uniform(-1e-11, 1e-11), af2_s_s2=0.0,
            tgd_s=rng.uniform(-1e-8, 1e-8), iode=(17 + i) % 256, iodc=(17 + i) % 256)
        ephemerides[prn] = quantize_ephemeris(eph)
    return ephemerides


def build_constellation(cfg: dict) -> Constellation:
    """From the scenario's [constellation] and [time] sections."""
    rinex, start_text = cfg["constellation"]["rinex"], cfg["time"]["start"]
    if not rinex:
        start = _parse_start(start_text or DEFAULT_START)
        return Constellation(synthesize(start), DEFAULT_IONO, _default_utc(start.week), start)
    nav = read_rinex_nav(rinex)
    if start_text:
        start = _parse_start(start_text)
    else:   # the earliest reference epoch: the file's day starts there
        first = min(nav.ephemerides, key=lambda e: GpsTime(e.week, e.toe_s).seconds)
        start = GpsTime(first.week, first.toe_s)
    ephemerides = {}
    for prn in range(1, 33):
        eph = nav.nearest(prn, start)
        if eph is not None:
            ephemerides[prn] = quantize_ephemeris(replace(eph, iodc=eph.iodc % 1024, iode=eph.iode % 256))
    if not ephemerides:
        raise ValueError(f"{rinex}: no healthy ephemeris within 4 h of {start.to_datetime():%Y-%m-%d %H:%M:%S}")
    return Constellation(ephemerides, nav.iono or DEFAULT_IONO, nav.utc or _default_utc(start.week), start)
