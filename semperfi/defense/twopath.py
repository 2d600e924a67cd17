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


@njit(inline="always")
def _chip_and_rest(units, sub, inv_sub):
    """units // sub and units % sub (floored) by a multiplication: an integer division per sample costs more than
    everything else done with it."""
    chip = np.int64(np.floor(units * inv_sub))
    rest = units - chip * sub
    if rest < 0:
        chip, rest = chip - 1, rest + sub
    elif rest >= sub:
        chip, rest = chip + 1, rest - sub
    return chip, rest


@njit(inline="always")
def _add_replicas(d_re, d_im, top, w_re, w_im, sub, inv_sub, n_cross, first_at, code_pad):
    """w times each offset's replica chip, into d as differences from one offset to the next: a sample at top
    (1/sub chips, past the first offset) meets code chip `chip` at the first offset, and the next chip at every
    offset sub - rest units further on -- n_cross crossings over the span, whatever the number of offsets."""
    chip, rest = _chip_and_rest(top, sub, inv_sub)
    s = code_pad[chip + PAD_CHIPS]
    d_re[0] += w_re * s
    d_im[0] += w_im * s
    for q in range(n_cross):
        step = code_pad[chip + q + 1 + PAD_CHIPS] - code_pad[chip + q + PAD_CHIPS]
        i = first_at[sub - rest + q * sub]
        d_re[i] += w_re * step
        d_im[i] += w_im * step


@njit(cache=True, nogil=True, fastmath=True)
def _profile_kernel(samples, block_carrier, carrier, code_phase_chips, chips_per_sample, sub, units, first_at,
                    code_pad, n_blocks, k):
    """The wiped blocks (k x 2 n_blocks: each block's real and imaginary parts), the first block's replicas at every
    offset (offsets x k, +/-1), each block's correction, and the replicas' Gram matrix: y = replicas @ wiped +
    correction, one matrix product (BLAS) for the bulk of the work.

    The code slides under the blocks only by its Doppler (a few thousandths of a chip a block), so block b's samples
    meet the same code chips as block 0's but for the few whose 1/sub-chip position moved: those are added again
    with their own replicas and taken off with block 0's, each as a handful of differences from one offset to the
    next (_add_replicas) rather than a sum over every offset. Offsets are units[i] / sub chips, sorted; first_at[v]
    is the first offset at least v units past the first."""
    n_off = units.size
    n_sub = CA_CODE_LENGTH_CHIPS * sub
    u0 = units[0]
    n_cross = (units[n_off - 1] - u0) // sub + 1
    inv_sub = 1.0 / sub
    wiped = np.empty((k, 2 * n_blocks), dtype=np.float32)
    correction = np.zeros((n_off, n_blocks), dtype=np.complex128)
    d_re, d_im = np.empty(n_off + 1), np.empty(n_off + 1)   # the last slot takes crossings past the last offset
    fine0 = np.empty(k, dtype=np.int64)
    for b in range(n_blocks):
        d_re[:] = 0.0
        d_im[:] = 0.0
        moved = False
        turn = block_carrier[b]
        # whole code periods taken off by subtraction instead of a remainder per sample: an integer times the period
        # off the position is exact in floating point, as the remainder is
        wraps = np.floor((code_phase_chips + b * k * chips_per_sample) / CA_CODE_LENGTH_CHIPS)
        for t in range(k):
            w = samples[b * k + t] * carrier[t] * turn
            wiped[t, 2 * b] = w.real
            wiped[t, 2 * b + 1] = w.imag
            pos = (code_phase_chips + (b * k + t) * chips_per_sample) - wraps * CA_CODE_LENGTH_CHIPS
            if pos >= CA_CODE_LENGTH_CHIPS:
                wraps += 1.0
                pos -= CA_CODE_LENGTH_CHIPS
            fine = min(np.int64(pos * sub), n_sub - 1)
            if b == 0:
                fine0[t] = fine
            elif fine != fine0[t]:
                moved = True
                _add_replicas(d_re, d_im, fine + u0, w.real, w.imag, sub, inv_sub, n_cross, first_at, code_pad)
                _add_replicas(d_re, d_im, fine0[t] + u0, -w.real, -w.imag, sub, inv_sub, n_cross, first_at,
                              code_pad)
        if moved:
            acc_re, acc_im = 0.0, 0.0
            for i in range(n_off):
                acc_re += d_re[i]
                acc_im += d_im[i]
                correction[i, b] = acc_re + 1j * acc_im
    # block 0's replicas: the chip of offset i is the first offset's plus (rest + units[i] - u0) // sub
    ahead = np.empty((sub, n_off), dtype=np.int64)
    for r in range(sub):
        for i in range(n_off):
            ahead[r, i] = (r + units[i] - u0) // sub
    # and their Gram matrix, exact (sums of +/-1) and without a product over the samples: offset i meets chip
    # `chip + ahead[rest, i]`, so gram[i, j] sums pairs[rest, ahead[rest, i], ahead[rest, j]] over the rests, where
    # pairs[r, a, b] sums code[chip + a] code[chip + b] over the samples with that rest
    n_ahead = n_cross + 1
    first = np.empty((n_off, k), dtype=np.float32)
    pairs = np.zeros((sub, n_ahead, n_ahead))
    for t in range(k):
        chip, rest = _chip_and_rest(fine0[t] + u0, sub, inv_sub)
        for i in range(n_off):
            first[i, t] = code_pad[chip + ahead[rest, i] + PAD_CHIPS]
        for a in range(n_ahead):
            c_a = code_pad[chip + a + PAD_CHIPS]
            for b in range(a, n_ahead):
                pairs[rest, a, b] += c_a * code_pad[chip + b + PAD_CHIPS]
    gram = np.empty((n_off, n_off))
    for i in range(n_off):
        for j in range(i, n_off):
            g = 0.0
            for r in range(sub):
                a, b = ahead[r, i], ahead[r, j]   # sorted offsets: a <= b
                g += pairs[r, a, b]
            gram[i, j] = g
            gram[j, i] = g
    return wiped, first, correction, gram


MAX_SUB = 1000   # offsets on a grid finer than 1/MAX_SUB chip are refused


@functools.lru_cache(maxsize=16)
def _grid(offsets_chips: tuple) -> tuple:
    """The offsets' grid (every offset a whole number of 1/sub chips), their order, each in units of 1/sub chip
    (sorted), and first_at[v]: the first of them at least v units past the first (cached: every fit asks for the
    same offsets)."""
    offsets = np.asarray(offsets_chips, dtype=np.float64)
    sub = next((r for r in range(1, MAX_SUB + 1) if np.allclose(offsets * r, np.round(offsets * r), atol=1e-6)), None)
    if sub is None:
        raise ValueError(f"delay offsets must lie on a grid of 1/{MAX_SUB} chip or coarser")
    order = np.argsort(offsets, kind="stable")
    units = np.round(offsets[order] * sub).astype(np.int64)
    first_at = np.searchsorted(units - units[0], np.arange(units[-1] - units[0] + sub + 1), side="left")
    return sub, order, units, first_at.astype(np.int64)


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
    sub, order, units, first_at = _grid(tuple(np.asarray(offsets_chips, dtype=np.float64)))
    wiped, first, correction, gram = _profile_kernel(
        np.ascontiguousarray(samples[:k * n_blocks]), block_carrier, carrier, float(code_phase_chips),
        _chips_per_sample(fs_hz, doppler_hz), sub, units, first_at, code_pad, n_blocks, k)
    # products of +/-1 with single-precision samples, summed by BLAS in single precision: errors of a few 1e-7 of
    # the largest correlation, far below the noise in it
    y = (first @ wiped).astype(np.float64).view(np.complex128) + correction
    back = np.argsort(order)   # the offsets' order as asked
    return y[back], gram[np.ix_(back, back)], k


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
