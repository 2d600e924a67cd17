"""The flight side of the closed loop, as a UAV's companion computer runs it: it serves the authenticated link to
the receiver and answers each spoofing alarm with a maneuver.

On "alarm": draw a pseudorandom maneuver (the OS's cryptographic source) that moves along every line of sight the
alarm carries far enough for the receiver to decide its peaks, answer "maneuver_request", fly it over
MAVLink in GUIDED (GUIDED_NOGPS when the autopilot has no GPS fix: mavlink_pilot), answer "maneuver_done" with the
IMU-only track (t_s on the vehicle's clock), give the vehicle its mode back once the autopilot has a position again,
and wait for the "verdict". Alarms that arrive while a maneuver is under way are answered by that maneuver. A maneuver
that cannot be flown (aborted at the geofence, a vehicle that does not follow) is answered "maneuver_failed"; the
vehicle is held level meanwhile, and the receiver's next alarm (it asks again while its guesses wait for a verdict)
gets a fresh maneuver, up to MAX_FAILED failures. Every step is reported to `report` as a dict (the demo prints and
plots them).
"""

from __future__ import annotations

import secrets
import socket
import time

import numpy as np

from .link import MAX_WHY_CHARS, LinkError, LinkPeer, alarm_lines_of_sight, alarm_required_spread_m
from .maneuver import ManeuverLimits, draw, spread_m, unit_ned
from .mavlink_pilot import Pilot, PilotError

VERDICT_WAIT_S = 120.0
MAX_FAILED = 3         # maneuvers that could not be flown, before the vehicle is left to regain its position or land
HELLO_WAIT_S = 5.0     # a connection must say an authenticated hello this soon, or it is dropped


def serve(port: int, key: bytes, vehicle_url: str, report, host: str = "127.0.0.1", max_maneuvers: int = 1,
          accept_timeout_s: float = 60.0, rng=None) -> None:
    """Accept one receiver on host:port and serve it until it hangs up or max_maneuvers are flown.

    rng: a seeded random.Random for tests only -- a seeded maneuver is predictable; None draws from the OS source."""
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind((host, port))
    srv.listen(4)
    report({"event": "listening", "port": port})
    try:
        peer, address = _authenticated(srv, key, accept_timeout_s, report)
    finally:
        srv.close()
    report({"event": "receiver_connected", "address": address})
    flown = failed = 0
    # one link to the vehicle for the whole session, watched from now on: a maneuver flown after the autopilot lost
    # its GPS (SemperFi withholds it while spoofing is suspected) is calibrated on the GPS-aided seconds before
    pilot = None
    try:
        pilot = Pilot(vehicle_url, timeout_s=10.0)
        pilot.watch()   # in the background: prepare() waits for it
    except PilotError as exc:
        report({"event": "vehicle_not_watched", "error": str(exc)})   # the alarm connects instead
    try:
        while flown < max_maneuvers and peer.closed is None:
            msg = peer.wait(1.0)
            if msg is None or msg[0] != "alarm":
                if pilot is not None and pilot.return_mode is not None and not _regain(pilot, report, peer.pending):
                    break   # landed
                continue
            report({"event": "alarm", "payload": msg[1]})
            try:
                sky, required_m = alarm_lines_of_sight(msg[1]), alarm_required_spread_m(msg[1])
            except LinkError as exc:
                report({"event": "alarm_rejected", "error": str(exc)})
                continue
            lines_of_sight = [unit_ned(az, el) for _, az, el in sky]
            try:
                pilot = pilot or Pilot(vehicle_url, timeout_s=10.0)
                status = pilot.prepare()   # the maneuver is drawn for where the vehicle is and how high
                maneuver = draw(ManeuverLimits(), track_heading_rad=status.track_heading_rad,
                                altitude_m=status.height_above_home_m,
                                lines_of_sight=lines_of_sight, required_spread_m=required_m, rng=rng)
                maneuver_id = secrets.token_hex(8)
                peer.send("maneuver_request", {"maneuver_id": maneuver_id, "t_s": pilot.tm.attitude_t_s})
                report({"event": "maneuver_drawn", "maneuver_id": maneuver_id, "legs": len(maneuver.legs),
                        "duration_s": round(maneuver.duration_s, 2), "path_m": round(maneuver.path_length_m, 1),
                        "end_distance_m": round(maneuver.end_distance_m, 1),
                        "height_m": round(status.height_above_home_m, 1),
                        **_spreads(maneuver, [prn for prn, _, _ in sky], lines_of_sight, required_m)})
                result = pilot.fly(maneuver)
            except (PilotError, ValueError, RuntimeError) as exc:
                report({"event": "maneuver_failed", "error": str(exc)})
                peer.send("maneuver_failed", {"why": str(exc)[:MAX_WHY_CHARS]})   # it waits for no track now
                failed += 1
                if failed >= MAX_FAILED:
                    if pilot is not None:
                        _regain(pilot, report)
                    break
                continue   # held level (the loop's regain) until the receiver asks again or a position comes back
            ins, t0 = result.ins, result.start_time_boot_s
            track = {"maneuver_id": maneuver_id, "t_s": [round(t0 + t, 3) for t in ins.t_s.tolist()],
                     "north_m": [round(x, 3) for x in ins.pos_ned_m[:, 0].tolist()],
                     "east_m": [round(x, 3) for x in ins.pos_ned_m[:, 1].tolist()],
                     "down_m": [round(x, 3) for x in ins.pos_ned_m[:, 2].tolist()],
                     "drift_bound_m": round(result.error_bound_m, 2)}
            peer.send("maneuver_done", track)
            report({"event": "maneuver_done", "start_s": round(t0, 2), "end_s": track["t_s"][-1],
                    "without_gps": result.without_gps, "ins_age_s": round(result.ins_age_s, 2), "track": track})
            flown += 1
            _regain(pilot, report)   # the verdict gives the autopilot its position back meanwhile
            verdict = _await(peer, "verdict", VERDICT_WAIT_S)
            report({"event": "verdict", "payload": verdict})
    finally:
        if pilot is not None:
            pilot.close()
        peer.close()


def _regain(pilot: Pilot, report, interrupt=lambda: False) -> bool:
    """A vehicle left in GUIDED_NOGPS (the maneuver flown without a position) is held level until the autopilot has
    its position back and takes its mode again, or lands (mavlink_pilot.Pilot.regain), or interrupt() (a message
    from the receiver) stops the hold for now. False when it landed."""
    if pilot.return_mode is None:
        return True
    try:
        if pilot.regain(VERDICT_WAIT_S, interrupt):
            report({"event": "mode_restored", "mode": pilot.tm.custom_mode})
    except PilotError as exc:
        report({"event": "regain_failed", "error": str(exc)})
        return False
    return True


def _authenticated(srv: socket.socket, key: bytes, timeout_s: float, report) -> tuple[LinkPeer, str]:
    """The first connection that says an authenticated hello within HELLO_WAIT_S; one that does not (silent, or
    without the key) is dropped and the next one is heard: a local process cannot hold the slot without the key."""
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise LinkError(f"no receiver connected within {timeout_s:g} s")
        srv.settimeout(left)
        try:
            conn, address = srv.accept()
        except (socket.timeout, TimeoutError):
            raise LinkError(f"no receiver connected within {timeout_s:g} s") from None
        where = f"{address[0]}:{address[1]}"
        peer = LinkPeer(conn, key)
        hello = peer.wait(min(HELLO_WAIT_S, max(deadline - time.monotonic(), 0.0)))
        if hello is not None and hello[0] == "hello":
            return peer, where
        peer.close()
        report({"event": "peer_refused", "address": where,
                "reason": "no authenticated hello" if hello is None else f"{hello[0]} before hello"})


def _spreads(maneuver, prns, lines_of_sight, required_m: float) -> dict:
    """How far the maneuver moves along each PRN's line of sight, and whether that is enough for every one (a draw
    that is not was the best of a bounded search)."""
    spread = spread_m(maneuver, lines_of_sight)
    return {"spread_m": {str(prn): round(float(x), 2) for prn, x in zip(prns, spread)},
            "decidable": bool(np.all(spread >= required_m))}


def _await(peer: LinkPeer, kind: str, timeout_s: float):
    waited = 0.0
    while waited < timeout_s and peer.closed is None:
        msg = peer.wait(1.0)
        waited += 1.0
        if msg is not None and msg[0] == kind:
            return msg[1]
    return None
