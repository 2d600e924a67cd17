"""The plug-in fingerprint reads what an unmodified receiver measured on clean's output against the clean scene."""

import numpy as np
import pytest

from script_modules import load_script
from semperfi.eval.plugin import SPOOFED_M, Ranges, range_differences, read_ranges
from semperfi.receiver.rinex_obs import ObsEpoch, write_rinex_obs

T0_S = 2190 * 604800.0 + 518400.0          # 1 Jan 2022 00:00 GPS, seconds since the GPS epoch
CLOCK_M = np.linspace(0.0, 300.0, 50)      # the cleaned run's clock walks away from the reference's


def _ranges(bias_m: dict[int, float], clock_m=0.0, seed: int = 0) -> dict[int, Ranges]:
    rng = np.random.default_rng(seed)
    t = T0_S + 0.1 * np.arange(CLOCK_M.size)
    return {prn: Ranges(t, 2.0e7 + 1e5 * prn + b + clock_m + rng.normal(0.0, 0.01, t.size), np.full(t.size, 42.0))
            for prn, b in bias_m.items()}


def test_each_prns_bias_is_measured_apart_from_the_clocks_and_the_lost_and_spoofed_ones_are_named():
    reference = _ranges({p: 0.0 for p in (2, 5, 7, 9, 12, 15, 20)})
    cleaned = _ranges({2: 0.0, 5: 0.0, 7: 3.0, 9: 0.0, 12: -1.5, 15: 900.0}, CLOCK_M, seed=1)
    d = range_differences(reference, cleaned)
    assert d[7]["mean_m"] == pytest.approx(3.0, abs=0.05) and d[7]["status"] == "twin"
    assert d[12]["mean_m"] == pytest.approx(-1.5, abs=0.05)
    assert max(abs(d[p]["mean_m"]) for p in (2, 5, 9)) < 0.05
    assert d[15]["status"] == "spoofed" and d[15]["mean_m"] > SPOOFED_M
    assert d[20]["status"] == "absent" and d[20]["epochs"] == 0
    assert d[7]["epochs"] == CLOCK_M.size


def test_only_the_epochs_after_from_s_are_compared():
    reference = _ranges({p: 0.0 for p in (2, 5, 7)})
    cleaned = _ranges({2: 0.0, 5: 0.0, 7: 4.0}, seed=1)
    late = range_differences(reference, cleaned, from_s=T0_S + 2.0)
    assert late[7]["epochs"] == CLOCK_M.size - 20


def test_our_rinex_observations_read_back_per_prn(tmp_path):
    epochs = [ObsEpoch(2190, 518400.0 + 0.1 * k,
                       {5: (2.1e7 + k, np.nan, -1200.0, 41.5), 9: (2.2e7, np.nan, 300.0, 38.0)})
              for k in range(5)]
    ranges = read_ranges(write_rinex_obs(tmp_path / "o.rnx", epochs))
    assert sorted(ranges) == [5, 9]
    np.testing.assert_allclose(ranges[5].range_m, 2.1e7 + np.arange(5), atol=1e-3)
    np.testing.assert_allclose(ranges[5].t_s, T0_S + 0.1 * np.arange(5), atol=1e-6)
    assert ranges[9].cn0_dbhz[0] == pytest.approx(38.0)


def test_the_twin_summary_reads_each_prns_first_stage_from_cleans_report():
    """What the plug-in grid tabulates per PRN: the first stage's twin as last measured and the median of its
    attenuation windows, a lower bound counting as its value; a PRN without a twin or a window says None."""
    from semperfi.eval.plugin import twin_summary
    report = {7: [{"stage": 0, "attenuation_db": [">=33.8", 20.1, 25.2], "legit_offset_chips": -0.378,
                   "twin_advantage_db": 10.9}, {"stage": 1, "attenuation_db": [">=16.8"]}],
              13: [{"stage": 0, "attenuation_db": [], "legit_offset_chips": 1.256}]}
    assert twin_summary(report) == {"7": {"offset_chips": -0.378, "advantage_db": 10.9, "attenuation_db": 25.2},
                                    "13": {"offset_chips": 1.256, "advantage_db": None, "attenuation_db": None}}


def test_the_grid_holds_gnss_sdrs_runs_on_the_recordings_without_an_attacker_to_the_same_test():
    """A cell fails when any GNSS-SDR run on its cleaned file does (first fix held to the median of the runs
    without an attacker); over the grid, the runs on the recordings without an attacker are counted by the same
    test against their own median, so a first fix that comes late on files nobody cleaned shows as often."""
    grid = load_script("plugin-grid")

    def run(first_fix_s, last_m=2.5, epochs=0.99):
        return {"fixes": 240, "first_fix_s": first_fix_s, "last_mean_m": last_m, "epochs_fixed": epochs}
    ours = {"semperfi --defense off": {"cleaned": {"fixes": 478, "last_mean_m": 0.2}}}
    late_cleaned = {"case": "a", "fixes": ours, "gnss_sdr_runs": {"reference": [run(35.1), run(35.2), run(53.1)],
                                                                    "cleaned": [run(35.2), run(53.2), run(35.1)]}}
    good = {"case": "b", "fixes": ours, "gnss_sdr_runs": {"reference": [run(35.1), run(35.1), run(35.2)],
                                                            "cleaned": [run(35.2), run(35.1), run(35.3, epochs=0.96)]}}
    far = {"case": "c", "fixes": ours, "gnss_sdr_runs": {"reference": [run(35.1)], "cleaned": [run(35.1, last_m=5.5)]}}
    assert [grid.verdict(c) for c in (late_cleaned, good, far)] == ["FAIL", "pass", "FAIL"]
    assert grid.runs_passing([late_cleaned, good, far, {"case": "d", "error": "x"}]) == {
        "cleaned": (5, 7), "reference": (6, 7)}


GNSS_SDR_CONSOLE = """Tracking of GPS L1 C/A signal started on channel 0 for satellite GPS PRN 01 (Block IIF)
Loss of lock in channel 0!
Tracking of GPS L1 C/A signal started on channel 5 for satellite GPS PRN 07 (Block IIR-M)
Tracking of GPS L1 C/A signal started on channel 0 for satellite GPS PRN 10 (Block IIF)
GPS L1 C/A tracking bit synchronization locked in channel 5 for satellite GPS PRN 07 (Block IIR-M)
Loss of lock in channel 5!
Loss of lock in channel 0!
Loss of lock in channel 9!
Tracking of GPS L1 C/A signal started on channel 5 for satellite GPS PRN 07 (Block IIR-M)
Loss of lock in channel 5!
"""


def test_gnss_sdrs_losses_of_lock_are_counted_per_satellite_its_channel_held(tmp_path):
    """A loss names a channel: it counts for the satellite that channel last started tracking (a channel reused
    for another satellite counts for the new one; a channel never started counts for none)."""
    from semperfi.eval.gnss_sdr import lock_losses
    log = tmp_path / "gnss-sdr.log"
    log.write_text(GNSS_SDR_CONSOLE)
    assert lock_losses(log) == {1: 1, 7: 2, 10: 1}
    assert lock_losses(tmp_path / "absent.log") == {}


def test_the_grid_counts_gnss_sdrs_losses_of_lock_on_the_scenes_satellites_only():
    """Per PRN over the runs, and over the grid on the satellites the scene holds (every one spoofed, so cancelled):
    a false acquisition of a PRN not in the sky loses its lock on any file and counts for neither."""
    grid = load_script("plugin-grid")
    cell = {"case": "a", "cancelled": [7, 10],
            "gnss_sdr_runs": {"cleaned": [{"lock_losses": {"7": 2, "3": 4}}, {"lock_losses": {"10": 1}}],
                              "reference": [{"lock_losses": {}}, {"lock_losses": {"7": 1}}]}}
    assert (grid.lock_losses(cell, "cleaned", "7"), grid.lock_losses(cell, "reference", "7")) == (2, 1)
    assert grid.lock_losses({"case": "b", "gnss_sdr_runs": {"cleaned": [{"fixes": 0}]}}, "cleaned", "7") is None
    assert grid.losses_over_grid([cell]) == {"cleaned": 3, "reference": 1}


def test_the_grid_says_how_many_satellites_gnss_sdr_observed_over_its_runs():
    """The fewest to the most over the runs on the cleaned file, then on the scene without an attacker; '-' for runs
    that did not count them (cells read back from an older cells.jsonl)."""
    grid = load_script("plugin-grid")
    cell = {"case": "a", "gnss_sdr_runs": {"cleaned": [{"satellites": 6}, {"satellites": 8}],
                                           "reference": [{"satellites": 7}, {"satellites": 7}]}}
    assert grid.satellites(cell) == "6-8, 7"
    assert grid.satellites({"case": "b", "gnss_sdr_runs": {"cleaned": [{"fixes": 0}]}}) == "-, -"


@pytest.mark.parametrize("front_end_hz", [0.0, 1e6])
def test_the_residual_profile_reads_what_clean_left_of_a_spoofer_at_its_lag_also_behind_a_front_end(
        tmp_path, monkeypatch, front_end_hz):
    """A 'cleaned' file that is the reference mix (the same noise) plus the spoofer 26 dB down: its profile holds
    5 % of the spoofer at lag 0, in phase with it, and the twin where it was put -- the scenes, rendered faster behind
    a front end, read through the same front end as the mix."""
    from signals import ca_signal
    from semperfi.eval import xgen
    from semperfi.eval.plugin import residual_profile
    from dataclasses import replace
    case = xgen.Case(xgen.PLACES["boston"], 500.0, 6.0, duration_s=0.3, front_end_hz=front_end_hz)
    fast = xgen.rendered(case)
    t = np.arange(int(round(case.duration_s * fast.fs_hz))) / fast.fs_hz
    scenes = []
    for name, chips in (("legit", 300.5), ("spoof", 300.0)):   # the twin half a chip after its spoofer
        z = ca_signal(11, t, chips, 1200.0, xgen.AMPLITUDE)
        path = tmp_path / f"{name}.bin"
        np.column_stack([z.real, z.imag]).round().astype(np.int16).tofile(path)
        scenes.append(path)
    monkeypatch.setattr(xgen, "scenes", lambda *a: tuple(scenes))
    monkeypatch.setattr(xgen, "prepare", lambda c, *a: xgen.mix(scenes[0], None, tmp_path / "reference.bin", c))
    residue_db = -26.0
    cleaned = xgen.mix(*scenes, tmp_path / "cleaned.bin", replace(case, advantage_db=case.advantage_db + residue_db))
    p = residual_profile(case, "", tmp_path, cleaned, 11, 0.05, span_s=0.1)
    at_zero = int(np.argmin(np.abs(p.lags_chips)))
    assert p.twin_offset_chips == pytest.approx(0.5, abs=0.2)
    assert abs(p.spoofer_coherent[at_zero]) == pytest.approx(10 ** (residue_db / 20), rel=0.05)
    assert abs(np.angle(p.spoofer_coherent[at_zero])) < 0.05
    assert np.argmax(p.rms) == at_zero


def test_gnss_sdrs_score_counts_only_true_fixes_and_its_longest_gap_from_its_first_fix():
    """10 Hz fixes from 35 s to the end of a 60 s recording: a 3 s hole at 40 s and 2 s of fixes 50 m off at
    50 s. Every epoch with a fix counts for epochs_fixed; only the true ones for true_fixed; the longest gap is
    the hole, the wrong stretch being shorter."""
    from semperfi.eval import xgen
    from semperfi.eval.crosscheck import GPS_UTC_LEAP_S
    from semperfi.eval.gnss_sdr import Fix
    from semperfi.eval.plugin import _gnss_sdr_score
    case = xgen.Case(xgen.PLACES["boston"], 500.0, 6.0, date="2022/01/01,00:00:13", duration_s=60.0)
    place = case.place
    north_deg_per_m = 1.0 / 111_111.0
    fixes = []
    for k in range(350, 600):
        t_s = k / 10.0
        if 40.0 <= t_s < 43.0:
            continue
        off_m = 50.0 if 50.0 <= t_s < 52.0 else 0.0
        sod = (13.0 + t_s - GPS_UTC_LEAP_S) % 86400.0
        fixes.append(Fix("", sod, place.lat_deg + off_m * north_deg_per_m, place.lon_deg, place.height_m, 8, 1.0))
    got = _gnss_sdr_score(fixes, case)
    assert got["first_fix_s"] == 35.0 and got["fixes"] == len(fixes)
    assert got["epochs_fixed"] == pytest.approx(220 / 250, abs=0.005)
    assert got["true_fixed"] == pytest.approx(200 / 250, abs=0.005)
    assert got["longest_gap_s"] == pytest.approx(3.0, abs=0.15)


def test_a_cell_whose_cleaning_stopped_is_an_error_not_a_receivers_result(monkeypatch, tmp_path):
    """`clean` that stopped on an internal error (a full disk, 4.7 s in) wrote a short file: the fingerprint says so
    and the grid's row is an error, where GNSS-SDR's no-fix on it had counted as the filter's failure."""
    import semperfi.defense as defense
    from semperfi.defense.clean import CleanSummary
    from semperfi.eval import plugin, xgen
    monkeypatch.setattr(xgen, "prepare", lambda case, nav, work: tmp_path / f"{case.tag}.bin")
    monkeypatch.setattr(defense, "clean_file", lambda *a, **k: CleanSummary(
        tmp_path / "c.bin", 4.7, 1.0, (7,), (7,), (7,), {}, {}, 0.0,
        internal_error="OSError: [Errno 28] No space left on device"))
    case = xgen.Case(xgen.PLACES["boston"], 500.0, 15.0, duration_s=60.0)
    with pytest.raises(RuntimeError, match=r"clean stopped at 4\.7 s: OSError: \[Errno 28\] No space left"):
        plugin.fingerprint(case, "nav", tmp_path, gnss_sdr=False)
    grid = load_script("plugin-grid")
    monkeypatch.setattr(grid, "fingerprint", plugin.fingerprint)
    cell = grid.run_cell(case, "nav", str(tmp_path))
    assert cell["error"].startswith("RuntimeError: clean stopped at 4.7 s") and grid.verdict(cell) == "error"


def test_a_cell_the_disk_cannot_hold_is_an_error_before_anything_is_written(monkeypatch, tmp_path):
    """The disk's free space against what the cell's files take (two scenes 4x faster behind a front end, three
    recordings), times the cells run beside it: too little is the row's error, and nothing is rendered."""
    from collections import namedtuple

    from semperfi.eval import xgen
    case = xgen.Case(xgen.PLACES["boston"], 500.0, 15.0, duration_s=60.0, fs_hz=2.6e6, front_end_hz=1e6)
    # complex int16 (4 bytes a sample): scenes at 10.4 MSa/s, recordings at 2.6 MSa/s
    assert xgen.disk_bytes(case) == int(2 * 10.4e6 * 60 * 4 + 3 * 2.6e6 * 60 * 4)
    grid = load_script("plugin-grid")
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(grid.shutil, "disk_usage", lambda path: usage(100e9, 96e9, 4e9))
    monkeypatch.setattr(grid, "fingerprint", lambda *a, **k: pytest.fail("a cell the disk cannot hold was run"))
    cell = grid.run_cell(case, "nav", str(tmp_path), cells_at_once=2)
    assert cell["error"] == "OSError: 4.0 GB free on the disk, 13.7 GB wanted by 2 cell(s) at once", cell
    assert grid.verdict(cell) == "error"


def test_a_rerun_runs_the_wanted_cells_without_a_row_and_those_whose_row_is_an_error(tmp_path):
    grid = load_script("plugin-grid")
    cells = grid.cells(tmp_path)
    done = {cells[0].tag: {"case": cells[0].tag, "error": "OSError: 1.0 GB free"},
            cells[1].tag: {"case": cells[1].tag, "fixes": {}}}
    assert [c.tag for c in grid.cells_to_run(cells, done, {0, 1, 2})] == [cells[0].tag, cells[2].tag]
    assert len(grid.cells_to_run(cells, done, None)) == len(cells) - 1
