"""The Adversarial Peak Identifier on a recording: a receiver that hovers, flies a maneuver and hovers again, an
attacker on from the first sample, and the INS-only track the vehicle logged (`semperfi run --imu`)."""

import csv
import functools
import json
from types import SimpleNamespace

import numpy as np

from semperfi.defense.config import load_config
from semperfi.defense.defended import DefendedReceiver
from semperfi.defense.imu_track import read_imu_csv
from semperfi.defense.maneuver_id import LinkedManeuver, sky
from semperfi.eval.flightpath import hover_maneuver_hover, ins_track, write_motion_csv
from semperfi.flight.deadreckoning import write_track_csv
from semperfi.flight.link import alarm_lines_of_sight
from semperfi.gps.ephemeris import satellite_position
from semperfi.gps.geometry import azimuth_elevation, enu_rotation, geodetic_to_ecef
from semperfi.receiver.run import run_file
from semperfi.sim.constellation import build_constellation
from semperfi.sim.run import simulate_to_file
from semperfi.sim.scenario import load_scenario

LAT, LON, H = 42.3398, -71.0892, 10.0


def _fly_through_attack(tmp_path, brdc_path, hover_before_s: float, *attacker_sets: str, flight_side=None):
    """Hover, the maneuver, hover; an attacker on from the first sample; the recording run defended with the INS
    track the vehicle logged, or with flight_side(the INS track, the maneuver's span) as its live flight link.
    Returns (events, horizontal errors against the truth by fix state)."""
    t, ned = hover_maneuver_hover(hover_before_s, 6.0)
    write_motion_csv(tmp_path / "motion.csv", t, ned, LAT, LON, H)
    write_track_csv(tmp_path / "ins.csv", t, ins_track(t, ned, seed=3))
    cfg = load_scenario(None, ["signal.fs_hz=2e6", f"time.duration_s={t[-1]}", f'constellation.rinex="{brdc_path}"',
                               'time.start="2022-01-01T00:00:27"', "constellation.max_satellites=8",
                               "attacker.enabled=true", *attacker_sets,
                               f'receiver.trajectory="{tmp_path / "motion.csv"}"'])
    simulate_to_file(cfg, tmp_path / "a.bin")
    track = read_imu_csv(tmp_path / "ins.csv")
    moving = t[np.flatnonzero(np.any(np.diff(ned, axis=0) != 0.0, axis=1))]
    receiver = functools.partial(DefendedReceiver, imu_track=track) if flight_side is None else \
        functools.partial(DefendedReceiver, flight_link=flight_side(track, (float(moving[0]), float(moving[-1]))))
    run_file(tmp_path / "a.bin", None, None, None, load_config(None, ['defense.mode="full"']), tmp_path / "out",
             str(brdc_path), receiver_factory=receiver)
    events = [json.loads(line) for line in open(tmp_path / "out" / "events.jsonl")]
    truth = np.loadtxt(tmp_path / "motion.csv", delimiter=",")
    rot = enu_rotation(np.radians(LAT), np.radians(LON))
    errors = {}
    for f in csv.DictReader(open(tmp_path / "out" / "fixes.csv")):
        k = int(round(float(f["t_rx_s"]) / 0.1))
        if k < len(truth):
            enu = rot @ (np.array([float(f[c]) for c in ("x_m", "y_m", "z_m")]) - truth[k, 1:])
            errors.setdefault(f["state"], []).append(float(np.hypot(enu[0], enu[1])))
    print({s: (len(e), round(float(np.mean(e)), 2), round(float(np.max(e)), 2)) for s, e in errors.items()})
    return events, errors


def test_twins_merged_under_their_spoofers_peaks_are_decided_on_the_one_peak_followed(tmp_path, brdc_path):
    """A stronger attacker claiming a position 150 m off: every twin lies 0.2-0.45 chip from its spoofer, inside one
    correlation peak, so the maneuver follows one peak per PRN (the stronger path, the attacker's). The peaks it
    shows not to follow are cancelled with their twins found by the two-path fit; the rest by the power relation
    those establish; no guess, and the fixes recovered on the truth (before: every such PRN was examined afresh
    after the verdict and cancelled on a guess, and the fixes stayed `recovering`)."""
    events, errors = _fly_through_attack(tmp_path, brdc_path, 18.0, "attacker.offset_east_m=150",
                                         "attacker.power_advantage_db=3")
    verdicts = next(e for e in events if e["event"] == "identification")["verdicts"]
    assert {v["peak"] for v in verdicts} == {0}, "one peak followed per PRN"
    assert not [v for v in verdicts if v["decided"] and not v["adversarial"]], \
        f"a spoofer-dominated peak cleared: {verdicts}"
    starts = [e for e in events if e["event"] == "cancellation_start"]
    assert not any(e["guessed"] for e in starts), starts
    assert len([e for e in starts if e["reason"].startswith("maneuver: the peak followed")]) >= 3, starts
    recovered = errors.get("recovered", [])
    assert len(recovered) >= 30 and np.mean(recovered) < 3.0 and max(recovered) < 10.0, errors.keys()
    # before the alarm, some channels on the spoofers' peaks and some on the twins: the ranges agree only with
    # several left out, which is no fix to call good (was: 13 nominal fixes 186-204 m off). They fail the integrity
    # test, and that makes the next look sensitive: the alarm comes before the maneuver starts, not during it
    assert max(errors.get("nominal", [0.0])) < 10.0, errors["nominal"]
    first = next(e for e in events if e["event"] == "spoofing_alarm")
    assert first["t_rx_s"] < 18.0, first


class _AbortsFirst:
    """A flight side that aborts its first maneuver (ArduCopter SITL: at the geofence) and flies the next one, whose
    INS track is the recording's maneuver."""
    closed, rejected = None, 0

    def __init__(self, track, span_s):
        keep = (track.t_s >= span_s[0] - 1.0) & (track.t_s <= span_s[1] + 1.0)
        self.track = {"maneuver_id": "second", "drift_bound_m": 2.0,
                      **{k: getattr(track, k)[keep].tolist() for k in ("t_s", "north_m", "east_m", "down_m")}}
        self.alarms, self.queued = [], []

    def send(self, kind, payload):
        if kind != "alarm":
            return
        self.alarms.append(payload["t_s"])
        self.queued += [("maneuver_failed", {"why": "vehicle 61 m from the start, outside the 60 m geofence"})] \
            if len(self.alarms) == 1 else \
            [("maneuver_request", {"maneuver_id": "second", "t_s": payload["t_s"]}), ("maneuver_done", self.track)]

    def poll(self):
        out, self.queued = self.queued, []
        return out


def _aborted_first(tmp_path, brdc_path, power_advantage_db: float):
    """The hover-maneuver-hover flight, the attacker on from the first sample, beside a flight side that aborts its
    first maneuver: (events, errors by fix state, the flight side)."""
    sides = []

    def flight_side(track, span_s):
        sides.append(_AbortsFirst(track, span_s))
        return sides[0]
    events, errors = _fly_through_attack(tmp_path, brdc_path, 18.0, f"attacker.power_advantage_db={power_advantage_db}",
                                         flight_side=flight_side)
    return events, errors, sides[0]


def test_a_maneuver_the_flight_side_aborted_is_asked_for_again_and_judges_the_guesses(tmp_path, brdc_path):
    """The closed loop on ArduCopter SITL at x1: the flight side aborted the maneuver at its geofence, the receiver
    cancelled every spoofer on a guess (the stronger peak, right here) and nobody asked for a second maneuver: its
    fixes stayed `recovering`, the autopilot never got a position it could use, and landed. Now the receiver asks
    again while guesses wait; the second maneuver judges them, and the true position is called recovered."""
    events, errors, side = _aborted_first(tmp_path, brdc_path, 6.0)
    kinds = [e["event"] for e in events]
    retry = next(e for e in events if e["event"] == "maneuver_retry")
    assert len(side.alarms) == 2 and kinds.count("maneuver_failed") == 1, side.alarms
    assert side.alarms[1] - side.alarms[0] >= LinkedManeuver.RETRY_S and retry["attempt"] == 2, (side.alarms, retry)
    guessed = {e["prn"] for e in events if e["event"] == "cancellation_start" and e["guessed"]}
    assert guessed and set(retry["guessed"]) <= guessed, (retry, guessed)
    judged = [v for e in events if e["event"] == "identification" for v in e["verdicts"]
              if v.get("reason") == "maneuver: the peak followed through it"]
    assert {v["prn"] for v in judged if v["adversarial"]} >= set(retry["guessed"]) - {None}, judged
    recovered = errors.get("recovered", [])
    assert len(recovered) >= 30 and np.mean(recovered) < 3.0 and max(recovered) < 10.0, errors.keys()
    assert max(errors.get("nominal", [0.0])) < 10.0, errors["nominal"]


def test_guesses_a_second_maneuver_shows_wrong_teach_the_attackers_power(tmp_path, brdc_path):
    """The same with an attacker 3 dB weaker: every guess (the stronger peak) cancelled the legitimate signal. The
    second maneuver shows each wrong, and each is swapped and alarmed afresh -- where the same guess was made again,
    to the end. Now the judged guesses establish the power relation (the attacker's peak the weaker), and the fresh
    alarms are decided by it, not guessed."""
    events, _, _ = _aborted_first(tmp_path, brdc_path, -3.0)
    retry = next(e for e in events if e["event"] == "maneuver_retry")
    wrong = [v["prn"] for e in events if e["event"] == "identification" for v in e["verdicts"]
             if v.get("reason") == "maneuver: the peak followed through it" and not v["adversarial"]]
    assert len(wrong) >= 3 and set(wrong) <= set(retry["guessed"]), (wrong, retry)
    learnt = [e for e in events if e["event"] == "attacker_power" and e["t_rx_s"] > retry["t_rx_s"]][-1]
    assert len(learnt["gaps_db"]) >= 3 and all(g < 0 for g in learnt["gaps_db"].values()), learnt
    inferred = [e["prn"] for e in events if e["event"] == "cancellation_start" and e["t_rx_s"] > retry["t_rx_s"]
                and not e["guessed"] and "weaker" in e["reason"]]
    assert len(inferred) >= 3, [e for e in events if e["event"] == "cancellation_start"]


def test_run_refuses_a_malformed_imu_track_in_one_line(tmp_path):
    import subprocess
    import sys
    (tmp_path / "x.bin").write_bytes(bytes(8000))
    (tmp_path / "ins.csv").write_text("t_s,north_m\n0,1\n")
    r = subprocess.run([sys.executable, "-m", "semperfi.cli", "run", str(tmp_path / "x.bin"), "--fs", "2e6", "--format",
                        "ishort", "--imu", str(tmp_path / "ins.csv"), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, (r.returncode, r.stderr)
    assert "header must be t_s,north_m,east_m,down_m" in r.stderr


class _Link:
    def __init__(self):
        self.sent = []

    def send(self, kind, payload):
        self.sent.append((kind, payload))

    def poll(self):
        return []


def test_the_alarm_carries_each_prns_line_of_sight_from_the_fix(brdc_path):
    c = build_constellation(load_scenario(None, [f'constellation.rinex="{brdc_path}"',
                                                 'time.start="2022-01-01T00:00:27"']))
    pos = geodetic_to_ecef(np.radians(LAT), np.radians(LON), H + 50.0)
    fix = SimpleNamespace(t_rx_s=12.0, gps_tow_s=c.start.tow_s + 12.0, pos_ecef_m=pos, lat_deg=LAT, lon_deg=LON)

    def ephemeris_of(prn, tow_s):
        return c.ephemerides.get(prn)
    link = _Link()
    LinkedManeuver(link, 2e6, sky=lambda: sky([1, 7, 30, 33], ephemeris_of, fix)).request(12.0, 7)
    kind, payload = link.sent[0]
    got = alarm_lines_of_sight(payload)   # what the flight side accepts
    assert kind == "alarm" and [prn for prn, _, _ in got] == [1, 7, 30], "PRN 33 has no ephemeris"
    for prn, az_deg, el_deg in got:
        sat = satellite_position(c.ephemerides[prn], np.array([fix.gps_tow_s - 0.075]))
        az, el = azimuth_elevation(pos, sat)
        assert abs(az_deg - np.degrees(az[0])) < 0.01 and abs(el_deg - np.degrees(el[0])) < 0.01, prn
