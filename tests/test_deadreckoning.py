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


def test_a_gyro_bias_measured_in_the_hover_is_taken_off():
    from semperfi.flight.deadreckoning import bias_between, hover_bias, ins_error_bound_m
    t, p, f, w, v0 = known_trajectory()
    bias = np.array([1e-3, -8e-4, 5e-4])   # SITL's gyro a few minutes after boot
    drift = np.full(3, 1.5e-5)              # and how fast it moves (0.05 deg/s a minute)
    rng = np.random.default_rng(1)

    def hover(t0_s):   # 3 s still and level, heading 0: the autopilot's attitude does not move
        th = t0_s + np.arange(0, 3, 0.02)
        gyro = bias + np.outer(th, drift) + rng.normal(0, 3e-4, (len(th), 3))
        accel = np.tile(-GRAVITY_NED_MPS2, (len(th), 1)) + rng.normal(0, 0.01, (len(th), 3))
        return hover_bias(th, accel, gyro, th, np.zeros((len(th), 3)), th, np.zeros((len(th), 3))), th.mean()

    (before, tb), (after, ta) = hover(-3.0), hover(t[-1])
    est = bias_between(before, after, tb, ta, 0.0)
    assert np.allclose(est.gyro_bias_rps, bias, atol=1e-4), est.gyro_bias_rps
    assert np.allclose(est.accel_residual_ned_mps2, 0.0), "the accelerometer's noise is not taken for a bias"
    wb = w + bias + np.outer(t, drift)
    raw = integrate(t, f, wb, vel0_ned_mps=v0)
    fixed = integrate(t, f, wb, vel0_ned_mps=v0, bias=est)
    end = p[-1] - p[0]
    assert np.linalg.norm(raw.pos_ned_m[-1] - end) > 3.0
    assert np.linalg.norm(fixed.pos_ned_m[-1] - end) < 0.3 * ins_error_bound_m(t[-1])
