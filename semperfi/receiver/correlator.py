"""Early/prompt/late correlation over one code period: the numba kernel and its numpy reference.

A block starts at the sample where the code phase is `code_phase_chips` (close to 0: the start of a code period)
and spans the samples up to the next code epoch.

Why a code bank: looking the code up per sample (three gathers and a carrier table per sample) keeps a CPU scalar.
Instead the PRN's code is sampled once at the receiver's nominal chips-per-sample, at BANK phases one
QUANTUM_CHIPS apart; a block is cut into sub-blocks short enough that the true code rate stays within a quantum of
the nominal one over each, and each sub-block reads one contiguous int8 row per replica. The carrier is a rotator:
a float64 phasor per sub-block times precomputed lane phasors. The inner loop has no gather and no branch, and LLVM
vectorises it.
"""

import weakref
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..gps import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, ca_code

QUANTUM_CHIPS = 1e-3        # replica phases are within this (0.3 m) of the true code, dithered as the code moves:
                            # far below the DLL's noise (5e-4 gave the same fixes, for a bank twice as big)
BANK_MARGIN_CHIPS = 4.0     # code wrapped on each side: more than early/late and the canceller's probes
                            # (1.5 chips) reach
MAX_SUB_SAMPLES = 1024      # longest sub-block (the lane phasors' length)
LANE_GROUP = 16


@dataclass(frozen=True)
class CodeBank:
    """One PRN's code at one sample rate: rows[f, i] = code[floor((i - first + f / phases) * step_chips)] (a
    shaped bank's, the code as a front end rounds its chips, times `scale`)."""
    rows: np.ndarray          # int8 (phases, columns)
    first: int                # column of chip 0 at phase 0
    step_chips: float         # nominal chips per sample
    scale: float = 1.0        # rows / scale is the code

    def __deepcopy__(self, memo):   # read-only and shared: a copied channel keeps the same bank
        return self


_BANKS: "weakref.WeakValueDictionary[tuple[int, float], CodeBank]" = weakref.WeakValueDictionary()


def code_bank(prn: int, fs_hz: float) -> CodeBank:
    """The bank for a PRN at a sample rate (1 MB whatever the rate), shared by the channels of that PRN (the
    receiver's, the canceller's, the identifier's) while one of them holds it."""
    bank = _BANKS.get((prn, fs_hz))
    if bank is None:
        bank = _BANKS[(prn, fs_hz)] = _make_bank(prn, fs_hz)
    return bank


def _make_bank(prn: int, fs_hz: float) -> CodeBank:
    step = CA_CHIP_RATE_HZ / fs_hz
    phases = int(np.ceil(step / QUANTUM_CHIPS))
    first = int(np.ceil(BANK_MARGIN_CHIPS / step))
    columns = first + int(np.ceil((CA_CODE_LENGTH_CHIPS + BANK_MARGIN_CHIPS) / step)) + 1
    col = np.arange(columns) - first
    chips = np.floor((col[None, :] + np.arange(phases)[:, None] / phases) * step).astype(np.int64)
    rows = ca_code(prn)[chips % CA_CODE_LENGTH_CHIPS].astype(np.int8)
    rows.flags.writeable = False
    return CodeBank(rows, first, step)


def lane_buffer() -> np.ndarray:
    """Scratch for the kernels' lane phasors (one per thread of work: kernels write to it)."""
    return np.empty(MAX_SUB_SAMPLES + LANE_GROUP, dtype=np.complex64)


@njit(cache=True, nogil=True)
def fill_lanes(lanes, step_cycles, m, sign):
    """lanes[j] = exp(sign * 2 pi i * j * step_cycles) for j < m (rounded up to whole groups of LANE_GROUP), from
    two short recurrences: one within a group, one from group to group."""
    a = sign * 2.0 * np.pi * step_cycles
    small = np.empty(LANE_GROUP, dtype=np.complex128)
    r1 = complex(np.cos(a), np.sin(a))
    c = 1.0 + 0.0j
    for b in range(LANE_GROUP):
        small[b] = c
        c *= r1
    big = 1.0 + 0.0j
    r16 = complex(np.cos(a * LANE_GROUP), np.sin(a * LANE_GROUP))
    for g in range(0, m, LANE_GROUP):
        for b in range(LANE_GROUP):
            lanes[g + b] = big * small[b]
        big *= r16


@njit(cache=True, nogil=True)
def sub_block_samples(code_step_chips, bank_step_chips):
    """Longest sub-block over which the true and nominal code steps part by less than a quantum: the whole
    MAX_SUB_SAMPLES for Dopplers and crystals within ~100 ppm, shorter (slower, as exact) beyond."""
    drift = abs(code_step_chips - bank_step_chips)
    if drift * MAX_SUB_SAMPLES <= QUANTUM_CHIPS:
        return MAX_SUB_SAMPLES
    return max(1, int(QUANTUM_CHIPS / drift))


@njit(cache=True, nogil=True)
def replica(rows, first, bank_step, code_phase_chips, code_step_chips, k0, m):
    """The m code samples from sample k0 of a block whose sample 0 is at code_phase_chips: the bank row whose
    phase is right at the sub-block's centre (its ends then stay within half a quantum of the true code)."""
    q = code_phase_chips + (k0 + 0.5 * (m - 1)) * code_step_chips - 0.5 * (m - 1) * bank_step
    b = q / bank_step + first
    col = np.int64(np.floor(b))
    row = np.int64(np.round((b - col) * rows.shape[0]))
    if row == rows.shape[0]:
        col += 1
        row = 0
    return rows[row, col:col + m]


@njit(cache=True, nogil=True)
def block_length(code_phase_chips: float, code_step_chips: float) -> int:
    """Samples from code_phase_chips up to (not including) the next code epoch."""
    return int(np.ceil((CA_CODE_LENGTH_CHIPS - code_phase_chips) / code_step_chips))


@njit(cache=True, nogil=True, fastmath=True)
def correlate_block(x, start, n, rows, first, bank_step, code_phase_chips, code_step_chips, carrier_phase_cycles,
                    carrier_step_cycles, half_spacing_chips, lanes):
    """(E, P, L) over x[start:start+n]; carrier phase in cycles at x[start], steps per sample. Sums are float32
    within a sub-block, float64 across."""
    m_max = sub_block_samples(code_step_chips, bank_step)
    fill_lanes(lanes, carrier_step_cycles, m_max, -1.0)
    e_re = e_im = p_re = p_im = l_re = l_im = 0.0
    k0 = 0
    while k0 < n:
        m = min(m_max, n - k0)
        a = -2.0 * np.pi * (carrier_phase_cycles + k0 * carrier_step_cycles)
        c0r, c0i = np.float32(np.cos(a)), np.float32(np.sin(a))
        re_e = replica(rows, first, bank_step, code_phase_chips + half_spacing_chips, code_step_chips, k0, m)
        re_p = replica(rows, first, bank_step, code_phase_chips, code_step_chips, k0, m)
        re_l = replica(rows, first, bank_step, code_phase_chips - half_spacing_chips, code_step_chips, k0, m)
        xs = x[start + k0:start + k0 + m]
        ser = sei = spr = spi = slr = sli = np.float32(0.0)
        for j in range(m):
            v = xs[j]
            ln = lanes[j]
            cr = c0r * ln.real - c0i * ln.imag
            ci = c0r * ln.imag + c0i * ln.real
            wr = v.real * cr - v.imag * ci
            wi = v.real * ci + v.imag * cr
            ce, cp_, cl = np.float32(re_e[j]), np.float32(re_p[j]), np.float32(re_l[j])
            ser += ce * wr
            sei += ce * wi
            spr += cp_ * wr
            spi += cp_ * wi
            slr += cl * wr
            sli += cl * wi
        e_re += ser
        e_im += sei
        p_re += spr
        p_im += spi
        l_re += slr
        l_im += sli
        k0 += m
    return complex(e_re, e_im), complex(p_re, p_im), complex(l_re, l_im)


def correlate_block_reference(x, code, code_phase_chips, code_step_chips, carrier_phase_cycles, carrier_step_cycles,
                              half_spacing_chips):
    """The same sums with numpy, the exact code phase and an exact exponential (slow; for tests)."""
    k = np.arange(x.size)
    pos = code_phase_chips + k * code_step_chips
    wiped = x * np.exp(-2j * np.pi * (carrier_phase_cycles + k * carrier_step_cycles))

    def chip(offset):
        return code[np.floor(pos + offset).astype(np.int64) % CA_CODE_LENGTH_CHIPS]
    return tuple(complex(np.sum(wiped * chip(o))) for o in (half_spacing_chips, 0.0, -half_spacing_chips))
