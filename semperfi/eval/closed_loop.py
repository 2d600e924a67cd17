"""The closed loop, end to end, in three processes as on a UAV: the world (vehicle behind MAVLink + GPS signals with
an attacker, `semperfi world`), the receiver (`semperfi run -` reading the world's samples, with the link), and the
flight side (`semperfi companion`: the link server, flying maneuvers over MAVLink). The world's samples reach the
receiver through a pipe; the receiver and the flight side talk over the authenticated link (TCP, a fresh random
key); the flight side commands the vehicle over MAVLink (UDP).

run_closed_loop() starts them, waits, and returns what happened: the flight side's report (maneuver, IMU track,
verdict), the receiver's events and fixes, and the vehicle's true track.
"""

from __future__ import annotations

import csv
import json
import os
import secrets
import socket
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pymap3d

from ..sim import load_scenario
from .metrics import errors

CLOSED_LOOP_SETTINGS = ["attacker.enabled=true", "attacker.power_advantage_db=6.0", "attacker.offset_east_m=1000.0",
                        "signal.fs_hz=2e6", 'signal.format="ishort"', "constellation.max_satellites=8"]


@dataclass
class ClosedLoop:
    out_dir: Path
    flight: list[dict] = field(default_factory=list)     # the companion's JSON lines
    events: list[dict] = field(default_factory=list)     # the receiver's events.jsonl
    fixes: list[dict] = field(default_factory=list)      # the receiver's fixes.csv rows
    truth: list[dict] = field(default_factory=list)      # the world's vehicle track
    receiver_stdout: str = ""
    errors: list[str] = field(default_factory=list)

    @classmethod
    def load(cls, out_dir: str | Path) -> "ClosedLoop":
        """What a finished run left in out_dir: the flight side's report, the receiver's events and fixes, the truth."""
        out = Path(out_dir)
        result = cls(out)
        paths = {"flight": out / "flight.jsonl", "events": out / "receiver" / "events.jsonl"}
        for name, path in paths.items():
            if path.exists():
                setattr(result, name, [json.loads(line) for line in open(path) if line.strip()])
        for name, path in (("fixes", out / "receiver" / "fixes.csv"), ("truth", out / "truth.csv")):
            if path.exists():
                setattr(result, name, list(csv.DictReader(open(path))))
        return result

    def first(self, kind: str, source: str = "events") -> dict | None:
        return next((e for e in getattr(self, source) if e.get("event") == kind), None)

    def fix_levels_m(self, state: str | None = None) -> np.ndarray:
        """The horizontal protection level of each fix (of one state), in fix_errors_m's order; a fix without one
        bounds nothing (0)."""
        rows = [r for r in self.fixes if state is None or r["state"] == state]
        return np.nan_to_num(np.array([float(r.get("hpl_m") or "nan") for r in rows]), nan=0.0)

    def fix_errors_m(self, state: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(t_rx_s, horizontal error) of each fix (of one state) against the vehicle's true position at its time."""
        if not self.fixes or not self.truth:
            return np.empty(0), np.empty(0)
        t_truth = np.array([float(r["t_s"]) for r in self.truth])
        rows = [r for r in self.fixes if state is None or r["state"] == state]
        t = np.array([float(r["t_rx_s"]) for r in rows])
        true = np.column_stack(pymap3d.geodetic2ecef(*(np.interp(t, t_truth, [float(r[k]) for r in self.truth])
                                                       for k in ("lat_deg", "lon_deg", "height_m"))))
        pos = np.array([[float(r[k]) for k in ("x_m", "y_m", "z_m")] for r in rows]).reshape(-1, 3)
        return t, errors(pos, true).horizontal_m


def _free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_closed_loop(out_dir: str | Path, duration_s: float, sets: list[str] = (), nav_path: str | None = None,
                    timeout_s: float = 1800.0, tee: bool = False, show: bool = False, seed: int = 0,
                    maneuver_seed: int | None = None) -> ClosedLoop:
    """tee: the world also keeps its samples in out_dir/world.bin (a conventional receiver can run on them).
    show: the receiver draws its live channel table on this process's terminal (its errors then go there too).
    seed: the vehicle's (wind, IMU errors) and the signals' noise; the maneuver is the OS's cryptographic draw,
    unless maneuver_seed (tests only: a seeded maneuver is predictable) makes it repeatable."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    key_path = out / "link.key"
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(32))
    mavlink_port, link_port = _free_port(socket.SOCK_DGRAM), _free_port()
    scenario = [*CLOSED_LOOP_SETTINGS, f"time.duration_s={duration_s}", f"signal.seed={seed + 1}", *sets]
    if nav_path:
        scenario += [f'constellation.rinex="{nav_path}"']
    me = [sys.executable, "-m", "semperfi.cli"]
    flight = subprocess.Popen(me + ["companion", "--port", str(link_port), "--link-key", str(key_path),
                                    "--vehicle", f"udpout:127.0.0.1:{mavlink_port}",
                                    *(["--test-seed", str(maneuver_seed)] if maneuver_seed is not None else [])],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    errors, receiver_stdout = [], ""
    try:
        if flight.stdout.readline().find('"listening"') < 0:
            raise RuntimeError(f"the flight side did not start: {flight.stderr.read()[-500:]}")
        world = subprocess.Popen(me + ["world", "--mavlink-port", str(mavlink_port), "--truth", str(out / "truth.csv"),
                                       "--seed", str(seed),
                                       *(["--tee", str(out / "world.bin")] if tee else []),
                                       *sum((["--set", s] for s in scenario), [])],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        signal = load_scenario(None, scenario)["signal"]   # what the world writes, whatever `sets` changed
        receiver_args = ["run", "-", "--fs", repr(signal["fs_hz"]), "--format", signal["format"],
                         "--if", repr(signal["if_hz"]), "--out", str(out / "receiver"),
                         "--link", f"127.0.0.1:{link_port}", "--link-key", str(key_path)]
        if nav_path:
            receiver_args += ["--nav", str(nav_path)]
        receiver = subprocess.run(me + receiver_args, stdin=world.stdout, stdout=subprocess.PIPE,
                                  stderr=None if show else subprocess.PIPE, text=True, timeout=timeout_s)
        world.stdout.close()
        world_err = world.communicate(timeout=60)[1].decode(errors="replace")
        receiver_stdout = receiver.stdout
        for name, code, err in (("receiver", receiver.returncode, receiver.stderr), ("world", world.returncode,
                                                                                    world_err)):
            if code not in (0, None) and err and err.strip():
                errors.append(f"{name}: {err.strip().splitlines()[-1]}")
    finally:
        try:
            flight_out, flight_err = flight.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            flight.kill()
            flight_out, flight_err = flight.communicate()
    flight_report = [json.loads(line) for line in flight_out.splitlines() if line.startswith("{")]
    (out / "flight.jsonl").write_text("".join(json.dumps(e) + "\n" for e in flight_report))
    if flight.returncode and flight_err.strip():
        errors.append(f"flight: {flight_err.strip().splitlines()[-1]}")
    result = ClosedLoop.load(out)
    result.receiver_stdout, result.errors = receiver_stdout, errors
    return result
