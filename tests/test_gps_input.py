"""The receiver as an autopilot's GPS (issue 24, item 4): GPS_INPUT fields against the fixes, the stream's schedule,
and no position the autopilot could trust while spoofing is suspected; NMEA to a port likewise."""

import math
import socket

import pytest
from pymavlink.dialects.v20 import common as mav
from pynmeagps import NMEAReader

from semperfi.receiver.fix_stream import BACKLOG, STALE_S, FixStream, Pacer
from semperfi.receiver.gps_input import FIX_3D, FIX_NO_FIX, MavlinkGpsOut, gps_input
from semperfi.receiver.nmea_out import NmeaOut

from test_outputs import LAT_DEG, LON_DEG, TOW_S, WEEK, _fix


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_a_good_fix_is_a_3d_fix_with_its_1_sigma_as_accuracies():
    fix = _fix(vel_east_m_s=4.0, hpl_m=16.5, vpl_m=29.25, h_sigma_m=2.5, v_sigma_m=4.25, raim="pass")
    m = gps_input(fix, 1.7e9)
    assert m.fix_type == FIX_3D and m.satellites_visible == fix.n_sats
    assert m.lat == round(LAT_DEG * 1e7) and m.lon == round(LON_DEG * 1e7) and m.alt == fix.height_m
    assert abs(m.ve - 4.0) < 1e-9 and abs(m.vn) < 1e-9 and abs(m.vd) < 1e-9
    assert m.horiz_accuracy == 2.5 and m.vert_accuracy == 4.25 and (m.hdop, m.vdop) == (fix.hdop, fix.vdop)
    assert m.time_week == WEEK and m.time_week_ms == round(TOW_S * 1e3) and m.time_usec == 1_700_000_000_000_000
    no_levels = gps_input(_fix(), 0.0)   # no integrity computed: accuracy from the DOPs
    assert no_levels.fix_type == FIX_3D and no_levels.horiz_accuracy == pytest.approx(5.0 * _fix().hdop)


@pytest.mark.parametrize("state, raim, fix_type", [
    ("nominal", "pass", FIX_3D), ("nominal", "fail", FIX_NO_FIX), ("unverified", "unverifiable", FIX_NO_FIX),
    ("spoofing_detected", "pass", FIX_NO_FIX), ("recovering", "pass", FIX_NO_FIX), ("recovered", "pass", FIX_3D),
    ("rectified", "excluded", FIX_3D)])
def test_while_spoofing_is_suspected_the_autopilot_gets_no_position(state, raim, fix_type):
    m = gps_input(_fix(state=state, raim=raim, hpl_m=5.0, vpl_m=8.0), 0.0)
    assert m.fix_type == fix_type
    if fix_type == FIX_NO_FIX:
        assert (m.lat, m.lon) == (0, 0) and m.horiz_accuracy >= 9999.0   # nothing it could fuse by mistake


def test_the_schedule_is_absolute_late_sends_do_not_drift_and_a_stall_does_not_burst():
    pacer = Pacer(0.1, 0.0)
    sends = []
    now = 0.0
    for late in [0.0, 0.03, 0.0, 0.07, 0.0, 0.0]:     # sends that ran late by these
        now = max(now, pacer.next_s) + late
        sends.append(now)
        pacer.sent(now)
    assert pacer.next_s == pytest.approx(0.6)          # six periods on: the late ones pushed nothing back
    assert max(b - a for a, b in zip(sends, sends[1:])) <= 0.1 + 0.07 + 1e-9
    pacer.sent(5.0)                                    # a 4 s stall: restart from now, no 40 sends in a row
    assert pacer.wait_s(5.0) == pytest.approx(0.1)


def test_the_stream_sends_each_fix_once_in_order_then_the_last_then_no_fix_once_it_is_stale():
    clock, got = FakeClock(), []
    stream = FixStream(lambda fix, unix_s: got.append(fix), clock=clock, wall=lambda: 0.0, start=False)
    stream.step()
    burst = [_fix(t_rx_s=1.0 + 0.1 * k) for k in range(3)]
    for fix in burst:                                  # a chunk's fixes arrive together
        stream.update(fix)
    for _ in range(4):                                 # one a period, in order, then the last again
        clock.t += 0.1
        stream.step()
    clock.t += STALE_S                                 # the input stalled
    stream.step()
    assert got == [None, *burst, burst[-1], None] and stream.sent == 6


def test_a_backlog_is_bounded_the_newest_fixes_go_out():
    clock, got = FakeClock(), []
    stream = FixStream(lambda fix, unix_s: got.append(fix), clock=clock, wall=lambda: 0.0, start=False)
    fixes = [_fix(t_rx_s=float(k)) for k in range(50)]   # a recording processed faster than real time
    for fix in fixes:
        stream.update(fix)
    for _ in range(BACKLOG + 1):
        stream.step()
    assert got == fixes[-BACKLOG:] + [fixes[-1]]


def test_a_dead_autopilot_link_is_counted_not_raised():
    def refuse(fix, unix_s):
        raise ConnectionRefusedError("gone")
    stream = FixStream(refuse, clock=FakeClock(), start=False)
    stream.step()
    assert stream.failed == 1 and stream.sent == 0


def test_gps_input_over_udp_decodes_to_the_fix():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    out = MavlinkGpsOut(f"udpout:127.0.0.1:{rx.getsockname()[1]}")
    fix = _fix(vel_east_m_s=-2.0, hpl_m=17.0, vpl_m=21.0, h_sigma_m=7.0, v_sigma_m=11.0, raim="pass")
    out.send(fix, 1.7e9)
    out.send(_fix(state="spoofing_detected", raim="pass"), 1.7e9 + 0.1)
    parser = mav.MAVLink(None)
    msgs = [parser.parse_char(rx.recv(1024)) for _ in range(2)]
    out.close()
    rx.close()
    good, suspect = msgs
    assert good.get_type() == "GPS_INPUT" and good.fix_type == FIX_3D
    assert good.lat == round(LAT_DEG * 1e7) and good.lon == round(LON_DEG * 1e7)
    assert math.isclose(good.ve, -2.0, abs_tol=1e-5) and math.isclose(good.horiz_accuracy, 7.0)
    assert good.time_week == WEEK and good.satellites_visible == fix.n_sats
    assert suspect.fix_type == FIX_NO_FIX and suspect.lat == 0


def test_nmea_over_tcp_marks_a_suspected_fix_invalid():
    srv = socket.create_server(("127.0.0.1", 0))
    out = NmeaOut(f"tcp:127.0.0.1:{srv.getsockname()[1]}")
    conn, _ = srv.accept()
    conn.settimeout(5.0)
    out.send(_fix(), 0.0)
    out.send(None, 0.0)                                # nothing while there is no fresh fix
    out.send(_fix(state="recovering"), 0.0)
    out.close()
    data = b""
    while chunk := conn.recv(4096):
        data += chunk
    conn.close()
    srv.close()
    msgs = [NMEAReader.parse(line + b"\r\n") for line in data.split(b"\r\n") if line]
    assert [m.msgID for m in msgs] == ["GGA", "RMC", "GGA", "RMC"]
    assert (msgs[0].quality, msgs[1].status) == (1, "A") and (msgs[2].quality, msgs[3].status) == (0, "V")


@pytest.mark.parametrize("url, word", [("tcp:127.0.0.1:1", "refused"), ("udpin:127.0.0.1:5000", "NMEA goes to"),
                                       ("nowhere", "expected tcp:")])
def test_a_wrong_nmea_address_is_one_error_at_once(url, word):
    with pytest.raises(ValueError, match=word):
        NmeaOut(url)
