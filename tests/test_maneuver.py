import math
import random

import numpy as np
import pytest

from semperfi.defense.identifier import MIN_SIGNATURE_M, ImuTrack, LineOfSight, PeakHistory, identify_peaks
from semperfi.defense.identifier import REQUIRED_SPREAD_M
from semperfi.flight.maneuver import ManeuverLimits, check, draw, spread_m, unit_ned

# the closed loop's sky (Boston, 2022-01-01 00:00:27): azimuth, elevation of its 8 PRNs
SKY = [(154.4, 48.3), (206.4, 60.0), (53.2, 42.8), (310.6, 13.1), (299.3, 36.0), (242.9, 20.8), (99.7, 58.9),
       (58.2, 11.6)]


def test_constraints_over_1000_draws():
    limits = ManeuverLimits()
    durations, ends = [], []
    for i in range(1000):
        heading = (i % 8) * math.pi / 4
        m = draw(limits, track_heading_rad=heading, altitude_m=40.0)
        assert m.duration_s <= 20.0
        assert m.end_distance_m >= 30.0 and m.path_length_m <= 50.0
        cross = -m.north_m * math.sin(heading) + m.east_m * math.cos(heading)
        assert np.max(np.abs(cross)) > 10.0          # leaves the 20 m corridor
        assert np.max(np.hypot(m.north_m, m.east_m)) <= limits.geofence_radius_m
        assert 40.0 - np.max(m.down_m) >= limits.min_altitude_m
        v = np.diff(np.c_[m.north_m, m.east_m], axis=0) / limits.dt_s
        assert np.max(np.hypot(v[:, 0], v[:, 1])) <= limits.max_speed_mps + 1e-6
        assert np.max(np.linalg.norm(np.diff(v, axis=0), axis=1)) / limits.dt_s <= limits.max_accel_mps2 + 1e-6
        assert check(m, limits, heading, 40.0) == []
        durations.append(m.duration_s)
        ends.append(m.end_distance_m)
    # drawn from the OS source: not all the same
    assert len(set(np.round(ends, 6))) > 990


def test_check_flags_a_straight_short_maneuver():
    from semperfi.flight.maneuver import Leg, Maneuver, plan_trajectory
    limits = ManeuverLimits()
    legs = (Leg(2.0, 0.0, 0.0, 3.0), Leg(2.0, 0.0, 0.0, 3.0))
    t, n, e, d = plan_trajectory(legs, limits)
    bad = check(Maneuver(legs, t, n, e, d), limits)
    assert {"straight", "end distance", "corridor"} <= set(bad)
    climb = (Leg(3.0, 0.0, -1.5, 8.0), Leg(0.0, 3.0, -1.5, 8.0))
    assert "altitude" in check(Maneuver(climb, *plan_trajectory(climb, limits)), limits, altitude_m=100.0)


def test_rejects_bad_limits():
    with pytest.raises(ValueError):
        ManeuverLimits(max_duration_s=30.0)
    with pytest.raises(ValueError):
        draw(altitude_m=5.0)
    with pytest.raises(ValueError):
        draw(altitude_m=130.0)   # above the ceiling


def test_a_seeded_draw_repeats():
    a, b = draw(rng=random.Random(7)), draw(rng=random.Random(7))
    assert a.legs == b.legs and np.array_equal(a.down_m, b.down_m)
    assert draw(rng=random.Random(8)).legs != a.legs


def test_the_spread_is_the_signature_the_identifier_decides_on():
    """A legitimate peak, its range following the maneuver exactly, is decided when the maneuver's spread along its
    line of sight reaches MIN_SIGNATURE_M, and left undecided below."""
    u = [unit_ned(az, el) for az, el in SKY]
    m = draw(rng=random.Random(3))   # no lines of sight: moves little along some
    spread = spread_m(m, u)
    assert spread.min() < MIN_SIGNATURE_M - 0.2 and spread.max() > MIN_SIGNATURE_M + 0.2, spread
    p = np.column_stack([m.north_m, m.east_m, m.down_m])
    clock_m = 40.0 * m.t_s
    peaks = [PeakHistory(k + 1, 0, m.t_s, 2.2e7 - p @ uk + clock_m) for k, uk in enumerate(u)]
    los = {k + 1: LineOfSight(k + 1, tuple(uk), m.t_s, np.zeros_like(m.t_s)) for k, uk in enumerate(u)}
    verdicts = identify_peaks(peaks, los, ImuTrack(m.t_s, m.north_m, m.east_m, m.down_m))
    for v, s in zip(verdicts, spread):
        if abs(s - MIN_SIGNATURE_M) > 0.2:
            assert v.decided == (s >= MIN_SIGNATURE_M) and not v.adversarial, (v, s)


def test_a_draw_that_moves_little_along_a_line_of_sight_is_rejected():
    u = [unit_ned(az, el) for az, el in SKY]
    free = draw(rng=random.Random(3))
    weak = u[int(np.argmin(spread_m(free, u)))]
    assert spread_m(free, [weak])[0] < REQUIRED_SPREAD_M
    # the same random source, told the line of sight: that draw is refused and the one flown moves along it
    told = draw(lines_of_sight=[weak], required_spread_m=REQUIRED_SPREAD_M, rng=random.Random(3))
    assert spread_m(told, [weak])[0] >= REQUIRED_SPREAD_M
    assert check(told, ManeuverLimits()) == []


def test_accepted_draws_move_enough_along_every_line_of_sight():
    limits = ManeuverLimits()
    for seed in range(60):
        turn_deg, heading = seed * 37.0, seed * 0.7   # the closed loop's sky, turned round: 60 geometries
        u = [unit_ned((az + turn_deg) % 360.0, el) for az, el in SKY]
        m = draw(limits, track_heading_rad=heading, lines_of_sight=u, required_spread_m=REQUIRED_SPREAD_M,
                 rng=random.Random(seed))
        assert spread_m(m, u).min() >= REQUIRED_SPREAD_M, seed
        assert check(m, limits, heading) == []
        assert np.max(np.abs(np.diff(m.down_m))) / limits.dt_s <= limits.max_vertical_speed_mps + 1e-9


def test_without_an_acceptable_draw_the_best_is_flown():
    """A vehicle that may barely climb cannot move 4.4 m along the zenith: the best draw of the search is flown."""
    limits = ManeuverLimits(max_vertical_speed_mps=0.1)
    u = [unit_ned(0.0, 90.0), unit_ned(30.0, 20.0)]
    few = draw(limits, lines_of_sight=u, required_spread_m=REQUIRED_SPREAD_M, rng=random.Random(5), max_tries=5)
    more = draw(limits, lines_of_sight=u, required_spread_m=REQUIRED_SPREAD_M, rng=random.Random(5),
                max_tries=200)
    assert check(few, limits) == [] and check(more, limits) == []
    assert spread_m(few, u).min() <= spread_m(more, u).min() < REQUIRED_SPREAD_M
