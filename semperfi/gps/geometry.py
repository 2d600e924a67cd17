"""Line-of-sight geometry: Sagnac (Earth rotation during flight), azimuth/elevation, WGS 84 conversions."""

import numpy as np

from .constants import OMEGA_EARTH_RAD_S, SPEED_OF_LIGHT_M_S

WGS84_A_M = 6378137.0
WGS84_F = 1 / 298.257223563
WGS84_E2 = WGS84_F * (2 - WGS84_F)


def rotate_earth(pos_ecef_m, flight_time_s):
    """A satellite position (ECEF at transmit time) expressed in the ECEF frame of reception time."""
    theta = OMEGA_EARTH_RAD_S * np.asarray(flight_time_s, dtype=np.float64)
    c, s = np.cos(theta), np.sin(theta)
    x, y, z = pos_ecef_m[..., 0], pos_ecef_m[..., 1], pos_ecef_m[..., 2]
    return np.stack([c * x + s * y, -s * x + c * y, z], axis=-1)


def geodetic_to_ecef(lat_rad, lon_rad, height_m):
    lat, lon, h = (np.asarray(v, dtype=np.float64) for v in (lat_rad, lon_rad, height_m))
    n = WGS84_A_M / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon),
                     (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1 - WGS84_E2) + h) * np.sin(lat)], axis=-1)


def ecef_to_geodetic(pos_ecef_m):
    """(lat_rad, lon_rad, height_m) by Bowring's iteration; exact to well below a millimetre."""
    p = np.asarray(pos_ecef_m, dtype=np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    lon = np.arctan2(y, x)
    rho = np.hypot(x, y)
    lat = np.arctan2(z, rho * (1 - WGS84_E2))
    for _ in range(6):
        n = WGS84_A_M / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
        h = _height_m(rho, z, lat, n)
        lat = np.arctan2(z, rho * (1 - WGS84_E2 * n / (n + h)))
    n = WGS84_A_M / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return lat, lon, _height_m(rho, z, lat, n)


def _height_m(rho, z, lat, n):
    """Height above the ellipsoid, well conditioned near the poles as at the equator."""
    return rho * np.cos(lat) + z * np.sin(lat) - n * (1 - WGS84_E2 * np.sin(lat) ** 2)


def enu_rotation(lat_rad: float, lon_rad: float) -> np.ndarray:
    """Rows are the east, north and up unit vectors in ECEF."""
    sl, cl, so, co = np.sin(lat_rad), np.cos(lat_rad), np.sin(lon_rad), np.cos(lon_rad)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def azimuth_elevation(receiver_ecef_m, sat_ecef_m):
    """Azimuth and elevation (rad) of satellites seen from a receiver."""
    lat, lon, _ = ecef_to_geodetic(receiver_ecef_m)
    los = np.asarray(sat_ecef_m, dtype=np.float64) - receiver_ecef_m
    enu = los @ enu_rotation(float(lat), float(lon)).T
    az = np.mod(np.arctan2(enu[..., 0], enu[..., 1]), 2 * np.pi)
    el = np.arcsin(enu[..., 2] / np.linalg.norm(enu, axis=-1))
    return az, el


def light_time_range(sat_position_at, sat_pos_vel_at, receiver_ecef_m, t_rx_s, iterations: int = 2):
    """Geometric range (m) and transmit time for a signal received at t_rx_s, by light-time iteration.

    sat_position_at(t_tx) gives ECEF positions at transmit time, sat_pos_vel_at(t_tx) positions and velocities;
    both are rotated into the reception frame (Sagnac). Two iterations from a 75 ms guess leave micrometres.
    Returns (range_m, t_tx_s, sat_pos_rx_frame, sat_vel_rx_frame).
    """
    t_rx = np.asarray(t_rx_s, dtype=np.float64)
    t_tx = t_rx - 0.075
    for _ in range(iterations):
        pos_r = rotate_earth(sat_position_at(t_tx), t_rx - t_tx)
        t_tx = t_rx - np.linalg.norm(pos_r - receiver_ecef_m, axis=-1) / SPEED_OF_LIGHT_M_S
    pos, vel = sat_pos_vel_at(t_tx)
    pos_r, vel_r = rotate_earth(pos, t_rx - t_tx), rotate_earth(vel, t_rx - t_tx)
    return np.linalg.norm(pos_r - receiver_ecef_m, axis=-1), t_tx, pos_r, vel_r
