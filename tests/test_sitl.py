"""Claims about the flight side on a real autopilot, ArduCopter SITL (../shared/sitl beside the repository; skipped
when it is not there): it asks for the streams it reads and gets them at their rates, it refuses a vehicle that is
disarmed on the ground without touching it, and the inertial track of a maneuver it flies ends within 2 m of the
simulator's truth (SIM_STATE, read by the test, never by the product), the vehicle given back to its mode; with the
GPS switched off (as while SemperFi withholds the position) the maneuver is flown in GUIDED_NOGPS, its track within
the looser bound the flight side then states, and the mode given back once the GPS is on again.

One SITL instance (-I7: TCP 5830/5832) serves the module, at --speedup 5; the maneuver is seeded."""

import random
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import common as mav

from semperfi.eval.autopilot import CRUISE_S, GUIDED, Observer, Sitl
from sitl import SITL_BINARY, SITL_DIR, sitl_fly

pytest.importorskip("pymavlink", reason="pymavlink is not installed")
pytest.importorskip("pymap3d", reason="pymap3d is not installed")

pytestmark = pytest.mark.skipif(not (SITL_DIR / "arducopter").exists(),
                                reason=f"no ArduCopter SITL at {SITL_DIR}")
INSTANCE, SPEEDUP, ALTITUDE_M = 7, 5.0, 30.0
BRAKE = 17   # holds where it is without a pilot (LOITER would follow SITL's throttle stick, down)


@pytest.fixture(scope="module")
def sitl(tmp_path_factory):
    script = sitl_fly()
    s = Sitl(INSTANCE, SPEEDUP, tmp_path_factory.mktemp("sitl"), SITL_BINARY).start()
    try:
        obs = Observer(s.url(0), speedup=SPEEDUP)
        obs.streams(extra=(mav.MAVLINK_MSG_ID_GPS_RAW_INT,))
    except BaseException:
        s.stop()
        raise
    yield script, s, obs
    obs.close()
    s.stop()


def test_a_disarmed_vehicle_on_the_ground_is_refused_and_left_alone(sitl):
    _, s, obs = sitl
    result = subprocess.run([sys.executable, "-m", "semperfi.cli", "fly", "--vehicle", s.url(1)],
                            check=False, capture_output=True, text=True, timeout=120)
    assert result.returncode != 0, result.stdout
    err = result.stderr.strip()
    assert err.count("\n") == 0 and "Traceback" not in err and "disarmed" in err, err
    hb = obs.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
    assert hb is not None and hb.custom_mode != 4, "the flight side did not switch a grounded vehicle to GUIDED"


def test_the_streams_asked_for_come_at_their_rates(sitl):
    from semperfi.flight.mavlink_pilot import Pilot
    from semperfi.flight.telemetry import STREAMS_HZ
    _, s, obs = sitl
    obs.arm()   # a vehicle ready to arm has a position to stream (it disarms itself again on the ground)
    pilot = Pilot(s.url(1), timeout_s=60)   # a position streams once the EKF has its origin
    try:
        pilot.connect()
        pilot.request_streams()
        assert pilot.imu_stream == "HIGHRES_IMU", "ArduCopter gives float IMU samples"
        counts = dict.fromkeys(STREAMS_HZ, 0)
        t0_s = t_s = None   # vehicle time, from the messages that carry it
        deadline = time.monotonic() + 30
        while (t_s is None or t_s - t0_s < 4.0) and time.monotonic() < deadline:
            msg = pilot._next(time.monotonic() + 10, "stream", time.monotonic())   # what its reader took in
            if msg.get_type() not in STREAMS_HZ:
                continue
            if hasattr(msg, "time_boot_ms"):
                t_s = msg.time_boot_ms / 1000.0
                t0_s = t_s if t0_s is None else t0_s
            if t0_s is not None:
                counts[msg.get_type()] += 1
    finally:
        pilot.close()
    for name, hz in STREAMS_HZ.items():
        rate = counts[name] / (t_s - t0_s)
        assert 0.7 * hz < rate < 1.3 * hz, f"{name} at {rate:.1f} Hz of vehicle time (asked {hz:g} Hz): {counts}"


def test_a_maneuver_flown_on_arducopter_is_tracked_within_2_m_by_the_imu(sitl):
    script, s, obs = sitl
    obs.takeoff(ALTITUDE_M)
    obs.set_mode(BRAKE)   # the flight side must give it back to BRAKE
    assert obs.wait_mode(BRAKE)
    time.sleep(CRUISE_S / SPEEDUP)   # cruising, not just off the takeoff: the EKF has settled
    row = script.fly_one(s.url(1), obs, rng=random.Random(11))
    assert obs.wait_mode(BRAKE), f"left in mode {obs.custom_mode}"
    m = row["maneuver"]
    assert m.duration_s >= 10.0 and row["height_m"] > 25.0
    assert min(row["height_m"] - m.down_m) >= 10.0, "drawn for the height it flies at"
    assert row["plan_vs_flown_end_m"] < 4.0, row["plan_vs_flown_end_m"]   # ArduCopter lags a plan by 0.2-2.8 m
    assert row["ins_end_error_m"] <= 2.0 and row["ins_max_error_m"] <= 2.0, \
        (f"INS ends {row['ins_end_error_m']:.2f} m from SIM_STATE (max {row['ins_max_error_m']:.2f} m) after "
         f"{row['track_s']:.1f} s")


def test_without_gps_the_maneuver_is_flown_in_guided_nogps_and_the_mode_given_back(sitl):
    script, s, obs = sitl
    if not (obs.height_m or 0.0) > 5.0:
        obs.takeoff(ALTITUDE_M)
    obs.set_mode(GUIDED)   # after the other maneuver it holds in BRAKE, which takes no position target
    assert obs.wait_mode(GUIDED)
    obs.climb_to(ALTITUDE_M)
    obs.set_mode(BRAKE)
    assert obs.wait_mode(BRAKE)
    time.sleep(2.0 / SPEEDUP)
    row = script.fly_one(s.url(1), obs, rng=random.Random(12), without_gps=True)
    flown = row["flown"]
    assert flown.without_gps, "the autopilot had no GPS: GUIDED_NOGPS"
    assert flown.ins_age_s > 2.0, "its INS started on the GPS-aided flight the flight side watched before"
    assert obs.wait_mode(BRAKE), f"left in mode {obs.custom_mode} (BRAKE needs the position back first)"
    assert obs.height_m > 15.0, f"the vehicle came down to {obs.height_m:.1f} m (the EKF failsafe lands in GUIDED)"
    assert row["plan_vs_flown_end_m"] < 8.0, row["plan_vs_flown_end_m"]   # steered by the INS: 0.2-4.8 m measured
    assert row["ins_end_error_m"] <= flown.error_bound_m, \
        (f"INS ends {row['ins_end_error_m']:.2f} m from SIM_STATE after {row['track_s']:.1f} s, its stated bound "
         f"{flown.error_bound_m:.1f} m")
