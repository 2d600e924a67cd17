"""C/A signals for tests, at baseband: the code sampled at the signal's own chip rate (Doppler on the code too)."""

import numpy as np

from semperfi.gps import CA_CHIP_RATE_HZ, L1_HZ, ca_code


def ca_signal(prn: int, t_s: np.ndarray, code_phase_chips: float, doppler_hz: float, amplitude: float,
              phase_rad: float = 0.0, bits: np.ndarray | None = None) -> np.ndarray:
    """amplitude * data * code * carrier at times t_s, the code at code_phase_chips at t = 0; bits (optional): 50 bit/s
    data, a bit every 20 of the signal's own code periods, from its first epoch on (repeating)."""
    chips = code_phase_chips + t_s * CA_CHIP_RATE_HZ * (1 + doppler_hz / L1_HZ)
    out = amplitude * ca_code(prn)[np.floor(chips).astype(np.int64) % 1023] \
        * np.exp(1j * (2 * np.pi * doppler_hz * t_s + phase_rad))
    if bits is not None:
        out = out * bits[np.floor(chips / 1023 / 20).astype(np.int64) % bits.size]
    return out
