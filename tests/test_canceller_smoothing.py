"""The canceller's per-period amplitude smoothing follows a twin that turns in the spoofer's carrier frame (their
Dopplers differ by up to a few hertz): a lag there would leave a copy of the twin in the spoofer's estimate, and
the subtraction would carve it out of the legitimate signal (a bias of metres on the twin's range)."""

import numpy as np
import pytest

from semperfi.defense.canceller import decision_smooth, decision_smooth_reference, rotation_per_period

LAM = 1.0 / 16                 # CancellerConfig.smoothing_ms
PERIODS = 4000                 # 4 s of code periods


def _twin(beat_hz: float, snr_db: float = 13.0, seed: int = 3):
    """Unit amplitude turning at beat_hz, 50 bit/s data, complex noise at snr_db per period."""
    rng = np.random.default_rng(seed)
    k = np.arange(PERIODS)
    bits = np.repeat(rng.choice([-1.0, 1.0], PERIODS // 20 + 1), 20)[:PERIODS]
    clean = np.exp(2j * np.pi * beat_hz * k * 1e-3 + 0.7j) * bits
    sigma = 10 ** (-snr_db / 20) / np.sqrt(2)
    return clean, clean + sigma * (rng.standard_normal(PERIODS) + 1j * rng.standard_normal(PERIODS))


@pytest.mark.parametrize("beat_hz", [-3.0, -0.8, 0.0, 0.8, 6.0, 26.0, -150.0, 240.0, -410.0])
def test_the_turn_per_period_is_measured_through_the_data_bits(beat_hz):
    """Up to a fast drone's, or a takeover's, few hundred hertz between a twin and its spoofer: over 10 periods
    alone, 26 Hz read as -24, -150 as nought."""
    _, noisy = _twin(beat_hz)
    turn = rotation_per_period(noisy[:200])        # one buffer
    # the angle's noise over 190 squared products at 13 dB, seen over 10 periods: ~3e-3 rad, well under this
    assert np.angle(turn) == pytest.approx(2 * np.pi * beat_hz * 1e-3, abs=1e-3)


def test_smoothing_with_the_turn_does_not_lag_a_turning_twin():
    clean, noisy = _twin(0.8)
    start = clean[0]
    lagging, _ = decision_smooth(noisy, start, LAM)
    turn = rotation_per_period(noisy)
    following, _ = decision_smooth(noisy, start, LAM, turn)
    settle = 200
    bias_lagging = abs(np.mean((lagging - clean)[settle:] * np.conj(clean[settle:])))
    bias_following = abs(np.mean((following - clean)[settle:] * np.conj(clean[settle:])))
    # a first-order smoother of time constant 16 periods lags a 0.8 Hz turn by 2 pi 0.8 Hz 16 ms = 0.08 rad: an error
    # of 8 % of the amplitude, always on the same side; with the turn predicted only the noise is left, which averages
    assert bias_lagging == pytest.approx(2 * np.pi * 0.8 * 16e-3, rel=0.2)
    assert bias_following < 0.01


def test_without_a_turn_the_smoothing_is_unchanged():
    _, noisy = _twin(0.0)
    a, ra = decision_smooth(noisy, noisy[0], LAM)
    b, rb = decision_smooth(noisy, noisy[0], LAM, 1.0)
    np.testing.assert_array_equal(a, b)
    assert ra == rb


@pytest.mark.parametrize("turn", [1.0, np.exp(0.005j)])
def test_the_compiled_smoothing_equals_its_reference(turn):
    """The kernel against the plain Python loop it compiles: the same estimates and reference (data bits flipping, a
    reference started against the first period's sign, no periods at all) to the last bits of their rounding -- on
    a CPU with FMA the compiler may fuse a complex product's multiply and add, which Python rounds twice (seen: 1
    ulp on 73 % of the periods with a turn, after a recompilation)."""
    _, noisy = _twin(2.0, snr_db=3.0)
    fast, ref_fast = decision_smooth(noisy, -noisy[0], LAM, turn)
    slow, ref_slow = decision_smooth_reference(noisy, -noisy[0], LAM, turn)
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-12)
    assert np.sign(fast.real).tolist() == np.sign(slow.real).tolist()   # the same data bit every period
    assert ref_fast == pytest.approx(ref_slow, rel=1e-12)
    empty, ref = decision_smooth(noisy[:0], 0.5 + 0.5j, LAM, turn)
    assert empty.size == 0 and ref == 0.5 + 0.5j
