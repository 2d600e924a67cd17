"""Signal delays of the atmosphere: the broadcast (Klobuchar) ionosphere and a standard-atmosphere troposphere."""

import numpy as np

from .constants import GPS_PI, SPEED_OF_LIGHT_M_S
from .ephemeris import IonoParams


def klobuchar_delay_s(iono: IonoParams, lat_rad: float, lon_rad: float, az_rad, el_rad, tow_s):
    """L1 ionospheric group delay (s) of the single-frequency user algorithm, IS-GPS-200 20.3.3.5.2.5."""
    el_sc = np.asarray(el_rad) / GPS_PI
    psi = 0.0137 / (el_sc + 0.11) - 0.022                       # earth-centred angle, semicircles
    phi_i = np.clip(lat_rad / GPS_PI + psi * np.cos(az_rad), -0.416, 0.416)
    lam_i = lon_rad / GPS_PI + psi * np.sin(az_rad) / np.cos(phi_i * GPS_PI)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * GPS_PI)    # geomagnetic latitude, semicircles
    t_local = np.mod(4.32e4 * lam_i + np.asarray(tow_s), 86400.0)
    f = 1.0 + 16.0 * (0.53 - el_sc) ** 3                        # obliquity factor
    amp = np.maximum(sum(a * phi_m ** n for n, a in enumerate(iono.alpha)), 0.0)
    per = np.maximum(sum(b * phi_m ** n for n, b in enumerate(iono.beta)), 72000.0)
    x = 2 * np.pi * (t_local - 50400.0) / per
    night = f * 5e-9
    day = f * (5e-9 + amp * (1 - x ** 2 / 2 + x ** 4 / 24))
    return np.where(np.abs(x) < 1.57, day, night)


def troposphere_delay_m(lat_rad: float, height_m: float, el_rad, humidity: float = 0.7):
    """Zenith delay of the Saastamoinen model in a standard atmosphere, mapped by 1/cos(zenith).

    The same model and standard atmosphere RTKLIB (and so GNSS-SDR) apply, so a receiver that corrects the
    troposphere sees none of it left in our signals.
    """
    el = np.asarray(el_rad, dtype=np.float64)
    if height_m < -100.0 or height_m > 1e4:
        return np.zeros_like(el)
    h = max(height_m, 0.0)
    pressure_hpa = 1013.25 * (1.0 - 2.2557e-5 * h) ** 5.2568
    temp_k = 15.0 - 6.5e-3 * h + 273.16
    e_hpa = 6.108 * humidity * np.exp((17.15 * temp_k - 4684.0) / (temp_k - 38.45))
    cos_z = np.cos(np.pi / 2 - np.maximum(el, 1e-3))
    dry = 0.0022768 * pressure_hpa / (1.0 - 0.00266 * np.cos(2 * lat_rad) - 0.00028 * h / 1e3) / cos_z
    wet = 0.002277 * (1255.0 / temp_k + 0.05) * e_hpa / cos_z
    return np.where(el > 0, dry + wet, 0.0)


def iono_delay_m(iono: IonoParams | None, lat_rad, lon_rad, az_rad, el_rad, tow_s):
    """Klobuchar delay in metres, or zero without coefficients."""
    if iono is None:
        return np.zeros_like(np.asarray(el_rad, dtype=np.float64))
    return SPEED_OF_LIGHT_M_S * klobuchar_delay_s(iono, lat_rad, lon_rad, az_rad, el_rad, tow_s)
