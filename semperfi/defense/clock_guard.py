"""Time integrity: a receiver clock that moves as no oscillator does is a time push, and the time is then distrusted.

A delay common to every range -- a spoofer aligned with the sky, then delaying every signal alike (TEXBAT's time
push) -- leaves the position where it was and walks the receiver clock bias: RAIM sees nothing (the delay goes whole
into the clock, no residual is left) and neither does a position check. What sees it is the clock's own history
(receiver/clock.py, a two-state Kalman filter with a TCXO's process noise): every fix whose ranges pass RAIM is a
measurement of bias (pseudoranges) and drift (Doppler), tested against the model's latest prediction and against
its predictions from 1, 2, 5, 10 and 20 s ago (receiver/clock.LAGS_S: a push that brings its rate in gradually is
taken in by the filter fix by fix, not by a prediction from before it began),

    T = nu' S^-1 nu > chi2.ppf(1 - pfa / 6, dof),   dof = 2 (bias and drift) or 1 (bias alone),

pfa = 1e-7 per fix shared by the six predictions (10 fixes a second: one false alarm in some 300 hours if the
innovations were white and Gaussian). The bias's measurement sigma is the fix's clock sigma (the weighted least squares
covariance with RAIM's sigma model, its floors included: some 7 ns where the epoch-to-epoch noise is 1-3 ns) with a
2 ns floor; the drift's, 3 ns/s, three times what the simulator's clean static and flying (3.75 m/s^2) scenes show.
On the clean static scene the latest prediction's statistic stays under 1 against a threshold of 36. Measured on
synthetic fixes of those sizes (tests/test_clock.py): a 100 ns step alarms at the first fix; a 25 ns/s ramp at the
first fix the Doppler sees it (derived bound with probability 0.99: 3.5 s), from the bias alone in 2 s (derived:
8.7 s); a push whose rate grows to 25 ns/s over 5 s in 4-5 s, at some 50 ns. What is seen goes into a `clock_alarm`
event (step ns, ramp ns/s, their sigmas, how old the prediction was) through the spoof guard
(SpoofGuard.clock_alarm).

Time protection level (Fix.tpl_ns) of a fix whose time is checked (time_state nominal):

    TPL = TPL_raim + pbias(dof) sqrt(S_bb) + pbias(2) sqrt(g' A g) + floor

-- RAIM's clock slope (one faulty range), the largest common-mode offset the clock test misses with probability pmd
(the same non-centrality as RAIM's pbias, on the innovation's sigma), the largest shift the previous accepted update
may have let into the model (A = K S K' of that update, g = [1, time since]), and what resynchronisations accepted
(below). What it does not cover: a push slower than the oscillator's own wander (a drift change the process noise
calls plausible, absorbed update by update). No receiver without an outside time reference can tell that one from
its TCXO; the defaults put that floor near a TCXO's (Allan deviation ~8e-10 at 1 s).

After a clock alarm the time is held on the model's prediction (time_state holdover), from the model as it was when
the oldest prediction that disagrees was made (the updates since may carry part of the push): gps_tow_s, clock_bias_m
and clock_drift_m_s are the prediction's, TPL = k_md sigma_pred(t) + pbias(2) sqrt(g' A g) + floor, growing as the
TCXO's random walk says. Fixes whose ranges RAIM cannot vouch for get the same holdover time (their clock is no
measurement). The time is taken back from the ranges (resynchronised) only when the defence has recovered (the fix's
position state is `recovered`: every PRN in it resolved) and the measurements agree with the prediction for resync_s;
what that acceptance may carry, pbias(dof) sqrt(S_bb) at that instant, stays in the floor from then on.

Why a separate time_state, not the position's state, and not a spoofing alarm on the guard's alarm_t_s: a common delay
does not move the position -- the ranges still give it, and RAIM still checks it -- so the position keeps its state
(nominal, recovered ...) and its availability. Raising the guard's attack alarm would leave every PRN unresolved and
out of the fixes until cancelled and verified, dropping good positions for a time-only fault. The clock alarm still
goes through the guard: it is the evidence of a seamless takeover (SpoofGuard.takeover) and sets its examinations to
their highest sensitivity, to find the spoofer's peaks parting from their twins. A consumer that needs time reads
time_state and tpl_ns; one that needs position reads state, hpl_m and vpl_m.
"""

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import special

from ..gps import SECONDS_PER_WEEK, SPEED_OF_LIGHT_M_S
from ..receiver import ClockModel, ClockNoise, Fix, Innovation, LAGS_S, chi2_isf, pbias, trusted

NS_PER_M = 1e9 / SPEED_OF_LIGHT_M_S


@dataclass(frozen=True)
class ClockGuardConfig:
    pfa: float = 1e-7                # false alarm per fix of the innovation test
    pmd: float = 1e-3                # missed detection for the protection levels (as integrity.pmd)
    drift_sigma_ns_s: float = 3.0    # 1 sigma of the Doppler-measured drift (clean scenes: ~1 ns/s)
    bias_floor_ns: float = 2.0       # added (root sum square) to the fix's clock sigma
    warmup_s: float = 5.0            # the model's first seconds: its time unverified
    resync_s: float = 5.0            # recovered fixes agreeing with the holdover this long take the time back
    noise: ClockNoise = field(default_factory=ClockNoise)


class ClockGuard:
    def __init__(self, guard, config: ClockGuardConfig = ClockGuardConfig()):
        """guard: the SpoofGuard (its mode, its events, its clock_alarm)."""
        self.guard, self.cfg = guard, config
        self.model = ClockModel(config.noise)
        self.started_s: float | None = None
        self.alarm_t_s: float | None = None      # the time is held since then (None: not held after an alarm)
        self.floor_ns = 0.0
        self.tainted_ns = 0.0    # the most that ranges the model took in may have been off together (unvouched_ns)
        self._absorbed = (None, np.zeros((2, 2)))   # (t, K S K') of the last accepted update
        self._agreeing_since: float | None = None
        self._k_md = float(-special.ndtri(config.pmd / 2.0))
        # each fix is tested against the latest prediction and those from LAGS_S ago: pfa shared among them
        self.pfa_test = config.pfa / (1 + len(LAGS_S))
        self.n_alarms = 0

    # -- the per-fix hook ----------------------------------------------------------------------------------
    def check(self, fix: Fix, unvouched_ns: float = 0.0) -> Fix:
        """The fix with its time_state and tpl_ns (and its time held on the model's prediction in holdover).
        unvouched_ns: how far the fix's ranges may all be off together, beyond their noise, by what the defence has
        not resolved -- 0 when its position is good, the merged separation when its unresolved PRNs are merged with
        their twins (a time push's aligned start), inf when they may be the attacker's (then no measurement)."""
        if self.guard.d["mode"] == "off":
            return fix
        c = self.cfg
        t = fix.t_rx_s
        z = (fix.clock_bias_m * NS_PER_M, fix.clock_drift_m_s * NS_PER_M,
             float(np.hypot(fix.clock_sigma_ns, c.bias_floor_ns)), c.drift_sigma_ns_s)
        measured = trusted(fix.raim) and np.isfinite(unvouched_ns) and all(np.isfinite(z[i]) for i in (0, 2))
        if not self.model.started:
            if measured:
                self._accept(t, z, unvouched_ns)
                self.started_s = t
            return replace(fix, time_state="unverified")
        warm = t - self.started_s >= c.warmup_s
        if not measured:
            return self._held(fix) if warm else replace(fix, time_state="unverified")
        inn = self.model.innovation(t, *z)
        if self.alarm_t_s is None:
            tests = [inn] + self.model.lagged_innovations(t, *z)
            alarmed = [i for i in tests if i.exceeds(self.pfa_test)]
            if alarmed:
                self._raise(fix, max(alarmed, key=lambda i: i.statistic / chi2_isf(self.pfa_test, i.dof)))
                # held on the model as it was before what it cannot explain: the oldest prediction that disagrees
                # (the updates since may have taken part of a push in, fix by fix)
                ref = self.model.snapshot_at(min(i.since_s for i in alarmed))
                if ref is not None:
                    self.model.reseed(*ref)
                    self._absorbed = (ref[0], ref[3])
                return self._held(fix)
            carried = self._carried_ns(t)
            self._accept(t, z, unvouched_ns)
            if not warm:
                return replace(fix, time_state="unverified")
            return replace(fix, time_state="nominal", tpl_ns=self._tpl(fix, inn, carried))
        # held since an alarm: the ranges take the time back only once the defence has recovered and they agree
        if fix.state == "recovered" and not inn.exceeds(self.pfa_test):
            if self._agreeing_since is None:
                self._agreeing_since = t
            if t - self._agreeing_since >= c.resync_s:
                return self._resync(fix, inn, z)
        else:
            self._agreeing_since = None
        return self._held(fix)

    # -- what it does --------------------------------------------------------------------------------------
    def _accept(self, t: float, z, unvouched_ns: float = 0.0) -> None:
        self.tainted_ns = max(self.tainted_ns, unvouched_ns)
        absorbed = self.model.update(t, *z)
        if absorbed is not None:
            self._absorbed = (t, absorbed)

    def _carried_ns(self, t: float) -> float:
        """The largest bias shift the last accepted update may have let in (undetected), carried to t."""
        t_a, a = self._absorbed
        if t_a is None:
            return 0.0
        g = np.array([1.0, t - t_a])
        return float(pbias(2, self.pfa_test, self.cfg.pmd) * np.sqrt(max(g @ a @ g, 0.0)))

    def _tpl(self, fix: Fix, inn: Innovation, carried_ns: float) -> float:
        raim = fix.tpl_ns if np.isfinite(fix.tpl_ns) else 0.0   # a fix without redundancy: the clock test alone
        return float(raim + pbias(inn.dof, self.pfa_test, self.cfg.pmd) * inn.sigma_step_ns + carried_ns
                     + self.floor_ns + self.tainted_ns)

    def _held(self, fix: Fix) -> Fix:
        """The fix timed by the model's prediction; its position (from the ranges) untouched. A model that took in
        merged ranges holds no time to vouch for: a push under way before it began is in its drift."""
        if self.tainted_ns > 0:
            return replace(fix, time_state="unverified")
        x, p = self.model.predict(fix.t_rx_s)
        tpl = self._k_md * float(np.sqrt(p[0, 0])) + self._carried_ns(fix.t_rx_s) + self.floor_ns
        week, tow = divmod(fix.gps_tow_s + (fix.clock_bias_m * NS_PER_M - x[0]) * 1e-9, SECONDS_PER_WEEK)
        return replace(fix, gps_week=fix.gps_week + int(week), gps_tow_s=float(tow),
                       clock_bias_m=float(x[0] / NS_PER_M), clock_drift_m_s=float(x[1] / NS_PER_M),
                       time_state="holdover", tpl_ns=float(tpl))

    def _raise(self, fix: Fix, inn: Innovation) -> None:
        self.alarm_t_s = fix.t_rx_s
        self._agreeing_since = None
        self.n_alarms += 1
        self.guard.clock_alarm(fix.t_rx_s, {
            "step_ns": round(inn.step_ns, 2), "sigma_step_ns": round(inn.sigma_step_ns, 2),
            "ramp_ns_s": None if not np.isfinite(inn.ramp_ns_s) else round(inn.ramp_ns_s, 3),
            "sigma_ramp_ns_s": None if not np.isfinite(inn.sigma_ramp_ns_s) else round(inn.sigma_ramp_ns_s, 3),
            "statistic": round(inn.statistic, 1), "threshold": round(float(chi2_isf(self.pfa_test, inn.dof)), 1),
            "dof": inn.dof, "predicted_from_s": round(inn.t_s - inn.since_s, 2), "position_state": fix.state,
            "prns": list(fix.prns)})

    def _resync(self, fix: Fix, inn: Innovation, z) -> Fix:
        """The ranges take the time back: the model goes on from its prediction, and what this acceptance may carry
        stays in the floor of every later TPL."""
        accepted = pbias(inn.dof, self.pfa_test, self.cfg.pmd) * inn.sigma_step_ns
        self.floor_ns += accepted
        self.tainted_ns = 0.0   # the clean ranges agree with the model: what is left of it is in the floor
        x, p = self.model.predict(fix.t_rx_s)
        self.model.reseed(fix.t_rx_s, x, p)
        self._accept(fix.t_rx_s, z)
        held_s = fix.t_rx_s - self.alarm_t_s
        self.alarm_t_s, self._agreeing_since = None, None
        if self.guard.events is not None:
            self.guard.events.emit("clock_resync", fix.t_rx_s, held_s=round(held_s, 2),
                                   step_ns=round(inn.step_ns, 2), floor_ns=round(self.floor_ns, 2))
        return replace(fix, time_state="nominal",
                       tpl_ns=float((fix.tpl_ns if np.isfinite(fix.tpl_ns) else 0.0) + self.floor_ns))
