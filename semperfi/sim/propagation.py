"""What a signal from each satellite looks like on arrival: pseudorange for the code and for the carrier.

The receiver clock is left out (the caller adds it), so the same routine serves the legitimate signals at the true
position and the attacker's at its claimed position.
"""

from dataclasses import dataclass

import numpy as np

from ..gps import (Ephemeris, IonoParams, SPEED_OF_LIGHT_M_S, azimuth_elevation, ecef_to_geodetic, iono_delay_m,
                   light_time_range, satellite_clock, satellite_position, satellite_position_velocity,
                   troposphere_delay_m)


@dataclass(frozen=True)
class Arrival:
    """Per satellite, at one reception instant."""
    code_m: np.ndarray        # range - c * satellite clock + ionosphere + troposphere
    carrier_m: np.ndarray     # as code_m but with the ionosphere advancing the carrier
    range_rate_m_s: np.ndarray
    azimuth_rad: np.ndarray
    elevation_rad: np.ndarray


def arrival(stacked: Ephemeris, receiver_ecef_m, receiver_vel_m_s, tow_s: float,
            iono: IonoParams | None, troposphere: bool) -> Arrival:
    """Signals received at GPS time tow_s by a receiver at receiver_ecef_m (all satellites of stacked)."""
    n = np.size(stacked.prn)
    t_rx = np.full(n, tow_s)
    rng, t_tx, sat_pos, sat_vel = light_time_range(lambda t: satellite_position(stacked, t),
                                                   lambda t: satellite_position_velocity(stacked, t),
                                                   receiver_ecef_m, t_rx)
    clock_s, clock_drift = satellite_clock(stacked, t_tx)
    los = (sat_pos - receiver_ecef_m) / rng[:, None]
    range_rate = np.sum(los * (sat_vel - receiver_vel_m_s), axis=1) - SPEED_OF_LIGHT_M_S * clock_drift
    az, el = azimuth_elevation(receiver_ecef_m, sat_pos)
    lat, lon, h = ecef_to_geodetic(receiver_ecef_m)
    iono_m = iono_delay_m(iono, float(lat), float(lon), az, el, tow_s)
    tropo_m = troposphere_delay_m(float(lat), float(h), el) if troposphere else np.zeros(n)
    geometric = rng - SPEED_OF_LIGHT_M_S * clock_s + tropo_m
    return Arrival(geometric + iono_m, geometric - iono_m, range_rate, az, el)
