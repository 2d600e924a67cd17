"""Tracking channels: an early-late DLL aided by the carrier, a Costas PLL with FLL assist for pull-in, C/N0,
lock detectors, bit synchronisation. One numba kernel runs a channel through a whole buffer of samples, one code
period at a time, so Python is only visited once per buffer.
"""

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..gps import CA_CHIP_RATE_HZ, CA_CODE_LENGTH_CHIPS, L1_HZ
from .correlator import block_length, code_bank, correlate_block, lane_buffer

# state vector of a channel (float64), shared by the kernel and its reference
CODE_PHASE, CODE_RATE, CARR_PHASE, CARR_FREQ, FREQ_STATE, PREV_I, PREV_Q, HAVE_PREV, CARR_TOTAL, NEXT_SAMPLE = range(10)
N_STATE = 10
# loop parameters (float64)
FS, IF, HALF_SPACING, PLL_WN, FLL_WN, DLL_K, T_INT = range(7)
N_PARAM = 7
BLOCK_COLUMNS = 6   # first sample, samples, code phase, code step, carrier phase, carrier step (per code period)


@dataclass(frozen=True)
class LoopConfig:
    pll_bw_hz: float = 18.0
    fll_bw_hz: float = 10.0        # during pull-in only
    dll_bw_hz: float = 2.0
    spacing_chips: float = 0.5     # early-late distance
    pull_in_ms: int = 500
    dll_narrow_bw_hz: float = 0.0  # when > 0: the DLL narrows to this after narrow_after_ms (gear shift)
    narrow_after_ms: int = 1500
    lock_window_ms: int = 200
    min_cn0_dbhz: float = 25.0
    min_carrier_lock: float = 0.4
    # The FLL comes back on while the carrier lock indicator of the last window is below this: a carrier frequency
    # step (a spoofer's time push starting, a jolt) pulls a Costas PLL of this bandwidth out of phase lock for good
    # (a 39 Hz step at 59 dB-Hz: the loop's peak phase error ~0.5 cycle), the FLL pulls the frequency back in a
    # few tens of ms and the PLL relocks; it stays off while locked, where its 1 ms discriminator only adds noise.
    assist_below_lock: float = 0.7
    lost_windows: int = 3          # consecutive bad windows before the channel declares loss of lock


def loop_params(fs_hz: float, if_hz: float, cfg: LoopConfig, pull_in: bool, narrow: bool = False) -> np.ndarray:
    prm = np.zeros(N_PARAM)
    prm[FS], prm[IF], prm[HALF_SPACING] = fs_hz, if_hz, cfg.spacing_chips / 2
    prm[PLL_WN] = cfg.pll_bw_hz / 0.53            # 2nd-order loop: Bn = 0.53 w0
    prm[FLL_WN] = 4.0 * cfg.fll_bw_hz if pull_in else 0.0   # 1st-order FLL: Bn = w0 / 4
    prm[DLL_K] = 4.0 * (cfg.dll_narrow_bw_hz if narrow and cfg.dll_narrow_bw_hz > 0 else cfg.dll_bw_hz)  # Bn = K/4
    prm[T_INT] = 1e-3
    return prm


@njit(cache=True, nogil=True)
def loop_update(st, prm, e, p, late):
    """Discriminators and loop filters after one code period; updates the NCOs in st."""
    t = prm[T_INT]
    i, q = p.real, p.imag
    e_pll = np.arctan(q / i) / (2 * np.pi) if i != 0.0 else 0.25 * np.sign(q)   # Costas: cycles, bit-insensitive
    e_fll = 0.0
    if st[HAVE_PREV] > 0.0:
        dot = st[PREV_I] * i + st[PREV_Q] * q
        cross = st[PREV_I] * q - st[PREV_Q] * i
        if dot != 0.0:
            e_fll = np.arctan(cross / dot) / (2 * np.pi * t)   # Hz; atan (not atan2) ignores bit flips
    st[PREV_I], st[PREV_Q], st[HAVE_PREV] = i, q, 1.0
    wn, wf = prm[PLL_WN], prm[FLL_WN]
    st[FREQ_STATE] += t * (wn * wn * e_pll + wf * e_fll)
    st[CARR_FREQ] = st[FREQ_STATE] + 1.414 * wn * e_pll
    ae, al = abs(e), abs(late)
    e_code = (ae - al) / (ae + al) * (1.0 - prm[HALF_SPACING]) if ae + al > 0.0 else 0.0   # chips
    st[CODE_RATE] = CA_CHIP_RATE_HZ * (1.0 + st[CARR_FREQ] / L1_HZ) + prm[DLL_K] * e_code


@njit(cache=True, nogil=True)
def track_kernel(x, base_sample, st, prm, rows, first, bank_step, lanes, out_e, out_p, out_l, out_epoch, out_doppler,
                 out_carr, out_block):
    """Track through x (whose first sample is absolute index base_sample) while whole code periods remain.

    Each period's E/P/L, the absolute (fractional) sample index of its code epoch, the Doppler and the accumulated
    carrier phase at that epoch are written to the out arrays, and the replica that was correlated to out_block
    (first sample, samples, code phase, code step, carrier phase, carrier step: what a canceller needs to rebuild
    it); returns how many periods were processed. rows/first/bank_step: the PRN's CodeBank; lanes: scratch.
    """
    fs = prm[FS]
    m = 0
    while m < out_p.size:
        offset = np.int64(st[NEXT_SAMPLE] - base_sample)
        if offset < 0:
            break
        cp = st[CODE_PHASE]
        step = st[CODE_RATE] / fs
        n = block_length(cp, step)
        if offset + n > x.size:
            break
        carr_step = (prm[IF] + st[CARR_FREQ]) / fs
        e, p, late = correlate_block(x, offset, n, rows, first, bank_step, cp, step, st[CARR_PHASE], carr_step,
                                  prm[HALF_SPACING], lanes)
        out_e[m], out_p[m], out_l[m] = e, p, late
        out_epoch[m] = st[NEXT_SAMPLE] - cp / step
        out_doppler[m] = st[CARR_FREQ]
        out_carr[m] = st[CARR_TOTAL]
        out_block[m, 0], out_block[m, 1], out_block[m, 2] = st[NEXT_SAMPLE], n, cp
        out_block[m, 3], out_block[m, 4], out_block[m, 5] = step, st[CARR_PHASE], carr_step
        ph = st[CARR_PHASE] + n * carr_step
        st[CARR_PHASE] = ph - np.floor(ph)
        st[CARR_TOTAL] += n * st[CARR_FREQ] / fs
        st[CODE_PHASE] = cp + n * step - CA_CODE_LENGTH_CHIPS
        st[NEXT_SAMPLE] += n
        loop_update(st, prm, e, p, late)
        m += 1
    return m


def track_reference(x, base_sample, st, prm, code, max_periods):
    """The kernel's loop with the plain numpy correlator (slow; for tests). Returns (E, P, L, epoch) lists."""
    from .correlator import correlate_block_reference
    fs = prm[FS]
    out = []
    while len(out) < max_periods:
        offset = int(st[NEXT_SAMPLE] - base_sample)
        cp, step = st[CODE_PHASE], st[CODE_RATE] / fs
        n = int(np.ceil((CA_CODE_LENGTH_CHIPS - cp) / step))
        if offset < 0 or offset + n > x.size:
            break
        carr_step = (prm[IF] + st[CARR_FREQ]) / fs
        e, p, late = correlate_block_reference(x[offset:offset + n], code, cp, step, st[CARR_PHASE], carr_step,
                                            prm[HALF_SPACING])
        out.append((e, p, late, st[NEXT_SAMPLE] - cp / step))
        st[CARR_PHASE] = (st[CARR_PHASE] + n * carr_step) % 1.0
        st[CARR_TOTAL] += n * st[CARR_FREQ] / fs
        st[CODE_PHASE] = cp + n * step - CA_CODE_LENGTH_CHIPS
        st[NEXT_SAMPLE] += n
        loop_update(st, prm, e, p, late)
    return out


def initial_state(code_phase_chips: float, at_sample: float, doppler_hz: float, fs_hz: float,
                  start_after_sample: float) -> np.ndarray:
    """A channel state starting at the first code epoch at or after start_after_sample.

    code_phase_chips is the chip arriving at sample at_sample (acquisition's convention); the code is propagated
    with the Doppler-scaled chip rate to the chosen epoch.
    """
    st = np.zeros(N_STATE)
    rate = CA_CHIP_RATE_HZ * (1.0 + doppler_hz / L1_HZ)
    step = rate / fs_hz
    cp_at_start = code_phase_chips + (start_after_sample - at_sample) * step
    to_epoch = (-cp_at_start) % CA_CODE_LENGTH_CHIPS        # chips until the next code epoch
    n_to_epoch = int(np.ceil(to_epoch / step - 1e-9))
    st[NEXT_SAMPLE] = start_after_sample + n_to_epoch
    st[CODE_PHASE] = n_to_epoch * step - to_epoch             # in [0, step)
    st[CODE_RATE] = rate
    st[CARR_FREQ] = st[FREQ_STATE] = doppler_hz
    return st


def cn0_m2m4_dbhz(prompt: np.ndarray, t_int_s: float = 1e-3) -> float:
    """The moments (M2M4) C/N0 estimator: data- and phase-insensitive, from prompt correlations alone."""
    p2 = np.abs(prompt) ** 2
    m2, m4 = float(np.mean(p2)), float(np.mean(p2 ** 2))
    pd = np.sqrt(max(2 * m2 * m2 - m4, 0.0))
    pn = m2 - pd
    if pd <= 0.0 or pn <= 0.0:
        return -np.inf if pd <= 0.0 else 99.0
    return float(10 * np.log10(pd / pn / t_int_s))


def carrier_lock(prompt: np.ndarray) -> float:
    """cos(2 x phase error) estimate in [-1, 1]: near 1 when the Costas loop is locked."""
    i2, q2 = float(np.sum(prompt.real ** 2)), float(np.sum(prompt.imag ** 2))
    return (i2 - q2) / (i2 + q2) if i2 + q2 > 0 else 0.0


class BitSync:
    """Finds the data bit edge from where the prompt's sign flips (mod 20 ms)."""

    def __init__(self, min_transitions: int = 12, ratio: float = 4.0):
        self.counts = np.zeros(20, dtype=np.int64)
        self.min_transitions, self.ratio = min_transitions, ratio
        self._prev_sign = 0.0
        self.edge_ms: int | None = None   # ms index (mod 20) at which bits start

    def push(self, prompt_i: np.ndarray, first_ms: int) -> None:
        if self.edge_ms is not None or prompt_i.size == 0:
            return
        signs = np.sign(prompt_i)
        prev = np.concatenate([[self._prev_sign], signs[:-1]])
        flips = np.nonzero((prev * signs) < 0)[0]
        np.add.at(self.counts, (first_ms + flips) % 20, 1)
        self._prev_sign = signs[-1]
        order = np.sort(self.counts)
        if order[-1] >= self.min_transitions and order[-1] >= self.ratio * max(order[-2], 1):
            self.edge_ms = int(np.argmax(self.counts))


class Channel:
    """One satellite being tracked: the NCO state, per-ms history, lock status, and bits for the decoder."""

    HISTORY_MS = 4000

    def __init__(self, prn: int, fs_hz: float, if_hz: float, state: np.ndarray, cfg: LoopConfig = LoopConfig()):
        self.prn, self.fs_hz, self.if_hz, self.cfg = prn, fs_hz, if_hz, cfg
        self.st = state
        self.bank = code_bank(prn, fs_hz)
        self._lanes = lane_buffer()
        self.ms = 0                    # code periods tracked so far
        self.bits = BitSync()
        self.cn0_dbhz = np.nan
        self.lock = 0.0
        self.locked = True
        self.assisted = False          # the FLL back on after a window with a poor carrier lock
        self._bad_windows = 0
        self._window: list[np.ndarray] = []
        self._window_len = 0
        n = self.HISTORY_MS
        self.epoch_sample = np.full(n, np.nan)   # ring buffers indexed by ms % n
        self.doppler_hz = np.zeros(n)
        self.carrier_cycles = np.zeros(n)
        self.prompt = np.zeros(n, dtype=np.complex128)
        self._next_bit_ms: int | None = None     # first ms not yet turned into a bit

    @property
    def pull_in(self) -> bool:
        return self.ms < self.cfg.pull_in_ms

    @property
    def fll_on(self) -> bool:
        return self.pull_in or self.assisted

    def process(self, x: np.ndarray, base_sample: int) -> tuple[np.ndarray, int]:
        """Track through the buffer; returns the new prompts and the ms index of the first of them."""
        max_ms = x.size // int(self.fs_hz * 1e-3 * 0.9) + 2
        out_e, out_p, out_l = (np.empty(max_ms, dtype=np.complex128) for _ in range(3))
        out_epoch, out_dopp, out_carr = (np.empty(max_ms) for _ in range(3))
        out_block = np.empty((max_ms, BLOCK_COLUMNS))
        prm = loop_params(self.fs_hz, self.if_hz, self.cfg, self.fll_on)
        first = self.ms
        m = 0
        # the FLL switches off at the end of pull-in: run the kernel up to that boundary first
        if self.pull_in:
            limit = min(max_ms, self.cfg.pull_in_ms - self.ms)
            m = track_kernel(x, base_sample, self.st, prm, *self._bank_args(), out_e[:limit], out_p[:limit],
                             out_l[:limit], out_epoch[:limit], out_dopp[:limit], out_carr[:limit], out_block[:limit])
            prm = loop_params(self.fs_hz, self.if_hz, self.cfg, self.assisted)
        if self.ms >= self.cfg.narrow_after_ms:
            prm = loop_params(self.fs_hz, self.if_hz, self.cfg, self.assisted, narrow=True)
        if m < max_ms:
            m += track_kernel(x, base_sample, self.st, prm, *self._bank_args(), out_e[m:], out_p[m:], out_l[m:],
                              out_epoch[m:], out_dopp[m:], out_carr[m:], out_block[m:])
        idx = (first + np.arange(m)) % self.HISTORY_MS
        self.epoch_sample[idx], self.doppler_hz[idx] = out_epoch[:m], out_dopp[:m]
        self.carrier_cycles[idx], self.prompt[idx] = out_carr[:m], out_p[:m]
        self.ms += m
        self._update_lock(out_p[:m])
        if not self.pull_in:
            self.bits.push(out_p[:m].real, first)
        self.last_blocks = out_block[:m]
        return out_p[:m], first

    def _bank_args(self) -> tuple:
        return self.bank.rows, self.bank.first, self.bank.step_chips, self._lanes

    def code_now(self) -> tuple[float, float, float]:
        """Where the loops hold the signal, in acquisition's convention: (the chip arriving at the next sample, the
        carrier's Doppler, that sample) -- initial_state's arguments to start another channel on it."""
        return float(self.st[CODE_PHASE]), float(self.st[CARR_FREQ]), float(self.st[NEXT_SAMPLE])

    def steer(self, code_phase_chips: float, doppler_hz: float) -> None:
        """Put the loops on a code phase (the chip arriving at the next sample) and a Doppler given from outside: a
        channel leashed to another's track. Its code runs from the first epoch at or after that sample (the periods
        before it are skipped, never read twice), its carrier's phase is kept."""
        at = float(self.st[NEXT_SAMPLE])
        fresh = initial_state(code_phase_chips, at, doppler_hz, self.fs_hz, at)
        for k in (CODE_PHASE, CODE_RATE, NEXT_SAMPLE, CARR_FREQ, FREQ_STATE):
            self.st[k] = fresh[k]

    def hold_lock(self) -> None:
        """Locked whatever its own prompts say: a channel steered from outside has the lock of what steers it."""
        self.locked, self._bad_windows = True, 0

    def _update_lock(self, prompt: np.ndarray) -> None:
        self._window.append(prompt)
        self._window_len += prompt.size
        while self._window_len >= self.cfg.lock_window_ms:
            w = np.concatenate(self._window)
            cur, rest = w[:self.cfg.lock_window_ms], w[self.cfg.lock_window_ms:]
            self._window, self._window_len = [rest], rest.size
            self.cn0_dbhz = cn0_m2m4_dbhz(cur)
            self.lock = carrier_lock(cur)
            bad = self.cn0_dbhz < self.cfg.min_cn0_dbhz or (not self.pull_in and self.lock < self.cfg.min_carrier_lock)
            self.assisted = not self.pull_in and self.lock < self.cfg.assist_below_lock
            self._bad_windows = self._bad_windows + 1 if bad else 0
            if self._bad_windows >= self.cfg.lost_windows:
                self.locked = False

    def take_bits(self) -> tuple[np.ndarray, int]:
        """Soft data bits completed since the last call, and the bit index of the first (bit 0 starts at ms edge)."""
        edge = self.bits.edge_ms
        if edge is None:
            return np.empty(0), 0
        if self._next_bit_ms is None:   # the first whole bit still in the history
            oldest = max(self.ms - self.HISTORY_MS + 1, 0)
            self._next_bit_ms = edge + 20 * int(np.ceil((oldest - edge) / 20))
        n_bits = (self.ms - self._next_bit_ms) // 20
        if n_bits <= 0:
            return np.empty(0), 0
        ms = self._next_bit_ms + np.arange(20 * n_bits)
        soft = self.prompt[ms % self.HISTORY_MS].real.reshape(n_bits, 20).sum(axis=1)
        first_index = (self._next_bit_ms - edge) // 20
        self._next_bit_ms += 20 * n_bits
        return soft, first_index

    def ms_of_bit(self, bit_index: int) -> int:
        return self.bits.edge_ms + 20 * bit_index

    @property
    def latest_epoch_sample(self) -> float:
        """The absolute sample of the latest code epoch tracked (where this channel's code phase is 0)."""
        return float(self.epoch_sample[(self.ms - 1) % self.HISTORY_MS])

    def epoch_around(self, sample: float) -> tuple[int, float] | None:
        """(ms index j, fraction) with code epoch j at or before the sample and epoch j + 1 after it."""
        lo = max(self.ms - self.HISTORY_MS + 1, 0)
        if self.ms - lo < 2:
            return None
        idx = np.arange(lo, self.ms)
        epochs = self.epoch_sample[idx % self.HISTORY_MS]
        k = int(np.searchsorted(epochs, sample, side="right")) - 1
        if k < 0 or k + 1 >= idx.size:
            return None
        return int(idx[k]), float((sample - epochs[k]) / (epochs[k + 1] - epochs[k]))

    def code_phase_at(self, sample: float) -> float | None:
        """The code phase (chips) arriving at an absolute sample, between the code epochs around it; None when they
        are not in the history."""
        around = self.epoch_around(sample)
        return None if around is None else around[1] * CA_CODE_LENGTH_CHIPS

    def transmit_time_at(self, sample: float, ms_ref: int, t_sv_ref_s: float) -> float | None:
        """Satellite time of the signal at an absolute sample index, given that code period ms_ref began at t_sv_ref.

        Interpolates between the code epochs around the sample; None when they are not in the history.
        """
        around = self.epoch_around(sample)
        if around is None:
            return None
        j, frac = around
        return t_sv_ref_s + (j - ms_ref + frac) * 1e-3

    def carrier_cycles_at(self, sample: float) -> float | None:
        """Accumulated carrier Doppler phase (cycles) at a sample: the integrated Doppler, for carrier smoothing."""
        around = self.epoch_around(sample)
        if around is None:
            return None
        j, frac = around
        a, b = self.carrier_cycles[j % self.HISTORY_MS], self.carrier_cycles[(j + 1) % self.HISTORY_MS]
        return float(a + frac * (b - a))

    def doppler_at(self, sample: float) -> float:
        i = (self.ms - 1) % self.HISTORY_MS
        return float(self.doppler_hz[i])
