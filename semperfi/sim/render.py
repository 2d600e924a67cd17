"""Rendering satellite signals into complex baseband: a numba kernel and the numpy reference it must equal.

Within one chunk every signal's code phase and carrier phase are linear in the sample index (the pseudorange is
interpolated linearly between chunk boundaries), so each sample costs an add, two table reads and a multiply.
"""

import numpy as np
from numba import njit

from ..gps import CA_CODE_LENGTH_CHIPS, CHIPS_PER_BIT

CARRIER_TABLE_BITS = 12
CARRIER_TABLE = np.exp(2j * np.pi * (np.arange(1 << CARRIER_TABLE_BITS) + 0.5)
                       / (1 << CARRIER_TABLE_BITS)).astype(np.complex64)


@njit(cache=True, nogil=True)
def _render_kernel(out, codes, bits, chips0, chip_rate, phase0_cycles, phase_rate_cycles, amplitude, table):
    n_table = table.size
    period = float(CA_CODE_LENGTH_CHIPS)
    for s in range(chips0.size):
        a = amplitude[s]
        if a == 0.0:
            continue
        code = codes[s]
        b = bits[s]
        # incremental phases: no division or modulo per sample; the float error over a chunk is ~1e-9 chip
        epochs = np.int64(chips0[s] // period)
        c = chips0[s] - epochs * period
        bit = epochs // 20
        epoch_in_bit = epochs - bit * 20
        cr = chip_rate[s]
        ph = phase0_cycles[s] - np.floor(phase0_cycles[s])
        pr = phase_rate_cycles[s] - np.floor(phase_rate_cycles[s])   # cycles per sample, folded into [0, 1)
        for k in range(out.size):
            out[k] += (a * code[np.int64(c)] * b[bit]) * table[np.int64(ph * n_table)]
            c += cr
            if c >= period:
                c -= period
                epoch_in_bit += 1
                if epoch_in_bit == 20:
                    epoch_in_bit = 0
                    bit += 1
            ph += pr
            if ph >= 1.0:
                ph -= 1.0


def render(out: np.ndarray, codes: np.ndarray, bits: np.ndarray, chips0: np.ndarray, chip_rate: np.ndarray,
           phase0_cycles: np.ndarray, phase_rate_cycles: np.ndarray, amplitude: np.ndarray) -> None:
    """Add signals into out (complex64): sum_s a_s * bit_s * code_s * exp(j 2 pi phase_s).

    Per signal s (rows): codes[s] is its +/-1 C/A code, bits[s] its +/-1 data bits from the first bit of the
    window, chips0[s] the chips since that bit's start at sample 0 (>= 0), chip_rate[s] chips per sample,
    phase0/phase_rate the carrier phase in cycles and cycles per sample.
    """
    _render_kernel(out, codes, bits, chips0, chip_rate, phase0_cycles, phase_rate_cycles, amplitude, CARRIER_TABLE)


def render_reference(n_samples: int, codes, bits, chips0, chip_rate, phase0_cycles, phase_rate_cycles, amplitude):
    """The same sum computed plainly with numpy and an exact complex exponential (slow; for tests)."""
    k = np.arange(n_samples)
    out = np.zeros(n_samples, dtype=np.complex128)
    for s in range(len(chips0)):
        chip = np.floor(chips0[s] + k * chip_rate[s]).astype(np.int64)
        phase = phase0_cycles[s] + k * phase_rate_cycles[s]
        out += amplitude[s] * codes[s][chip % CA_CODE_LENGTH_CHIPS] * bits[s][chip // CHIPS_PER_BIT] \
            * np.exp(2j * np.pi * phase)
    return out
