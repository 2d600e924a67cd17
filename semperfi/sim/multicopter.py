"""Multicopter dynamics as ArduCopter flies them, with an IMU error model: a velocity loop under an acceleration
limit and seeded wind gusts; the body tilted so its thrust gives that acceleration (a multicopter's accelerometer
sees thrust along its body z only, ~10 deg at 2 m/s^2); the heading turned at a limited rate to face the direction
of travel (ArduCopter's WP_YAW_BEHAVIOR) unless a heading is commanded; and an IMU (FRD body, NED navigation frame)
with bias, bias instability, white noise and a gyro bias that drifts with time, as ArduCopter SITL's does."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semperfi.flight import GRAVITY_NED_MPS2, rotation_matrix


@dataclass(frozen=True)
class VehicleParams:
    velocity_gain_per_s: float = 2.0
    max_accel_mps2: float = 3.0
    gust_sigma_mps2: float = 0.3
    gust_tau_s: float = 2.0
    tilt_hz: float = 1.5                   # the body leans toward the thrust asked, critically damped: rates stay
    max_yaw_rate_rps: float = math.radians(60.0)      # continuous, as a real airframe's (and strapdown needs)
    max_yaw_accel_rps2: float = math.radians(120.0)
    face_travel_above_mps: float = 1.0     # slower than this the heading is held


@dataclass(frozen=True)
class ImuErrors:
    """Defaults reach ~1.59 km/h (0.44 m/s) velocity error over 20 s, the paper's worst case, once the hover has
    measured the biases; without that the gyro's drift alone (SITL's 0.05 deg/s per minute, on every axis) moves a
    20 s track metres."""
    accel_bias_mps2: float = 0.005
    accel_bias_instability_mps2: float = 0.002
    accel_noise_mps2_rthz: float = 0.05      # velocity random walk
    gyro_bias_rps: float = 3e-5
    gyro_noise_rps_rthz: float = 3e-4
    gyro_drift_rps_per_s: float = math.radians(0.05) / 60.0


@dataclass(frozen=True)
class FlightRecord:
    t_s: np.ndarray
    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    accel_body_mps2: np.ndarray   # IMU specific force, with errors
    gyro_body_rps: np.ndarray
    c_nb: np.ndarray              # (n, 3, 3) body to NED at each t_s
    imu_t_s: np.ndarray           # when the IMU samples were taken: t_s + dt_s / 2


def attitude(thrust_ned: np.ndarray, yaw_rad: float) -> np.ndarray:
    """Body (FRD) to NED rotation of a multicopter whose body -z points along thrust_ned (the specific force's
    opposite, a - g reversed), with its nose at yaw_rad."""
    z_b = -thrust_ned / np.linalg.norm(thrust_ned)
    heading = np.array([math.cos(yaw_rad), math.sin(yaw_rad), 0.0])
    x_b = heading - (heading @ z_b) / z_b[2] * np.array([0.0, 0.0, 1.0])   # the nose over the heading (Euler yaw)
    x_b /= np.linalg.norm(x_b)
    return np.column_stack([x_b, np.cross(z_b, x_b), z_b])


def rotation_vector(c: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle) of a rotation matrix."""
    angle = math.acos(max(-1.0, min(1.0, (np.trace(c) - 1.0) / 2.0)))
    axis = np.array([c[2, 1] - c[1, 2], c[0, 2] - c[2, 0], c[1, 0] - c[0, 1]]) / 2.0
    return axis if angle < 1e-9 else axis * (angle / math.sin(angle))


class Multicopter:
    """The vehicle one step at a time (the MAVLink endpoint drives it live); seeded: same seed, same flight.

    step() takes the commanded NED velocity (and heading, or None to face the travel), moves the vehicle by dt_s and
    returns the IMU's specific force and angular rate (body frame, with errors) at the step's midpoint, dt_s / 2
    before the time it ends at (a sample a real IMU could give, as the strapdown integration reads them)."""

    def __init__(self, seed: int, heading_rad: float = 0.0, params=VehicleParams(), imu=ImuErrors(),
                 pos_ned_m=(0.0, 0.0, 0.0)):
        self.params, self.imu = params, imu
        self.rng = np.random.default_rng(seed)
        self.heading_rad = float(heading_rad)
        self.pos_ned_m = np.array(pos_ned_m, float)
        self.vel_ned_mps = np.zeros(3)
        self.accel_ned_mps2 = np.zeros(3)
        self.rates_body_rps = np.zeros(3)
        self.t_s = 0.0
        self._gust = np.zeros(3)
        self._axis_rate = np.zeros(3)   # how fast the thrust axis (a unit vector, NED) swings
        self._yaw_rate_rps = 0.0
        self.c_nb = attitude(-GRAVITY_NED_MPS2, self.heading_rad)
        self._a_bias = self.rng.normal(0, imu.accel_bias_mps2, 3)
        self._g_bias = self.rng.normal(0, imu.gyro_bias_rps, 3)

    @property
    def roll_pitch_yaw_rad(self) -> np.ndarray:
        c = self.c_nb
        return np.array([math.atan2(c[2, 1], c[2, 2]), -math.asin(max(-1.0, min(1.0, c[2, 0]))),
                         math.atan2(c[1, 0], c[0, 0])])

    def step(self, setpoint_vel_ned_mps, dt_s: float, yaw_rad: float | None = None,
             accel_ned_mps2=None) -> tuple[np.ndarray, np.ndarray]:
        """accel_ned_mps2: the acceleration asked for instead of a velocity (an attitude target's tilt)."""
        p, imu, rng = self.params, self.imu, self.rng
        a_cmd = (p.velocity_gain_per_s * (np.asarray(setpoint_vel_ned_mps, float) - self.vel_ned_mps)
                 if accel_ned_mps2 is None else np.array(accel_ned_mps2, float))
        norm = np.linalg.norm(a_cmd)
        if norm > p.max_accel_mps2:
            a_cmd *= p.max_accel_mps2 / norm
        alpha = np.exp(-dt_s / p.gust_tau_s)
        self._gust = alpha * self._gust + np.sqrt(1 - alpha ** 2) * rng.normal(0, p.gust_sigma_mps2, 3)
        # the thrust axis leans toward the one asked (first order); the thrust along it is what was asked, through
        # the step along the body's z axis at its midpoint (where the IMU is sampled)
        wanted = a_cmd - GRAVITY_NED_MPS2
        wn = 2 * math.pi * p.tilt_hz
        rate0 = self._axis_rate
        self._axis_rate = rate0 + (wn ** 2 * (wanted / np.linalg.norm(wanted) + self.c_nb[:, 2])
                                   - 2 * wn * rate0) * dt_s
        axis = -self.c_nb[:, 2] + 0.5 * (rate0 + self._axis_rate) * dt_s   # the rate ramps through the step
        self._turn(yaw_rad, dt_s)
        c_next = attitude(axis, self.heading_rad)
        turned = rotation_vector(self.c_nb.T @ c_next)
        self.rates_body_rps = turned / dt_s
        c_mid = self.c_nb @ rotation_matrix(turned / 2)
        self.c_nb = c_next
        self.t_s += dt_s
        a = -c_mid[:, 2] * np.linalg.norm(wanted) + GRAVITY_NED_MPS2 + self._gust
        self._a_bias = self._a_bias + rng.normal(0, imu.accel_bias_instability_mps2 * np.sqrt(dt_s), 3)
        f_true = c_mid.T @ (a - GRAVITY_NED_MPS2)   # thrust along body z, and the gust's push
        accel = f_true + self._a_bias + rng.normal(0, imu.accel_noise_mps2_rthz / np.sqrt(dt_s), 3)
        drift = imu.gyro_drift_rps_per_s * self.t_s
        gyro = self.rates_body_rps + self._g_bias + drift + rng.normal(0, imu.gyro_noise_rps_rthz / np.sqrt(dt_s), 3)
        self.pos_ned_m = self.pos_ned_m + self.vel_ned_mps * dt_s + 0.5 * a * dt_s ** 2
        self.vel_ned_mps = self.vel_ned_mps + a * dt_s
        self.accel_ned_mps2 = a
        return accel, gyro

    def rest(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """A step standing on the ground: only the IMU's errors move."""
        imu, rng = self.imu, self.rng
        self.t_s += dt_s
        self.vel_ned_mps = np.zeros(3)
        self.accel_ned_mps2 = np.zeros(3)
        self.rates_body_rps = np.zeros(3)
        accel = (self.c_nb.T @ -GRAVITY_NED_MPS2 + self._a_bias
                 + rng.normal(0, imu.accel_noise_mps2_rthz / np.sqrt(dt_s), 3))
        gyro = (self._g_bias + imu.gyro_drift_rps_per_s * self.t_s
                + rng.normal(0, imu.gyro_noise_rps_rthz / np.sqrt(dt_s), 3))
        return accel, gyro

    def _turn(self, yaw_rad: float | None, dt_s: float) -> None:
        """Toward the commanded heading, else toward the direction of travel when moving, at the yaw rate limit."""
        vn, ve = self.vel_ned_mps[:2]
        if yaw_rad is None and math.hypot(vn, ve) < self.params.face_travel_above_mps:
            gap = 0.0   # slow: the heading is held
        elif yaw_rad is None:
            gap = (math.atan2(ve, vn) - self.heading_rad + math.pi) % (2 * math.pi) - math.pi
        else:
            gap = (yaw_rad - self.heading_rad + math.pi) % (2 * math.pi) - math.pi
        p = self.params
        # the rate that would stop on the heading at the accel limit, reached at that limit: no jump in rate
        wanted = math.copysign(min(p.max_yaw_rate_rps, math.sqrt(2 * p.max_yaw_accel_rps2 * abs(gap)) * 0.9), gap)
        step = p.max_yaw_accel_rps2 * dt_s
        rate0 = self._yaw_rate_rps
        self._yaw_rate_rps += max(-step, min(step, wanted - rate0))
        turn = 0.5 * (rate0 + self._yaw_rate_rps) * dt_s
        self.heading_rad = (self.heading_rad + turn + math.pi) % (2 * math.pi) - math.pi


def fly(setpoints, dt_s: float, seed: int, heading_rad: float = 0.0, params=VehicleParams(),
        imu=ImuErrors(), yaw_rad: float | None = None) -> FlightRecord:
    """setpoints: (n, 3) commanded NED velocity per step (yaw_rad: the heading held; None faces the travel).
    Seeded: same seed, same flight. IMU sample k is the step from t_s[k] to t_s[k + 1]'s midpoint, imu_t_s[k]."""
    vehicle = Multicopter(seed, heading_rad, params, imu)
    pos, vel, acc, gyr, att = [], [], [], [], []
    for sp in np.asarray(setpoints, float):
        pos.append(vehicle.pos_ned_m.copy())
        vel.append(vehicle.vel_ned_mps.copy())
        att.append(vehicle.c_nb.copy())
        f, w = vehicle.step(sp, dt_s, yaw_rad)
        acc.append(f)
        gyr.append(w)
    t = np.arange(len(pos)) * dt_s
    return FlightRecord(t, np.array(pos), np.array(vel), np.array(acc), np.array(gyr), np.array(att), t + dt_s / 2)
