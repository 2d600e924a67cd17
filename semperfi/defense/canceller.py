"""The Legitimate Signal Retriever: successive interference cancellation of the spoofer's signals.

For every adversarial peak a tracking channel follows the spoofer's signal (code, carrier, data bits); each code
period's replica is rebuilt exactly as it was correlated, its complex amplitude (amplitude, carrier phase and data
bit at once) is the least-squares estimate P / n smoothed over neighbouring periods, and the replica times that
amplitude is subtracted. Stages can be chained: stage k tracks what stage k - 1 left (the SIC iterations).
"""

import copy
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from ..gps import (CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, CA_CODE_PERIOD_S, L1_HZ, ca_code, chips_apart,
                  chips_offset)
from ..receiver import (Channel, CodeBank, DopplerGrid, LoopConfig, NEXT_SAMPLE, Peak, acquire, cores, fill_lanes,
                        initial_state, lane_buffer, replica, run_each, sub_block_samples)
from .chip_shape import (LAGS_CHIPS, RECTANGULAR, TAP_REACH_CHIPS, TAPS_CHIPS, TWIN_NEAR_CHIPS, ChipShape,
                         ChipShapeMeter, knot_bank, shaped_bank)
from .twopath_track import TwoPaths, bank_lags, correlator_bank, fit_two_paths, paths_at, signal_products

MEASURE_EVERY = 8                 # code periods per attenuation measurement
MEASURED_WITHIN_DB = 6.0          # the spoofers that measure the front end's chips: this close to the strongest


@njit(cache=True, nogil=True, fastmath=True)
def _subtract_kernel(x, base_sample, blocks, amplitudes, rows, first, bank_step, offset_chips, lanes, both_images):
    """x -= amplitude * code * carrier per block (the part of each block inside x), the code moved by offset_chips."""
    for m in range(blocks.shape[0]):
        start = np.int64(blocks[m, 0]) - base_sample
        n, cp, step = np.int64(blocks[m, 1]), blocks[m, 2] + offset_chips, blocks[m, 3]
        ph, pstep = blocks[m, 4], blocks[m, 5]
        a = amplitudes[m]
        lo, hi = max(0, -start), min(n, x.size - start)
        if hi <= lo:   # a block wholly outside x (a thread's span holds only part of the buffer)
            continue
        s_max = sub_block_samples(step, bank_step)
        fill_lanes(lanes, pstep, s_max, 1.0)
        # sub-blocks on the block's own grid of s_max samples, each read whole from the bank: a block cut by the
        # end of x, or by a split of x between threads, gets the same replica in each part as in one pass
        g0 = lo - lo % s_max
        while g0 < hi:
            s = min(s_max, n - g0)
            rot = a * np.exp(2j * np.pi * (ph + g0 * pstep))
            c0r, c0i = np.float32(rot.real), np.float32(rot.imag)
            j0, j1 = max(lo, g0) - g0, min(hi, g0 + s) - g0
            code = replica(rows, first, bank_step, cp, step, g0, s)[j0:j1]
            ls = lanes[j0:j1]
            xs = x[start + g0 + j0:start + g0 + j1]
            for j in range(j1 - j0):
                ln = ls[j]
                c = np.float32(code[j])
                vr = c * (c0r * ln.real - c0i * ln.imag)
                if both_images:
                    xs[j] -= 2.0 * vr
                else:
                    xs[j] -= complex(vr, c * (c0r * ln.imag + c0i * ln.real))
            g0 += s


@njit(cache=True, nogil=True, fastmath=True)
def _residual_kernel(x, base_sample, blocks, rows, first, bank_step, offset_chips, lanes, out_beta, out_power):
    """Per block: the residual's correlation with the (unit) replica, the code moved by offset_chips, and the
    residual's mean power; nan for a block not wholly inside x."""
    for m in range(blocks.shape[0]):
        start = np.int64(blocks[m, 0]) - base_sample
        n, cp, step = np.int64(blocks[m, 1]), blocks[m, 2] + offset_chips, blocks[m, 3]
        if start < 0 or start + n > x.size:
            out_beta[m], out_power[m] = np.nan, np.nan
            continue
        s_max = sub_block_samples(step, bank_step)
        fill_lanes(lanes, blocks[m, 5], s_max, -1.0)
        acc = 0j
        power = 0.0
        k0 = 0
        while k0 < n:
            s = min(s_max, n - k0)
            rot = np.exp(-2j * np.pi * (blocks[m, 4] + k0 * blocks[m, 5]))
            c0r, c0i = np.float32(rot.real), np.float32(rot.imag)
            code = replica(rows, first, bank_step, cp, step, k0, s)
            xs = x[start + k0:start + k0 + s]
            br = bi = pw = np.float32(0.0)
            for j in range(s):
                v = xs[j]
                ln = lanes[j]
                c = np.float32(code[j])
                wr = c * (c0r * ln.real - c0i * ln.imag)
                wi = c * (c0r * ln.imag + c0i * ln.real)
                br += v.real * wr - v.imag * wi
                bi += v.real * wi + v.imag * wr
                pw += v.real * v.real + v.imag * v.imag
            acc += complex(br, bi)
            power += pw
            k0 += s
        out_beta[m], out_power[m] = acc / n, power / n


def subtract_replicas(x: np.ndarray, base_sample: int, blocks: np.ndarray, amplitudes: np.ndarray, bank: CodeBank,
                      both_images: bool = False, offset_chips: float = 0.0) -> None:
    """x -= sum over code periods of amplitude * code * carrier, the replicas described by tracking's blocks (the
    code moved by offset_chips).

    both_images: x holds real samples at an IF, where a signal is there twice (at +IF, which tracking measured, and
    its mirror at -IF); subtract the real signal, 2 Re(replica), so the result is real and free of both. bank: the
    code as it is subtracted (a shaped bank: as the front end delivers it, chip_shape)."""
    _subtract_kernel(x, base_sample, blocks, amplitudes.astype(np.complex128) / bank.scale, bank.rows, bank.first,
                     bank.step_chips, offset_chips, lane_buffer(), both_images)


def residuals(x: np.ndarray, base_sample: int, blocks: np.ndarray, bank: CodeBank,
              offset_chips: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per block: x's correlation with the unit replica (code moved by offset_chips) / samples, and x's mean power."""
    beta, power = np.empty(len(blocks), dtype=np.complex128), np.empty(len(blocks))
    _residual_kernel(x, base_sample, blocks, bank.rows, bank.first, bank.step_chips, offset_chips, lane_buffer(),
                     beta, power)
    return beta, power


def noise_power(power: np.ndarray, blocks: np.ndarray) -> float:
    """The variance of one block's correlation with white noise: the samples' mean power over the blocks (the
    noise's, at a C/N0 where every signal lies below it; power: per block, nan where not measured) / the samples in
    a block."""
    ok = np.isfinite(power)
    if not ok.any():
        return 0.0
    n = blocks[ok, 1]
    return float(np.sum(power[ok] * n) / np.sum(n) / np.mean(blocks[:, 1]))


@njit(cache=True, nogil=True)
def _overlap_kernel(blocks, rows, first, bank_step, moved_rows, offset_chips, out):
    """out[m]: block m's replica times the replica from moved_rows moved by offset_chips, summed / samples."""
    for m in range(blocks.shape[0]):
        n, cp, step = np.int64(blocks[m, 1]), blocks[m, 2], blocks[m, 3]
        s_max = sub_block_samples(step, bank_step)
        acc = np.int64(0)
        k0 = 0
        while k0 < n:
            s = min(s_max, n - k0)
            here = replica(rows, first, bank_step, cp, step, k0, s)
            moved = replica(moved_rows, first, bank_step, cp + offset_chips, step, k0, s)
            for j in range(s):
                acc += np.int64(here[j]) * np.int64(moved[j])
            k0 += s
        out[m] = acc / n


def code_overlap(blocks: np.ndarray, bank: CodeBank, offset_chips: float,
                 moved_bank: CodeBank | None = None) -> np.ndarray:
    """Per block: what a unit signal on the replica moved by offset_chips (its chips from moved_bank: shaped as
    received) gives at the replica itself, the replicas exactly as the kernels build them (a twin's share of its
    spoofer's prompt)."""
    moved_bank = bank if moved_bank is None else moved_bank
    out = np.empty(len(blocks))
    _overlap_kernel(blocks, bank.rows, bank.first, bank.step_chips, moved_bank.rows, float(offset_chips), out)
    return out / moved_bank.scale


def code_overlap_reference(blocks, prn: int, offset_chips: float, shape: ChipShape = RECTANGULAR) -> np.ndarray:
    """The same with numpy and the exact code phase (slow; for tests)."""
    code = ca_code(prn).astype(np.float64)
    out = np.empty(len(blocks))
    for m, (_, n, cp, step, _, _) in enumerate(blocks):
        k = np.arange(int(n))
        here = code[np.floor(cp + k * step).astype(np.int64) % 1023]
        out[m] = np.mean(here * shape.values(prn, cp + offset_chips + k * step))
    return out


def replicas_reference(n_samples: int, base_sample: int, blocks, amplitudes, prn: int,
                       shape: ChipShape = RECTANGULAR) -> np.ndarray:
    """The same replicas with numpy and an exact exponential (slow; for tests)."""
    out = np.zeros(n_samples, dtype=np.complex128)
    for (first, n, cp, step, ph, pstep), a in zip(blocks, amplitudes):
        k = np.arange(int(n))
        idx = int(first) - base_sample + k
        ok = (idx >= 0) & (idx < n_samples)
        out[idx[ok]] += (a * shape.values(prn, cp + k * step) * np.exp(2j * np.pi * (ph + k * pstep)))[ok]
    return out


@dataclass(frozen=True)
class CancellerConfig:
    # The replica's code phase error is what limits the attenuation (an error of e chips leaves 2e of the power):
    # a narrow correlator (its E-L zero is not pulled by where samples fall on the chips) and, once settled, a
    # narrow loop.
    dll_bw_hz: float = 2.0
    narrow_dll_bw_hz: float = 0.5
    narrow_after_ms: int = 1000
    spacing_chips: float = 0.1
    pll_bw_hz: float = 15.0
    pull_in_ms: int = 300          # nothing is subtracted while the loops settle
    smoothing_ms: int = 16         # time constant of the amplitude/phase estimate
    max_stages: int = 3
    real_samples: bool = False     # real samples at an IF: a signal and its mirror image are both subtracted


def refine_peak(samples: np.ndarray, fs_hz: float, if_hz: float, peak: Peak) -> Peak:
    """The adversarial peak on a narrow fine grid (25 Hz, 5 ms coherent), keeping to its own code phase."""
    grid = DopplerGrid(peak.doppler_hz, 300.0, 25.0)
    caf = acquire(samples, fs_hz, [peak.prn], grid, if_hz, coherent_ms=5, noncoherent=2, pfa=1e-2,
                  max_peaks=8)[peak.prn]
    near = [p for p in caf.peaks if chips_apart(p.code_phase_chips, peak.code_phase_chips) < 0.6]
    return near[0] if near else peak


def decision_smooth_reference(values: np.ndarray, ref: complex, lam: float, rotation: complex = 1.0
                              ) -> tuple[np.ndarray, complex]:
    """Decision-directed smoothing of per-period complex amplitudes: each period's data bit is its sign against the
    running reference, which follows the bit-stripped values with gain lam. A signal turning in the frame of the
    replica (a twin whose carrier is not the one tracked) turns the reference by `rotation` each period first, or
    the smoothing would lag it. Returns the estimates (bits restored) and the reference after the last period.
    (Plain Python: the reference of decision_smooth.)"""
    est = np.empty_like(values)
    for i, a in enumerate(values):
        ref = ref * rotation
        bit = 1.0 if (a * np.conj(ref)).real >= 0 else -1.0
        ref = ref + lam * (a * bit - ref)
        est[i] = ref * bit
    return est, ref


_smooth_kernel = njit(cache=True, nogil=True)(decision_smooth_reference)


def decision_smooth(values: np.ndarray, ref: complex, lam: float, rotation: complex = 1.0
                    ) -> tuple[np.ndarray, complex]:
    """decision_smooth_reference compiled (a Python loop per code period of every track was a second a minute)."""
    est, ref = _smooth_kernel(np.asarray(values, dtype=np.complex128), complex(ref), float(lam), complex(rotation))
    return est, complex(ref)


ROTATION_LAG_PERIODS = 10        # the twin's turn is measured finely over this many periods
ROTATION_GAIN = 0.2               # per buffer: the twin's turn, smoothed over about a second


def rotation_per_period(values: np.ndarray, lag: int = ROTATION_LAG_PERIODS) -> complex | None:
    """How far a signal's per-period complex amplitudes turn each period, whatever its data bits: the angle of
    sum (v_k v*_{k-lag})^2 is twice the turn over lag periods (squaring takes the bits away), known modulo pi / lag;
    the angle of sum v_k v*_{k-1} (a bit flips between one pair in 20: the sum shrinks, its angle stays) picks
    which, within +-500 Hz. Over `lag` periods alone a flying receiver's twin aliased: 5 m/s north, 26 Hz from its
    spoofer, read as -24 Hz. None when too short."""
    v = np.asarray(values)[np.isfinite(values)]
    if v.size <= lag:
        return None
    coarse, fine = np.sum(v[1:] * np.conj(v[:-1])), np.sum((v[lag:] * np.conj(v[:-lag])) ** 2)
    if coarse == 0 or fine == 0:
        return None
    over_lag = 0.5 * np.angle(fine)
    wraps = np.round((np.angle(coarse) * lag - over_lag) / np.pi)
    return complex(np.exp(1j * (over_lag + wraps * np.pi) / lag))


# A flying receiver's twin drifts through its spoofer (their code rates differ as their carriers do: 11.7 Hz apart,
# 0.008 chip/s). Closer than CROSSING_CHIPS the two-path fit cannot place it (its pairs stop MIN_SEPARATION_CHIPS
# apart: the twin was held 0.1 chip off while it crossed, the spoofer's estimate took it in, and the track lost its
# spoofer; GPS-SDR-SIM, 500 m, +10 dB, 5 m/s). There the twin's offset is carried by its rate, and the two are told
# apart by their carriers: over a buffer the spoofer's amplitude stands still in its own carrier frame while the
# twin's turns, so one least-squares fit of both per buffer splits them, provided the twin turns enough in it.
CROSSING_CHIPS = 0.15
CROSSING_MIN_HZ = 3.0             # below, the twin turns under a cycle in a buffer: too close to split by carrier
CROSSING_MIN_SPREAD = 0.5         # the fit's two columns (1 and the turn) at least this far from collinear


# A legitimate peak closer than this to the spoofer's leaks into the spoofer's amplitude estimate (the code
# autocorrelation at their offset): both signals are then followed jointly by the two-path tracker.
JOINT_WITHIN_CHIPS = 1.2
# Further off, a PRN whose code correlates with itself at +-1 or +-2 chips (63 or 65 / 1023: half the PRNs) still leaks
# its twin into the spoofer's prompt, a few per cent of it, and the replica then carves that much of the twin out at the
# spoofer's delay; a receiver with early and late half a chip either side of the twin (GNSS-SDR) is biased by such an
# anti-echo up to 1.5 chips away (GPS-SDR-SIM, 500 m, +3 and +6 dB: PRN 17's twin 1.27 chip off, 4.5 % leaking,
# -1.3 to -1.4 m).
LEAKING_WITHIN_CHIPS = 1.5
LEAKING_SHARE = 0.01
# Rounded chips (a front end's, chip_shape) spread each signal's correlation further: a twin up to this much further
# off leaks, and pulls its spoofer's early-late balance (GPS-SDR-SIM behind a 1 MHz front end, 1 km: spoofers 0.01-0.05
# chip off their replicas, twins 1-2 chips away)
SHAPED_REACH_CHIPS = TAP_REACH_CHIPS
BACKFILL_COHERENT_WITHIN_CHIPS_S = 0.5   # the DLL's code rate and the carrier's, apart by less: the carrier's
TWIN_GAIN = 0.5                   # fraction of each buffer's measured twin offset error applied
# Behind a front end the two rounded paths' fit says where the twin is only while its carrier stands off its
# spoofer's: the bank's real products then span both paths, in phase (or in anti-phase) one vector, and the fit slides
# along a ridge of place against amplitude. GPS-SDR-SIM behind 1 MHz, static, 500 m, +6 dB: twins 0.38 and 0.49 chip
# off turning 0.04-0.06 Hz against their spoofers were placed within 0.02 chip while |sin| of their phase apart
# stayed over 0.85, drawn 0.04 chip off by 0.6, 0.1-0.26 chip off (and the spoofer's amplitude with them) near 0 and
# 180 degrees. A settled twin turning slower than TWIN_SLOW_HZ is placed by the buffers in quadrature
# (TWIN_QUADRATURE_SIN) alone, each weighed by sin^2 over TWIN_PLACE_MEMORY_S (a twin 0.013 chip off its place still
# biased its range 3-4 m), and held there through the stretches between, moved only as its carrier predicts, for up
# to TWIN_HOLD_S after its last placing: a real twin's phase turns on (a 0.01 Hz beat stays within 30 degrees of
# in-phase 15 s at a time), a front end's phantom of the spoofer's own chips never leaves it, and unplaced for
# TWIN_PLACED_S it is fitted buffer by buffer as before.
TWIN_SLOW_HZ = 1.0
TWIN_QUADRATURE_SIN = 0.85
TWIN_PLACE_MEMORY_S = 10.0
TWIN_PLACED_S = 1.0
# Behind a front end the spoofer does not sit where its replica's early-late balance puts it in the shaped model's
# frame: a joint track's two-path fit put every spoofer 0.005-0.011 chip off its replica, and what was subtracted lay
# 0.014-0.022 chip from where the shape fits the spoofer best (GPS-SDR-SIM behind 1 MHz, static 500 m +6 dB), a
# residual of a few per cent of the spoofer across its twin (PRN 1's range 3.5 m off, PRN 17's 2.9 m). The place is
# the front end's and the loops', the same for every spoofer (0.009-0.017 chip over 10 of 12 PRNs at +3 dB), where a
# close twin in phase bends one track's fit (PRN 7, 0.38 chip: -0.038): each joint track learns it from its fits over
# PLACE_MEMORY_S (spoofer_place_chips), and every shaped replica is subtracted at the median of those that learnt it
# PLACE_LEARNT_S or longer (ChipShapeMeter.place_chips, once PLACE_VOTERS have), in steps of PLACE_STEP_CHIPS (each
# its own bank), within PLACE_MAX_CHIPS of the replica.
PLACE_MEMORY_S = 2.0
PLACE_LEARNT_S = 2.0
PLACE_VOTERS = 3
PLACE_STEP_CHIPS = 0.002
PLACE_MAX_CHIPS = 0.05
TWIN_HOLD_S = 20.0
# Once settled on chips found ideal, a joint track fits the offsets on its bank's products (signal_products) carried
# over the last TWIN_MEMORY_S or so, each buffer's weighed down by exp(-its length / TWIN_MEMORY_S): the two paths'
# offsets change slowly, and one 50 ms buffer scatters the twin's by 0.009 chip RMS (a 45 dB-Hz twin 0.8 chip from a
# +15 dB spoofer, ideal chips), and its leakage into the spoofer's prompt, taken out of the spoofer's amplitude, with
# it: followed buffer by buffer the twin sat 0.012 chip too close beside a second spoofer, 0.001 chip on the last
# second
TWIN_MEMORY_S = 1.0
TWIN_SMEAR_CHIPS = 0.001          # or, for a twin that moves, as long as it moves this far
LAG_KEPT_CHIPS = 0.5              # the carried products' lags are kept while they reach this far beyond the twin
# A legitimate signal within BIASED_WITHIN_CHIPS of its spoofer keeps, after cancellation, the spoofer's residual
# within BIASED_RESIDUAL_DB of itself when the spoofer is BIASED_TWIN_DB stronger (the residual some
# ASSUMED_ATTENUATION_DB down), and the closer the twin the worse the spoofer's own estimate: a multipath at under a
# chip. Measured with GNSS-SDR behind the plug-in filter (GPS-SDR-SIM, 500 m, twins 0.37 and 0.49 chip away): at
# +15 dB biased 1.1 m, at +20 dB 4.2-4.6 m (twins 0.85-1.2 chip away under 0.7 m at both); 17 dB is where the bias
# reaches about 2 m. A cancellation that achieves less leaves a weaker attacker's residual as close: ArduCopter SITL,
# a +3 dB takeover, a twin 0.2-0.5 chip from its spoofer, the first windows 12-18 dB: its range put a fix called
# recovered 10.5 m off. A measured attenuation counts only where it is worse than the assumed one: with a twin that
# close the measurement (which takes the fitted twin out) flatters (39-45 dB measured at +15 and +20 dB alike).
BIASED_TWIN_DB = 17.0
ASSUMED_ATTENUATION_DB = 32.0
BIASED_RESIDUAL_DB = BIASED_TWIN_DB - ASSUMED_ATTENUATION_DB
BIASED_WITHIN_CHIPS = 0.6


def biased_twin(advantage_db: float, offset_chips: float, attenuation_db: float | None = None) -> bool:
    """Whether a legitimate twin this far (chips) under a spoofer this much stronger (dB), whose cancellation
    achieved attenuation_db (None: not measured yet), keeps a biased range after the spoofer's cancellation."""
    achieved = ASSUMED_ATTENUATION_DB if attenuation_db is None else min(attenuation_db, ASSUMED_ATTENUATION_DB)
    return advantage_db - achieved >= BIASED_RESIDUAL_DB and abs(offset_chips) < BIASED_WITHIN_CHIPS


class AdversaryTrack:
    """One spoofed signal followed and cancelled, with what it measured of its own cancellation.

    When the legitimate peak of the same PRN lies within about a chip (legit_offset_chips: its code phase minus the
    spoofer's, at the same instant), the spoofer's prompt holds a share of the legitimate signal (the codes'
    autocorrelation at that offset), and pulls the spoofer's early-late balance. Subtracting that would carve an
    anti-echo into the legitimate signal and bias its tracking, so both signals are followed by the two-path tracker
    (twopath_track): each buffer's bank of correlators gives the ML delays of both and each code period's two
    amplitudes; the twin is taken out of a copy of the samples, and the spoofer tracked again on it.
    """

    def __init__(self, prn: int, fs_hz: float, if_hz: float, peak: Peak, peak_sample: int, start_after_sample: int,
                 cfg: CancellerConfig, stage: int, legit_offset_chips: float | None = None,
                 front_end: ChipShapeMeter | None = None):
        self.prn, self.stage, self.cfg = prn, stage, cfg
        self.front_end = front_end     # the chips' shape as received (rectangular without one)
        self._subtracted: tuple[tuple | None, CodeBank | None] = (None, None)   # (shape, place) and its bank
        self.spoofer_place_chips = 0.0   # where the spoofer sits from its replica, behind a front end (PLACE_*)
        self.place_learnt_ms = 0         # ... learnt over this many code periods
        self.legit_offset_chips = legit_offset_chips
        # under a spoofer far stronger than any satellite (Canceller.cancel's defer_twin) a twin the two-path fit
        # placed within TWIN_NEAR_CHIPS on ideal chips' model may be a front end's rounding of the spoofer's own
        # chips: it is not followed until the meter has measured the shape and placed the spoofer's twin on it
        # (seat_twin), nor is a twin it shows that the track knew nothing of
        self.defer_twin = False
        self.suspect_chips: float | None = None   # the suspected twin's offset, until judged
        self.dismissed_chips: float | None = None   # a suspected twin the meter found no signal
        loop = LoopConfig(pll_bw_hz=cfg.pll_bw_hz, dll_bw_hz=cfg.dll_bw_hz, pull_in_ms=cfg.pull_in_ms,
                          min_cn0_dbhz=20.0, dll_narrow_bw_hz=cfg.narrow_dll_bw_hz,
                          narrow_after_ms=cfg.narrow_after_ms, spacing_chips=cfg.spacing_chips)
        st = initial_state(peak.code_phase_chips, peak_sample, peak.doppler_hz, fs_hz, start_after_sample)
        self.channel = Channel(prn, fs_hz, if_hz, st, loop)
        self._ref = 0j                 # smoothed complex amplitude (bit removed)
        self._legit_ref = 0j           # the same for a legitimate signal within a chip
        self._legit_turn: float | None = None   # its turn per period (rad) in the spoofer's carrier frame:
                                       # they differ in Doppler
        self._legit_est: np.ndarray | None = None   # its amplitude per code period of the last buffer
        self._twin_lag = 0.0           # and where it was, from the spoofer's replica
        self._placed_ms = 0            # periods of a settled twin fitted in quadrature with its spoofer ...
        self._last_placed_ms: int | None = None   # ... the period the latest such buffer ended on ...
        self._placed_weight = 0.0      # ... and their weight in its place (TWIN_PLACE_MEMORY_S)
        self._bank: tuple[np.ndarray, np.ndarray] | None = None   # the last fit's correlations and lags
        self._products: tuple[np.ndarray, np.ndarray] | None = None   # (lags, products) carried (TWIN_MEMORY_S)
        self._ref_start = 0j           # _ref before this buffer's periods (the refit smooths them again)
        self._lam = 1.0 / cfg.smoothing_ms
        self._acc_signal = self._acc_residual = self._acc_noise = 0.0
        self._acc_n = 0
        self._measure_phase = 0
        self.attenuation_db: list[tuple[float, bool]] = []   # per ~1 s window: (dB, only a lower bound)
        self.settled = False
        # while the loops settle, samples from here on (where the track began: the stage has emitted none of them)
        # are held back; None once settled
        self.hold_from: float | None = float(start_after_sample)

    @property
    def next_sample(self) -> float:
        return float(self.channel.st[NEXT_SAMPLE])

    @property
    def shape(self) -> ChipShape:
        return RECTANGULAR if self.front_end is None else self.front_end.shape

    @property
    def subtract_bank(self) -> CodeBank:
        """The code as it is subtracted: shaped as the front end delivers it (tracking keeps rectangular chips),
        moved to where the spoofer sits (bank_place_chips). Held here: the banks are shared while someone holds them,
        and built again (1 MB) when no one does."""
        key = (self.shape, self.bank_place_chips)
        if self._subtracted[0] != key:
            self._subtracted = (key, shaped_bank(self.prn, self.channel.fs_hz, *key))
        return self._subtracted[1]

    @property
    def bank_place_chips(self) -> float:
        """How far the subtracted bank's code is moved from the replica: the spoofers' place, on PLACE_STEP_CHIPS."""
        if self.shape.rectangular:
            return 0.0
        return round(round(self.front_end.place_chips / PLACE_STEP_CHIPS) * PLACE_STEP_CHIPS, 6)

    def _learn_place(self, paths: TwoPaths, periods: int) -> None:
        """The spoofer's place from a two-path fit of this buffer, behind a front end (PLACE_MEMORY_S)."""
        if self.shape.rectangular or not self.settled or self._crossing():
            return
        keep = np.exp(-periods * CA_CODE_PERIOD_S / PLACE_MEMORY_S)
        place = keep * self.spoofer_place_chips + (1.0 - keep) * paths.spoofer_offset_chips
        self.spoofer_place_chips = float(np.clip(place, -PLACE_MAX_CHIPS, PLACE_MAX_CHIPS))
        self.place_learnt_ms += periods

    def seat_twin(self, twin: tuple[float, float] | None) -> None:
        """The twin the meter judged (ChipShapeMeter.fit_when_ready: offset from the spoofer, dB under it; None:
        none), followed jointly where it leaks into the spoofer: a suspected twin's place (none: the front end's
        rounding, dismissed), and a twin a lone track knew nothing of (a synchronized attacker's twin a chip or two
        off, hidden in the spoofer at the alarm); for a track that defers its twin only. A judgement without a level
        (dB nan: ideal chips, or too weak to tell) puts a suspected twin where the two-path fit placed it."""
        suspect, self.suspect_chips = self.suspect_chips, None
        if not self.defer_twin or (self.legit_offset_chips is not None and suspect is None):
            return
        if twin is not None and np.isnan(twin[1]):   # a deferred suspect goes where the two-path fit placed it
            if self.legit_offset_chips is None:
                self.legit_offset_chips = twin[0]
            return
        self.legit_offset_chips = None if twin is None else twin[0]
        if not self._joint():
            self.legit_offset_chips = None
        if suspect is not None and self.legit_offset_chips is None:
            self.dismissed_chips = suspect

    def track(self, tracked: np.ndarray, base_sample: int) -> None:
        """The tracking half: reads samples only, so several tracks can run at once (the kernels release the GIL)."""
        first_ms = self.channel.ms
        before = copy.deepcopy(self.channel) if self._joint() else None
        prompts, _ = self.channel.process(tracked, base_sample)
        blocks = self.channel.last_blocks
        self._legit_est = None   # this buffer's, or none (a stale one would not match its blocks)
        if before is not None and self.settled:   # the twin's offset moves as its carrier turns against the spoofer's
            self.legit_offset_chips += self._offset_rate_chips_s * prompts.size * CA_CODE_PERIOD_S
        paths = None
        if before is not None and prompts.size:
            paths = self._twin_where_carried(tracked, base_sample, blocks) if self.settled else \
                self._two_paths(tracked, base_sample, blocks)[0]
        if paths is not None:
            # the twin within a chip pulls the spoofer's early-late balance: take it out of a copy of the samples and
            # track the same samples again from the same loop state
            # (a copy from where this buffer's tracking began: samples held back before it are not read again)
            # Once settled, the twin is learnt by refit(), on samples without the other PRNs' spoofers
            start = max(0, int(np.floor(float(before.st[NEXT_SAMPLE]))) - base_sample - 1)
            without_legit = np.array(tracked[start:], copy=True)
            subtract_replicas(without_legit, base_sample + start, blocks,
                              self._legit_amplitudes(paths.twin_amplitudes, update=not self.settled),
                              self.subtract_bank, offset_chips=paths.twin_offset_chips - self.bank_place_chips)
            self.channel = before
            prompts, _ = self.channel.process(without_legit, base_sample + start)
            blocks = self.channel.last_blocks
            if not self.settled:   # the separation is the same seen from either replica (the fit places both paths)
                self.legit_offset_chips += TWIN_GAIN * (paths.separation_chips - self.legit_offset_chips)
        self._tracked = (first_ms, prompts, blocks)

    def refit(self, work: np.ndarray, base_sample: int, planned: tuple) -> np.ndarray | None:
        """A joint track's second look, once every track's replica is subtracted from `work`: this buffer's
        periods less the other PRNs' spoofers (this track's own replica added back). Their codes' cross-correlation
        is no noise a buffer averages away where two Dopplers are close modulo 1 kHz: fitted on the raw samples,
        the twin came out 0.01-0.06 chip too far and a few per cent too weak (GPS-SDR-SIM, every PRN spoofed at
        +6 and +15 dB). The twin and the spoofer's amplitude are measured again there; returns the change to this
        buffer's replica amplitudes (None: not joint, or no fit)."""
        blocks, est = planned
        if not self._joint():
            return None
        paths, prompt = self._two_paths(work, base_sample, blocks, add=est, carry=True)
        if paths is None:
            return None
        placing = self._twin_placing(paths, len(blocks))
        if placing == "held":   # the spoofer where it sits, the twin where it was placed
            place = self.bank_place_chips
            paths = paths_at(self.prn, *self._bank, place, place + float(self.legit_offset_chips), self.shape)
        else:
            # near phase a slow twin's fit slides (_twin_placing): the place is learnt in quadrature only
            if placing == "placed" or abs(self._turn_hz) >= TWIN_SLOW_HZ:
                self._learn_place(paths, len(blocks))
            if placing is None:
                self.legit_offset_chips += TWIN_GAIN * (paths.separation_chips - self.legit_offset_chips)
        self._legit_est = self._legit_amplitudes(paths.twin_amplitudes)
        self._twin_lag = paths.twin_offset_chips
        # the spoofer's prompt less the twin's share of it: the residual at the replica, the twin subtracted
        beta = prompt - self._legit_est * code_overlap(blocks, self.channel.bank,
                                                       paths.twin_offset_chips - self.bank_place_chips,
                                                       self.subtract_bank)
        beta = np.where(np.isfinite(beta), beta, est)
        again, self._ref = decision_smooth(beta, self._ref_start, self._lam)
        return again - est

    def _twin_placing(self, paths: TwoPaths, periods: int) -> str | None:
        """How a slowly turning settled twin behind a front end is placed by this buffer's fit: 'placed' (the carriers
        in quadrature, TWIN_QUADRATURE_SIN: the fit moves the place by its weight), 'held' (near phase: the place
        stays), None where the fit is taken buffer by buffer as before (chips not found rounded, a twin crossing or
        turning fast, one placed too little or too long ago)."""
        meter = self.front_end
        if meter is None or not meter.done or meter.shape.rectangular or self._crossing() or self._bank is None \
                or not self.settled or abs(self._turn_hz) >= TWIN_SLOW_HZ or self._ref == 0 or self._legit_ref == 0:
            return None
        sin = float(np.sin(np.angle(self._legit_ref * np.conj(self._ref))))
        if abs(sin) >= TWIN_QUADRATURE_SIN:
            weight = sin ** 2
            self._placed_weight = self._placed_weight * np.exp(-periods * CA_CODE_PERIOD_S / TWIN_PLACE_MEMORY_S) \
                + weight
            self.legit_offset_chips += weight / self._placed_weight * (paths.separation_chips
                                                                        - self.legit_offset_chips)
            self._placed_ms += periods
            self._last_placed_ms = self.channel.ms
            return "placed"
        if self._last_placed_ms is not None \
                and (self.channel.ms - self._last_placed_ms) * CA_CODE_PERIOD_S > TWIN_HOLD_S:
            self._placed_ms, self._last_placed_ms, self._placed_weight = 0, None, 0.0
        return "held" if self._placed_ms * CA_CODE_PERIOD_S >= TWIN_PLACED_S else None

    @property
    def _turn_hz(self) -> float:
        return (self._legit_turn or 0.0) / (2 * np.pi * CA_CODE_PERIOD_S)

    @property
    def _offset_rate_chips_s(self) -> float:
        """How fast the twin's code moves from the spoofer's: code and carrier Doppler go together."""
        return self._turn_hz * CA_CHIP_RATE_HZ / L1_HZ

    def _crossing(self) -> bool:
        return self.settled and abs(self.legit_offset_chips) < CROSSING_CHIPS and abs(self._turn_hz) >= CROSSING_MIN_HZ

    def _two_paths(self, x: np.ndarray, base_sample: int, blocks: np.ndarray, add: np.ndarray | None = None,
                   carry: bool = False) -> tuple[TwoPaths | None, np.ndarray]:
        """Both paths fitted on this buffer, and each period's correlation with the replica itself. add: this
        track's replica amplitudes, added back to x as it is read (x less every spoofer, this one's put back);
        carry: the offsets fitted on the products carried from earlier buffers too (TWIN_MEMORY_S)."""
        crossing = self._crossing()
        carry = carry and self._chips_known_ideal()
        lags = np.zeros(1) if crossing else np.append(self._bank_lags(carry), 0.0)
        y, power = correlator_bank(x, base_sample, blocks, self.channel.bank, lags, add, self.cfg.real_samples,
                                   self.subtract_bank)
        prompt = y[:, -1]
        self._bank = (y[:, :-1], lags[:-1])
        if crossing:
            self._products = None
            return self._split_by_carrier(prompt), prompt
        y, lags, noise = y[:, :-1], lags[:-1], self._noise_power(power, blocks)
        products = None
        if carry:
            products = signal_products(self.prn, y, lags, noise)
            if self._products is not None and np.array_equal(self._products[0], lags):
                # a twin moving from its spoofer (a flying receiver) is remembered as long as it stays in place
                memory_s = min(TWIN_MEMORY_S, TWIN_SMEAR_CHIPS / max(abs(self._offset_rate_chips_s), 1e-9))
                products += np.exp(-len(blocks) * CA_CODE_PERIOD_S / memory_s) * self._products[1]
            self._products = (lags, products)
        return fit_two_paths(self.prn, y, lags, self.legit_offset_chips, noise, self.shape, products), prompt

    def _noise_power(self, power: np.ndarray, blocks: np.ndarray) -> float:
        """noise_power of the bank's samples less this track's own two signals, which the samples' power holds: a
        +15 dB spoofer is 38 % of the noise at 2.6 MSa/s, and that much more of the noise's share taken out of the
        products drew a twin in quadrature 0.38 chip off towards its spoofer (a wide correlator's range behind the
        filter 0.43-0.58 m off over three noise seeds, 0.01-0.16 m with the signals' power taken out). A real
        signal's power is twice its complex amplitude's (the mirror image)."""
        images = 2.0 if self.cfg.real_samples else 1.0
        own = images * (abs(self._ref) ** 2 + abs(self._legit_ref) ** 2)
        return max(0.0, noise_power(power - own, blocks))

    def _chips_known_ideal(self) -> bool:
        """Whether the meter found the chips rectangular, the two-path model then exact: behind a front end its
        misfit looks like a twin a few tenths of a chip off, and a fit remembered over a second held such a phantom
        until it took the spoofer's power (GPS-SDR-SIM behind 1 MHz, flying, 3 km, +10 dB: the twin fitted 27 dB
        over its spoofer, the spoofer left in the output, GNSS-SDR behind the filter 1685 m off)."""
        meter = self.front_end
        return meter is None or (meter.done and meter.shape.rectangular)

    def _bank_lags(self, carry: bool) -> np.ndarray:
        """The bank's lags: the carried products' while they still reach LAG_KEPT_CHIPS beyond the twin (carry:
        on whole steps, else as the twin's offset puts them)."""
        offset = self.legit_offset_chips
        if carry and self._products is not None:
            lags = self._products[0]
            if lags[0] + LAG_KEPT_CHIPS <= min(0.0, offset) and max(0.0, offset) <= lags[-1] - LAG_KEPT_CHIPS:
                return lags
        return bank_lags(offset, whole_steps=carry)

    def _twin_where_carried(self, x: np.ndarray, base_sample: int, blocks: np.ndarray) -> TwoPaths | None:
        """A settled track's twin for its first tracking pass, at the offset carried from the last buffer's fit, the
        spoofer on the replica: two correlators, not a bank. The fit's own offsets there differed from these by its
        noise (GPS-SDR-SIM, every PRN spoofed, +6 dB, twins 0.8 and 1 chip off: the spoofer 0.003 +- 0.006 chip, the
        twin 0.006 +- 0.015 chip), and refit() fits the buffer again on the replica tracked without the twin."""
        crossing = self._crossing()
        place = self.bank_place_chips
        lags = np.zeros(1) if crossing else np.array([place, place + self.legit_offset_chips])
        y, _ = correlator_bank(x, base_sample, blocks, self.channel.bank, lags)
        if crossing:
            return self._split_by_carrier(y[:, 0])
        return paths_at(self.prn, y, lags, place, place + float(self.legit_offset_chips), self.shape)

    def _split_by_carrier(self, z: np.ndarray) -> TwoPaths | None:
        """A twin crossing its spoofer (CROSSING_CHIPS), at its predicted offset: the prompt per period is
        b_k (s + c_k t rho^k) R-weighted, the spoofer's bits b_k decided against its reference, rho the twin's turn;
        s and t by least squares over the buffer, then the twin's own bits c_k relative to the spoofer's decided
        and the fit made again (z: the prompt per period). None when the buffer is too short for the turn to tell
        the two apart."""
        ok = np.isfinite(z)
        if self._ref == 0 or not ok.any():
            return None
        turning = np.exp(2j * np.pi * self._turn_hz * CA_CODE_PERIOD_S * np.arange(z.size))
        if abs(np.mean(turning[ok])) > 1.0 - CROSSING_MIN_SPREAD:
            return None
        bits = np.where((z * np.conj(self._ref)).real >= 0, 1.0, -1.0)
        zb = (z * bits)[ok]
        relative = np.ones(zb.size)
        for decide in (True, False):
            a = np.column_stack([np.ones(zb.size), relative * turning[ok]])
            (s_amp, t_amp), *_ = np.linalg.lstsq(a, zb, rcond=None)
            if decide:
                relative = np.where(((zb - s_amp) * np.conj(t_amp * turning[ok])).real >= 0, 1.0, -1.0)
        spoofer = np.full(z.size, np.nan + 0j)
        twin = np.full(z.size, np.nan + 0j)
        spoofer[ok] = bits[ok] * s_amp
        leak = self.shape.correlation(self.prn, self.legit_offset_chips)
        twin[ok] = bits[ok] * relative * t_amp * turning[ok] / leak
        return TwoPaths(0.0, float(self.legit_offset_chips), spoofer, twin)

    def _legit_amplitudes(self, raw: np.ndarray, update: bool = True) -> np.ndarray:
        """The legitimate signal's amplitude per code period (in the spoofer's carrier frame), smoothed with its own
        data bits decided against a running reference."""
        raw = np.nan_to_num(raw)
        if update and not self._crossing():   # (crossing, raw is built with the turn: nothing to learn from)
            turn = rotation_per_period(raw)
            if turn is not None:
                # the first measurement taken whole: from nought, a flying receiver's twin turning tens of hertz
                # took seconds to be followed, its amplitude smeared into the spoofer's replica meanwhile
                self._legit_turn = float(np.angle(turn)) if self._legit_turn is None else \
                    self._legit_turn + ROTATION_GAIN * (np.angle(turn) - self._legit_turn)
        ref = self._legit_ref if self._legit_ref != 0 else (raw[0] if raw.size else 0j)
        est, ref = decision_smooth(raw, ref, self._lam, np.exp(1j * (self._legit_turn or 0.0)))
        if update:
            self._legit_ref = ref
        return est

    @property
    def latest_attenuation_db(self) -> float | None:
        """The attenuation of the latest window measured (a lower bound counts as its value), None before any."""
        return self.attenuation_db[-1][0] if self.attenuation_db else None

    @property
    def twin_advantage_db(self) -> float | None:
        """How much stronger the spoofer is than its legitimate twin within a chip (None without a twin so close)."""
        if not self._joint() or self._ref == 0 or self._legit_ref == 0:
            return None
        return float(20 * np.log10(abs(self._ref) / abs(self._legit_ref)))

    def _joint(self) -> bool:
        offset = self.legit_offset_chips
        if offset is None:
            return False
        reach = LEAKING_WITHIN_CHIPS + (0.0 if self.shape.rectangular else SHAPED_REACH_CHIPS)
        return abs(offset) < JOINT_WITHIN_CHIPS or (
            abs(offset) < reach and abs(self.shape.correlation(self.prn, offset)) >= LEAKING_SHARE)

    def prepare(self, work: np.ndarray, base_sample: int) -> tuple | None:
        """The cancelling half (its stage subtracts, then measure()): the replicas track() measured, as (blocks,
        amplitudes) to subtract from `work`, or None while the loops settle.

        Nothing is subtracted while the loops settle; those samples are held back (hold_from) and, once the
        loops have settled, cancelled here with the settled replica extended backwards in time.
        """
        i0 = self._first_settled()
        if i0 is None:
            return None
        _, prompts, blocks = self._tracked
        blocks, alphas = blocks[i0:], prompts[i0:] / blocks[i0:, 1]   # least squares: unit-modulus replica
        if not self.settled:
            self._ref = alphas[0]
        self._ref_start = self._ref
        est, self._ref = decision_smooth(alphas, self._ref, self._lam)
        if not self.settled:
            self.settled = True
            self._backfill(work, base_sample, blocks[0], est[0])
            self.hold_from = None
        return blocks, est

    def subtract(self, x: np.ndarray, base_sample: int, blocks: np.ndarray, amplitudes: np.ndarray) -> None:
        """x less this track's replicas (prepare()'s, or refit()'s change to them) over the part of them inside x."""
        subtract_replicas(x, base_sample, blocks, amplitudes, self.subtract_bank, self.cfg.real_samples)

    def _first_settled(self) -> int | None:
        """The first of the periods track() measured that lies past the loops' pull-in (None: none does)."""
        first_ms, prompts, _ = self._tracked
        settled = first_ms + np.arange(prompts.size) >= self.cfg.pull_in_ms
        return int(np.argmax(settled)) if settled.any() else None

    def measure(self, work: np.ndarray, base_sample: int, planned: tuple) -> None:
        """What the subtraction of prepare()'s replicas left (after it)."""
        if self._joint() and self._legit_est is None:
            return   # the twin not fitted in this buffer: it would count as a residual
        self._measure(work, base_sample, *planned, self._legit_est)

    def _held_blocks(self, base_sample: int, settled_block: np.ndarray) -> np.ndarray | None:
        """The code periods of the held samples, newest first, from the first settled block back to where the
        track began (the partial one before its first epoch too); None when there are none."""
        first, _, cp, step, ph, pstep = settled_block
        # the code's rate from the carrier's where the two agree as a satellite's do: a DLL just settled is still a
        # tenth of a chip a second off (0.03 chip at the held samples' start, the spoofer 12 dB down there); a
        # spoofer whose code and carrier part keeps the DLL's rate
        fs_hz = self.channel.fs_hz
        coherent = CA_CHIP_RATE_HZ * (1.0 + (pstep * fs_hz - self.channel.if_hz) / L1_HZ) / fs_hz
        if abs(coherent - step) * fs_hz < BACKFILL_COHERENT_WITHIN_CHIPS_S:
            step = coherent
        period = CA_CODE_LENGTH_CHIPS / step                 # samples per code period
        epoch0 = first - cp / step                           # fractional sample of the settled block's epoch
        lowest = np.ceil(max(self.hold_from, base_sample))
        blocks = []
        k = 1
        while np.ceil(epoch0 - (k - 1) * period) > lowest:   # newest first: the smoothing walks back in time
            e = epoch0 - k * period
            s0 = max(np.ceil(e), lowest)
            n = np.ceil(e + period) - s0
            blocks.append((s0, n, (s0 - e) * step, step, ph + (s0 - first) * pstep, pstep))
            k += 1
        return np.array(blocks) if blocks else None

    def _backfill(self, work: np.ndarray, base_sample: int, settled_block: np.ndarray, settled_est: complex) -> None:
        """Cancel the held samples, from where the track began (the partial code period before its first epoch
        too) up to the first settled block, with the settled replica run backwards. Its amplitude is smoothed
        back in time turning by the carrier's error at the settling: a PLL just settled is a few Hz off, and a
        smoothing that does not turn lags it (GPS-SDR-SIM, +10 dB, every PRN spoofed from the first sample, a
        2 Hz error: the spoofer 8-10 dB down over the held 0.3 s, 20-30 dB with the turn, as after it; an
        unmodified receiver behind the plug-in filter acquired the spoofers' leftovers there and lost them)."""
        blocks = self._held_blocks(base_sample, settled_block)
        if blocks is None:
            return
        beta, power = residuals(work, base_sample, blocks, self.channel.bank)
        ok = np.isfinite(power)
        bit = 1.0 if (settled_est * np.conj(self._ref)).real >= 0 else -1.0
        turn = rotation_per_period(beta[ok])
        est, _ = decision_smooth(beta[ok], settled_est * bit, self._lam, 1.0 if turn is None else turn)
        subtract_replicas(work, base_sample, blocks[ok], est, self.subtract_bank, self.cfg.real_samples)

    def _measure(self, work, base_sample, blocks, est, legit=None) -> None:
        """What is left at the replica: the attenuation this track achieves (noise-corrected powers).

        Over a window of N code periods, the residual's power at the replica, less the noise's share (the
        residual's power / n per period), against the cancelled signal's power. When what is left is below what the
        window can resolve (about 2 noise / sqrt(N)), that resolution is reported, flagged as a lower bound.
        """
        # one code period in MEASURE_EVERY is enough for the report, and keeps the measurement cheap
        pick = (np.arange(len(blocks)) + self._measure_phase) % MEASURE_EVERY == 0
        self._measure_phase = (self._measure_phase + len(blocks)) % MEASURE_EVERY
        blocks, est = blocks[pick], est[pick]
        beta, power = residuals(work, base_sample, blocks, self.channel.bank)
        if legit is not None:   # a legitimate signal within a chip is seen at the replica too: not a residual
            beta = beta - self.shape.correlation(self.prn, self._twin_lag) * legit[pick]
        ok = np.isfinite(power)
        self._acc_signal += float(np.sum(np.abs(est[ok]) ** 2))
        self._acc_residual += float(np.sum(np.abs(beta[ok]) ** 2))
        self._acc_noise += float(np.sum(power[ok] / blocks[ok, 1]))
        self._acc_n += int(np.sum(ok))
        if self._acc_n >= 2000 // MEASURE_EVERY:   # a report every ~2 s
            resolution = 2.0 * self._acc_noise / np.sqrt(self._acc_n)
            residual = self._acc_residual - self._acc_noise
            bound = residual < resolution
            self.attenuation_db.append((round(float(10 * np.log10(self._acc_signal / max(residual, resolution))), 1),
                                        bool(bound)))
            self._acc_signal = self._acc_residual = self._acc_noise = 0.0
            self._acc_n = 0


# What is left of a PRN given up (Canceller.cancel's removal: its legitimate twin merged with what the stages left of
# its spoofer) is taken out by projection, not by one more replica: each code period, the samples' components on the
# PRN's code at every REMOVAL_STEP_CHIPS within REMOVAL_REACH_CHIPS of the remainder are fitted together and
# subtracted, whatever signals lie there and however a front end rounds their chips. One replica on the merged pair
# left a signal to track (GPS-SDR-SIM behind 1 MHz, flying, 500 m, +15 dB: PRN 7 taken out at 4.4 s, our receiver
# behind the filter acquired what was left at 16.1 s, 37 dB-Hz, its range 27.8 m off).
REMOVAL_STEP_CHIPS = 0.1
REMOVAL_REACH_CHIPS = 2.0
REMOVAL_RCOND = 1e-6     # the lags' Gram inverted on its directions this far above its largest
# The Gram of the sampled codes at those lags hangs on where the samples fall on the chips: over a whole period,
# on the block's code phase modulo a sample (the same positions, one sample on). It is held for REMOVAL_PHASES such
# phases: one half a phase off leaves at most -30 dB of a signal on one lag; one Gram from another period's phase
# left -15 dB (a 50 dB-Hz twin still trackable), 32 phases -26 dB
REMOVAL_PHASES = 64
# A remainder is not a signal a loop can hold for long: where the twin crosses its spoofer, the first stage's joint
# track takes part of it with the spoofer, and what is left beats against the spoofer's residual. Followed alone, it
# was lost three times in 51 s and the satellite left in the output (GPS-SDR-SIM behind 1 MHz, real samples, flying,
# 500 m, +15 dB: PRN 7's range 21.8 m off behind the filter). So a removal is leashed to its spoofer's first-stage
# track, which holds (the strongest signal there is): its own loops follow the remainder while they stay within
# REMOVAL_LEASH_CHIPS of where that track puts the twin (within REMOVAL_CENTRE_CHIPS of the spoofer: the lags' reach
# covers both) and within REMOVAL_LEASH_HZ of its Doppler (a flying receiver's twin beats against a static attacker's
# spoofer at up to ~30 Hz), and are moved back there when they stray; it keeps its lock while that track does.
REMOVAL_LEASH_CHIPS = 0.5
REMOVAL_CENTRE_CHIPS = 1.0
REMOVAL_LEASH_HZ = 50.0


class RemovalTrack(AdversaryTrack):
    """A PRN's remainder followed by a lone track leashed to its spoofer's (anchor), and taken out by projection on
    the code around it (the lags)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.anchor: AdversaryTrack | None = None   # the PRN's first-stage track (None: the removal follows alone)
        self.anchor_offset_chips = 0.0              # where the remainder was from it, for an anchor without a twin
        reach = int(round(REMOVAL_REACH_CHIPS / REMOVAL_STEP_CHIPS))
        self.lags = REMOVAL_STEP_CHIPS * np.arange(-reach, reach + 1)
        self._zero = reach                  # the lag of the replica itself
        self._fit: np.ndarray | None = None   # the Gram's pseudo-inverse: the components from the correlations
        self._prompt: np.ndarray | None = None   # the correlation with the replica itself, per period

    def leash(self, anchor: AdversaryTrack, remainder_chips: float, sample: int) -> None:
        """Follow the remainder (its code phase at an absolute sample) leashed to its spoofer's first-stage track,
        when it lies within REMOVAL_CENTRE_CHIPS of it (further off it is a signal of its own, the spoofer's residual
        apart, that its loops hold alone)."""
        chips = anchor.channel.code_phase_at(sample)
        if chips is None or abs(chips_offset(remainder_chips, chips)) > REMOVAL_CENTRE_CHIPS:
            return
        self.anchor, self.anchor_offset_chips = anchor, chips_offset(remainder_chips, chips)

    def track(self, tracked: np.ndarray, base_sample: int) -> None:
        leashed = self._pull_to_anchor()
        super().track(tracked, base_sample)
        if leashed:
            self.channel.hold_lock()

    def _pull_to_anchor(self) -> bool:
        """The loops moved back to where the anchor puts the twin when they strayed (REMOVAL_LEASH_*); whether the
        anchor still holds what it tracks (False: it lost it, or its history does not reach this track's samples)."""
        anchor = self.anchor
        if anchor is None or not anchor.channel.locked:
            return False
        own_chips, own_hz, at = self.channel.code_now()
        chips = anchor.channel.code_phase_at(at)
        if chips is None:
            return False
        offset = self.anchor_offset_chips if anchor.legit_offset_chips is None else anchor.legit_offset_chips
        want = (chips + float(np.clip(offset, -REMOVAL_CENTRE_CHIPS, REMOVAL_CENTRE_CHIPS))) % CA_CODE_LENGTH_CHIPS
        hz = anchor.channel.doppler_at(at)
        if abs(chips_offset(want, own_chips)) > REMOVAL_LEASH_CHIPS or abs(own_hz - hz) > REMOVAL_LEASH_HZ:
            self.channel.steer(want, hz)
        return True

    def _fits(self, block: np.ndarray) -> np.ndarray:
        """(REMOVAL_PHASES, lags, lags): the pseudo-inverse of the lags' Gram over a period like block's, its code
        phase at each phase of a sample (computed once: the rate hardly changes)."""
        if self._fit is None:
            n_lags, step = self.lags.size, float(block[3])
            fits = np.empty((REMOVAL_PHASES, n_lags, n_lags))
            one = np.array([block], dtype=np.float64)
            for q in range(REMOVAL_PHASES):
                gram = np.empty((n_lags, n_lags))
                for j, lag in enumerate(self.lags):
                    one[0, 2] = q * step / REMOVAL_PHASES + lag
                    for k in range(j, n_lags):
                        gram[j, k] = gram[k, j] = code_overlap(one, self.channel.bank, self.lags[k] - lag)[0]
                fits[q] = np.linalg.pinv(gram, rcond=REMOVAL_RCOND, hermitian=True)
            self._fit = fits
        return self._fit

    def _components(self, x: np.ndarray, base_sample: int, blocks: np.ndarray) -> np.ndarray:
        """Per code period, the least-squares amplitudes of the code at each lag (a_b = G_b^+ y_b)."""
        phase = np.round(np.mod(blocks[:, 2], blocks[:, 3]) / blocks[:, 3] * REMOVAL_PHASES).astype(np.int64)
        y, _ = correlator_bank(x, base_sample, blocks, self.channel.bank, self.lags)
        self._prompt = y[:, self._zero]
        return np.einsum("bjk,bk->bj", self._fits(blocks[0])[phase % REMOVAL_PHASES], np.nan_to_num(y))

    def prepare(self, work: np.ndarray, base_sample: int) -> tuple | None:
        i0 = self._first_settled()
        if i0 is None:
            return None
        blocks = self._tracked[2][i0:]
        if not self.settled:   # the held samples too, period by period
            self.settled = True
            held = self._held_blocks(base_sample, blocks[0])
            if held is not None:
                self.subtract(work, base_sample, held, self._components(work, base_sample, held))
            self.hold_from = None
        return blocks, self._components(work, base_sample, blocks)

    def subtract(self, x: np.ndarray, base_sample: int, blocks: np.ndarray, amplitudes: np.ndarray) -> None:
        # lag by lag: one kernel summing every lag's code first was no faster (0.11 against 0.09 s of CPU a second
        # at 2.6 MSa/s)
        for k, lag in enumerate(self.lags):
            subtract_replicas(x, base_sample, blocks, amplitudes[:, k], self.channel.bank, self.cfg.real_samples,
                              offset_chips=float(lag))

    def measure(self, work: np.ndarray, base_sample: int, planned: tuple) -> None:
        self._measure(work, base_sample, planned[0], self._prompt)


def _spans(n: int, parts: int) -> list[tuple[int, int]]:
    """[0, n) cut into `parts` consecutive spans (the threads' shares of a buffer)."""
    edges = np.linspace(0, n, max(1, parts) + 1).astype(np.int64)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


@dataclass
class CancellerStage:
    """One SIC iteration as a streaming filter: samples in, the same samples less its tracks' replicas out."""
    fs_hz: float
    if_hz: float
    index: int
    cfg: CancellerConfig = field(default_factory=CancellerConfig)
    front_end: ChipShapeMeter | None = None   # measured by the first stage's tracks, read by every stage's

    def __post_init__(self):
        self.tracks: dict[int, AdversaryTrack] = {}
        self._raw = np.empty(0, dtype=np.complex64)
        self._work = np.empty(0, dtype=np.complex64)
        self.base = 0                 # absolute index of _raw[0]

    @property
    def end_sample(self) -> int:
        return self.base + self._raw.size

    def add(self, peak: Peak, peak_sample: int, legit_offset_chips: float | None = None,
            defer_twin: bool = False, removal: bool = False) -> AdversaryTrack:
        # a twin this close was placed by a two-path fit on ideal chips' model (no CAF parts two peaks so close)
        meter = self.front_end
        defer_twin = defer_twin and meter is not None and not (meter.done and meter.shape.rectangular)
        deferred = defer_twin and legit_offset_chips is not None and abs(legit_offset_chips) < TWIN_NEAR_CHIPS
        kind = RemovalTrack if removal else AdversaryTrack
        track = kind(peak.prn, self.fs_hz, self.if_hz, peak, peak_sample, self.end_sample, self.cfg, self.index,
                     None if deferred or removal else legit_offset_chips, self.front_end)
        track.defer_twin = defer_twin
        if deferred:
            track.suspect_chips = legit_offset_chips
        self.tracks[peak.prn] = track
        return track

    def push(self, chunk: np.ndarray) -> np.ndarray:
        # the chunk joins the raw buffer the tracks read, then, on a worker beside the tracks, the buffer subtracted
        # from: under attack the main thread's share of a stage bounds the run. One copy at a time: both at once took
        # 20-30 MB more at the peak (10 MSa/s, every PRN spoofed)
        # (nothing held: the chunk itself, which is never written -- the guard's start-up hands over its first 0.3 s
        # at once, and a copy of it was 24 MB more at the peak at 10 MSa/s)
        self._raw = np.concatenate([self._raw, chunk]) if self._raw.size else chunk
        held = self._work
        work = np.empty(held.size + chunk.size, dtype=np.complex64)

        def join() -> None:
            work[:held.size] = held
            work[held.size:] = chunk
        tracks = list(self.tracks.items())
        # the longest first (a track with a twin within a chip fits two paths too): both threads end together
        longest_first = sorted(tracks, key=lambda item: not item[1]._joint())
        run_each(lambda item: join() if item is None else item[1].track(self._raw, self.base), [None, *longest_first])
        self._work = work
        if self.front_end is not None and (self.index == 0 and not self.front_end.done
                                           or any(tr.suspect_chips is not None for _, tr in tracks)):
            self._measure_front_end([tr for _, tr in tracks])
        planned = [(tr, tr.prepare(self._work, self.base)) for _, tr in tracks]
        planned = [(tr, p) for tr, p in planned if p is not None]
        work, base = self._work, self.base

        def subtract(part: tuple[int, int]) -> None:
            # every track's replicas over one span of samples, in the tracks' order: each sample is computed as by
            # one thread over the whole buffer
            a, b = part
            for tr, (blocks, est) in planned:
                tr.subtract(work[a:b], base + a, blocks, est)
        run_each(subtract, _spans(work.size, cores()))
        # joint tracks look again without the other spoofers (each reads work), then their changes are subtracted
        deltas = run_each(lambda item: item[0].refit(work, base, item[1]), planned)
        again = [(tr, blocks, delta) for (tr, (blocks, _)), delta in zip(planned, deltas) if delta is not None]
        if again:
            def correct(part: tuple[int, int]) -> None:
                a, b = part
                for tr, blocks, delta in again:
                    tr.subtract(work[a:b], base + a, blocks, delta)
            run_each(correct, _spans(work.size, cores()))
            planned = [(tr, (blocks, est if delta is None else est + delta))
                       for (tr, (blocks, est)), delta in zip(planned, deltas)]
        run_each(lambda item: item[0].measure(work, base, item[1]), planned)   # each reads work, writes its own
        for prn, tr in tracks:
            if not tr.channel.locked:   # the spoofer went away (or was never there)
                del self.tracks[prn]
        done = min([int(tr.next_sample if tr.hold_from is None else tr.hold_from) for tr in self.tracks.values()]
                   + [self.end_sample])
        n = max(0, done - self.base)
        out = self._work[:n]
        self._raw, self._work = self._raw[n:], self._work[n:].copy()
        self.base += n
        return out

    def _measure_front_end(self, tracks: list[AdversaryTrack]) -> None:
        """The first stage's settled spoofers, on the samples before any subtraction, measure the chips' shape (before
        the replicas of this buffer and the held samples are subtracted with it); then any stage's spoofers with a
        suspected twin, until the meter places it."""
        def measure(tr: AdversaryTrack):
            first_ms, prompts, blocks = tr._tracked
            settled = first_ms + np.arange(prompts.size) >= self.cfg.pull_in_ms
            if not settled.any():
                return None
            blocks, prompts = blocks[settled], prompts[settled]
            y, power = correlator_bank(self._raw, self.base, blocks, tr.channel.bank, LAGS_CHIPS)
            knots = None
            if not self.front_end.done:   # the knots' correlations serve the shape's fit alone
                bank = knot_bank(tr.prn, tr.channel.fs_hz)
                knots = correlator_bank(self._raw, self.base, blocks, bank, TAPS_CHIPS)[0] / bank.scale
            return tr, y, knots, prompts / blocks[:, 1], noise_power(power, blocks), blocks
        if self.front_end.done:
            tracks = [tr for tr in tracks if tr.suspect_chips is not None]
        else:   # the strongest only: a spoofer 6 dB weaker brings a quarter of the SNR for the same cost (101 lags)
            strongest = max((tr.channel.cn0_dbhz for tr in tracks if np.isfinite(tr.channel.cn0_dbhz)), default=np.nan)
            tracks = [tr for tr in tracks if not tr.channel.cn0_dbhz < strongest - MEASURED_WITHIN_DB
                      or tr.suspect_chips is not None]
        for seen in run_each(measure, tracks):
            if seen is not None:
                tr, y, knots, amplitudes, noise, blocks = seen
                self.front_end.add(tr.prn, y, knots, amplitudes, noise, blocks,
                                   tr.legit_offset_chips if tr._joint() else None, tr.suspect_chips)
        for prn, twin in self.front_end.fit_when_ready().items():
            if prn in self.tracks:
                self.tracks[prn].seat_twin(twin)

    def flush(self) -> np.ndarray:
        out = self._work
        self.base += out.size
        self._raw = self._work = np.empty(0, dtype=np.complex64)
        return out


class Canceller:
    """The whole LSR: a pipeline of stages; start() cancels a new adversarial peak, iterate() adds a stage."""

    def __init__(self, fs_hz: float, if_hz: float = 0.0, cfg: CancellerConfig = CancellerConfig()):
        self.fs_hz, self.if_hz, self.cfg = fs_hz, if_hz, cfg
        self.stages: list[CancellerStage] = []
        self._emitted = 0
        self.front_end = ChipShapeMeter()

    @property
    def prns(self) -> set[int]:
        return {p for s in self.stages for p in s.tracks}

    def cancel(self, peak: Peak, peak_sample: int, stage: int = 0, legit_code_phase_chips: float | None = None,
               removal: bool = False, defer_twin: bool = False) -> AdversaryTrack | None:
        """Start cancelling a peak at the given stage (0 = the first pass); None past the iteration bound.
        legit_code_phase_chips: where the same PRN's legitimate peak is, at the same instant, when known.
        removal: one stage past the bound, for what is left of a PRN given up (its remaining signal taken out, by
        projection: RemovalTrack).
        defer_twin: a suspected twin (AdversaryTrack.suspect_chips) is not followed until the meter has judged it:
        under a spoofer far stronger than any satellite the rounding's second path is as strong as the spoofer, and
        a joint track on it splits the spoofer in two (the shape then measured on halves, its cancellation gone)."""
        if stage >= self.cfg.max_stages + (1 if removal else 0):
            return None
        while len(self.stages) <= stage:   # a new stage takes the previous one's output from its next sample on
            st = CancellerStage(self.fs_hz, self.if_hz, len(self.stages), self.cfg, self.front_end)
            st.base = self.stages[-1].base if self.stages else self._emitted
            self.stages.append(st)
        offset = None
        if legit_code_phase_chips is not None:
            offset = chips_offset(legit_code_phase_chips, peak.code_phase_chips)
        return self.stages[stage].add(peak, peak_sample, offset, defer_twin, removal)

    def restart(self) -> None:
        """Every stage begun again at the first sample with the tracks it holds now, their code and carrier carried
        back there (the plug-in filter's start-up replay, SpoofGuard's replay_start: spoofers alarmed a second
        apart are cancelled from the first sample alike). What the tracks judged of their twins and of the
        spoofers' place is kept; their measurements start again."""
        old, self.stages, self._emitted = self.stages, [], 0
        again: dict[int, AdversaryTrack] = {}   # id of each old track -> its new one (a removal's anchor)
        for st in old:
            stage = CancellerStage(self.fs_hz, self.if_hz, st.index, self.cfg, self.front_end)
            for prn, tr in st.tracks.items():
                chips, doppler_hz, sample = tr.channel.code_now()
                twin = tr.suspect_chips
                if twin is None and tr.legit_offset_chips is not None:   # where it was at the first sample
                    twin = tr.legit_offset_chips - (tr._offset_rate_chips_s * sample / self.fs_hz if tr.settled
                                                    else 0.0)
                new = stage.add(Peak(prn, chips, doppler_hz, 0.0, float(tr.channel.cn0_dbhz)), sample, twin,
                                defer_twin=tr.suspect_chips is not None and tr.defer_twin,
                                removal=isinstance(tr, RemovalTrack))
                new.defer_twin, new.dismissed_chips = tr.defer_twin, tr.dismissed_chips
                new.spoofer_place_chips, new.place_learnt_ms = tr.spoofer_place_chips, tr.place_learnt_ms
                if isinstance(tr, RemovalTrack) and tr.anchor is not None:   # its anchor's stage, the first, is anew
                    new.anchor, new.anchor_offset_chips = again.get(id(tr.anchor)), tr.anchor_offset_chips
                again[id(tr)] = new
            self.stages.append(stage)

    def remove(self, remainder: Peak, sample: int) -> AdversaryTrack | None:
        """Take out what is left of a PRN given up (a RemovalTrack on its remainder, at an absolute sample). The
        later stages' lone tracks that chased that remainder within REMOVAL_REACH_CHIPS give way to it, and it goes
        after the first stage and any later one kept: a joint track (its twin places the removal again when it ends)
        or one cancelling another copy further off. Left behind the chasers, it tracked what they had half taken out
        and lost it three times in 2.5 s, and the satellite stayed in the output, called removed (GPS-SDR-SIM behind
        1 MHz, flying, 500 m, +10 dB: PRN 7 at 36-41 dB-Hz to the end, our receiver's range behind the filter 9 m
        off). It is leashed to the PRN's first-stage track (RemovalTrack.leash) when there is one."""
        stage = 1
        for k, st in enumerate(self.stages[1:], start=1):
            tr = st.tracks.get(remainder.prn)
            if tr is None:
                continue
            chips = tr.channel.code_phase_at(sample)
            if tr.legit_offset_chips is None and (
                    chips is None or chips_apart(chips, remainder.code_phase_chips) <= REMOVAL_REACH_CHIPS):
                del st.tracks[remainder.prn]
            else:
                stage = k + 1
        track = self.cancel(remainder, sample, stage, removal=True)
        anchor = self.stages[0].tracks.get(remainder.prn) if self.stages else None
        if track is not None and anchor is not None and not isinstance(anchor, RemovalTrack):
            track.leash(anchor, remainder.code_phase_chips, sample)
        return track

    def removing(self, prn: int) -> bool:
        """Whether a PRN's remainder is being taken out (a RemovalTrack follows it)."""
        return any(isinstance(st.tracks.get(prn), RemovalTrack) for st in self.stages)

    def drop(self, prn: int) -> None:
        """Stop cancelling a PRN in every stage (what was cancelled is found to be the legitimate signal)."""
        for st in self.stages:
            st.tracks.pop(prn, None)

    def push(self, chunk: np.ndarray) -> np.ndarray:
        """Samples in; cleaned samples out, in order, a little behind (each stage holds back a code period)."""
        out = np.asarray(chunk, dtype=np.complex64)
        for st in self.stages:
            out = st.push(out)
        self._emitted += out.size
        self._vote_place()
        return out

    def _vote_place(self) -> None:
        """The spoofers' place behind a front end: the median of the tracks that learnt theirs (PLACE_*)."""
        learnt = [tr.spoofer_place_chips for st in self.stages for tr in st.tracks.values()
                  if getattr(tr, "place_learnt_ms", 0) * CA_CODE_PERIOD_S >= PLACE_LEARNT_S]
        if len(learnt) >= PLACE_VOTERS:
            self.front_end.place_chips = float(np.median(learnt))

    def flush(self) -> np.ndarray:
        """The samples still held back, at the end of the stream."""
        out = np.empty(0, dtype=np.complex64)
        for st in self.stages:
            out = np.concatenate([st.push(out), st.flush()])
        self._emitted += out.size
        return out

    def report(self) -> dict[int, list[dict]]:
        """Per PRN, per stage: the attenuation measured in each window so far."""
        out: dict[int, list[dict]] = {}
        for st in self.stages:
            for prn, tr in st.tracks.items():
                entry = {"stage": st.index,
                         "attenuation_db": [f">={v}" if lower else v for v, lower in tr.attenuation_db]}
                if tr.legit_offset_chips is not None:
                    entry["legit_offset_chips"] = round(float(tr.legit_offset_chips), 3)
                if tr.dismissed_chips is not None:   # the front end's rounding, not a twin
                    entry["dismissed_twin_chips"] = round(float(tr.dismissed_chips), 3)
                if tr.twin_advantage_db is not None:
                    entry["twin_advantage_db"] = round(tr.twin_advantage_db, 1)
                out.setdefault(prn, []).append(entry)
        return out


def caf_amplitude(samples: np.ndarray, fs_hz: float, if_hz: float, prn: int, code_phase_chips: float,
                  doppler_hz: float, n_blocks: int = 20) -> float:
    """A signal's amplitude from its CAF peak: |a| = sqrt(S_max) / K (the paper's equation 10).

    S_max, the peak's |R|^2, also holds the power of the noise and of every other signal passing through the
    correlator, which inflates the paper's estimate at low C/N0; that share is measured at code phases far from any
    peak of this PRN and taken out.
    """
    from ..receiver import correlate_ms
    k = int(round(fs_hz * 1e-3))
    x = samples[:k * n_blocks]
    peak, *off = correlate_ms(x, fs_hz, prn, [code_phase_chips + d for d in (0.0, 257.3, 511.7, 768.1)], doppler_hz,
                              if_hz)
    s_max, floor = float(np.mean(np.abs(peak) ** 2)), float(np.mean(np.abs(np.concatenate(off)) ** 2))
    return float(np.sqrt(max(s_max - floor, 0.0)) / k)
