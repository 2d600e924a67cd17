"""Rendering satellite signals into complex baseband: a numba kernel and the numpy reference it must equal.

Within one chunk every signal's code phase and carrier phase are linear in the sample index (the pseudorange is
interpolated linearly between chunk boundaries), so each sample costs two table reads and a multiply-add: its
chip's value (amplitude, code and data bit) and its carrier phasor.
"""

import numpy as np
from numba import njit

from ..gps import CA_CODE_LENGTH_CHIPS, CHIPS_PER_BIT

CARRIER_TABLE_BITS = 12
CARRIER_TABLE = np.exp(2j * np.pi * (np.arange(1 << CARRIER_TABLE_BITS) + 0.5)
                       / (1 << CARRIER_TABLE_BITS)).astype(np.complex64)


PHASE_FRACTION_BITS = 40   # the carrier's phase in fixed point: 2^-41 cycle a sample, k * step within int64


@njit(cache=True, nogil=True, fastmath=True)
def _render_kernel(out, codes, bits, chips0, chip_rate, phase0_cycles, phase_rate_cycles, amplitude, table):
    n = out.size
    shift = PHASE_FRACTION_BITS - CARRIER_TABLE_BITS
    mask = (1 << CARRIER_TABLE_BITS) - 1
    one = float(1 << PHASE_FRACTION_BITS)
    for s in range(chips0.size):
        a = amplitude[s]
        if a == 0.0:
            continue
        code = codes[s]
        b = bits[s]
        # amplitude x code x data bit for every chip the chunk spans: then a sample is a read by its chip's index,
        # with no branch at code epochs or bit edges (half the time of an incremental loop that tests for them)
        # (one chip to spare: offset + k * rate below may round up across a chip edge that chips0 + k * rate did not)
        first = np.int64(chips0[s])
        span = np.int64(chips0[s] + (n - 1) * chip_rate[s]) - first + 2
        chip_values = np.empty(span, dtype=np.float32)
        for j in range(span):
            chip = first + j
            chip_values[j] = a * code[chip % CA_CODE_LENGTH_CHIPS] * b[chip // CHIPS_PER_BIT]
        offset, rate = chips0[s] - first, chip_rate[s]
        ph = np.int64((phase0_cycles[s] - np.floor(phase0_cycles[s])) * one)
        step = np.int64(np.round((phase_rate_cycles[s] - np.floor(phase_rate_cycles[s])) * one))
        for k in range(n):
            out[k] += chip_values[np.int64(offset + k * rate)] * table[((ph + k * step) >> shift) & mask]


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
