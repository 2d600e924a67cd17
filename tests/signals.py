"""C/A signals for tests, at baseband: the code sampled at the signal's own chip rate (Doppler on the code too)."""

import numpy as np

from semperfi.gps import CA_CHIP_RATE_HZ, L1_HZ, ca_code


def ca_signal(prn: int, t_s: np.ndarray, code_phase_chips: float, doppler_hz: float, amplitude: float,
              phase_rad: float = 0.0, bits: np.ndarray | None = None) -> np.ndarray:
    """amplitude * data * code * carrier at times t_s, the code at code_phase_chips at t = 0; bits (optional): 50 bit/s
    data, a bit every 20 of the signal's own code periods, from its first epoch on (repeating)."""
    chips = code_phase_chips + t_s * CA_CHIP_RATE_HZ * (1 + doppler_hz / L1_HZ)
    out = amplitude * ca_code(prn)[np.floor(chips).astype(np.int64) % 1023] \
        * np.exp(1j * (2 * np.pi * doppler_hz * t_s + phase_rad))
    if bits is not None:
        out = out * bits[np.floor(chips / 1023 / 20).astype(np.int64) % bits.size]
    return out


def behind_front_end(fs_hz: float, cutoff_hz: float, duration_s: float, legit: list[tuple], spoofers: list[tuple],
                     amplitude: float, advantage_db: float, seed: int = 1, up: int = 4, if_hz: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(with the spoofers, without) as a real front end delivers them: rendered `up` times faster with unit noise,
    through a 5th-order Butterworth low-pass of cutoff_hz (0: none, ideal chips) and decimated to fs_hz -- chips
    rounded as an analog filter before a sampler rounds them. legit and spoofers: (prn, code phase chips, Doppler
    Hz, phase rad) each, amplitude per sample at fs_hz for unit noise per component. if_hz: real samples at that IF
    (complex64 with no imaginary part), the band moved there before the sampler."""
    from scipy.signal import butter, sosfilt
    rng = np.random.default_rng(seed)
    fast = fs_hz * up
    sos = butter(5, cutoff_hz, fs=fast, output="sos") if cutoff_hz else None
    state = [np.zeros((sos.shape[0], 2), dtype=complex) if sos is not None else None for _ in range(2)]
    gain = 10 ** (advantage_db / 20)
    out: list[list[np.ndarray]] = [[], []]
    chunk = int(round(0.1 * fast))
    for a in range(0, int(round(duration_s * fast)), chunk):
        t = (a + np.arange(chunk)) / fast
        clean = (rng.standard_normal(chunk) + 1j * rng.standard_normal(chunk)) * np.sqrt(up)
        for prn, cp, dop, ph in legit:
            clean += ca_signal(prn, t, cp, dop, amplitude, ph)
        attacked = clean.copy()
        for prn, cp, dop, ph in spoofers:
            attacked += ca_signal(prn, t, cp, dop, amplitude * gain, ph)
        for i, v in enumerate((attacked, clean)):
            if sos is not None:
                v, state[i] = sosfilt(sos, v, zi=state[i])
            if if_hz:
                v = np.sqrt(2) * np.real(v * np.exp(2j * np.pi * if_hz * t)) + 0j
            out[i].append(v[::up].astype(np.complex64))
    return np.concatenate(out[0]), np.concatenate(out[1])


def cancelling_pairs(x: np.ndarray, fs_hz: float, spoofers: list[tuple], legit: list[tuple]):
    """A Canceller started on each spoofer as its first 10 ms find it, its twin's place handed to it: spoofers and
    legit as behind_front_end takes them, pairwise."""
    from semperfi.defense.canceller import Canceller, CancellerConfig, refine_peak
    from semperfi.receiver.acquisition import DopplerGrid, acquire
    c = Canceller(fs_hz, 0.0, CancellerConfig())
    look = x[:int(0.01 * fs_hz)]
    for (prn, spoofer_chips, *_), (_, legit_chips, *_) in zip(spoofers, legit):
        caf = acquire(look, fs_hz, [prn], DopplerGrid(max_hz=6000, step_hz=333), coherent_ms=2, noncoherent=5)[prn]
        peak = refine_peak(look, fs_hz, 0.0, caf.best)
        c.cancel(peak, 0, 0, legit_code_phase_chips=(peak.code_phase_chips + legit_chips - spoofer_chips) % 1023)
    return c
