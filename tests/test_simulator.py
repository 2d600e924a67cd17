"""The simulator's signals, checked the way a receiver would see them."""

import csv
import hashlib
import json

import numpy as np
import pytest

from semperfi.gps.constants import SPEED_OF_LIGHT_M_S
from semperfi.gps.lnav import decode_subframe
from semperfi.iq import open_iq
from semperfi.receiver.acquisition import DopplerGrid, acquire
from semperfi.receiver.cn0 import cn0_known_noise_dbhz, correlate_ms
from semperfi.sim.run import simulate_to_file
from semperfi.sim.scenario import load_scenario
from semperfi.sim.truth import read_signal_truth, truth_paths

FS = 2e6


def simulate(tmp_path, name, *sets, duration=1.0, fmt="ishort"):
    cfg = load_scenario(None, [f"signal.fs_hz={FS}", f"time.duration_s={duration}", f'signal.format="{fmt}"', *sets])
    out = tmp_path / f"{name}.bin"
    simulate_to_file(cfg, out)
    return out, read_signal_truth(truth_paths(out)["signals.csv"])


def first_truth(rows, prn, source="legit"):
    return next(r for r in rows if r["prn"] == prn and r["source"] == source)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return simulate(tmp_path_factory.mktemp("clean"), "clean")


def test_every_satellite_acquires_at_the_truths_code_phase_and_doppler(clean):
    out, rows = clean
    x = open_iq(out).read(0, int(0.02 * FS))
    legit = sorted({int(r["prn"]) for r in rows if r["source"] == "legit"})
    assert len(legit) >= 8
    cafs = acquire(x, FS, legit, DopplerGrid(max_hz=6000, step_hz=125), coherent_ms=2, noncoherent=5)
    for prn in legit:
        truth = first_truth(rows, prn)
        peak = cafs[prn].best
        assert peak is not None, f"PRN {prn} not acquired"
        dcode = (peak.code_phase_chips - truth["code_phase_chips"] + 511.5) % 1023 - 511.5
        assert abs(dcode) < 0.15, \
            f"PRN {prn}: code phase {peak.code_phase_chips:.3f} vs truth {truth['code_phase_chips']:.3f}"
        assert abs(peak.doppler_hz - truth["doppler_hz"]) < 100, \
            f"PRN {prn}: Doppler {peak.doppler_hz:.0f} vs {truth['doppler_hz']:.0f}"


@pytest.mark.parametrize("cn0, fmt, if_hz", [(35.0, "ishort", 0.0), (45.0, "ishort", 0.0), (45.0, "short", 6e5)])
def test_measured_cn0_is_the_setting(tmp_path, cn0, fmt, if_hz):
    """Complex baseband, and real samples at an IF (as a single-channel front end writes them; read back as the
    signal at +IF and its mirror): the C/N0 a receiver measures is the one asked for."""
    out, rows = simulate(tmp_path, "cn0", f"constellation.cn0_dbhz={cn0}", "constellation.max_satellites=4",
                         f"signal.if_hz={if_hz}", duration=1.0, fmt=fmt)
    reader = open_iq(out)
    assert reader.fmt.is_complex == (fmt == "ishort") and reader.if_hz == if_hz
    x = reader.read(0, int(FS))
    for prn in sorted({int(r["prn"]) for r in rows}):
        t = first_truth(rows, prn)
        prompt = correlate_ms(x, FS, prn, t["code_phase_chips"], t["doppler_hz"], if_hz)
        noise = correlate_ms(x, FS, prn, t["code_phase_chips"] + 400.0, t["doppler_hz"], if_hz)
        measured = cn0_known_noise_dbhz(prompt, noise)
        assert abs(measured - cn0) < 1.0, f"PRN {prn}: measured {measured:.2f} dB-Hz, set {cn0}"


def test_navigation_bits_ride_on_code_epochs_and_pass_parity(tmp_path):
    """Demodulate one satellite at the truth's code phase and Doppler: whole subframes, zero parity errors,
    and the HOW's TOW names the subframe the truth's transmit time says."""
    out, rows = simulate(tmp_path, "bits", "constellation.max_satellites=1", "constellation.cn0_dbhz=50",
                         duration=7.0)
    t0 = rows[0]
    prn = int(t0["prn"])
    p = correlate_ms(open_iq(out).read(0, int(7.0 * FS)), FS, prn, t0["code_phase_chips"], t0["doppler_hz"])
    phase = np.unwrap(np.angle(p ** 2)) / 2   # squaring removes the data: what is left is the carrier residual
    baseband = (p * np.exp(-1j * phase)).real
    energy = [np.sum(np.abs(np.add.reduceat(baseband[o:], np.arange(0, baseband.size - o - 20, 20))))
              for o in range(20)]
    edge = int(np.argmax(energy))
    bits = (np.add.reduceat(baseband[edge:], np.arange(0, baseband.size - edge - 20, 20)) < 0).astype(np.uint8)
    preamble = np.array([1, 0, 0, 0, 1, 0, 1, 1], dtype=np.uint8)
    decoded = []
    for polarity in (0, 1):
        b = bits ^ polarity
        for start in range(0, b.size - 299):
            if np.array_equal(b[start:start + 8], preamble):
                sf = decode_subframe(b[start:start + 300])
                if sf.parity_errors == 0:
                    decoded.append(sf)
    assert len(decoded) == 1, f"{len(decoded)} clean subframes in 7 s of signal"
    rx = list(csv.DictReader(open(truth_paths(out)["receiver.csv"])))[0]
    t_sv = float(rx["gps_tow_s"]) - t0["pseudorange_m"] / SPEED_OF_LIGHT_M_S + float(rx["clock_bias_s"])
    assert decoded[0].tow_count_next == int(np.floor(t_sv / 6.0)) + 2, (decoded[0].tow_count_next, t_sv)


def test_attacker_peak_sits_at_its_truth_and_is_stronger(tmp_path):
    out, rows = simulate(tmp_path, "spoof", "attacker.enabled=true", "attacker.power_advantage_db=6.0",
                         "attacker.offset_east_m=1000.0", duration=0.05)
    x = open_iq(out).read(0, int(0.02 * FS))
    spoofed = sorted({int(r["prn"]) for r in rows if r["source"] == "spoof"})
    assert spoofed
    cafs = acquire(x, FS, spoofed, DopplerGrid(max_hz=6000, step_hz=125), coherent_ms=2, noncoherent=5)
    apart = [p for p in spoofed if abs((first_truth(rows, p, "spoof")["code_phase_chips"]
                                        - first_truth(rows, p)["code_phase_chips"] + 511.5) % 1023 - 511.5) > 1.5]
    assert len(apart) >= 3, "a 1 km offset parts most spoofed peaks from their twins by more than 1.5 chips"
    for prn in apart:   # closer pairs merge into one lobe, whose maximum lies between them
        s = first_truth(rows, prn, "spoof")
        peak = cafs[prn].best
        dcode = (peak.code_phase_chips - s["code_phase_chips"] + 511.5) % 1023 - 511.5
        assert abs(dcode) < 0.15, \
            f"PRN {prn}: strongest peak at {peak.code_phase_chips:.2f}, spoofer at {s['code_phase_chips']:.2f}"
        assert abs(peak.doppler_hz - s["doppler_hz"]) < 100


@pytest.mark.parametrize("time_offset_s", [0.0, 5e-6])
def test_static_offset_moves_pseudoranges_by_the_geometry(tmp_path, time_offset_s):
    """Spoofed minus legitimate pseudorange = range difference from the claimed point (1 km east) + the spoofer's
    clock offset, common to all PRNs."""
    _, rows = simulate(tmp_path, "geom", "attacker.enabled=true", "attacker.offset_east_m=1000.0",
                       f"attacker.time_offset_s={time_offset_s}", duration=0.02)
    legit = {int(r["prn"]): r for r in rows if r["source"] == "legit" and r["t_rx_s"] == 0.0}
    spoof = {int(r["prn"]): r for r in rows if r["source"] == "spoof" and r["t_rx_s"] == 0.0}
    common = sorted(set(legit) & set(spoof))
    diffs = np.array([spoof[p]["pseudorange_m"] - legit[p]["pseudorange_m"] for p in common])
    diffs -= SPEED_OF_LIGHT_M_S * time_offset_s
    assert np.all(np.abs(diffs) <= 1000.0 + 5.0), diffs
    assert np.ptp(diffs) > 100.0, "a 1 km offset must move the pseudoranges differently per satellite"


def test_seamless_takeover_starts_aligned_then_drifts(tmp_path):
    _, rows = simulate(tmp_path, "takeover", "attacker.enabled=true", 'attacker.mode="takeover"',
                       "attacker.push_hold_s=0.5", "attacker.push_speed_m_s=200.0", duration=2.0)
    prn = int(next(r["prn"] for r in rows if r["source"] == "spoof"))

    def at(src, t):
        return min((r for r in rows if r["prn"] == prn and r["source"] == src), key=lambda r: abs(r["t_rx_s"] - t))
    start_gap = abs(at("spoof", 0.0)["pseudorange_m"] - at("legit", 0.0)["pseudorange_m"])
    assert start_gap < 0.01, f"aligned start: {start_gap:.4f} m apart"
    assert abs(at("spoof", 0.0)["carrier_phase_cycles"] - at("legit", 0.0)["carrier_phase_cycles"]) < 1e-3
    end_gap = abs(at("spoof", 1.9)["pseudorange_m"] - at("legit", 1.9)["pseudorange_m"])
    assert end_gap > 10.0, f"after 1.4 s of drag-off at 200 m/s the pseudoranges must part (gap {end_gap:.1f} m)"


def test_meaconing_delays_every_prn_by_the_replay_delay(tmp_path):
    _, rows = simulate(tmp_path, "meacon", "attacker.enabled=true", 'attacker.mode="meaconing"',
                       "attacker.offset_east_m=0.0", "attacker.delay_s=1e-6", duration=0.02)
    legit = {int(r["prn"]): r["pseudorange_m"] for r in rows if r["source"] == "legit" and r["t_rx_s"] == 0.0}
    spoof = {int(r["prn"]): r["pseudorange_m"] for r in rows if r["source"] == "spoof" and r["t_rx_s"] == 0.0}
    for p in set(legit) & set(spoof):
        assert spoof[p] - legit[p] == pytest.approx(SPEED_OF_LIGHT_M_S * 1e-6, abs=2.0)


def test_time_push_delays_every_prn_alike_code_and_carrier_and_writes_its_truth(tmp_path):
    """Aligned with the sky at first, then every spoofed signal delayed by rate x (t - start - hold): the same delay on
    each PRN, in code and carrier alike; the receiver truth says the delay."""
    out, rows = simulate(tmp_path, "tpush", "attacker.enabled=true", 'attacker.mode="time_push"',
                         "attacker.start_s=0.2", "attacker.push_hold_s=0.3", "attacker.time_push_rate_s_s=1e-6",
                         "attacker.time_push_ramp_s=0.0", duration=1.0)
    def gap(t, key):
        at = {(int(r["prn"]), r["source"]): r[key] for r in rows if abs(r["t_rx_s"] - t) < 1e-9}
        return np.array([at[(p, "spoof")] - at[(p, "legit")] for p, s in at if s == "spoof"])
    for t, delay_s in ((0.4, 0.0), (0.9, 0.4e-6)):
        code = gap(t, "pseudorange_m")
        assert np.allclose(code, SPEED_OF_LIGHT_M_S * delay_s, atol=0.05), (t, code)
        carrier_m = -gap(t, "carrier_phase_cycles") * 0.190293672798365
        assert (np.allclose(carrier_m, carrier_m[0])
                and abs(carrier_m[0] - SPEED_OF_LIGHT_M_S * delay_s) < 0.2), carrier_m
    truth = list(csv.DictReader(open(truth_paths(out)["receiver.csv"])))
    claimed = {round(float(r["t_rx_s"]), 1): r["claimed_delay_s"] for r in truth}
    assert claimed[0.1] == "" and float(claimed[0.9]) == pytest.approx(0.4e-6, rel=1e-6)
    events = [json.loads(line) for line in open(truth_paths(out)["events.jsonl"])]
    assert ([e["event"] for e in events] == ["attack_start", "drag_off_start"]
            and events[1]["time_push_rate_s_s"] == 1e-6)


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    digest = []
    for i, seed in enumerate((5, 5, 6)):
        out, _ = simulate(tmp_path, f"det{i}", f"signal.seed={seed}", "attacker.enabled=true", duration=0.05,
                          fmt="ibyte")
        digest.append(hashlib.sha256(out.read_bytes()).hexdigest())
    assert digest[0] == digest[1] != digest[2]


def test_outputs_are_described(clean):
    out, _ = clean
    meta = json.loads(out.with_suffix(".sigmf-meta").read_text())
    assert meta["global"]["core:datatype"] == "ci16_le"
    assert meta["global"]["core:sample_rate"] == FS
    assert out.with_name("clean.scenario.toml").is_file()
    assert open_iq(out).n_samples == int(FS * 1.0)


def test_intermediate_frequency_shifts_every_signal(tmp_path):
    out, rows = simulate(tmp_path, "if", "signal.if_hz=250000.0", "constellation.max_satellites=5", duration=0.02,
                         fmt="gr_complex")
    reader = open_iq(out)
    assert reader.if_hz == 250000.0
    cafs = acquire(reader.read(0, int(0.01 * FS)), FS, sorted({int(r["prn"]) for r in rows}),
                   DopplerGrid(max_hz=6000, step_hz=125), if_hz=reader.if_hz, coherent_ms=2, noncoherent=5)
    for prn, caf in cafs.items():
        t = first_truth(rows, prn)
        assert caf.best is not None and abs(caf.best.doppler_hz - t["doppler_hz"]) < 100, prn
