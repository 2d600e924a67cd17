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


@njit(cache=True, nogil=True, fastmath=True)
def _profile_kernel(samples, block_carrier, carrier, code_phase_chips, chips_per_sample, sub, units, code_pad,
                    n_blocks, k):
    """Each block's correlations y[i, b] with the code at every offset (units[i] / sub chips, sorted), and the
    replicas' Gram matrix over block 0.

    A block's wiped samples are summed into bins of 1/sub chip by their code position. An offset of q whole chips
    and rho units meets chip c + q in bin (c, r) for r < sub - rho and chip c + q + 1 above, so with P[c, m] the
    sum of chip c's first m bins and T[c] all of them,

        y = sum_c (code[c+q] - code[c+q+1]) P[c, sub - rho] + code[c+q+1] T[c]

    a pass over the samples and a few sums per chip and offset, whatever the rate: at 10 MSa/s half the time
    of the product of every offset's replica with every sample, which this replaced."""
    n_off = units.size
    n_sub = CA_CODE_LENGTH_CHIPS * sub
    q = np.empty(n_off, dtype=np.int64)
    m = np.empty(n_off, dtype=np.int64)
    for i in range(n_off):
        q[i] = units[i] // sub                      # floored, as the chips are
        m[i] = sub - (units[i] - q[i] * sub)
    q_lo = q[0]
    n_q = q[n_off - 1] - q_lo + 1
    y = np.empty((n_off, n_blocks), dtype=np.complex128)
    w_re, w_im = np.zeros(n_sub), np.zeros(n_sub)
    p_re, p_im = np.empty(sub + 1), np.empty(sub + 1)
    d_re, d_im = np.empty((n_q, sub + 1)), np.empty((n_q, sub + 1))
    s_re, s_im = np.empty(n_q), np.empty(n_q)
    fine0 = np.empty(k, dtype=np.int64)
    for b in range(n_blocks):
        w_re[:] = 0.0
        w_im[:] = 0.0
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
            if b == 0:
                fine0[t] = fine
            w_re[fine] += w.real
            w_im[fine] += w.imag
        d_re[:, :] = 0.0
        d_im[:, :] = 0.0
        s_re[:] = 0.0
        s_im[:] = 0.0
        for c in range(CA_CODE_LENGTH_CHIPS):
            a_re, a_im = 0.0, 0.0
            p_re[0], p_im[0] = 0.0, 0.0
            for r in range(sub):
                a_re += w_re[c * sub + r]
                a_im += w_im[c * sub + r]
                p_re[r + 1], p_im[r + 1] = a_re, a_im
            for j in range(n_q):
                after = code_pad[c + q_lo + j + 1 + PAD_CHIPS]
                s_re[j] += after * a_re
                s_im[j] += after * a_im
                step = code_pad[c + q_lo + j + PAD_CHIPS] - after
                if step != 0.0:                      # half the chips: the code does not change there
                    for mm in range(1, sub + 1):
                        d_re[j, mm] += step * p_re[mm]
                        d_im[j, mm] += step * p_im[mm]
        for i in range(n_off):
            j = q[i] - q_lo
            y[i, b] = complex(d_re[j, m[i]] + s_re[j], d_im[j, m[i]] + s_im[j])
    return y, _gram(fine0, units, sub, code_pad)


@njit(cache=True, nogil=True)
def _gram(fine, units, sub, code_pad):
    """The replicas' Gram matrix over one block's samples at these 1/sub-chip positions, exact (sums of +/-1) and
    without a product over the samples: offset i meets chip `chip + ahead[rest, i]`, so gram[i, j] sums
    pairs[rest, ahead[rest, i], ahead[rest, j]] over the rests, where pairs[r, a, b] sums code[chip + a]
    code[chip + b] over the samples with that rest."""
    n_off = units.size
    u0 = units[0]
    n_ahead = (units[n_off - 1] - u0) // sub + 2
    ahead = np.empty((sub, n_off), dtype=np.int64)
    for r in range(sub):
        for i in range(n_off):
            ahead[r, i] = (r + units[i] - u0) // sub
    pairs = np.zeros((sub, n_ahead, n_ahead))
    inv_sub = 1.0 / sub
    for t in range(fine.size):
        chip, rest = _chip_and_rest(fine[t] + u0, sub, inv_sub)
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
    return gram


MAX_SUB = 1000   # offsets on a grid finer than 1/MAX_SUB chip are refused


@functools.lru_cache(maxsize=16)
def _grid(offsets_chips: tuple) -> tuple:
    """The offsets' grid (every offset a whole number of 1/sub chips), their order, and each in units of 1/sub chip
    (sorted) (cached: every fit asks for the same offsets)."""
    offsets = np.asarray(offsets_chips, dtype=np.float64)
    sub = next((r for r in range(1, MAX_SUB + 1) if np.allclose(offsets * r, np.round(offsets * r), atol=1e-6)), None)
    if sub is None:
        raise ValueError(f"delay offsets must lie on a grid of 1/{MAX_SUB} chip or coarser")
    order = np.argsort(offsets, kind="stable")
    return sub, order, np.round(offsets[order] * sub).astype(np.int64)


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
    sub, order, units = _grid(tuple(np.asarray(offsets_chips, dtype=np.float64)))
    y, gram = _profile_kernel(np.ascontiguousarray(samples[:k * n_blocks]), block_carrier, carrier,
                              float(code_phase_chips), _chips_per_sample(fs_hz, doppler_hz), sub, units, code_pad,
                              n_blocks, k)
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
