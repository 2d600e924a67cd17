"""Adversarial Peak Identifier (paper sections 3.3-4).

(a) ``paper_test``: the paper's test -- the mean Euclidean distance between the IMU (dead-reckoned) track and the
GPS track, both relative to the maneuver start, against a 5 m threshold.  Above: the tracked peaks are adversarial.

(b) ``identify_peaks``: a per-peak verdict.  During the maneuver a legitimate peak's pseudorange changes by
    d_rho_k(t) = d_sat_k(t) - u_k . d_p(t) + c*d_b(t)
(u_k unit line of sight receiver->satellite in NED, d_p the vehicle displacement, d_b the receiver clock change,
common to all legitimate peaks; d_sat_k the satellite's own range change, predicted from ephemeris for the start
position).  A static or trajectory-planned spoofer's peak does not follow d_p projected on u_k.  For each peak the
residual r_k(t) = d_rho_k - d_sat_k + u_k . d_p must equal the common clock; the clock is found as the largest
consensus among peaks (no assumption on power: a weaker attacker is treated alike), so partial spoofing and several
candidate peaks per PRN are decided peak by peak.  Doppler is used the same way with the IMU velocity.  A peak
whose line-of-sight motion during the maneuver is too small to tell is reported ``decided=False``.

d_sat_k is predicted for the position the receiver has, which under attack is the spoofer's, kilometres off. A
position error e turns the prediction by -(u_k(t) - u_k(0)) . e: about 3 m per kilometre over 20 s, a different
slow drift on every satellite, enough to push legitimate peaks out of the consensus. Where the lines of sight'
rotation is known (LineOfSight.u_change_ned), e is estimated with the clock from the consensus peaks (three
unknowns for all of them) and removed before the verdicts. Tested to 3 km; at 5 km a few legitimate peaks in a
hundred are flagged (the first consensus, blind to the error, starts too narrow).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semperfi.gps import L1_WAVELENGTH_M

PAPER_THRESHOLD_M = 5.0
# a peak that agrees with the clock is cleared only if the maneuver moved it this much along its line of sight (rms
# about the mean over the window): less, and a spoofer's peak could agree as well
MIN_SIGNATURE_M = 3.0
# the INS drift over a maneuver of up to 20 s at the paper's IMU level (0.44 m/s after 20 s: about 0.011 m/s^2 t^2/2)
INS_DRIFT_M = 2.0
# what a maneuver must move the vehicle along a line of sight for a legitimate peak there to be cleared: the INS
# track is the flown one plus a drift growing from zero to at most INS_DRIFT_M, and the rms about the mean is a
# seminorm (such a drift's is at most half its range); the vehicle flies the plan late and through gusts, its spread
# 0.9 of the plan's or more (95% of simulated flights). Sent with an alarm, for the flight side's draw
REQUIRED_SPREAD_M = (MIN_SIGNATURE_M + INS_DRIFT_M / 2) / 0.9
MIN_SHAPE_M = 1.0   # a maneuver's rms beyond a quadratic in time, for the one-track test to hold it against the INS
# a legitimate set's track is the INS's error off (the LS offset amplifies it: to 2.3 tolerances over 200 synthetic
# maneuvers with the paper's worst IMU): beyond this many tolerances, the set's track is not the vehicle's
TRACK_OFF_TOLERANCES = 3.0
MAX_POSITION_ERROR_M = 30e3   # beyond this the lines of sight themselves are wrong, not just the prediction


# An INS track's rows at most this close (10 kHz; IMUs log at 1 kHz or less): rows 1e-12 s apart made the maneuver
# search's one-second smoothing a kernel of 10^12 taps
MIN_IMU_SPACING_S = 1e-4


@dataclass(frozen=True)
class ImuTrack:
    """Dead-reckoned track, NED metres from any origin."""
    t_s: np.ndarray
    north_m: np.ndarray
    east_m: np.ndarray
    down_m: np.ndarray

    def __post_init__(self):
        n = len(self.t_s)
        if n < 2 or any(len(a) != n for a in (self.north_m, self.east_m, self.down_m)):
            raise ValueError("IMU track: need >= 2 samples and equal-length columns")
        if not np.all(np.isfinite(np.c_[self.t_s, self.north_m, self.east_m, self.down_m])):
            raise ValueError("IMU track: non-finite value")
        if np.any(np.diff(self.t_s) < MIN_IMU_SPACING_S):
            raise ValueError(f"IMU track: t_s must increase by {MIN_IMU_SPACING_S:g} s or more per row")

    def shifted(self, dt_s: float) -> "ImuTrack":
        """The same track with its clock moved by dt_s (a recording processed from --skip on)."""
        return ImuTrack(self.t_s + dt_s, self.north_m, self.east_m, self.down_m) if dt_s else self

    def position_at(self, t_s) -> np.ndarray:
        """NED displacement from the track's first sample, (len(t), 3)."""
        cols = [np.interp(t_s, self.t_s, c - c[0]) for c in (self.north_m, self.east_m, self.down_m)]
        return np.stack(cols, axis=-1)

    def velocity_at(self, t_s) -> np.ndarray:
        cols = [np.interp(t_s, self.t_s, np.gradient(c, self.t_s)) for c in (self.north_m, self.east_m, self.down_m)]
        return np.stack(cols, axis=-1)


@dataclass(frozen=True)
class GpsTrack:
    t_s: np.ndarray
    north_m: np.ndarray
    east_m: np.ndarray
    down_m: np.ndarray


@dataclass(frozen=True)
class LineOfSight:
    """Unit vector receiver->satellite in NED at the maneuver start, and the satellite's own range change
    (predicted from ephemeris for the start position) on ``t_s``."""
    prn: int
    u_ned: tuple[float, float, float]
    t_s: np.ndarray
    sat_range_change_m: np.ndarray
    sat_range_rate_change_mps: np.ndarray | None = None
    u_change_ned: np.ndarray | None = None   # (len(t_s), 3): the line of sight's turn since t_s[0]


@dataclass(frozen=True)
class PeakHistory:
    prn: int
    peak_id: int
    t_s: np.ndarray
    pseudorange_m: np.ndarray
    doppler_hz: np.ndarray | None = None


@dataclass(frozen=True)
class PeakVerdict:
    prn: int
    peak_id: int
    adversarial: bool
    decided: bool
    score: float          # rms residual against the common clock, in units of the tolerance (<= 1: legitimate)
    reason: str


@dataclass(frozen=True)
class PaperVerdict:
    adversarial: bool
    mean_distance_m: float


def paper_test(imu: ImuTrack, gps: GpsTrack, threshold_m: float = PAPER_THRESHOLD_M) -> PaperVerdict:
    """Mean Euclidean distance between the IMU and GPS tracks, both relative to the maneuver start."""
    t = np.asarray(gps.t_s, float)
    t = t[(t >= imu.t_s[0]) & (t <= imu.t_s[-1])]
    if len(t) < 2:
        raise ValueError("GPS and IMU tracks do not overlap")
    p_imu = imu.position_at(t)
    p_imu -= p_imu[0]
    p_gps = np.stack([np.interp(t, gps.t_s, c) for c in (gps.north_m, gps.east_m, gps.down_m)], axis=-1)
    p_gps -= p_gps[0]
    d = float(np.mean(np.linalg.norm(p_imu - p_gps, axis=1)))
    return PaperVerdict(d > threshold_m, d)


def identify_peaks(peaks, los, imu: ImuTrack, range_tol_m: float = 4.5, doppler_tol_hz: float = 7.5,
                   min_signature_m: float = MIN_SIGNATURE_M, ambiguous_up_to: float = 1.25) -> list[PeakVerdict]:
    """Per-peak verdict; see the module docstring.  ``los``: mapping prn -> LineOfSight."""
    peaks = list(peaks)
    if not peaks:
        return []
    t0, t1 = max(p.t_s[0] for p in peaks), min(p.t_s[-1] for p in peaks)
    t0, t1 = max(t0, imu.t_s[0]), min(t1, imu.t_s[-1])
    if t1 <= t0:
        raise ValueError("peak histories and IMU track do not overlap")
    t = np.linspace(t0, t1, 101)
    d_p = imu.position_at(t) - imu.position_at(t[:1])
    v = imu.velocity_at(t)
    dv = v - v[:1]
    res, sig, res_d, turn, moved, moved_d, us = [], [], [], [], [], [], []
    for p in peaks:
        if p.prn not in los:
            raise ValueError(f"no line of sight for PRN {p.prn}")
        L = los[p.prn]
        u = np.asarray(L.u_ned, float)
        u = u / np.linalg.norm(u)
        rho = np.interp(t, p.t_s, p.pseudorange_m)
        sat = np.interp(t, L.t_s, L.sat_range_change_m)
        proj = d_p @ u
        us.append(u)
        moved.append(proj)
        moved_d.append(dv @ u)
        res.append((rho - rho[0]) - (sat - sat[0]) + proj)
        turn.append(None if L.u_change_ned is None else
                    np.stack([np.interp(t, L.t_s, L.u_change_ned[:, k]) for k in range(3)], axis=-1))
        sig.append(float(np.sqrt(np.mean((proj - proj.mean()) ** 2))))
        if p.doppler_hz is not None:
            rate = -L1_WAVELENGTH_M * np.interp(t, p.t_s, p.doppler_hz)
            sat_rate = (np.interp(t, L.t_s, L.sat_range_rate_change_mps)
                        if L.sat_range_rate_change_mps is not None else np.zeros_like(t))
            res_d.append((rate - rate[0]) - (sat_rate - sat_rate[0]) + dv @ u)
        else:
            res_d.append(None)
    raw = np.array(res)
    res = raw
    turn = np.array(turn) if all(g is not None for g in turn) else None
    use_d = all(r is not None for r in res_d)
    res_d = np.array(res_d) if use_d else None
    moved, moved_d = np.array(moved), (np.array(moved_d) if use_d else None)
    tol_rate = L1_WAVELENGTH_M * doppler_tol_hz
    # the residuals of a receiver that did not move: a single transmitter's peaks all share one there (its own range
    # change to the vehicle), whatever the maneuver
    still, still_d = raw - moved, (res_d - moved_d if use_d else None)

    def mismatch(i, j, r, r_d, detrend=False):
        d = r[i] - r[j]
        if detrend:   # a position error's drift is nearly linear in time; the maneuver's signature is not
            d = d - np.polyval(np.polyfit(t, d, 1), t)
        e = np.sqrt(np.mean(d ** 2)) / range_tol_m
        if use_d:
            e = max(e, np.sqrt(np.mean((r_d[i] - r_d[j]) ** 2)) / tol_rate)
        return e

    n = len(peaks)

    def consensus(r, r_d, detrend=False):
        m = np.array([[mismatch(i, j, r, r_d, detrend) for j in range(n)] for i in range(n)])
        # the hypothesis peak with the most peaks agreeing (tie: smallest total mismatch)
        counts = [(int(np.sum(m[i] <= 1.0)), -float(np.sum(np.minimum(m[i], 1.0)))) for i in range(n)]
        best = max(range(n), key=lambda i: counts[i])
        return np.flatnonzero(m[best] <= 1.0)

    def against(members, r, r_d):
        clock = np.median(r[members], axis=0)
        e = np.sqrt(np.mean((r - clock) ** 2, axis=1)) / range_tol_m
        if use_d:
            e = np.maximum(e, np.sqrt(np.mean((r_d - np.median(r_d[members], axis=0)) ** 2, axis=1)) / tol_rate)
        return e

    def position_error(members) -> np.ndarray:
        """The receiver position error (NED m) the members' residuals show, clock eliminated."""
        if turn is None or len(members) < 3:
            return np.zeros(3)
        d = raw[members] - raw[members].mean(axis=0)
        h = turn[members] - turn[members].mean(axis=0)
        e = np.linalg.lstsq(h.reshape(-1, 3), d.reshape(-1), rcond=None)[0]
        size = float(np.linalg.norm(e))
        return e if size <= MAX_POSITION_ERROR_M else e * (MAX_POSITION_ERROR_M / size)

    def corrected_consensus(members):
        """Estimate the position error from the members, correct, find the consensus again (a few rounds)."""
        nonlocal res
        for _ in range(3):
            res = raw - turn @ position_error(members)
            again = consensus(res, res_d)
            if set(again) == set(members):
                break
            members = again
        return members, res

    members = consensus(res, res_d)
    if turn is not None:
        # start from the plain consensus, and from one on detrended differences (blind to the position error's
        # near-linear drift, which beyond a few km splits the plain one); keep the larger, tighter consensus
        best = None
        for start in (members, consensus(res, res_d, detrend=True)):
            m_k, res_k = corrected_consensus(start)
            res = res_k
            score = (len(m_k), -float(np.mean(against(m_k, res, res_d)[m_k])))
            if best is None or score > best[0]:
                best = (score, m_k, res_k)
        _, members, res = best
    errors = against(members, res, res_d)
    for _ in range(3):   # refine the clock from the peaks that agree with it
        refined = np.flatnonzero(errors <= 1.0)
        if len(refined) < len(members) or len(refined) < 2:
            break
        members, errors = refined, against(refined, res, res_d)
    # a consensus of peaks that a receiver that did not move explains as well proves nothing: when every followed peak
    # is the attacker's (a takeover of every PRN, each twin merged under its spoofer's peak), those whose lines of
    # sight the maneuver moved alike agree on a clock as legitimate peaks would (ArduCopter SITL closed loop: a PRN
    # cleared so had its legitimate twin cancelled). The clock is proven by two of its peaks that such a receiver does
    # not explain.
    still_members = consensus(still, still_d)
    still_fit = (against(still_members, still, still_d) <= 1.0) if len(still_members) >= 2 else np.zeros(n, bool)
    proven = int(np.sum(~still_fit[members])) >= 2
    # that group is the attacker's only if the maneuver moved its members differently: legitimate peaks agree there
    # only as far as they moved alike, and a consensus's members lie within one tolerance of its centre, so within two
    # of each other; beyond 2.5 (noise) they are not all legitimate
    attackers = any(mismatch(i, j, moved, moved_d) > 2.5 for i in still_members for j in still_members if i < j)
    static = still_fit if attackers else np.zeros(n, bool)
    why = _another_track(raw, np.array(us), t, d_p, range_tol_m)
    if why is not None:
        return [PeakVerdict(p.prn, p.peak_id, True, True, float(e), why) for p, e in zip(peaks, errors)]
    out = []
    for i, p in enumerate(peaks):
        e = errors[i]
        if len(members) < 2 or not (proven or static[i]):
            out.append(PeakVerdict(p.prn, p.peak_id, False, False, float(e), "no consensus clock" if len(members) < 2
                                   else "no proven consensus clock"))
        elif e <= 1.0 and (static[i] or not proven):
            out.append(PeakVerdict(p.prn, p.peak_id, False, False, float(e),
                                   "agrees with the vehicle's motion and with a receiver that did not move alike"))
        elif e <= 1.0 and sig[i] < min_signature_m:
            # agrees with the clock, but the maneuver barely moved along this line of sight: not proven
            out.append(PeakVerdict(p.prn, p.peak_id, False, False, float(e),
                                   f"line-of-sight motion {sig[i]:.1f} m too small to decide"))
        elif e <= 1.0:
            out.append(PeakVerdict(p.prn, p.peak_id, False, True, float(e), "follows the vehicle's motion"))
        elif e <= ambiguous_up_to:
            # IMU drift at the paper's level reaches here on legitimate peaks: neither cleared nor cancelled
            out.append(PeakVerdict(p.prn, p.peak_id, False, False, float(e), "ambiguous residual"))
        else:
            out.append(PeakVerdict(p.prn, p.peak_id, True, True, float(e),
                                   "does not follow the vehicle's motion on its line of sight"))
    # one satellite has one legitimate signal: if several of its peaks pass, the maneuver did not tell them apart
    passed = {}
    for v in out:
        if v.decided and not v.adversarial:
            passed[v.prn] = passed.get(v.prn, 0) + 1
    return [PeakVerdict(v.prn, v.peak_id, False, False, v.score, "several peaks of this PRN follow the motion")
            if passed.get(v.prn, 0) > 1 and v.decided and not v.adversarial else v for v in out]


def _another_track(raw: np.ndarray, u: np.ndarray, t: np.ndarray, d_p: np.ndarray,
                   range_tol_m: float) -> str | None:
    """Why all the peaks together are the attacker's, or None. A peak's residual is
    clock + u . (INS track - the track its range follows): an attacker makes its peaks one consistent set, so when
    every followed peak is the attacker's (a takeover of every PRN, each twin merged under its spoofer) they fit one
    clock and one offset e(t) = INS track - their track, and no consensus among them is proven. A set mixing
    legitimate peaks with the attacker's fits no one track. A legitimate set's e is the INS's drift; the attacker's
    set is told by either of:
    - the maneuver missing from its track: e holds the maneuver's shape (compared horizontally with a quadratic in
      time taken out: a drift, a drag at constant speed or acceleration). Over 200 synthetic maneuvers with the
      paper's worst IMU, 0.89-1.13 of it is missing for the attacker's sets, -0.18-0.16 for legitimate ones, whatever
      the INS's drift (tests/test_identifier.py). An attacker that follows the vehicle (a takeover steering off the
      true track) puts the maneuver in its track; then:
    - its track leaving the INS's by more than the INS can drift (TRACK_OFF_TOLERANCES tolerances, rms): the paper's
      test, on the peaks' carrier ranges; as sound as the INS's stated bound.
    Needs one peak more than the four unknowns."""
    if len(raw) < 5:
        return None
    h = np.column_stack([np.ones(len(raw)), u])
    sol = np.linalg.lstsq(h, raw, rcond=None)[0]
    if np.any(np.sqrt(np.mean((raw - h @ sol) ** 2, axis=1)) > range_tol_m):
        return None
    v = np.vander(t - t[0], 3)

    def shape(x):
        return x - v @ np.linalg.lstsq(v, x, rcond=None)[0]
    offset, maneuver = shape(sol[1:3].T), shape(d_p[:, :2])
    power = float(np.sum(maneuver ** 2))
    share = float(np.sum(offset * maneuver)) / power if power >= MIN_SHAPE_M ** 2 * len(t) else 0.0
    if share > 0.5:
        return f"with the others, fixes a track without the vehicle's maneuver ({share:.2f} of it missing)"
    off_m = float(np.sqrt(np.mean(np.sum(sol[1:3] ** 2, axis=0))))
    if off_m > TRACK_OFF_TOLERANCES * range_tol_m:
        return f"with the others, fixes a track {off_m:.0f} m (rms) off the vehicle's INS"
    return None
