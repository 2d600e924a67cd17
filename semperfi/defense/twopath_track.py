"""The canceller's two-path tracker: a bank of correlators around the spoofer's replica, and the maximum-likelihood
delays of the spoofer and of its legitimate twin when the two lie within about a chip (one merged CAF peak or two
touching ones), in the spirit of the multipath-estimating DLL.

Per code period b the bank holds y_b[k] = <x, c(tau_s + lag_k)> / n, the correlations with the spoofer's replica
moved by lag_k. Two paths at offsets u (the spoofer) and v (its twin) from that replica predict
y_b = A(u, v) [a_b, l_b]^T with A's columns the PRN's code autocorrelation r(lag_k - u) and r(lag_k - v). The amplitudes
(amplitude, carrier phase and data bit of each signal) are free per period, so the likelihood, maximised over them,
depends on the buffer only through S = sum_b y_b y_b^H:

    maximise  tr((A^T A)^-1 A^T Re(S) A)   over (u, v),     then [a_b, l_b]^T = (A^T A)^-1 A^T y_b.

A grid search and a finer one around its best keep the cost independent of the number of periods; the bank's cost
is one pass over the samples with every lag.
"""

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..gps import ca_code
from ..receiver import MAX_SUB_SAMPLES, CodeBank, fill_lanes, lane_buffer, replica, sub_block_samples
from .chip_shape import RECTANGULAR, ChipShape, code_correlation

LAG_STEP_CHIPS = 0.1        # bank spacing: the triangles' kinks of two paths 0.2 chip apart fall between coarser lags
LAG_MARGIN_CHIPS = 0.8      # the bank reaches this far beyond both paths
SPOOFER_SPAN_CHIPS = 0.2    # the spoofer's replica is tracked: it is within this of the spoofer
TWIN_SPAN_CHIPS = 0.4       # how far the twin's offset is searched around its last estimate
COARSE_CHIPS = 0.01
FINE_CHIPS = 0.002
MIN_SEPARATION_CHIPS = 0.1  # closer than this the two columns of A are nearly the same: no fit


def bank_lags(twin_offset_chips: float, whole_steps: bool = False) -> np.ndarray:
    """The lags covering the spoofer (0) and its twin, with a margin either side; whole_steps: on whole steps of
    LAG_STEP_CHIPS (a twin that moves a little keeps the same lags, and its buffers' products add up)."""
    lo = min(0.0, twin_offset_chips) - LAG_MARGIN_CHIPS
    hi = max(0.0, twin_offset_chips) + LAG_MARGIN_CHIPS
    if whole_steps:
        lo, hi = LAG_STEP_CHIPS * np.floor(lo / LAG_STEP_CHIPS), LAG_STEP_CHIPS * np.ceil(hi / LAG_STEP_CHIPS)
        return np.round(lo + LAG_STEP_CHIPS * np.arange(round((hi - lo) / LAG_STEP_CHIPS) + 1), 10)
    n = int(np.ceil((hi - lo) / LAG_STEP_CHIPS)) + 1
    return lo + LAG_STEP_CHIPS * np.arange(n)


@njit(cache=True, nogil=True, fastmath=True)
def _bank_kernel(x, base_sample, blocks, rows, first, bank_step, lags, lanes, wiped, add, add_rows, both_images, out,
                 out_power):
    """out[m, k]: block m's correlation with the replica moved by lags[k], / samples; out_power[m]: the block's mean
    power; nan for a block not wholly in x. add (one per block, or none): the replica at lag 0 from add_rows (the
    shape subtracted) times add[m] is added to the samples as they are read (both_images: its real part, twice). The
    carrier is wiped once per sub-block, then each lag is one pass of multiply-adds over it."""
    n_lags = lags.size
    acc_re = np.empty(n_lags)
    acc_im = np.empty(n_lags)
    for m in range(blocks.shape[0]):
        start = np.int64(blocks[m, 0]) - base_sample
        n, cp, step = np.int64(blocks[m, 1]), blocks[m, 2], blocks[m, 3]
        if start < 0 or start + n > x.size:
            for k in range(n_lags):
                out[m, k] = np.nan
            out_power[m] = np.nan
            continue
        s_max = sub_block_samples(step, bank_step)
        fill_lanes(lanes, blocks[m, 5], s_max, -1.0)
        acc_re[:] = 0.0
        acc_im[:] = 0.0
        power = 0.0
        k0 = 0
        while k0 < n:
            s = min(s_max, n - k0)
            rot = np.exp(-2j * np.pi * (blocks[m, 4] + k0 * blocks[m, 5]))
            c0r, c0i = np.float32(rot.real), np.float32(rot.imag)
            xs = x[start + k0:start + k0 + s]
            pw = np.float32(0.0)
            for j in range(s):
                v = xs[j]
                ln = lanes[j]
                cr = c0r * ln.real - c0i * ln.imag
                ci = c0r * ln.imag + c0i * ln.real
                wr, wi = v.real * cr - v.imag * ci, v.real * ci + v.imag * cr
                wiped[j] = complex(wr, wi)
            if add.size:   # a loop of its own: merged into the wipe above, its branch cost 3-4 s of CPU a minute
                ar, ai = np.float32(add[m].real), np.float32(add[m].imag)
                own = replica(add_rows, first, bank_step, cp, step, k0, s)
                for j in range(s):
                    c = np.float32(own[j])
                    w = wiped[j]
                    wr, wi = w.real + c * ar, w.imag + c * ai
                    if both_images:   # conj(add) code conj(carrier)^2: the mirror image, wiped
                        ln = lanes[j]
                        cr = c0r * ln.real - c0i * ln.imag
                        ci = c0r * ln.imag + c0i * ln.real
                        qr, qi = cr * cr - ci * ci, 2 * cr * ci
                        wr += c * (ar * qr + ai * qi)
                        wi += c * (ar * qi - ai * qr)
                    wiped[j] = complex(wr, wi)
            for j in range(s):
                w = wiped[j]
                pw += w.real * w.real + w.imag * w.imag
            power += pw
            for k in range(n_lags):
                code = replica(rows, first, bank_step, cp + lags[k], step, k0, s)
                sr = si = np.float32(0.0)
                for j in range(s):
                    c = np.float32(code[j])
                    sr += c * wiped[j].real
                    si += c * wiped[j].imag
                acc_re[k] += sr
                acc_im[k] += si
            k0 += s
        for k in range(n_lags):
            out[m, k] = complex(acc_re[k], acc_im[k]) / n
        out_power[m] = power / n


def correlator_bank(x: np.ndarray, base_sample: int, blocks: np.ndarray, bank: CodeBank, lags: np.ndarray,
                    add: np.ndarray | None = None, both_images: bool = False,
                    add_bank: CodeBank | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(blocks, lags): each code period's correlation with the spoofer's replica (tracking's blocks) moved by each
    lag, divided by the period's samples: a signal of amplitude a at offset d gives about a r(lag - d); and (blocks):
    each period's mean sample power. add: amplitudes per block of the replica itself (from add_bank, the shape that
    was subtracted; bank's by default), added to x as it is read (x is not written: a cancelled spoofer looked at
    again without a copy)."""
    out = np.empty((len(blocks), len(lags)), dtype=np.complex128)
    power = np.empty(len(blocks))
    wiped = np.empty(MAX_SUB_SAMPLES, dtype=np.complex64)
    add_bank = bank if add_bank is None else add_bank
    add = np.empty(0, dtype=np.complex128) if add is None else np.asarray(add, dtype=np.complex128) / add_bank.scale
    _bank_kernel(x, base_sample, blocks, bank.rows, bank.first, bank.step_chips, np.asarray(lags, dtype=np.float64),
                 lane_buffer(), wiped, add, add_bank.rows, both_images, out, power)
    return out, power


def correlator_bank_reference(x: np.ndarray, base_sample: int, blocks, prn: int, lags, add=None,
                              both_images: bool = False, add_shape: ChipShape = RECTANGULAR
                              ) -> tuple[np.ndarray, np.ndarray]:
    """The same with numpy, the exact code phase and an exact exponential (slow; for tests)."""
    code = ca_code(prn).astype(np.float64)
    out = np.full((len(blocks), len(lags)), np.nan, dtype=np.complex128)
    power = np.full(len(blocks), np.nan)
    for m, (first, n, cp, step, ph, pstep) in enumerate(blocks):
        start, k = int(first) - base_sample, np.arange(int(n))
        if start < 0 or start + int(n) > x.size:
            continue
        carrier = np.exp(2j * np.pi * (ph + k * pstep))
        seen = x[start:start + int(n)].astype(np.complex128)
        if add is not None:
            own = add[m] * add_shape.values(prn, cp + k * step) * carrier
            seen = seen + (2 * own.real if both_images else own)
        wiped = seen * np.conj(carrier)
        power[m] = np.mean(np.abs(seen) ** 2)
        for i, lag in enumerate(lags):
            out[m, i] = np.sum(wiped * code[np.floor(cp + lag + k * step).astype(np.int64) % 1023]) / n
    return out, power


@dataclass(frozen=True)
class TwoPaths:
    spoofer_offset_chips: float      # u: the spoofer, from the replica the bank was built on
    twin_offset_chips: float         # v: its legitimate twin, from the same replica
    spoofer_amplitudes: np.ndarray   # a_b per code period (complex, in the replica's carrier frame)
    twin_amplitudes: np.ndarray      # l_b per code period

    @property
    def separation_chips(self) -> float:
        """The twin's offset from the spoofer itself (v - u)."""
        return self.twin_offset_chips - self.spoofer_offset_chips


def _explained(prn, us, vs, lags, s_re, side, shape):
    """tr((A^T A)^-1 A^T Re(S) A) for every (u, v) on a grid; -inf where the twin is not on its side of the spoofer
    by MIN_SEPARATION_CHIPS (too close to fit, or crossed over)."""
    au, av = shape.correlation(prn, lags[None, :] - us[:, None]), shape.correlation(prn, lags[None, :] - vs[:, None])
    h_uu = np.einsum("ik,kl,il->i", au, s_re, au)
    h_vv = np.einsum("jk,kl,jl->j", av, s_re, av)
    h_uv = au @ s_re @ av.T
    g_uu, g_vv, g_uv = np.sum(au * au, axis=1), np.sum(av * av, axis=1), au @ av.T
    det = g_uu[:, None] * g_vv[None, :] - g_uv ** 2
    spaced = side * (vs[None, :] - us[:, None]) >= MIN_SEPARATION_CHIPS
    with np.errstate(divide="ignore", invalid="ignore"):
        e = (g_vv[None, :] * h_uu[:, None] + g_uu[:, None] * h_vv[None, :] - 2 * g_uv * h_uv) / det
    return np.where(spaced & (det > 1e-9), e, -np.inf)


def _best(prn, us, vs, lags, s_re, side, shape):
    """The grid's best (u, v), and whether any pair on it could be fitted at all."""
    e = _explained(prn, us, vs, lags, s_re, side, shape)
    i, j = np.unravel_index(int(np.argmax(e)), e.shape)
    return float(us[i]), float(vs[j]), bool(np.isfinite(e[i, j]))


def signal_products(prn: int, y: np.ndarray, lags: np.ndarray, noise_power: float = 0.0) -> np.ndarray:
    """Re(S), S = sum_b y_b y_b^H over a bank's finite periods, less the white noise's share: the noise in
    neighbouring lags is correlated as the code is with itself, and left in S it favours the pair whose two
    triangles span more of it, the twin pushed away from the spoofer (GPS-SDR-SIM, a 44 dB-Hz twin half a chip from
    a +6 dB spoofer: 0.02-0.03 chip too far, its amplitude 3-5 % low, the spoofer's replica keeping 5 % of the
    twin's leakage)."""
    yy = y[np.isfinite(y).all(axis=1)]
    return np.real(yy.T @ yy.conj()) - len(yy) * noise_power * code_correlation(prn, lags[:, None] - lags[None, :])


def fit_two_paths(prn: int, y: np.ndarray, lags: np.ndarray, twin_guess_chips: float,
                  noise_power: float = 0.0, shape: ChipShape = RECTANGULAR,
                  products: np.ndarray | None = None) -> TwoPaths | None:
    """The ML offsets of the spoofer (near 0) and its twin (near twin_guess_chips, on the same side of the spoofer)
    from a bank's correlations y (periods, lags); None without a finite period or when the twin's side cannot hold
    a fit. noise_power: the variance of one period's correlation with white noise (sample power / samples); shape:
    the chips' as received (chip_shape); products: the signal_products the offsets are fitted on, when not this
    buffer's alone (earlier buffers' on the same lags added: the amplitudes are still this buffer's)."""
    if not np.isfinite(y).all(axis=1).any():
        return None
    s_re = signal_products(prn, y, lags, noise_power) if products is None else products
    side = 1.0 if twin_guess_chips >= 0 else -1.0
    us = np.arange(-SPOOFER_SPAN_CHIPS, SPOOFER_SPAN_CHIPS + 1e-9, COARSE_CHIPS)
    vs = twin_guess_chips + np.arange(-TWIN_SPAN_CHIPS, TWIN_SPAN_CHIPS + 1e-9, COARSE_CHIPS)
    u, v, fitted = _best(prn, us, vs, lags, s_re, side, shape)
    if not fitted:
        return None                                     # no pair on the twin's side: never across the spoofer
    fine = np.arange(-COARSE_CHIPS, COARSE_CHIPS + 1e-9, FINE_CHIPS)
    u, v, _ = _best(prn, u + fine, v + fine, lags, s_re, side, shape)
    return paths_at(prn, y, lags, u, v, shape)


def paths_at(prn: int, y: np.ndarray, lags: np.ndarray, u: float, v: float,
             shape: ChipShape = RECTANGULAR) -> TwoPaths:
    """Both paths at known offsets u and v: each period's two amplitudes by least squares from its correlations
    y (periods, lags), nan for a period with a correlation missing. With the two lags at u and v this is each
    path's matched filter, the two unmixed: all the buffer says of the amplitudes once the delays are known."""
    ok = np.isfinite(y).all(axis=1)
    a = np.column_stack([shape.correlation(prn, lags - u), shape.correlation(prn, lags - v)])
    amps = np.full((len(y), 2), np.nan + 0j)
    if ok.any():
        amps[ok] = np.linalg.solve(a.T @ a, a.T @ y[ok].T).T
    return TwoPaths(u, v, amps[:, 0], amps[:, 1])


def fit_two_paths_reference(prn: int, y: np.ndarray, lags: np.ndarray, us: np.ndarray, vs: np.ndarray,
                            side: float) -> tuple[float, float]:
    """The least-squares (u, v) by brute force: every pair, every period's amplitudes by lstsq (slow; for tests)."""
    best, arg = np.inf, (np.nan, np.nan)
    for u in us:
        for v in vs:
            if side * (v - u) < MIN_SEPARATION_CHIPS:
                continue
            a = np.column_stack([code_correlation(prn, lags - u),
                                 code_correlation(prn, lags - v)]).astype(np.complex128)
            coef = np.linalg.lstsq(a, y.T, rcond=None)[0]
            cost = float(np.sum(np.abs(y.T - a @ coef) ** 2))
            if cost < best:
                best, arg = cost, (float(u), float(v))
    return arg
