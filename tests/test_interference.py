"""Claims about narrowband interference: a CW tone or spur is no satellite, it is named, and real satellites are
still found under it (issue 23, item 4)."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from semperfi.cli import main
from semperfi.errors import EXIT_NO_SIGNAL
from semperfi.gps.codes import UNUSED_G2_DELAYS, ca_code, gold_code
from semperfi.iq import open_iq, with_iq_swap
from semperfi.receiver.acquisition import DopplerGrid, acquire
from semperfi.receiver.interference import JAMMING_JN_DB, Monitor, excise_narrowband

REAL_4MHZ = Path(__file__).parent / "data" / "pocketsdr" / "L1_20211202_084700_4MHz_IQ.bin"
TONES_HZ = (0.0, 1e3, 100e3, 250e3, 600e3, 1e6)
# IS-GPS-200 Table 3-Ia: the G2 delay (chips) of PRN 1..32
G2_DELAYS = (5, 6, 7, 8, 17, 18, 139, 140, 141, 251, 252, 254, 255, 256, 257, 258, 469, 470, 471, 472, 473, 474,
             509, 512, 513, 514, 515, 516, 859, 860, 861, 862)


def _quantised(x: np.ndarray, lo: int = -32768, hi: int = 32767) -> np.ndarray:
    return (np.clip(np.round(x.real), lo, hi) + 1j * np.clip(np.round(x.imag), lo, hi)).astype(np.complex64)


def _tone(fs_hz: float, n: int, f_hz: float, amplitude: float) -> np.ndarray:
    return amplitude * np.exp(2j * np.pi * (f_hz * np.arange(n) / fs_hz + 0.3))


def _as_cli_does(x: np.ndarray, fs_hz: float):
    return acquire(x, fs_hz, range(1, 33), DopplerGrid(0.0, 6000.0, 333.0), 0.0, 2, 5, excise=True,
                   tail_threshold=True)


def test_the_reference_codes_are_gold_codes_no_satellite_sends():
    for prn, delay in enumerate(G2_DELAYS, start=1):
        assert np.array_equal(gold_code(delay), ca_code(prn)), f"G2 delay {delay} is not PRN {prn}"
    for delay in UNUSED_G2_DELAYS:
        assert not any(np.array_equal(gold_code(delay), ca_code(prn)) for prn in range(1, 33))
        assert abs(int(gold_code(delay).astype(int).sum())) <= 65   # a balanced Gold code (+-1, 63 or 65)


@pytest.mark.parametrize("fs_hz", [4e6, 2.6e6])
def test_a_pure_carrier_tone_is_jamming_not_satellites(fs_hz):
    """A noiseless tone (int16) at any offset: before, 1-5 PRNs 'acquired' at 35-40 dB-Hz; now none, and the tone
    named as jamming at its frequency."""
    n = int(0.01 * fs_hz)
    for f_hz in TONES_HZ:
        if f_hz >= fs_hz / 2:
            continue
        cafs = _as_cli_does(_quantised(_tone(fs_hz, n, f_hz, 1000.0)), fs_hz)
        found = sorted(p for p, c in cafs.items() if c.best)
        assert not found, f"tone at {f_hz:g} Hz, {fs_hz:g} Sa/s: PRNs {found} 'acquired'"
        interference = cafs[1].interference
        assert interference.jamming and interference.jn_db >= JAMMING_JN_DB
        assert abs(interference.lines[0].offset_hz - f_hz) <= 100.0, interference.describe()


def test_a_tone_in_noise_without_gps_is_named_and_no_prn_found():
    rng = np.random.default_rng(7)
    fs = 4e6
    n = int(0.01 * fs)
    noise = 20.0 * (rng.normal(size=n) + 1j * rng.normal(size=n))
    for f_hz in TONES_HZ:
        x = _quantised(noise + _tone(fs, n, f_hz, 20.0 * np.sqrt(2) * 10 ** (17 / 20)))   # J/N 17 dB
        cafs = _as_cli_does(x, fs)
        assert not [p for p, c in cafs.items() if c.best], f"tone at {f_hz:g} Hz"
        interference = cafs[1].interference
        assert interference.present and not interference.jamming
        assert abs(interference.lines[0].offset_hz - f_hz) <= 100.0
        assert abs(interference.lines[0].jn_db - 17.0) < 1.0, interference.describe()


def test_satellites_of_a_real_capture_are_found_under_a_tone_20_db_above_the_noise():
    """PocketSDR's 4 MSa/s int8 capture, a tone 20 dB above its noise added and re-quantised to int8: the same
    satellites as without it, no other PRN, the tone named at its offset and power."""
    if not REAL_4MHZ.is_file():
        pytest.skip(f"{REAL_4MHZ} absent (PocketSDR sample data)")
    fs = 4e6
    x = open_iq(REAL_4MHZ, with_iq_swap("ibyte"), fs).read(24191, int(0.05 * fs)).astype(np.complex64)
    noise_power = float(np.mean(np.abs(x) ** 2))

    def acquired(samples):
        cafs = acquire(samples, fs, range(1, 33), DopplerGrid(0.0, 6000.0, 100.0), 0.0, 5, 10, excise=True,
                       tail_threshold=True)
        return {p: c.best for p, c in cafs.items() if c.best}, cafs[1].interference

    clean, _ = acquired(x)
    assert {16, 18, 29, 31, 32} <= set(clean)   # GNSS-SDR's satellites (test_real_captures)
    for f_hz in (0.0, 1e3, 250e3, 1e6, 1.5e6):
        y = _quantised(x + _tone(fs, x.size, f_hz, np.sqrt(100 * noise_power)), -128, 127)
        found, interference = acquired(y)
        assert set(found) == set(clean), f"tone at {f_hz:g} Hz: {sorted(found)} vs {sorted(clean)}"
        for prn, best in found.items():
            assert abs(best.doppler_hz - clean[prn].doppler_hz) < 50.0
        assert abs(interference.lines[0].offset_hz - f_hz) <= 100.0 and not interference.jamming
        assert abs(interference.lines[0].jn_db - 20.0) < 1.5, interference.describe()


def test_a_real_if_tone_is_one_line_at_its_offset_from_the_if():
    rng = np.random.default_rng(3)
    fs, if_hz = 12e6, 3e6
    n = int(0.01 * fs)
    t = np.arange(n) / fs
    x = rng.normal(size=n) * 10 + 100 * np.cos(2 * np.pi * (if_hz + 40e3) * t)
    _, found = excise_narrowband(x.astype(np.complex64), fs, if_hz, int(fs * 1e-3))
    assert len(found.lines) == 1 and abs(found.lines[0].offset_hz - 40e3) <= 100.0


def test_the_monitor_reports_a_tone_when_it_starts_and_when_it_ends():
    rng = np.random.default_rng(5)
    fs = 2e6
    events = []
    monitor = Monitor(fs, 0.0, lambda kind, t_s, **fields: events.append((kind, round(t_s, 1), fields)))
    for second in range(5):
        x = (rng.normal(size=int(fs)) + 1j * rng.normal(size=int(fs))).astype(np.complex64)
        if 1 <= second <= 2:
            x += _tone(fs, x.size, -300e3, 10.0).astype(np.complex64)
        monitor.push(x)
    kinds = [(k, t) for k, t, _ in events]
    assert kinds == [("interference", 1.0), ("interference_ended", 3.0)], events
    assert events[0][2]["tones_hz"] and abs(events[0][2]["tones_hz"][0] + 300e3) <= 100.0


def _write_ishort(path: Path, x: np.ndarray) -> None:
    a = np.empty(2 * x.size, np.int16)
    a[0::2], a[1::2] = x.real, x.imag
    a.tofile(path)


def test_acquire_run_and_clean_name_a_tone_and_exit_no_signal(tmp_path):
    fs = 2e6
    rng = np.random.default_rng(11)
    n = int(0.6 * fs)
    x = _quantised(20 * (rng.normal(size=n) + 1j * rng.normal(size=n)) + _tone(fs, n, 250e3, 2000.0))
    path = tmp_path / "tone.bin"
    _write_ishort(path, x)
    runner = CliRunner()
    acq = runner.invoke(main, ["acquire", str(path), "--fs", "2e6", "--format", "ishort"])
    assert acq.exit_code == EXIT_NO_SIGNAL and "+250.0 kHz" in acq.output, acq.output
    assert "Traceback" not in acq.output
    run = runner.invoke(main, ["run", str(path), "--fs", "2e6", "--format", "ishort", "--out", str(tmp_path / "run")])
    assert run.exit_code == EXIT_NO_SIGNAL and "+250.0 kHz" in run.output, run.output
    events = [json.loads(line) for line in (tmp_path / "run" / "events.jsonl").read_text().splitlines()]
    tone = [e for e in events if e["event"] == "interference"]
    assert tone and abs(tone[0]["tones_hz"][0] - 250e3) <= 100.0
    clean = runner.invoke(main, ["clean", str(path), "--fs", "2e6", "--format", "ishort", "-o",
                                 str(tmp_path / "clean.bin")])
    assert clean.exit_code == EXIT_NO_SIGNAL and "+250.0 kHz" in clean.output, clean.output
    events = [json.loads(line) for line in (tmp_path / "clean.events.jsonl").read_text().splitlines()]
    assert any(e["event"] == "interference" for e in events)


@pytest.mark.parametrize("n", [80_000, 80_001, 2_000, 64 * 16 - 1])
def test_the_local_floor_equals_its_reference(n):
    """The one-median floor against the 64-median loop, on an exponential spectrum with a few spurs; lengths that do
    and do not divide into 64 parts."""
    from semperfi.receiver.interference import _local_floor, _local_floor_reference
    p = np.random.default_rng(n).exponential(1.0, n)
    p[::997] *= 1e4
    assert np.array_equal(_local_floor(p), _local_floor_reference(p))
