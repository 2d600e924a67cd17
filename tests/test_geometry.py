"""The gps room's geodesy (numpy only, vectorised over satellites and epochs, as DESIGN.md asks of gps/) against
pymap3d, the field's library, on points from the sea floor to GPS orbit."""

import numpy as np
import pymap3d

from semperfi.gps.geometry import azimuth_elevation, ecef_to_geodetic, enu_rotation, geodetic_to_ecef


def _points(n=500, seed=3):
    rng = np.random.default_rng(seed)
    return rng.uniform(-90, 90, n), rng.uniform(-180, 180, n), rng.uniform(-500.0, 2.2e7, n)


def test_geodetic_and_ecef_agree_with_pymap3d_to_a_millimetre():
    lat, lon, h = _points()
    mine = geodetic_to_ecef(np.radians(lat), np.radians(lon), h).T
    theirs = np.array(pymap3d.geodetic2ecef(lat, lon, h))
    assert np.max(np.abs(mine - theirs)) < 1e-3
    # the inverse returns pymap3d's input exactly (pymap3d's own inverse drifts by up to 1e-4 deg at orbit heights)
    back = ecef_to_geodetic(theirs.T)
    assert np.max(np.abs(np.degrees(back[0]) - lat)) < 1e-10 and np.max(np.abs(back[2] - h)) < 1e-4
    assert np.max(np.abs((np.degrees(back[1]) - lon + 180) % 360 - 180)) < 1e-10
    ground = h < 1e5                     # and agrees with pymap3d's inverse near the ground
    lat2, _, h2 = pymap3d.ecef2geodetic(*theirs[:, ground])
    assert np.max(np.abs(np.degrees(back[0][ground]) - lat2)) < 1e-8 and np.max(np.abs(back[2][ground] - h2)) < 1e-3


def test_enu_and_elevation_agree_with_pymap3d():
    lat, lon, h = 42.3398, -71.0892, 10.0
    rx = np.array(pymap3d.geodetic2ecef(lat, lon, h))
    sat_lat, sat_lon, sat_h = _points(200, seed=4)
    sats = np.array(pymap3d.geodetic2ecef(sat_lat, sat_lon, np.full(200, 2.02e7))).T
    enu = (sats - rx) @ enu_rotation(np.radians(lat), np.radians(lon)).T
    want = np.array(pymap3d.ecef2enu(sats[:, 0], sats[:, 1], sats[:, 2], lat, lon, h)).T
    assert np.max(np.abs(enu - want)) < 1e-3
    az, el = azimuth_elevation(rx, sats)
    az2, el2, _ = pymap3d.ecef2aer(sats[:, 0], sats[:, 1], sats[:, 2], lat, lon, h)
    assert np.max(np.abs(np.degrees(el) - el2)) < 1e-7
    assert np.max(np.abs((np.degrees(az) - az2 + 180) % 360 - 180)) < 1e-7
