"""The receiver clock's own model: bias and drift predicted from their history (a two-state Kalman filter).

State x = [b, d]: the clock bias (ns, receiver clock ahead of GPS time) and its drift (ns/s). Measured at each fix:
b from the pseudoranges (the fix's clock_bias_m, 1 sigma the clock component of the weighted least squares
covariance, Fix.clock_sigma_ns) and d from the Doppler range rates (the fix's clock_drift_m_s).

Process noise: the oscillator's two power-law terms that dominate a TCXO over seconds to minutes (Brown & Hwang,
Introduction to Random Signals and Applied Kalman Filtering, 4th ed., sec. 9.3): white frequency noise h0 (random walk
of the bias) and random-walk frequency noise h_-2 (random walk of the drift), S_f = h0 / 2, S_g = 2 pi^2 h_-2,

    Q(T) = [[S_f T + S_g T^3 / 3, S_g T^2 / 2],
            [S_g T^2 / 2,         S_g T      ]].

Their typical TCXO values are h0 = 2e-19 s, h_-2 = 2e-20 / s (Allan deviation ~5e-10 at 1 s); the defaults are three
times those (ClockNoise: Allan deviation ~8e-10 at 1 s), conservative for a cheap front end's TCXO shaken and warmed
in flight: a larger process noise means fewer false alarms, a holdover uncertainty that grows faster (after Dt s
without measurements the bias is uncertain by sqrt(P_bb + 2 P_bd Dt + P_dd Dt^2 + S_f Dt + S_g Dt^3 / 3), 1 sigma
about 20 ns after 10 s and 630 ns after 100 s from a well-known drift: an honest TCXO holdover is short) and a slower
detection of a push that ramps its rate in gradually (ten times the typical values would let a push reaching 25 ns/s
over 5 s through unseen).

Besides the prediction from the latest update, the model keeps a snapshot of itself every second (HISTORY_S of them)
and predicts from LAGS_S ago too: a push that brings its delay rate in gradually is absorbed, fix by fix, by the
filter's drift (each fix's innovation stays small), but not by a prediction from before it began.

The model measures; what to make of an innovation it cannot explain is the defence's (defense/clock_guard.py).
"""

from dataclasses import dataclass

import numpy as np

from .chisquare import chi2_isf

LAGS_S = (1.0, 2.0, 5.0, 10.0, 20.0)   # predictions from these many seconds ago are tested too
SNAPSHOT_EVERY_S = 1.0
HISTORY_S = 25.0


@dataclass(frozen=True)
class ClockNoise:
    h0_s: float = 6e-19        # white frequency noise (3 x a typical TCXO's 2e-19)
    h_minus2_per_s: float = 6e-20   # random-walk frequency noise (3 x 2e-20)

    @property
    def s_f(self) -> float:
        """Bias random walk, ns^2 / s."""
        return self.h0_s / 2.0 * 1e18

    @property
    def s_g(self) -> float:
        """Drift random walk, (ns/s)^2 / s."""
        return 2.0 * np.pi ** 2 * self.h_minus2_per_s * 1e18

    def q(self, dt_s: float) -> np.ndarray:
        t = max(float(dt_s), 0.0)
        return np.array([[self.s_f * t + self.s_g * t ** 3 / 3.0, self.s_g * t ** 2 / 2.0],
                         [self.s_g * t ** 2 / 2.0, self.s_g * t]])

    def allan_deviation(self, tau_s: float) -> float:
        """sigma_y(tau) of the two terms (dimensionless)."""
        return float(np.sqrt(self.h0_s / (2.0 * tau_s) + 2.0 * np.pi ** 2 * self.h_minus2_per_s * tau_s / 3.0))


@dataclass(frozen=True)
class Innovation:
    """A measurement against the model's prediction at its instant."""
    t_s: float
    step_ns: float             # measured bias - predicted bias
    ramp_ns_s: float           # measured drift - predicted drift (nan without a drift measurement)
    sigma_step_ns: float       # sqrt of the innovation variance of each
    sigma_ramp_ns_s: float
    statistic: float           # nu' S^-1 nu: chi-square with dof degrees of freedom when the model holds
    dof: int
    nu: np.ndarray             # the innovation vector over the measured components
    s: np.ndarray              # its covariance
    h: np.ndarray              # the measured rows of the identity
    since_s: float = float("nan")  # the instant of the state it was predicted from

    def exceeds(self, pfa: float) -> bool:
        return self.statistic > chi2_isf(pfa, self.dof)


def transition(dt_s: float) -> np.ndarray:
    return np.array([[1.0, dt_s], [0.0, 1.0]])


class ClockModel:
    """A two-state Kalman filter on the receiver clock; predict() never changes it, update() does."""

    def __init__(self, noise: ClockNoise = ClockNoise()):
        self.noise = noise
        self.t_s: float | None = None
        self.x = np.zeros(2)
        self.p = np.zeros((2, 2))
        self.n_updates = 0
        self.shift = np.zeros((2, 2))   # K S K' of the last update: the covariance of the state shift it allowed
        # (t, x, P, shift) after an update, every second
        self.history: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []

    @property
    def started(self) -> bool:
        return self.t_s is not None

    def predict(self, t_s: float, since=None) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance at t_s, from the last update (the holdover prediction when no update follows), or
        from a snapshot (t, x, P)."""
        t0, x0, p0 = since[:3] if since is not None else (self.t_s, self.x, self.p)
        dt = t_s - t0
        f = transition(dt)
        return f @ x0, f @ p0 @ f.T + self.noise.q(dt)

    @staticmethod
    def _measured(bias_ns: float, drift_ns_s: float, sigma_bias_ns: float, sigma_drift_ns_s: float):
        ok = np.array([np.isfinite(bias_ns) and np.isfinite(sigma_bias_ns),
                       np.isfinite(drift_ns_s) and np.isfinite(sigma_drift_ns_s)])
        h = np.eye(2)[ok]
        return ok, h, np.array([bias_ns, drift_ns_s])[ok], np.diag(np.array([sigma_bias_ns, sigma_drift_ns_s])[ok] ** 2)

    def lagged_innovations(self, t_s: float, bias_ns: float, drift_ns_s: float, sigma_bias_ns: float,
                           sigma_drift_ns_s: float, lags_s=LAGS_S) -> list[Innovation]:
        """The measurement against the predictions from the snapshots about lags_s ago (those the history holds)."""
        out, used = [], set()
        for lag in lags_s:
            older = [i for i, snap in enumerate(self.history) if snap[0] <= t_s - lag]
            if older and older[-1] not in used:
                used.add(older[-1])
                inn = self.innovation(t_s, bias_ns, drift_ns_s, sigma_bias_ns, sigma_drift_ns_s,
                                      since=self.history[older[-1]])
                if inn is not None:
                    out.append(inn)
        return out

    def innovation(self, t_s: float, bias_ns: float, drift_ns_s: float, sigma_bias_ns: float,
                   sigma_drift_ns_s: float, since=None) -> Innovation | None:
        """The measurement against the prediction (None before the first update or without any measurement)."""
        ok, h, z, r = self._measured(bias_ns, drift_ns_s, sigma_bias_ns, sigma_drift_ns_s)
        if not self.started or not ok.any():
            return None
        x, p = self.predict(t_s, since)
        t_from = since[0] if since is not None else self.t_s
        nu = z - h @ x
        s = h @ p @ h.T + r
        stat = float(nu @ np.linalg.solve(s, nu))
        full_nu, full_sd = np.full(2, np.nan), np.full(2, np.nan)
        full_nu[ok], full_sd[ok] = nu, np.sqrt(np.diag(s))
        return Innovation(t_s, float(full_nu[0]), float(full_nu[1]), float(full_sd[0]), float(full_sd[1]), stat,
                          int(ok.sum()), nu, s, h, float(t_from))

    def update(self, t_s: float, bias_ns: float, drift_ns_s: float, sigma_bias_ns: float,
               sigma_drift_ns_s: float) -> np.ndarray | None:
        """Take a measurement in; returns K S K' (the state shift's covariance this update allowed), None when nothing
        was measured. The first update starts the model (an unmeasured drift starts at 0 +/- 1 ms/s)."""
        ok, h, z, r = self._measured(bias_ns, drift_ns_s, sigma_bias_ns, sigma_drift_ns_s)
        if not ok[0] and not self.started:
            return None
        if not self.started:
            self.t_s, self.n_updates = t_s, 1
            self.x = np.array([bias_ns, drift_ns_s if ok[1] else 0.0])
            self.p = np.diag([sigma_bias_ns ** 2, sigma_drift_ns_s ** 2 if ok[1] else 1e12])
            self.shift = self.p.copy()
            self._snapshot()
            return self.shift
        if not ok.any():
            return None
        x, p = self.predict(t_s)
        s = h @ p @ h.T + r
        k = p @ h.T @ np.linalg.inv(s)
        self.x = x + k @ (z - h @ x)
        i_kh = np.eye(2) - k @ h
        self.p = i_kh @ p @ i_kh.T + k @ r @ k.T      # Joseph form: stays symmetric and positive
        self.t_s = t_s
        self.n_updates += 1
        self.shift = k @ s @ k.T
        self._snapshot()
        return self.shift

    def _snapshot(self) -> None:
        if not self.history or self.t_s - self.history[-1][0] >= SNAPSHOT_EVERY_S - 1e-6:
            self.history.append((self.t_s, self.x.copy(), self.p.copy(), self.shift.copy()))
            self.history = [h for h in self.history if h[0] >= self.t_s - HISTORY_S]

    def reseed(self, t_s: float, x: np.ndarray, p: np.ndarray, shift=None) -> None:
        """Restart from a given state (a snapshot from before an alarm, the holdover prediction when the measurements
        are trusted again); the history after it is dropped."""
        self.t_s, self.x, self.p = t_s, np.array(x, float), np.array(p, float)
        self.shift = np.zeros((2, 2)) if shift is None else np.array(shift, float)
        self.history = [h for h in self.history if h[0] < t_s]
        self._snapshot()

    def snapshot_at(self, t_s: float):
        """The history's snapshot taken at t_s (None if it is gone)."""
        return next((h for h in self.history if abs(h[0] - t_s) < 1e-9), None)
