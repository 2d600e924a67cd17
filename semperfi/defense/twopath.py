"""Are there two signals of one PRN under a single correlation peak? A generalised likelihood ratio test.

A seamless takeover starts with the spoofed peak on top of the legitimate one; the two only become separate local
maxima of the CAF once they are about a chip apart. Modelling the samples of each 1 ms block as
x = a c(tau1) + b c(tau2) + noise (c the sampled code, complex a and b per block), the least-squares fit of one or
two paths is closed-form, and the energy each explains is

    E1(tau)       = sum_b |y_b(tau)|^2 / K
    E2(tau1,tau2) = sum_b y_b^H G^-1 y_b,   G = [[K, m], [m, K]],  m = <c(tau1), c(tau2)>

with y_b(tau) the block's correlation with the code delayed by tau. Under one path, (max E2 - max E1) / sigma^2
is about chi-square with 2 x blocks degrees of freedom (times 1/2), which sets the threshold.
"""

import functools
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..gps import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, L1_HZ, ca_code, chips_apart
from ..receiver import chi2_isf


@dataclass(frozen=True)
class TwoPathFit:
    prn: int
    code_phase_chips: float          # the stronger path
    second_code_phase_chips: float   # the weaker path
    power_ratio_db: float            # weaker / stronger
    statistic: float                 # (E2 - E1) / sigma^2
    threshold: float

    @property
    def separation_chips(self) -> float:
        return chips_apart(self.second_code_phase_chips, self.code_phase_chips)

    @property
    def significant(self) -> bool:
        return self.statistic > self.threshold


PAD_CHIPS = 8


@njit(cache=True, nogil=True, fastmath=True)
def _profile_kernel(samples, block_carrier, carrier, code_phase_chips, chips_per_sample, sub, frac_sub, frac_of,
                    shift_of, code_pad, n_blocks, k):
    """y[i, b] = sum over block b of the wiped samples * code(position + frac_sub[frac_of[i]] / sub + shift_of[i]);
    and the first block's replicas r[i, t], whose Gram matrix r r^T the caller forms (BLAS does a matrix product far
    faster).

    Each block is wiped off (its carrier: one block's exponentials turned by the block's own) and its code positions
    found here, in one pass. Every offset is a whole number of 1/sub chips: the samples are summed once per 1/sub of
    a chip, and a chip's sum at any fractional offset is a difference of their running sums -- the cost of a block
    no longer grows with the sample rate times the number of offsets. Offsets a whole number of chips apart share
    those chip sums, and each offset's correlation is the code, shifted, against them."""
    n_off = frac_of.size
    n_chips = CA_CODE_LENGTH_CHIPS + 1
    n_sub = CA_CODE_LENGTH_CHIPS * sub
    y = np.zeros((n_off, n_blocks), dtype=np.complex128)
    chip, rest = np.empty(k, dtype=np.int64), np.empty(k, dtype=np.int64)
    c_re, c_im = np.zeros(n_sub + 1), np.zeros(n_sub + 1)
    b_re, b_im = np.empty(n_chips), np.empty(n_chips)
    first = np.empty((n_off, k), dtype=np.float32)   # +/-1: its products sum exactly in single precision
    for b in range(n_blocks):
        c_re[:] = 0.0
        c_im[:] = 0.0
        turn = block_carrier[b]
        # whole code periods taken off by subtraction instead of a remainder per sample: an integer times the period
        # off the position is exact in floating point, as the remainder is
        wraps = np.floor((code_phase_chips + b * k * chips_per_sample) / CA_CODE_LENGTH_CHIPS)
        for t in range(k):
            w = samples[b * k + t] * carrier[t] * turn
            pos = (code_phase_chips + (b * k + t) * chips_per_sample) - wraps * CA_CODE_LENGTH_CHIPS
            if pos >= CA_CODE_LENGTH_CHIPS:
                wraps += 1.0
                pos -= CA_CODE_LENGTH_CHIPS
            fine = min(np.int64(pos * sub), n_sub - 1)
            c_re[fine + 1] += w.real
            c_im[fine + 1] += w.imag
            if b == 0:   # floor(pos + j / sub) = chip + (rest + j >= sub): no division per offset below
                chip[t], rest[t] = fine // sub, fine % sub
        for g in range(n_sub):
            c_re[g + 1] += c_re[g]
            c_im[g + 1] += c_im[g]
        for f in range(frac_sub.size):
            j = frac_sub[f]
            # chip m at this offset: the 1/sub bins from m * sub - j on (the first chip starts at 0, the last one
            # ends at n_sub: they are cut short, or empty)
            b_re[0], b_im[0] = c_re[sub - j], c_im[sub - j]
            for m in range(1, n_chips - 1):
                lo = m * sub - j
                b_re[m] = c_re[lo + sub] - c_re[lo]
                b_im[m] = c_im[lo + sub] - c_im[lo]
            lo = CA_CODE_LENGTH_CHIPS * sub - j
            b_re[n_chips - 1] = c_re[n_sub] - c_re[lo] if j > 0 else 0.0
            b_im[n_chips - 1] = c_im[n_sub] - c_im[lo] if j > 0 else 0.0
            for i in range(n_off):
                if frac_of[i] != f:
                    continue
                base = shift_of[i] + PAD_CHIPS
                acc_re, acc_im = 0.0, 0.0
                for m in range(n_chips):
                    acc_re += code_pad[m + base] * b_re[m]
                    acc_im += code_pad[m + base] * b_im[m]
                y[i, b] = acc_re + 1j * acc_im
                if b == 0:
                    for t in range(k):
                        first[i, t] = code_pad[chip[t] + (1 if rest[t] + j >= sub else 0) + base]
    return y, first


MAX_SUB = 1000   # offsets on a grid finer than 1/MAX_SUB chip are refused


@functools.lru_cache(maxsize=16)
def _split_offsets(offsets_chips: tuple) -> tuple:
    """The offsets' grid (every offset a whole number of 1/sub chips), each offset's fractional part in 1/sub chips
    (shared by offsets whole chips apart: frac_sub[frac_of[i]]) and its whole number of chips (cached: every fit
    asks for the same grid)."""
    offsets = np.asarray(offsets_chips, dtype=np.float64)
    sub = next((r for r in range(1, MAX_SUB + 1) if np.allclose(offsets * r, np.round(offsets * r), atol=1e-6)), None)
    if sub is None:
        raise ValueError(f"delay offsets must lie on a grid of 1/{MAX_SUB} chip or coarser")
    units = np.round(offsets * sub).astype(np.int64)
    shift = np.floor_divide(units, sub)
    frac_sub, frac_of = np.unique(units - shift * sub, return_inverse=True)
    return sub, frac_sub.astype(np.int64), frac_of.astype(np.int64), shift.astype(np.int64)


@functools.lru_cache(maxsize=64)
def float_code(prn: int) -> np.ndarray:
    """The PRN's C/A code as +/-1.0 (read-only): what the kernels multiply samples by."""
    code = ca_code(prn).astype(np.float64)
    code.setflags(write=False)
    return code


def _chips_per_sample(fs_hz, doppler_hz):
    return CA_CHIP_RATE_HZ * (1.0 + doppler_hz / L1_HZ) / fs_hz


def _carrier(fs_hz, doppler_hz, if_hz, n_blocks):
    """The carrier of one block, and each block's start phase: k + n_blocks exponentials instead of k * n_blocks."""
    k = int(round(fs_hz * 1e-3))
    cycles = (doppler_hz + if_hz) / fs_hz
    return np.exp(-2j * np.pi * cycles * (k * np.arange(n_blocks))), np.exp(-2j * np.pi * cycles * np.arange(k))


def _wipe_and_positions(samples, fs_hz, code_phase_chips, doppler_hz, if_hz, n_blocks):
    block_carrier, carrier = _carrier(fs_hz, doppler_hz, if_hz, n_blocks)
    k = carrier.size
    n = k * n_blocks
    t = np.arange(n)
    wiped = (samples[:n].reshape(n_blocks, k) * block_carrier[:, None] * carrier).ravel()
    return wiped, (code_phase_chips + t * _chips_per_sample(fs_hz, doppler_hz)) % CA_CODE_LENGTH_CHIPS, k


def delay_profile(samples, fs_hz, prn, code_phase_chips, doppler_hz, if_hz, offsets_chips, n_blocks):
    """Per-block correlations y[i, b] with the code delayed by offsets_chips[i] around code_phase_chips, and the
    code's Gram matrix m[i, j] over one block (samples per block K = one code period)."""
    if np.max(np.abs(offsets_chips)) >= PAD_CHIPS - 1:
        raise ValueError(f"delay offsets beyond +/-{PAD_CHIPS - 1} chips")
    k = int(round(fs_hz * 1e-3))
    block_carrier, carrier = _carrier(fs_hz, doppler_hz, if_hz, n_blocks)
    code = float_code(prn)
    code_pad = np.concatenate([code[-PAD_CHIPS:], code, code[:PAD_CHIPS]])
    y, first = _profile_kernel(np.ascontiguousarray(samples[:k * n_blocks]), block_carrier, carrier,
                               float(code_phase_chips), _chips_per_sample(fs_hz, doppler_hz),
                               *_split_offsets(tuple(np.asarray(offsets_chips, dtype=np.float64))), code_pad,
                               n_blocks, k)
    return y, (first @ first.T).astype(np.float64), k


def delay_profile_reference(samples, fs_hz, prn, code_phase_chips, doppler_hz, if_hz, offsets_chips, n_blocks):
    """The same with plain numpy (slow; for tests)."""
    wiped, chip_pos, k = _wipe_and_positions(samples, fs_hz, code_phase_chips, doppler_hz, if_hz, n_blocks)
    chips = np.floor(chip_pos[None, :] + np.asarray(offsets_chips)[:, None]).astype(np.int64)
    replicas = ca_code(prn).astype(np.float64)[chips % CA_CODE_LENGTH_CHIPS]
    y = np.einsum("ibk,bk->ib", replicas.reshape(len(offsets_chips), n_blocks, k), wiped.reshape(n_blocks, k))
    return y, replicas[:, :k] @ replicas[:, :k].T, k


@functools.lru_cache(maxsize=32)
def _threshold(pfa: float, n_offsets: int, n_blocks: int) -> float:
    n_pairs = n_offsets * (n_offsets - 1) / 2   # the maximum over pairs: Bonferroni
    return float(chi2_isf(pfa / n_pairs, 2 * n_blocks) / 2)


def two_path_test(samples, fs_hz, prn, code_phase_chips, doppler_hz, if_hz=0.0, n_blocks=20, span_chips=2.0,
                  step_chips=0.05, pfa=1e-4, min_spacing_chips=0.2) -> TwoPathFit:
    """The best one- and two-path fits around a peak, and whether the second path is real."""
    offsets = np.arange(-span_chips, span_chips + 1e-9, step_chips)
    y, gram, k = delay_profile(samples, fs_hz, prn, code_phase_chips, doppler_hz, if_hz, offsets, n_blocks)
    noise_var = float(np.mean(np.abs(samples[:k * n_blocks]) ** 2))   # signals lie far below the noise
    s = np.sum(np.abs(y) ** 2, axis=1)                                 # sum_b |y_b(tau_i)|^2
    c = np.real(y @ y.conj().T)                                        # sum_b Re(y_i conj(y_j))
    e1 = s / k
    i1 = int(np.argmax(e1))
    den = k * k - gram ** 2
    spaced = np.abs(offsets[:, None] - offsets[None, :]) >= min_spacing_chips
    with np.errstate(divide="ignore", invalid="ignore"):
        e2 = np.where(spaced & (den > 0), (k * s[:, None] + k * s[None, :] - 2 * gram * c) / den, -np.inf)
    i, j = np.unravel_index(int(np.argmax(e2)), e2.shape)
    # the two paths' amplitudes (per-block LS), to tell the stronger from the weaker
    g_inv = np.array([[k, -gram[i, j]], [-gram[i, j], k]]) / den[i, j]
    amps = g_inv @ np.stack([y[i], y[j]])
    p_i, p_j = float(np.mean(np.abs(amps[0]) ** 2)), float(np.mean(np.abs(amps[1]) ** 2))
    if p_j > p_i:
        i, j, p_i, p_j = j, i, p_j, p_i
    statistic = float((e2.max() - e1[i1]) / noise_var)
    threshold = _threshold(pfa, offsets.size, n_blocks)
    return TwoPathFit(prn, float((code_phase_chips + offsets[i]) % 1023), float((code_phase_chips + offsets[j]) % 1023),
                      float(10 * np.log10(max(p_j, 1e-30) / max(p_i, 1e-30))), statistic, threshold)
