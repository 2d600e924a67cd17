"""Single point positioning: weighted least squares position, velocity and receiver clock from one epoch.

GPS L1 C/A the way RTKLIB's pntpos does it, inverting exactly the physics the simulator renders:

* transmit time t_tx = t_sv - dt_sv, with dt_sv the L1 C/A satellite clock (polynomial + relativistic - TGD, all of
  it from `satellite_clock`), evaluated once at t_sv and once more at the corrected time;
* the satellite at t_tx, rotated into the ECEF frame of reception by the Earth's turn during the geometric flight
  time (Sagnac), both position and velocity;
* corrected pseudorange P + c dt_sv - ionosphere (Klobuchar) - troposphere (Saastamoinen) = range + c dt_rx;
* Gauss-Newton from the prior fix or the Earth's centre. The atmosphere corrections, the elevation mask and the
  elevation weights need a position, so they switch on once the estimate has settled within COARSE_STEP_M.

Conventions: `Observation.pseudorange_m` = c (t_rx - t_sv) with t_rx the receiver clock in GPS seconds of week, so
t_sv + P/c is the reception instant on the receiver clock; the fix's GPS time is that minus the clock bias.
"""

from dataclasses import dataclass, replace

import numpy as np

from ..gps import (IonoParams, L1_WAVELENGTH_M, SECONDS_PER_WEEK, SPEED_OF_LIGHT_M_S, azimuth_elevation,
                   ecef_to_geodetic, enu_rotation, iono_delay_m, rotate_earth, satellite_clock,
                   satellite_position_velocity, stack_ephemerides, troposphere_delay_m)
from . import integrity
from .types import Fix, Observation

C = SPEED_OF_LIGHT_M_S
MAX_ITERATIONS = 20
CONVERGED_M = 1e-4            # position + clock step that ends the iteration (RTKLIB's value)
COARSE_STEP_M = 1e3           # below this step the position is known well enough for elevations and atmosphere
SIGMA_A_M = 0.3               # code noise floor:            sigma^2 = a^2 + b^2 / sin^2(el)
SIGMA_B_M = 0.3               # elevation-dependent part     (RTKLIB's 0.003 m x code/phase ratio 100)
MIN_SIN_EL = 0.05             # keeps the variance finite for satellites at or below the horizon (mask <= 0)
MAX_HEIGHT_M = 1e6            # a fix further than this from the ellipsoid is absurd
MAX_RESIDUAL_RMS_M = 1e3      # post-fit residuals this large mean the measurements do not fit any one position


@dataclass(frozen=True)
class _Satellites:
    """Everything about the satellites that does not depend on the receiver's position."""
    prn: np.ndarray
    pos_tx_m: np.ndarray      # (n, 3) ECEF at transmit time
    vel_tx_m_s: np.ndarray    # (n, 3)
    clock_m: np.ndarray       # c * dt_sv (relativistic included, TGD removed)
    drift_m_s: np.ndarray     # c * satellite clock drift
    pseudorange_m: np.ndarray
    range_rate_m_s: np.ndarray  # -doppler * wavelength
    weight: np.ndarray
    t_rx_clock_s: float       # reception instant on the receiver clock, GPS seconds of week


@dataclass(frozen=True)
class _Model:
    """The measurement model evaluated at one receiver position and clock bias."""
    range_m: np.ndarray
    los: np.ndarray           # (n, 3) unit vectors receiver -> satellite, reception frame
    sat_pos_m: np.ndarray     # (n, 3) reception frame
    sat_vel_m_s: np.ndarray
    elevation_rad: np.ndarray
    residual_m: np.ndarray    # corrected pseudorange - (range + clock bias)
    use: np.ndarray           # bool: above the mask (everything while the position is still coarse)
    weight: np.ndarray        # inverse variance (1/m^2) times Observation.weight


def _satellites(observations: list[Observation]) -> _Satellites:
    eph = stack_ephemerides(o.ephemeris for o in observations)
    t_sv = np.array([o.t_sv_s for o in observations])
    p = np.array([o.pseudorange_m for o in observations])
    dt_sv, _ = satellite_clock(eph, t_sv)
    dt_sv, _ = satellite_clock(eph, t_sv - dt_sv)      # once more at the transmit time itself (RTKLIB)
    t_tx = t_sv - dt_sv
    clock_s, drift_s_s = satellite_clock(eph, t_tx)
    pos, vel = satellite_position_velocity(eph, t_tx)
    t_rx = t_sv + p / C                                  # equal for all at a common reception instant
    t_rx = t_rx[0] + (t_rx - t_rx[0]) - np.round((t_rx - t_rx[0]) / SECONDS_PER_WEEK) * SECONDS_PER_WEEK
    return _Satellites(np.array([o.prn for o in observations]), pos, vel, C * clock_s, C * drift_s_s, p,
                       -np.array([o.doppler_hz for o in observations]) * L1_WAVELENGTH_M,
                       np.array([o.weight for o in observations], dtype=np.float64), float(np.median(t_rx)))


def _geometric_range(sat_pos_tx_m, receiver_m):
    """Range and satellite position in the reception frame; flight time = geometric range / c, as simulated."""
    rng = np.linalg.norm(sat_pos_tx_m - receiver_m, axis=-1)
    for _ in range(2):      # 130 m of Sagnac shift change the flight time by 0.4 us: two passes leave nanometres
        sat_r = rotate_earth(sat_pos_tx_m, rng / C)
        rng = np.linalg.norm(sat_r - receiver_m, axis=-1)
    return rng, sat_r


def _variance_m2(el_rad):
    """RTKLIB-like code variance: a noise floor plus a part growing towards the horizon."""
    sin_el = np.maximum(np.sin(el_rad), MIN_SIN_EL)
    return SIGMA_A_M ** 2 + SIGMA_B_M ** 2 / sin_el ** 2


def _evaluate(sats: _Satellites, receiver_m, bias_m: float, iono: IonoParams | None, troposphere: bool,
              mask_rad: float, settled: bool) -> _Model:
    rng, sat_pos = _geometric_range(sats.pos_tx_m, receiver_m)
    los = (sat_pos - receiver_m) / rng[:, None]
    sat_vel = rotate_earth(sats.vel_tx_m_s, rng / C)
    corrected = sats.pseudorange_m + sats.clock_m
    n = len(rng)
    if settled:
        az, el = azimuth_elevation(receiver_m, sat_pos)
        lat, lon, h = ecef_to_geodetic(receiver_m)
        tow_s = sats.t_rx_clock_s - bias_m / C          # Klobuchar wants GPS time of reception
        corrected = corrected - iono_delay_m(iono, float(lat), float(lon), az, el, tow_s)
        if troposphere:
            corrected = corrected - troposphere_delay_m(float(lat), float(h), el)
        use, weight = el >= mask_rad, sats.weight / _variance_m2(el)
    else:
        el = np.full(n, np.nan)
        use, weight = np.ones(n, dtype=bool), sats.weight.copy()
    use &= weight > 0
    return _Model(rng, los, sat_pos, sat_vel, el, corrected - (rng + bias_m), use, weight)


def _wls(h, y, w):
    """Weighted least squares step, or None when the geometry does not determine it."""
    sw = np.sqrt(w)[:, None]
    x, _, rank, _ = np.linalg.lstsq(h * sw, y * sw[:, 0], rcond=None)
    return x if rank == h.shape[1] else None


def _dops(los_ecef, lat_rad: float, lon_rad: float) -> tuple[float, float, float]:
    """PDOP, HDOP, VDOP of the unweighted geometry in the local east-north-up frame."""
    h = np.column_stack([los_ecef @ enu_rotation(lat_rad, lon_rad).T, np.ones(len(los_ecef))])
    q = np.linalg.inv(h.T @ h)
    qe, qn, qu = q[0, 0], q[1, 1], q[2, 2]
    return float(np.sqrt(qe + qn + qu)), float(np.sqrt(qe + qn)), float(np.sqrt(qu))


def _velocity(sats: _Satellites, model: _Model, use: np.ndarray):
    """Receiver velocity (m/s) and c * clock drift (m/s) from the Doppler range rates.

    range_rate = los . (v_sat - v_rx) + c drift_rx - c drift_sat, the satellite velocity rotated into the reception
    frame like its position.
    """
    use = use & np.isfinite(sats.range_rate_m_s)
    if use.sum() < 4:
        return np.full(3, np.nan), float("nan")
    los = model.los[use]
    y = sats.range_rate_m_s[use] - np.sum(los * model.sat_vel_m_s[use], axis=1) + sats.drift_m_s[use]
    x = _wls(np.column_stack([-los, np.ones(len(los))]), y, model.weight[use])
    if x is None:
        return np.full(3, np.nan), float("nan")
    return x[:3], float(x[3])


def _gps_time(week: int, tow_s: float) -> tuple[int, float]:
    extra, tow = divmod(tow_s, SECONDS_PER_WEEK)
    return week + int(extra), float(tow)


def solve(observations: list[Observation], t_rx_s: float, gps_week: int, iono: IonoParams | None,
          troposphere: bool = True, prior: Fix | None = None, elevation_mask_deg: float = 5.0,
          raim: integrity.IntegrityConfig = integrity.IntegrityConfig()) -> Fix | None:
    """solve_once, then RAIM (integrity.fde) on the solution; excluded ranges are dropped and the fix solved again.

    The Fix carries raim (pass | fail | excluded | unverifiable), excluded_prns, test_statistic, hpl_m, vpl_m and
    tpl_ns (the clock's protection level against one faulty range, integrity.time_protection_level, in ns).
    """
    observations = [o for o in observations
                    if np.isfinite(o.pseudorange_m) and np.isfinite(o.t_sv_s) and o.weight > 0]
    out = _solve_once(observations, t_rx_s, gps_week, iono, troposphere, prior, elevation_mask_deg)
    if out is None:
        return None
    fix, result = _with_raim(observations, *out, raim)
    if not result.excluded:
        return fix
    used = [o for o, u in zip(observations, out[2].use) if u]
    bad = {used[i].prn for i in result.excluded}
    again = _solve_once([o for o in observations if o.prn not in bad], t_rx_s, gps_week, iono, troposphere, prior,
                        elevation_mask_deg)
    if again is None:
        return replace(fix, raim="fail")
    fix2, result2 = _with_raim([o for o in observations if o.prn not in bad], *again, raim)
    status = "excluded" if result2.status == "pass" else ("fail" if result2.status == "excluded" else result2.status)
    return replace(fix2, raim=status, excluded_prns=tuple(sorted(bad | set(fix2.excluded_prns))))


def _with_raim(observations, fix: Fix, sats: "_Satellites", model: "_Model", cfg: integrity.IntegrityConfig):
    use = model.use
    lat, lon = np.radians(fix.lat_deg), np.radians(fix.lon_deg)
    h = np.column_stack([-model.los[use] @ enu_rotation(lat, lon).T, np.ones(int(use.sum()))])
    cn0 = np.array([o.cn0_dbhz for o in observations], dtype=np.float64)[use]
    sigma = integrity.sigma_m(cn0, model.elevation_rad[use], cfg.sigma)   # C/N0 is in here: not Observation.weight
    result = integrity.fde(h, model.residual_m[use], sigma, cfg)
    prns = sats.prn[use]
    return replace(fix, raim=result.status, excluded_prns=tuple(int(prns[i]) for i in result.excluded),
                   test_statistic=result.test.statistic, hpl_m=result.hpl_m, vpl_m=result.vpl_m,
                   tpl_ns=result.tpl_m / C * 1e9, clock_sigma_ns=result.clock_sigma_m / C * 1e9,
                   h_sigma_m=result.h_sigma_m, v_sigma_m=result.v_sigma_m), result


def _solve_once(observations: list[Observation], t_rx_s: float, gps_week: int, iono: IonoParams | None,
                troposphere: bool = True, prior: Fix | None = None, elevation_mask_deg: float = 5.0):
    """Position, velocity and clock of the receiver at one reception instant, or None when there is no sound fix.

    t_rx_s (seconds since the first sample) is carried into the Fix; the GPS time comes from the observations.
    None when fewer than 4 satellites are usable above the mask, the iteration does not converge, or the result is
    absurd (further than MAX_HEIGHT_M from the ellipsoid, residual RMS above MAX_RESIDUAL_RMS_M).
    """
    observations = [o for o in observations
                    if np.isfinite(o.pseudorange_m) and np.isfinite(o.t_sv_s) and o.weight > 0]
    if len(observations) < 4:
        return None
    mask_rad = np.radians(elevation_mask_deg)
    with np.errstate(all="ignore"):      # garbage input may overflow on its way to being rejected
        sats = _satellites(observations)
        x = np.array(prior.pos_ecef_m, dtype=np.float64) if prior is not None else np.zeros(3)
        bias_m = float(prior.clock_bias_m) if prior is not None else 0.0
        settled = False          # even after a prior: it may be stale or wrong (a spoofer's), so let it prove itself
        for _ in range(MAX_ITERATIONS):
            model = _evaluate(sats, x, bias_m, iono, troposphere, mask_rad, settled)
            if model.use.sum() < 4:
                return None
            u = model.use
            step = _wls(np.column_stack([-model.los[u], np.ones(u.sum())]), model.residual_m[u], model.weight[u])
            if step is None or not np.all(np.isfinite(step)):
                return None
            x, bias_m = x + step[:3], bias_m + step[3]
            step_m = float(np.linalg.norm(step))
            if settled and step_m < CONVERGED_M:
                break
            settled = settled or step_m < COARSE_STEP_M
        else:
            return None
        model = _evaluate(sats, x, bias_m, iono, troposphere, mask_rad, True)
        fix = _fix(sats, model, x, bias_m, t_rx_s, gps_week)
        return None if fix is None else (fix, sats, model)


def _fix(sats: _Satellites, model: _Model, pos_m, bias_m: float, t_rx_s: float, gps_week: int) -> Fix | None:
    use = model.use
    if use.sum() < 4:
        return None
    lat, lon, h = (float(v) for v in ecef_to_geodetic(pos_m))
    rms_m = float(np.sqrt(np.mean(model.residual_m[use] ** 2)))
    if not (abs(h) < MAX_HEIGHT_M and rms_m < MAX_RESIDUAL_RMS_M and np.isfinite(bias_m)):
        return None
    try:
        pdop, hdop, vdop = _dops(model.los[use], lat, lon)
    except np.linalg.LinAlgError:
        return None
    vel, drift_m_s = _velocity(sats, model, use)
    week, tow = _gps_time(gps_week, sats.t_rx_clock_s - bias_m / C)
    return Fix(t_rx_s=t_rx_s, gps_week=week, gps_tow_s=tow, pos_ecef_m=pos_m, vel_ecef_m_s=vel,
               clock_bias_m=float(bias_m), clock_drift_m_s=drift_m_s, lat_deg=float(np.degrees(lat)),
               lon_deg=float(np.degrees(lon)), height_m=h, n_sats=int(use.sum()),
               prns=tuple(int(p) for p in sats.prn[use]), pdop=pdop, hdop=hdop, vdop=vdop, residual_rms_m=rms_m)


def residual_check(fix: Fix, observations: list[Observation], iono: IonoParams | None = None,
                   troposphere: bool = True) -> dict[int, float]:
    """Post-fit pseudorange residuals (m) per PRN against a fix: corrected pseudorange - (range + clock bias).

    Pass the same iono/troposphere settings as to solve(). Satellites the fix did not use (below the mask, or
    left out on purpose) are evaluated too, so a caller can test one satellite against the others' solution.
    """
    observations = [o for o in observations if np.isfinite(o.pseudorange_m) and np.isfinite(o.t_sv_s)]
    if not observations:
        return {}
    with np.errstate(all="ignore"):
        sats = _satellites(observations)
        model = _evaluate(sats, np.asarray(fix.pos_ecef_m, dtype=np.float64), fix.clock_bias_m, iono, troposphere,
                          -np.pi, True)
    return {int(p): float(r) for p, r in zip(sats.prn, model.residual_m)}
