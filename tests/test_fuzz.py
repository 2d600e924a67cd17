"""Seeded mutation fuzzing of every input surface (issue 23): whatever arrives, the answer is the input accepted or
one documented error (ValueError at the library level, one line and a non-zero exit at the command line), never
another exception, never a hang, never a dead reader thread.

Each surface starts from a valid input and mutates it with a seeded generator (bytes flipped, inserted, deleted,
duplicated; the input cut anywhere; numbers replaced by extremes; structure nested deep), so the same inputs come
every run. INPUTS_PER_SURFACE says how many each tries.
"""

import io
import math
import random
import socket
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from semperfi.cli import main

from rtl_tcp_server import serve_once

SEED = 23
INPUTS_PER_SURFACE = {"iq file": 120, "sidecar": 200, "rinex": 40, "toml": 200, "set": 400, "imu csv": 200,
                      "stdin": 30, "rtl_tcp": 50, "link frames": 2000, "link stream": 60, "mavlink": 300}
EXTREMES = ["0", "-0", "1e308", "-1e308", "1e-320", "nan", "inf", "-inf", "NaN", "Infinity", "99999999999999999999",
            "-1", "\"\"", "\"x\"", "[]", "{}", "true", "null", "1e12", "2.5e6", "\"" + "A" * 5000 + "\""]


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One to four edits of a byte string."""
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(7)
        i = rng.randrange(len(b) + 1) if b else 0
        if op == 0 and b:                        # flip a byte
            b[min(i, len(b) - 1)] = rng.randrange(256)
        elif op == 1:                            # insert random bytes
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        elif op == 2:                            # delete a slice
            del b[i:i + rng.randint(1, 64)]
        elif op == 3:                            # cut the rest
            del b[i:]
        elif op == 4 and b:                      # duplicate a slice
            j = rng.randrange(len(b))
            b[i:i] = b[j:j + rng.randint(1, 256)]
        elif op == 5:                            # a number replaced by an extreme
            text = b.decode("latin-1")
            digits = [k for k, c in enumerate(text) if c.isdigit()]
            if digits:
                k = rng.choice(digits)
                b = bytearray((text[:k] + rng.choice(EXTREMES) + text[k + 1:]).encode("latin-1"))
        else:                                    # a byte of structure doubled ({[", or a line)
            if b:
                b[i:i] = bytes([b[min(i, len(b) - 1)]]) * rng.randint(1, 3000)
    return bytes(b)


def _one_line_or_ok(result, codes=(0, 2, 3, 4, 5)) -> None:
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert result.exit_code in codes, (result.exit_code, result.output[-500:])
    assert "Traceback" not in result.output
    if result.exit_code:
        errors = [line for line in result.output.splitlines() if line.startswith("semperfi: error")]
        assert len(errors) == 1, result.output[-800:]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """30 ms of simulated int16 samples at 2 MSa/s with their SigMF sidecar."""
    path = tmp_path_factory.mktemp("fuzz") / "rec.bin"
    r = CliRunner().invoke(main, ["sim", "-o", str(path), "--fs", "2e6", "--duration", "0.03"])
    assert r.exit_code == 0, r.output
    return path


def test_fuzzed_iq_files_are_read_or_refused_in_one_line(recording, tmp_path):
    rng = random.Random(SEED)
    raw = recording.read_bytes()[:40_000]
    runner = CliRunner()
    for n in range(INPUTS_PER_SURFACE["iq file"]):
        path = tmp_path / f"m{n}.bin"
        path.write_bytes(mutate(raw, rng))
        fmt = rng.choice(["ishort", "ibyte", "gr_complex", "short", "byte", "iq2", "real4", "cu8", "bogus"])
        fs = rng.choice(["2e6", "2.5e6", "1e3", "4e6"])
        args = ["acquire", str(path), "--fs", fs, "--format", fmt, "--coherent-ms", "1", "--noncoherent", "2",
                "--prn", "1-4"]
        if fmt in ("short", "byte", "real4"):
            args += ["--if", rng.choice(["5e5", "0", "3e6"])]
        _one_line_or_ok(runner.invoke(main, args))


def test_fuzzed_sigmf_sidecars_are_read_or_refused_in_one_line(recording, tmp_path):
    rng = random.Random(SEED)
    meta = recording.with_suffix(".sigmf-meta").read_bytes()
    data = recording.read_bytes()[:40_000]
    runner = CliRunner()
    for n in range(INPUTS_PER_SURFACE["sidecar"]):
        path = tmp_path / f"s{n}.bin"
        path.write_bytes(data)
        text = mutate(meta, rng)
        if n % 10 == 9:   # nested deep, the way a hostile file would
            text = b'{"global": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
        path.with_suffix(".sigmf-meta").write_bytes(text)
        _one_line_or_ok(runner.invoke(main, ["acquire", str(path), "--coherent-ms", "1", "--noncoherent", "2",
                                             "--prn", "1-2"]))


def test_fuzzed_rinex_navigation_files_are_read_or_refused(tmp_path, brdc_path):
    from semperfi.iq.rinex import read_rinex_nav
    rng = random.Random(SEED)
    lines = Path(brdc_path).read_bytes().splitlines(keepends=True)[:120]   # the header and ~14 records
    for n in range(INPUTS_PER_SURFACE["rinex"]):
        path = tmp_path / f"n{n}.22n"
        path.write_bytes(b"".join(lines[:8]) + mutate(b"".join(lines[8:]), rng))
        try:
            nav = read_rinex_nav(path)
        except ValueError:
            continue
        for eph in nav.ephemerides:   # what is accepted is physically plausible
            assert 4000 < eph.sqrt_a_sqrt_m < 6000 and math.isfinite(eph.toe_s)


def test_fuzzed_toml_and_set_overrides_are_taken_or_refused(tmp_path):
    from semperfi.defense.config import DEFAULTS as DEFENSE
    from semperfi.defense.config import load_config
    from semperfi.sim.scenario import load_scenario
    rng = random.Random(SEED)
    good = (b'[acquisition]\ncoherent_ms = 2\npfa = 1e-3\n[tracking]\npll_bw_hz = 18.0\n'
            b'[defense]\nmode = "full"\n')
    for n in range(INPUTS_PER_SURFACE["toml"]):
        path = tmp_path / f"c{n}.toml"
        path.write_bytes(mutate(good, rng))
        for load in (lambda: load_config(str(path), []), lambda: load_scenario(str(path), [])):
            try:
                load()
            except ValueError:
                pass
    keys = ["acquisition.pfa", "acquisition.prns", "tracking.channels", "defense.mode", "signal.fs_hz",
            "signal.noise_rms", "attacker.power_advantage_db", "time.duration_s", "pvt.rate_hz", "nosuch.key",
            "acquisition", "a.b.c.d", "", "defense.separation_ns", *(f"defense.{k}" for k in list(DEFENSE)[:8])]
    values = EXTREMES + ["[1, 2]", '"full"']
    for _ in range(INPUTS_PER_SURFACE["set"]):
        item = rng.choice(keys) + rng.choice(["=", "==", "", "=="]) + rng.choice(values)
        for load in (lambda: load_config(None, [item]), lambda: load_scenario(None, [item])):
            try:
                load()
            except ValueError:
                pass


def test_fuzzed_imu_tracks_are_read_or_refused(tmp_path):
    from semperfi.defense.imu_track import find_maneuver, read_imu_csv
    rng = random.Random(SEED)
    t = np.arange(0, 30, 0.02)
    good = "t_s,north_m,east_m,down_m\n" + "".join(
        f"{x:.3f},{5 * np.sin(x / 3):.3f},{2 * x:.3f},0.0\n" for x in t)
    for n in range(INPUTS_PER_SURFACE["imu csv"]):
        path = tmp_path / f"i{n}.csv"
        path.write_bytes(mutate(good.encode(), rng))
        try:
            track = read_imu_csv(path)
        except ValueError:
            continue
        try:
            find_maneuver(track)
        except ValueError:
            pass


def test_fuzzed_standard_input_is_processed_or_refused_in_one_line(recording, tmp_path):
    rng = random.Random(SEED)
    raw = recording.read_bytes()
    runner = CliRunner()
    for n in range(INPUTS_PER_SURFACE["stdin"]):
        cmd = rng.choice(["run", "clean"])
        out = ["--out", str(tmp_path / f"o{n}")] if cmd == "run" else ["-o", str(tmp_path / f"c{n}.bin")]
        result = runner.invoke(main, [cmd, "-", "--fs", "2e6", "--format", rng.choice(["ishort", "ibyte"]), *out],
                               input=mutate(raw, rng))
        _one_line_or_ok(result)


def test_fuzzed_rtl_tcp_servers_are_read_or_refused():
    from semperfi.iq.source import SampleSource
    rng = random.Random(SEED)
    good = b"RTL0" + struct.pack(">II", 5, 29) + bytes(rng.randrange(256) for _ in range(20_000))
    for _ in range(INPUTS_PER_SURFACE["rtl_tcp"]):
        hostile = mutate(good, rng)
        port, _, _ = serve_once(hostile[12:], header=hostile[:12], close_after=len(hostile))
        t0 = time.monotonic()
        try:
            source = SampleSource(f"rtl_tcp://127.0.0.1:{port}", fs_hz=1.2e6)
            source._input.source.timeout_s = 0.3
            for _chunk in source.chunks(0.005):
                pass
            source.close()
        except ValueError:
            pass
        assert time.monotonic() - t0 < 5.0, "a hostile rtl_tcp server held the reader"


def test_fuzzed_link_frames_are_rejected_never_raised_otherwise():
    from semperfi.flight.link import Codec, LinkError
    rng = random.Random(SEED)
    tx, rx = Codec(b"k" * 32), Codec(b"k" * 32)
    payloads = [("alarm", {"reason": "x", "t_s": 1.0, "lines_of_sight": [{"prn": 3, "az_deg": 10.0, "el_deg": 40.0}],
                           "required_spread_m": 12.0}),
                ("maneuver_done", {"maneuver_id": "m", "t_s": [0.0, 1.0], "north_m": [0.0, 1.0],
                                   "east_m": [0.0, 1.0], "down_m": [0.0, 0.0]}),
                ("verdict", {"maneuver_id": "m", "failed": None, "adversarial": True, "peaks": []})]
    accepted = 0
    for n in range(INPUTS_PER_SURFACE["link frames"]):
        kind, payload = payloads[n % len(payloads)]
        frame = tx.encode(kind, payload)[4:]       # without the length prefix: the decoder's input
        try:
            rx.decode(mutate(frame, rng))
            accepted += 1
        except LinkError:
            pass
    assert rx.rejected >= INPUTS_PER_SURFACE["link frames"] - accepted - 5


def test_fuzzed_link_streams_close_the_link_or_are_rejected_never_kill_the_reader():
    from semperfi.flight.link import Codec, LinkPeer
    rng = random.Random(SEED)
    key = b"k" * 32
    good = Codec(key).encode("maneuver_request", {"maneuver_id": "m"})
    for _ in range(INPUTS_PER_SURFACE["link stream"]):
        srv = socket.create_server(("127.0.0.1", 0))
        peer = LinkPeer.connect("127.0.0.1", srv.getsockname()[1], key)
        conn, _ = srv.accept()
        conn.sendall(mutate(good * 3, rng))
        conn.close()
        srv.close()
        deadline = time.monotonic() + 5
        while peer.closed is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert peer.closed is not None, "the reader neither ended the link nor saw the peer go"
        peer._reader.join(2)
        assert not peer._reader.is_alive()
        peer.close()


def test_fuzzed_mavlink_from_a_hostile_vehicle_is_a_pilot_error():
    """A 'vehicle' that answers with garbage and mutated MAVLink: the pilot gives up with PilotError (one line at
    the command line), never another exception, within its timeout."""
    from pymavlink.dialects.v20 import common as mav

    from semperfi.flight.maneuver import ManeuverLimits, draw
    from semperfi.flight.mavlink_pilot import Pilot, PilotError
    rng = random.Random(SEED)
    encoder = mav.MAVLink(io.BytesIO(), srcSystem=1, srcComponent=1)
    templates = [
        mav.MAVLink_heartbeat_message(2, 3, 0x81, 4, 4, 3),
        mav.MAVLink_command_ack_message(176, 0),
        mav.MAVLink_attitude_message(1000, 0.1, 0.0, 1.0, 0.0, 0.0, 0.0),
        mav.MAVLink_local_position_ned_message(1000, 0.0, 0.0, -50.0, 0.0, 0.0, 0.0),
        mav.MAVLink_scaled_imu_message(1000, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 0),
    ]
    frames = [t.pack(encoder) for t in templates]
    maneuver = draw(ManeuverLimits(), rng=random.Random(1))
    sent = 0
    for round_ in range(3):
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
        probe.close()
        pilot = Pilot(f"udpin:127.0.0.1:{port}", timeout_s=1.0)
        stop = threading.Event()
        out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

        def flood():
            nonlocal sent
            while not stop.is_set() and sent < INPUTS_PER_SURFACE["mavlink"] * (round_ + 1) // 3:
                frame = rng.choice(frames)
                out.sendto(mutate(frame, rng) if rng.random() < 0.8 else frame, ("127.0.0.1", port))
                sent += 1
                time.sleep(0.003)
        thread = threading.Thread(target=flood, daemon=True)
        thread.start()
        t0 = time.monotonic()
        try:
            with pytest.raises(PilotError):
                pilot.fly(maneuver)
        finally:
            stop.set()
            thread.join(2)
            pilot.close()
            out.close()
        assert time.monotonic() - t0 < 60.0
    assert sent >= INPUTS_PER_SURFACE["mavlink"] * 2 // 3
