"""Receiver motion: static, a 10 Hz trajectory file as gps-sdr-sim reads them, or live from a vehicle model."""

from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from ..gps import geodetic_to_ecef

MAX_TRAJECTORY_ROWS = 10_000_000


class StaticMotion:
    def __init__(self, pos_ecef_m):
        self.pos = np.asarray(pos_ecef_m, dtype=np.float64)

    def state(self, t_s):
        """Position and velocity (ECEF) at times t_s since the first sample; arrays of shape (n, 3)."""
        n = np.size(t_s)
        return np.broadcast_to(self.pos, (n, 3)).copy(), np.zeros((n, 3))


class TrajectoryMotion:
    """A sampled trajectory, interpolated by cubic splines (continuous velocity, so Doppler has no steps)."""

    def __init__(self, t_s, pos_ecef_m):
        t_s = np.asarray(t_s, dtype=np.float64)
        if t_s.size < 2 or np.any(np.diff(t_s) <= 0):
            raise ValueError("a trajectory needs at least two rows with increasing time")
        self._spline = CubicSpline(t_s, np.asarray(pos_ecef_m, dtype=np.float64), axis=0)
        self._velocity = self._spline.derivative()
        self.t_end_s = float(t_s[-1])

    def state(self, t_s):
        t = np.clip(np.atleast_1d(np.asarray(t_s, dtype=np.float64)), None, self.t_end_s)
        return self._spline(t), self._velocity(t)

    @classmethod
    def from_csv(cls, path: str | Path, lla: bool = False) -> "TrajectoryMotion":
        """Rows 't_s,x_m,y_m,z_m' (ECEF) or, with lla, 't_s,lat_deg,lon_deg,height_m'."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"trajectory file not found: {path}")
        try:
            rows = np.loadtxt(path, delimiter=",", ndmin=2, comments="#", max_rows=MAX_TRAJECTORY_ROWS)
        except ValueError as exc:
            raise ValueError(f"{path}: not a numeric CSV trajectory ({str(exc)[:80]})") from None
        if rows.shape[1] < 4 or not np.all(np.isfinite(rows[:, :4])):
            raise ValueError(f"{path}: a trajectory row is t_s and three coordinates")
        t, xyz = rows[:, 0] - rows[0, 0], rows[:, 1:4]
        if lla:
            xyz = geodetic_to_ecef(np.radians(xyz[:, 0]), np.radians(xyz[:, 1]), xyz[:, 2])
        radius = np.linalg.norm(xyz, axis=1)
        if np.any(radius < 6.0e6) or np.any(radius > 7.5e6):
            raise ValueError(f"{path}: positions are not near the Earth's surface (ECEF metres"
                             f"{'' if lla else ', or pass trajectory_lla for lat,lon,height'})")
        return cls(t, xyz)


class LiveMotion:
    """Driven chunk by chunk by a vehicle model: the latest state, extrapolated with constant acceleration."""

    def __init__(self, pos_ecef_m, vel_ecef_m_s=(0.0, 0.0, 0.0)):
        self.set_state(0.0, pos_ecef_m, vel_ecef_m_s)

    def set_state(self, t_s: float, pos_ecef_m, vel_ecef_m_s, acc_ecef_m_s2=(0.0, 0.0, 0.0)) -> None:
        self._t0 = float(t_s)
        self._p, self._v, self._a = (np.asarray(x, dtype=np.float64) for x in (pos_ecef_m, vel_ecef_m_s, acc_ecef_m_s2))

    def state(self, t_s):
        dt = (np.atleast_1d(np.asarray(t_s, dtype=np.float64)) - self._t0)[:, None]
        return self._p + self._v * dt + 0.5 * self._a * dt ** 2, self._v + self._a * dt
