"""Receiver autonomous integrity monitoring: residual chi-square test, fault detection and exclusion, protection levels.

Pure functions on the linearised measurement model at a solution: `h_enu` (n, 4) rows [-los_enu, 1], the post-fit
(or pre-fit at the solution, the same thing after projection) pseudorange residuals and each range's expected sigma.

Sigma model (explicit, `SigmaModel`): variance = DLL thermal noise (coherent early-minus-late, Kaplan & Hegarty
coherent EML: sigma^2 [chip^2] = B_L d / (2 C/N0) * (1 + 2 / (T C/N0 (2 - d)))) reduced by carrier smoothing over
tau seconds (the DLL output decorrelates in ~1/(4 B_L): averaging keeps a fraction ~1/(4 B_L tau), capped at 1),
plus a floor for orbit/clock/residual atmosphere: floor_m^2 + (atmosphere_m / sin el)^2.

Test: T = r' W r (W = diag 1/sigma^2) ~ chi2(n - 4) without fault; alarm when T > chi2.ppf(1 - pfa, n - 4).
Protection levels (Brown; Walter & Enge weighted): slope_i = |error per unit bias on i| / sqrt((W P)_ii), pbias the
sqrt of the non-centrality giving missed detection pmd at the threshold, HPL = max_i Hslope_i * pbias, same for VPL,
and for the receiver clock TPL = max_i Tslope_i * pbias with Tslope_i = |K_ti| / sqrt((W P)_ii), K_t the clock row of
the weighted least squares gain (in metres here; the fix carries it in ns).

What TPL bounds: the clock error an undetected fault on ONE range can cause. A delay common to every range (a time
push) leaves no residual at all -- it goes whole into the clock -- so no RAIM sees it: the receiver's clock model
(receiver/clock.py) and the defence's clock guard (defense/clock_guard.py) are what bound that part.
"""

from dataclasses import dataclass

from functools import lru_cache

import numpy as np
from .chisquare import chi2_isf, ncx2_noncentrality

CHIP_M = 299792458.0 / 1.023e6
RAIM_STATES = ("pass", "fail", "excluded", "unverifiable")
TRUSTED_STATES = ("pass", "excluded")


@dataclass(frozen=True)
class SigmaModel:
    dll_bw_hz: float = 2.0           # tracking.dll_bw_hz
    spacing_chips: float = 0.5       # tracking.spacing_chips (early-late)
    integration_s: float = 0.001     # coherent integration of the DLL discriminator
    smoothing_s: float = 20.0        # pvt.smoothing_s (Hatch filter); 0 = off
    floor_m: float = 0.5             # orbit + clock + receiver floor
    atmosphere_m: float = 0.5        # residual iono/tropo at zenith, grows as 1/sin(el)
    min_cn0_dbhz: float = 20.0       # C/N0 used for channels reporting less (or NaN)


@dataclass(frozen=True)
class IntegrityConfig:
    pfa: float = 1e-5                # false-alarm probability per fix
    pmd: float = 1e-3                # missed-detection probability for the protection levels
    exclude: bool = True             # False: detection only (status pass | fail | unverifiable)
    # The protection levels bound the error under one faulty range. A sky whose ranges agree only once two or more
    # are excluded is not one fault: a spoofer on from power-on, some channels on its peaks and some on the
    # legitimate ones, made 5 of 8 agree 186 m from the truth (HPL 30-74 m) and called it nominal
    max_exclusions: int = 1
    sigma: SigmaModel = SigmaModel()


@dataclass(frozen=True)
class RaimTest:
    statistic: float                 # r' W r (dimensionless); nan when dof == 0
    threshold: float
    dof: int
    passed: bool                     # False also when dof == 0 (nothing verified)


@dataclass(frozen=True)
class RaimResult:
    status: str                      # one of RAIM_STATES
    use: np.ndarray                  # bool (n,): ranges kept
    excluded: tuple[int, ...]        # indices excluded, in order
    test: RaimTest                   # test on the kept ranges
    hpl_m: float
    vpl_m: float
    tpl_m: float = float("nan")      # clock-bias protection level (m); nan without redundancy
    clock_sigma_m: float = float("nan")  # 1 sigma of the clock estimate, fault-free (weighted least squares covariance)
    h_sigma_m: float = float("nan")      # 1 sigma horizontal (root of the east + north variances) and vertical
    v_sigma_m: float = float("nan")      # errors, fault-free, same covariance


def sigma_m(cn0_dbhz, elevation_rad, model: SigmaModel = SigmaModel()) -> np.ndarray:
    """Expected 1-sigma pseudorange error (m) per range from its C/N0 (dB-Hz) and elevation."""
    cn0 = np.asarray(cn0_dbhz, dtype=np.float64)
    cn0 = np.where(np.isfinite(cn0), np.maximum(cn0, model.min_cn0_dbhz), model.min_cn0_dbhz)
    c_n0 = 10.0 ** (cn0 / 10.0)
    d = model.spacing_chips
    var_chip2 = model.dll_bw_hz * d / (2 * c_n0) * (1 + 2 / (model.integration_s * c_n0 * (2 - d)))
    if model.smoothing_s > 0:
        var_chip2 = var_chip2 * min(1.0, 1.0 / (4 * model.dll_bw_hz * model.smoothing_s))
    sin_el = np.maximum(np.sin(np.asarray(elevation_rad, dtype=np.float64)), 0.05)
    return np.sqrt(var_chip2 * CHIP_M ** 2 + model.floor_m ** 2 + (model.atmosphere_m / sin_el) ** 2)


def _projection(h, w):
    q = np.linalg.inv(h.T @ (h * w[:, None]))
    s = q @ h.T * w[None, :]                 # (4, n): state error per unit range bias
    p = np.eye(len(w)) - h @ s               # residual = P y
    return q, s, p


def chi2_test(h_enu, residual_m, sigma, pfa: float) -> RaimTest:
    """Weighted sum of squared post-fit residuals against the chi-square threshold for false-alarm pfa."""
    h, y, s = np.asarray(h_enu, float), np.asarray(residual_m, float), np.asarray(sigma, float)
    dof = len(y) - h.shape[1]
    if dof < 1:
        return RaimTest(float("nan"), float("nan"), max(dof, 0), False)
    w = 1.0 / s ** 2
    _, _, p = _projection(h, w)
    r = p @ y
    t = float(np.sum(w * r ** 2))
    thr = float(chi2_isf(pfa, dof))
    return RaimTest(t, thr, dof, t <= thr)


def normalized_residuals(h_enu, residual_m, sigma) -> np.ndarray:
    """w-test statistics: each post-fit residual divided by its own standard deviation (Baarda)."""
    h, y, s = np.asarray(h_enu, float), np.asarray(residual_m, float), np.asarray(sigma, float)
    w = 1.0 / s ** 2
    q, _, p = _projection(h, w)
    var_r = s ** 2 - np.einsum("ij,jk,ik->i", h, q, h)
    return (p @ y) / np.sqrt(np.maximum(var_r, 1e-12 * s ** 2))


@lru_cache(maxsize=512)   # an inverse of the non-central chi-square: once per (dof, pfa, pmd)
def pbias(dof: int, pfa: float, pmd: float) -> float:
    """sqrt of the non-centrality at which a chi2(dof) test with false alarm pfa misses with probability pmd."""
    lam = ncx2_noncentrality(chi2_isf(pfa, dof), dof, pmd)
    return float(np.sqrt(lam))


def _slopes(h_enu, sigma):
    """(dof, east-north slope, up slope, clock slope) per range: state error per unit of test statistic's sqrt."""
    h, s = np.asarray(h_enu, float), np.asarray(sigma, float)
    dof = len(s) - h.shape[1]
    if dof < 1:
        return dof, None, None, None
    w = 1.0 / s ** 2
    _, k, p = _projection(h, w)
    root_wp = np.sqrt(np.maximum(np.diag(p) * w, 1e-300))
    return dof, np.hypot(k[0], k[1]) / root_wp, np.abs(k[2]) / root_wp, np.abs(k[3]) / root_wp


def protection_levels(h_enu, sigma, pfa: float, pmd: float) -> tuple[float, float]:
    """HPL, VPL (m): the largest position error an undetected single-range bias can cause (nan without redundancy)."""
    dof, hslope, vslope, _ = _slopes(h_enu, sigma)
    if dof < 1:
        return float("nan"), float("nan")
    pb = pbias(dof, pfa, pmd)
    return float(hslope.max() * pb), float(vslope.max() * pb)


def time_protection_level(h_enu, sigma, pfa: float, pmd: float) -> float:
    """TPL (m of c * clock bias): the largest clock error an undetected single-range bias can cause, the clock
    component of the same slopes (nan without redundancy). A common delay on every range is outside it."""
    dof, _, _, tslope = _slopes(h_enu, sigma)
    if dof < 1:
        return float("nan")
    return float(tslope.max() * pbias(dof, pfa, pmd))


def clock_sigma(h_enu, sigma) -> float:
    """1 sigma (m) of the clock component of the weighted least squares solution, fault-free: sqrt(Q_tt)."""
    return solution_sigmas(h_enu, sigma)[2]


def solution_sigmas(h_enu, sigma) -> tuple[float, float, float]:
    """1 sigma (m) of the weighted least squares solution, fault-free: horizontal sqrt(Q_ee + Q_nn), vertical
    sqrt(Q_uu) and clock sqrt(Q_tt) -- what an accuracy estimate (an autopilot's hAcc, vAcc) means, where a
    protection level bounds a fault."""
    h, s = np.asarray(h_enu, float), np.asarray(sigma, float)
    if len(s) < h.shape[1]:
        return float("nan"), float("nan"), float("nan")
    q, _, _ = _projection(h, 1.0 / s ** 2)
    return float(np.sqrt(q[0, 0] + q[1, 1])), float(np.sqrt(q[2, 2])), float(np.sqrt(q[3, 3]))


def fde(h_enu, residual_m, sigma, config: IntegrityConfig = IntegrityConfig()) -> RaimResult:
    """Test; while it fails, one more exclusion still leaves redundancy and config.max_exclusions allows it, drop the
    largest normalized residual.

    The residuals are linearised at one solution: exclusion is exact for a linear model (the caller may re-solve).
    """
    h, y, s = np.asarray(h_enu, float), np.asarray(residual_m, float), np.asarray(sigma, float)
    n_state = h.shape[1]
    use = np.ones(len(y), dtype=bool)
    excluded: list[int] = []
    while True:
        test = chi2_test(h[use], y[use], s[use], config.pfa)
        if (test.dof < 1 or test.passed or not config.exclude or len(excluded) >= config.max_exclusions
                or use.sum() - 1 - n_state < 1):
            break
        idx = np.flatnonzero(use)
        worst = idx[int(np.argmax(np.abs(normalized_residuals(h[use], y[use], s[use]))))]
        use[worst] = False
        excluded.append(int(worst))
    if test.dof < 1:
        status = "unverifiable"
    elif not test.passed:
        status = "fail"
    else:
        status = "excluded" if excluded else "pass"
    hpl, vpl = protection_levels(h[use], s[use], config.pfa, config.pmd)
    tpl = time_protection_level(h[use], s[use], config.pfa, config.pmd)
    h_sigma, v_sigma, t_sigma = solution_sigmas(h[use], s[use])
    return RaimResult(status, use, tuple(excluded), test, hpl, vpl, tpl, t_sigma, h_sigma, v_sigma)


def trusted(raim: str) -> bool:
    """True only for a fix whose ranges were verified consistent (the defence may call it nominal/recovered)."""
    return raim in TRUSTED_STATES
