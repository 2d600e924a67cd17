"""Strapdown inertial navigation (body frame FRD, navigation frame local NED), decoupled from GPS.

During the maneuver the flight side stops fusing GPS (the paper's EKF/GPS decoupling) and integrates the IMU alone
from the state at the maneuver start.  Earth rotation and transport rate are neglected: over <= 20 s and < 50 m
they add centimetres, far below the IMU errors the identifier tolerates.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

GRAVITY_NED_MPS2 = np.array([0.0, 0.0, 9.80665])


@dataclass(frozen=True)
class InsTrack:
    t_s: np.ndarray
    pos_ned_m: np.ndarray     # (n, 3)
    vel_ned_mps: np.ndarray   # (n, 3)


def _rodrigues(phi: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(phi))
    k = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    if a < 1e-9:
        return np.eye(3) + k
    return np.eye(3) + np.sin(a) / a * k + (1 - np.cos(a)) / a ** 2 * (k @ k)


def integrate(t_s, accel_body_mps2, gyro_body_rps, c_nb0=None, vel0_ned_mps=None) -> InsTrack:
    """Integrate specific force (m/s^2) and angular rate (rad/s), both in the body frame, sampled at t_s."""
    t = np.asarray(t_s, float)
    f = np.asarray(accel_body_mps2, float)
    w = np.asarray(gyro_body_rps, float)
    if f.shape != (len(t), 3) or w.shape != (len(t), 3) or len(t) < 2:
        raise ValueError("accel and gyro must be (n, 3) with n = len(t_s) >= 2")
    if np.any(np.diff(t) <= 0) or not np.all(np.isfinite(f)) or not np.all(np.isfinite(w)):
        raise ValueError("IMU samples: time must increase and values be finite")
    c = np.eye(3) if c_nb0 is None else np.array(c_nb0, float)
    v = np.zeros(3) if vel0_ned_mps is None else np.array(vel0_ned_mps, float)
    p = np.zeros(3)
    pos, vel = [p.copy()], [v.copy()]
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        # trapezoid on rates and specific force: second-order accurate attitude and velocity
        c_next = c @ _rodrigues(0.5 * (w[i] + w[i + 1]) * dt)
        a0 = c @ f[i] + GRAVITY_NED_MPS2
        a1 = c_next @ f[i + 1] + GRAVITY_NED_MPS2
        v_next = v + 0.5 * (a0 + a1) * dt
        p = p + 0.5 * (v + v_next) * dt
        v, c = v_next, c_next
        pos.append(p.copy())
        vel.append(v.copy())
    return InsTrack(t, np.array(pos), np.array(vel))


def write_track_csv(path, t_s, pos_ned_m) -> Path:
    """The IMU track in `semperfi run --imu` format: t_s,north_m,east_m,down_m."""
    np.savetxt(path, np.column_stack([t_s, pos_ned_m]), fmt="%.3f", delimiter=",",
               header="t_s,north_m,east_m,down_m", comments="")
    return Path(path)
