"""The defence on a recording from a generator nobody here wrote: GPS-SDR-SIM's legitimate and spoofer scenes on the
same GPS time (a synchronized attacker), mixed with our own calibrated noise. Runs when gps-sdr-sim is on PATH."""

import numpy as np
import pytest

from semperfi.eval.xgen import PLACES, Case, gps_sdr_sim_path, prepare, run_case
from semperfi.iq import open_iq
from semperfi.receiver.acquisition import DopplerGrid, acquire

pytestmark = pytest.mark.skipif(gps_sdr_sim_path() is None,
                                reason="gps-sdr-sim is not on PATH (build github.com/osqzss/gps-sdr-sim with one gcc "
                                       "line and put it on PATH to run the cross-generator checks)")


def test_the_mix_puts_gps_sdr_sim_satellites_at_the_c_n0_asked_for(tmp_path, brdc_path):
    case = Case(PLACES["boston"], 0.0, 0.0, duration_s=1.0, attacker=False, cn0_dbhz=45.0)
    x = open_iq(prepare(case, brdc_path, tmp_path)).read(0, int(0.2 * case.fs_hz))
    cafs = acquire(x, case.fs_hz, range(1, 33), DopplerGrid(0.0, 6000.0, 50.0), coherent_ms=10, noncoherent=20)
    cn0 = [c.best.cn0_dbhz for c in cafs.values() if c.best is not None and c.best.metric > 100]
    assert len(cn0) >= 6, f"{len(cn0)} satellites acquired"
    assert abs(np.median(cn0) - 45.0) < 2.0, f"C/N0 of the acquired satellites: {np.round(cn0, 1)}"


def test_a_synchronized_attack_from_another_generator_is_recovered(tmp_path, brdc_path):
    case = Case(PLACES["boston"], 1000.0, 6.0, duration_s=22.0)
    r = run_case(case, brdc_path, tmp_path)
    print(r)
    assert r["called_good_but_wrong"] == 0, r
    assert r["recovered"] > 0 and r["last_state"] == "recovered", r
    assert r["last_mean_m"] < 5.0, r
