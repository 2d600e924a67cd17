"""Single point positioning against observations made with the simulator's own physics."""

from dataclasses import replace
from datetime import datetime

import numpy as np
import pymap3d
import pytest

from semperfi.gps.constants import L1_WAVELENGTH_M, OMEGA_EARTH_RAD_S, SPEED_OF_LIGHT_M_S as C
from semperfi.gps.ephemeris import satellite_clock, satellite_position, stack_ephemerides
from semperfi.gps.geometry import geodetic_to_ecef
from semperfi.gps.time import GpsTime
from semperfi.receiver.integrity import IntegrityConfig
from semperfi.receiver.pvt import residual_check, solve
from semperfi.receiver.types import Observation
from semperfi.sim.constellation import DEFAULT_IONO, build_constellation, synthesize
from semperfi.sim.propagation import arrival

START = GpsTime.from_datetime(datetime(2024, 6, 1, 12, 0, 0))
BOSTON = (42.3398, -71.0892, 10.0)
SYDNEY = (-33.8688, 151.2093, 58.0)
BIAS_S = 2.5e-4            # receiver clock ahead of GPS time: 75 km
DRIFT_S_S = 5e-8           # 15 m/s of clock drift
T_RX_S = 12.5              # receiver time since the first sample, carried through untouched


def ecef(lat_deg, lon_deg, h_m):
    return geodetic_to_ecef(np.radians(lat_deg), np.radians(lon_deg), h_m)


def observe(ephemerides, pos_m, tow_s, iono, troposphere, vel_m_s=np.zeros(3), bias_s=BIAS_S,
            drift_s_s=DRIFT_S_S, noise_m=0.0, seed=0, min_el_deg=0.0):
    """Observations exactly as the receiver reads them off the simulator's signal at GPS time tow_s.

    P = code pseudorange + c * bias; t_sv = receiver clock - P/c; Doppler from the range rate plus the clock drift.
    """
    prns = sorted(ephemerides)
    arr = arrival(stack_ephemerides(ephemerides[p] for p in prns), pos_m, vel_m_s, tow_s, iono, troposphere)
    noise = np.random.default_rng(seed).normal(0.0, noise_m, len(prns))
    t_rx_clock = tow_s + bias_s
    obs = []
    for i, prn in enumerate(prns):
        if arr.elevation_rad[i] <= np.radians(min_el_deg):
            continue
        p = arr.code_m[i] + C * bias_s + noise[i]
        doppler = -(arr.range_rate_m_s[i] + C * drift_s_s) / L1_WAVELENGTH_M
        obs.append(Observation(prn, float(p), float(t_rx_clock - p / C), float(doppler), 45.0, ephemerides[prn]))
    return obs, dict(zip(prns, np.degrees(arr.elevation_rad)))


@pytest.fixture(scope="module")
def synth():
    return synthesize(START)


@pytest.fixture(scope="module")
def boston():
    return ecef(*BOSTON)


def pos_error_m(fix, truth_m):
    return float(np.linalg.norm(fix.pos_ecef_m - truth_m))


@pytest.mark.parametrize("atmosphere", [True, False])
def test_noise_free_fix_is_the_truth_within_a_centimetre(synth, boston, atmosphere):
    tow = START.tow_s + 40.0
    iono = DEFAULT_IONO if atmosphere else None
    obs, el_deg = observe(synth, boston, tow, iono, atmosphere)
    fix = solve(obs, T_RX_S, START.week, iono, troposphere=atmosphere)
    assert fix is not None
    err = pos_error_m(fix, boston)
    assert err < 0.01, f"position off by {err:.4f} m"
    assert abs(fix.clock_bias_m - C * BIAS_S) < 0.01, f"clock bias {fix.clock_bias_m:.4f} m vs {C * BIAS_S:.4f} m"
    assert abs(fix.gps_tow_s - tow) < 1e-8 and fix.gps_week == START.week and fix.t_rx_s == T_RX_S
    assert abs(fix.lat_deg - BOSTON[0]) < 1e-7 and abs(fix.lon_deg - BOSTON[1]) < 1e-7
    assert abs(fix.height_m - BOSTON[2]) < 0.01
    above = tuple(sorted(p for p, e in el_deg.items() if e >= 5.0))
    assert len(obs) > len(above), "the scenario should hold satellites between the horizon and the mask"
    assert tuple(sorted(fix.prns)) == above and fix.n_sats == len(above)
    assert fix.residual_rms_m < 1e-3


def test_the_atmosphere_corrections_matter(synth, boston):
    """Solving atmosphere-laden pseudoranges without the corrections lands metres away: the corrections are real."""
    obs, _ = observe(synth, boston, START.tow_s + 40.0, DEFAULT_IONO, True)
    no_iono = solve(obs, T_RX_S, START.week, None, troposphere=True)
    no_tropo = solve(obs, T_RX_S, START.week, DEFAULT_IONO, troposphere=False)
    assert pos_error_m(no_iono, boston) > 1.0, f"{pos_error_m(no_iono, boston):.3f} m without the ionosphere"
    assert pos_error_m(no_tropo, boston) > 1.0, f"{pos_error_m(no_tropo, boston):.3f} m without the troposphere"


def independent_dops(ephemerides, prns, pos_m, lla, tow_s):
    """DOPs from pymap3d's azimuth/elevation of each satellite, nothing from the product."""
    sat = np.array([satellite_position(ephemerides[p], tow_s - 0.075) for p in prns])
    az, el, _ = pymap3d.ecef2aer(sat[:, 0], sat[:, 1], sat[:, 2], *lla)
    az, el = np.radians(az), np.radians(el)
    h = np.column_stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el), np.ones(len(prns))])
    q = np.diag(np.linalg.inv(h.T @ h))
    return np.sqrt(q[:3].sum()), np.sqrt(q[:2].sum()), np.sqrt(q[2])


def test_one_metre_noise_stays_within_five_metres_and_dops_are_right(synth, boston):
    tow = START.tow_s + 40.0
    errors = []
    for seed in range(10):
        obs, _ = observe(synth, boston, tow, DEFAULT_IONO, True, noise_m=1.0, seed=seed)
        fix = solve(obs, T_RX_S, START.week, DEFAULT_IONO)
        assert fix is not None
        errors.append(pos_error_m(fix, boston))
        assert 0.2 < fix.residual_rms_m < 2.0, f"seed {seed}: residual RMS {fix.residual_rms_m:.2f} m for 1 m noise"
    assert max(errors) < 5.0, f"errors {np.round(errors, 2)} m with 1 m noise"
    assert max(errors) > 0.05, "noise should move the fix"
    pdop, hdop, vdop = independent_dops(synth, fix.prns, boston, BOSTON, tow)
    assert fix.pdop == pytest.approx(pdop, rel=1e-4), f"PDOP {fix.pdop:.4f} vs {pdop:.4f}"
    assert fix.hdop == pytest.approx(hdop, rel=1e-4), f"HDOP {fix.hdop:.4f} vs {hdop:.4f}"
    assert fix.vdop == pytest.approx(vdop, rel=1e-4), f"VDOP {fix.vdop:.4f} vs {vdop:.4f}"


def test_moving_receiver_velocity_and_clock_drift(synth, boston):
    lat, lon = np.radians(BOSTON[0]), np.radians(BOSTON[1])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    vel = 10.0 * east + 2.0 * up
    obs, _ = observe(synth, boston, START.tow_s + 40.0, DEFAULT_IONO, True, vel_m_s=vel)
    fix = solve(obs, T_RX_S, START.week, DEFAULT_IONO)
    verr = float(np.linalg.norm(fix.vel_ecef_m_s - vel))
    # the model is exact here, so hold it to 1 mm/s: tight enough to notice a satellite clock drift left out
    assert verr < 1e-3, f"velocity {fix.vel_ecef_m_s} vs {vel}: {verr * 1e3:.3f} mm/s off"
    assert abs(fix.clock_drift_m_s - C * DRIFT_S_S) < 1e-3, \
        f"drift {fix.clock_drift_m_s:.4f} vs {C * DRIFT_S_S:.4f} m/s"
    assert pos_error_m(fix, boston) < 0.01


def test_a_prior_fix_gives_the_same_answer(synth, boston):
    tow = START.tow_s + 40.0
    first = solve(observe(synth, boston, tow, DEFAULT_IONO, True)[0], T_RX_S, START.week, DEFAULT_IONO)
    later = boston + np.array([30.0, -20.0, 10.0])      # moved a little; the clock ran on
    obs, _ = observe(synth, later, tow + 1.0, DEFAULT_IONO, True, bias_s=BIAS_S + DRIFT_S_S)
    fix = solve(obs, T_RX_S + 1.0, START.week, DEFAULT_IONO, prior=first)
    assert pos_error_m(fix, later) < 0.01
    assert abs(fix.gps_tow_s - (tow + 1.0)) < 1e-8


def test_too_few_satellites_is_none(synth, boston):
    obs, el_deg = observe(synth, boston, START.tow_s + 40.0, DEFAULT_IONO, True)
    high = sorted(obs, key=lambda o: -el_deg[o.prn])
    assert solve(high[:3], T_RX_S, START.week, DEFAULT_IONO) is None
    assert solve([], T_RX_S, START.week, DEFAULT_IONO) is None
    low = [o for o in obs if el_deg[o.prn] < 5.0]
    assert low, "the scenario should hold a satellite below the mask"
    four = high[:3] + low[:1]      # four satellites, but one under the 5 degree mask
    assert solve(four, T_RX_S, START.week, DEFAULT_IONO) is None
    assert solve(high[:4], T_RX_S, START.week, DEFAULT_IONO) is not None


@pytest.mark.parametrize("seed", range(12))
def test_garbage_pseudoranges_are_none_not_an_exception(synth, boston, seed):
    obs, _ = observe(synth, boston, START.tow_s + 40.0, DEFAULT_IONO, True)
    rng = np.random.default_rng(seed)
    t_rx_clock = obs[0].t_sv_s + obs[0].pseudorange_m / C
    garbage = []
    for o in obs:
        p = float(rng.uniform(1.9e7, 2.6e7))
        garbage.append(replace(o, pseudorange_m=p, t_sv_s=t_rx_clock - p / C))
    assert solve(garbage, T_RX_S, START.week, DEFAULT_IONO) is None


def test_non_finite_and_degenerate_inputs_are_none(synth, boston):
    obs, _ = observe(synth, boston, START.tow_s + 40.0, DEFAULT_IONO, True)
    nan = [replace(o, pseudorange_m=float("nan")) for o in obs]
    assert solve(nan, T_RX_S, START.week, DEFAULT_IONO) is None
    same = [replace(obs[0], prn=p) for p in range(1, 9)]    # one satellite eight times: no geometry
    assert solve(same, T_RX_S, START.week, DEFAULT_IONO) is None
    zero = [replace(o, pseudorange_m=0.0, t_sv_s=obs[0].t_sv_s) for o in obs]
    assert solve(zero, T_RX_S, START.week, DEFAULT_IONO) is None


def test_residual_check_sees_a_faulty_satellite(synth, boston):
    """A 60 m fault shows in the post-fit residuals, and a fix without that satellite measures it outright."""
    obs, el_deg = observe(synth, boston, START.tow_s + 40.0, DEFAULT_IONO, True)
    bad = max((o for o in obs if el_deg[o.prn] > 5.0), key=lambda o: el_deg[o.prn])
    faulty = [replace(o, pseudorange_m=o.pseudorange_m + 60.0) if o is bad else o for o in obs]
    fix = solve(faulty, T_RX_S, START.week, DEFAULT_IONO, raim=IntegrityConfig(exclude=False))
    assert fix.raim == "fail", fix.raim
    res = residual_check(fix, faulty, DEFAULT_IONO)
    assert set(res) == {o.prn for o in obs}
    used = np.array([res[p] for p in fix.prns])
    assert np.sqrt(np.mean(used ** 2)) == pytest.approx(fix.residual_rms_m, rel=1e-9)
    assert res[bad.prn] > 20.0 and fix.residual_rms_m > 5.0, f"PRN {bad.prn}: {res[bad.prn]:.1f} m, {res}"
    others = solve([o for o in faulty if o.prn != bad.prn], T_RX_S, START.week, DEFAULT_IONO)
    loo = residual_check(others, faulty, DEFAULT_IONO)
    assert loo[bad.prn] == pytest.approx(60.0, abs=0.01), f"left-out PRN {bad.prn}: {loo[bad.prn]:.3f} m"
    assert max(abs(r) for p, r in loo.items() if p != bad.prn) < 0.01


def rtklib_style_observations(ephemerides, pos_m, tow_s, sagnac: bool):
    """Pseudoranges written independently of the product: light-time iteration on the unrotated orbit, with the
    Earth's rotation as RTKLIB's first-order correction omega/c (xs yr - ys xr), or none at all."""
    obs = []
    for prn, eph in sorted(ephemerides.items()):
        t_tx = tow_s - 0.075
        for _ in range(5):
            s = satellite_position(eph, t_tx)
            rho = np.linalg.norm(s - pos_m)
            if sagnac:
                rho += OMEGA_EARTH_RAD_S * (s[0] * pos_m[1] - s[1] * pos_m[0]) / C
            t_tx = tow_s - rho / C
        up = pos_m / np.linalg.norm(pos_m)
        if np.dot(s - pos_m, up) / np.linalg.norm(s - pos_m) < np.sin(np.radians(10.0)):
            continue
        p = rho - C * float(satellite_clock(eph, t_tx)[0]) + C * BIAS_S
        obs.append(Observation(prn, p, tow_s + BIAS_S - p / C, 0.0, 45.0, eph))
    return obs


def test_sagnac_against_an_independent_first_order_model(synth, boston):
    tow = START.tow_s + 40.0
    with_rotation = solve(rtklib_style_observations(synth, boston, tow, True), T_RX_S, START.week, None, False)
    assert pos_error_m(with_rotation, boston) < 0.01, f"{pos_error_m(with_rotation, boston):.4f} m off"
    # a world without Earth rotation: the receiver, which applies it, must now land tens of metres away
    without = solve(rtklib_style_observations(synth, boston, tow, False), T_RX_S, START.week, None, False)
    err = pos_error_m(without, boston)
    assert 10.0 < err < 200.0, f"omitting the Earth's rotation moved the fix by only {err:.2f} m"


def test_sydney_from_broadcast_ephemerides(brdc_path):
    cfg = {"constellation": {"rinex": str(brdc_path)}, "time": {"start": "2022-01-01T03:00:00"}}
    const = build_constellation(cfg)
    truth = ecef(*SYDNEY)
    tow = const.start.tow_s + 17.0
    vel = np.array([3.0, -4.0, 1.0])
    obs, _ = observe(const.ephemerides, truth, tow, const.iono, True, vel_m_s=vel)
    fix = solve(obs, T_RX_S, const.start.week, const.iono)
    assert fix is not None and fix.n_sats >= 6
    err = pos_error_m(fix, truth)
    assert err < 0.01, f"Sydney fix {err:.4f} m off ({fix.n_sats} satellites)"
    assert abs(fix.lat_deg - SYDNEY[0]) < 1e-7 and abs(fix.lon_deg - SYDNEY[1]) < 1e-7
    assert abs(fix.clock_bias_m - C * BIAS_S) < 0.01
    verr = float(np.linalg.norm(fix.vel_ecef_m_s - vel))
    assert verr < 1e-3, f"Sydney velocity {verr * 1e3:.3f} mm/s off"
    assert abs(fix.clock_drift_m_s - C * DRIFT_S_S) < 1e-3


@pytest.mark.parametrize("bias_s", [-0.012, 0.0, 0.019])
def test_a_receiver_clock_far_off_gps_time_still_fixes(synth, boston, bias_s):
    """A receiver that starts its clock from a guess is milliseconds (thousands of km) off; that is only a bias."""
    tow = START.tow_s + 40.0
    obs, _ = observe(synth, boston, tow, DEFAULT_IONO, True, bias_s=bias_s)
    fix = solve(obs, T_RX_S, START.week, DEFAULT_IONO)
    assert pos_error_m(fix, boston) < 0.01 and abs(fix.clock_bias_m - C * bias_s) < 0.01
    assert abs(fix.gps_tow_s - tow) < 1e-8


def test_a_prior_on_the_other_side_of_the_earth_does_not_mislead(synth, boston):
    sydney_fix = replace(solve(observe(synth, boston, START.tow_s, DEFAULT_IONO, True)[0], T_RX_S, START.week,
                               DEFAULT_IONO), pos_ecef_m=ecef(*SYDNEY), clock_bias_m=0.0)
    obs, _ = observe(synth, boston, START.tow_s + 40.0, DEFAULT_IONO, True)
    fix = solve(obs, T_RX_S, START.week, DEFAULT_IONO, prior=sydney_fix)
    assert fix is not None and pos_error_m(fix, boston) < 0.01


def test_a_fix_carries_its_time_protection_level_in_ns(synth, boston):
    obs, _ = observe(synth, boston, START.tow_s, DEFAULT_IONO, True, min_el_deg=5.0)
    fix = solve(obs, 1.0, START.week, DEFAULT_IONO)
    assert fix.raim == "pass" and 5.0 < fix.tpl_ns < 300.0, (fix.raim, fix.tpl_ns)
    assert 0.0 < fix.clock_sigma_ns < fix.tpl_ns and fix.time_state == "unverified"
    four = solve(obs[:4], 1.0, START.week, DEFAULT_IONO)
    assert np.isnan(four.tpl_ns)
