"""The two-path fit beside strong signals of other PRNs: their cross-talk into each 1 ms block is not a second path."""

import numpy as np
import pytest

from semperfi.defense.detector import (TWO_PATH_BLOCK_S, DetectorConfig, cross_power, cross_power_reference,
                                      hidden_pair, is_cross_talk)
from semperfi.receiver.acquisition import DopplerGrid, Peak, acquire
from signals import ca_signal

FS = 2.6e6
T = np.arange(int(FS * 0.04)) / FS


def _signal(prn, chips, doppler_hz, phase, cn0_dbhz):
    return ca_signal(prn, T, chips, doppler_hz, np.sqrt(10 ** (cn0_dbhz / 10) / FS), phase)


@pytest.mark.parametrize("seed", range(6))
def test_strong_prns_cross_talk_is_no_second_path_and_a_real_one_is(seed):
    """A 45 dB-Hz PRN beside eight 60 dB-Hz spoofers of other PRNs (a +10 dB attacker on the strong satellites):
    the fit finds a "second path" some 12 dB down that is their summed cross-talk, and it is judged so; a real
    second signal 4 dB down a chip away is not."""
    rng = np.random.default_rng(seed)
    x = (rng.standard_normal(T.size) + 1j * rng.standard_normal(T.size)) / np.sqrt(2)
    strong = rng.choice([p for p in range(1, 33) if p != 5], 8, replace=False)
    for prn in strong:
        x = x + _signal(prn, rng.uniform(0, 1023), rng.uniform(-3000, 3000), rng.uniform(0, 2 * np.pi), 55.0)
    doppler = rng.uniform(-3000, 3000)
    x = x + _signal(5, 300.3, doppler, 0.3, 45.0)
    cfg = DetectorConfig()

    def judged(samples):
        samples = samples.astype(np.complex64)
        cafs = acquire(samples[:int(FS * 1e-3) * 20], FS, [5, *strong], DopplerGrid(0, 5000, 333.0), 0.0, 2, 10,
                       1e-3, 8)
        pair = hidden_pair(samples, FS, 0.0, cafs[5].best, cfg, sensitive=True)
        return pair, pair is not None and is_cross_talk(pair.auxiliary, cafs[5], cafs, cfg, FS,
                                                        block_s=TWO_PATH_BLOCK_S)

    pair, cross_talk = judged(x)
    assert pair is None or cross_talk, pair
    pair, cross_talk = judged(x + _signal(5, 301.3, doppler, 2.0, 42.0))
    assert pair is not None and not cross_talk and abs(pair.separation_chips - 1.0) < 0.15, pair


@pytest.mark.parametrize("block_ms", [1, 2])
def test_the_cross_power_kernel_is_its_reference(block_ms):
    """The phasor-turned kernel against the exponentials of the plain numpy sum, over random pairs of signals: the
    same power to a part in 1e9, including the same-PRN case (a code's own autocorrelation) and 5 kHz apart."""
    rng = np.random.default_rng(7)
    n = int(FS * 2e-3)
    for _ in range(40):
        a = Peak(int(rng.integers(1, 33)), rng.uniform(0, 1023), rng.uniform(-5000, 5000), 10.0, 45.0)
        b = Peak(int(rng.integers(1, 33)), rng.uniform(0, 1023), rng.uniform(-5000, 5000), 50.0, 55.0)
        k = int(FS * block_ms * 1e-3)
        want = cross_power_reference(a, b, FS, n, k)
        assert cross_power(a, b, FS, n, k) == pytest.approx(want, rel=1e-9, abs=1e-15)
    same = Peak(a.prn, a.code_phase_chips, a.doppler_hz, 50.0, 55.0)
    assert cross_power(a, same, FS, n, n) == pytest.approx(1.0, abs=1e-12)   # the code against itself: all of it
