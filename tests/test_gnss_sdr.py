"""A receiver nobody here wrote agrees with the simulator: GNSS-SDR fixes where the truth (or the attacker) says."""

import shutil

import numpy as np
import pytest

from semperfi.eval.gnss_sdr import horizontal_errors_m, parse_gga, run_gnss_sdr
from semperfi.sim.run import simulate_to_file
from semperfi.sim.scenario import load_scenario

needs_gnss_sdr = pytest.mark.skipif(shutil.which("gnss-sdr") is None,
                                    reason="gnss-sdr is not on PATH (scripts/crosscheck-gnss-sdr installs it)")
FS = 2e6
# Subframe 1 begins 16 s into the file, after every channel has found its bit and frame sync (begun 3 s in, GNSS-SDR
# missed it on most channels and waited a whole frame: 55 s were needed); its ephemerides are complete 34 s in
COMMON = [f"signal.fs_hz={FS}", "time.duration_s=42.0", 'time.start="2022-01-01T00:00:14"']


def _run(tmp_path, name, brdc_path, *sets):
    cfg = load_scenario(None, COMMON + [f'constellation.rinex="{brdc_path}"', *sets])
    out = tmp_path / f"{name}.bin"
    simulate_to_file(cfg, out)
    # a long output path: GNSS-SDR cuts one of about 170 characters short and writes its fixes elsewhere
    fixes = run_gnss_sdr(out, FS, "ishort", 0.0, tmp_path / ("a-long-folder-name-" * 9) / f"{name}.gnss-sdr",
                         timeout_s=600)
    return cfg, fixes


@needs_gnss_sdr
@pytest.mark.gnss_sdr
def test_gnss_sdr_fixes_on_the_truth(tmp_path, brdc_path):
    cfg, fixes = _run(tmp_path, "static", brdc_path)
    assert len(fixes) >= 20, f"GNSS-SDR gave {len(fixes)} fixes"
    err = horizontal_errors_m(fixes, cfg["receiver"]["lat_deg"], cfg["receiver"]["lon_deg"])
    # the median: RTKLIB's first few fixes, before its solution settles, wander tens of metres by how GNSS-SDR's
    # threads were scheduled (a mean over them failed under load: 5.8 m)
    assert np.median(err) < 5.0, \
        f"GNSS-SDR horizontal error: median {np.median(err):.2f} m, p95 {np.percentile(err, 95):.2f} m"


@needs_gnss_sdr
@pytest.mark.gnss_sdr
def test_gnss_sdr_follows_the_attacker_to_its_claimed_position(tmp_path, brdc_path):
    """The simulator renders the claimed position: with the spoofer's peaks apart from the legitimate ones (an
    unsynchronized spoofer, 5 us off GPS time) GNSS-SDR locks on the stronger and fixes there. Synchronized, some PRNs'
    peaks merge with their twins and where a conventional receiver ends depends on which it happened to lock."""
    cfg, fixes = _run(tmp_path, "attack", brdc_path, "attacker.enabled=true", "attacker.power_advantage_db=6.0",
                      "attacker.offset_east_m=1000.0", "attacker.time_offset_s=5e-6")
    assert len(fixes) >= 20, f"GNSS-SDR gave {len(fixes)} fixes"
    lat0, lon0 = np.radians(cfg["receiver"]["lat_deg"]), cfg["receiver"]["lon_deg"]
    claimed_lon = lon0 + np.degrees(1000.0 / (6378137.0 * np.cos(lat0)))   # 1 km east, to a metre
    err = horizontal_errors_m(fixes, cfg["receiver"]["lat_deg"], claimed_lon)
    assert np.mean(err) < 50.0, f"distance from the claimed position: mean {np.mean(err):.1f} m"


def test_crosscheck_command_line_says_each_mistake_in_one_line(tmp_path, capsys):
    from semperfi.eval.crosscheck import main
    iq = tmp_path / "x.bin"
    iq.write_bytes(bytes(16))   # no sidecar
    for argv, words in [([], "Missing argument 'IQ_FILE'"), ([str(iq), "--bogus"], "No such option"),
                        ([str(iq), "--reference-lat", "91", "--reference-lon", "0"], "out of range"),
                        ([str(iq), "--reference-lat", "1"], "go together"),
                        ([str(iq), "--format", "short"], "'short' is not one of"),
                        ([str(tmp_path / "nope.bin")], "IQ file not found"),
                        ([str(iq)], "give --fs and --format")]:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("crosscheck: error: ") and err.count("\n") == 1 and words in err, (argv, err)
    assert main(["-h"]) == 0 and "--reference-lat DEG" in capsys.readouterr().out


def test_gga_parsing():
    fix = parse_gga("$GPGGA,120024.10,4220.3886360,N,07105.3542378,W,1,08,1.0,12.817,M,0.000,M,0.0,*5B")
    assert fix is not None
    assert fix.lat_deg == pytest.approx(42 + 20.3886360 / 60)
    assert fix.lon_deg == pytest.approx(-(71 + 5.3542378 / 60))
    assert fix.n_sats == 8


@needs_gnss_sdr
@pytest.mark.gnss_sdr
def test_plug_in_filter_output_makes_gnss_sdr_fix_the_truth(tmp_path, brdc_path):
    """The plug-in claim, checked by a receiver nobody here wrote: spoofed in, GNSS-SDR at the attacker's position;
    through `semperfi clean`, GNSS-SDR at the truth."""
    from semperfi.defense.config import load_config
    from semperfi.defense.clean import clean_file

    cfg = load_scenario(None, COMMON + [f'constellation.rinex="{brdc_path}"', "attacker.enabled=true",
                                        "attacker.power_advantage_db=6.0", "attacker.offset_east_m=1000.0"])
    spoofed = tmp_path / "spoofed.bin"
    simulate_to_file(cfg, spoofed)
    summary = clean_file(spoofed, tmp_path / "clean.bin", None, None, None,
                         load_config(None, ['defense.mode="full"']))
    assert set(summary.cancelled) and set(summary.verified) == set(summary.cancelled)
    fixes = run_gnss_sdr(tmp_path / "clean.bin", FS, "ishort", 0.0, tmp_path / "clean.gnss-sdr", timeout_s=600)
    assert len(fixes) >= 20, f"GNSS-SDR gave {len(fixes)} fixes on the cleaned file"
    err = horizontal_errors_m(fixes, cfg["receiver"]["lat_deg"], cfg["receiver"]["lon_deg"])
    summary = (f"GNSS-SDR on the cleaned file: {len(fixes)} fixes, horizontal error mean {np.mean(err):.2f} m, "
               f"p95 {np.percentile(err, 95):.2f} m, max {np.max(err):.2f} m")
    print(summary)
    # GNSS-SDR's single-epoch fixes scatter (up to 7.6 m on a clean 45 dB-Hz file, more when it drops to four
    # satellites after a loss of lock): the claim is held on their mean
    assert np.mean(err) < 10.0, summary


def test_gnss_sdr_is_configured_for_real_samples_at_an_if():
    """A real recording at an IF (int16, as `clean` writes one back): the file source reads shorts, the adapter
    passes them through and the input filter mixes them to complex baseband (its low-pass takes the mirror image
    away); real samples without an IF have no baseband to be read as, and are refused."""
    from semperfi.eval.gnss_sdr import gnss_sdr_config
    lines = gnss_sdr_config("/tmp/r.bin", 10.4e6, "short", 2.6e6).splitlines()
    for line in ("SignalSource.item_type=short", "DataTypeAdapter.implementation=Pass_Through",
                 "DataTypeAdapter.item_type=short", "InputFilter.implementation=Freq_Xlating_Fir_Filter",
                 "InputFilter.input_item_type=short", "InputFilter.output_item_type=gr_complex",
                 "InputFilter.IF=2600000"):
        assert line in lines, line
    complex_lines = gnss_sdr_config("/tmp/c.bin", 4e6, "gr_complex", 0.0).splitlines()
    assert "DataTypeAdapter.item_type=gr_complex" in complex_lines
    assert "InputFilter.implementation=Pass_Through" in complex_lines
    with pytest.raises(ValueError, match="need an IF"):
        gnss_sdr_config("/tmp/r.bin", 10.4e6, "short", 0.0)


def test_gnss_sdrs_acquisition_dwells_are_configurable_and_one_by_default():
    """One dwell by default (the configuration every comparison so far ran with); the plug-in grid asks for two,
    and a count GNSS-SDR cannot take is refused before it runs."""
    from semperfi.eval.gnss_sdr import gnss_sdr_config
    assert "Acquisition_1C.max_dwells=1" in gnss_sdr_config("/tmp/c.bin", 4e6, "gr_complex").splitlines()
    assert "Acquisition_1C.max_dwells=2" in gnss_sdr_config("/tmp/c.bin", 4e6, "gr_complex", max_dwells=2).splitlines()
    with pytest.raises(ValueError, match="max_dwells"):
        gnss_sdr_config("/tmp/c.bin", 4e6, "gr_complex", max_dwells=0)


@needs_gnss_sdr
@pytest.mark.gnss_sdr
def test_samples_at_a_long_path_are_read_through_a_short_link_and_a_flowgraph_that_never_ran_is_an_error(
        tmp_path, monkeypatch):
    """GNSS-SDR cuts a samples path of 194 characters short, cannot open it, and exits with status 0 and no fix (the
    real-IF plug-in grid's flying 500 m +3 dB cell: 'no fix' that was no run). Its samples are linked into its run's
    directory under a short name; and should it still not start, that is an error, not a recording without a fix."""
    from semperfi.eval import gnss_sdr
    deep = tmp_path / ("a-long-folder-name-" * 6) / ("another-long-folder-name-" * 4)
    deep.mkdir(parents=True)
    data = deep / "noise.bin"
    rng = np.random.default_rng(1)
    data.write_bytes(np.rint(rng.standard_normal(2 * int(0.5 * FS)) * 100).astype("<i2").tobytes())
    assert len(str(data)) > 200
    assert run_gnss_sdr(data, FS, "ishort", 0.0, deep / "run", timeout_s=120) == []
    assert "SignalSource.filename=samples" in (deep / "run" / gnss_sdr.CONFIG_NAME).read_text().splitlines()
    monkeypatch.setattr(gnss_sdr, "_short_link", lambda data_file, out_dir: str(data_file))
    with pytest.raises(RuntimeError, match="Unable to connect flowgraph"):
        run_gnss_sdr(data, FS, "ishort", 0.0, deep / "run-full-path", timeout_s=120)
