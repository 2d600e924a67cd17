"""Strapdown inertial navigation (body frame FRD, navigation frame local NED), decoupled from GPS.

During the maneuver the flight side stops fusing GPS (the paper's EKF/GPS decoupling) and integrates the IMU alone
from the state at the maneuver start.  Earth rotation and transport rate are neglected: over <= 20 s and < 50 m
they add centimetres, far below the IMU errors the identifier tolerates.

What breaks a 20 s strapdown track is not the integration but the sensor's biases: a gyro bias b tilts gravity into
the horizontal and moves the track g b t^3 / 6 (1 mrad/s: 13 m in 20 s; ArduCopter SITL's gyro drifts by that in
a few minutes), an accelerometer bias or a tilt error a moves it a t^2 / 2 (0.01 m/s^2: 2 m).  Both are measured in
a hover just before the maneuver (hover_bias): the gyro's bias is what it reads beyond the autopilot's own
bias-corrected rates, and the accelerometer's (with the start attitude's tilt error) is the specific force the
hover's attitude leaves unexplained by its change of velocity.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

GRAVITY_NED_MPS2 = np.array([0.0, 0.0, 9.80665])


@dataclass(frozen=True)
class InsTrack:
    t_s: np.ndarray
    pos_ned_m: np.ndarray     # (n, 3)
    vel_ned_mps: np.ndarray   # (n, 3)


def rotation_matrix(phi: np.ndarray) -> np.ndarray:
    """The rotation matrix of a rotation vector (Rodrigues): the strapdown's step, and the simulated airframe's."""
    a = float(np.linalg.norm(phi))
    k = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    if a < 1e-9:
        return np.eye(3) + k
    return np.eye(3) + np.sin(a) / a * k + (1 - np.cos(a)) / a ** 2 * (k @ k)


@dataclass(frozen=True)
class HoverBias:
    gyro_bias_rps: np.ndarray              # body frame: subtract from the gyro (at the track's start)
    accel_residual_ned_mps2: np.ndarray    # navigation frame: subtract from the integrated acceleration
    # how the gyro's bias changes with time from the start
    gyro_drift_rps2: np.ndarray = field(default_factory=lambda: np.zeros(3))


def bias_between(before: HoverBias, after: HoverBias, before_t_s: float, after_t_s: float,
                 start_t_s: float) -> HoverBias:
    """A drifting bias from a hover before the track and one after it (their mid-times): the gyro's bias moves in
    a straight line between them (SITL's drifts by 0.05 deg/s a minute: 0.3 mrad/s over a maneuver, 1-2 m in
    20 s); the accelerometer's, which holds the start attitude's tilt error, is the first hover's."""
    drift = (after.gyro_bias_rps - before.gyro_bias_rps) / (after_t_s - before_t_s)
    return HoverBias(before.gyro_bias_rps + drift * (start_t_s - before_t_s), before.accel_residual_ned_mps2, drift)


def hover_bias(imu_t_s, accel_body_mps2, gyro_body_rps, att_t_s, att_rpy_rad, vel_t_s, vel_ned_mps) -> HoverBias:
    """The IMU's biases from a hover (a few seconds, heading held, nearly still): the gyro's is the slope of the
    angle it integrates beyond the angle the autopilot's attitude (ATTITUDE) turned through over the same span (a
    least-squares line: the autopilot's attitude is noisy sample to sample); the accelerometer's, with the
    autopilot's tilt error, is the mean of C f + g beyond the mean acceleration of the hover's velocity change (the
    autopilot's velocities, vel_ned_mps at vel_t_s, taken at the first and last IMU samples' times)."""
    from .telemetry import c_nb
    t, f, w = np.asarray(imu_t_s, float), np.asarray(accel_body_mps2, float), np.asarray(gyro_body_rps, float)
    ta, rpy = np.asarray(att_t_s, float), np.asarray(att_rpy_rad, float)
    if len(t) < 10 or len(ta) < 10:
        raise ValueError("a hover needs at least 10 IMU and 10 attitude samples")
    c = np.array([c_nb(*a) for a in rpy])
    turned = np.array([_rotation_vector(c[0].T @ ck) for ck in c])            # body frame, from the first
    turned_at = np.column_stack([np.interp(t, ta, turned[:, k]) for k in range(3)])
    gyro_angle = np.vstack([np.zeros(3), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t)[:, None], axis=0)])
    inside = (t >= ta[0]) & (t <= ta[-1])
    gyro_bias = np.polyfit(t[inside] - t[0], (gyro_angle - turned_at)[inside], 1)[0]
    at = np.clip(np.searchsorted(ta, t, side="right") - 1, 0, len(ta) - 1)   # the attitude last reported
    unexplained = np.einsum("nij,nj->ni", c[at], f) + GRAVITY_NED_MPS2
    tv, v = np.asarray(vel_t_s, float), np.asarray(vel_ned_mps, float)
    dv = np.array([np.interp(t[-1], tv, v[:, k]) - np.interp(t[0], tv, v[:, k]) for k in range(3)])
    accel = unexplained.mean(axis=0) - dv / (t[-1] - t[0])
    # a noisy accelerometer's mean over a short hover is mostly its noise: taken off only where it stands out of
    # that noise (three standard errors), else the correction adds more error than it removes. The noise is what
    # changes sample to sample: the hover's own slow swaying is no noise (its velocity change accounts for it)
    noise = np.diff(unexplained, axis=0).std(axis=0) / np.sqrt(2 * len(t))
    return HoverBias(gyro_bias, np.where(np.abs(accel) > 3 * noise, accel, 0.0))


def _rotation_vector(c: np.ndarray) -> np.ndarray:
    angle = np.arccos(np.clip((np.trace(c) - 1.0) / 2.0, -1.0, 1.0))
    axis = np.array([c[2, 1] - c[1, 2], c[0, 2] - c[2, 0], c[1, 0] - c[0, 1]]) / 2.0
    return axis if angle < 1e-9 else axis * (angle / np.sin(angle))


# what the hovers leave of each error, at worst (ArduCopter SITL: 13 maneuvers of 13-20 s, at most 0.63 of the
# bound anywhere along their tracks; scripts/sitl-fly prints them)
START_VELOCITY_ERROR_MPS = 0.05        # the autopilot's velocity at the start (GPS-aided until then)
ACCEL_RESIDUAL_MPS2 = 0.005            # accelerometer bias and start tilt left after the hover's correction
GYRO_RESIDUAL_RPS = 1.5e-4             # gyro bias left after the two hovers' line (SITL's drifts 0.015 mrad/s^2)
FLOOR_M = 0.3                          # sample timing: 20 ms at 4 m/s, and the truth's own tagging
# A flight side that did not watch the GPS-aided flight before the GPS was lost (mavlink_pilot: its calibration is
# then a hover without GPS) starts from the autopilot's dead-reckoned velocity and measures the gyro against an
# attitude that drifts: ArduCopter SITL, GPS switched off, 15-21 s tracks ended 1.8-26.8 m off (11 maneuvers; a
# start velocity 0.09-0.37 m/s off, gyro biases 0.1-2 mrad/s off); this bound held all of them (26.8 m after 20.8 s
# against 28.1). Watched, its INS starts on the GPS-aided flight and the bound above holds, counted from there.
NO_GPS_START_VELOCITY_ERROR_MPS = 0.6
NO_GPS_ACCEL_RESIDUAL_MPS2 = 0.03
NO_GPS_GYRO_RESIDUAL_RPS = 6e-4

# A drift measured before the track and carried on through it (the GPS-aided windows before the GPS was lost) may
# turn meanwhile: ArduCopter SITL's gyro drifts in a triangle wave (+-0.025 mrad/s^2), and a track flown over its turn
# ended 4.95 m off after 18 s (its INS 23 s old) against 2 m elsewhere
DRIFT_CHANGE_RPS2 = 2e-5


def ins_error_bound_m(t_s, without_gps: bool = False, drift_carried: bool = False):
    """How far a hover-calibrated strapdown track may be from the truth t_s after its start: a start velocity error
    (t), the accelerometer's residual (t^2 / 2) and the gyro's, tilting gravity (g t^3 / 6): 2.4 m after 15 s, 4.3 m
    after 20 s (without_gps: the autopilot had no GPS at the start, 17 and 27 m; drift_carried: the gyro's drift
    measured before the INS started and carried on, g dd t^4 / 24 more for a drift that changes by dd). The flight
    side sends it with its track; the identifier's range tolerance grows with it (never under its own INS_DRIFT_M,
    2 m)."""
    t = np.asarray(t_s, float)
    v, a, w = ((NO_GPS_START_VELOCITY_ERROR_MPS, NO_GPS_ACCEL_RESIDUAL_MPS2, NO_GPS_GYRO_RESIDUAL_RPS) if without_gps
               else (START_VELOCITY_ERROR_MPS, ACCEL_RESIDUAL_MPS2, GYRO_RESIDUAL_RPS))
    turn = DRIFT_CHANGE_RPS2 if drift_carried else 0.0
    return FLOOR_M + v * t + a * t ** 2 / 2 + GRAVITY_NED_MPS2[2] * (w * t ** 3 / 6 + turn * t ** 4 / 24)


def track_error_bound_m(length_s: float, age_s: float = 0.0, without_gps: bool = False,
                        drift_carried: bool = False) -> float:
    """How far a track length_s long may be off the truth at its end, relative to its own start, from an INS that had
    run age_s when it began: what the INS erred before is not in the track, but the velocity error it grew then is
    (ins_error_bound_m's growth over the track). An INS 40 s old states 84 m over 15 s, against 2.4 m fresh."""
    grown = ins_error_bound_m(age_s + length_s, without_gps, drift_carried)
    return float(grown - (ins_error_bound_m(age_s, without_gps, drift_carried) - FLOOR_M))


class Strapdown:
    """The strapdown integration one IMU sample at a time, from the attitude c_nb0 and velocity vel0_ned_mps at t0_s
    (bias: hover_bias, taken off each sample): what the flight side steers by when the autopilot has no position,
    and what integrate() runs over a whole track."""

    def __init__(self, t0_s: float, accel_body_mps2, gyro_body_rps, c_nb0=None, vel0_ned_mps=None,
                 bias: HoverBias | None = None):
        self.t0_s = self.t_s = float(t0_s)
        self.bias = bias
        self.residual = np.zeros(3) if bias is None else bias.accel_residual_ned_mps2
        self.c_nb = np.eye(3) if c_nb0 is None else np.array(c_nb0, float)
        self.vel_ned_mps = np.zeros(3) if vel0_ned_mps is None else np.array(vel0_ned_mps, float)
        self.pos_ned_m = np.zeros(3)
        self._f, self._w = self._corrected(self.t_s, accel_body_mps2, gyro_body_rps)

    def _corrected(self, t_s: float, accel_body_mps2, gyro_body_rps) -> tuple[np.ndarray, np.ndarray]:
        f, w = np.asarray(accel_body_mps2, float), np.asarray(gyro_body_rps, float)
        if f.shape != (3,) or w.shape != (3,) or not np.all(np.isfinite(f)) or not np.all(np.isfinite(w)):
            raise ValueError("IMU samples: accel and gyro must be 3 finite values")
        if self.bias is not None:
            w = w - self.bias.gyro_bias_rps - (t_s - self.t0_s) * self.bias.gyro_drift_rps2
        return f, w

    def step(self, t_s: float, accel_body_mps2, gyro_body_rps) -> None:
        """Take the next sample (t_s after the last one)."""
        dt = float(t_s) - self.t_s
        if not dt > 0:
            raise ValueError("IMU samples: time must increase")
        f, w = self._corrected(t_s, accel_body_mps2, gyro_body_rps)
        c = self.c_nb
        # trapezoid on rates and specific force: second-order accurate attitude and velocity
        c_next = c @ rotation_matrix(0.5 * (self._w + w) * dt)
        a0 = c @ self._f + GRAVITY_NED_MPS2 - self.residual
        a1 = c_next @ f + GRAVITY_NED_MPS2 - self.residual
        v_next = self.vel_ned_mps + 0.5 * (a0 + a1) * dt
        self.pos_ned_m = self.pos_ned_m + 0.5 * (self.vel_ned_mps + v_next) * dt
        self.vel_ned_mps, self.c_nb, self.t_s, self._f, self._w = v_next, c_next, float(t_s), f, w


def integrate(t_s, accel_body_mps2, gyro_body_rps, c_nb0=None, vel0_ned_mps=None, bias: HoverBias | None = None
              ) -> InsTrack:
    """Integrate specific force (m/s^2) and angular rate (rad/s), both in the body frame, sampled at t_s, from the
    attitude c_nb0 and velocity vel0_ned_mps at t_s[0]; bias (hover_bias) is taken off the samples."""
    t = np.asarray(t_s, float)
    f = np.asarray(accel_body_mps2, float)
    w = np.asarray(gyro_body_rps, float)
    if f.shape != (len(t), 3) or w.shape != (len(t), 3) or len(t) < 2:
        raise ValueError("accel and gyro must be (n, 3) with n = len(t_s) >= 2")
    ins = Strapdown(t[0], f[0], w[0], c_nb0, vel0_ned_mps, bias)
    pos, vel = [ins.pos_ned_m], [ins.vel_ned_mps]
    for i in range(1, len(t)):
        ins.step(t[i], f[i], w[i])
        pos.append(ins.pos_ned_m)
        vel.append(ins.vel_ned_mps)
    return InsTrack(t, np.array(pos), np.array(vel))


def write_track_csv(path, t_s, pos_ned_m) -> Path:
    """The IMU track in `semperfi run --imu` format: t_s,north_m,east_m,down_m."""
    np.savetxt(path, np.column_stack([t_s, pos_ned_m]), fmt="%.3f", delimiter=",",
               header="t_s,north_m,east_m,down_m", comments="")
    return Path(path)
