"""Early/prompt/late correlation over one code period: the numba kernel and its numpy reference.

A block starts at the sample where the code phase is `code_phase_chips` (close to 0: the start of a code period)
and spans the samples up to the next code epoch. The carrier replica is wiped off with a 4096-entry table.
"""

import numpy as np
from numba import njit

from ..gps.constants import CA_CODE_LENGTH_CHIPS

TABLE_BITS = 12
# exp(-j 2 pi phase) at the centre of each table cell: the wipe-off of a carrier with that phase
WIPE_TABLE = np.exp(-2j * np.pi * (np.arange(1 << TABLE_BITS) + 0.5) / (1 << TABLE_BITS)).astype(np.complex64)


def extended_code(code: np.ndarray) -> np.ndarray:
    """The +/-1 code with one chip of wrap-around on each side, so early and late need no modulo (index + 1)."""
    return np.concatenate([code[-1:], code, code[:1]]).astype(np.float32)


@njit(cache=True, nogil=True)
def block_length(code_phase_chips: float, code_step_chips: float) -> int:
    """Samples from code_phase_chips up to (not including) the next code epoch."""
    return int(np.ceil((CA_CODE_LENGTH_CHIPS - code_phase_chips) / code_step_chips))


FIX_BITS = 32                       # fractional bits of the fixed-point code and carrier phases
FIX_ONE = float(1 << FIX_BITS)


@njit(cache=True, nogil=True, fastmath=True)
def correlate_block(x, start, n, code_ext, code_phase_chips, code_step_chips, carrier_phase_cycles,
                    carrier_step_cycles, half_spacing_chips, table):
    """(E, P, L) over x[start:start+n]; carrier phase in cycles at x[start], steps per sample.

    Code and carrier phases are 32.32 fixed point computed from the sample index (not accumulated), so the loop has
    no branch and no carried dependency but the float32 sums: LLVM vectorises it. The quantisation (2^-32 chip or
    cycle per sample) is far below the table's own resolution.
    """
    table_shift = FIX_BITS - TABLE_BITS   # table has 1 << TABLE_BITS entries
    mask = table.size - 1
    ph0 = np.int64((carrier_phase_cycles - np.floor(carrier_phase_cycles)) * FIX_ONE)
    dph = np.int64(np.round((carrier_step_cycles - np.floor(carrier_step_cycles)) * FIX_ONE))
    # +1 keeps code positions positive (and indexes code_ext, which has one chip of wrap-around on each side)
    pos_e = np.int64((code_phase_chips + half_spacing_chips + 1.0) * FIX_ONE)
    pos_p = np.int64((code_phase_chips + 1.0) * FIX_ONE)
    pos_l = np.int64((code_phase_chips - half_spacing_chips + 1.0) * FIX_ONE)
    dpos = np.int64(np.round(code_step_chips * FIX_ONE))
    e_re = e_im = p_re = p_im = l_re = l_im = np.float32(0.0)
    for k in range(n):
        v = x[start + k]
        c = table[((ph0 + k * dph) >> table_shift) & mask]
        wr = v.real * c.real - v.imag * c.imag
        wi = v.real * c.imag + v.imag * c.real
        d = k * dpos
        pe = code_ext[(pos_e + d) >> FIX_BITS]
        pp = code_ext[(pos_p + d) >> FIX_BITS]
        pl = code_ext[(pos_l + d) >> FIX_BITS]
        e_re += pe * wr
        e_im += pe * wi
        p_re += pp * wr
        p_im += pp * wi
        l_re += pl * wr
        l_im += pl * wi
    return complex(e_re, e_im), complex(p_re, p_im), complex(l_re, l_im)


def correlate_block_reference(x, code, code_phase_chips, code_step_chips, carrier_phase_cycles, carrier_step_cycles,
                              half_spacing_chips):
    """The same sums with numpy and an exact exponential (slow; for tests)."""
    k = np.arange(x.size)
    pos = code_phase_chips + k * code_step_chips
    wiped = x * np.exp(-2j * np.pi * (carrier_phase_cycles + k * carrier_step_cycles))
    chip = lambda offset: code[np.floor(pos + offset).astype(np.int64) % CA_CODE_LENGTH_CHIPS]
    return tuple(complex(np.sum(wiped * chip(o))) for o in (half_spacing_chips, 0.0, -half_spacing_chips))
