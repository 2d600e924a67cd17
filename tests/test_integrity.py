"""RAIM: the chi-square residual test, fault detection and exclusion, and protection levels, on real geometry."""

import csv
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from semperfi.gps.geometry import enu_rotation
from semperfi.receiver import integrity
from semperfi.receiver.pvt import _solve_once, solve
from semperfi.sim.constellation import DEFAULT_IONO

from test_pvt import BOSTON, START, ecef, observe, synth  # noqa: F401  (fixture)

PFA = 0.01                  # high enough to count false alarms in a few thousand trials
CFG = integrity.IntegrityConfig(pfa=PFA, pmd=1e-3)
CN0_DBHZ = 45.0


@pytest.fixture(scope="module")
def scene(synth):  # noqa: F811 -- synth is test_pvt's fixture, imported above for its name
    """Noise-free observations, the linearised geometry (ENU) and each range's sigma at Boston."""
    truth = ecef(*BOSTON)
    obs, _ = observe(synth, truth, START.tow_s, DEFAULT_IONO, True, min_el_deg=5.0)
    fix, sats, model = _solve_once(obs, 1.0, START.week, DEFAULT_IONO)
    use = model.use
    rot = enu_rotation(np.radians(fix.lat_deg), np.radians(fix.lon_deg))
    h = np.column_stack([-model.los[use] @ rot.T, np.ones(int(use.sum()))])
    sigma = integrity.sigma_m(np.full(int(use.sum()), CN0_DBHZ), model.elevation_rad[use], CFG.sigma)
    obs = [o for o, u in zip(obs, use) if u]
    return truth, obs, h, sigma, rot


def test_sigma_model_falls_with_cn0_and_has_a_floor():
    s = integrity.sigma_m([30.0, 45.0, 55.0], np.radians([90.0, 90.0, 90.0]))
    assert s[0] > s[1] > s[2] >= np.hypot(0.5, 0.5), s
    raw = integrity.sigma_m([35.0], [np.pi / 2], integrity.SigmaModel(smoothing_s=0, floor_m=0, atmosphere_m=0))
    assert 1.0 < raw[0] < 6.0, f"unsmoothed DLL sigma at 35 dB-Hz, 0.5 chip, 2 Hz: {raw[0]:.2f} m"


def test_clean_ranges_pass_at_the_false_alarm_rate(scene):
    _, _, h, sigma, _ = scene
    rng = np.random.default_rng(1)
    trials = 4000
    alarms = sum(integrity.fde(h, rng.normal(0, sigma), sigma, CFG).status != "pass" for _ in range(trials))
    lo, hi = stats.binom.ppf([1e-4, 1 - 1e-4], trials, PFA)
    assert lo <= alarms <= hi, f"{alarms} alarms in {trials} clean trials, expected {PFA * trials:.0f} [{lo}, {hi}]"


def test_protection_levels_bound_the_clean_error(scene):
    _, _, h, sigma, _ = scene
    hpl, vpl = integrity.protection_levels(h, sigma, CFG.pfa, CFG.pmd)
    w = 1 / sigma ** 2
    k = np.linalg.solve(h.T @ (h * w[:, None]), h.T * w)
    err = k @ np.random.default_rng(2).normal(0, sigma[:, None], (len(sigma), 5000))
    h_ok = np.mean(np.hypot(err[0], err[1]) <= hpl)
    v_ok = np.mean(np.abs(err[2]) <= vpl)
    assert h_ok >= 0.99 and v_ok >= 0.99, f"HPL {hpl:.1f} m bounds {h_ok:.4f}, VPL {vpl:.1f} m bounds {v_ok:.4f}"
    assert 1.0 < hpl < 50.0, f"HPL {hpl:.1f} m with {len(sigma)} satellites at {CN0_DBHZ} dB-Hz"


def test_time_protection_level_bounds_the_clean_clock_error_and_a_missed_fault(scene):
    _, _, h, sigma, _ = scene
    tpl = integrity.time_protection_level(h, sigma, CFG.pfa, CFG.pmd)
    w = 1 / sigma ** 2
    k = np.linalg.solve(h.T @ (h * w[:, None]), h.T * w)
    err = k[3] @ np.random.default_rng(6).normal(0, sigma[:, None], (len(sigma), 5000))
    assert np.mean(np.abs(err) <= tpl) >= 0.999, f"TPL {tpl:.1f} m bounds {np.mean(np.abs(err) <= tpl):.4f}"
    assert np.sqrt(np.linalg.inv(h.T @ (h * w[:, None]))[3, 3]) == pytest.approx(integrity.clock_sigma(h, sigma))
    # a fault on one range just large enough to be missed (the test at its threshold) moves the clock at most TPL
    rng = np.random.default_rng(7)
    for i in range(len(sigma)):
        for _ in range(50):
            y = rng.normal(0, sigma)
            y[i] += rng.uniform(-1, 1) * 40.0
            if integrity.chi2_test(h, y, sigma, CFG.pfa).passed:
                assert abs(k[3] @ y) <= tpl, (i, k[3] @ y, tpl)
    assert np.isnan(integrity.time_protection_level(h[:4], sigma[:4], CFG.pfa, CFG.pmd))


@pytest.mark.parametrize("bias_m", [100.0, 300.0])
def test_one_biased_range_is_detected_and_excluded(scene, bias_m):
    _, _, h, sigma, _ = scene
    rng = np.random.default_rng(3)
    right = 0
    for trial in range(200):
        y = rng.normal(0, sigma)
        bad = trial % len(sigma)
        y[bad] += bias_m
        r = integrity.fde(h, y, sigma, CFG)
        right += r.status == "excluded" and r.excluded == (bad,)
    assert right >= 195, f"{right}/200 fixes excluded the right range biased by {bias_m} m"


def test_two_ranges_pulled_together_are_detected(scene):
    _, _, h, sigma, _ = scene
    rng = np.random.default_rng(4)
    detected = 0
    for trial in range(200):
        y = rng.normal(0, sigma)
        a, b = trial % len(sigma), (trial + 1) % len(sigma)
        y[[a, b]] += 100.0
        r = integrity.fde(h, y, sigma, CFG)
        detected += r.status == "fail" or (r.status == "excluded" and {a, b} <= set(r.excluded))
    assert detected >= 190, f"two ranges biased by 100 m: {detected}/200 detected (failed or both excluded)"


def test_a_sky_that_agrees_only_without_two_ranges_is_not_trusted(scene):
    """The protection levels bound the error under one faulty range: two ranges pulled apart are never excluded both
    and called good (a spoofer from power-on, half the channels on it, made 5 of 8 agree 186 m off, HPL 30-74 m).
    Asked for, a second exclusion is still made."""
    _, _, h, sigma, _ = scene
    rng = np.random.default_rng(6)
    for trial in range(50):
        y = rng.normal(0, sigma)
        a, b = trial % len(sigma), (trial + 3) % len(sigma)
        y[a] += 400.0
        y[b] -= 400.0
        r = integrity.fde(h, y, sigma, CFG)
        assert r.status == "fail" and len(r.excluded) == 1 and not integrity.trusted(r.status), (r.status, r.excluded)
        two = integrity.fde(h, y, sigma, replace(CFG, max_exclusions=2))
        assert two.status == "excluded" and set(two.excluded) == {a, b}, (two.status, two.excluded)


def test_four_satellites_are_unverifiable(scene):
    truth, obs, _, _, _ = scene
    fix = solve(obs[:4], 1.0, START.week, DEFAULT_IONO, raim=CFG)
    assert fix is not None and fix.raim == "unverifiable" and not integrity.trusted(fix.raim), fix.raim
    assert np.isnan(fix.hpl_m)


def test_solve_excludes_the_faulty_prn_and_lands_on_the_truth(scene):
    truth, obs, _, sigma, _ = scene
    rng = np.random.default_rng(5)
    noisy = [replace(o, pseudorange_m=o.pseudorange_m + rng.normal(0, s)) for o, s in zip(obs, sigma)]
    clean = solve(noisy, 1.0, START.week, DEFAULT_IONO, raim=CFG)
    assert clean.raim == "pass" and integrity.trusted(clean.raim), clean.raim
    err = np.linalg.norm(clean.pos_ecef_m - truth)
    assert err < clean.hpl_m, f"clean error {err:.2f} m, HPL {clean.hpl_m:.2f} m"
    bad = noisy[2].prn
    faulty = [replace(o, pseudorange_m=o.pseudorange_m + 300.0) if o.prn == bad else o for o in noisy]
    fix = solve(faulty, 1.0, START.week, DEFAULT_IONO, raim=CFG)
    err = np.linalg.norm(fix.pos_ecef_m - truth)
    assert fix.raim == "excluded" and fix.excluded_prns == (bad,) and bad not in fix.prns, (fix.raim, fix.excluded_prns)
    assert err < 5.0, f"after excluding PRN {bad}: {err:.2f} m from the truth"


def test_clean_simulated_recording_passes_raim_with_realistic_protection_levels(tmp_path, brdc_path):
    from test_receiver import enu_errors, read_fixes, receive, simulate
    simulate(tmp_path / "a.bin", f'constellation.rinex="{brdc_path}"', 'time.start="2022-01-01T00:00:27"',
             duration=16.0)
    receive(tmp_path / "a.bin", tmp_path / "out", str(brdc_path))
    fixes = read_fixes(tmp_path / "out")
    assert fixes, "no fix"
    raim = [f["raim"] for f in fixes]
    passed = sum(r == "pass" for r in raim) / len(raim)
    hpl = np.array([float(f["hpl_m"]) for f in fixes])
    horizontal = np.hypot(*enu_errors(fixes)[:, :2].T)
    assert passed >= 0.95, f"{passed:.1%} of {len(fixes)} clean fixes pass RAIM: {sorted(set(raim))}"
    assert np.all((hpl > 1.0) & (hpl < 100.0)), f"HPL {hpl.min():.1f}..{hpl.max():.1f} m"
    assert np.all(horizontal <= hpl), f"error {horizontal.max():.1f} m exceeds HPL"
    # the time: the truth's GPS time of each fix's sample against the fix's, within RAIM's TPL (a clean sky: no
    # common delay for it to miss)
    truth = list(csv.DictReader(open(tmp_path / "a.truth-receiver.csv")))
    t = np.array([float(r["t_rx_s"]) for r in truth])
    tow = np.array([float(r["gps_tow_s"]) for r in truth])
    err_ns = np.array([(float(f["gps_tow_s"]) - np.interp(float(f["t_rx_s"]), t, tow)) * 1e9 for f in fixes])
    tpl = np.array([float(f["tpl_ns"]) for f in fixes])
    assert np.all((tpl > 5.0) & (tpl < 300.0)), f"TPL {tpl.min():.1f}..{tpl.max():.1f} ns"
    assert np.all(np.abs(err_ns) <= tpl), f"time error {np.abs(err_ns).max():.1f} ns exceeds TPL"
    assert {f["time_state"] for f in fixes} == {"unverified"}   # the receiver alone checks no common delay


def test_the_solution_sigmas_are_the_uere_times_the_dops_when_every_range_has_the_same_sigma():
    """An autopilot's hAcc/vAcc (GPS_INPUT) are these 1 sigma values: with equal range sigmas, sigma x HDOP and
    sigma x VDOP by the DOPs' definition; a faulty range's bound (HPL) is several times more."""
    from semperfi.receiver.integrity import protection_levels, solution_sigmas
    az = np.radians([0.0, 70.0, 140.0, 210.0, 280.0, 330.0, 45.0])
    el = np.radians([80.0, 40.0, 25.0, 55.0, 15.0, 35.0, 60.0])
    los = np.column_stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])
    h = np.column_stack([-los, np.ones(len(az))])
    q = np.linalg.inv(h.T @ h)
    hdop, vdop = np.sqrt(q[0, 0] + q[1, 1]), np.sqrt(q[2, 2])
    h_sigma, v_sigma, t_sigma = solution_sigmas(h, np.full(len(az), 3.0))
    assert h_sigma == pytest.approx(3.0 * hdop) and v_sigma == pytest.approx(3.0 * vdop)
    assert t_sigma == pytest.approx(3.0 * np.sqrt(q[3, 3]))
    hpl, vpl = protection_levels(h, np.full(len(az), 3.0), 1e-5, 1e-3)
    assert hpl > 2.0 * h_sigma and vpl > 2.0 * v_sigma
