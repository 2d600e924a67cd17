"""The paper's closed loop with a real autopilot: ArduCopter SITL flies with SemperFi as its only GPS.

    semperfi demo --autopilot PATH/arducopter [--speedup 1] [--out out/autopilot]

Four parts, as on a UAV. The autopilot (ArduCopter SITL, `GPS1_TYPE 14`) takes its GPS only from the receiver's
MAVLink GPS_INPUT. The world renders the GPS signals (and, once the vehicle is cruising, a synchronized attacker
1 km east at +6 dB) from where SITL's physics says the vehicle truly is (SIM_STATE, read on the autopilot's first
link: the world may read the truth, the receiver and the flight side never do), chunk by chunk on SITL's clock, into
the receiver's standard input. The receiver (`semperfi run -`, defended) feeds the autopilot and, on an alarm, asks
the flight side (`semperfi companion`, on the autopilot's second link) for a maneuver over the authenticated link;
the inertial track that comes back decides the peaks, the attacker's are cancelled, and the autopilot gets the true
position again. This module arms, takes off, cruises, switches the attacker on, waits for the recovery, commands the
vehicle back to where it hovered, and judges every GPS_INPUT the autopilot was given against SITL's truth.

While spoofing is suspected the autopilot gets no fix and dead-reckons; its failsafes stay as ArduPilot ships them.
The paper turned the EKF failsafe off on its S500 for the maneuver; here that let ArduCopter, its EKF drifting
without GPS, fly 1.5 km off when the receiver could not give the true position back (a takeover, +3 dB, dragged
at 10 m/s), where with the failsafe on it lands ~9 s into the outage: the safe end when no true fix comes.
"""

from __future__ import annotations

import bisect
import contextlib
import csv
import json
import math
import os
import secrets
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import common as mav

from ..gps import GpsTime, enu_rotation
from ..iq import as_format, encode_samples
from ..sim import CHUNK_S, load_scenario, make_live_simulator
from .autopilot import CRUISE_S, GUIDED, Observer, Sitl
from .closed_loop import CLOSED_LOOP_SETTINGS

ALTITUDE_M = 30.0
AUTOPILOT_PARAMS = {"GPS1_TYPE": 14,      # its GPS is GPS_INPUT, ours
                    # the fix reaches it a few tenths of a second after its epoch (the receiver computes a chunk of
                    # samples at a time, the stream hands the fixes on one a period): ArduPilot's most; at its default
                    # 10 m/s return the EKF took the lag for a glitch (measured: a 40 m overshoot, then LAND)
                    "GPS1_DELAY_MS": 250, "WPNAV_SPEED": 300}
FAR_FUTURE_S = 86400.0                     # the attacker waits until the world switches it on
SCENE_S = 3600.0                           # the world renders until stopped; this only bounds it
TRUTH_EVERY_S = 0.1
STALL_S = 10.0                             # SITL silent this long (wall) is gone
GPS_FIX_3D = 3
ARRIVED_M = 3.0                            # back at the hover point ...
RETURN_S = 60.0                            # ... within this (vehicle time) ...
SETTLE_S = 10.0                            # ... and then holding there this long before the end is judged
# The world holds SITL back (SIM_SPEEDUP, which SITL takes at run time) when it lags more than PACE_LAG_S of vehicle
# time: the fixes then reach the autopilot as late as a receiver's own latency makes them, not as late as two shared
# cores make the rendering of the signals. At x1 the world lagged up to 4.1 s and the EKF, flying back, took the
# late fixes for a glitch and landed. Held back by PACE_STEP at a time, never under PACE_FLOOR of the speed asked.
PACE_LAG_S = 0.5
PACE_STEP = 0.8
PACE_FLOOR = 0.25
PACE_EVERY_S = 1.0                         # world time between two looks at the lag


@dataclass
class LoopResult:
    out_dir: Path
    phases: dict = field(default_factory=dict)       # name -> signal time (s from the world's first sample)
    gps_errors: list = field(default_factory=list)   # (t_s, fix_type, horizontal error m, h_acc m) per GPS_INPUT
    end_error_m: float = math.nan                    # the vehicle's final distance from where it was commanded
    errors: list = field(default_factory=list)

    @property
    def worst_used_error_m(self) -> float:
        used = [e for _, ft, e, _ in self.gps_errors if ft >= GPS_FIX_3D]
        return max(used) if used else math.nan

    @property
    def outages(self) -> list[tuple[float, float]]:
        """(first GPS_INPUT without a 3D fix, first with one again) for each spell without one after the attack
        began; the end is NaN when the fix never came back. The loop's own marks are the first of each kind, which a
        spell of a tenth of a second (a static attacker decided by continuity) can be."""
        start_s, spells, began = self.phases.get("attack", math.inf), [], None
        for t, ft, _, _ in self.gps_errors:
            if t >= start_s and ft < GPS_FIX_3D and began is None:
                began = t
            elif ft >= GPS_FIX_3D and began is not None:
                spells.append((began, t))
                began = None
        return spells + ([(began, math.nan)] if began is not None else [])


class SitlWorld(threading.Thread):
    """Renders cfg's scenario around SITL's vehicle into `out` on SITL's clock: chunk k is written once the truth
    reaches its end (a slower receiver slows the world, which then lags SITL: the lag is measured, `lag_s`)."""

    def __init__(self, cfg: dict, observer: Observer, out, truth_path: Path, speedup: float, log=print):
        super().__init__(daemon=True)
        self.log, self._told = log, 0
        self.sim, self.motion = make_live_simulator(cfg)
        self.fmt = as_format(cfg["signal"]["format"])
        self.obs, self.out, self.truth_path, self.speedup = observer, out, truth_path, speedup
        self.t_boot0_s: float | None = None
        self.tau_s = 0.0
        self.lag_s = 0.0
        self.pace = speedup                # SITL's speed now (SIM_SPEEDUP), held back while the world lags
        self.slowest = speedup
        self.error: str | None = None
        self._attack = threading.Event()
        self._halt = threading.Event()

    def tell(self) -> None:
        """Hand on what the autopilot said (STATUSTEXT) since the last call."""
        while self._told < len(self.obs.texts):
            self.log(f"{self.tau_s:6.1f} s  autopilot: {self.obs.texts[self._told][1]}")
            self._told += 1

    def attack(self) -> None:
        """Switch the attacker on at the next chunk."""
        self._attack.set()

    def stop(self) -> None:
        self._halt.set()

    def _truth_at(self, t_boot_s: float):
        """ECEF position and velocity, and (lat, lon, alt), at vehicle time t_boot_s; None until SITL gets there."""
        return truth_at(self.obs.truth, t_boot_s)

    def _wait_truth(self, tau_s: float):
        deadline = time.monotonic() + STALL_S
        while not self._halt.is_set():
            state = self._truth_at(self.t_boot0_s + tau_s)
            if state is not None:
                return state
            if time.monotonic() > deadline:
                raise RuntimeError(f"no SIM_STATE from the autopilot for {STALL_S:g} s")
            time.sleep(0.002)
        return None

    def _pace(self, lag_s: float) -> None:
        """Hold SITL back while the world lags it by more than PACE_LAG_S, let it go again once caught up."""
        if lag_s > PACE_LAG_S:
            pace = max(self.pace * PACE_STEP, self.speedup * PACE_FLOOR)
        elif lag_s < PACE_LAG_S / 2:
            pace = min(self.pace / PACE_STEP, self.speedup)
        else:
            return
        if pace != self.pace:
            self.pace, self.slowest = pace, min(self.slowest, pace)
            self.obs.set_speedup(pace)

    def vehicle_s(self) -> float:
        """SITL's clock now (vehicle boot seconds)."""
        return self.obs.truth[-1][0] if self.obs.truth else 0.0

    def run(self) -> None:
        _best_effort()
        try:
            self._run()
        except BrokenPipeError:
            pass   # the receiver stopped reading
        except Exception as exc:   # noqa: BLE001 -- reported by the loop, one line
            self.error = f"world: {exc}"
        finally:
            try:
                self.out.close()
            except OSError:
                pass

    def _run(self) -> None:
        while not self.obs.truth and not self._halt.wait(0.05):
            pass
        self.t_boot0_s = self.obs.truth[-1][0]
        state = self._wait_truth(0.0)
        if state is None:
            return
        self.motion.set_state(0.0, state[0], state[1])
        every = int(round(TRUTH_EVERY_S / CHUNK_S))
        with open(self.truth_path, "w", newline="") as f:
            truth = csv.writer(f, lineterminator="\n")
            truth.writerow(["t_s", "t_boot_s", "lat_deg", "lon_deg", "height_m"])
            for k, chunk in enumerate(self.sim.chunks()):
                if self._halt.is_set():
                    return
                self.out.write(encode_samples(chunk, self.fmt, 1.0)[0].tobytes())
                self.tau_s = (k + 1) * CHUNK_S
                if self._attack.is_set() and self.sim.attack.start_s > self.tau_s:
                    self.sim.attack = replace(self.sim.attack, start_s=self.tau_s + CHUNK_S)
                state = self._wait_truth((k + 2) * CHUNK_S)
                if state is None:
                    return
                self.motion.set_state((k + 2) * CHUNK_S, state[0], state[1])
                lag_s = self.obs.truth[-1][0] - self.t_boot0_s - self.tau_s   # vehicle seconds
                self.lag_s = max(self.lag_s, lag_s / self.speedup)
                if k % int(round(PACE_EVERY_S / CHUNK_S)) == 0:
                    self._pace(lag_s)
                if k % every == 0:
                    lat, lon, alt = state[2]
                    truth.writerow([f"{(k + 2) * CHUNK_S:.2f}", f"{self.t_boot0_s + (k + 2) * CHUNK_S:.3f}",
                                    f"{lat:.8f}", f"{lon:.8f}", f"{alt:.3f}"])
                    f.flush()


BEST_EFFORT_NICE = 10


def _best_effort(pid: int = 0) -> None:
    """Lower a process's (by default the calling thread's) CPU priority below the autopilot's and the flight side's,
    as on a UAV where the control loops come first: at x1 on two cores, the receiver under attack and the world's
    rendering starved the flight side's 25 Hz attitude loop, which then could not hold the maneuver and aborted it
    (seen in static and takeover runs alike). On Linux a thread's nice value is its own."""
    with contextlib.suppress(OSError, AttributeError):
        os.setpriority(os.PRIO_PROCESS, pid or threading.get_native_id(), BEST_EFFORT_NICE)


def truth_at(truth: list[tuple], t_boot_s: float):
    """ECEF position and velocity, and (lat, lon, alt), at vehicle time t_boot_s from SIM_STATE records (Observer.truth,
    appended in time order); None until they reach it. The records around it are found wherever they are: a world
    lagging SITL by more than the last few seconds of records (at x1 on two cores, 13-16 s) had its vehicle's state
    read from the oldest of them instead -- the signals rendered from a position seconds ahead of their own time,
    moving faster than their Doppler said, and every tracking loop on them stressed (the canceller's lost lock 75
    times in one takeover)."""
    n = len(truth)
    if n < 2 or truth[n - 1][0] < t_boot_s:
        return None
    k = bisect.bisect_right(truth, t_boot_s, 0, n, key=lambda record: record[0])
    around = np.array(truth[max(0, k - 2):min(n, k + 2)])
    around = around[np.r_[True, np.diff(around[:, 0]) > 0]]
    lat, lon, alt, vn, ve, vd = (np.interp(t_boot_s, around[:, 0], around[:, j]) for j in (1, 2, 3, 13, 14, 15))
    pos = np.array(pymap3d.geodetic2ecef(lat, lon, alt))
    vel = enu_rotation(math.radians(lat), math.radians(lon)).T @ np.array([ve, vn, -vd])
    return pos, vel, (lat, lon, alt)


def _attack_words(a: dict) -> str:
    """The scenario's attacker in a few words."""
    where = (f"drags the fix off at {a['push_speed_m_s']:g} m/s after {a['push_hold_s']:g} s aligned"
             if a["mode"] in ("push", "takeover") else
             f"claims {math.hypot(a['offset_east_m'], a['offset_north_m']):g} m away" if a["mode"] == "static" else
             "delays every signal alike" if a["mode"] == "time_push" else
             f"replays the sky {a['delay_s'] * 1e6:g} us late")
    return f"{a['mode']}, {a['power_advantage_db']:+g} dB, {where}, every PRN in view"


def _distance_m(truth: tuple, lat_lon_e7: tuple[int, int]) -> float:
    """Horizontal distance of a SIM_STATE record from a commanded latitude/longitude (deg * 1e7)."""
    n, e, _ = pymap3d.geodetic2ned(truth[1], truth[2], 0.0, lat_lon_e7[0] / 1e7, lat_lon_e7[1] / 1e7, 0.0)
    return float(math.hypot(n, e))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _drain(stream, path: Path) -> None:
    """The flight side's report lines into a file as they come (an unread pipe would stall it)."""
    with open(path, "w") as f:
        for line in stream:
            f.write(line)
            f.flush()


def _narrate(world: SitlWorld) -> None:
    """Hand on what the autopilot says, as long as the world runs."""
    while world.is_alive():
        world.tell()
        time.sleep(0.2)
    world.tell()


def _wait(what: str, done, timeout_s: float, world: SitlWorld, poll_s: float = 0.1) -> None:
    """Until done(), for timeout_s of vehicle time (SITL's clock, which the world may hold back); SITL silent is
    the world's error (STALL_S)."""
    deadline = world.vehicle_s() + timeout_s
    while not done():
        if world.error or not world.is_alive():
            raise RuntimeError(world.error or "the world stopped")
        if world.vehicle_s() > deadline:
            raise RuntimeError(f"timed out waiting for {what} ({timeout_s:g} s)")
        time.sleep(poll_s)


def _fly_on(seconds: float, world: SitlWorld) -> None:
    """Let seconds of vehicle time pass."""
    end = world.vehicle_s() + seconds
    _wait(f"{seconds:g} s of flight", lambda: world.vehicle_s() >= end, seconds + 1.0, world, 0.05)


def run_autopilot_loop(out_dir: str | Path, binary: str | Path, speedup: float = 1.0, instance: int = 6,
                       sets: list[str] = (), seed: int = 0, log=lambda line: None) -> LoopResult:
    """The whole loop; log(line) hears each phase as it happens (seed: the signals' noise; the maneuver is the OS's
    cryptographic draw, as in flight)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = LoopResult(out)
    cfg = load_scenario(None, [*CLOSED_LOOP_SETTINGS, f"attacker.start_s={FAR_FUTURE_S}",
                               f"time.duration_s={SCENE_S}", f"signal.seed={seed + 1}", *sets])
    r, sig = cfg["receiver"], cfg["signal"]
    key_path = out / "link.key"
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(32))
    link_port = _free_port()
    me = [sys.executable, "-m", "semperfi.cli"]
    sitl = Sitl(instance, speedup, out / "sitl", binary, params=AUTOPILOT_PARAMS,
                home=(r["lat_deg"], r["lon_deg"], r["height_m"])).start()
    procs: list[subprocess.Popen] = []
    world = obs = None
    logs = contextlib.ExitStack()   # the children's output files, closed at the end
    try:
        obs = Observer(sitl.url(0), speedup=speedup)
        obs.streams(extra=(mav.MAVLINK_MSG_ID_GPS_RAW_INT,))
        log(f"autopilot: ArduCopter SITL instance {instance}, x{speedup:g}, home {r['lat_deg']:.5f} {r['lon_deg']:.5f}")
        companion = subprocess.Popen(me + ["companion", "--port", str(link_port), "--link-key", str(key_path),
                                           "--vehicle", sitl.url(1)],
                                     stdout=subprocess.PIPE,
                                     stderr=logs.enter_context(open(out / "companion.err", "w")), text=True)
        procs.append(companion)
        if companion.stdout.readline().find('"listening"') < 0:
            raise RuntimeError("the flight side did not start (companion.err says why)")
        threading.Thread(target=_drain, args=(companion.stdout, out / "flight.jsonl"), daemon=True).start()
        receiver = subprocess.Popen(me + ["run", "-", "--fs", repr(sig["fs_hz"]), "--format", sig["format"],
                                          "--if", repr(sig["if_hz"]), "--out", str(out / "receiver"),
                                          "--link", f"127.0.0.1:{link_port}", "--link-key", str(key_path),
                                          "--mavlink-gps", sitl.url(2), "--fix-rate", f"{10.0 * max(speedup, 1.0):g}"],
                                    stdin=subprocess.PIPE, stdout=logs.enter_context(open(out / "receiver.out", "w")),
                                    stderr=logs.enter_context(open(out / "receiver.err", "w")))
        _best_effort(receiver.pid)   # before it has read a sample: its threads to come inherit it
        procs.append(receiver)
        world = SitlWorld(cfg, obs, receiver.stdin, out / "truth.csv", speedup, log)
        world.start()
        threading.Thread(target=_narrate, args=(world,), daemon=True).start()
        _wait("the autopilot's first GPS fix", lambda: obs.gps_fix_type == GPS_FIX_3D, 420.0, world)
        result.phases["autopilot_fix"] = world.tau_s
        log(f"{world.tau_s:6.1f} s  the autopilot has SemperFi's 3D fix")
        obs.takeoff(ALTITUDE_M)
        result.phases["airborne"] = world.tau_s
        log(f"{world.tau_s:6.1f} s  airborne at {ALTITUDE_M:g} m in GUIDED")
        _fly_on(CRUISE_S, world)
        hover = obs.lat_lon_e7
        world.attack()
        _wait("the attack", lambda: world.sim.attack.start_s < FAR_FUTURE_S and world.tau_s > world.sim.attack.start_s,
              30.0, world, 0.01)
        result.phases["attack"] = world.sim.attack.start_s
        log(f"{world.tau_s:6.1f} s  the attacker is on: {_attack_words(cfg['attacker'])}")
        _wait("the autopilot to lose its fix (the alarm)", lambda: (obs.gps_fix_type or 0) < GPS_FIX_3D,
              90.0, world, 0.02)
        result.phases["autopilot_no_fix"] = world.tau_s
        log(f"{world.tau_s:6.1f} s  the autopilot gets no fix: spoofing is suspected")
        _wait("the autopilot's fix back (the recovery)", lambda: obs.gps_fix_type == GPS_FIX_3D,
              300.0, world, 0.02)
        result.phases["autopilot_fix_back"] = world.tau_s
        log(f"{world.tau_s:6.1f} s  the autopilot has the true position again")
        flight = out / "flight.jsonl"
        _wait("the flight side's verdict", lambda: flight.exists() and ('"verdict"' in flight.read_text() or
                                                                     '"maneuver_failed"' in flight.read_text()),
              180.0, world, 0.2)
        result.phases["verdict"] = world.tau_s
        failed, done = _first(flight, "maneuver_failed"), _first(flight, "maneuver_done")
        aborted = flight.read_text().count('"maneuver_failed"')
        log(f"{world.tau_s:6.1f} s  the maneuver is "
            + ("flown and judged" if done else f"aborted: {failed['error']}")
            + (f" ({aborted} aborted before: {failed['error']})" if done and failed else "")
            + "; the vehicle is sent back to its hover point")
        _fly_on(2.0, world)   # the flight side hands the vehicle back in the mode it found it in
        obs.set_mode(GUIDED)
        obs.conn.mav.set_position_target_global_int_send(0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                         0b0000_1101_1111_1000, hover[0], hover[1], ALTITUDE_M,
                                                         0, 0, 0, 0, 0, 0, 0, 0)
        _wait("the vehicle back at its hover point", lambda: _distance_m(obs.truth[-1], hover) < ARRIVED_M,
              RETURN_S, world, 0.2)
        _fly_on(SETTLE_S, world)
        result.phases["end"] = world.tau_s
        result.end_error_m = _distance_m(obs.truth[-1], hover)
        log(f"{world.tau_s:6.1f} s  it holds {result.end_error_m:.1f} m from where it was commanded")
    except (RuntimeError, OSError) as exc:
        result.errors.append(str(exc))
    finally:
        if world is not None:
            world.stop()
            world.join(10)
            if world.error:
                result.errors.append(world.error)
        for p in procs:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(10)
        logs.close()
        if obs is not None:
            (out / "autopilot.txt").write_text("".join(f"{t if t is None else round(t, 2)} {text}\n"
                                                       for t, text in obs.texts))
            obs.close()
        sitl.stop()
    if world is not None and world.t_boot0_s is not None:
        result.gps_errors = judge_gps_input(out, world.sim.t0)
        result.phases["world_lag_s"] = round(world.lag_s, 2)
        result.phases["slowest_pace"] = round(world.slowest, 3)   # SITL held back to this speed at most
        result.phases["t_boot0_s"] = world.t_boot0_s
    (out / "summary.json").write_text(json.dumps({"phases": result.phases, "end_error_m": result.end_error_m,
                                                  "worst_used_gps_error_m": result.worst_used_error_m,
                                                  "errors": result.errors}, indent=1))
    return result


def judge_gps_input(out: Path, t0: GpsTime) -> list[tuple]:
    """(t_s, fix_type, horizontal error m, h_acc m) of every GPS_INPUT the receiver sent, against the truth at the
    time the fix is for (its GPS week and time of week; t_s from the world's first sample)."""
    path, truth_path = out / "receiver" / "gps_input.csv", out / "truth.csv"
    if not path.exists() or not truth_path.exists():
        return []
    truth = np.array([[float(x[k]) for k in ("t_s", "lat_deg", "lon_deg")] for x in csv.DictReader(open(truth_path))])
    rows = []
    for m in csv.DictReader(open(path)):
        if int(m["time_week"]) == 0:
            continue   # no fix at all yet
        t_s = (int(m["time_week"]) - t0.week) * 604800.0 + int(m["time_week_ms"]) / 1e3 - t0.tow_s
        fix_type = int(m["fix_type"])
        error = math.nan
        if fix_type >= GPS_FIX_3D and len(truth) and truth[0, 0] <= t_s <= truth[-1, 0]:
            lat, lon = (np.interp(t_s, truth[:, 0], truth[:, k]) for k in (1, 2))
            n, e, _ = pymap3d.geodetic2ned(float(m["lat_deg"]), float(m["lon_deg"]), 0.0, lat, lon, 0.0)
            error = float(math.hypot(n, e))
        rows.append((round(t_s, 3), fix_type, error, float(m["h_acc_m"])))
    return rows


def report(result: LoopResult) -> list[str]:
    """What the loop showed, in a few lines (and the plot beside)."""
    used = [(t, e) for t, ft, e, _ in result.gps_errors if ft >= GPS_FIX_3D and math.isfinite(e)]
    withheld = sum(ft < GPS_FIX_3D for _, ft, _, _ in result.gps_errors)
    lines = [f"GPS_INPUT sent to the autopilot: {len(result.gps_errors)}, {len(used)} with a 3D fix, "
             f"{withheld} without (no fix while spoofing was suspected)"]
    if used:
        errors = np.array([e for _, e in used])
        lines.append(f"  3D fixes against SITL's truth: median {np.median(errors):.1f} m, worst {errors.max():.1f} m "
                     f"({int(np.sum(errors > 10.0))} over 10 m)")
    spells = result.outages
    if spells:
        longest = max(spells, key=lambda s: s[1] - s[0] if math.isfinite(s[1]) else math.inf)
        lines.append(f"  without a fix after the attack: {len(spells)} spell(s), the longest {longest[0]:.1f}-"
                     f"{longest[1]:.1f} s ({longest[1] - longest[0]:.1f} s)")
    if math.isfinite(result.end_error_m):
        lines.append(f"the vehicle ends {result.end_error_m:.1f} m from where it was commanded")
    if "slowest_pace" in result.phases:
        lines.append(f"the world lagged SITL by {result.phases['world_lag_s']:.1f} s at most; it held SITL back to "
                     f"x{result.phases['slowest_pace']:g} at its slowest (SIM_SPEEDUP)")
    try:
        lines.append(f"plot: {plot(result)}")
    except (ImportError, OSError, ValueError) as exc:
        lines.append(f"no plot: {exc}")
    return lines


def _first(path: Path, kind: str) -> dict | None:
    """The first JSON line of `kind` in a report file."""
    if not path.exists():
        return None
    for line in open(path):
        if line.startswith("{") and f'"{kind}"' in line:
            return json.loads(line)
    return None


def plot(result: LoopResult) -> Path:
    """The attack, the alarm, the maneuver and the recovery on one time axis: each GPS_INPUT's horizontal error
    against SITL's truth and its fix type; the vehicle's path beside."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = result.out_dir
    g = np.array([(t, ft, e, h) for t, ft, e, h in result.gps_errors]) if result.gps_errors else np.empty((0, 4))
    fig, (ax, tx) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    if len(g):
        used = g[:, 1] >= GPS_FIX_3D
        ax.plot(g[used, 0], g[used, 2], ".", ms=3, color="tab:green", label="GPS_INPUT 3D fix: error vs SITL truth")
        ax.plot(g[used, 0], g[used, 3], "-", lw=0.8, color="0.5", label="its stated horizontal accuracy (1 sigma)")
        tx.plot(g[:, 0], g[:, 1], drawstyle="steps-post", color="k")
    ax.axhline(10.0, color="tab:red", ls=":", lw=1, label="10 m")
    marks = [(result.phases.get("attack"), "attacker on", "tab:red")]
    for k, (began, ended) in enumerate(result.outages):   # each spell without a fix, not only the first
        marks += [(began, "alarm: no fix to the autopilot" if k == 0 else None, "tab:orange"),
                  (ended, "recovered: true fix again" if k == 0 else None, "tab:green")]
    for t, label, color in marks:
        if t is not None and math.isfinite(t):
            for a in (ax, tx):
                a.axvline(t, color=color, ls="--", lw=1, label=label if a is ax else None)
    done = _first(out / "flight.jsonl", "maneuver_done")
    if done and "t_boot0_s" in result.phases:   # the flight side times it in vehicle boot seconds
        t0 = result.phases["t_boot0_s"]
        ax.axvspan(done["start_s"] - t0, done["end_s"] - t0, color="tab:blue", alpha=0.12, label="maneuver flown")
    ax.set(ylabel="horizontal error, m", yscale="symlog", title="ArduCopter SITL with SemperFi as its only GPS")
    ax.legend(fontsize=8, loc="upper left")
    tx.set(xlabel="s from the world's first sample", ylabel="fix type", yticks=[0, 1, 2, 3])
    fig.tight_layout()
    path = out / "autopilot-loop.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
