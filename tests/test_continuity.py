"""The continuity identifier: which of a PRN's two peaks continues the range tracked before the alarm."""

import numpy as np

from semperfi.defense.continuity import ANCHOR_BEFORE_ALARM_S, CHIP_M, Continuity
from semperfi.defense.identifier import ImuTrack
from semperfi.gps.codes import chips_offset
from semperfi.receiver.types import Fix

FS = 1000.0
ORIGIN = np.array([1530272.0, -4466812.0, 4273585.0])
LOS = {5: np.array([0.6, 0.0, 0.8]), 9: np.array([-0.3, 0.9, 0.3])}
ATMOSPHERE_M = {5: 7.0, 9: 12.0}   # what the fix's model leaves out of each range: calibrated away at the anchor


def fix_at(t_s, drift_m_s=0.0):
    return Fix(t_rx_s=t_s, gps_week=2190, gps_tow_s=1000.0 + t_s, pos_ecef_m=ORIGIN.copy(), vel_ecef_m_s=np.zeros(3),
               clock_bias_m=0.0, clock_drift_m_s=drift_m_s, lat_deg=42.34, lon_deg=-71.09, height_m=10.0, n_sats=6,
               prns=(5, 9), pdop=2.0, hdop=1.0, vdop=1.5, residual_rms_m=0.5)


def predicted_chips(prn, sample, fix, pos_ecef_m):
    """A toy range model: the position along the line of sight, the clock's drift since the fix."""
    range_m = -LOS[prn] @ (pos_ecef_m - ORIGIN) + fix.clock_drift_m_s * (sample / FS - fix.t_rx_s)
    return (100.0 + range_m / CHIP_M) % 1023.0


def true_chips(prn, t_s, extra_m=0.0):
    """Where the legitimate peak is: a static receiver, a clock without drift, the atmosphere, plus extra_m."""
    return (100.0 + (ATMOSPHERE_M[prn] + extra_m) / CHIP_M) % 1023.0


def anchored(alarm_t_s=10.0):
    still = ImuTrack(np.array([0.0, 100.0]), np.zeros(2), np.zeros(2), np.zeros(2))
    c = Continuity(FS, 150.0, still)
    for t in np.arange(0.0, alarm_t_s, 0.5):
        # the last fixes before the alarm: the parting spoofer pulls their Doppler, hence their clock drift
        c.note(fix_at(t, 3.0 if t > alarm_t_s - 1.0 else 0.05), {p: true_chips(p, t) for p in LOS})
    c.freeze(alarm_t_s, predicted_chips)
    return c


def test_the_anchor_is_older_than_the_alarm_and_its_drift_is_the_median():
    c = anchored()
    assert c.anchor.fix.t_rx_s <= 10.0 - ANCHOR_BEFORE_ALARM_S and c.anchor.fix.t_rx_s == 8.0
    assert c.anchor.fix.clock_drift_m_s == 0.05
    assert all(abs(chips_offset(c.anchor.bias_chips[p], ATMOSPHERE_M[p] / CHIP_M)) < 1e-6 for p in LOS)


def test_the_peak_inside_the_radius_is_the_legitimate_one():
    c = anchored()
    t = 30.0
    assert 150.0 < c.radius_m(t * FS) < 200.0
    for prn in LOS:
        legit, spoofer = true_chips(prn, t, 1.0), true_chips(prn, t, 260.0)
        assert c.legitimate(prn, t * FS, (legit, spoofer), predicted_chips) == 0
        assert c.legitimate(prn, t * FS, (spoofer, legit), predicted_chips) == 1
        # both inside (the spoofer has not left yet): nothing is decided, nor when neither is
        assert c.legitimate(prn, t * FS, (legit, true_chips(prn, t, -90.0)), predicted_chips) is None
        assert c.legitimate(prn, t * FS, (true_chips(prn, t, 400.0), spoofer), predicted_chips) is None


def test_nothing_is_decided_without_an_anchor_or_once_the_radius_is_too_wide():
    c = anchored(alarm_t_s=1.0)        # no nominal fix two seconds before the alarm
    assert c.anchor is None
    assert c.legitimate(5, 5.0 * FS, (true_chips(5, 5.0), true_chips(5, 5.0, 500.0)), predicted_chips) is None
    c = anchored()
    late = 400.0 * FS                  # the INS and the clock have drifted too far to tell
    assert c.legitimate(5, late, (true_chips(5, 400.0), true_chips(5, 400.0, 900.0)), predicted_chips) is None


def test_the_ins_displacement_moves_the_prediction():
    flown = ImuTrack(np.array([0.0, 10.0, 40.0]), np.zeros(3), np.array([0.0, 0.0, 600.0]), np.zeros(3))
    c = Continuity(FS, 150.0, flown)
    for t in np.arange(0.0, 10.0, 0.5):
        c.note(fix_at(t), {p: true_chips(p, t) for p in LOS})
    c.freeze(10.0, predicted_chips)
    t = 40.0                           # 600 m east of the anchor: the legitimate range moved by -u . d
    moved = c.predicted_position(t * FS) - ORIGIN
    assert abs(np.linalg.norm(moved) - 600.0) < 1.0
    verdicts = {}
    for prn in LOS:
        legit, left_behind = true_chips(prn, t, -LOS[prn] @ moved), true_chips(prn, t)
        verdicts[prn] = c.legitimate(prn, t * FS, (legit, left_behind), predicted_chips)
    # PRN 5 looks east (its range moved 340 m: the peak left behind is out of the radius); PRN 9 looks north
    assert verdicts == {5: 0, 9: None}, verdicts


def test_a_guess_continuity_confirms_is_resolved_and_one_it_refutes_is_swapped_then_given_up():
    from semperfi.defense.config import load_config
    from semperfi.defense.guard import MAX_SWAPS, SpoofGuard
    guard = SpoofGuard(load_config(None, []), 2e6)

    def cancelled_on_a_guess(prn):   # cancelled on the stronger-peak guess and verified clean after it
        guard.alarmed_prns.add(prn)
        guard.detector.raise_alarm(prn, 20.0)
        guard.cancel_started[prn] = 20.0
        guard.verified.add(prn)
        guard.guessed.add(prn)

    for prn in (5, 9):
        cancelled_on_a_guess(prn)
    assert not guard.resolved(5) and not guard.resolved(9)
    guard.identified(5, cancelled_is_attacker=True, t_s=30.0)
    assert guard.resolved(5)
    # the cancelled peak was the legitimate one: the cancellation is dropped and the PRN examined afresh
    guard.identified(9, cancelled_is_attacker=False, t_s=30.0)
    assert 9 not in guard.cancel_started and 9 not in guard.alarmed_prns and 9 not in guard.detector.alarmed
    assert not guard.resolved(9) and 9 not in guard.gave_up
    for _ in range(MAX_SWAPS):       # and if it keeps coming back to it, given up
        cancelled_on_a_guess(9)
        guard.identified(9, cancelled_is_attacker=False, t_s=31.0)
    assert not guard.resolved(9) and "legitimate" in guard.gave_up[9]


def test_the_maneuver_judges_a_guess_where_the_cancelled_track_is_and_nothing_it_cannot_compare():
    """A PRN cancelled on a guess, its raw peak followed through the maneuver: the follower is compared with the
    cancelled track at the track's latest code epoch (the canceller runs behind the raw stream). Where the follower
    has no history there, nothing is judged: before, that counted as 'followed peak is not the cancelled one' and
    dropped six right guesses at once."""
    from types import SimpleNamespace

    from semperfi.defense.config import load_config
    from semperfi.defense.guard import SpoofGuard
    from semperfi.receiver import Peak
    guard = SpoofGuard(load_config(None, []), 2e6)
    epoch = 123_456.0
    for prn in (5, 9, 12):
        guard.alarmed_prns.add(prn)
        guard.detector.raise_alarm(prn, 20.0)
        guard.cancel_started[prn] = 20.0
        guard.verified.add(prn)
        guard.guessed.add(prn)
    channel = SimpleNamespace(ms=500, latest_epoch_sample=epoch)
    guard.canceller.stages = [SimpleNamespace(tracks={p: SimpleNamespace(channel=channel) for p in (5, 9, 12)})]

    def follower(chips):   # a peak at `chips` from the cancelled track, known only at its latest epoch
        return SimpleNamespace(peak_at=lambda s: Peak(0, chips % 1023, 0.0, 10.0, 45.0) if s == epoch else None)

    guard._judge_cancelled(5, follower(1022.9), adversarial=True, t_s=30.0)   # the cancelled peak, shown not to follow
    assert guard.resolved(5)
    guard._judge_cancelled(9, follower(0.8), adversarial=True, t_s=30.0)      # another peak did not follow
    assert 9 not in guard.cancel_started and not guard.resolved(9)
    guard._judge_cancelled(12, SimpleNamespace(peak_at=lambda s: None), adversarial=True, t_s=30.0)
    assert 12 in guard.guessed and 12 in guard.cancel_started, "judged on nothing"


def test_known_prns_correct_the_prediction_of_a_drag_before_the_alarm():
    """A spoofer dragged the tracked ranges 120 m east before the alarm (unseen: each range pulled less than the
    separation), so the anchor sits 120 m off. Five PRNs known legitimate measure that; the sixth, whose spoofer's
    peak is 110 m from its legitimate one, is decided once the correction applies, and not before."""
    los = {p: v / np.linalg.norm(v) for p, v in {1: np.array([0.3, 0.2, 0.9]), 2: np.array([-0.7, 0.1, 0.7]),
                                                3: np.array([0.1, -0.8, 0.6]), 4: np.array([0.6, 0.6, 0.5]),
                                                5: np.array([-0.4, -0.5, 0.75]), 6: np.array([0.9, -0.1, 0.4])}.items()}
    drag = np.array([0.0, 120.0, 0.0])   # ECEF metres, as good as any direction for the fit

    def chips_at(prn, pos_ecef_m, clock_m=0.0):
        return (300.0 + (los[prn] @ (pos_ecef_m - ORIGIN) + clock_m) / CHIP_M) % 1023.0

    def predicted(prn, sample, fix, pos_ecef_m):
        return chips_at(prn, pos_ecef_m)

    still = ImuTrack(np.array([0.0, 100.0]), np.zeros(2), np.zeros(2), np.zeros(2))
    c = Continuity(FS, 150.0, still)
    for t in np.arange(0.0, 10.0, 0.5):
        fix = fix_at(t)
        fix = Fix(**{**fix.__dict__, "pos_ecef_m": ORIGIN + drag})        # the dragged anchor
        c.note(fix, {p: chips_at(p, ORIGIN + drag) for p in los})
    c.freeze(10.0, predicted)
    t = 20.0
    legit, spoofer = chips_at(6, ORIGIN), chips_at(6, ORIGIN, 110.0)
    assert c.legitimate(6, t * FS, (legit, spoofer), predicted) is None   # both within 150 m of the dragged anchor
    c.refine(t * FS, {p: chips_at(p, ORIGIN) for p in (1, 2, 3, 4, 5)}, predicted)
    assert c.correction is not None and np.allclose(c.correction[1][:3], -drag, atol=0.5), c.correction
    assert c.legitimate(6, t * FS, (legit, spoofer), predicted) == 0
    assert c.legitimate(6, t * FS, (spoofer, legit), predicted) == 1
    # known PRNs that disagree with any one position and clock correct nothing
    c.refine(t * FS, {**{p: chips_at(p, ORIGIN) for p in (1, 2, 3, 4)}, 5: chips_at(5, ORIGIN, 80.0)}, predicted)
    assert c.correction is None


def test_with_no_maneuver_to_decide_a_guess_falls_back_on_the_power_relation_continuity_showed():
    """Continuity named the attacker's peak on three PRNs (it appeared after the receiver had the other), each the
    stronger by 3-5 dB. A later alarm with no earlier lock and no maneuver to come is decided by that relation, not
    guessed; where the attacker was the weaker on one of them, no relation holds and it stays a guess."""
    from semperfi.defense.config import load_config
    from semperfi.defense.detector import Alarm, PeakPair
    from semperfi.defense.guard import SpoofGuard
    from semperfi.receiver import Peak

    def alarm(prn, attacker_metric, twin_metric, newcomer):
        attacker, twin = Peak(prn, 100.0, 1000.0, attacker_metric, 45.0), Peak(prn, 102.0, 1000.0, twin_metric, 42.0)
        pair = PeakPair(prn, attacker, twin, 2.0, "caf")
        return Alarm(20.0, prn, pair, 100.0 if newcomer else None)

    for weaker_on_one, guessed in ((False, False), (True, True)):
        guard = SpoofGuard(load_config(None, []), 2e6)
        started = {}
        guard._start_cancelling = lambda prn, t_s, choice: started.setdefault(prn, choice)
        for prn, gap in zip((3, 5, 7), (2.0, 3.0, 0.5 if weaker_on_one else 2.5)):
            guard._on_alarm(alarm(prn, 40.0 * gap, 40.0, newcomer=True), 20.0)
        guard._on_alarm(alarm(9, 100.0, 40.0, newcomer=False), 21.0)   # the stronger peak at 100.0 chips
        assert [started[p].guessed for p in (3, 5, 7)] == [False] * 3
        assert started[9].guessed == guessed and started[9].adversarial.code_phase_chips == 100.0, started[9]
