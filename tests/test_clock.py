"""Time integrity: the receiver clock model (receiver/clock.py), the defence's clock guard (defense/clock_guard.py),
and the time protection level on the simulator's clean, flying and time-pushed scenes.

The unit tests feed the guard synthetic fixes: a linear clock (bias + drift) measured with white noise of the sizes
the simulator's clean scenes show (bias 1.3 ns, Doppler drift 1 ns/s at 10 Hz), the guard's model told the fix's clock
sigma (6.7 ns, what the weighted least squares covariance gives there) and its drift sigma (3 ns/s). Latencies are
derived from the model's own variances: an offset is detected with probability 1 - pmd once its non-centrality
against a prediction reaches pbias^2 (the same quantity RAIM's protection levels use)."""

import csv

import numpy as np
import pytest

from semperfi.defense.clock_guard import NS_PER_M, ClockGuard, ClockGuardConfig
from semperfi.receiver.clock import LAGS_S, ClockModel, ClockNoise
from semperfi.receiver.integrity import pbias
from semperfi.receiver.types import TIME_TRUSTED, TRUSTED_STATES, Fix

RATE_HZ = 10.0
T0_TOW = 518427.0
BIAS0_NS, DRIFT_NS_S = 250_000.0, 300.0
NOISE_B_NS, NOISE_D_NS_S = 1.3, 1.0
SIGMA_B_NS = 6.7
PMD_LATENCY = 0.01


class StubGuard:
    d = {"mode": "full"}
    events = None

    def __init__(self):
        self.alarms = []

    def clock_alarm(self, t_s, event):
        self.alarms.append((t_s, event))


def _fix(t, bias_ns, drift_ns_s, state="nominal", raim="pass"):
    return Fix(t_rx_s=t, gps_week=2190, gps_tow_s=T0_TOW + t - bias_ns * 1e-9, pos_ecef_m=np.zeros(3),
               vel_ecef_m_s=np.zeros(3), clock_bias_m=bias_ns / NS_PER_M, clock_drift_m_s=drift_ns_s / NS_PER_M,
               lat_deg=42.0, lon_deg=-71.0, height_m=10.0, n_sats=8, prns=tuple(range(1, 9)), pdop=1.5, hdop=0.8,
               vdop=1.2, residual_rms_m=1.0, state=state, raim=raim, tpl_ns=42.0, clock_sigma_ns=SIGMA_B_NS)


def _run(seconds, push_ns=lambda t: 0.0, push_rate=lambda t: 0.0, seed=0, drift_measured=True,
         state=lambda t: "nominal", random_walk=False, unvouched_ns=0.0):
    """(guard, [(the fix out of the guard, its time error against the true clock in ns)])."""
    rng = np.random.default_rng(seed)
    guard = ClockGuard(StubGuard())
    out = []
    drift, bias = DRIFT_NS_S, BIAS0_NS
    dt = 1.0 / RATE_HZ
    noise = ClockNoise()
    for k in range(int(seconds * RATE_HZ)):
        t = 10.0 + k * dt
        if random_walk and k:   # the clock the model assumes, at the typical TCXO's third of its noise
            q = noise.q(dt) / 3.0
            w = rng.multivariate_normal(np.zeros(2), q)
            bias, drift = bias + drift * dt + w[0], drift + w[1]
        elif k:
            bias += drift * dt
        meas_b = bias + push_ns(t) + rng.normal(0, NOISE_B_NS)
        meas_d = drift + push_rate(t) + rng.normal(0, NOISE_D_NS_S) if drift_measured else float("nan")
        f = guard.check(_fix(t, meas_b, meas_d, state(t)), unvouched_ns)
        true_tow = T0_TOW + t - bias * 1e-9
        out.append((f, (f.gps_tow_s - true_tow) * 1e9))
    return guard, out


def _cfg_numbers():
    c = ClockGuardConfig()
    pfa_test = c.pfa / (1 + len(LAGS_S))
    return c, pfa_test


def test_the_process_noise_is_a_tcxos():
    n = ClockNoise()
    assert 1e-10 <= n.allan_deviation(1.0) <= 1e-9, n.allan_deviation(1.0)
    assert n.allan_deviation(10.0) > n.allan_deviation(1.0) * 0.5   # random walk FM takes over past a few seconds
    m = ClockModel(n)
    m.update(0.0, 0.0, 0.0, 1.0, 0.01)
    held = [np.sqrt(m.predict(dt)[1][0, 0]) for dt in (1.0, 10.0, 100.0)]
    assert held[0] < 2.0 and 10.0 < held[1] < 40.0 and 300.0 < held[2] < 1500.0, held


@pytest.mark.parametrize("seed", range(4))
def test_a_clean_drifting_clock_never_alarms_and_its_tpl_bounds_the_time(seed):
    guard, out = _run(300.0, seed=seed, random_walk=True)
    assert not guard.guard.alarms, guard.guard.alarms[:2]
    states = [f.time_state for f, _ in out]
    warm = int(ClockGuardConfig().warmup_s * RATE_HZ) + 1
    assert states[:warm - 1] == ["unverified"] * (warm - 1) and set(states[warm:]) == {"nominal"}
    err = np.array([abs(e) for f, e in out[warm:]])
    tpl = np.array([f.tpl_ns for f, _ in out[warm:]])
    assert np.all(err <= tpl), f"error {err.max():.1f} ns over TPL {tpl[np.argmax(err - tpl)]:.1f}"
    assert np.all(tpl < 150.0), tpl.max()


def test_a_100_ns_step_alarms_at_the_first_fix():
    c, pfa_test = _cfg_numbers()
    # derived: the step against the latest prediction, sigma = sqrt(R + P_bb) >= the fix's clock sigma
    sigma = np.hypot(SIGMA_B_NS, c.bias_floor_ns) * 1.1
    assert (100.0 / sigma) ** 2 > pbias(2, pfa_test, c.pmd) ** 2   # detected with probability >= 1 - pmd
    onset = 40.0
    guard, out = _run(60.0, push_ns=lambda t: 100.0 if t >= onset - 1e-9 else 0.0, seed=7)
    (t_alarm, event), = guard.guard.alarms
    assert abs(t_alarm - onset) < 1e-6, t_alarm
    assert 80.0 < event["step_ns"] < 120.0 and event["sigma_step_ns"] < 10.0, event
    after = [(f, e) for f, e in out if f.t_rx_s >= onset - 1e-9]
    assert all(f.time_state == "holdover" for f, _ in after)
    assert all(abs(e) <= f.tpl_ns for f, e in out if f.time_state in TIME_TRUSTED), "a held time beyond its TPL"


def _latency_s(rate_ns_s: float, drift_measured: bool) -> float:
    """The first time after a ramp's onset at which a prediction from before it -- the latest update for the first fix,
    else a snapshot LAGS_S old (one second apart, so at least tau + 1 s old) -- sees the ramp's offset (and its rate,
    when the Doppler measures it) at the non-centrality pbias(pmd=PMD_LATENCY)^2: that fix alarms with probability
    >= 1 - PMD_LATENCY (and the later ones more). Only predictions from before the onset are counted: the filter's
    latest, which takes part of the ramp in, alarms earlier in practice, but its share is not derived here."""
    c, pfa_test = _cfg_numbers()
    guard, _ = _run(60.0, seed=11, drift_measured=drift_measured)
    m = guard.model
    dof = 2 if drift_measured else 1
    lam = pbias(dof, pfa_test, PMD_LATENCY) ** 2
    r = np.diag([np.hypot(SIGMA_B_NS, c.bias_floor_ns) ** 2, c.drift_sigma_ns_s ** 2])[:dof, :dof]
    for tau in np.arange(0.0, 30.0, 1.0 / RATE_HZ):
        ages = [1.0 / RATE_HZ] if tau == 0 else [lag for lag in LAGS_S if lag >= tau + 1.0]
        for age in ages:
            _, p = m.predict(m.t_s + age)              # the steady state's P carried that far
            nu = np.array([rate_ns_s * tau, rate_ns_s])[:dof]
            if nu @ np.linalg.solve(p[:dof, :dof] + r, nu) >= lam:
                return float(tau)
    return float("inf")


@pytest.mark.parametrize("drift_measured", [True, False], ids=["doppler", "bias-only"])
def test_a_25_ns_s_ramp_alarms_within_the_derived_latency(drift_measured):
    n_s = _latency_s(25.0, drift_measured)
    assert n_s <= (4.0 if drift_measured else 10.0), n_s
    onset = 40.0
    for seed in range(3):
        guard, out = _run(70.0, push_ns=lambda t: 25.0 * max(0.0, t - onset),
                          push_rate=lambda t: 25.0 if t >= onset - 1e-9 else 0.0, seed=seed,
                          drift_measured=drift_measured)
        assert guard.guard.alarms, "no alarm"
        t_alarm, event = guard.guard.alarms[0]
        latency = t_alarm - onset
        print(f"{'doppler' if drift_measured else 'bias only'}: alarm {latency:.1f} s after the onset (derived "
              f"{n_s:.1f} s): {event}")
        assert -1e-6 <= latency <= n_s + 1e-6, f"alarm {latency:.1f} s after the onset, derived {n_s:.1f} s"
        bad = [(round(f.t_rx_s, 1), round(e), round(f.tpl_ns)) for f, e in out
               if f.time_state in TIME_TRUSTED and abs(e) > f.tpl_ns]
        assert not bad, bad[:5]


def test_a_push_that_ramps_its_rate_in_is_held_on_the_clock_before_it():
    """The TEXBAT-like push: the rate grows to 25 ns/s over 5 s. Each fix's innovation stays small (the filter's drift
    follows), the predictions from before the onset do not: alarmed, and held on the snapshot that disagrees."""
    onset, ramp = 40.0, 5.0

    def push(t):
        tau = max(0.0, t - onset)
        return 25.0 * (tau * tau / (2 * ramp) if tau < ramp else tau - ramp / 2)

    guard, out = _run(80.0, push_ns=push, push_rate=lambda t: 25.0 * min(max(0.0, t - onset) / ramp, 1.0), seed=5)
    t_alarm = guard.guard.alarms[0][0]
    assert onset < t_alarm < onset + 6.0, t_alarm
    bad = [(round(f.t_rx_s, 1), round(e), round(f.tpl_ns)) for f, e in out
           if f.time_state in TIME_TRUSTED and abs(e) > f.tpl_ns]
    assert not bad, f"time beyond its TPL (t, error ns, TPL ns): {bad[:5]}"
    held = [abs(e) for f, e in out if f.time_state == "holdover"]
    assert held and max(held) < 20.0, max(held)


def test_recovered_fixes_agreeing_with_the_holdover_take_the_time_back():
    onset, back = 40.0, 50.0
    guard, out = _run(80.0, push_ns=lambda t: 100.0 if onset <= t < back else 0.0,
                      state=lambda t: "recovered" if t >= back else "spoofing_detected", seed=2)
    assert len(guard.guard.alarms) == 1
    states = {round(f.t_rx_s, 1): f.time_state for f, _ in out}
    assert states[45.0] == "holdover" and states[back + 3.0] == "holdover"
    assert states[back + ClockGuardConfig().resync_s + 1.0] == "nominal"
    assert guard.floor_ns > 0
    assert all(abs(e) <= f.tpl_ns for f, e in out if f.time_state in TIME_TRUSTED)


def test_the_guard_never_touches_the_position_and_stands_aside_when_the_defence_is_off():
    guard, out = _run(30.0, push_ns=lambda t: 500.0 if t > 25.0 else 0.0, seed=1)
    fin = _fix(30.0, BIAS0_NS, DRIFT_NS_S, state="recovered")
    held = guard.check(fin)
    assert held.time_state == "holdover"
    assert held.state == fin.state and held.lat_deg == fin.lat_deg and np.all(held.pos_ecef_m == fin.pos_ecef_m)
    stub = StubGuard()
    stub.d = {"mode": "off"}
    assert ClockGuard(stub).check(fin) is fin


def test_fixes_raim_cannot_vouch_for_are_timed_by_the_model():
    guard, out = _run(20.0, seed=4, state=lambda t: "nominal")
    f = guard.check(_fix(30.05, BIAS0_NS + DRIFT_NS_S * 20.05 + 5000.0, DRIFT_NS_S, raim="fail"))
    assert f.time_state == "holdover" and not guard.guard.alarms
    true_tow = T0_TOW + 30.05 - (BIAS0_NS + DRIFT_NS_S * 20.05) * 1e-9
    assert abs(f.gps_tow_s - true_tow) * 1e9 <= f.tpl_ns


def test_ranges_that_may_be_the_attackers_are_no_measurement_of_the_clock():
    """A fix whose PRNs the defence has not resolved (unvouched: their ranges may all be the attacker's, consistent
    and wrong) is timed by the model, its 5 us push unseen by it and unalarmed."""
    guard, _ = _run(20.0, seed=4)
    f = guard.check(_fix(30.05, BIAS0_NS + DRIFT_NS_S * 20.05 + 5000.0, DRIFT_NS_S, state="recovering"),
                    float("inf"))
    assert f.time_state == "holdover" and not guard.guard.alarms
    true_tow = T0_TOW + 30.05 - (BIAS0_NS + DRIFT_NS_S * 20.05) * 1e-9
    assert abs(f.gps_tow_s - true_tow) * 1e9 <= f.tpl_ns


def test_a_model_fed_merged_ranges_bounds_its_time_by_the_merge_and_holds_none():
    """Ranges merged with their spoofers' (a time push aligned from before the model started: its delay up to the
    merged separation, its rate taken for the oscillator's) time the fixes within that much more, and after the
    clock alarm there is no holdover to vouch for: the model's drift may be the push's."""
    merged_ns, rate = 489.0, 25.0
    # the push at 25 ns/s from the start, held at 15 s, then pushing faster
    guard, out = _run(30.0, push_ns=lambda t: rate * min(t - 10.0, 15.0) + 40.0 * max(t - 25.0, 0.0) ** 2,
                      push_rate=lambda t: rate * (t < 25.0), seed=3, unvouched_ns=merged_ns)
    nominal = [(f, e) for f, e in out if f.time_state in TIME_TRUSTED]
    assert nominal and all(abs(e) <= f.tpl_ns for f, e in nominal)
    assert min(f.tpl_ns for f, _ in nominal) >= merged_ns
    assert guard.guard.alarms and 25.0 <= guard.guard.alarms[0][0] < 27.0
    assert {f.time_state for f, _ in out if f.t_rx_s > guard.guard.alarms[0][0]} == {"unverified"}


# -- the simulator's scenes --------------------------------------------------------------------------------------

def _scene(tmp_path, brdc_path, name, *sets, duration):
    from test_defense import _run_defended, simulate
    simulate(tmp_path / f"{name}.bin", f'constellation.rinex="{brdc_path}"', 'time.start="2022-01-01T00:00:27"',
             "constellation.max_satellites=8", *sets, duration=duration)
    _, fixes, events, _ = _run_defended(tmp_path / f"{name}.bin", tmp_path / name, nav=str(brdc_path))
    truth = list(csv.DictReader(open(tmp_path / f"{name}.truth-receiver.csv")))
    t = np.array([float(r["t_rx_s"]) for r in truth])
    tow = np.array([float(r["gps_tow_s"]) for r in truth])
    for f in fixes:   # the true GPS time of the fix's sample: the truth is linear in between its 0.1 s rows
        f["time_error_ns"] = (float(f["gps_tow_s"]) - np.interp(float(f["t_rx_s"]), t, tow)) * 1e9
    return fixes, events, truth


def _beyond_tpl(fixes):
    return [(f["t_rx_s"], round(f["time_error_ns"]), f["tpl_ns"], f["time_state"]) for f in fixes
            if f["time_state"] in TIME_TRUSTED and abs(f["time_error_ns"]) > float(f["tpl_ns"])]


def test_clean_drifting_and_flying_scenes_never_alarm_and_tpl_bounds_the_time(tmp_path, brdc_path):
    from semperfi.gps.geometry import enu_rotation, geodetic_to_ecef
    from test_receiver import LAT, LON, H
    fixes, events, _ = _scene(tmp_path, brdc_path, "drift", "receiver.clock_drift_s_s=3e-7", duration=30.0)
    center = geodetic_to_ecef(np.radians(LAT), np.radians(LON), H)
    east, north = enu_rotation(np.radians(LAT), np.radians(LON))[:2]
    t = np.arange(0.0, 30.05, 0.1)
    w = 15.0 / 60.0   # 15 m/s on a 60 m radius: 3.75 m/s^2 of centripetal acceleration
    xyz = center + np.outer(60 * np.cos(w * t), east) + np.outer(60 * np.sin(w * t), north) + \
        np.outer(20 * np.sin(0.5 * t), np.cross(east, north))
    traj = tmp_path / "flight.csv"
    traj.write_text("".join(f"{ti:.1f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n" for ti, p in zip(t, xyz)))
    flying, flying_events, _ = _scene(tmp_path, brdc_path, "fly", f'receiver.trajectory="{traj}"',
                                      "receiver.clock_drift_s_s=-1e-6", duration=30.0)
    for name, fx, ev in (("drift", fixes, events), ("flying", flying, flying_events)):
        assert fx, name
        assert not [e for e in ev if e["event"] == "clock_alarm"], \
            (name, [e for e in ev if e["event"] == "clock_alarm"])
        nominal = [f for f in fx if f["time_state"] == "nominal"]
        assert len(nominal) >= 0.7 * len(fx), (name, len(nominal), len(fx))
        assert not _beyond_tpl(fx), (name, _beyond_tpl(fx)[:5])
        err = np.array([abs(f["time_error_ns"]) for f in nominal])
        print(f"{name}: {len(fx)} fixes, {len(nominal)} time nominal, |time error| max {err.max():.1f} ns, "
              f"TPL {min(float(f['tpl_ns']) for f in nominal):.0f}..{max(float(f['tpl_ns']) for f in nominal):.0f} ns")


def test_a_time_push_on_the_simulator_alarms_and_no_good_fix_is_beyond_its_tpl(tmp_path, brdc_path):
    """The seamless push: +10 dB, code and carrier aligned with the sky from 14 s, then delaying every signal, the rate
    growing to 25 ns/s over 5 s from 18 s. The receiver's position stays right; its clock walks with the push."""
    push_s = 18.0
    fixes, events, truth = _scene(tmp_path, brdc_path, "push", "attacker.enabled=true", 'attacker.mode="time_push"',
                                  "attacker.start_s=14", "attacker.push_hold_s=4", "attacker.power_ramp_s=2",
                                  "attacker.power_advantage_db=10", "attacker.time_push_rate_s_s=2.5e-8",
                                  "attacker.time_push_ramp_s=5", duration=30.0)
    delays = [float(r["claimed_delay_s"]) for r in truth if r["claimed_delay_s"]]
    assert delays and max(delays) > 200e-9, "the push reached 200 ns"
    alarms = [e for e in events if e["event"] == "clock_alarm"]
    assert alarms, "no clock alarm"
    latency = alarms[0]["t_rx_s"] - push_s
    assert 0 < latency < 6.0, latency
    assert not _beyond_tpl(fixes), _beyond_tpl(fixes)[:5]
    from test_defense import _horizontal_m
    good = [f for f in fixes if f["state"] in TRUSTED_STATES or f["time_state"] == "holdover"]
    assert all(_horizontal_m(f) < 10.0 for f in good), "the position from the ranges stays"
    held = [f for f in fixes if f["time_state"] == "holdover"]
    pushed = [abs(f["time_error_ns"]) for f in held]
    print(f"time push: alarm {latency:.1f} s after the push began ({alarms[0]}); {len(held)} fixes held, their "
          f"|time error| max {max(pushed) if pushed else float('nan'):.1f} ns, TPL up to "
          f"{max((float(f['tpl_ns']) for f in held), default=float('nan')):.0f} ns")
