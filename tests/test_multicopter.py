import math

import numpy as np

from semperfi.flight.deadreckoning import bias_between, hover_bias, integrate
from semperfi.sim.multicopter import ImuErrors, fly

HOVER_S = 3.0


def setpoints(dt):
    n = int(6 / dt)
    hover = np.zeros((int(HOVER_S / dt), 3))
    return np.r_[hover, np.tile([4.0, 0, 0], (n, 1)), np.tile([0, 4.0, 0], (n, 1)), np.tile([-2.0, 2.0, 0], (n, 1)),
                 np.zeros((n // 2, 3)), hover]


def _rpy(c):
    return [math.atan2(c[2, 1], c[2, 2]), -math.asin(c[2, 0]), math.atan2(c[1, 0], c[0, 0])]


def _hover(r, sel):
    """What the flight side measures in a hover: the IMU against the autopilot's attitude (true, here)."""
    return hover_bias(r.imu_t_s[sel], r.accel_body_mps2[sel], r.gyro_body_rps[sel], r.t_s[sel],
                      [_rpy(c) for c in r.c_nb[sel]], r.t_s[sel], r.vel_ned_mps[sel])


def test_the_vehicle_faces_its_travel_and_tilts_when_it_accelerates():
    dt = 0.02
    r = fly(setpoints(dt), dt, seed=1, heading_rad=0.0)
    heading = np.degrees(np.arctan2(r.c_nb[:, 1, 0], r.c_nb[:, 0, 0]))
    tilt = np.degrees(np.arccos(r.c_nb[:, 2, 2]))
    k = int((HOVER_S + 11.0) / dt)   # flying east
    assert abs(heading[k] - 90.0) < 5.0, heading[k]
    assert tilt.max() > 8.0 and tilt[int(HOVER_S / dt) - 1] < 3.0, tilt.max()   # gusts lean it a little
    held = fly(setpoints(dt), dt, seed=1, heading_rad=0.0, yaw_rad=0.0)
    assert np.max(np.abs(np.arctan2(held.c_nb[:, 1, 0], held.c_nb[:, 0, 0]))) < 0.01, "a heading asked is held"


def test_seeded_and_dead_reckoning_drift_at_paper_level_once_the_hovers_measure_the_biases():
    dt = 0.02
    a = fly(setpoints(dt), dt, seed=3, heading_rad=0.7)
    b = fly(setpoints(dt), dt, seed=3, heading_rad=0.7)
    assert np.array_equal(a.accel_body_mps2, b.accel_body_mps2)
    raw, calibrated = [], []
    imu = ImuErrors(gyro_bias_rps=1e-3)   # SITL's gyro, a few minutes after boot
    for seed in range(10):
        r = fly(setpoints(dt), dt, seed=seed, heading_rad=0.7, imu=imu)
        assert np.linalg.norm(r.pos_ned_m[-1]) > 30          # the vehicle actually went somewhere
        n_hover = int(HOVER_S / dt)
        before, after = slice(0, n_hover), slice(len(r.t_s) - n_hover, len(r.t_s))
        man = slice(n_hover - 1, len(r.t_s) - n_hover)
        t = r.imu_t_s[man]
        bias = bias_between(_hover(r, before), _hover(r, after), r.imu_t_s[before].mean(), r.imu_t_s[after].mean(),
                            t[0])
        for errs, b in ((raw, None), (calibrated, bias)):
            ins = integrate(t, r.accel_body_mps2[man], r.gyro_body_rps[man], c_nb0=r.c_nb[n_hover - 1],
                            vel0_ned_mps=r.vel_ned_mps[n_hover - 1], bias=b)
            errs.append(np.linalg.norm(ins.vel_ned_mps[-1] - r.vel_ned_mps[man][-1]))
    # 27 s of flight: a 1 mrad/s gyro bias left in costs metres a second; measured in the hovers, the error is
    # near the paper's 1.59 km/h (0.44 m/s after 20 s; its accelerometer's noise alone walks to 0.45 m/s in 27 s),
    # not zero
    assert np.median(raw) > 1.0, raw
    assert 0.01 < np.median(calibrated) < 0.8, calibrated
