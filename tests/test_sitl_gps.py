"""SemperFi as ArduCopter's only GPS (issue 24, item 4): GPS_INPUT accepted by the real autopilot (ArduPilot SITL,
`GPS1_TYPE 14`), its GPS_RAW_INT showing our fix, and no fix while spoofing is suspected. Skipped, saying why, when
../shared/sitl/ is not there."""

import time

import pytest

from semperfi.receiver.fix_stream import FixStream
from semperfi.receiver.gps_input import FIX_3D, MavlinkGpsOut

from semperfi.eval.autopilot import Sitl
from sitl import SITL_BINARY, SITL_DIR
from test_outputs import _fix

pytestmark = pytest.mark.skipif(not (SITL_DIR / "arducopter").exists(), reason=f"no ArduCopter SITL at {SITL_DIR}")
INSTANCE = 8                          # ports 5840-5843: clear of instance 0 and of test_sitl.py's 7
HOME = (-35.3632621, 149.1652374, 584.0)   # SITL's default home (CMAC): the fix we feed it
GPS_RAW_INT_ID = 24


@pytest.fixture(scope="module")
def autopilot(tmp_path_factory):
    sitl = Sitl(INSTANCE, 1.0, tmp_path_factory.mktemp("sitl"), SITL_BINARY, params={"GPS1_TYPE": 14})
    sitl.start()
    try:
        out = None
        for _ in range(50):               # it listens a moment after starting
            try:
                out = MavlinkGpsOut(sitl.url(0))
                break
            except ValueError:
                time.sleep(0.2)
        assert out is not None, "ArduCopter SITL did not listen"
        assert out.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=30) is not None
        out.conn.mav.command_long_send(1, 1, 511, 0, GPS_RAW_INT_ID, 200_000, 0, 0, 0, 0, 0)   # 5 Hz
        yield out
        out.close()
    finally:
        sitl.stop()


def _gps_raw(out, seconds: float):
    """The GPS_RAW_INT the autopilot sent over `seconds`."""
    got, t_end = [], time.monotonic() + seconds
    while time.monotonic() < t_end:
        m = out.conn.recv_match(type="GPS_RAW_INT", blocking=True, timeout=0.2)
        if m is not None:
            got.append(m)
    return got


def test_the_autopilot_takes_our_fix_and_drops_it_while_spoofing_is_suspected(autopilot):
    import threading
    good = _fix(lat_deg=HOME[0], lon_deg=HOME[1], height_m=HOME[2], raim="pass", hpl_m=13.0, vpl_m=20.0,
                h_sigma_m=3.0, v_sigma_m=5.0)
    suspect = _fix(lat_deg=HOME[0] + 0.01, lon_deg=HOME[1], state="spoofing_detected", raim="pass")
    stream = FixStream(autopilot.send)
    current = {"fix": good}
    stop = threading.Event()

    def receiver():   # fixes keep coming, 10 a second, as from the receiver
        while not stop.wait(0.1):
            stream.update(current["fix"])

    feeder = threading.Thread(target=receiver, daemon=True)
    feeder.start()
    try:
        _gps_raw(autopilot, 8.0)          # the autopilot finds its MAVLink GPS and settles
        raw = _gps_raw(autopilot, 2.0)
        assert raw, "no GPS_RAW_INT from the autopilot"
        assert all(m.fix_type == FIX_3D for m in raw), [m.fix_type for m in raw]
        assert all((m.lat, m.lon) == (round(HOME[0] * 1e7), round(HOME[1] * 1e7)) for m in raw)
        assert raw[-1].h_acc == 3000 and raw[-1].satellites_visible == good.n_sats, raw[-1]
        current["fix"] = suspect
        _gps_raw(autopilot, 1.0)
        raw = _gps_raw(autopilot, 2.0)
        assert raw and all(m.fix_type <= 1 for m in raw), [m.fix_type for m in raw]
        assert all(abs(m.lat - round(suspect.lat_deg * 1e7)) > 1000 for m in raw)   # never the suspect position
        current["fix"] = good             # recovered: the true position again at once
        _gps_raw(autopilot, 1.0)
        raw = _gps_raw(autopilot, 1.0)
        assert raw and raw[-1].fix_type == FIX_3D and raw[-1].lat == round(HOME[0] * 1e7)
    finally:
        stop.set()
        feeder.join(2)
        stream.close()
    assert stream.failed == 0
