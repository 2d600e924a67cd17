"""Satellite positions and clocks from brdc0010.22n against an independent scalar computation and physics."""

import math

import numpy as np
import pytest

from semperfi.gps.ephemeris import satellite_clock, satellite_position_velocity
from semperfi.iq.rinex import read_rinex_nav


def textbook_position(eph, t):
    """IS-GPS-200 Table 20-IV written out longhand with the math module, one instant at a time."""
    mu, we = 3.986005e14, 7.2921151467e-5
    a = eph.sqrt_a_sqrt_m ** 2
    tk = t - eph.toe_s
    if tk > 302400:
        tk -= 604800
    if tk < -302400:
        tk += 604800
    m = eph.m0_rad + (math.sqrt(mu / a ** 3) + eph.delta_n_rad_s) * tk
    e_anom = m
    for _ in range(50):   # fixed-point iteration, unlike the Newton iteration of the product
        e_anom = m + eph.e * math.sin(e_anom)
    nu = 2 * math.atan(math.sqrt((1 + eph.e) / (1 - eph.e)) * math.tan(e_anom / 2))
    phi = nu + eph.omega_rad
    u = phi + eph.cus_rad * math.sin(2 * phi) + eph.cuc_rad * math.cos(2 * phi)
    r = a * (1 - eph.e * math.cos(e_anom)) + eph.crs_m * math.sin(2 * phi) + eph.crc_m * math.cos(2 * phi)
    i = eph.i0_rad + eph.idot_rad_s * tk + eph.cis_rad * math.sin(2 * phi) + eph.cic_rad * math.cos(2 * phi)
    om = eph.omega0_rad + (eph.omega_dot_rad_s - we) * tk - we * eph.toe_s
    orbit = np.array([r * math.cos(u), r * math.sin(u), 0.0])
    rot_i = np.array([[1, 0, 0], [0, math.cos(i), -math.sin(i)], [0, math.sin(i), math.cos(i)]])
    rot_om = np.array([[math.cos(om), -math.sin(om), 0], [math.sin(om), math.cos(om), 0], [0, 0, 1]])
    return rot_om @ rot_i @ orbit


@pytest.fixture(scope="module")
def nav(brdc_path):
    return read_rinex_nav(brdc_path)


def test_reads_all_gps_satellites(nav):
    prns = {e.prn for e in nav.ephemerides}
    assert len(prns) >= 30, prns
    assert nav.iono.alpha[0] == pytest.approx(1.211e-08)
    assert nav.utc.delta_t_ls_s == 18


def test_positions_match_the_textbook_computation(nav):
    worst = 0.0
    for eph in nav.ephemerides[::7]:
        for dt in (-7200.0, -1800.0, 0.0, 900.0, 7200.0):
            t = (eph.toe_s + dt) % 604800
            pos, _ = satellite_position_velocity(eph, t)
            worst = max(worst, float(np.linalg.norm(pos - textbook_position(eph, t))))
    assert worst < 1e-3, f"largest difference {worst:.2e} m"


def test_consecutive_broadcast_sets_agree_where_they_overlap(nav):
    """Two ephemerides of the same satellite, two hours apart, describe the same orbit to a few metres."""
    by_prn = {}
    for eph in nav.ephemerides:
        by_prn.setdefault(eph.prn, []).append(eph)
    gaps = []
    for ephs in by_prn.values():
        ephs.sort(key=lambda e: e.toe_s)
        for a, b in zip(ephs, ephs[1:]):
            if b.toe_s - a.toe_s == 7200.0:
                t = a.toe_s + 3600.0
                gaps.append(np.linalg.norm(satellite_position_velocity(a, t)[0] - satellite_position_velocity(b, t)[0]))
                ca, cb = satellite_clock(a, t)[0], satellite_clock(b, t)[0]
                gaps.append(abs(ca - cb) * 299792458.0)
    assert len(gaps) > 100
    assert np.percentile(gaps, 95) < 5.0, f"95th percentile {np.percentile(gaps, 95):.2f} m"


def test_velocity_is_the_derivative_of_position(nav):
    eph = nav.ephemerides[3]
    t = np.array([eph.toe_s - 3000.0, eph.toe_s + 100.0, eph.toe_s + 5000.0])
    _, vel = satellite_position_velocity(eph, t)
    h = 0.05
    numeric = (satellite_position_velocity(eph, t + h)[0] - satellite_position_velocity(eph, t - h)[0]) / (2 * h)
    assert np.max(np.abs(vel - numeric)) < 1e-4
    radius = np.linalg.norm(satellite_position_velocity(eph, t)[0], axis=1)
    assert np.all((radius > 2.6e7) & (radius < 2.7e7))


def test_clock_includes_the_relativistic_term(nav):
    eph = max(nav.ephemerides, key=lambda e: e.e)
    t = np.linspace(eph.toe_s, eph.toe_s + 43082, 200)   # one orbit
    clock, drift = satellite_clock(eph, t)
    linear = eph.af0_s + eph.af1_s_s * (t - eph.toc_s) + eph.af2_s_s2 * (t - eph.toc_s) ** 2 - eph.tgd_s
    rel = clock - linear
    # amplitude F e sqrt(A): tens of nanoseconds for e ~ 0.02
    assert np.max(np.abs(rel)) == pytest.approx(4.442807633e-10 * eph.e * eph.sqrt_a_sqrt_m, rel=1e-3)
    numeric = np.gradient(clock, t)
    assert np.max(np.abs(drift[1:-1] - numeric[1:-1])) < 1e-13


def test_garbled_rinex_is_one_clear_error(tmp_path):
    bad = tmp_path / "bad.22n"
    bad.write_text("this is not\na navigation file\n" * 10)
    with pytest.raises(ValueError, match="bad.22n"):
        read_rinex_nav(bad)
    with pytest.raises(ValueError, match="not found"):
        read_rinex_nav(tmp_path / "missing.22n")
