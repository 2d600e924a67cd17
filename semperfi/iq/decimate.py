"""Streaming anti-alias decimation: a 25 MSa/s recording (TEXBAT) brought to a processing rate in bounded memory.

A linear-phase FIR low-pass (scipy.signal.firwin, Kaiser window) computes only the kept outputs over consecutive
chunks (a numba kernel in float32; scipy.signal.upfirdn is its slow reference); the filter's tail carries over
between chunks, so the output is the same however the input is chunked. The filter's delay is compensated: output
sample j is input time j * M.
"""

from __future__ import annotations

import math
from typing import Iterable, Iterator

import numba
import numpy as np

TAPS_PER_PHASE = 16    # taps = 2 * TAPS_PER_PHASE * M + 1: ~60 dB stop band from 0.5 fs_out, even delay
MIN_PROCESSING_HZ = 2.1e6   # C/A's main lobe (+-1.023 MHz) and a little margin
PASSBAND = 0.8         # of the output Nyquist band kept flat; GPS L1 C/A's main lobe needs +-1.023 MHz


def decimation_factor(fs_in_hz: float, fs_out_hz: float) -> int:
    """The integer M with fs_in = M * fs_out, or one ValueError line."""
    if not (math.isfinite(fs_in_hz) and math.isfinite(fs_out_hz)) or fs_in_hz <= 0 or fs_out_hz <= 0:
        raise ValueError(f"sample rates must be positive, got {fs_in_hz!r} -> {fs_out_hz!r}")
    if fs_out_hz < MIN_PROCESSING_HZ:
        raise ValueError(f"processing rate {fs_out_hz:g} Hz is too low for GPS L1 C/A (at least 2.1 MHz)")
    ratio = fs_in_hz / fs_out_hz
    m = int(round(ratio))
    if m < 1 or abs(ratio - m) > 1e-9 * ratio:
        near = max(1, min(m, math.floor(fs_in_hz / MIN_PROCESSING_HZ)))   # the closest rate that would do
        raise ValueError(f"processing rate {fs_out_hz:g} Hz must divide the file's rate {fs_in_hz:g} Hz "
                         f"(e.g. {fs_in_hz / near:g} Hz)")
    return m


class StreamDecimator:
    """Low-pass and keep every M-th sample of a complex stream fed in chunks of any size."""

    def __init__(self, factor: int):
        if int(factor) != factor or factor < 1:
            raise ValueError(f"decimation factor must be a positive integer, got {factor!r}")
        self.factor = m = int(factor)
        n_taps = 2 * TAPS_PER_PHASE * m + 1
        from scipy import signal   # here: importing scipy.signal costs most of a second, and few runs decimate
        self.taps = (signal.firwin(n_taps, PASSBAND / m, window=("kaiser", 6.0)) if m > 1
                     else np.ones(1)).astype(np.float32)
        self._reversed_taps = np.ascontiguousarray(self.taps[::-1])
        self._tail = np.zeros(len(self.taps) - 1, dtype=np.complex64)   # the last L-1 inputs seen
        self._phase = 0             # where, past the tail, the next kept output's newest input sits
        self._skip = TAPS_PER_PHASE if m > 1 else 0   # outputs before input sample 0 (the filter's delay)

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """Decimated samples of `chunk` (complex64); their count varies by one with the chunking."""
        x = np.asarray(chunk, dtype=np.complex64)
        if self.factor == 1:
            return x.copy()
        n_tail, m = len(self._tail), self.factor
        ext = np.concatenate([self._tail, x])
        # Full-convolution index n of ext holds the filter output whose newest input is ext[n]; keep n = n_tail +
        # phase + j*M. Feeding ext[phase:] makes those indices n_tail + j*M, and n_tail is a multiple of M.
        count = max(0, (len(ext) - self._phase - n_tail + m - 1) // m)
        out = np.empty(count, dtype=np.complex64)
        _fir_decimate(ext.view(np.float32), self._reversed_taps, self._phase, m, out.view(np.float32))
        self._phase = self._phase + count * m - len(x)
        self._tail = ext[len(ext) - n_tail:].copy()
        if self._skip:
            drop = min(self._skip, len(out))
            out, self._skip = out[drop:], self._skip - drop
        return out


def reference_process(taps: np.ndarray, ext: np.ndarray, phase: int, m: int) -> np.ndarray:
    """The slow reference of the kernel: the outputs whose newest input is ext[phase + L-1 + j*M]."""
    from scipy import signal
    n_tail = len(taps) - 1
    y = signal.upfirdn(taps, ext[phase:], 1, m)
    count = max(0, (len(ext) - phase - n_tail + m - 1) // m)
    return y[n_tail // m:n_tail // m + count].astype(np.complex64)


@numba.njit(cache=True, fastmath=True, nogil=True)
def _fir_decimate(ext_iq, reversed_taps, phase, m, out_iq):
    """out[j] = sum_k taps[k] ext[phase + L-1 + j*M - k], on interleaved float32 I/Q (taps reversed, so the inner
    loop runs forward over memory)."""
    n_taps = len(reversed_taps)
    for j in range(len(out_iq) // 2):
        first = phase + j * m
        re = np.float32(0.0)
        im = np.float32(0.0)
        for k in range(n_taps):
            h = reversed_taps[k]
            re += h * ext_iq[2 * (first + k)]
            im += h * ext_iq[2 * (first + k) + 1]
        out_iq[2 * j] = re
        out_iq[2 * j + 1] = im


def decimate_chunks(chunks: Iterable[np.ndarray], factor: int) -> Iterator[np.ndarray]:
    """Decimate a stream of chunks; the caller's chunks are never held past their turn."""
    dec = StreamDecimator(factor)
    for chunk in chunks:
        out = dec.process(chunk)
        if out.size:
            yield out
