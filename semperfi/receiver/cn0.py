"""Carrier-to-noise density from correlator outputs."""

import numpy as np

from ..gps import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, L1_HZ, ca_code


def correlate_ms(samples: np.ndarray, fs_hz: float, prn: int, code_phase_chips, doppler_hz: float,
                 if_hz: float = 0.0) -> np.ndarray:
    """One complex correlation per millisecond against a replica that follows the code Doppler; for several code
    phases at once (code_phase_chips a sequence: one row each), the carrier wiped off once for all of them.

    code_phase_chips is the chip arriving at the first sample (the convention of acquisition and the truth log).
    """
    phases = np.atleast_1d(np.asarray(code_phase_chips, dtype=np.float64))
    n_ms = int(round(fs_hz * 1e-3))
    n_blocks = samples.size // n_ms
    chip_rate = CA_CHIP_RATE_HZ * (1.0 + doppler_hz / L1_HZ)
    code = ca_code(prn)
    out = np.empty((phases.size, n_blocks), dtype=np.complex128)
    step = 100   # milliseconds per pass: bounded memory, continuous phase (k counts from the first sample)
    for b0 in range(0, n_blocks, step):
        b1 = min(b0 + step, n_blocks)
        k = np.arange(b0 * n_ms, b1 * n_ms)
        wiped = samples[k] * np.exp(-2j * np.pi * (doppler_hz + if_hz) / fs_hz * k)
        for row, phase in enumerate(phases):
            chips = np.floor(phase + k * (chip_rate / fs_hz)).astype(np.int64) % CA_CODE_LENGTH_CHIPS
            out[row, b0:b1] = (wiped * code[chips]).reshape(-1, n_ms).sum(axis=1)
    return out if np.ndim(code_phase_chips) else out[0]


def cn0_known_noise_dbhz(prompt: np.ndarray, off_peak: np.ndarray, block_s: float = 1e-3) -> float:
    """C/N0 from prompt correlations and correlations far from any peak (which hold only noise).

    E|P|^2 = C T^2 fs^2-ish + sigma^2 and E|N|^2 = sigma^2 in the same units, so C/N0 = (|P|^2 - s2) / s2 / T.
    """
    noise = float(np.mean(np.abs(off_peak) ** 2))
    signal = float(np.mean(np.abs(prompt) ** 2)) - noise
    return float(10 * np.log10(max(signal, 1e-30) / noise / block_s))
