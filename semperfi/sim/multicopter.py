"""Multicopter point-mass dynamics with a velocity loop, acceleration limit and seeded wind gusts, and an IMU error
model (bias, bias instability, white noise, velocity random walk) producing accelerometer/gyro samples (FRD body,
NED nav, level flight with yaw held: the body is the NED frame rotated by the heading)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semperfi.flight.deadreckoning import GRAVITY_NED_MPS2


@dataclass(frozen=True)
class VehicleParams:
    velocity_gain_per_s: float = 2.0
    max_accel_mps2: float = 3.0
    gust_sigma_mps2: float = 0.3
    gust_tau_s: float = 2.0


@dataclass(frozen=True)
class ImuErrors:
    """Defaults reach ~1.59 km/h (0.44 m/s) velocity error over 20 s, the paper's worst case."""
    accel_bias_mps2: float = 0.005
    accel_bias_instability_mps2: float = 0.002
    accel_noise_mps2_rthz: float = 0.05      # velocity random walk
    gyro_bias_rps: float = 3e-5
    gyro_noise_rps_rthz: float = 3e-4


@dataclass(frozen=True)
class FlightRecord:
    t_s: np.ndarray
    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    accel_body_mps2: np.ndarray   # IMU specific force, with errors
    gyro_body_rps: np.ndarray


def fly(setpoints, dt_s: float, seed: int, heading_rad: float = 0.0, params=VehicleParams(),
        imu=ImuErrors()) -> FlightRecord:
    """setpoints: (n, 3) commanded NED velocity per step.  Seeded: same seed, same flight."""
    rng = np.random.default_rng(seed)
    sp = np.asarray(setpoints, float)
    n = len(sp)
    v = np.zeros(3)
    p = np.zeros(3)
    gust = np.zeros(3)
    c = np.array([[np.cos(heading_rad), -np.sin(heading_rad), 0], [np.sin(heading_rad), np.cos(heading_rad), 0],
                  [0, 0, 1]])
    a_bias = rng.normal(0, imu.accel_bias_mps2, 3)
    g_bias = rng.normal(0, imu.gyro_bias_rps, 3)
    pos, vel, acc, gyr = [], [], [], []
    alpha = np.exp(-dt_s / params.gust_tau_s)
    for k in range(n):
        a_cmd = params.velocity_gain_per_s * (sp[k] - v)
        norm = np.linalg.norm(a_cmd)
        if norm > params.max_accel_mps2:
            a_cmd *= params.max_accel_mps2 / norm
        gust = alpha * gust + np.sqrt(1 - alpha ** 2) * rng.normal(0, params.gust_sigma_mps2, 3)
        a = a_cmd + gust
        a_bias = a_bias + rng.normal(0, imu.accel_bias_instability_mps2 * np.sqrt(dt_s), 3)
        f_true = c.T @ (a - GRAVITY_NED_MPS2)
        pos.append(p.copy())
        vel.append(v.copy())
        acc.append(f_true + a_bias + rng.normal(0, imu.accel_noise_mps2_rthz / np.sqrt(dt_s), 3))
        gyr.append(g_bias + rng.normal(0, imu.gyro_noise_rps_rthz / np.sqrt(dt_s), 3))
        p = p + v * dt_s + 0.5 * a * dt_s ** 2
        v = v + a * dt_s
    return FlightRecord(np.arange(n) * dt_s, np.array(pos), np.array(vel), np.array(acc), np.array(gyr))
