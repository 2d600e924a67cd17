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


class Multicopter:
    """The vehicle one step at a time (the MAVLink endpoint drives it live); seeded: same seed, same flight.

    step() takes the commanded NED velocity, moves the vehicle by dt_s and returns the IMU's specific force and
    angular rate (body frame, with errors) over that step."""

    def __init__(self, seed: int, heading_rad: float = 0.0, params=VehicleParams(), imu=ImuErrors(),
                 pos_ned_m=(0.0, 0.0, 0.0)):
        self.params, self.imu = params, imu
        self.rng = np.random.default_rng(seed)
        self.heading_rad = float(heading_rad)
        self.pos_ned_m = np.array(pos_ned_m, float)
        self.vel_ned_mps = np.zeros(3)
        self.accel_ned_mps2 = np.zeros(3)
        self._gust = np.zeros(3)
        self._c_nb = np.array([[np.cos(heading_rad), -np.sin(heading_rad), 0],
                               [np.sin(heading_rad), np.cos(heading_rad), 0], [0, 0, 1]])
        self._a_bias = self.rng.normal(0, imu.accel_bias_mps2, 3)
        self._g_bias = self.rng.normal(0, imu.gyro_bias_rps, 3)

    def step(self, setpoint_vel_ned_mps, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        p, imu, rng = self.params, self.imu, self.rng
        a_cmd = p.velocity_gain_per_s * (np.asarray(setpoint_vel_ned_mps, float) - self.vel_ned_mps)
        norm = np.linalg.norm(a_cmd)
        if norm > p.max_accel_mps2:
            a_cmd *= p.max_accel_mps2 / norm
        alpha = np.exp(-dt_s / p.gust_tau_s)
        self._gust = alpha * self._gust + np.sqrt(1 - alpha ** 2) * rng.normal(0, p.gust_sigma_mps2, 3)
        a = a_cmd + self._gust
        self._a_bias = self._a_bias + rng.normal(0, imu.accel_bias_instability_mps2 * np.sqrt(dt_s), 3)
        f_true = self._c_nb.T @ (a - GRAVITY_NED_MPS2)
        accel = f_true + self._a_bias + rng.normal(0, imu.accel_noise_mps2_rthz / np.sqrt(dt_s), 3)
        gyro = self._g_bias + rng.normal(0, imu.gyro_noise_rps_rthz / np.sqrt(dt_s), 3)
        self.pos_ned_m = self.pos_ned_m + self.vel_ned_mps * dt_s + 0.5 * a * dt_s ** 2
        self.vel_ned_mps = self.vel_ned_mps + a * dt_s
        self.accel_ned_mps2 = a
        return accel, gyro


def fly(setpoints, dt_s: float, seed: int, heading_rad: float = 0.0, params=VehicleParams(),
        imu=ImuErrors()) -> FlightRecord:
    """setpoints: (n, 3) commanded NED velocity per step.  Seeded: same seed, same flight."""
    vehicle = Multicopter(seed, heading_rad, params, imu)
    pos, vel, acc, gyr = [], [], [], []
    for sp in np.asarray(setpoints, float):
        pos.append(vehicle.pos_ned_m.copy())
        vel.append(vehicle.vel_ned_mps.copy())
        f, w = vehicle.step(sp, dt_s)
        acc.append(f)
        gyr.append(w)
    return FlightRecord(np.arange(len(pos)) * dt_s, np.array(pos), np.array(vel), np.array(acc), np.array(gyr))
