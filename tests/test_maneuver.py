import math

import numpy as np
import pytest

from semperfi.flight.maneuver import ManeuverLimits, check, draw


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


def test_rejects_bad_limits():
    with pytest.raises(ValueError):
        ManeuverLimits(max_duration_s=30.0)
    with pytest.raises(ValueError):
        draw(altitude_m=5.0)
