import numpy as np

from semperfi.flight.deadreckoning import GRAVITY_NED_MPS2, integrate


def known_trajectory():
    # a circle-ish 15 s path with the vehicle yawing: p(t), heading psi(t)
    t = np.arange(0, 15, 0.005)
    p = np.c_[10 * np.sin(0.3 * t), 8 * (1 - np.cos(0.3 * t)), -0.5 * t]
    a = np.c_[-0.9 * np.sin(0.3 * t), 0.72 * np.cos(0.3 * t), np.zeros_like(t)]
    v0 = np.array([3.0, 0.0, -0.5])
    psi = 0.2 * t
    rate = np.c_[np.zeros_like(t), np.zeros_like(t), np.full_like(t, 0.2)]   # yaw rate about body z (down)
    f_body = []
    for ai, ps in zip(a, psi):
        c_nb = np.array([[np.cos(ps), -np.sin(ps), 0], [np.sin(ps), np.cos(ps), 0], [0, 0, 1]])
        f_body.append(c_nb.T @ (ai - GRAVITY_NED_MPS2))
    return t, p, np.array(f_body), rate, v0


def test_strapdown_follows_known_trajectory():
    t, p, f, w, v0 = known_trajectory()
    ins = integrate(t, f, w, vel0_ned_mps=v0)
    err = np.linalg.norm(ins.pos_ned_m - (p - p[0]), axis=1)
    assert err.max() < 0.05


def test_gyro_bias_makes_drift_visible():
    t, p, f, w, v0 = known_trajectory()
    w = w + np.array([0.0, 0.01, 0.0])     # 0.57 deg/s pitch-rate bias tilts gravity into the horizontal
    ins = integrate(t, f, w, vel0_ned_mps=v0)
    assert np.linalg.norm(ins.pos_ned_m[-1] - (p[-1] - p[0])) > 1.0
