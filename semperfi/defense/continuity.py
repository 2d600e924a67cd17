"""Which of a PRN's two peaks continues the range the receiver tracked before the attack became known.

Before any alarm, each range a nominal fix is built on lies within the detector's separation of the legitimate one
(a spoofer pulling it further would have shown as a second peak). The last such fix -- its ranges, its clock and
its drift -- and the INS displacement since carry each PRN's range forward: the legitimate peak stays within a
radius of the prediction (that separation, plus the INS's and the clock's drift since), and a peak outside it is not
the legitimate one. When exactly one of a PRN's two peaks lies inside, it is the legitimate one: a takeover's
spoofer, aligned with the legitimate signals at first, identifies itself by leaving them. While both lie inside,
nothing is decided.

Each PRN's prediction is calibrated on its own tracked range at the anchor (atmosphere, the fix's residual), so
what is carried forward is the range itself, not the fix's model of it.

Once four PRNs or more are known to carry the legitimate signal only, what their ranges say of the prediction's
error -- a drag before the alarm that moved the anchor, the INS's and the clock's drift since: a position and a clock
offset, fitted by least squares -- corrects the prediction of the others, whose radius shrinks to what one range can
be off unseen by the nominal fixes' integrity test, plus the atmosphere's change: REFINED_RADIUS_M.
"""

from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from ..gps import CA_CHIP_RATE_HZ, SPEED_OF_LIGHT_M_S, chips_offset, enu_rotation
from ..receiver import Fix
from .identifier import ImuTrack

CHIP_M = SPEED_OF_LIGHT_M_S / CA_CHIP_RATE_HZ
INS_DRIFT_M_S2 = 0.02      # dead-reckoning error growth (a consumer IMU's accelerometer bias): 36 m after a minute
CLOCK_WANDER_M_S = 0.3     # the anchor's clock drift estimate's error plus a TCXO's wander over a minute
MAX_RADIUS_M = 1000.0      # past this the prediction tells nothing a fix does not
# the spoofer starts parting a little before the alarm: the two carriers under one peak pull its Doppler (a takeover's
# last fixes before the alarm had their clock drift 3 m/s off), so the anchor is a fix this much older, and its clock
# drift the median over the nominal fixes of DRIFT_OVER_S before it
ANCHOR_BEFORE_ALARM_S = 2.0
DRIFT_OVER_S = 10.0
REFINED_RADIUS_M = 50.0
REFINE_MAX_PDOP = 6.0      # the known PRNs' geometry must pin the position the correction carries
REFINE_MAX_RMS_M = 15.0    # and, with one to spare, agree with one position and clock
GRADIENT_STEP_M = 1.0


@dataclass(frozen=True)
class Anchor:
    fix: Fix
    sample: float
    bias_chips: dict[int, float]      # PRN -> tracked minus predicted code phase at the anchor
    ins_ned_m: np.ndarray             # the INS position at the anchor


class Continuity:
    def __init__(self, fs_hz: float, separation_m: float, ins: ImuTrack):
        """separation_m: the detector's separation (the most a spoofer can pull a tracked range unseen);
        ins: the vehicle's dead-reckoned track, receiver time."""
        self.fs_hz, self.separation_m, self.ins = fs_hz, separation_m, ins
        self.anchor: Anchor | None = None
        self._nominal: deque[tuple[Fix, dict[int, float], np.ndarray]] = deque()   # (fix, tracked chips, INS pos)
        self.correction: tuple[float, np.ndarray] | None = None   # (sample, [ECEF position offset m, clock m])

    def note(self, fix: Fix, tracked_chips: dict[int, float]) -> None:
        """A nominal fix before any alarm, a candidate anchor, with each locked channel's code phase at its sample."""
        self._nominal.append((fix, tracked_chips, self.ins.position_at(np.array([fix.t_rx_s]))[0]))
        while fix.t_rx_s - self._nominal[0][0].t_rx_s > DRIFT_OVER_S + ANCHOR_BEFORE_ALARM_S:
            self._nominal.popleft()

    def freeze(self, alarm_t_s: float, predicted_chips) -> None:
        """The attack is known: the anchor is the last nominal fix ANCHOR_BEFORE_ALARM_S before the alarm (none if
        there is none), with the clock drift of the fixes before it, each PRN calibrated on its tracked code phase.
        predicted_chips(prn, sample, fix, pos_ecef_m) -> the code phase a fix predicts (None without ephemeris)."""
        before = [n for n in self._nominal if n[0].t_rx_s <= alarm_t_s - ANCHOR_BEFORE_ALARM_S]
        self._nominal.clear()
        if not before:
            return
        fix, tracked_chips, ins_ned_m = before[-1]
        drift = float(np.median([f.clock_drift_m_s for f, _, _ in before if fix.t_rx_s - f.t_rx_s <= DRIFT_OVER_S]))
        sample = fix.t_rx_s * self.fs_hz
        bias = {}
        for prn, chips in tracked_chips.items():
            pred = predicted_chips(prn, sample, fix, fix.pos_ecef_m)
            if pred is not None:
                bias[prn] = chips_offset(chips, pred)
        self.anchor = Anchor(replace(fix, clock_drift_m_s=drift), sample, bias, ins_ned_m)

    def radius_m(self, sample: float) -> float:
        dt_s = (sample - self.anchor.sample) / self.fs_hz
        return self.separation_m + 0.5 * INS_DRIFT_M_S2 * dt_s ** 2 + CLOCK_WANDER_M_S * abs(dt_s)

    def predicted_position(self, sample: float) -> np.ndarray:
        """The anchor's position moved by the INS displacement since (ECEF)."""
        a = self.anchor
        d_ned = self.ins.position_at(np.array([sample / self.fs_hz]))[0] - a.ins_ned_m
        enu = np.array([d_ned[1], d_ned[0], -d_ned[2]])
        return a.fix.pos_ecef_m + enu @ enu_rotation(np.radians(a.fix.lat_deg), np.radians(a.fix.lon_deg))

    def _predicted(self, prn: int, sample: float, predicted_chips) -> tuple[float, np.ndarray] | None:
        """(calibrated code phase, unit line of sight) for the INS-carried position; the line of sight is the
        prediction's own gradient (a metre toward the satellite is a metre less range)."""
        a = self.anchor
        pos = self.predicted_position(sample)
        pred = predicted_chips(prn, sample, a.fix, pos)
        if pred is None:
            return None
        steps = [predicted_chips(prn, sample, a.fix, pos + GRADIENT_STEP_M * e) for e in np.eye(3)]
        u = np.array([chips_offset(c, pred) * CHIP_M / GRADIENT_STEP_M for c in steps])
        return pred + a.bias_chips[prn], u

    def refine(self, sample: float, legit_chips: dict[int, float], predicted_chips) -> None:
        """Known-legitimate PRNs' code phases at a sample: the prediction's position and clock error, fitted."""
        self.correction = None
        if self.anchor is None:
            return
        rows, r = [], []
        for prn, chips in legit_chips.items():
            got = self._predicted(prn, sample, predicted_chips) if prn in self.anchor.bias_chips else None
            if got is not None:
                rows.append([*got[1], 1.0])
                r.append(chips_offset(chips, got[0]) * CHIP_M)
        if len(r) < 4:
            return
        h, r = np.array(rows), np.array(r)
        x, *_ = np.linalg.lstsq(h, r, rcond=None)
        pdop = float(np.sqrt(np.trace(np.linalg.pinv(h.T @ h)[:3, :3])))
        if pdop > REFINE_MAX_PDOP or (len(r) > 4 and np.sqrt(np.mean((r - h @ x) ** 2)) > REFINE_MAX_RMS_M):
            return
        self.correction = (sample, x)

    def legitimate(self, prn: int, sample: float, peaks_chips: tuple[float, float], predicted_chips) -> int | None:
        """Which of two code phases (at an absolute sample) is the legitimate signal's: 0 or 1, or None when both
        or neither lie within the radius of the prediction, or there is nothing to predict from."""
        a = self.anchor
        if a is None or prn not in a.bias_chips:
            return None
        got = self._predicted(prn, sample, predicted_chips)
        if got is None:
            return None
        expected, u = got
        if self.correction is not None:
            at, x = self.correction
            expected += (u @ x[:3] + x[3]) / CHIP_M
            radius = REFINED_RADIUS_M + CLOCK_WANDER_M_S * abs(sample - at) / self.fs_hz
        else:
            radius = self.radius_m(sample)
            if radius > MAX_RADIUS_M:
                return None
        inside = [abs(chips_offset(c, expected)) * CHIP_M <= radius for c in peaks_chips]
        return inside.index(True) if sum(inside) == 1 else None
