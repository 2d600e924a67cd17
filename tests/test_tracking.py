"""Tracking: the numba correlator and loop kernel against their numpy references, and channels on real signals."""

import numpy as np
import pytest

from semperfi.gps.codes import ca_code
from semperfi.gps.constants import CA_CHIP_RATE_HZ, L1_HZ
from semperfi.iq import open_iq
from semperfi.receiver.correlator import (QUANTUM_CHIPS, block_length, code_bank, correlate_block,
                                          correlate_block_reference, lane_buffer)
from semperfi.receiver.tracking import (Channel, LoopConfig, initial_state, loop_params, track_kernel,
                                        track_reference)
from semperfi.sim.run import simulate_to_file
from semperfi.sim.scenario import load_scenario
from semperfi.sim.truth import read_signal_truth, truth_paths

FS = 2e6


@pytest.mark.parametrize("fs", [FS, 2.6e6, 10e6, 25e6])
def test_correlator_kernel_equals_reference(fs):
    rng = np.random.default_rng(11)
    x = (rng.standard_normal(30000) + 1j * rng.standard_normal(30000)).astype(np.complex64)
    code, bank, lanes = ca_code(7), code_bank(7, fs), lane_buffer()
    for _ in range(20):
        # Doppler up to 5 ppm, and at times a front end 50 ppm off (short sub-blocks)
        ppm = rng.choice([rng.uniform(-5, 5), rng.choice([-50, 50])])
        cp, step = rng.uniform(0, 0.5), CA_CHIP_RATE_HZ / fs * (1 + ppm * 1e-6)
        phase, cstep = rng.uniform(-3, 3), rng.uniform(-0.004, 0.004)
        half = rng.choice([0.05, 0.25, 0.5])
        n = block_length(cp, step)
        fast = correlate_block(x, 100, n, bank.rows, bank.first, bank.step_chips, cp, step, phase, cstep, half, lanes)
        slow = correlate_block_reference(x[100:100 + n], code, cp, step, phase, cstep, half)
        mag = np.abs(x[100:100 + n])
        pos = cp + np.arange(n) * step
        for f, s, offset in zip(fast, slow, (half, 0.0, -half)):
            # float32 sums and rotator: 1e-5 of the magnitudes; the replica's phase rounded to the bank: a sample
            # within a quantum of a chip edge may take the neighbouring chip
            edge = np.abs(pos + offset - np.round(pos + offset)) < QUANTUM_CHIPS
            assert abs(f - s) < 1e-5 * mag.sum() + 2 * mag[edge].sum(), (f, s)
            assert edge.mean() < 0.01


@pytest.fixture(scope="module")
def one_satellite(tmp_path_factory):
    out = tmp_path_factory.mktemp("trk") / "one.bin"
    cfg = load_scenario(None, [f"signal.fs_hz={FS}", "time.duration_s=4.0", "constellation.max_satellites=4",
                               'signal.format="gr_complex"'])
    simulate_to_file(cfg, out)
    return open_iq(out), read_signal_truth(truth_paths(out)["signals.csv"])


def truth_code_phase(rows, prn, t_s):
    """The truth's code phase (chips) at receiver times t_s, propagated from the nearest earlier truth row."""
    mine = [r for r in rows if r["prn"] == prn]
    ts = np.array([r["t_rx_s"] for r in mine])
    i = np.clip(np.searchsorted(ts, t_s, side="right") - 1, 0, len(mine) - 1)
    cp = np.array([r["code_phase_chips"] for r in mine])[i]
    rate = CA_CHIP_RATE_HZ * (1 + np.array([r["doppler_hz"] for r in mine])[i] / L1_HZ)
    return (cp + (t_s - ts[i]) * rate) % 1023.0


def test_track_kernel_equals_its_reference(one_satellite):
    reader, rows = one_satellite
    t0 = rows[0]
    x = reader.read(0, int(0.3 * FS))
    st0 = initial_state(t0["code_phase_chips"], 0, t0["doppler_hz"] + 30.0, FS, 0)
    prm = loop_params(FS, 0.0, LoopConfig(), pull_in=True)
    st_fast, st_slow = st0.copy(), st0.copy()
    n = 290
    outs = [np.empty(n, dtype=np.complex128) for _ in range(3)] + [np.empty(n) for _ in range(3)] + [np.empty((n, 6))]
    bank = code_bank(int(t0["prn"]), FS)
    m = track_kernel(x, 0, st_fast, prm, bank.rows, bank.first, bank.step_chips, lane_buffer(), *outs)
    ref = track_reference(x, 0, st_slow, prm, ca_code(int(t0["prn"])), n)
    assert m == len(ref) == n
    p_fast, p_slow = outs[1], np.array([r[1] for r in ref])
    # the bank's rounding (a sample within 5e-4 chip of a chip edge may take the neighbouring chip: ~2 samples of
    # |x| ~ 1.3 per period, against |P| ~ 350) and the loops' tiny differences that follow; rarely a block is one
    # sample longer, which moves that period's sums
    close = np.abs(p_fast - p_slow) < 0.03 * np.abs(p_slow)
    assert close.mean() > 0.97, f"{close.mean():.3f} of the prompts agree"
    assert np.allclose(outs[3], [r[3] for r in ref], atol=2e-3)   # code epochs, samples (1e-3 chip)
    from semperfi.receiver import tracking as t
    # CODE_RATE: chips/s, DLL gain 8 Hz times a discriminator within 0.004 chip; CARR_FREQ: Hz
    for index, tol in ((t.CODE_PHASE, 1e-3), (t.CODE_RATE, 0.03), (t.CARR_PHASE, 1e-3), (t.CARR_FREQ, 0.05),
                       (t.CARR_TOTAL, 1e-3), (t.NEXT_SAMPLE, 0.0)):
        assert abs(st_fast[index] - st_slow[index]) <= tol, (index, st_fast[index], st_slow[index])


def test_channels_hold_lock_with_small_code_error(one_satellite):
    reader, rows = one_satellite
    prns = sorted({int(r["prn"]) for r in rows})
    channels = {}
    for prn in prns:
        t = next(r for r in rows if r["prn"] == prn)
        # start from a realistic acquisition error: 0.2 chip and 80 Hz off
        st = initial_state(t["code_phase_chips"] + 0.2, 0, t["doppler_hz"] + 80.0, FS, 0)
        channels[prn] = Channel(prn, FS, 0.0, st)
    base, keep = 0, np.empty(0, dtype=np.complex64)
    for chunk in reader.chunks():
        buf = np.concatenate([keep, chunk])
        for ch in channels.values():
            ch.process(buf, base)
        keep = buf[-4000:]
        base += buf.size - keep.size
    for prn, ch in channels.items():
        assert ch.locked
        idx = np.arange(1000, ch.ms)   # after a second of pull-in
        epochs = ch.epoch_sample[idx % ch.HISTORY_MS]
        err = (truth_code_phase(rows, prn, epochs / FS) + 511.5) % 1023 - 511.5   # code phase 0 at every epoch
        rms = float(np.sqrt(np.mean(err ** 2)))
        assert rms < 0.05, f"PRN {prn}: code phase error RMS {rms:.4f} chip"
        t_last = next(r for r in reversed(rows) if r["prn"] == prn)
        assert abs(ch.doppler_hz[(ch.ms - 1) % ch.HISTORY_MS] - t_last["doppler_hz"]) < 5.0
        assert abs(ch.cn0_dbhz - 45.0) < 1.5, f"PRN {prn}: C/N0 {ch.cn0_dbhz:.1f}"
        assert ch.bits.edge_ms is not None


def test_channel_declares_loss_of_lock_in_noise():
    rng = np.random.default_rng(5)
    ch = Channel(3, FS, 0.0, initial_state(100.0, 0, 1000.0, FS, 0))
    x = (rng.standard_normal(int(3 * FS)) + 1j * rng.standard_normal(int(3 * FS))).astype(np.complex64)
    ch.process(x, 0)
    assert not ch.locked


def test_a_carrier_frequency_step_is_followed_not_lost():
    """A time push switched on at once (TEXBAT's 25 ns/s: the carrier steps by 39 Hz) on a spoofer at 59 dB-Hz with
    its legitimate twin 10 dB under it: a Costas PLL of 18 Hz alone slips out of phase lock (peak phase error about
    half a cycle) and loses the channel; with the FLL back on after a poor lock window it follows the step."""
    fs, prn, dop, step_hz, t_step = 2.6e6, 7, 1200.0, -39.0, 1.5
    rng = np.random.default_rng(3)
    t = np.arange(int(fs * 4.0)) / fs
    after = np.clip(t - t_step, 0.0, None)
    rate = CA_CHIP_RATE_HZ * (1 + dop / L1_HZ)
    code = ca_code(prn)
    spoofer = code[np.floor((t + after * step_hz / L1_HZ) * rate).astype(int) % 1023] * np.exp(
        2j * np.pi * (dop * t + step_hz * after))
    twin = code[np.floor(t * rate).astype(int) % 1023] * np.exp(1j * (2 * np.pi * dop * t + 1.0))
    x = (np.sqrt(10 ** 5.9 / fs) * spoofer + np.sqrt(10 ** 4.9 / fs) * twin
         + (rng.standard_normal(t.size) + 1j * rng.standard_normal(t.size)) / np.sqrt(2)).astype(np.complex64)
    ch = Channel(prn, fs, 0.0, initial_state(0.0, 0, dop + 5.0, fs, 0), LoopConfig())
    dopplers = []
    for end in range(int(fs * 0.1), t.size + 1, int(fs * 0.1)):
        first = int(ch.st[9])       # NEXT_SAMPLE: the buffer from the channel's next code period on
        ch.process(x[first:end], first)
        assert ch.locked, f"lost lock at {end / fs:.1f} s"
        dopplers.append((end / fs, ch.doppler_at(0)))
    late = np.array([d for s, d in dopplers if s > 3.0])
    assert np.all(np.abs(late - (dop + step_hz)) < 3.0), late


def test_channels_run_on_threads_give_what_they_give_one_after_another(monkeypatch):
    """The suite's workers run single-threaded (conftest): the threaded path is checked here, results in order."""
    import numpy as np

    from semperfi.receiver import workers
    monkeypatch.setenv(workers.THREADS_ENV, "2")
    if workers.cores() < 2:
        import pytest
        pytest.skip("one core: no threads to check")
    x = np.random.default_rng(4).normal(size=(6, 50_000))
    threaded = workers.run_each(lambda row: float(np.sum(np.cumsum(row) ** 2)), list(x))
    monkeypatch.setenv(workers.THREADS_ENV, "1")
    serial = workers.run_each(lambda row: float(np.sum(np.cumsum(row) ** 2)), list(x))
    assert threaded == serial


def test_a_channel_steered_from_outside_runs_its_code_from_there_and_keeps_the_lock_it_is_given():
    """Channel.steer (a removal leashed to its spoofer's track): the chip given arrives at the next sample, so the
    next code epoch falls where that chip and the Doppler's chip rate put it, the first at or after that sample; the
    carrier runs at the Doppler given. hold_lock: a channel that lost its lock in noise is locked again."""
    rng = np.random.default_rng(5)
    ch = Channel(3, FS, 0.0, initial_state(100.0, 0, 1000.0, FS, 0))
    x = (rng.standard_normal(int(3 * FS)) + 1j * rng.standard_normal(int(3 * FS))).astype(np.complex64)
    ch.process(x, 0)
    assert not ch.locked
    _, _, at = ch.code_now()
    ch.steer(700.3, -1500.0)
    chips, doppler_hz, sample = ch.code_now()
    step = CA_CHIP_RATE_HZ * (1 - 1500.0 / L1_HZ) / FS
    epoch = at + (1023 - 700.3) / step          # where chip 0 arrives, in samples
    assert doppler_hz == -1500.0 and sample == np.ceil(epoch)
    assert chips == pytest.approx((sample - epoch) * step, abs=1e-9) and 0 <= chips < step
    ch.hold_lock()
    assert ch.locked
