"""Claims about streaming decimation: chunking never changes the output, time is kept, aliases are rejected."""

import numpy as np
import pytest

from semperfi.iq.decimate import StreamDecimator, decimate_chunks, decimation_factor

FS_IN = 25e6


def _tone(freq_hz: float, n: int, noise: float = 0.0, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS_IN
    x = np.exp(2j * np.pi * freq_hz * t)
    if noise:
        x = x + noise * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    return x.astype(np.complex64)


def test_output_does_not_depend_on_chunking():
    x = _tone(0.7e6, 200_000, noise=0.3)
    whole = StreamDecimator(5).process(x)
    cuts = np.cumsum([1, 7, 999, 33_333, 50_000])
    pieces = np.concatenate(list(decimate_chunks(np.split(x, cuts), 5)))
    assert len(pieces) == len(whole), f"{len(pieces)} vs {len(whole)} samples"
    assert np.array_equal(pieces, whole), f"max difference {np.abs(pieces - whole).max()}"


def test_output_sample_j_is_input_time_j_times_m():
    """The filter's delay is compensated: a tone keeps its phase at the decimated instants (no time shift)."""
    f_hz, m = 0.5e6, 10
    y = StreamDecimator(m).process(_tone(f_hz, 100_000))
    ref = np.exp(2j * np.pi * f_hz * np.arange(len(y)) * m / FS_IN)
    err_deg = np.degrees(np.angle(np.mean(y[50:-50] * np.conj(ref[50:-50]))))
    assert abs(err_deg) < 0.5, f"phase error {err_deg:.3f} deg: output not aligned with input time"
    assert abs(np.abs(y[50:-50]).mean() - 1.0) < 0.01, "pass band not flat at 0.5 MHz (0.4 of the output Nyquist)"


def test_out_of_band_tone_is_rejected_not_aliased():
    y = StreamDecimator(5).process(_tone(4.0e6, 100_000))   # would alias to -1 MHz at 5 MSa/s
    level_db = 20 * np.log10(np.abs(y[50:]).max())
    assert level_db < -55, f"4 MHz tone leaks at {level_db:.1f} dB after decimating to 5 MSa/s"


@pytest.mark.parametrize("fs_in, fs_out, word", [(25e6, 4e6, "divide"), (25e6, 1e6, "too low"),
                                                 (25e6, -1.0, "positive")])
def test_bad_processing_rate_is_one_line(fs_in, fs_out, word):
    with pytest.raises(ValueError, match=word):
        decimation_factor(fs_in, fs_out)


def test_kernel_matches_its_upfirdn_reference():
    from semperfi.iq.decimate import _fir_decimate, reference_process
    rng = np.random.default_rng(4)
    for m in (2, 5, 6):
        dec = StreamDecimator(m)
        ext = (rng.standard_normal(5000) + 1j * rng.standard_normal(5000)).astype(np.complex64) * 100
        for phase in (0, 1, m - 1):
            want = reference_process(dec.taps, ext, phase, m)
            got = np.empty(len(want), dtype=np.complex64)
            _fir_decimate(ext.view(np.float32), dec.taps[::-1].copy(), phase, m, got.view(np.float32))
            assert np.abs(got - want).max() < 1e-3 * np.abs(want).max(), (m, phase)
